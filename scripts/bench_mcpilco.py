"""Benchmark MC-PILCO on the cartpole swing-up (console script ``mcpilco-bench-mcpilco``).

Four parts, each optional:

1. ``runs``: S seeds of the whole loop (exploration + policy trials) per env; per trial
   (3, 6, 9, 12, 15 s of experience) the success rate, mean time upright, mean ``|x|``,
   wall-clock per trial and per optimisation step. Seeds are sweep jobs
   (:mod:`mcpilco.experiments.sweep`) with one torch thread each, in ``--jobs`` local
   processes or on Ray (``--ray [ADDRESS]``); a finished seed is not rerun.
2. ``timing``: seconds per policy optimisation step (forward + backward through the
   ``M x H`` particle rollout + Adam step) at ``M = 400`` particles (``--timing-particles``:
   e.g. ``25 400``, where the few-particle step is the fixed, op-by-op cost of the horizon),
   ``H = 60``, for several GP sizes ``N`` (GP fitted on random-exploration data), 1 torch
   thread and 2 threads. With ``--device cuda`` each step is timed both as one replayed CUDA
   graph (what the optimiser does on a GPU) and launched op by op.
3. ``rmse``: RBF+MPK vs RBF-only (thesis Fig. 5.5): both GPs fitted on the same 3 s of
   random exploration (actions held the preset's ``explore_hold`` steps, ``--explore-hold``);
   a fixed learned swing-up policy (the final policy of a successful run of part 1, or
   ``--rmse-policy``) runs on the env and ``M`` particles are rolled out through each GP;
   reported: the RMSE of theta between particles and the real trajectory per time step
   and averaged over the 60 steps, over ``--rmse-seeds`` exploration seeds.
4. ``rmse_runs``: the same comparison on the data of finished runs (``--rmse-runs``, default
   every run under ``--runs-dir`` whose last trial swung up): both GPs fitted on the run's
   data before its last trial, particles under the last trial's policy from that trial's real
   initial state, against its real trajectory. Grouped by the kernel each run learned with
   and its env.

Writes ``results/mcpilco_cartpole.json`` (merged with an existing file, one section per
env), ``results/mcpilco_cartpole.md`` and ``results/mcpilco_cartpole.png``. ``--pool`` merges
sections of the same config run on other seeds (e.g. 12 seeds, then 8 more with
``--first-seed 12 --label bench5``) into one section over all of them.

Usage::

    mcpilco-bench-mcpilco --seeds 20 --jobs 2                  # all parts, default env
    mcpilco-bench-mcpilco --parts runs --seeds 5 --preset small
    mcpilco-bench-mcpilco --parts runs --env mcpilco/DMCCartpoleSwingUp-v0 --seeds 5
    mcpilco-bench-mcpilco --parts timing rmse
    mcpilco-bench-mcpilco --pool bench bench5                  # one section, seeds of both
    mcpilco-bench-mcpilco --parts timing --device cuda --timing-particles 400 4000
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.agents.common.cli import console_main
from mcpilco.agents.mc_pilco import DEFAULT_ENV_ID, MCPilcoConfig, TaskSpec, load_config
from mcpilco.agents.mc_pilco.dynamics import KERNEL_CHOICES
from mcpilco.agents.mc_pilco.loop import ROLLOUT_DTYPES
from mcpilco.experiments.sweep import (
    Job,
    SweepError,
    SweepReport,
    SweepRunner,
    add_sweep_arguments,
    runner_from_args,
)

PARTS = ("runs", "timing", "rmse", "rmse_runs")


# ------------------------------------------------------------------------------- runs
def _fmt(v: float | None) -> str:
    """A table cell: ``v`` to 2 decimals, ``-`` where the section did not record it."""
    return "-" if v is None else f"{v:.2f}"


def section_key(env_id: str, label: str = "") -> str:
    """Key of a ``--label``-ed section under ``runs`` in ``mcpilco_cartpole.json``."""
    return env_id + (f" ({label})" if label else "")


def run_seed(config: dict[str, Any], out: str) -> dict[str, Any]:
    """One seed's run (``config``: an :class:`MCPilcoConfig` dict) in ``out``; a finished or
    killed run found there is resumed, so that seeds can be added to a section later
    (``--first-seed 0 --seeds 12`` after 6 seeds reruns only seeds 6..11). ``seconds`` is the
    sum of the trials' ``wall_s`` (GP fit, policy optimisation, episode), the same whether the
    trials ran now or in an earlier call. A sweep job of :func:`bench_runs`."""
    from mcpilco.agents.mc_pilco import run_mcpilco
    from mcpilco.models.device import retain_host_memory

    retain_host_memory()
    cfg = MCPilcoConfig.from_dict(config)
    summary = run_mcpilco(
        cfg,
        out,
        resume=(Path(out) / "checkpoint.pt").is_file(),
        overwrite=not (Path(out) / "checkpoint.pt").is_file(),  # the seed's own folder
        progress=False,
        log=None,
        write_rrd=False,
    )
    seconds = float(sum(r["wall_s"] for r in summary.records))
    return {"seed": cfg.seed, "records": summary.records, "seconds": seconds}


def aggregate_runs(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per trial index: success rate, mean time in the goal region, timings over seeds."""
    rows = []
    n_trials = min(len(r["records"]) for r in runs)
    for k in range(n_trials):
        recs = [r["records"][k] for r in runs]
        row = {
            "trial": k,
            "experience_s": recs[0]["experience_s"],
            "kind": recs[0]["kind"],
            "seeds": len(recs),
            "success_rate": float(np.mean([r["success"] for r in recs])),
            "time_in_goal_s": float(np.mean([r["time_in_goal"] for r in recs])),
            "cost": float(np.mean([r["cost"] for r in recs])),
            "wall_s_per_trial": float(np.mean([r["wall_s"] for r in recs])),
        }
        if recs[0]["kind"] == "policy":
            row["opt_steps"] = float(np.mean([r["opt_steps"] for r in recs]))
            row["s_per_opt_step"] = float(np.mean([r["s_per_opt_step"] for r in recs]))
            row["cpu_s_per_opt_step"] = float(
                np.mean([r.get("cpu_s_per_opt_step", np.nan) for r in recs])
            )
            row["gp_fit_s"] = float(np.mean([r["gp_fit_s"] for r in recs]))
        rows.append(row)
    return rows


def bench_runs(
    cfg: MCPilcoConfig, seeds: list[int], runner: SweepRunner, runs_dir: Path
) -> tuple[dict[str, Any] | None, SweepReport]:
    """The seeds' runs (:func:`run_seed`, one torch thread each) as sweep jobs: run ``seed<s>``
    in ``runs_dir/seed<s>``, its result in ``runs_dir/seed<s>.json``. Returns the section of
    the seeds that finished (None when none did) and the sweep's report."""
    jobs = [
        Job(
            f"seed{s}",
            run_seed,
            {
                "config": dataclasses.replace(cfg, seed=s, torch_threads=1).to_dict(),
                "out": str(runs_dir / f"seed{s}"),
            },
        )
        for s in seeds
    ]
    t0 = time.perf_counter()
    sweep = runner.run(jobs, runs_dir, desc=f"seeds {cfg.env_id}")
    runs = list(sweep.results.values())
    if not runs:
        return None, sweep
    return make_section(cfg.to_dict(), runs, runner.slots(), time.perf_counter() - t0), sweep


def make_section(
    config: dict[str, Any], runs: list[dict[str, Any]], jobs: int, wall_s_total: float
) -> dict[str, Any]:
    """The results section of ``runs`` (the dicts of :func:`run_seed`, one per seed)."""
    return {
        "config": config,
        "seeds": [r["seed"] for r in runs],
        "jobs": jobs,
        "wall_s_total": wall_s_total,
        "wall_s_per_run": float(np.mean([r["seconds"] for r in runs])),
        "per_trial": aggregate_runs(runs),
        "per_seed": [
            {
                "seed": r["seed"],
                "success": [bool(x["success"]) for x in r["records"]],
                "seconds": r["seconds"],
            }
            for r in runs
        ],
    }


POOLED_MEANS = (
    "success_rate",
    "time_in_goal_s",
    "cost",
    "wall_s_per_trial",
    "opt_steps",
    "s_per_opt_step",
    "cpu_s_per_opt_step",
    "gp_fit_s",
)
"""Per-trial fields of a section that are means over seeds (pooled weighted by seed count)."""

_RUN_ONLY_FIELDS = ("num_trials", "seed", "torch_threads")
"""Config fields that may differ between sections that are pooled."""


def pool_sections(sections: list[dict[str, Any]]) -> dict[str, Any]:
    """One section over the union of the seeds of ``sections`` (same experiment, other seeds).

    Each per-trial field in :data:`POOLED_MEANS` is a mean over seeds, so the pooled value
    is exact: :math:`\\bar v = \\sum_j S_j \\bar v_j / \\sum_j S_j` over the sections ``j``
    that ran trial ``k`` (``S_j`` seeds each). Trials that only some sections ran are pooled
    over those (their ``seeds`` count says how many).

    Raises:
        ValueError: if the configs differ in anything but the number of trials (and the
            seed), or if a seed appears in two sections.
    """
    if len(sections) < 2:
        raise ValueError(f"pooling needs at least 2 sections, got {len(sections)}")

    def experiment(cfg: dict[str, Any]) -> dict[str, Any]:
        # fields a section written by an older version lacks take their default
        full = MCPilcoConfig.from_dict(cfg).to_dict()
        return {k: v for k, v in full.items() if k not in _RUN_ONLY_FIELDS}

    ref = experiment(sections[0]["config"])
    for sec in sections[1:]:
        other = experiment(sec["config"])
        if other != ref:
            diff = sorted(k for k in set(ref) | set(other) if ref.get(k) != other.get(k))
            raise ValueError(f"sections differ in config fields {diff}; only seeds may differ")
    seeds = [s for sec in sections for s in sec["seeds"]]
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"a seed appears in two sections: {sorted(seeds)}")
    n_trials = max(len(sec["per_trial"]) for sec in sections)
    rows = []
    for k in range(n_trials):
        have = [sec["per_trial"][k] for sec in sections if len(sec["per_trial"]) > k]
        total = sum(r["seeds"] for r in have)
        row = {key: have[0][key] for key in ("trial", "experience_s", "kind")}
        row["seeds"] = total
        for key in POOLED_MEANS:
            if all(key in r for r in have):
                row[key] = float(sum(r["seeds"] * r[key] for r in have) / total)
        rows.append(row)
    config = dict(sections[0]["config"])
    config["num_trials"] = max(sec["config"]["num_trials"] for sec in sections)
    n_seeds = [len(sec["seeds"]) for sec in sections]
    return {
        "config": config,
        "seeds": seeds,
        "jobs": sections[0]["jobs"],
        "wall_s_total": float(sum(sec["wall_s_total"] for sec in sections)),
        "wall_s_per_run": float(
            sum(n * sec["wall_s_per_run"] for n, sec in zip(n_seeds, sections, strict=True))
            / sum(n_seeds)
        ),
        "per_trial": rows,
        "per_seed": [p for sec in sections for p in sec["per_seed"]],
        "pooled_from": [len(sec["seeds"]) for sec in sections],
        "pooled_num_trials": [int(sec["config"]["num_trials"]) for sec in sections],
    }


# ----------------------------------------------------------------------------- timing
def _exploration_data(env_id: str, n_points: int, seed: int, hold: int = 1):
    """``n_points`` transitions of random-exploration episodes (actions held ``hold`` steps,
    :func:`~mcpilco.agents.mc_pilco.loop.exploration_actions`)."""
    from mcpilco.agents.mc_pilco.loop import exploration_actions, make_env, run_episode, transitions

    task = TaskSpec.for_env(env_id)
    H = task.horizon
    env = make_env(env_id, H, task)
    rng = np.random.default_rng(seed)
    eps = []
    while sum(len(e["actions"]) for e in eps) < n_points:
        it = iter(exploration_actions(rng, H, hold, task.action_low, task.action_high))
        eps.append(run_episode(env, lambda _o, it=it: next(it), seed * 1000 + len(eps), H, task))
    env.close()
    s, a, s1 = transitions(eps)
    return s[:n_points], a[:n_points], s1[:n_points], eps


def time_opt_step(
    n_points: int,
    num_particles: int = 400,
    horizon: int = 60,
    kernel: str = "rbf+mpk",
    threads: int = 1,
    repeats: int = 5,
    env_id: str = DEFAULT_ENV_ID,
    device: str = "cpu",
    cuda_graph: bool = True,
    compile_rollout: bool = False,
    heap_contrast: bool = False,
) -> dict[str, float]:
    """Median wall and CPU seconds of one optimisation step (rollout, backward, Adam).

    ``compile_rollout``: also time the same step compiled (:meth:`MCPilcoLoss.compile_step`)
    by its default backend (``compiled_*``: ``native`` where it applies, else ``direct``), by
    the ``direct`` backend (``direct_*``, when the default is ``native``) and by
    ``torch.compile`` of the time step (``dynamo_*``, when the default is not already that),
    each on its own loss module sharing the policy and the GP posterior; the eager and the
    compiled steps
    alternate within each round, so their ratios hold on a busy machine. ``compile_s``: the
    time of ``compile_step`` (the compilation and its check against the eager step, one step
    of each); ``compile_check`` its figures. A compiled step that fails the check is not
    timed (``compiled_rejected``).

    The process keeps its freed memory (:func:`~mcpilco.models.device.retain_host_memory`,
    as the scripts do); ``page_faults_per_step`` counts the minor page faults of each timed
    step. ``heap_contrast``: also time the eager step with glibc's initial heap thresholds
    (128 KiB, where its adaptive rule can stay), in the same rounds (``heap128k_*``); each
    timed step then follows an untimed one in the same setting.

    On a CUDA ``device`` the GP is fitted on the CPU and its posterior, the policy and the
    particles move to the device; each timed step ends with a synchronisation, and with
    ``cuda_graph`` the forward and backward pass is one replayed CUDA graph, as in
    :func:`~mcpilco.agents.mc_pilco.optimize_policy`.
    """
    import torch

    from mcpilco.agents.mc_pilco import (
        GPDynamicsModel,
        MCPilcoLoss,
        SaturatingCost,
        SquashedRBFPolicy,
        StateLayout,
        make_policy_module,
    )
    from mcpilco.agents.mc_pilco.optimize import loss_and_grad_fn
    from mcpilco.models.device import (
        GLIBC_INITIAL_THRESHOLD,
        resolve_device,
        retain_host_memory,
    )

    dev = resolve_device(device)
    sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
    torch.set_num_threads(threads)
    retain_host_memory()
    s, a, s1, _ = _exploration_data(env_id, n_points, 0)
    task = TaskSpec.for_env(env_id)
    model = GPDynamicsModel(task, kernel=kernel, adam_iters=30, lbfgs_iters=5, max_points=None)
    model.fit(s, a, s1)
    policy = SquashedRBFPolicy(
        StateLayout.from_task(task), task.action_low, task.action_high, seed=0
    )
    module, dynamics = make_policy_module(policy), model.particle_dynamics()
    cost = SaturatingCost.from_task(task)

    def make_loss() -> MCPilcoLoss:  # moves the policy and the GP posterior with it
        args = (module, dynamics, cost, horizon, num_particles, task.init_mean)
        return MCPilcoLoss(*args, obs_noise_std=0.01).to(dev)

    opt = torch.optim.Adam(policy.parameters(), lr=0.01)
    policy.train()
    # the optimiser's own step: eager on the CPU, one CUDA graph on a GPU (captured here)
    params = list(policy.parameters())
    step_fns = {"eager": loss_and_grad_fn(make_loss(), params, cuda_graph=cuda_graph)}
    compile_info: dict[str, object] = {}
    compiled_losses = []
    if compile_rollout:
        # "compiled": the default backend (native, else direct, where they apply);
        # "direct": inductor-compiled time steps; "dynamo": torch.compile of the time step
        for name, backend in (("compiled", "auto"), ("direct", "direct"), ("dynamo", "dynamo")):
            if name == "direct" and compile_info.get("compile_backend") != "native":
                continue  # the default already is direct (or direct does not apply)
            compiled = make_loss()
            t_compile = time.perf_counter()
            accepted = compiled.compile_step(backend=backend, dynamic=False)
            prefix = "" if name == "compiled" else f"{name}_"
            compile_info.update(
                {
                    f"{prefix}compile_backend": compiled.compile_backend,
                    f"{prefix}rollout_shards": compiled.rollout_shards,
                    f"{prefix}compile_s": time.perf_counter() - t_compile,
                    f"{prefix}compile_check": compiled.compile_check,
                    f"{prefix}compile_error": compiled.compile_error,
                    f"{prefix}compiled_rejected": not accepted,
                }
            )
            compiled_losses.append(compiled)
            if accepted:
                step_fns[name] = loss_and_grad_fn(compiled, params, cuda_graph=cuda_graph)
            if compiled.compile_backend == "dynamo" and name == "compiled":
                break  # the default already is dynamo here
    if heap_contrast:
        step_fns["heap128k"] = step_fns["eager"]
    walls: dict[str, list[float]] = {k: [] for k in step_fns}
    cpus: dict[str, list[float]] = {k: [] for k in step_fns}
    faults: dict[str, list[int]] = {k: [] for k in step_fns}
    for i in range(repeats + 1):
        for name, step_fn in step_fns.items():
            if name == "heap128k":
                retain_host_memory(GLIBC_INITIAL_THRESHOLD, GLIBC_INITIAL_THRESHOLD)
            if heap_contrast:  # one untimed step after each switch: the heap settles first
                step_fn()
                opt.step()
            sync()
            t, c = time.perf_counter(), time.process_time()
            f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            step_fn()
            opt.step()
            sync()
            if i:  # the first round is a warm-up
                walls[name].append(time.perf_counter() - t)
                cpus[name].append(time.process_time() - c)
                faults[name].append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
            if name == "heap128k":
                retain_host_memory()
    out = {
        "n_points": n_points,
        "num_particles": num_particles,
        "threads": threads,
        "device": str(dev),
        "cuda_graph": bool(cuda_graph and dev.type == "cuda"),
        "s_per_step_wall": statistics.median(walls["eager"]),
        "s_per_step_cpu": statistics.median(cpus["eager"]),
        "page_faults_per_step": statistics.median(faults["eager"]),
    }
    out.update(compile_info)
    for name in ("compiled", "direct", "dynamo", "heap128k"):
        if name in step_fns:
            out.update(
                {
                    f"{name}_s_per_step_wall": statistics.median(walls[name]),
                    f"{name}_s_per_step_cpu": statistics.median(cpus[name]),
                    f"{name}_page_faults_per_step": statistics.median(faults[name]),
                }
            )
    for compiled in compiled_losses:
        compiled.compile_step(False)
    return out


# ------------------------------------------------------------------------------- rmse
def find_swingup_policy(runs_dir: Path) -> Path:
    """The checkpoint of the first run under ``runs_dir`` (sorted) whose last trial swung the
    pole up; its policy is the fixed "learned policy that correctly executes the swing-up" of
    thesis Fig. 5.5."""
    found = swingup_runs(runs_dir)
    if found:
        return found[0]
    raise FileNotFoundError(
        f"no run under {runs_dir} ends with a successful swing-up; run the 'runs' part first "
        "or pass --rmse-policy CHECKPOINT"
    )


def _theta_rmse_both_kernels(
    data: tuple,
    policy,
    real: np.ndarray,
    num_particles: int,
    seed: int,
    keep_particles: bool = False,
    **fit_kwargs: Any,
) -> dict[str, Any]:
    """Fit an RBF+MPK and an RBF-only GP on ``data = (s, a, s')``, roll ``M`` particles out
    through each under ``policy`` from ``real[0]``; per kernel the RMSE of theta against
    ``real[1:, 2]`` over particles and steps (``kernel``), per step (``kernel_per_step``)
    and, with ``keep_particles``, the first 100 particles' theta (``kernel_particles``)."""
    import torch

    from mcpilco.agents.mc_pilco import (
        GPDynamicsModel,
        MCPilcoLoss,
        SaturatingCost,
        make_policy_module,
    )

    out: dict[str, Any] = {}
    horizon = len(real) - 1
    task = TaskSpec.for_env(DEFAULT_ENV_ID)
    for kernel in ("rbf+mpk", "rbf"):
        model = GPDynamicsModel(task, kernel=kernel, **fit_kwargs).fit(*data)
        torch.manual_seed(seed)
        loss = MCPilcoLoss(
            make_policy_module(policy),
            model.particle_dynamics(),
            SaturatingCost.from_task(task),
            horizon,
            num_particles,
            task.init_mean,
        )
        policy.eval()
        with torch.no_grad():
            x0 = torch.as_tensor(real[0], dtype=torch.float32).expand(num_particles, 4)
            parts = loss.rollout(initial_state=x0.clone()).states.numpy()
        err = parts[:, 1:, 2] - real[None, 1:, 2]
        out[kernel] = float(np.sqrt(np.mean(err**2)))
        out[f"{kernel}_per_step"] = np.sqrt(np.mean(err**2, axis=0)).tolist()
        if keep_particles:
            out[f"{kernel}_particles"] = parts[:100, :, 2].tolist()
    return out


def particle_rmse(
    seed: int,
    policy_ckpt: Path,
    num_particles: int = 400,
    env_id: str = DEFAULT_ENV_ID,
    explore_hold: int = 1,
) -> dict:
    """Thesis Fig. 5.5: RBF+MPK and RBF-only GPs fitted on the same 3 s of random exploration
    (seed ``seed``, actions held ``explore_hold`` steps); ``M`` particles rolled out through
    each under a fixed learned swing-up policy, from the real initial state; per time step,
    the RMSE of theta between the particles and the real trajectory of that policy (root mean
    over particles), and its mean over the 60 steps."""
    import torch

    from mcpilco.agents.mc_pilco import SquashedRBFPolicy
    from mcpilco.agents.mc_pilco.checkpoint import load_checkpoint
    from mcpilco.agents.mc_pilco.loop import _policy_act, make_env, run_episode

    torch.set_num_threads(1)
    s, a, s1, _ = _exploration_data(env_id, 60, 100 + seed, explore_hold)  # 3 s
    ckpt = load_checkpoint(policy_ckpt)
    task = TaskSpec.for_env(env_id)
    policy = SquashedRBFPolicy(**ckpt["policy_settings"])
    policy.load_state_dict(ckpt["policy"])
    env = make_env(env_id, task.horizon, task)
    real = run_episode(env, _policy_act(policy), 5000 + seed, task.horizon, task)["states"]
    env.close()
    out: dict[str, Any] = {"seed": seed, "real_success_theta_end": float(real[-1, 2])}
    first = seed == 0  # the plot shows the particles of seed 0
    out.update(_theta_rmse_both_kernels((s, a, s1), policy, real, num_particles, seed, first))
    if first:
        out["real_theta"] = real[:, 2].tolist()
    return out


def particle_rmse_on_run(ckpt_path: Path, num_particles: int = 400) -> dict[str, Any]:
    """Thesis Fig. 5.5 on a finished run's own data: RBF+MPK and RBF-only GPs fitted (with
    the run's GP settings) on every transition before its last trial; ``M`` particles under
    the policy of that trial from its real initial state, against its real trajectory (the
    noise-free states the env recorded). The run's last trial must have swung up."""
    import torch

    from mcpilco.agents.mc_pilco import SquashedRBFPolicy
    from mcpilco.agents.mc_pilco.checkpoint import load_checkpoint
    from mcpilco.agents.mc_pilco.loop import transitions

    torch.set_num_threads(1)
    ckpt = load_checkpoint(ckpt_path)
    cfg = MCPilcoConfig.from_dict(ckpt["config"])
    episodes, arrays = ckpt["episodes"], ckpt["arrays"]
    if len(episodes) < 2 or not ckpt["records"][-1]["success"]:
        raise ValueError(f"{ckpt_path}: needs a run whose last policy trial swung up")
    policy = SquashedRBFPolicy(**ckpt["policy_settings"])
    policy.load_state_dict(ckpt["policy"])
    real = np.asarray(arrays[-1]["real"])
    out: dict[str, Any] = {
        "run": str(ckpt_path),
        "env_id": cfg.env_id,
        "run_kernel": cfg.kernel,
        "n_data": int(sum(len(e["actions"]) for e in episodes[:-1])),
    }
    out.update(
        _theta_rmse_both_kernels(
            transitions(episodes[:-1]),
            policy,
            real,
            num_particles,
            cfg.seed,
            max_points=cfg.max_points,
            adam_iters=cfg.gp_adam_iters,
            lbfgs_iters=cfg.gp_lbfgs_iters,
        )
    )
    return out


def swingup_runs(runs_dir: Path) -> list[Path]:
    """Checkpoints under ``runs_dir`` (sorted) whose last trial swung the pole up."""
    from mcpilco.agents.mc_pilco.checkpoint import load_checkpoint

    found = []
    for ckpt_path in sorted(Path(runs_dir).glob("**/checkpoint.pt")):
        ckpt = load_checkpoint(ckpt_path)
        if len(ckpt["records"]) > 1 and ckpt["records"][-1]["success"]:
            found.append(ckpt_path)
    return found


def group_rmse_runs(per_run: list[dict]) -> dict[str, list[dict]]:
    """``particle_rmse_on_run`` results by the kernel the run learned with and its env (runs
    on different envs are never pooled), keys sorted."""
    groups: dict[str, list[dict]] = {}
    for r in per_run:
        groups.setdefault(f"{r['run_kernel']} on {r['env_id']}", []).append(r)
    return dict(sorted(groups.items()))


def summarise_rmse_runs(per_run: list[dict]) -> dict[str, dict]:
    """Per group (:func:`group_rmse_runs`): runs, mean / median RMSE of both GPs, and the
    number of runs where the RBF+MPK particles are closer (lower RMSE)."""
    groups: dict[str, dict] = {}
    for kern, rows in group_rmse_runs(per_run).items():
        g: dict[str, Any] = {"runs": len(rows)}
        for k in ("rbf+mpk", "rbf"):
            vals = [r[k] for r in rows]
            g[k] = {"mean": float(np.mean(vals)), "median": float(np.median(vals))}
        g["mpk_better"] = int(sum(r["rbf+mpk"] < r["rbf"] for r in rows))
        groups[kern] = g
    return groups


def plot_rmse(rm: dict, path: Path) -> None:
    """Thesis Fig. 5.5: theta particles of both models against the real trajectory (seed 0),
    and the per-step RMSE (median over seeds) of both."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    first = rm["per_seed"][0]
    t = np.arange(len(first["real_theta"])) * 0.05
    fig, axes = plt.subplots(3, 1, figsize=(7, 8), sharex=True)
    for ax, k in zip(axes[:2], ("rbf+mpk", "rbf"), strict=True):
        ax.plot(t, np.asarray(first[f"{k}_particles"]).T, color="tab:blue", alpha=0.12, lw=0.7)
        ax.plot(t, first["real_theta"], "o", color="black", ms=2.5, label="real")
        ax.set_ylabel("theta [rad]")
        ax.set_title(f"GP kernel {k}: particles vs real (exploration seed 0)")
        ax.set_ylim(-2 * np.pi, 2 * np.pi)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper left", fontsize=8)
    for k, col in (("rbf+mpk", "tab:blue"), ("rbf", "tab:red")):
        per = np.median([p[f"{k}_per_step"] for p in rm["per_seed"]], axis=0)
        axes[2].semilogy(t[1:], per, color=col, label=k)
    axes[2].set_ylabel("RMSE theta [rad]")
    axes[2].set_xlabel("time [s]")
    axes[2].set_title(f"median over {rm['seeds']} exploration seeds")
    axes[2].legend(fontsize=8)
    axes[2].grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_rmse_runs(per_run: list[dict], path: Path) -> None:
    """Part ``rmse_runs``: per time step, the median over runs of the theta RMSE of both GPs,
    one panel per kernel the runs learned with."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = group_rmse_runs(per_run)
    fig, axes = plt.subplots(1, len(groups), figsize=(6 * len(groups), 3.6), squeeze=False)
    for ax, (g, rows) in zip(axes[0], groups.items(), strict=True):
        for k, col in (("rbf+mpk", "tab:blue"), ("rbf", "tab:red")):
            per = np.median([r[f"{k}_per_step"] for r in rows], axis=0)
            ax.plot(np.arange(1, len(per) + 1) * 0.05, per, color=col, label=f"GP {k}")
        ax.set_title(f"{len(rows)} runs learned with {g}\n(GPs fitted on their data)", fontsize=10)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("median RMSE theta [rad]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ------------------------------------------------------------------------------ report
def _md_table(env_id: str, section: dict) -> str:
    lines = [f"### {env_id}", ""]
    cfg = section["config"]
    seeds = section["seeds"]
    pooled = ""
    if section.get("pooled_from"):
        pooled = (
            f"Pooled from {len(section['pooled_from'])} runs of the same config "
            f"({' + '.join(str(n) for n in section['pooled_from'])} seeds; a trial that "
            "only some ran is over those seeds, as its row says"
        )
        trials = sorted(set(section.get("pooled_num_trials", [])))
        if len(trials) > 1:
            pooled += f"; the wall-clock per run averages runs of {trials} policy trials"
        pooled += "). "
    lines.append(
        pooled + f"{len(seeds)} seeds ({_seed_ranges(seeds)}); M={cfg['num_particles']} particles, "
        f"max {cfg['opt']['max_steps']} opt steps per trial (first: {cfg['opt_steps_first']}), "
        f"GP subset N<={cfg['max_points']}, kernel {cfg['kernel']}, "
        f"K={cfg.get('num_candidates', 1)} candidate policies, "
        f"rollout GP {cfg.get('rollout_dtype', 'float32')}"
        f"{', time step compiled (--compile-rollout)' if cfg.get('compile_rollout') else ''}, "
        "exploration actions held "
        f"{cfg.get('explore_hold', 1)} step(s); "
        f"{section['jobs']} parallel "
        f"jobs x 1 thread; mean wall-clock per run {section['wall_s_per_run']:.0f} s."
    )
    lines += [
        "",
        "| experience | policy trained on | success rate | time in goal [s] "
        "| wall per trial [s] | opt steps | s / opt step (wall) | s / opt step (CPU) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    prev = None
    for r in section["per_trial"]:
        trained = f"{prev:.0f} s" if prev is not None and r["kind"] == "policy" else "-"
        prev = r["experience_s"]
        kind = (
            r["kind"]
            if r.get("seeds", len(seeds)) == len(seeds)
            else f"{r['kind']}, {r['seeds']} seeds"
        )
        lines.append(
            f"| {r['experience_s']:.0f} s ({kind}) | {trained} "
            f"| {100 * r['success_rate']:.0f}% "
            f"| {_fmt(r.get('time_in_goal_s'))} | {r['wall_s_per_trial']:.1f} "
            f"| {r.get('opt_steps', 0):.0f} | {r.get('s_per_opt_step', float('nan')):.3f} "
            f"| {r.get('cpu_s_per_opt_step', float('nan')):.3f} |"
        )
    return "\n".join(lines) + "\n"


def _seed_ranges(seeds: list[int]) -> str:
    """``[0, 1, 2, 5, 6]`` -> ``"0-2, 5-6"``."""
    runs: list[list[int]] = []  # [first, last] of each run of consecutive seeds
    for s in sorted(seeds):
        if runs and runs[-1][1] == s - 1:
            runs[-1][1] = s
        else:
            runs.append([s, s])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


CONVENTION_NOTE = (
    "Rows: `experience` counts the seconds of interaction up to the end of that trial (the "
    "trial included); `policy trained on` is the data the trial's policy was optimised on. "
    "Thesis Table 5.1 indexes its columns by the latter (its 3.8 % at 3 s is a policy trial, "
    "not the random exploration)."
)


def write_report(results: dict, out_dir: Path) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    md = ["# MC-PILCO on the cartpole swing-up", "", CONVENTION_NOTE, ""]
    if results.get("machine"):
        md += [f"Machine: {results['machine']}.", ""]
    for env_id, section in results.get("runs", {}).items():
        md.append(_md_table(env_id, section))
    if results.get("timing"):
        md += [
            "### Seconds per optimisation step (H = 60)",
            "",
            "A step at a few particles is the fixed cost of the 60-step rollout (one op after "
            "another, forward and backward); the rest grows with M.",
            "",
            "Compiled: the same step compiled (`--compile-rollout`) by the default backend "
            "(column backend; `native`: the whole rollout, forward and backward, in the "
            "package's C++ loop; `direct`: forward and backward of a time step chained by hand "
            "and compiled by inductor, no dynamo and no autograd per time step), alternating "
            "with the eager step in each round; compile s: the compilation and its check "
            "against the eager step (for `direct`, about 1 s where inductor's on-disk cache "
            "already held graphs of the same size, from any GP); shards: the threads a "
            "compiled rollout is split over, by particles (two threads: 2 at 400 particles, 1 "
            "at 25). Direct: the `direct` backend in the same rounds, where the default is "
            "`native`. Dynamo: the time step `torch.compile`-d instead, in the same rounds.",
            "",
            "Faults: minor page faults per step, with the freed memory kept in the process "
            "(`retain_host_memory`). 128 KiB heap: the eager step with glibc's initial "
            "allocator thresholds instead (`--timing-heap-contrast`), in the same rounds.",
            "",
            "| particles M | GP points N | device | CUDA graph | threads | wall s/step "
            "| CPU s/step | faults | compiled: backend | wall s/step | CPU s/step "
            "| speed-up (CPU) | compile s | shards | direct: wall s/step | CPU s/step "
            "| dynamo: wall s/step | CPU s/step | 128 KiB heap: wall s/step | faults |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for t in results["timing"]:
            graph = "yes" if t.get("cuda_graph") else "no"
            comp = "| - | - | - | - | - | -"
            backend = t.get("compile_backend") or "-"
            if t.get("compile_error"):
                comp = f"| {backend} | compilation failed | - | - | - | -"
            elif t.get("compiled_rejected"):
                comp = f"| {backend} | failed its check against the eager step | - | - | - | -"
            elif "compiled_s_per_step_wall" in t:
                comp = (
                    f"| {backend} | {t['compiled_s_per_step_wall']:.3f} "
                    f"| {t['compiled_s_per_step_cpu']:.3f} "
                    f"| {t['s_per_step_cpu'] / t['compiled_s_per_step_cpu']:.2f}x "
                    f"| {t['compile_s']:.1f} | {t.get('rollout_shards', 1)}"
                )
            if "direct_s_per_step_wall" in t:
                comp += f" | {t['direct_s_per_step_wall']:.3f} | {t['direct_s_per_step_cpu']:.3f}"
            else:
                comp += " | - | -"
            if "dynamo_s_per_step_wall" in t:
                comp += f" | {t['dynamo_s_per_step_wall']:.3f} | {t['dynamo_s_per_step_cpu']:.3f}"
            else:
                comp += " | - | -"
            faults = t.get("page_faults_per_step")
            heap = "| - | -"
            if "heap128k_s_per_step_wall" in t:
                heap = (
                    f"| {t['heap128k_s_per_step_wall']:.3f} "
                    f"| {t['heap128k_page_faults_per_step']:.0f}"
                )
            md.append(
                f"| {t['num_particles']} | {t['n_points']} | {t.get('device', 'cpu')} | {graph} "
                f"| {t['threads']} | {t['s_per_step_wall']:.3f} | {t['s_per_step_cpu']:.3f} "
                f"| {'-' if faults is None else f'{faults:.0f}'} {comp} {heap} |"
            )
        md.append("")
    if results.get("rmse"):
        r = results["rmse"]
        md += [
            "### Particle RMSE of theta over 60 steps (thesis Fig. 5.5: learned swing-up "
            "policy, GPs on 3 s of exploration)",
            "",
            "| kernel | RMSE theta [rad], mean +- std over seeds | median |",
            "|---|---|---|",
        ]
        for k in ("rbf+mpk", "rbf"):
            med = r[k].get("median", float("nan"))
            md.append(f"| {k} | {r[k]['mean']:.3f} +- {r[k]['std']:.3f} | {med:.3f} |")
        md.append(
            f"\n{r['seeds']} exploration seeds (actions held "
            f"{r.get('explore_hold', 1)} steps); "
            f"RBF+MPK lower in {r['mpk_better']} of them; "
            f"policy from `{r.get('policy', '?')}`. Plot: `mcpilco_cartpole_rmse.png`.\n"
        )
    if results.get("rmse_runs"):
        md += [
            "### Particle RMSE of theta on the runs' own data (Fig. 5.5 protocol, part "
            "`rmse_runs`)",
            "",
            "GPs fitted on each run's data before its last trial; particles under that "
            "trial's policy from its real initial state, against its real trajectory. "
            "Plot: `mcpilco_cartpole_rmse_runs.png`.",
            "",
            "| policy learned with, env | runs | RBF+MPK mean / median [rad] | RBF mean / median "
            "[rad] | RBF+MPK lower in |",
            "|---|---|---|---|---|",
        ]
        for kern, g in results["rmse_runs"]["groups"].items():
            a, b = g["rbf+mpk"], g["rbf"]
            md.append(
                f"| {kern} | {g['runs']} | {a['mean']:.4f} / {a['median']:.4f} "
                f"| {b['mean']:.4f} / {b['median']:.4f} | {g['mpk_better']} of {g['runs']} |"
            )
        md.append("")
    (out_dir / "mcpilco_cartpole.md").write_text("\n".join(md))
    with open(out_dir / "mcpilco_cartpole.json", "w") as fh:
        json.dump(results, fh, indent=1)
    if results.get("runs"):
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        n_sections = len(results["runs"])
        fig, axes = plt.subplots(1, 2, figsize=(9, 3.5 + 0.25 * -(-n_sections // 3)))
        for env_id, section in results["runs"].items():
            rows = section["per_trial"]
            t = [r["experience_s"] for r in rows]
            axes[0].plot(t, [100 * r["success_rate"] for r in rows], "o-", label=env_id)
            goal = [r.get("time_in_goal_s", float("nan")) for r in rows]
            axes[1].plot(t, goal, "o-", label=env_id)
        for ax, lab in zip(axes, ["success rate [%]", "time in goal [s]"], strict=True):
            ax.set_xlabel("experience [s]")
            ax.set_ylabel(lab)
            ax.grid(alpha=0.3)
        handles, labels = axes[0].get_legend_handles_labels()
        ncol = 3
        fig.legend(handles, labels, loc="lower center", ncol=ncol, fontsize=8, frameon=False)
        legend_rows = -(-len(labels) // ncol)
        fig.tight_layout(rect=(0, 0.06 * legend_rows, 1, 1))  # the legend below the panels
        fig.savefig(out_dir / "mcpilco_cartpole.png", dpi=110)
        plt.close(fig)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="mcpilco-bench-mcpilco",
        description=__doc__,
        formatter_class=argparse.RawTextHelpFormatter,
    )
    p.add_argument(
        "--parts",
        nargs="+",
        choices=PARTS,
        help=f"parts to run (default: all of {', '.join(PARTS)}; none when --pool is given)",
    )
    p.add_argument(
        "--pool",
        nargs="+",
        metavar="LABEL",
        help="pool the existing sections with these labels ('' for the unlabelled one) of "
        "each --env into a section labelled LABEL1+LABEL2 (same config, other seeds), after "
        "the parts",
    )
    p.add_argument("--env", nargs="+", default=[DEFAULT_ENV_ID], help="env ids for the runs")
    p.add_argument("--seeds", type=int, default=20, help="number of seeds S (0..S-1)")
    p.add_argument("--first-seed", type=int, default=0)
    add_sweep_arguments(p)  # --jobs N (local processes, 1 thread each), --ray [ADDRESS]
    p.add_argument("--preset", default="bench", help="preset of each env's config file")
    p.add_argument("--trials", type=int, help="policy trials (override)")
    p.add_argument("--particles", type=int, help="particles (override)")
    p.add_argument("--opt-steps", type=int, help="max opt steps per trial (override)")
    p.add_argument("--candidates", type=int, help="K policies side by side (override)")
    p.add_argument(
        "--kernel",
        choices=KERNEL_CHOICES,
        help="GP kernel of the runs (override; e.g. rbf for the RBF-only ablation)",
    )
    p.add_argument(
        "--rollout-dtype",
        choices=ROLLOUT_DTYPES,
        help="dtype of the GP posterior in the particle rollouts (override; float32 default)",
    )
    p.add_argument(
        "--compile-rollout",
        action="store_true",
        default=None,
        help="compile the rollout's time step in the runs (MCPilcoLoss.compile_step, default "
        "backend); the timing part then also times every setting compiled, by the default "
        "backend and by torch.compile",
    )
    p.add_argument(
        "--explore-hold",
        type=int,
        help="steps each random exploration action is held (override; default: the env's, 2 "
        "on mcpilco/CartpoleSwingUp-v0, 1 = i.i.d. per step on mcpilco/DMCCartpoleSwingUp-v0 "
        "and in the runs before this option)",
    )
    p.add_argument(
        "--candidate-scales",
        type=float,
        nargs="+",
        help="initial weight scale of each candidate (K values; sets K when --candidates "
        "is not given)",
    )
    p.add_argument(
        "--label",
        default="",
        help="suffix of the results section and run folder (e.g. 'K2'), to keep variants apart",
    )
    p.add_argument(
        "--device",
        default="cpu",
        help="where the runs' policy optimisation and the timing part run: cpu or cuda[:index]",
    )
    p.add_argument("--timing-n", type=int, nargs="+", default=[100, 200, 300])
    p.add_argument("--timing-threads", type=int, nargs="+", default=[1, 2])
    p.add_argument(
        "--timing-particles",
        type=int,
        nargs="+",
        default=[400],
        help="particle counts M of the timing part (e.g. 25 400: the fixed cost and the goal's M)",
    )
    p.add_argument(
        "--timing-heap-contrast",
        action="store_true",
        help="timing part: also time the eager step with glibc's initial heap thresholds "
        "(128 KiB) instead of the retained heap, alternating in the same rounds",
    )
    p.add_argument("--rmse-seeds", type=int, default=10)
    p.add_argument(
        "--rmse-policy",
        type=Path,
        help="checkpoint.pt of a run whose last trial swung up (default: the first such run "
        "under --runs-dir)",
    )
    p.add_argument(
        "--rmse-runs",
        type=Path,
        nargs="+",
        metavar="DIR",
        help="rmse_runs part: run folders (or folders of them) to use; only runs whose last "
        "trial swung up count (default: all such runs under --runs-dir)",
    )
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--runs-dir", type=Path, default=Path("runs/bench_mcpilco"))
    return p


@console_main("mcpilco-bench-mcpilco")
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.parts is None:
        args.parts = [] if args.pool else list(PARTS)
    if args.seeds < 1:
        parser.error("--seeds must be >= 1")
    try:
        runner = runner_from_args(args)
    except SweepError as err:
        parser.error(str(err))
    for name in ("timing_n", "timing_threads", "timing_particles"):
        if min(getattr(args, name)) < 1:
            parser.error(f"--{name.replace('_', '-')} values must be >= 1")
    from mcpilco.agents.mc_pilco.loop import check_compile_toolchain
    from mcpilco.envs.tasks import task_ids
    from mcpilco.models.device import resolve_device

    ids = task_ids()
    for env_id in args.env:
        if env_id not in ids:
            parser.error(f"no task ships for env id {env_id!r}; tasks: {', '.join(ids)}")
    scales = args.candidate_scales
    try:  # one config per env: an env without --explore-hold gets its own default hold
        env_cfgs = {
            env_id: load_config(env_id, preset=args.preset).with_overrides(
                num_trials=args.trials,
                num_particles=args.particles,
                num_candidates=(
                    args.candidates if args.candidates is not None or not scales else len(scales)
                ),
                kernel=args.kernel,
                rollout_dtype=args.rollout_dtype,
                compile_rollout=args.compile_rollout,
                explore_hold=args.explore_hold,
                candidate_weight_scales=scales,
                device=args.device,
                opt_steps=args.opt_steps,
            )
            for env_id in args.env
        }
        if args.compile_rollout:
            check_compile_toolchain(resolve_device(args.device))
        resolve_device(args.device)
    except ValueError as err:
        parser.error(str(err))

    json_path = args.out / "mcpilco_cartpole.json"
    results: dict[str, Any] = {}
    if json_path.is_file():
        results = json.loads(json_path.read_text())
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    failed = 0
    if "runs" in args.parts:
        results.setdefault("runs", {})
        for env_id in args.env:
            env_cfg = env_cfgs[env_id]
            tag = env_id.split("/")[-1] + (f"_{args.label}" if args.label else "")
            key = section_key(env_id, args.label)
            section, sweep = bench_runs(env_cfg, seeds, runner, args.runs_dir / tag)
            print(sweep.summary())
            failed += len(sweep.failed)
            if section is None:
                continue
            results["runs"][key] = section
            print(_md_table(key, section))
            write_report(results, args.out)
    if "timing" in args.parts:
        results["timing"] = []
        for n in args.timing_n:
            for th in args.timing_threads:
                for m in args.timing_particles:
                    for graph in (True, False) if args.device.startswith("cuda") else (False,):
                        t = time_opt_step(
                            n, num_particles=m, threads=th, device=args.device,
                            cuda_graph=graph, compile_rollout=bool(args.compile_rollout),
                            heap_contrast=bool(args.timing_heap_contrast),
                        )  # fmt: skip
                        comp = t.get("compiled_s_per_step_wall")
                        print(
                            f"N={n} M={m} threads={th} device={t['device']} "
                            f"graph={t['cuda_graph']}: {t['s_per_step_wall']:.3f} s/step wall"
                            + (f", compiled {comp:.3f}" if comp is not None else "")
                            + (", compiled step rejected" if t.get("compiled_rejected") else "")
                            + (
                                f", 128 KiB heap {t['heap128k_s_per_step_wall']:.3f}"
                                if "heap128k_s_per_step_wall" in t
                                else ""
                            )
                        )
                        results["timing"].append(t)
        write_report(results, args.out)
    if "rmse" in args.parts:
        try:
            policy_ckpt = args.rmse_policy or find_swingup_policy(args.runs_dir)
        except FileNotFoundError as err:
            parser.error(str(err))
        hold = args.explore_hold or load_config(DEFAULT_ENV_ID).explore_hold  # rmse runs this env
        per_seed = [
            particle_rmse(s, policy_ckpt, explore_hold=hold) for s in range(args.rmse_seeds)
        ]
        rm = {
            "seeds": len(per_seed),
            "per_seed": per_seed,
            "policy": str(policy_ckpt),
            "explore_hold": hold,
        }
        for k in ("rbf+mpk", "rbf"):
            vals = [p[k] for p in per_seed]
            rm[k] = {
                "mean": float(np.mean(vals)),
                "std": float(np.std(vals)),
                "median": float(np.median(vals)),
            }
        rm["mpk_better"] = int(sum(p["rbf+mpk"] < p["rbf"] for p in per_seed))
        args.out.mkdir(parents=True, exist_ok=True)
        plot_rmse(rm, args.out / "mcpilco_cartpole_rmse.png")
        for p_ in rm["per_seed"]:  # keep the JSON small: particles only in the plot
            for k in list(p_):
                if k.endswith("_particles"):
                    del p_[k]
        results["rmse"] = rm
        print(f"theta RMSE: rbf+mpk {rm['rbf+mpk']}, rbf {rm['rbf']}")
        write_report(results, args.out)
    if "rmse_runs" in args.parts:
        ckpts = [c for d in (args.rmse_runs or [args.runs_dir]) for c in swingup_runs(d)]
        if not ckpts:
            parser.error("rmse_runs: no run whose last trial swung up; run the 'runs' part first")
        from tqdm.auto import tqdm

        per_run = [particle_rmse_on_run(c) for c in tqdm(ckpts, desc="rmse on runs")]
        groups = summarise_rmse_runs(per_run)
        args.out.mkdir(parents=True, exist_ok=True)
        plot_rmse_runs(per_run, args.out / "mcpilco_cartpole_rmse_runs.png")
        for r in per_run:  # keep the JSON small: per-step curves only in the plot
            for k in ("rbf+mpk", "rbf"):
                del r[f"{k}_per_step"]
        results["rmse_runs"] = {"per_run": per_run, "groups": groups}
        for kern, g in groups.items():
            print(f"runs learned with {kern}: {g}")
        write_report(results, args.out)
    if args.pool:
        sections = results.get("runs", {})
        for env_id in args.env:
            keys = [section_key(env_id, label) for label in args.pool]
            missing = [k for k in keys if k not in sections]
            if missing:
                parser.error(f"--pool: no section {missing} in {json_path}; have {list(sections)}")
            try:
                pooled = pool_sections([sections[k] for k in keys])
            except ValueError as err:
                parser.error(f"--pool: {err}")
            key = section_key(env_id, "+".join(args.pool))
            sections[key] = pooled
            print(_md_table(key, pooled))
        write_report(results, args.out)
    print(f"wrote {json_path} and {args.out / 'mcpilco_cartpole.md'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
