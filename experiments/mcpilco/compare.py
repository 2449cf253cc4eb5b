"""The benchmark face of the comparison of MC-PILCO with PILCO and SB3 SAC / TD3 / PPO on one
task env (``mcpilco-compare``): the runs over seeds as sweep jobs, the result file, its
Markdown table and figure, and the headline rows of the results index.

The library part (one method on one seed as a learning curve, the curves aggregated over
seeds, ``T90`` / ``T100`` and the data-efficiency ratios) is
:mod:`mcpilco.agents.baselines.compare`. Here :func:`compare` collects the existing curves,
runs the missing ones as sweep jobs (:func:`run_job`) and builds the report;
:func:`write_report` writes ``compare_<env>[_<tag>].json`` (the result schema of
:mod:`mcpilco.experiments.results`), ``.md`` and ``.png``.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.agents.baselines.common import (
    load_curves,
    make_curve,
    save_curve,
    trial_records_to_points,
)
from mcpilco.agents.baselines.compare import (
    LABELS,
    SB3_METHODS,
    SUCCESS_LEVEL,
    build_report,
    covers,
    curve_path,
    run_method,
)
from mcpilco.agents.mc_pilco.trainer import check_dynamics_task
from mcpilco.envs.tasks.spec import TaskSpec
from mcpilco.envs.yaml_files import parse_yaml
from mcpilco.experiments.infra.sweep import Job, SweepRunner
from mcpilco.experiments.results import (
    Headline,
    Result,
    ResultLayout,
    read_result,
    seed_ranges,
    write_result,
)


# ------------------------------------------------------------------------------ report
def _fmt_s(v: float | None) -> str:
    return "-" if v is None else f"{v:,.0f} s" if v >= 10 else f"{v:.1f} s"


def _fmt_ratio(r: dict[str, Any]) -> str:
    if r["value"] is not None:
        return f"{r['value']:,.1f}x"
    if r["lower_bound"] is not None:
        return f"> {r['lower_bound']:,.1f}x"
    return "-"


def markdown(report: dict[str, Any]) -> str:
    """The report as Markdown: one table row per method (seeds, budget, final and best
    success, T90, ratio to MC-PILCO, compute), failed runs, then the targets met or not."""
    env_id, aggs, head = report["env_id"], report["methods"], report["headline"]
    lines = [
        f"# MC-PILCO vs baselines on {env_id}"
        + (f" ({report['tag']})" if report.get("tag") else ""),
        "",
    ]
    if report.get("note"):
        lines += [report["note"], ""]
    if report.get("command"):
        lines += [f"Command: `{report['command']}` ({report.get('measured', 'undated')})", ""]
    lines += [
        "Success = the task's success test at the episode end (`envs/tasks/`). "
        "Experience = env steps x the control period (MC-PILCO / PILCO: the steps of each "
        "trial, exploration included). Success rate: mean over seeds (MC-PILCO / PILCO: the "
        "trial's episode; SB3: 10 deterministic evaluation episodes every K steps).",
        "",
        "| method | seeds | budget | final success | best success | experience to 90% "
        "| ratio to MC-PILCO | experience to 100% (all seeds) | ratio (100%) "
        "| seeds reaching 90% (median) | compute |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for m, a in aggs.items():
        t90, t100 = (
            _fmt_s(a[key]) if a.get(key) is not None else f"not reached (> {_fmt_s(a['budget_s'])})"
            for key in ("t90_s", "t100_s")
        )
        r100 = head.get("ratios_100", {}).get(m, {"value": None, "lower_bound": None})
        comp = []
        if a.get("cpu_s_per_1k_steps") is not None:
            comp.append(f"{a['cpu_s_per_1k_steps']:.1f} CPU s / 1k steps")
        if a.get("wall_s_per_run") is not None:
            comp.append(f"{a['wall_s_per_run']:.0f} s wall / run")
        lines.append(
            f"| {LABELS.get(m, m)} | {len(a['seeds'])} | {_fmt_s(a['budget_s'])} "
            f"| {100 * a['final_success']:.0f}% | {100 * a['best_success']:.0f}% | {t90} "
            f"| {_fmt_ratio(head['ratios'][m])} | {t100} | {_fmt_ratio(r100)} "
            f"| {a['seeds_reaching_90']}/{len(a['seeds'])} ({_fmt_s(a['median_seed_t90_s'])}) "
            f"| {'; '.join(comp) or '-'} |"
        )
    for f in report.get("failed", []):
        lines.append(
            f"| {LABELS.get(f['method'], f['method'])} | seed {f['seed']} FAILED: "
            f"{f['error'][:200]} |||||||||"
        )
    finals = [set(a["final_info_median"]) for a in aggs.values()]
    keys = sorted(set.intersection(*finals)) if finals else []
    if keys:
        lines += [
            "",
            "At each method's last evaluation, the env's final `info` (median over the "
            "episodes of a seed, then over seeds):",
            "",
            "| method | experience | " + " | ".join(keys) + " |",
            "|---|---|" + "---|" * len(keys),
        ]
        for m, a in aggs.items():
            cells = " | ".join(f"{a['final_info_median'][k]:.4g}" for k in keys)
            lines.append(f"| {LABELS.get(m, m)} | {_fmt_s(a['budget_s'])} | {cells} |")
    goal = head["goal"]
    lines += ["", "Data-efficiency targets:", ""]
    if "note" in goal:
        lines.append(f"- {goal['note']}: ratios are undefined.")
    if "sb3" in goal:
        g = goal["sb3"]
        lines.append(
            f"- MC-PILCO needs >= {g['target']:.0f}x less experience than the best SB3 method "
            f"({LABELS[g['best_method']]}): measured ratio "
            f"{'> ' if g['ratio_is_lower_bound'] else ''}{g['ratio']:,.1f}x -> **{g['status']}**."
        )
    if "pilco" in goal:
        g = goal["pilco"]
        lines.append(
            f"- MC-PILCO needs less experience than TorchRL's PILCO: measured ratio "
            f"{'> ' if g['ratio_is_lower_bound'] else ''}{g['ratio']:,.2f}x -> **{g['status']}**."
        )
    return "\n".join(lines) + "\n"


def plot(report: dict[str, Any], path: Path) -> Path:
    """Success rate [%] vs experience [s] on a log x-axis, mean +- s.e.m. band per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.2))
    styles = {
        "mcpilco": ("o", "-"),
        "pilco": ("s", "-"),
        "sac": ("^", "--"),
        "td3": ("v", "-."),
        "ppo": ("D", ":"),
    }
    for m, a in report["methods"].items():
        t = np.asarray(a["experience_s"], dtype=float)
        mean = 100 * np.asarray(a["success_mean"])
        sem = 100 * np.asarray(a["success_sem"])
        keep = t > 0
        t, mean, sem = t[keep], mean[keep], sem[keep]
        if t.size == 0:
            continue
        n = len(a["seeds"])
        label = f"{LABELS.get(m, m)} ({n} seed{'s' if n > 1 else ''})"
        marker, ls = styles.get(m, ("o", "-"))
        (line,) = ax.plot(
            t, mean, drawstyle="steps-post", marker=marker, ls=ls, ms=4, lw=1.5, label=label
        )
        if len(a["seeds"]) > 1:
            ax.fill_between(
                t,
                np.clip(mean - sem, 0, 100),
                np.clip(mean + sem, 0, 100),
                step="post",
                alpha=0.2,
                color=line.get_color(),
            )
        if a["t90_s"] is not None:
            ax.axvline(a["t90_s"], color=line.get_color(), ls=":", lw=1)
    ax.axhline(100 * SUCCESS_LEVEL, color="k", ls="--", lw=0.8, label="90%")
    ax.set_xscale("log")
    ax.set_xlabel("experience [s] (log scale)")
    ax.set_ylabel("success rate [%]")
    ax.set_ylim(-3, 103)
    ax.set_title(f"{report['env_id']}" + (f" ({report['tag']})" if report.get("tag") else ""))
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_report(report: dict[str, Any], out_dir: Path) -> dict[str, Path]:
    """``compare_<env>[_<tag>].json / .md / .png`` in ``out_dir``."""
    stem = (
        "compare_"
        + report["env_id"].split("/")[-1]
        + (f"_{report['tag']}" if report.get("tag") else "")
    )
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {
        "json": out_dir / f"{stem}.json",
        "md": out_dir / f"{stem}.md",
        "png": out_dir / f"{stem}.png",
    }
    write_result(paths["json"], RESULT_LAYOUTS[0], report)
    paths["md"].write_text(markdown(report))
    plot(report, paths["png"])
    return paths


def run_job(method: str, env_id: str, seed: int, out: str, opts: dict[str, Any]) -> Job:
    """The sweep job of one run (:func:`run_method`), keyed ``<method>/seed<s>``: its result
    file is ``<method>/seed<s>.json`` next to the run folder ``out``."""
    kwargs = {"method": method, "env_id": env_id, "seed": seed, "out_dir": out, "opts": opts}
    return Job(f"{method}/seed{seed}", run_method, kwargs, cpus=int(opts.get("threads") or 1))


def curves_from_bench_json(path: Path, env_id: str, label: str = "") -> list[dict[str, Any]]:
    """MC-PILCO curves from ``mcpilco-bench-mcpilco``'s JSON (per-seed success per trial;
    ``label``: the section written with ``mcpilco-bench-mcpilco --label LABEL``) or from the
    reaching study of ``mcpilco-bench-kinematics --reaching-seeds``
    (``kinematics_reaching.json``,
    :func:`~mcpilco.experiments.kinematics.reaching.reaching_curves`)."""
    from mcpilco.experiments.mcpilco.bench import section_key

    data = read_result(path).payload()
    if isinstance(data.get("rows"), list) and all("mcpilco" in r for r in data["rows"]):
        from mcpilco.experiments.kinematics.reaching import reaching_curves

        if label:
            raise ValueError(f"{path} is a reaching study: it has no sections (drop the label)")
        return reaching_curves(data, env_id, source=str(path))
    key = section_key(env_id, label)
    section = data.get("runs", {}).get(key)
    if section is None:
        raise ValueError(
            f"{path} has no MC-PILCO runs {key!r} (sections: {sorted(data.get('runs', {}))}); "
            f"run mcpilco-bench-mcpilco --parts runs --env {env_id}"
            + (f" --label {label}" if label else "")
            + " first"
        )
    horizon = int(section["config"].get("horizon") or TaskSpec.for_env(env_id).horizon)
    times = [r["experience_s"] for r in section["per_trial"]]
    dt = times[0] / horizon
    curves = []
    for s in section["per_seed"]:
        recs = [
            {"index": k, "experience_s": (k + 1) * horizon * dt, "success": ok}
            for k, ok in enumerate(s["success"])
        ]
        curves.append(
            make_curve(
                "mcpilco",
                env_id,
                s["seed"],
                dt,
                trial_records_to_points(recs, horizon),
                source=str(path),
                wall_s=s.get("seconds"),
                complete=True,
            )
        )
    return curves


# ------------------------------------------------------------------------- options
def parse_steps(tokens: list[str] | None) -> dict[str, int]:
    """SB3 budgets from ``["N"]`` (every SB3 method) or ``["sac=N", ...]``: method -> env
    steps.

    Raises:
        ValueError: an unknown method, a value that is not an integer >= 1.
    """
    steps: dict[str, int] = {}
    for tok in tokens or []:
        if "=" in tok:
            algo, _, val = tok.partition("=")
            algos = [algo]
        else:
            val, algos = tok, list(SB3_METHODS)
        for a in algos:
            if a not in SB3_METHODS:
                raise ValueError(
                    f"--steps: unknown SB3 method {a!r}; valid: {', '.join(SB3_METHODS)}"
                )
        try:
            n = int(float(val))
        except ValueError as err:
            raise ValueError(f"--steps: {tok!r} is not an integer number of env steps") from err
        if n < 1:
            raise ValueError(f"--steps: must be >= 1 env step, got {n}")
        for a in algos:
            steps[a] = n
    return steps


def parse_sb3_hp(tokens: list[str] | None) -> dict[str, dict[str, Any]]:
    """SB3 hyperparameter overrides from ``["sac.learning_starts=1000", ...]``: method ->
    {key: value}, each value read by the package's YAML loader
    (:func:`mcpilco.envs.yaml_files.parse_yaml`: numbers, booleans, lists, null; else text).

    Raises:
        ValueError: a token that is not ``ALGO.KEY=VALUE`` with an SB3 method.
    """
    hp: dict[str, dict[str, Any]] = {}
    for tok in tokens or []:
        key, sep, val = tok.partition("=")
        algo, dot, name = key.partition(".")
        if not sep or not dot or algo not in SB3_METHODS or not name:
            raise ValueError(
                f"--sb3-hp: {tok!r} must look like ALGO.KEY=VALUE with ALGO in "
                f"{', '.join(SB3_METHODS)} (e.g. sac.learning_starts=1000)"
            )
        hp.setdefault(algo, {})[name] = parse_yaml(val, f"--sb3-hp {key}")
    return hp


# ----------------------------------------------------------------------------- compare
def compare(
    env_id: str,
    methods: Sequence[str],
    seeds: Sequence[int],
    opts: dict[str, Any],
    runner: SweepRunner,
    runs_dir: Path,
    *,
    curves: Sequence[dict[str, Any]] = (),
    mcpilco_json: Path | None = None,
    mcpilco_label: str = "",
    collect_only: bool = False,
    rerun: bool = False,
    tag: str | None = None,
    note: str | None = None,
    warn: Callable[[str], None] = lambda line: print(line, file=sys.stderr),
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """The comparison report of ``methods`` x ``seeds`` on ``env_id`` (:func:`build_report`,
    with ``failed`` runs and the ``settings``).

    Curves come from ``curves`` (e.g. files a user passed), MC-PILCO's from ``mcpilco_json``
    (``mcpilco-bench-mcpilco``'s JSON, section ``mcpilco_label``) when given, and per method
    and seed from ``runs_dir/<env>/<method>/seed<s>/curve.json`` when it covers the budget
    (:func:`covers`; any curve found with ``collect_only``, none with ``rerun``); the other
    runs are run (or resumed from their checkpoints) as sweep jobs of ``runner``
    (:func:`run_job`), unless ``collect_only``. ``opts``: see :func:`run_method`.

    Raises:
        ValueError: ``mcpilco_json`` lacks the section, or no curve of ``env_id`` is left.
    """
    curves, runs_dir = list(curves), Path(runs_dir)
    methods = list(methods)
    requested = list(methods)
    if mcpilco_json is None and "mcpilco" in methods:
        check_dynamics_task(TaskSpec.for_env(env_id))
    if mcpilco_json is not None and "mcpilco" in methods:
        try:
            curves += curves_from_bench_json(mcpilco_json, env_id, mcpilco_label)
        except (OSError, ValueError) as err:
            raise ValueError(f"--mcpilco-json: {err}") from None
        methods.remove("mcpilco")
    jobs = []
    for m in methods:
        for s in seeds:
            path = curve_path(runs_dir, env_id, m, s)
            if path.is_file():
                c = load_curves(path)[0]
                if collect_only or (not rerun and covers(c, m, opts)):
                    curves.append(c)
                    continue
            if not collect_only:
                jobs.append(run_job(m, env_id, s, str(path.parent), opts))
    t0 = time.perf_counter()
    failed = []
    if jobs:
        log(f"running {len(jobs)} job(s): {', '.join(j.key for j in jobs)}")
        # the runs to do were chosen above from their curves (a killed run resumes from its
        # checkpoint), so the sweep reruns every job it is given
        sweep = runner.run(jobs, runs_dir / env_id.split("/")[-1], rerun=True, desc="runs")
        for curve in sweep.results.values():  # a run on another node wrote its curve there
            path = curve_path(runs_dir, env_id, curve["method"], curve["seed"])
            if not path.is_file():
                save_curve(path, curve)
            curves.append(curve)
        failed = [
            {
                "failed": True,
                "method": f.kwargs["method"],
                "seed": f.kwargs["seed"],
                "out": f.kwargs["out_dir"],
                "error": f.error,
                "traceback": str(f.error_path),
            }
            for f in sweep.failed
        ]
        if failed:
            warn(sweep.summary())
    try:
        report = build_report(env_id, curves, tag=tag, note=note)
    except ValueError as err:
        if failed:
            raise ValueError(f"{err} ({len(failed)} run(s) failed, see above)") from None
        raise
    report["failed"] = failed
    for line in report["duplicates_dropped"]:
        warn(f"note: {line}: counted once")
    if "mcpilco" not in report["methods"] and any(f["method"] == "mcpilco" for f in failed):
        report["headline"]["goal"]["note"] = "MC-PILCO has no finished run (it failed, see above)"
    report["settings"] = {
        "methods": requested,
        "seeds": list(seeds),
        "opts": {k: v for k, v in opts.items() if k not in ("progress", "log")},
        "wall_s_this_call": time.perf_counter() - t0,
    }
    return report


# -- result file and headline rows of the results index -----------------------------------

RESULT_LAYOUTS = (
    ResultLayout(
        "compare",
        config=("env_id", "tag", "note", "settings"),
        cases=("curves",),
        failures=("failed",),
        seeds=lambda p: [c["seed"] for c in p.get("curves", []) if "seed" in c],
    ),
)
"""The layout of ``compare_<env>[_<tag>].json`` (:mod:`mcpilco.experiments.results`)."""


def _per_method_seeds(r: Result) -> str:
    return "; ".join(
        f"{name} {seed_ranges(m['seeds'])}" for name, m in r["methods"].items() if m["seeds"]
    )


def _ratio_text(r: Result, name: str) -> str:
    """Method ``name``'s experience to 90 % success over MC-PILCO's, or its lower bound."""
    x = r["headline"]["ratios"][name]
    value, bound = x["value"], x["lower_bound"]
    if value is not None:
        return f"{value:,.0f}x"
    return f"> {bound:,.0f}x" if bound >= 10 else f"> {bound:.2f}x"


def _cartpole_row(r: Result) -> str:
    return (
        f"experience to 90 % success: MC-PILCO {r['headline']['mcpilco_t90_s']:.0f} s; "
        f"SAC needs {_ratio_text(r, 'sac')} as much, TD3 {_ratio_text(r, 'td3')}, "
        f"PPO {_ratio_text(r, 'ppo')}, TorchRL PILCO {_ratio_text(r, 'pilco')}"
    )


def _tracking_row(r: Result) -> str:
    sac = r["methods"]["sac"]
    return (
        "experience until every joint's tracking error is halved in 90 % of the seeds: "
        f"MC-PILCO {r['headline']['mcpilco_t90_s']:.0f} s; SAC needs {_ratio_text(r, 'sac')} "
        f"as much (best success rate {100 * sac['best_success']:.0f} % within "
        f"{sac['budget_s']:,.0f} s)"
    )


def _reaching_row(r: Result) -> str:
    m, sac = r["methods"]["mcpilco"], r["methods"]["sac"]
    pos = {k: 1e3 * a["final_info_median"]["position_error"] for k, a in (("m", m), ("s", sac))}
    return (
        "experience until 90 % of the targets are reached (1 cm, 0.05 rad), identification "
        f"frames included: MC-PILCO {r['headline']['mcpilco_t90_s']:.0f} s; SAC needs "
        f"{_ratio_text(r, 'sac')} as much (best success rate {100 * sac['best_success']:.0f} % "
        f"within {sac['budget_s']:,.0f} s; final position error {pos['s']:.0f} mm against "
        f"MC-PILCO's {pos['m']:.1f} mm)"
    )


def _balance_row(r: Result) -> str:
    def t100(method: str) -> str:
        t = r["methods"][method]["t100_s"]
        return "not reached" if t is None else f"{t:.1f} s"

    m = r["methods"]["mcpilco"]
    line = (
        f"experience until all {len(m['seeds'])} seeds balance at once: MC-PILCO {t100('mcpilco')}"
    )
    if "pilco" in r["methods"]:
        return line + f", TorchRL PILCO {t100('pilco')} (its example's settings)"
    return line + "; TorchRL PILCO not measured"


def _row(capability: str, stem: str, figure: Callable[[Result], str]) -> Headline:
    return Headline(capability, f"{stem}.json", figure, f"{stem}.md", seeds=_per_method_seeds)


HEADLINES = (
    _row(
        "MC-PILCO, Gymnasium InvertedPendulum-v5 (terminating episodes)",
        "compare_InvertedPendulum-v5_seeds1000",
        _balance_row,
    ),
    _row(
        "MC-PILCO against TorchRL PILCO, InvertedPendulum-v5",
        "compare_InvertedPendulum-v5_noisefloor110",
        _balance_row,
    ),
    _row("Baselines (SB3, TorchRL PILCO)", "compare_CartpoleSwingUp-v0_hold2_sb3", _cartpole_row),
    _row("Baselines, UR10 tracking (SB3 SAC)", "compare_UR10-v0_positions", _tracking_row),
    _row(
        "Baselines, marker-camera reaching (SB3 SAC)",
        "compare_MarkerCameraReach-v0",
        _reaching_row,
    ),
)
"""The comparison's rows of the results index."""


def replot(result: Result, json_path: Path) -> list[Path]:
    """Redraw a comparison's figure (``.png`` next to its result file) from the file."""
    return [plot(result.payload(), Path(json_path).with_suffix(".png"))]
