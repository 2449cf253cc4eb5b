"""MC-PILCO: Monte Carlo probabilistic inference for learning control (thesis ch. 5).

TorchRL-style parts (Amadio et al., IEEE T-RO 2022) over any task that declares a
:class:`TaskSpec`:

* task: :class:`TaskSpec` (state layout, angles, speed-integration pairs, action bounds,
  cost, success test; :mod:`mcpilco.envs.tasks.spec`), shipped for the registered envs
  (:mod:`mcpilco.envs.tasks`);
* modules: :class:`SquashedRBFPolicy` (a ``TensorDictModule`` via :func:`make_policy_module`),
  :class:`GPDynamicsModel` / :class:`SpeedIntegrationDynamics` (GP changes, speed
  integration), :class:`SaturatingCost`;
* objective: :class:`MCPilcoLoss` (particle rollout, ``loss_cost``; tensordict keys set by
  ``set_keys``); fast rollouts of it
  (native C++, chained PyTorch, ``torch.compile``) chosen and checked against the eager one
  by :func:`use_fast_rollout`;
* TorchRL parts (:mod:`.torchrl_parts`): the GP world model as a ``TensorDictModule``
  (:class:`ParticleWorldModel`) and a TorchRL env of a task (:func:`make_torchrl_env`),
  used by the example ``examples/torchrl``;
* training: :func:`optimize_policy` (Adam + monitoring rule) and :class:`Trainer` (thesis
  Algorithm 1: trials, checkpoints, PNG and Rerun outputs; :func:`run_mcpilco` runs one),
  configured by :class:`MCPilcoConfig` and per-env YAML files (:func:`load_config`). The
  runtime shared with the baselines (trials, records, checkpoints) is
  :mod:`mcpilco.agents.common`.
"""

from mcpilco.agents.common.records import RunSummary, TrialRecord
from mcpilco.agents.common.trials import DEFAULT_ENV_ID, make_env, registered_ids, run_episode
from mcpilco.agents.mc_pilco.config import MCPilcoConfig, load_config, parse_set
from mcpilco.agents.mc_pilco.cost import SaturatingCost
from mcpilco.agents.mc_pilco.dynamics import (
    GPDynamicsModel,
    SpeedIntegrationDynamics,
    make_kernel_factory,
    speed_integration,
    transitions_to_dataset,
)
from mcpilco.agents.mc_pilco.fast import FastRollout, use_fast_rollout
from mcpilco.agents.mc_pilco.features import StateLayout, gp_inputs
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
    make_policy_module,
)
from mcpilco.agents.mc_pilco.torchrl_parts import ParticleWorldModel, make_torchrl_env
from mcpilco.agents.mc_pilco.trainer import Trainer, run_mcpilco
from mcpilco.envs.tasks.spec import TaskSpec, TaskSpecError

__all__ = [
    "DEFAULT_ENV_ID",
    "CostMonitor",
    "FastRollout",
    "GPDynamicsModel",
    "MCPilcoConfig",
    "MCPilcoLoss",
    "OptimizationResult",
    "ParticleRollout",
    "ParticleWorldModel",
    "PolicyOptConfig",
    "PolicyPopulation",
    "RunSummary",
    "SaturatingCost",
    "SpeedIntegrationDynamics",
    "SquashedRBFPolicy",
    "StateLayout",
    "TaskSpec",
    "TaskSpecError",
    "Trainer",
    "TrialRecord",
    "gp_inputs",
    "load_config",
    "make_env",
    "make_kernel_factory",
    "make_policy_module",
    "make_torchrl_env",
    "optimize_policy",
    "parse_set",
    "registered_ids",
    "run_episode",
    "run_mcpilco",
    "speed_integration",
    "transitions_to_dataset",
    "use_fast_rollout",
]
