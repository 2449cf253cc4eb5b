"""MC-PILCO: Monte Carlo probabilistic inference for learning control (thesis ch. 5).

TorchRL-style parts (Amadio et al., IEEE T-RO 2022):

* modules: :class:`SquashedRBFPolicy` (a ``TensorDictModule`` via :func:`make_policy_module`),
  :class:`GPDynamicsModel` / :class:`SpeedIntegrationDynamics` (GP velocity changes, speed
  integration), :class:`SwingUpCost`;
* objective: :class:`MCPilcoLoss` (particle rollout, ``loss_cost``);
* loop: :func:`optimize_policy` (Adam + monitoring rule) and :func:`run_mcpilco` (trials,
  checkpoints, PNG and Rerun outputs), with :data:`DEMO_CONFIG`, :data:`SMALL_CONFIG` and
  :data:`BENCH_CONFIG`.
"""

from mcpilco.agents.mc_pilco.cost import SwingUpCost
from mcpilco.agents.mc_pilco.dynamics import (
    GPDynamicsModel,
    SpeedIntegrationDynamics,
    cartpole_gp_inputs,
    make_kernel_factory,
    speed_integration,
    transitions_to_dataset,
)
from mcpilco.agents.mc_pilco.loop import (
    BENCH_CONFIG,
    DEFAULT_ENV_ID,
    DEMO_CONFIG,
    PRESETS,
    SMALL_CONFIG,
    MCPilcoConfig,
    RunSummary,
    default_explore_hold,
    make_env,
    registered_ids,
    run_episode,
    run_mcpilco,
)
from mcpilco.agents.mc_pilco.loss import MCPilcoLoss, ParticleRollout
from mcpilco.agents.mc_pilco.optimize import (
    CostMonitor,
    OptimizationResult,
    PolicyOptConfig,
    optimize_policy,
)
from mcpilco.agents.mc_pilco.policy import (
    PolicyPopulation,
    SquashedRBFPolicy,
    cartpole_policy_features,
    make_policy_module,
)

__all__ = [
    "BENCH_CONFIG",
    "DEFAULT_ENV_ID",
    "DEMO_CONFIG",
    "PRESETS",
    "SMALL_CONFIG",
    "default_explore_hold",
    "CostMonitor",
    "GPDynamicsModel",
    "MCPilcoConfig",
    "MCPilcoLoss",
    "OptimizationResult",
    "ParticleRollout",
    "PolicyOptConfig",
    "PolicyPopulation",
    "RunSummary",
    "SpeedIntegrationDynamics",
    "SquashedRBFPolicy",
    "SwingUpCost",
    "cartpole_gp_inputs",
    "cartpole_policy_features",
    "make_env",
    "make_kernel_factory",
    "make_policy_module",
    "optimize_policy",
    "registered_ids",
    "run_episode",
    "run_mcpilco",
    "speed_integration",
    "transitions_to_dataset",
]
