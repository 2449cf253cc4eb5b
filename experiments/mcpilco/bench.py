"""The MC-PILCO benchmark of ``mcpilco-bench-mcpilco``: its four parts and its report.

1. ``runs``: S seeds of the whole loop (exploration + policy trials) per env; per trial the
   success rate, mean time in the goal region, cost, wall-clock per trial and per
   optimisation step (:func:`bench_runs`). Seeds are sweep jobs
   (:mod:`mcpilco.experiments.infra.sweep`) with one torch thread each; a finished seed is read
   back, not rerun. :func:`pool_sections` merges sections of the same config run on other
   seeds into one section over all of them.
2. ``timing``: seconds per policy optimisation step for several GP sizes, particle counts
   and thread counts (:func:`timing_part`, :mod:`mcpilco.experiments.mcpilco.timing`).
3. ``rmse``: RBF+MPK vs RBF-only particle RMSE of theta on exploration data (thesis
   Fig. 5.5; :func:`rmse_part`, :mod:`mcpilco.experiments.mcpilco.rmse`).
4. ``rmse_runs``: the same comparison on the data of finished runs (:func:`rmse_runs_part`).

Results live in one JSON file, ``mcpilco_cartpole.json`` (one runs section per env and
label, merged with the file found), with a Markdown report and plots next to it
(:func:`write_report`).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.agents.mc_pilco import DEFAULT_ENV_ID, MCPilcoConfig, load_config
from mcpilco.experiments.infra.sweep import Job, SweepReport, SweepRunner
from mcpilco.experiments.results import (
    Headline,
    Result,
    ResultLayout,
    percent,
    rate,
    read_result,
    seed_ranges,
    write_result,
)

PARTS = ("runs", "timing", "rmse", "rmse_runs")  # the parts, in the order they run
RESULTS_NAME = "mcpilco_cartpole"  # stem of the JSON, Markdown and PNG outputs

__all__ = [
    "PARTS",
    "POOLED_MEANS",
    "aggregate_runs",
    "bench_configs",
    "bench_runs",
    "load_results",
    "make_section",
    "pool_part",
    "pool_sections",
    "rmse_part",
    "rmse_runs_part",
    "run_seed",
    "runs_part",
    "section_key",
    "section_table",
    "stage_table",
    "reference_step",
    "reference_table",
    "timing_key",
    "timing_part",
    "timing_row",
    "write_report",
]


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
    from mcpilco.agents.mc_pilco import Trainer
    from mcpilco.models.device import retain_host_memory

    retain_host_memory()
    cfg = MCPilcoConfig.from_dict(config)
    summary = Trainer(
        cfg,
        out,
        resume=(Path(out) / "checkpoint.pt").is_file(),
        overwrite=not (Path(out) / "checkpoint.pt").is_file(),  # the seed's own folder
        progress=False,
        log=None,
        write_rrd=False,
    ).run()
    seconds = float(sum(r["wall_s"] for r in summary.records))
    return {"seed": cfg.seed, "records": summary.records, "seconds": seconds}


def aggregate_runs(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per trial index: success rate (with its 95 % Wilson interval over the seeds), mean
    time in the goal region, timings over seeds."""
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
            "success_ci95": rate(sum(bool(r["success"]) for r in recs), len(recs))["ci95"],
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
            predicted = [
                r["predicted_success"] for r in recs if r.get("predicted_success") is not None
            ]
            if predicted:  # the model's success rate of the applied policies (mean)
                row["predicted_success"] = float(np.mean(predicted))
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
        # a field the saved section lacks (e.g. explore_hold) takes its default
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
        if "success_rate" in row:  # the pooled count of successes, exact as the mean is
            row["success_ci95"] = rate(round(row["success_rate"] * total), total)["ci95"]
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


# ------------------------------------------------------------------------------ parts
def bench_configs(
    env_ids: Sequence[str],
    preset: str = "bench",
    task_overrides: dict[str, Any] | None = None,
    **options: Any,
) -> dict[str, MCPilcoConfig]:
    """One config per env: the env's file and ``preset``, then ``options``
    (:meth:`MCPilcoConfig.with_overrides` keywords; None keeps the env's value, so an env
    keeps its own exploration hold unless one is given). ``candidate_weight_scales``
    without ``num_candidates`` sets the number of candidates. ``task_overrides`` replaces
    fields of each env's shipped task (a task variant, e.g. ``{"speed_integration": True}``),
    which the config then carries as its ``task``.

    Raises:
        ValueError: an env without a shipped task, an unknown preset, a bad value, a device
            this machine lacks, ``compile_rollout`` without a C++ compiler.
    """
    from mcpilco.agents.mc_pilco.trainer import check_compile_toolchain
    from mcpilco.envs.tasks import task_ids
    from mcpilco.models.device import resolve_device

    ids = task_ids()
    for env_id in env_ids:
        if env_id not in ids:
            raise ValueError(f"no task ships for env id {env_id!r}; tasks: {', '.join(ids)}")
    scales = options.get("candidate_weight_scales")
    if options.get("num_candidates") is None and scales:
        options["num_candidates"] = len(scales)
    configs = {
        env_id: load_config(env_id, preset=preset).with_overrides(**options) for env_id in env_ids
    }
    if task_overrides:
        from mcpilco.envs.tasks import task_data

        for env_id, cfg in configs.items():
            configs[env_id] = cfg.with_overrides(task={**task_data(env_id), **task_overrides})
            configs[env_id].task_spec()  # a bad field is an error here, not in every job
    device = options.get("device") or "cpu"
    if options.get("compile_rollout"):
        for config in configs.values():
            check_compile_toolchain(resolve_device(device), config.rollout_backend)
    resolve_device(device)
    return configs


def load_results(out_dir: Path, name: str = RESULTS_NAME) -> dict[str, Any]:
    """The results in ``out_dir/<name>.json`` (default ``mcpilco_cartpole.json``; empty when
    there is none yet)."""
    path = Path(out_dir) / f"{name}.json"
    return read_result(path).payload() if path.is_file() else {}


def runs_part(
    results: dict[str, Any],
    configs: dict[str, MCPilcoConfig],
    seeds: Sequence[int],
    runner: SweepRunner,
    runs_dir: Path,
    out_dir: Path,
    label: str = "",
    log: Callable[[str], None] = print,
) -> int:
    """Part ``runs``: the seeds of each config (:func:`bench_runs`) in
    ``runs_dir/<env name>[_<label>]``, each env's section stored under
    :func:`section_key` and the report written after each env. Returns the number of
    failed seeds."""
    failed = 0
    results.setdefault("runs", {})
    for env_id, cfg in configs.items():
        tag = env_id.split("/")[-1] + (f"_{label}" if label else "")
        key = section_key(env_id, label)
        section, sweep = bench_runs(cfg, list(seeds), runner, Path(runs_dir) / tag)
        log(sweep.summary())
        failed += len(sweep.failed)
        if section is None:
            continue
        results["runs"][key] = section
        log(section_table(key, section))
        write_report(results, out_dir)
    return failed


def timing_part(
    results: dict[str, Any],
    out_dir: Path,
    n_points: Sequence[int],
    threads: Sequence[int],
    particles: Sequence[int],
    device: str = "cpu",
    compile_rollout: bool = False,
    heap_contrast: bool = False,
    env_ids: Sequence[str] = (DEFAULT_ENV_ID,),
    append: bool = False,
    log: Callable[[str], None] = print,
    kernel: str | None = None,
    mpk_degree: int | None = None,
    variants: Sequence[str] | None = None,
    reference_repo: Path | None = None,
) -> list[dict[str, Any]]:
    """Part ``timing``: :func:`~mcpilco.experiments.mcpilco.timing.time_opt_step` for every
    task spec (``env_ids``, each over its own horizon and with its config's GP kernel), GP
    size, thread count and particle count (on a CUDA device both with and without a CUDA
    graph; ``kernel``, ``mpk_degree``: instead of the config's); replaces
    ``results["timing"]`` (``append``: only the rows timed again now, :func:`timing_key`)
    and writes the report. ``env_ids`` may name a timing spec of
    :func:`~mcpilco.experiments.mcpilco.timing.timing_task` (it uses its env's config);
    ``variants``: the fast steps to time (None: all of
    :data:`~mcpilco.experiments.mcpilco.timing.VARIANTS`). ``reference_repo``: a checkout of
    the reference implementation, whose own step is timed in the same rounds as every row
    (:mod:`~mcpilco.experiments.mcpilco.reference`) and recorded in
    ``results["reference_steps"]`` too, where the reference table divides the row's step
    into it."""
    from mcpilco.experiments.mcpilco.timing import VARIANTS, time_opt_step, timing_task

    rows = []
    graphs = (True, False) if device.startswith("cuda") else (False,)
    grid = [
        (e, n, th, m, g)
        for e in env_ids
        for n in n_points
        for th in threads
        for m in particles
        for g in graphs
    ]
    # each spec's GP as its config fits it, or as the arguments say
    configs = {
        e: load_config(timing_task(e)[1]).with_overrides(kernel=kernel, mpk_degree=mpk_degree)
        for e in env_ids
    }
    for env_id, n, th, m, graph in grid:
        cfg = configs[env_id]
        t = time_opt_step(
            n, num_particles=m, threads=th, device=device, cuda_graph=graph,
            compile_rollout=compile_rollout, heap_contrast=heap_contrast, env_id=env_id,
            kernel=cfg.kernel, mpk_degree=cfg.mpk_degree,
            variants=tuple(VARIANTS if variants is None else variants),
            reference_repo=None if reference_repo is None else str(reference_repo),
        )  # fmt: skip
        comp = t.get("compiled_s_per_step_wall")
        log(
            f"{env_id} N={n} M={m} threads={th} device={t['device']} "
            f"graph={t['cuda_graph']}: {t['s_per_step_wall']:.3f} s/step wall"
            + (f", compiled {comp:.3f}" if comp is not None else "")
            + (", compiled step rejected" if t.get("compiled_rejected") else "")
            + (
                f", 128 KiB heap {t['heap128k_s_per_step_wall']:.3f}"
                if "heap128k_s_per_step_wall" in t
                else ""
            )
            + (
                f", reference ({t['reference_task']}) {t['reference_s_per_step_wall']:.3f}"
                if "reference_s_per_step_wall" in t
                else ""
            )
        )
        rows.append(t)
    if append:  # keep the rows not timed again now
        timed = {timing_key(t) for t in rows}
        kept = [t for t in results.get("timing", []) if timing_key(t) not in timed]
        results["timing"] = kept + rows
    else:
        results["timing"] = rows
    measured = [reference_step(t) for t in rows if "reference_s_per_step_wall" in t]
    if measured:  # replaces the reference's steps timed again now
        key = lambda m: (m["env_id"], m["n_points"], m["num_particles"], m["threads"])  # noqa: E731
        timed = {key(m) for m in measured}
        kept = [m for m in results.get("reference_steps", []) if key(m) not in timed]
        results["reference_steps"] = kept + measured
    write_report(results, out_dir)
    return rows


REFERENCE_TASK_NAMES = {"ur5": "UR5", "cartpole": "cart-pole"}  # the reference's tasks' names


def reference_step(t: dict) -> dict[str, Any]:
    """The entry of ``results["reference_steps"]`` for a timing row ``t`` with the
    reference's own step timed beside it (:func:`reference_table`)."""
    return {
        "env_id": t["env_id"],
        "task": REFERENCE_TASK_NAMES.get(t["reference_task"], t["reference_task"]),
        "n_points": t["n_points"],
        "num_particles": t["num_particles"],
        "threads": t["threads"],
        "s_per_step": t["reference_s_per_step_wall"],
        "reference_n_points": t["reference_n_points"],
        "data": t["reference_data"],
        "same_run": True,
    }


def rmse_part(
    results: dict[str, Any],
    out_dir: Path,
    seeds: int,
    policy_ckpt: Path | None = None,
    runs_dir: Path | None = None,
    explore_hold: int | None = None,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Part ``rmse``: :func:`~mcpilco.experiments.mcpilco.rmse.particle_rmse` on ``seeds``
    exploration seeds of the default env (actions held ``explore_hold`` steps, default: its
    config's), under the policy of ``policy_ckpt`` (default: the first run under
    ``runs_dir`` whose last trial swung up); writes the plot ``mcpilco_cartpole_rmse.png``
    (which alone keeps the particles), stores the summary in ``results["rmse"]`` and writes
    the report.

    Raises:
        FileNotFoundError: no policy given and no run under ``runs_dir`` swung up.
    """
    from mcpilco.experiments.mcpilco.rmse import (
        find_swingup_policy,
        particle_rmse,
        plot_rmse,
        summarise_rmse,
    )

    if policy_ckpt is None:
        policy_ckpt = find_swingup_policy(Path(runs_dir or "."))
    if explore_hold is None:
        explore_hold = load_config(DEFAULT_ENV_ID).explore_hold
    per_seed = [particle_rmse(s, policy_ckpt, explore_hold=explore_hold) for s in range(seeds)]
    rm = summarise_rmse(per_seed)
    rm.update(policy=str(policy_ckpt), explore_hold=explore_hold)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    plot_rmse(rm, out_dir / f"{RESULTS_NAME}_rmse.png")
    for p in rm["per_seed"]:  # keep the JSON small: particles only in the plot
        for k in list(p):
            if k.endswith("_particles"):
                del p[k]
    results["rmse"] = rm
    log(f"theta RMSE: rbf+mpk {rm['rbf+mpk']}, rbf {rm['rbf']}")
    write_report(results, out_dir)
    return rm


def rmse_runs_part(
    results: dict[str, Any],
    out_dir: Path,
    run_dirs: Sequence[Path],
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Part ``rmse_runs``: :func:`~mcpilco.experiments.mcpilco.rmse.particle_rmse_on_run` on
    every run under ``run_dirs`` whose last trial swung up, summarised per group (the kernel
    a run learned with, its env); writes ``mcpilco_cartpole_rmse_runs.png`` (which alone
    keeps the per-step curves), stores ``results["rmse_runs"]`` and writes the report.

    Raises:
        ValueError: no such run under ``run_dirs``.
    """
    from tqdm.auto import tqdm

    from mcpilco.experiments.mcpilco.rmse import (
        particle_rmse_on_run,
        plot_rmse_runs,
        summarise_rmse_runs,
        swingup_runs,
    )

    ckpts = [c for d in run_dirs for c in swingup_runs(d)]
    if not ckpts:
        raise ValueError("rmse_runs: no run whose last trial swung up; run the 'runs' part first")
    per_run = [particle_rmse_on_run(c) for c in tqdm(ckpts, desc="rmse on runs")]
    groups = summarise_rmse_runs(per_run)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    plot_rmse_runs(per_run, out_dir / f"{RESULTS_NAME}_rmse_runs.png")
    for r in per_run:  # keep the JSON small: per-step curves only in the plot
        for k in ("rbf+mpk", "rbf"):
            del r[f"{k}_per_step"]
    results["rmse_runs"] = {"per_run": per_run, "groups": groups}
    for kern, g in groups.items():
        log(f"runs learned with {kern}: {g}")
    write_report(results, out_dir)
    return results["rmse_runs"]


def pool_part(
    results: dict[str, Any],
    out_dir: Path,
    env_ids: Sequence[str],
    labels: Sequence[str],
    log: Callable[[str], None] = print,
) -> list[str]:
    """Pool the sections labelled ``labels`` of each env (:func:`pool_sections`) into a
    section labelled ``LABEL1+LABEL2...``; writes the report and returns the new keys.

    Raises:
        ValueError: a missing section, or sections that may not be pooled.
    """
    sections = results.setdefault("runs", {})
    pooled_keys = []
    for env_id in env_ids:
        keys = [section_key(env_id, label) for label in labels]
        missing = [k for k in keys if k not in sections]
        if missing:
            raise ValueError(
                f"--pool: no section {missing} in {Path(out_dir) / f'{RESULTS_NAME}.json'}; "
                f"have {list(sections)}"
            )
        try:
            pooled = pool_sections([sections[k] for k in keys])
        except ValueError as err:
            raise ValueError(f"--pool: {err}") from None
        key = section_key(env_id, "+".join(labels))
        sections[key] = pooled
        pooled_keys.append(key)
        log(section_table(key, pooled))
    write_report(results, out_dir)
    return pooled_keys


# ------------------------------------------------------------------------------ report
def section_table(env_id: str, section: dict) -> str:
    """The Markdown table of a runs section (:func:`make_section` or :func:`pool_sections`)
    under the heading ``env_id``: its config in one paragraph, then one row per trial."""
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
        pooled + f"{len(seeds)} seeds ({seed_ranges(seeds)}); M={cfg['num_particles']} particles, "
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
    # sections measured before trials recorded time in goal keep their time upright
    goal_key, goal_name = "time_in_goal_s", "time in goal"
    if not any(goal_key in r for r in section["per_trial"]):
        if any("time_upright_s" in r for r in section["per_trial"]):
            goal_key, goal_name = "time_upright_s", "time upright"
    lines += [
        "",
        f"| experience | policy trained on | success rate [95 % Wilson] | {goal_name} [s] "
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
        n = r.get("seeds", len(seeds))
        lo, hi = rate(round(r["success_rate"] * n), n)["ci95"]
        lines.append(
            f"| {r['experience_s']:.0f} s ({kind}) | {trained} "
            f"| {100 * r['success_rate']:.0f}% [{100 * lo:.0f}-{100 * hi:.0f}] "
            f"| {_fmt(r.get(goal_key))} | {r['wall_s_per_trial']:.1f} "
            f"| {r.get('opt_steps', 0):.0f} | {r.get('s_per_opt_step', float('nan')):.3f} "
            f"| {r.get('cpu_s_per_opt_step', float('nan')):.3f} |"
        )
    return "\n".join(lines) + "\n"


CONVENTION_NOTE = (
    "Rows: `experience` counts the seconds of interaction up to the end of that trial (the "
    "trial included); `policy trained on` is the data the trial's policy was optimised on. "
    "Thesis Table 5.1 indexes its columns by the latter (its 3.8 % at 3 s is a policy trial, "
    "not the random exploration)."
)


def timing_spec(t: dict) -> tuple[str, str, int | None]:
    """A timing row's task spec and GP kernel: ``(env_id, kernel, mpk_degree)``; rows saved
    before specs and kernels were recorded are the cart-pole's with RBF + degree-2 MPK."""
    kernel = t.get("kernel", "rbf+mpk")
    return t.get("env_id", DEFAULT_ENV_ID), kernel, t.get("mpk_degree", 2)


def timing_key(t: dict) -> tuple:
    """What makes two timing rows the same measurement: the spec and kernel
    (:func:`timing_spec`), ``N``, particles, threads, device and CUDA graph."""
    return (
        *timing_spec(t), t["n_points"], t["num_particles"], t["threads"],
        t.get("device", "cpu"), bool(t.get("cuda_graph")),
    )  # fmt: skip


def kernel_label(kernel: str, mpk_degree: int | None = None) -> str:
    """A kernel's name in the reports: ``"rbf+mpk"`` with its degree (``"RBF + MPK
    (p = 1)"``), ``"RBF"``, ``"rigid body"``."""
    if kernel == "rbf+mpk":
        return f"RBF + MPK (p = {mpk_degree})"
    return {"rbf": "RBF", "rigid_body": "rigid body"}.get(kernel, kernel)


def timing_row(t: dict) -> str:
    """One row of a spec's timing table (:func:`write_report`) for a result of
    :func:`~mcpilco.experiments.mcpilco.timing.time_opt_step`."""
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
    if "torch_s_per_step_wall" in t:
        comp += f" | {t['torch_s_per_step_wall']:.3f} | {t['torch_s_per_step_cpu']:.3f}"
    else:
        comp += " | - | -"
    if "dynamo_s_per_step_wall" in t:
        comp += f" | {t['dynamo_s_per_step_wall']:.3f} | {t['dynamo_s_per_step_cpu']:.3f}"
    else:
        comp += " | - | -"
    comp += f" | {t['avx2_s_per_step_wall']:.3f}" if "avx2_s_per_step_wall" in t else " | -"
    if "reference_s_per_step_wall" in t:
        comp += f" | {t['reference_s_per_step_wall']:.3f} ({t['reference_task']})"
    else:
        comp += " | -"
    faults = t.get("page_faults_per_step")
    heap = "| - | -"
    if "heap128k_s_per_step_wall" in t:
        heap = f"| {t['heap128k_s_per_step_wall']:.3f} | {t['heap128k_page_faults_per_step']:.0f}"
    if "floor_s" in t:
        heap += f" | {t['floor_s']:.4f} | {t['matmul_gflops']:.0f}"
    else:
        heap += " | - | -"
    heap += f" | {t['products_floor_s']:.3f}" if "products_floor_s" in t else " | -"
    heap += f" | {t['cpu_model']} ({t['cpu_isa']})" if "cpu_model" in t else " | -"
    return (
        f"| {t['num_particles']} | {t['n_points']} | {t.get('device', 'cpu')} | {graph} "
        f"| {t['threads']} | {t['s_per_step_wall']:.3f} | {t['s_per_step_cpu']:.3f} "
        f"| {'-' if faults is None else f'{faults:.0f}'} {comp} {heap} |"
    )


def stage_table(timing: list[dict]) -> list[str]:
    """Markdown lines: where the ``native`` step's time goes, for every timing row that
    recorded it (``native_stage_s``, ``native_stage_floor_s`` of
    :func:`~mcpilco.experiments.mcpilco.timing.time_opt_step`): each stage that runs products
    with the GP's constant matrices, its seconds per step (summed over the threads) and how
    many times its floor that is, then the rest of the loops (policy, sampling, cost)."""
    rows = [t for t in timing if t.get("native_stage_floor_s") and t.get("native_stage_s")]
    if not rows:
        return []
    stages = list(rows[0]["native_stage_floor_s"])
    md = [
        "### Where the `native` step's time goes",
        "",
        "Seconds per step of each stage of the `native` loops that runs products with the GP's "
        "constant matrices (the engine's stage clocks, summed over its threads) and, in "
        "brackets, that time over the stage's floor (its flops at the row's matmul rate per "
        "thread, summed over the threads likewise); "
        "rest: the other stages (policy, GP inputs, sampling, integration, cost).",
        "",
        "| spec | N | M | threads | " + " | ".join(stages) + " | rest | all stages |",
        "|---|---|---|---|" + "---|" * (len(stages) + 2),
    ]
    for t in rows:
        sec, floor = t["native_stage_s"], t["native_stage_floor_s"]
        cells = [
            f"{sec.get(s, 0.0):.3f} ({sec.get(s, 0.0) / floor[s]:.1f}x)" if floor[s] else "-"
            for s in stages
        ]
        rest = sum(v for s, v in sec.items() if s not in floor)
        md.append(
            f"| {timing_spec(t)[0]} | {t['n_points']} | {t['num_particles']} | {t['threads']} "
            f"| {' | '.join(cells)} | {rest:.3f} | {sum(sec.values()):.3f} |"
        )
    return [*md, ""]


def _ratio(x: float) -> str:
    """A speed-up ratio: whole numbers from 10 on, two significant digits below."""
    return f"{x:.0f}" if x >= 10 else f"{x:.2g}"


def reference_table(timing: list[dict], measured: Sequence[dict] = ()) -> list[str]:
    """Markdown lines: every timed step (the fast rollout's where there is one, else the
    eager one) against the reference implementation's seconds per step, with its floor.

    ``measured``: the reference's own steps timed on this machine on a comparable task
    (``env_id`` of the package's spec, ``task``: the reference's, ``n_points``,
    ``num_particles``, ``threads``, ``s_per_step``); a row with the same spec, N, M and
    threads is divided into that step, any other cart-pole row into the cart-pole range
    (:data:`~mcpilco.experiments.mcpilco.timing.REFERENCE_S_PER_STEP`); other rows get no
    ratio."""
    from mcpilco.experiments.mcpilco.timing import REFERENCE_S_PER_STEP, reference_speedup

    lo, hi = REFERENCE_S_PER_STEP
    own = {(m["env_id"], m["n_points"], m["num_particles"], m["threads"]): m for m in measured}
    md = [
        "### Against the reference implementation",
        "",
        f"The reference implementation (merlresearch/MC-PILCO) takes {lo:.2f}-{hi:.2f} s per "
        "optimisation step on the cart-pole at N = 60 GP points and 400 particles on this "
        "machine class; each step here (the fast rollout's, else the eager one, wall clock) "
        "is divided into that range, or into the reference's own step on a comparable task "
        "where one was timed with the same N, particles and threads (its task and seconds "
        "in brackets; a row of another spec without one has no ratio). The cart-pole range "
        "holds for N = 60: at larger N the reference takes longer, so that ratio understates "
        "the speed-up.",
        "",
        "| spec | particles M | GP points N | threads | step | wall s/step | CPU s/step "
        "| floor s/step | x reference |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for t in timing:
        env_id, kernel, degree = timing_spec(t)
        fast = "compiled_s_per_step_wall" in t
        key = "compiled_" if fast else ""
        wall, cpu = t[f"{key}s_per_step_wall"], t[f"{key}s_per_step_cpu"]
        step = t.get("compile_backend") if fast else "eager"
        floor = f"{t['floor_s']:.4f}" if "floor_s" in t else "-"
        ref = own.get((env_id, t["n_points"], t["num_particles"], t["threads"]))
        if ref is not None:
            ratio = (
                f"{_ratio(ref['s_per_step'] / wall)}x ({ref['task']}: {ref['s_per_step']:.2f} s)"
            )
        elif env_id == DEFAULT_ENV_ID:
            a, b = reference_speedup(wall)
            ratio = f"{_ratio(a)}-{_ratio(b)}x"
        else:  # no reference step timed for this spec
            ratio = "-"
        md.append(
            f"| {env_id} ({kernel_label(kernel, degree)}) | {t['num_particles']} "
            f"| {t['n_points']} | {t['threads']} | {step} | {wall:.3f} | {cpu:.3f} | {floor} "
            f"| {ratio} |"
        )
    md.append("")
    return md


def write_report(results: dict, out_dir: Path) -> None:
    """``mcpilco_cartpole.md``, ``.json`` and (with runs) the figures of ``results`` in
    ``out_dir``: one table per runs section, the timing table, the two RMSE tables;
    ``mcpilco_cartpole_sections.png`` shows every section's success rate and time in goal
    against experience, ``mcpilco_cartpole.png`` the headline (:func:`replot`)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    md = ["# MC-PILCO on the cartpole swing-up", "", CONVENTION_NOTE, ""]
    if results.get("machine"):
        md += [f"Machine: {results['machine']}.", ""]
    for env_id, section in results.get("runs", {}).items():
        md.append(section_table(env_id, section))
    if results.get("timing"):
        md += [
            "### Seconds per optimisation step",
            "",
            "One table per task spec (its states n, actions A, GP outputs m and horizon H).",
            "",
            "A step at a few particles is the fixed cost of the H-step rollout (one op after "
            "another, forward and backward); the rest grows with M.",
            "",
            "Fast: the same step with the fast rollout (`--compile-rollout`) of the default "
            "backend (column backend; `native`: the whole rollout, forward and backward, in "
            "the package's C++ loop), alternating with the eager step in each round; build s: "
            "building it and its check against the eager rollout; shards: the threads a "
            "rollout is split over, by particles (two threads: 2 at 400 particles, 1 at 25). "
            "Torch: the same chained maths in PyTorch ops (backend `torch`) in the same "
            "rounds, where the default is `native`. Dynamo: the time step `torch.compile`-d "
            "instead, in the same rounds. Avx2 build: the `native` rollout built for AVX2 "
            "without AVX-512 (x86-64-v3), in the same rounds. Reference: the reference "
            "implementation's own step on its matching task (`--reference-repo`), in the same "
            "rounds. Floor: the flops of the GP posterior variance "
            "(2 N^2 per particle, output and step, forward and backward) at this machine's "
            "float32 matmul rate (column GFLOP/s, 512 x 512 product on the same threads); "
            "products floor: every product with the GP's constant matrices (the RBF's "
            "exponents, the MPK's feature block, the triangular factor; forward and backward) "
            "at that rate. CPU: the model and its vector ISA; the JSON rows hold the native "
            "build's compiler and flags (`-march=native`: built for that CPU) and, for the "
            "`native` step, the seconds of each stage of its loops.",
            "",
            "Faults: minor page faults per step, with the freed memory kept in the process "
            "(`retain_host_memory`). 128 KiB heap: the eager step with glibc's initial "
            "allocator thresholds instead (`--timing-heap-contrast`), in the same rounds.",
            "",
        ]
        groups: dict[tuple, list[dict]] = {}
        for t in results["timing"]:
            groups.setdefault(timing_spec(t), []).append(t)
        for (env_id, kernel, degree), rows in groups.items():
            t0 = rows[0]
            shape = (
                f"n = {t0['state_dim']}, A = {t0['action_dim']}, m = {t0['gp_outputs']}, "
                if "state_dim" in t0
                else ""
            )
            md += [
                f"#### {env_id} ({shape}H = {t0.get('horizon', 60)}; GP "
                f"{kernel_label(kernel, degree)})",
                "",
                "| particles M | GP points N | device | CUDA graph | threads | wall s/step "
                "| CPU s/step | faults | fast: backend | wall s/step | CPU s/step "
                "| speed-up (CPU) | build s | shards | torch: wall s/step | CPU s/step "
                "| dynamo: wall s/step | CPU s/step | avx2 build: wall s/step "
                "| reference: wall s/step | 128 KiB heap: wall s/step | faults "
                "| floor s/step | GFLOP/s | products floor s/step | CPU |",
                "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
                "---|---|---|---|---|---|",
            ]
            md += [timing_row(t) for t in rows]
            md.append("")
        md += stage_table(results["timing"])
        md += reference_table(results["timing"], results.get("reference_steps", ()))
        if results.get("reference_steps_note"):
            md += [f"The reference's own steps: {results['reference_steps_note']}.", ""]
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
    (out_dir / f"{RESULTS_NAME}.md").write_text("\n".join(md))
    write_result(out_dir / f"{RESULTS_NAME}.json", RESULT_LAYOUTS[0], results)
    if results.get("runs"):
        json_path = out_dir / f"{RESULTS_NAME}.json"
        replot(read_result(json_path), json_path)


def plot_sections(results: dict[str, Any], path: Path) -> Path:
    """Success rate and time in goal against experience, one curve per runs section (the lab
    figure of the Markdown report; the headline is :mod:`mcpilco.experiments.mcpilco.figures`)."""
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
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def replot(result: Result, json_path: Path) -> list[Path]:
    """Redraw the figures of an MC-PILCO result file next to it: the sections figure and,
    when the headline's sections are there, the headline figure (the RMSE parts' figures
    need the particles and per-step errors, which the file does not hold)."""
    from mcpilco.experiments.mcpilco.figures import HEADLINE_SECTIONS, replot_headline

    out_dir = Path(json_path).parent
    stem = Path(json_path).stem
    paths = []
    if result.get("runs"):
        paths.append(plot_sections(result.payload(), out_dir / f"{stem}_sections.png"))
        if all(key in result["runs"] for key, _, _ in HEADLINE_SECTIONS):
            paths.append(replot_headline(out_dir))
    return paths


# -- result file and headline rows of the results index -----------------------------------

RESULT_LAYOUTS = (
    ResultLayout(
        "mcpilco",
        config=("note", "reference_steps_note"),
        cases=("runs", "rmse_runs"),
        seeds=lambda p: [s for sec in p.get("runs", {}).values() for s in sec.get("seeds", ())],
    ),
)
"""The layout of ``mcpilco_cartpole.json`` (:mod:`mcpilco.experiments.results`)."""

DEFAULT_LABEL = "hold2"  # the runs of the bench preset with held exploration (the default)
NATIVE_LABEL = "native"  # the same runs with the compiled rollout
FRESH_LABEL = "fresh100"  # seeds 100-119, on which no setting was chosen
DMC_SECTION = "mcpilco/DMCCartpoleSwingUp-v0 (snap140)"  # the dm-control headline's section


def run_section(result: Result, label: str) -> dict[str, Any]:
    """The cart-pole runs section written with ``--label label``."""
    return result["runs"][section_key(DEFAULT_ENV_ID, label)]


def success_at(section: dict[str, Any]) -> dict[float, float]:
    """Experience [s] -> success rate of a runs section."""
    return {r["experience_s"]: r["success_rate"] for r in section["per_trial"]}


def _default_row(r: Result) -> str:
    s = success_at(run_section(r, DEFAULT_LABEL))
    return (
        f"swing-up success {percent(s[12.0])} after 12 s and {percent(s[15.0])} after 15 s of "
        "experience (bench preset, held exploration)"
    )


def _native_row(r: Result) -> str:
    s = success_at(run_section(r, NATIVE_LABEL))
    return f"rollout compiled (`native`): success {percent(s[12.0])} after 12 s of experience"


def _fresh_row(r: Result) -> str:
    s = success_at(run_section(r, FRESH_LABEL))
    return (
        f"on seeds no setting was chosen on (`native` rollout): success {percent(s[9.0])} / "
        f"{percent(s[12.0])} / {percent(s[15.0])} after 9 / 12 / 15 s of experience"
    )


def _dmc_row(r: Result) -> str:
    s = success_at(r["runs"][DMC_SECTION])
    return (
        f"dm-control's cart-pole (end stops declared), seeds no setting was chosen on: success "
        f"{percent(s[7.0])} / {percent(s[11.0])} / {percent(s[15.0])} after 7 / 11 / 15 s of "
        "experience"
    )


def _step_row(r: Result) -> str:
    timing = r["timing"]
    row = next(  # the cart-pole's row (arm specs time the same N, M and threads)
        t
        for t in timing
        if t["n_points"] == 100 and t["num_particles"] == 400 and t["threads"] == 2
        and t.get("env_id", DEFAULT_ENV_ID) == DEFAULT_ENV_ID
    )  # fmt: skip
    line = (
        f"{row['compiled_s_per_step_wall']:.3f} s per policy-optimisation step "
        f"(`{row['compile_backend']}`, 400 particles, N = 100, 2 threads; eager "
        f"{row['s_per_step_wall']:.3f} s)"
    )
    large = [  # the cart-pole at the bench preset's largest GP
        t
        for t in timing
        if t["n_points"] == 250 and t["num_particles"] == 400 and t["threads"] == 2
        and t.get("env_id", row.get("env_id")) == row.get("env_id")
        and "compiled_s_per_step_wall" in t
    ]  # fmt: skip
    if large:
        line += f", {large[0]['compiled_s_per_step_wall']:.3f} s at N = 250"
    own = {  # the reference's own steps, by spec, N, particles and threads
        (m["env_id"], m["n_points"], m["num_particles"], m["threads"]): m["s_per_step"]
        for m in r.get("reference_steps", [])
    }
    key = lambda t: (t.get("env_id"), t["n_points"], t["num_particles"], t["threads"])  # noqa: E731
    ratios = [
        own[key(t)] / t["compiled_s_per_step_wall"]
        for t in timing
        if key(t) in own and t.get("mpk_degree") == 1 and "compiled_s_per_step_wall" in t
    ]
    if ratios:  # the arm spec against the reference's own arm task, same kernel
        line += (
            f"; arm spec (UR10, RBF + MPK p = 1) {min(ratios):.0f}-{max(ratios):.0f}x the "
            "reference's step on its UR5 task"
        )
    return line


def _gpu_row(r: Result) -> str:
    steps = [t["s_per_step_wall"] for t in r["timing"] if t.get("cuda_graph")]
    return f"{min(steps):.3f}-{max(steps):.3f} s per step on an H100 (400-4,000 particles)"


def _runs_seeds(label: str) -> Callable[[Result], str]:
    return lambda r: seed_ranges(run_section(r, label)["seeds"])


def _no_seeds(r: Result) -> str:
    return "-"


def _runs_part(label: str) -> str:
    return f"runs ({label})"


JSON_NAME = f"{RESULTS_NAME}.json"  # the bench's result file
HEADLINES = (
    Headline(
        "MC-PILCO, cart-pole swing-up",
        JSON_NAME,
        _default_row,
        f"{RESULTS_NAME}.md",
        part=_runs_part(DEFAULT_LABEL),
        seeds=_runs_seeds(DEFAULT_LABEL),
    ),
    Headline(
        "MC-PILCO, compiled rollout",
        JSON_NAME,
        _native_row,
        f"{RESULTS_NAME}.md",
        part=_runs_part(NATIVE_LABEL),
        seeds=_runs_seeds(NATIVE_LABEL),
    ),
    Headline(
        "MC-PILCO, fresh seeds",
        JSON_NAME,
        _fresh_row,
        f"{RESULTS_NAME}.md",
        part=_runs_part(FRESH_LABEL),
        seeds=_runs_seeds(FRESH_LABEL),
    ),
    Headline(
        "MC-PILCO, dm-control cart-pole",
        JSON_NAME,
        _dmc_row,
        f"{RESULTS_NAME}.md",
        part="runs (DMC snap140)",
        seeds=lambda r: seed_ranges(r["runs"][DMC_SECTION]["seeds"]),
    ),
    Headline(
        "MC-PILCO, speed (CPU)",
        JSON_NAME,
        _step_row,
        f"{RESULTS_NAME}.md",
        part="timing",
        seeds=_no_seeds,
    ),
    Headline(
        "MC-PILCO, speed (GPU)",
        f"h100/{JSON_NAME}",
        _gpu_row,
        f"h100/{RESULTS_NAME}.md",
        seeds=_no_seeds,
    ),
)
"""The MC-PILCO benchmark's rows of the results index."""
