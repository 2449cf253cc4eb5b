"""MC-PILCO on a tracking task: the tracking error per joint after each trial against the
controller alone (part ``tracking`` of ``mcpilco-bench-mcpilco``).

A tracking task's cost terms track reference states (``q_b - q_r,b``; the UR10 task of
``envs/tasks/ur10_tracking.yaml``). Each seed runs the whole loop (:func:`bench_runs`); its
trial records carry ``tracking_rms``, the RMS of ``q_b - q_r,b`` over the episode per joint.
The baseline is the controller alone: the same episodes (same reset seeds,
:func:`~mcpilco.agents.common.trials.trial_seed`) with the action at the middle of its
range (a zero torque correction). Reported per policy trial: the mean over seeds of each
joint's RMS, its ratio to the baseline's, and the number of seeds whose every joint is at
most half the baseline's (the goal "error at least halved"). On an arm env with a known
model (``feedforward_action`` of :class:`~mcpilco.envs.arm_env.ArmTrackingEnv`) the same
episodes also run with the simulator's own inverse-dynamics feed-forward held over each
control period and clipped to the action bounds: what an ideal model achieves within them.

Writes ``results/mcpilco_tracking.json`` (one section per env and label),
``mcpilco_tracking.md`` and ``mcpilco_tracking.png`` (per joint: RMS against experience,
mean and the seeds' range, the baseline dashed); the kernel comparison
(:func:`tracking_kernels_part`) adds its table and ``mcpilco_tracking_kernels_<runs>.png``.
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.agents.mc_pilco import MCPilcoConfig
from mcpilco.experiments.infra.sweep import Job, SweepRunner
from mcpilco.experiments.mcpilco.bench import (
    bench_runs,
    kernel_label,
    load_results,
    section_key,
)
from mcpilco.experiments.results import (
    Headline,
    Result,
    ResultLayout,
    read_result,
    seed_ranges,
    write_result,
)

RESULTS_NAME = "mcpilco_tracking"  # stem of the JSON, Markdown and PNG outputs
PUSH_VARIANTS = ("both", "filtered", "kept")  # push sections: with / without the push filter
HALVED = 0.5  # the goal: every joint's RMS at most this fraction of the controller alone's


def train_task_detector(
    config: MCPilcoConfig,
    path: Path,
    episodes: int = 5,
    seed: int = 0,
    gp_points: int = 1500,
) -> Path:
    """A collision detector for ``config``'s arm task, saved at ``path``: ``episodes``
    collision-free episodes of the task (its reference, pushes off, random corrections as in
    the exploration trial, reset seeds ``seed, seed + 1, ...`` of their own) logged at the
    env's sampling time, then :func:`~mcpilco.models.collision.train_detector` with the FC
    estimator on the robot's nominal model, thresholds by the maximum rule on the last
    episode, 2-sample persistence. What a user does on the real arm: record the task's
    motion without contacts, train, then filter the learning runs."""
    from mcpilco.agents.common.trials import exploration_actions, make_env, run_episode
    from mcpilco.envs.arm_data import log_from_infos
    from mcpilco.experiments.collision.nominal import nominal_model
    from mcpilco.models.collision import train_detector
    from mcpilco.models.robot_data import save_dataset

    task = config.task_spec()
    kwargs = {k: v for k, v in (config.env_kwargs or {}).items() if k != "disturbances"}
    env = make_env(config.env_id, task.horizon, task, kwargs)
    rng = np.random.default_rng(seed)
    rows: list[dict[str, Any]] = []
    try:
        robot = type(env.unwrapped).__name__.removesuffix("Env").lower()
        sample_time = float(env.unwrapped.dt)
        for e in range(episodes):
            acts = iter(
                exploration_actions(rng, task.horizon, 1, task.action_low, task.action_high)
            )
            ep = run_episode(
                env, lambda _x, it=acts: next(it), seed + e, task.horizon, task, record_info=True
            )
            rows += [info for step in ep["infos"] for info in step]
    finally:
        env.close()
    log = log_from_infos(rows)
    log["t"] = np.arange(len(rows)) * sample_time  # one clock over the episodes
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    log_path = path.with_suffix(".free.parquet")
    save_dataset(log, log_path)
    train_detector(
        log_path, nominal_model(robot), estimator="FC", gp_points=gp_points,
        calibration_fraction=1.0 / episodes, persistence=2, save=path,
    )  # fmt: skip
    return path


def controller_alone(
    config: MCPilcoConfig, seed: int, trials: int, feedforward: bool = False
) -> list[dict[str, float]] | None:
    """``tracking_rms`` of the episodes of policy trials ``1..trials`` of run ``seed`` with
    the action held at the middle of its range (the env's controller alone), or with
    ``feedforward`` the env's known-model feed-forward held over each control period
    (``feedforward_action`` of :class:`~mcpilco.envs.arm_env.ArmTrackingEnv`; None for an
    env without one)."""
    from mcpilco.agents.common.trials import make_env, run_episode, trial_seed

    task = config.task_spec()
    env = make_env(config.env_id, task.horizon, task, config.env_kwargs)
    arm = env.unwrapped
    if feedforward and not hasattr(arm, "feedforward_action"):
        env.close()
        return None
    mid = (np.asarray(task.action_low) + np.asarray(task.action_high)) / 2

    def act(_x: np.ndarray) -> np.ndarray:
        return arm.feedforward_action(arm.time, task.dt) if feedforward else mid

    try:
        return [
            run_episode(env, act, trial_seed(seed, k), task.horizon, task)["tracking_rms"]
            for k in range(1, trials + 1)
        ]
    finally:
        env.close()


def tracking_section(
    config: MCPilcoConfig, runs: Sequence[dict[str, Any]], section: dict[str, Any]
) -> dict[str, Any]:
    """``section`` (:func:`bench_runs`) with the tracking figures of ``runs`` (the seeds'
    :func:`~mcpilco.experiments.mcpilco.bench.run_seed` results): per seed the RMS per joint
    after each trial and the controller alone's; per policy trial the means, ratios and
    the count of seeds with every joint halved."""
    per_seed = []
    for r in sorted(runs, key=lambda r: r["seed"]):
        recs = [x for x in r["records"] if x["kind"] == "policy"]
        per_seed.append(
            {
                "seed": r["seed"],
                "records": recs,
                "rms": [x["tracking_rms"] for x in recs],
                "alone": controller_alone(config, r["seed"], len(recs)),
                "feedforward": controller_alone(config, r["seed"], len(recs), feedforward=True),
                "experience_s": [x["experience_s"] for x in recs],
            }
        )
    joints = list(per_seed[0]["rms"][0])
    trials = min(len(s["rms"]) for s in per_seed)
    rows = []
    for k in range(trials):
        rms = np.array([[s["rms"][k][j] for j in joints] for s in per_seed])
        alone = np.array([[s["alone"][k][j] for j in joints] for s in per_seed])
        ratio = rms / alone
        ff = {}
        if all(s["feedforward"] for s in per_seed):
            ideal = np.array([[s["feedforward"][k][j] for j in joints] for s in per_seed])
            ff = {
                "feedforward_mean": ideal.mean(0).tolist(),
                "feedforward_ratio": (ideal / alone).mean(0).tolist(),
                "feedforward_halved": int(np.sum(np.all(ideal / alone <= HALVED, axis=1))),
            }
        rows.append(
            {
                **ff,
                "trial": k + 1,
                "experience_s": per_seed[0]["experience_s"][k],
                "rms_mean": rms.mean(0).tolist(),
                "rms_min": rms.min(0).tolist(),
                "rms_max": rms.max(0).tolist(),
                "alone_mean": alone.mean(0).tolist(),
                "ratio_mean": ratio.mean(0).tolist(),
                "ratio_worst": ratio.max(0).tolist(),
                "seeds_halved": int(np.sum(np.all(ratio <= HALVED, axis=1))),
                **push_counts([s["records"][k] for s in per_seed]),
            }
        )
    for p in per_seed:
        del p["records"]
    return {**section, "joints": joints, "tracking": rows, "tracking_per_seed": per_seed}


def overall(section: dict[str, Any], k: int) -> dict[str, float]:
    """The error of all joints together after policy trial ``k + 1``: per seed
    ``sqrt(mean_j rms_j^2)`` of the episode and of the controller alone's; returned as the
    means over seeds (``rms``, ``alone``) and the mean of the seeds' ratios (``ratio``) and
    the number of seeds at most :data:`HALVED` of the controller alone (``halved``)."""
    joints = section["joints"]
    per = section["tracking_per_seed"]

    def total(row: dict[str, float]) -> float:
        return float(np.sqrt(np.mean([row[j] ** 2 for j in joints])))

    rms = np.array([total(p["rms"][k]) for p in per])
    alone = np.array([total(p["alone"][k]) for p in per])
    return {
        "rms": float(rms.mean()),
        "alone": float(alone.mean()),
        "ratio": float(np.mean(rms / alone)),
        "halved": int(np.sum(rms <= HALVED * alone)),
    }


def push_counts(records: Sequence[dict[str, Any]]) -> dict[str, int]:
    """Sums over seeds of a trial's pushed transitions (``n_contact``, the env's truth),
    those a push filter left out (``n_filtered``) and the pushed ones among them, where the
    records have them."""
    return {
        key: int(sum(r[key] for r in records))
        for key in ("n_contact", "n_filtered", "n_filtered_contact")
        if all(key in r for r in records)
    }


def tracking_table(key: str, section: dict[str, Any]) -> str:
    """The Markdown table of a tracking section: one row per policy trial, per joint the
    mean RMS [mrad] and its ratio to the controller alone."""
    cfg, joints, seeds = section["config"], section["joints"], section["seeds"]
    lines = [
        f"### {key}",
        "",
        f"{len(seeds)} seeds ({seed_ranges(seeds)}); M={cfg['num_particles']} particles, "
        f"max {cfg['opt']['max_steps']} opt steps per trial, GP subset N<={cfg['max_points']}, "
        f"kernel {kernel_label(cfg['kernel'], cfg.get('mpk_degree', 2))}, "
        f"rollout {cfg.get('rollout_backend', 'auto')} "
        f"{cfg.get('rollout_dtype', 'float32')}, policy init {cfg.get('policy_init', 'box')}; "
        f"{section['jobs']} parallel jobs x 1 thread; mean wall-clock per run "
        f"{section['wall_s_per_run']:.0f} s.",
        "",
        "Per joint: mean over seeds of the episode's tracking RMS [mrad] (ratio to the "
        "controller alone, mean over seeds). Halved: seeds whose every joint is at most "
        f"{HALVED:g} x the controller alone's. All joints: sqrt(mean over joints of RMS^2) "
        "per seed, mean over seeds (ratio: mean of the seeds' ratios); all joints halved: "
        "seeds whose all-joint error is at most half the controller alone's. Known-model "
        "feed-forward: the simulator's inverse dynamics on the reference, held over each "
        "control period and clipped to the action bounds, on the same episodes (in brackets "
        "in a trial's row: its seeds with every joint halved). "
        "Pushed / filtered: the trial's transitions "
        "(40 ms) during an external push (the env's truth) / left out of the GP data by the "
        "push filter (in brackets: both), summed over seeds.",
        "",
        "| experience | " + " | ".join(joints) + " | every joint halved | all joints "
        "| all joints halved | pushed / filtered (both) |",
        "|---|" + "---|" * len(joints) + "---|---|---|---|",
    ]
    first = section["tracking"][0]
    lines.append(
        "| controller alone | "
        + " | ".join(f"{1e3 * v:.1f}" for v in first["alone_mean"])
        + f" | - | {1e3 * overall(section, 0)['alone']:.1f} | - | - |"
    )
    if "feedforward_mean" in first:
        cells = zip(first["feedforward_mean"], first["feedforward_ratio"], strict=True)
        lines.append(
            "| known-model feed-forward | "
            + " | ".join(f"{1e3 * m:.1f} ({q:.2f})" for m, q in cells)
            + f" | {first['feedforward_halved']} / {len(seeds)} | - | - | - |"
        )
    for k, r in enumerate(section["tracking"]):
        cells = [
            f"{1e3 * m:.1f} ({q:.2f})" for m, q in zip(r["rms_mean"], r["ratio_mean"], strict=True)
        ]
        tot = overall(section, k)
        ideal = f" (feed-forward {r['feedforward_halved']})" if "feedforward_halved" in r else ""
        lines.append(
            f"| {r['experience_s']:.0f} s (policy {r['trial']}) | "
            + " | ".join(cells)
            + f" | {r['seeds_halved']} / {len(seeds)}{ideal} | {1e3 * tot['rms']:.1f} "
            f"({tot['ratio']:.2f}) | {tot['halved']} / {len(seeds)} | {_push_cell(r)} |"
        )
    return "\n".join(lines) + "\n"


def _push_cell(row: dict[str, Any]) -> str:
    """``pushed / filtered (both)`` transitions of a trial, summed over seeds; ``-`` for a
    count the records do not have."""
    if "n_contact" not in row and "n_filtered" not in row:
        return "-"
    both = f" ({row['n_filtered_contact']})" if "n_filtered_contact" in row else ""
    return f"{row.get('n_contact', '-')} / {row.get('n_filtered', '-')}{both}"


def kernel_rmse_on_run(
    ckpt_path: str | Path,
    kernels: Sequence[str],
    num_particles: int = 100,
    fit_trials: int | None = None,
) -> dict[str, Any]:
    """The kernels' multi-step prediction error on a finished tracking run's own data: for
    each kernel label of ``kernels``
    (:data:`~mcpilco.experiments.mcpilco.rmse.KERNEL_ARGS`) a GP fitted with the run's GP
    settings on every transition before its last trial (those its push filter left out
    excluded), or on those of its first ``fit_trials`` trials only (1: the exploration
    trial's: how well each kernel predicts from the data the first policy is optimised on);
    ``M`` particles under the policy of the last trial from its real initial state over the
    whole horizon, against its real trajectory. Per kernel and joint: the RMSE of ``q_b``
    over particles and steps [rad] (``rmse``), per step (``per_step``), and the seconds of
    the fit and rollout (``seconds``). A sweep job of :func:`tracking_kernels_part`.

    Raises:
        ValueError: no policy trial in the run, or ``fit_trials`` not in ``1 .. trials - 1``.
    """
    from mcpilco.agents.common.checkpoint import load_checkpoint
    from mcpilco.agents.common.trials import transitions
    from mcpilco.agents.mc_pilco import SquashedRBFPolicy
    from mcpilco.experiments.mcpilco.rmse import model_particles

    ckpt = load_checkpoint(ckpt_path)
    cfg = MCPilcoConfig.from_dict(ckpt["config"])
    task = cfg.task_spec()
    episodes, arrays = ckpt["episodes"], ckpt["arrays"]
    if len(episodes) < 2 or not task.joints:
        raise ValueError(f"{ckpt_path}: needs an arm task's run with a policy trial")
    policy = SquashedRBFPolicy(**ckpt["policy_settings"])
    policy.load_state_dict(ckpt["policy"])
    if fit_trials is not None and not 1 <= fit_trials < len(episodes):
        raise ValueError(
            f"{ckpt_path}: fit_trials must be in 1 .. {len(episodes) - 1} (the trials before "
            f"the last), got {fit_trials}"
        )
    n_fit = fit_trials or len(episodes) - 1
    real = np.asarray(arrays[-1]["real"])
    idx = [task.state_names.index(j) for j in task.joints]
    data = transitions(episodes[:n_fit], task)
    fit = dict(
        max_points=cfg.max_points, adam_iters=cfg.gp_adam_iters, lbfgs_iters=cfg.gp_lbfgs_iters,
        noise_min=cfg.gp_noise_min, min_lengthscale=cfg.gp_min_lengthscale,
    )  # fmt: skip
    out: dict[str, Any] = {
        "run": Path(ckpt_path).parent.name,
        "seed": cfg.seed,
        "run_kernel": kernel_label(cfg.kernel, cfg.mpk_degree),
        "n_data": len(data[1]),
        "fit_trials": n_fit,
        "last_trial": len(episodes) - 1,
        "joints": list(task.joints),
        "kernels": {},
    }
    for kernel in kernels:
        t0 = time.perf_counter()
        parts = model_particles(
            task, data, policy, real[0], len(real) - 1, kernel, num_particles, cfg.seed, **fit
        )
        err = parts[:, 1:, idx] - real[None, 1:, idx]  # (M, H, joints)
        out["kernels"][kernel] = {
            "rmse": np.sqrt(np.mean(err**2, axis=(0, 1))).tolist(),
            "per_step": np.sqrt(np.mean(err**2, axis=0)).tolist(),
            "seconds": time.perf_counter() - t0,
        }
    return out


def summarise_kernel_rmse(per_run: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """:func:`kernel_rmse_on_run` over runs: per kernel the mean and median over runs of
    each joint's RMSE, the mean over runs of the all-joint RMSE ``sqrt(mean_b rmse_b^2)``,
    per joint the number of runs in which the kernel's RMSE is the lowest, and per step and
    joint the median over runs (``per_step_median``); the runs' figures without their steps
    (``per_run``)."""
    kernels = list(per_run[0]["kernels"])
    rm = {k: np.array([r["kernels"][k]["rmse"] for r in per_run]) for k in kernels}
    best = np.argmin(np.stack([rm[k] for k in kernels]), axis=0)  # (runs, joints)
    return {
        "runs": len(per_run),
        "joints": per_run[0]["joints"],
        "run_kernel": sorted({r["run_kernel"] for r in per_run}),
        "n_data": [r["n_data"] for r in per_run],
        "fit_trials": sorted({r.get("fit_trials") for r in per_run} - {None}),
        "last_trial": sorted({r.get("last_trial") for r in per_run} - {None}),
        "kernels": {
            k: {
                "mean": rm[k].mean(0).tolist(),
                "median": np.median(rm[k], axis=0).tolist(),
                "all_joints_mean": float(np.mean(np.sqrt(np.mean(rm[k] ** 2, axis=1)))),
                "lowest": (best == i).sum(0).tolist(),
                "seconds_mean": float(np.mean([r["kernels"][k]["seconds"] for r in per_run])),
                "per_step_median": np.median(
                    [r["kernels"][k]["per_step"] for r in per_run], axis=0
                ).tolist(),
            }
            for i, k in enumerate(kernels)
        },
        "per_run": [
            {
                **r,
                "kernels": {
                    k: {key: v for key, v in fig.items() if key != "per_step"}
                    for k, fig in r["kernels"].items()
                },
            }
            for r in per_run
        ],
    }


def kernel_rmse_table(key: str, summary: dict[str, Any]) -> str:
    """Markdown: per kernel the mean RMSE [mrad] of each joint's predicted trajectory, the
    all-joint mean, and the runs in which it was lowest per joint."""
    from mcpilco.experiments.mcpilco.rmse import KERNEL_ARGS

    joints = summary["joints"]
    lo, hi = min(summary["n_data"]), max(summary["n_data"])
    fit, last = summary.get("fit_trials", []), summary.get("last_trial", [])
    if not fit or fit == last:
        data = "a run's transitions before its last policy trial"
    elif fit == [1]:
        data = "the transitions of a run's exploration trial only"
    else:
        data = f"a run's transitions of its first {'/'.join(map(str, fit))} trials"
    lines = [
        f"### Multi-step prediction error per joint: {key}",
        "",
        f"{summary['runs']} runs (learned with {', '.join(summary['run_kernel'])}); each kernel's "
        f"GP fitted on {data} ({lo if lo == hi else f'{lo}-{hi}'} transitions), particles under "
        "the last trial's policy from its real initial state over the whole horizon against its "
        "real trajectory. Per joint: RMSE of q over particles and steps [mrad], mean over runs "
        "(in brackets: runs in which this kernel's is the lowest). All joints: "
        "sqrt(mean over joints of RMSE^2), mean over runs.",
        "",
        "| kernel | " + " | ".join(joints) + " | all joints | s per fit and rollout |",
        "|---|" + "---|" * len(joints) + "---|---|",
    ]
    for k, v in summary["kernels"].items():
        cells = [f"{1e3 * m:.1f} ({n})" for m, n in zip(v["mean"], v["lowest"], strict=True)]
        lines.append(
            f"| {kernel_label(**KERNEL_ARGS[k])} | " + " | ".join(cells)
            + f" | {1e3 * v['all_joints_mean']:.1f} | {v['seconds_mean']:.0f} |"
        )  # fmt: skip
    return "\n".join(lines) + "\n"


def tracking_kernels_part(
    runs_dirs: Sequence[Path],
    out_dir: Path,
    kernels: Sequence[str],
    runner: SweepRunner,
    num_particles: int = 100,
    command: str = "",
    log: Callable[[str], None] = print,
    fit_trials: int | None = None,
) -> dict[str, Any]:
    """Part ``tracking_kernels``: :func:`kernel_rmse_on_run` on every run
    (``*/checkpoint.pt``) under each of ``runs_dirs`` as sweep jobs of ``runner`` (one torch
    thread each; results in ``<runs_dir>/kernel_rmse/``, or ``kernel_rmse_fit<K>/`` with
    ``fit_trials`` ``K``, kept for the same runs and arguments), summarised
    (:func:`summarise_kernel_rmse`) under the folder's name (``<name>_fit<K>``) in
    ``kernels`` of ``out_dir/mcpilco_tracking.json``; the report is rewritten.

    Raises:
        ValueError: no folder, a folder without a run, an unknown kernel label,
            ``fit_trials < 1``, a failed job (e.g. ``fit_trials`` not before a run's last
            trial).
    """
    from mcpilco.experiments.mcpilco.rmse import KERNEL_ARGS

    if not runs_dirs:
        raise ValueError("tracking_kernels needs the folders of tracking runs (--rmse-runs DIR)")
    unknown = [k for k in kernels if k not in KERNEL_ARGS]
    if unknown:
        raise ValueError(f"unknown kernels {unknown}; choose from {sorted(KERNEL_ARGS)}")
    if fit_trials is not None and fit_trials < 1:
        raise ValueError(f"fit_trials must be >= 1 (1: the exploration trial), got {fit_trials}")
    results = load_results(out_dir, RESULTS_NAME)
    for runs_dir in runs_dirs:
        ckpts = sorted(Path(runs_dir).glob("*/checkpoint.pt"))
        if not ckpts:
            raise ValueError(f"no finished run (*/checkpoint.pt) under {runs_dir}")
        args: dict[str, Any] = {"kernels": list(kernels), "num_particles": int(num_particles)}
        suffix = "" if fit_trials is None else f"_fit{int(fit_trials)}"
        if fit_trials is not None:
            args["fit_trials"] = int(fit_trials)
        jobs = [
            Job(c.parent.name, kernel_rmse_on_run, {"ckpt_path": str(c), **args}, threads=1)
            for c in ckpts
        ]
        sweep = runner.run(
            jobs, Path(runs_dir) / f"kernel_rmse{suffix}", desc=f"kernels {runs_dir}"
        )
        if sweep.failed:
            raise ValueError(f"{len(sweep.failed)} runs failed: {sweep.summary()}")
        per_run = [sweep.results[job.key] for job in jobs]
        for r in per_run:
            log(
                f"{r['run']}: "
                + ", ".join(
                    f"{k} {1e3 * np.sqrt(np.mean(np.square(v['rmse']))):.1f} mrad"
                    for k, v in r["kernels"].items()
                )
            )
        key = Path(runs_dir).name + suffix
        results.setdefault("kernels", {})[key] = summarise_kernel_rmse(per_run)
        if command:
            results.setdefault("commands", {})[kernels_entry(key)] = command
        results.setdefault("measured", {})[kernels_entry(key)] = time.strftime("%Y-%m-%d")
        log(kernel_rmse_table(key, results["kernels"][key]))
        write_tracking_report(results, out_dir)
    return results


def plot_kernel_rmse(summary: dict[str, Any], path: Path) -> None:
    """Per joint, the median over runs of each kernel's RMSE of q against time over the
    horizon (:func:`summarise_kernel_rmse`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mcpilco.experiments.mcpilco.rmse import KERNEL_ARGS

    joints = summary["joints"]
    cols = min(len(joints), 3)
    rows = -(-len(joints) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 2.6 * rows), squeeze=False)
    for k, v in summary["kernels"].items():
        per = 1e3 * np.asarray(v["per_step_median"])  # (H, joints)
        steps = np.arange(1, len(per) + 1)
        for j, name in enumerate(joints):
            ax = axes[j // cols][j % cols]
            ax.plot(steps, per[:, j], label=kernel_label(**KERNEL_ARGS[k]))
            ax.set_title(f"{name}: RMSE of q [mrad]", fontsize=9)
            ax.set_xlabel("step")
    for j in range(len(joints), rows * cols):
        axes[j // cols][j % cols].axis("off")
    axes[0][0].legend(fontsize=7)
    fig.suptitle(
        f"particles against the real trajectory, median over {summary['runs']} runs", fontsize=9
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def kernels_entry(key: str) -> str:
    """The key of a kernel comparison's command and date (``commands``, ``measured``)."""
    return f"kernels {key}"


def _command_lines(results: dict[str, Any], entry: str) -> list[str]:
    """Markdown lines naming the command of ``entry`` and its date, if recorded."""
    command = results.get("commands", {}).get(entry)
    if not command:
        return []
    return [f"Command: `{command}` ({results.get('measured', {}).get(entry, 'undated')})", ""]


def write_tracking_report(results: dict[str, Any], out_dir: Path) -> None:
    """``mcpilco_tracking.{json,md,png}`` of ``results`` (``{"runs": {key: section}}``)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    md = [
        "# MC-PILCO on tracking tasks",
        "",
        "Command: `mcpilco-bench-mcpilco --parts tracking --env ENV --seeds S --first-seed F "
        "--jobs J [--label L]`. Experience counts the exploration trial.",
        "",
    ]
    if results.get("machine"):
        md += [f"Machine: {results['machine']}.", ""]
    for key, section in results.get("runs", {}).items():
        md += [tracking_table(key, section), *_command_lines(results, key)]
    for key, summary in results.get("kernels", {}).items():
        md += [kernel_rmse_table(key, summary), *_command_lines(results, kernels_entry(key))]
    (out_dir / f"{RESULTS_NAME}.md").write_text("\n".join(md))
    write_result(out_dir / f"{RESULTS_NAME}.json", RESULT_LAYOUTS[0], results)
    replot(read_result(out_dir / f"{RESULTS_NAME}.json"), out_dir / f"{RESULTS_NAME}.json")


def replot(result: Result, json_path: Path) -> list[Path]:
    """Redraw the figures of a tracking result file next to it: one kernel RMSE plot per
    kernel comparison and (with runs) the tracking RMS per joint (:func:`plot_tracking`)."""
    out_dir = Path(json_path).parent
    paths = []
    for key, summary in result.get("kernels", {}).items():
        path = out_dir / f"{RESULTS_NAME}_kernels_{key}.png"
        plot_kernel_rmse(summary, path)
        paths.append(path)
    if result.get("runs"):
        paths.append(plot_tracking(result.payload(), out_dir / f"{RESULTS_NAME}.png"))
    return paths


def plot_tracking(results: dict[str, Any], path: Path) -> Path:
    """Tracking RMS per joint against experience, one curve per runs section, the controller
    alone dashed and half of it dotted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sections = list(results["runs"].items())
    n_joints = max(len(s["joints"]) for _, s in sections)
    cols = min(n_joints, 3)
    rows = -(-n_joints // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 2.8 * rows), squeeze=False)
    for key, section in sections:
        t = [r["experience_s"] for r in section["tracking"]]
        for j, name in enumerate(section["joints"]):
            ax = axes[j // cols][j % cols]
            mean = [1e3 * r["rms_mean"][j] for r in section["tracking"]]
            lo = [1e3 * r["rms_min"][j] for r in section["tracking"]]
            hi = [1e3 * r["rms_max"][j] for r in section["tracking"]]
            (line,) = ax.plot(t, mean, "o-", label=key)
            ax.fill_between(t, lo, hi, color=line.get_color(), alpha=0.2)
            alone = 1e3 * section["tracking"][0]["alone_mean"][j]
            ax.axhline(alone, color=line.get_color(), ls="--", lw=1)
            ax.axhline(HALVED * alone, color="grey", ls=":", lw=1)
            ax.set_title(f"{name}: tracking RMS [mrad]")
            ax.set_xlabel("experience [s]")
            ax.set_ylim(bottom=0)
    for j in range(n_joints, rows * cols):
        axes[j // cols][j % cols].axis("off")
    axes[0][0].legend(fontsize=7)
    fig.suptitle("dashed: controller alone; dotted: half of it; band: seeds' range", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def tracking_part(
    configs: dict[str, MCPilcoConfig],
    seeds: Sequence[int],
    runner: SweepRunner,
    runs_dir: Path,
    out_dir: Path,
    label: str = "",
    pushes: str | None = None,
    command: str = "",
    log: Callable[[str], None] = print,
) -> int:
    """Part ``tracking``: the seeds of each config (:func:`bench_runs`, in
    ``runs_dir/<env name>[_<label>]``), each env's tracking section stored under
    :func:`section_key` in ``out_dir/mcpilco_tracking.json`` and the report written after
    each env. Returns the number of failed seeds.

    ``pushes`` (one of :data:`PUSH_VARIANTS`, None: pushes off): the env's random pushes
    on (``env_kwargs: {disturbances: true}``) in learning and evaluation, with the
    transitions of the pushes kept in the GP data (``"kept"``, label ``pushes``), left out
    by the push filter (``"filtered"``, label ``pushes-filtered``) with a detector of
    :func:`train_task_detector`, trained once in ``runs_dir``, or both sections on the same
    seeds (``"both"``). ``command``: the command line, recorded with each section's date of
    measurement (``commands`` and ``measured``, keyed by section).

    Raises:
        ValueError: a config whose task tracks no reference state, or an unknown ``pushes``.
    """
    if pushes is not None and pushes not in PUSH_VARIANTS:
        raise ValueError(f"pushes must be one of {PUSH_VARIANTS} or None, got {pushes!r}")
    for env_id, cfg in configs.items():
        if not cfg.task_spec().tracked_states():
            raise ValueError(f"{env_id}: the task's cost tracks no reference state")
    import torch

    results = load_results(out_dir, RESULTS_NAME)
    results["machine"] = (
        f"{platform.machine()} {os.cpu_count()} CPUs, Python {platform.python_version()}, "
        f"torch {torch.__version__}"
    )
    results.setdefault("runs", {})
    failed = 0
    for env_id, cfg in configs.items():
        variants = [(label, cfg)]
        if pushes is not None:
            kwargs = {**(cfg.env_kwargs or {}), "disturbances": True}
            pushed = cfg.with_overrides(env_kwargs=kwargs)
            prefix = f"{label}-" if label else ""
            variants = [] if pushes == "filtered" else [(f"{prefix}pushes", pushed)]
            if pushes != "kept":
                name = env_id.split("/")[-1]
                detector = Path(runs_dir) / f"{name}_{label}_detector.pt"
                if not detector.is_file():
                    log(f"training the push detector of {env_id} in {detector}")
                    train_task_detector(cfg, detector, seed=10_000)
                filtered = pushed.with_overrides(push_filter=str(detector))
                variants.append((f"{prefix}pushes-filtered", filtered))
        for lab, c in variants:
            tag = env_id.split("/")[-1] + (f"_{lab}" if lab else "")
            section, sweep = bench_runs(c, list(seeds), runner, Path(runs_dir) / tag)
            log(sweep.summary())
            failed += len(sweep.failed)
            if section is None:
                continue
            key = section_key(env_id, lab)
            results["runs"][key] = tracking_section(c, list(sweep.results.values()), section)
            if command:
                results.setdefault("commands", {})[key] = command
            results.setdefault("measured", {})[key] = time.strftime("%Y-%m-%d")
            log(tracking_table(key, results["runs"][key]))
            write_tracking_report(results, out_dir)
    return failed


# -- result file and headline rows of the results index -----------------------------------

RESULT_LAYOUTS = (
    ResultLayout(
        "mcpilco_tracking",
        cases=("runs",),
        seeds=lambda p: [s for sec in p.get("runs", {}).values() for s in sec.get("seeds", ())],
    ),
)
"""The layout of ``mcpilco_tracking.json`` (:mod:`mcpilco.experiments.results`)."""

TRACKING_SECTION = "mcpilco/UR10-v0 (positions)"  # the UR10 tracking headline's section
PUSHES_SECTION = "mcpilco/UR10-v0 (positions-pushes)"  # the same seeds under pushes, no filter
FILTERED_SECTION = "mcpilco/UR10-v0 (positions-pushes-filtered)"  # pushes, push filter on
KERNELS_SECTION = "UR10-v0_positions"  # the kernel comparison on the shipped task's runs
CONTROL_SECTIONS = {  # the same seeds learned with each kernel: label -> section
    "RBF + MPK (p = 1)": TRACKING_SECTION,
    "RBF": "mcpilco/UR10-v0 (positions-rbf)",
    "rigid body": "mcpilco/UR10-v0 (positions-rigid)",
}


def tracking_figure(sec: dict[str, Any]) -> str:
    """The tracking RMS after a section's last policy trial against the controller alone:
    all joints and per joint."""
    last = sec["tracking"][-1]
    tot = overall(sec, len(sec["tracking"]) - 1)
    ratios = " / ".join(f"{q:.2f}" for q in last["ratio_mean"])
    n = len(sec["seeds"])
    ideal = (
        f" (the known-model feed-forward: {last['feedforward_halved']})"
        if "feedforward_halved" in last
        else ""
    )
    return (
        f"after {last['experience_s']:.0f} s of experience: all joints "
        f"{tot['ratio']:.2f} x the PD + gravity controller's error (halved in "
        f"{tot['halved']} of {n} seeds); per joint {ratios}; every joint halved in "
        f"{last['seeds_halved']} of {n} seeds{ideal}"
    )


def _tracking_row(r: Result) -> str:
    return "UR10 tracking " + tracking_figure(r["runs"][TRACKING_SECTION])


def _pushes_row(r: Result) -> str:
    sec, unfiltered = r["runs"][FILTERED_SECTION], r["runs"][PUSHES_SECTION]
    k = len(unfiltered["tracking"]) - 1
    return (
        "UR10 tracking under pushes, push filter on, "
        + tracking_figure(sec)
        + f"; without the filter all joints {overall(unfiltered, k)['ratio']:.2f} x"
    )


def _kernels_row(r: Result) -> str:
    from mcpilco.experiments.mcpilco.rmse import KERNEL_ARGS

    rows = r["kernels"][KERNELS_SECTION]["kernels"]
    cells = ", ".join(
        f"{kernel_label(**KERNEL_ARGS[k])} {1e3 * v['all_joints_mean']:.1f}"
        for k, v in rows.items()
    )
    halved = ", ".join(
        f"{name} "
        + " / ".join(str(row["seeds_halved"]) for row in r["runs"][key]["tracking"])
        + f" of {len(r['runs'][key]['seeds'])}"
        for name, key in CONTROL_SECTIONS.items()
    )
    return (
        "UR10 multi-step prediction RMSE over 4 s, all joints [mrad], GPs of the position and "
        f"velocity changes: {cells}; control, seeds with every joint's tracking error halved "
        f"after policy trials 1 / 2 / 3: {halved}"
    )


def _section_seeds(key: str) -> Callable[[Result], str]:
    return lambda r: seed_ranges(r["runs"][key]["seeds"])


HEADLINES = (
    Headline(
        "MC-PILCO, UR10 tracking",
        f"{RESULTS_NAME}.json",
        _tracking_row,
        f"{RESULTS_NAME}.md",
        part=TRACKING_SECTION,
        seeds=_section_seeds(TRACKING_SECTION),
    ),
    Headline(
        "MC-PILCO, UR10 tracking under pushes",
        f"{RESULTS_NAME}.json",
        _pushes_row,
        f"{RESULTS_NAME}.md",
        part=FILTERED_SECTION,
        seeds=_section_seeds(FILTERED_SECTION),
    ),
    Headline(
        "MC-PILCO, UR10 GP kernels",
        f"{RESULTS_NAME}.json",
        _kernels_row,
        f"{RESULTS_NAME}.md",
        part=kernels_entry(KERNELS_SECTION),
        seeds=lambda r: seed_ranges(x["seed"] for x in r["kernels"][KERNELS_SECTION]["per_run"]),
    ),
)
"""The tracking benchmark's rows of the results index."""
