"""MC-PILCO trained through TorchRL's objects (thesis Algorithm 1), in the layout of TorchRL's
``sota-implementations``: this script and ``config.yaml`` beside it.

The parts are the package's (task, policy, GP dynamics, cost, policy optimisation, config),
seen as TorchRL objects:

* env: ``GymEnv`` (``DMControlEnv`` for ``dm_control/<domain>-<task>-v0``) whose transforms
  write the task's state under ``"state"``
  (:func:`mcpilco.agents.mc_pilco.torchrl_parts.make_torchrl_env`);
* policy: the squashed RBF policy as a ``TensorDictModule`` (``"state"`` -> ``"action"``);
* collector: TorchRL's ``Collector``, one batch per trial of the task's ``trial_steps``
  steps (reset at each trial and whenever the env ends an episode); its
  ``init_random_frames`` make trial 0 the random exploration (i.i.d. uniform actions);
* data ``D``: a ``ReplayBuffer`` holding every transition collected;
* world model: the GP dynamics fitted on ``D`` as a ``TensorDictModule``
  (:class:`~mcpilco.agents.mc_pilco.torchrl_parts.ParticleWorldModel`);
* objective: :class:`~mcpilco.agents.mc_pilco.loss.MCPilcoLoss` (a TorchRL ``LossModule``;
  its keys set with ``set_keys`` to the env's), minimised by
  :func:`~mcpilco.agents.mc_pilco.optimize.optimize_policy`.

Run::

    python examples/torchrl/mc_pilco.py                       # config.yaml's env
    python examples/torchrl/mc_pilco.py --set env_id=dm_control/pendulum-swingup-v0 \\
        --set config.num_trials=8
    python examples/torchrl/mc_pilco.py --config my.yaml      # same layout as config.yaml

The script decides compiling: ``config.compile_rollout: true`` builds the fast rollout of
the loss (:func:`~mcpilco.agents.mc_pilco.fast.use_fast_rollout`) after each GP fit,
checked against the eager rollout. Everything runs on the CPU. Each trial prints one line;
:func:`train` returns the trials' records.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict.nn import TensorDictModule
from torchrl.data import LazyTensorStorage, ReplayBuffer

from mcpilco.agents.mc_pilco import (
    MCPilcoLoss,
    PolicyPopulation,
    StateLayout,
    load_config,
    optimize_policy,
    parse_set,
    use_fast_rollout,
)
from mcpilco.agents.mc_pilco.loss import TerminationSet
from mcpilco.agents.mc_pilco.optimize import choose_policy
from mcpilco.agents.mc_pilco.policy import data_init
from mcpilco.agents.mc_pilco.torchrl_parts import STATE_KEY, ParticleWorldModel, make_torchrl_env
from mcpilco.agents.mc_pilco.trainer import (
    dynamics_model,
    initial_std,
    optimised_cost,
    policy_candidates,
)
from mcpilco.envs.yaml_files import read_yaml

try:  # TorchRL >= 0.11 names its single-process collector Collector
    from torchrl.collectors import Collector
except ImportError:  # pragma: no cover - older TorchRL
    from torchrl.collectors import SyncDataCollector as Collector

CONFIG = Path(__file__).with_name("config.yaml")  # the example's config file


def read_config(path: str | Path = CONFIG, overrides: list[str] | None = None) -> dict[str, Any]:
    """The example's config: the YAML file at ``path``, then ``overrides`` (``key=value``,
    dotted keys for nested ones, as ``mcpilco-train --set``)."""
    cfg = read_yaml(path, "example config")
    if not isinstance(cfg, dict) or "env_id" not in cfg:
        raise ValueError(f"{path}: expected a mapping with env_id and config")
    return merge(cfg, parse_set(overrides))


def merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``over``'s values, nested mappings merged key by key."""
    out = dict(base)
    for k, v in over.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def first_episode(batch) -> Any:
    """The rows of a trial's batch up to the end of its first episode."""
    done = batch["next", "done"].reshape(-1).nonzero()
    return batch if len(done) == 0 else batch[: int(done[0]) + 1]


def train(cfg: dict[str, Any], log=print) -> list[dict[str, Any]]:
    """MC-PILCO on ``cfg["env_id"]`` with the package's config for it merged with
    ``cfg["config"]``; returns one record per trial (``cost``: the task's cost of the
    trial's first episode; ``success``: the task's test on it; ``final_state``: its last
    state; ``env_return``: the env's summed reward over the trial; ``experience_s``: the
    seconds of interaction so far)."""
    config = load_config(cfg["env_id"], overrides=cfg.get("config") or {})
    task = config.task_spec()
    if config.torch_threads is not None:
        torch.set_num_threads(int(config.torch_threads))
    torch.manual_seed(config.seed)
    layout = StateLayout.from_task(task)
    steps = task.steps_per_trial

    # the package's parts: policy candidates, GP dynamics model, cost
    candidates = policy_candidates(config, task, layout)
    policy, population = candidates[0], PolicyPopulation(candidates)
    model = dynamics_model(config, task)
    cost = optimised_cost(config, task)
    init_std = initial_std(config, task, layout)

    # TorchRL's objects: env, actor, collector, replay buffer, loss
    env = make_torchrl_env(task, config.seed, config.env_kwargs)
    actor = TensorDictModule(policy, in_keys=[STATE_KEY], out_keys=["action"])
    collector = Collector(
        env,
        actor,
        frames_per_batch=steps,
        total_frames=steps * (config.num_trials + 1),
        init_random_frames=steps,  # trial 0: random exploration
        reset_at_each_iter=True,
    )
    data = ReplayBuffer(storage=LazyTensorStorage(steps * (config.num_trials + 1)))

    def make_loss(world: ParticleWorldModel) -> MCPilcoLoss:
        """The objective over the world model, its keys set to the env's."""
        loss = MCPilcoLoss(
            TensorDictModule(population, in_keys=[STATE_KEY], out_keys=["action"]),
            world,
            cost,
            horizon=task.horizon,
            num_particles=config.num_particles,
            init_mean=task.init_mean,
            init_std=init_std,
            obs_noise_std=config.sim_obs_noise_std,
            termination=TerminationSet.from_task(task),
        )
        loss.set_keys(observation=STATE_KEY, next_observation=("next", STATE_KEY))
        return loss

    records: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    try:
        for k, batch in enumerate(collector):
            data.extend(batch.reshape(-1))
            ep = first_episode(batch)
            states = task.state_from_obs(ep["next", "observation"].numpy())
            rec = {
                "trial": k,
                "kind": "exploration" if k == 0 else "policy",
                "cost": float(np.sum(task.cost(states))),
                "success": bool(task.is_success(states, {}, len(states))),
                "final_state": states[-1].tolist(),
                "env_return": float(batch["next", "reward"].sum()),
                "experience_s": len(data) * task.dt,
                "wall_s": time.perf_counter() - t0,
            }
            records.append(rec)
            if log is not None:
                log(
                    f"trial {k} ({rec['kind']}, {rec['experience_s']:.1f} s of experience): "
                    f"cost {rec['cost']:.2f}, success {rec['success']}, "
                    f"env return {rec['env_return']:.2f}, time {rec['wall_s']:.1f} s"
                )
            if k == config.num_trials:
                break
            # model learning: the GP dynamics on every transition of D (less those at limits)
            d = data[:]
            s = task.state_from_obs(d["observation"].numpy())
            s1 = task.state_from_obs(d["next", "observation"].numpy())
            a = d["action"].numpy().astype(np.float64)
            if task.limits:
                free = ~task.touches_limit(s, s1)
                s, a, s1 = s[free], a[free], s1[free]
            model.fit(s, a, s1)
            if k == 0 and config.policy_init == "data":  # centres from the explored states
                init = data_init(task.features(s))
                population.use_data_init(init)
                policy.use_data_init(init)
                population.reset_parameters(config.seed)
                population.copy_to(0, policy)
            world = ParticleWorldModel.from_model(
                model,
                getattr(torch, config.rollout_dtype),
                in_keys=(STATE_KEY, "action", "noise"),
                out_keys=(("next", STATE_KEY), ("next", "state_mean")),
            )
            loss = make_loss(world)
            if config.compile_rollout:  # the script's choice; checked against the eager rollout
                fast = use_fast_rollout(loss, config.rollout_backend, dynamic=False)
                if log is not None:
                    log(f"fast rollout: {fast.backend or 'eager'} {fast.error or ''}".rstrip())
            # policy update: minimise J^ over the candidates, apply the best one
            res = optimize_policy(loss, population, config.opt)
            choose_policy(loss, population, policy, res.snapshots)
            policy.eval()
    finally:
        collector.shutdown()
        env.close()
    return records


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default=str(CONFIG), help="the example's YAML config")
    parser.add_argument("--set", action="append", default=[], help="key=value (dotted keys)")
    args = parser.parse_args(argv)
    train(read_config(args.config, args.set))


if __name__ == "__main__":
    main()
