"""Baselines against MC-PILCO on the same envs, trials, seeds and success definition.

* :mod:`.pilco`: PILCO (moment matching) from TorchRL's own parts (``GPWorldModel``,
  ``RBFController``, ``ExponentialQuadraticCost``) in MC-PILCO's outer loop;
* :mod:`.sb3`: SAC, TD3 and PPO from stable-baselines3 with rl-baselines3-zoo
  hyper-parameters, evaluated every ``K`` env steps on 10 episodes (success rate vs
  seconds of experience), checkpointed and resumable;
* :mod:`.common`: task envs, the learning-curve JSON format, policy evaluation;
* :mod:`.compare`: one method on one seed as a learning curve, the curves aggregated over
  seeds, ``T90`` and the data-efficiency ratios to MC-PILCO (the library of
  ``mcpilco-compare``, whose benchmark face is :mod:`mcpilco.experiments.mcpilco.compare`).

Heavy libraries (torchrl, botorch, stable-baselines3) are imported by the sub-modules only.
"""

from mcpilco.agents.baselines.common import (
    CURVE_FORMAT,
    check_task_env,
    env_has_task,
    evaluate_success,
    load_curves,
    make_curve,
    save_curve,
    task_env_ids,
    trial_records_to_points,
)

__all__ = [
    "CURVE_FORMAT",
    "check_task_env",
    "env_has_task",
    "evaluate_success",
    "load_curves",
    "make_curve",
    "save_curve",
    "task_env_ids",
    "trial_records_to_points",
]
