"""The index of measured results: ``results/README.md``, generated from the results JSON.

Every benchmark writes its own JSON (and a Markdown table, often a PNG) under ``results/``,
each with its own schema. :data:`REGISTRY` lists the headline figures the README and the
documentation cite: for each, the JSON file that backs it, a function that reads the figure
from that file, and the page (Markdown or PNG) a reader opens for the details.
:func:`render_index` turns the registry into one Markdown table with, per row:

* the capability and the headline figure (from the registry's extractor);
* the command that produced the file: the JSON's ``command`` (top level, or under
  ``meta`` / ``commands``, keyed by the row's ``key`` where the file has several), else
  "not recorded";
* the seeds: the row's ``seeds`` function, else the JSON's ``seeds`` list, else "not
  recorded";
* the date of measurement: the JSON's ``measured`` (a date, or a mapping keyed by the row's
  ``key``); else the author date of the last commit that changed the file, marked
  "(last commit)"; else "not recorded".

Run ``mcpilco-results-index`` after adding or rerunning a benchmark; a test checks that the
committed ``results/README.md`` equals the generated one. A registered file that is missing
is an error that names it, so a deleted result cannot leave a stale row.
"""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

NOT_RECORDED = "not recorded"  # what a row says where its file does not record a field


@dataclass(frozen=True)
class Headline:
    """One headline figure of the index.

    Args:
        capability: what the figure measures, as the README names the capability.
        path: the JSON file that backs it, relative to the results folder.
        figure: reads the figure (one short sentence) from the loaded JSON.
        page: the file a reader opens for the details (``.md`` or ``.png``), relative to the
            results folder.
        key: which entry of the JSON's ``commands`` / ``measured`` mappings belongs to this
            row, for files that hold several measurements.
        seeds: reads the seeds (a short text) from the loaded JSON; by default the JSON's
            top-level ``seeds`` list.
    """

    capability: str
    path: str
    figure: Callable[[dict[str, Any]], str]
    page: str
    key: str | None = None
    seeds: Callable[[dict[str, Any]], str] | None = None


def seed_ranges(seeds: Sequence[int]) -> str:
    """``[0, 1, 2, 5, 7, 8]`` -> ``"0-2, 5, 7-8"`` (sorted, repeats dropped)."""
    vals = sorted({int(s) for s in seeds})
    if not vals:
        return NOT_RECORDED
    parts, start, prev = [], vals[0], vals[0]
    for s in [*vals[1:], None]:
        if s is not None and s == prev + 1:
            prev = s
            continue
        parts.append(f"{start}" if start == prev else f"{start}-{prev}")
        if s is not None:
            start = prev = s
    return ", ".join(parts)


def _pick(value: Any, key: str | None) -> str | None:
    """A string field, or the entry ``key`` of a mapping of them."""
    if isinstance(value, str):
        return value
    if isinstance(value, dict) and key is not None and isinstance(value.get(key), str):
        return value[key]
    return None


def recorded_command(data: dict[str, Any], key: str | None = None) -> str:
    """The command recorded in a results JSON (see the module docstring), or "not recorded"."""
    for value in (
        data.get("command"),
        (data.get("meta") or {}).get("command"),
        data.get("commands"),
    ):
        cmd = _pick(value, key)
        if cmd:
            return cmd
    return NOT_RECORDED


def recorded_seeds(data: dict[str, Any]) -> str:
    """The JSON's top-level ``seeds`` list as ranges, or "not recorded"."""
    seeds = data.get("seeds")
    if isinstance(seeds, list) and seeds:
        return seed_ranges(seeds)
    return NOT_RECORDED


def last_commit_date(path: Path) -> str | None:
    """Author date (YYYY-MM-DD) of the last commit that changed ``path``; None outside git."""
    try:
        out = subprocess.run(
            ["git", "log", "-1", "--format=%as", "--", path.name],
            cwd=path.parent,
            capture_output=True,
            text=True,
            timeout=30,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    date = out.stdout.strip()
    return date if out.returncode == 0 and date else None


def measurement_date(data: dict[str, Any], path: Path, key: str | None, use_git: bool) -> str:
    """The JSON's ``measured`` date, else the file's last commit date (marked), else none."""
    date = _pick(data.get("measured"), key)
    if date:
        return date
    if use_git:
        git_date = last_commit_date(path)
        if git_date:
            return f"{git_date} (last commit)"
    return NOT_RECORDED


@dataclass(frozen=True)
class Row:
    """One rendered row of the index."""

    capability: str
    figure: str
    command: str
    seeds: str
    date: str
    page: str


def index_rows(
    results_dir: str | Path, registry: Sequence[Headline] | None = None, use_git: bool = True
) -> list[Row]:
    """Read every registered file under ``results_dir`` and extract its row.

    Raises:
        FileNotFoundError: a registered JSON or page is missing (named in the message).
        ValueError: an extractor failed on its file (file and capability named).
    """
    results_dir = Path(results_dir)
    rows = []
    for h in REGISTRY if registry is None else registry:
        path = results_dir / h.path
        for needed in (path, results_dir / h.page):
            if not needed.is_file():
                raise FileNotFoundError(
                    f"{needed}: registered in the results index ({h.capability}) but missing; "
                    "rerun its benchmark or remove its entry from "
                    "mcpilco.experiments.results_index.REGISTRY"
                )
        data = json.loads(path.read_text())
        try:
            figure = h.figure(data)
            seeds = h.seeds(data) if h.seeds is not None else recorded_seeds(data)
        except (KeyError, IndexError, TypeError, ValueError) as err:
            raise ValueError(
                f"{path}: cannot read the headline figure of '{h.capability}' "
                f"({type(err).__name__}: {err}); has the file's schema changed?"
            ) from err
        rows.append(
            Row(
                capability=h.capability,
                figure=figure,
                command=recorded_command(data, h.key),
                seeds=seeds,
                date=measurement_date(data, path, h.key, use_git),
                page=h.page,
            )
        )
    return rows


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def render_index(
    results_dir: str | Path, registry: Sequence[Headline] | None = None, use_git: bool = True
) -> str:
    """The Markdown of ``results/README.md``: a header and one table row per headline."""
    lines = [
        "# Results",
        "",
        "Measured outputs of the benchmarks: each JSON holds the numbers, the Markdown "
        "table and PNG next to it show them. The table below lists every headline figure "
        "that the README and the documentation cite, with the command that produced it, "
        "its seeds and the date of measurement (from the JSON; where the JSON does not "
        "record a date, the date of the file's last commit).",
        "",
        "Generated by `mcpilco-results-index` from the JSON files; do not edit by hand. "
        "Protocols: `docs/benchmarks.md`.",
        "",
        "| capability | headline figure | command | seeds | measured | details |",
        "|---|---|---|---|---|---|",
    ]
    for r in index_rows(results_dir, registry, use_git):
        cmd = r.command if r.command == NOT_RECORDED else f"`{r.command}`"
        lines.append(
            f"| {_cell(r.capability)} | {_cell(r.figure)} | {_cell(cmd)} | {_cell(r.seeds)} "
            f"| {r.date} | [{r.page}]({r.page}) |"
        )
    return "\n".join(lines) + "\n"


def write_index(
    results_dir: str | Path = "results",
    out: str | Path | None = None,
    registry: Sequence[Headline] | None = None,
    use_git: bool = True,
) -> Path:
    """Write the index (by default ``<results_dir>/README.md``) and return its path."""
    results_dir = Path(results_dir)
    out = results_dir / "README.md" if out is None else Path(out)
    text = render_index(results_dir, registry, use_git)
    out.write_text(text)
    return out


# -- extractors of the registered files ---------------------------------------------------


def _pct(x: float) -> str:
    return f"{100 * x:.0f} %"


def _mm(xs: Sequence[float]) -> str:
    return " / ".join(f"{1e3 * x:.1f}" for x in xs) + " mm"


def _run_section(data: dict[str, Any], label: str) -> dict[str, Any]:
    return data["runs"][f"mcpilco/CartpoleSwingUp-v0 ({label})"]


def _success_at(section: dict[str, Any]) -> dict[float, float]:
    return {r["experience_s"]: r["success_rate"] for r in section["per_trial"]}


def _mcpilco_default(data: dict[str, Any]) -> str:
    s = _success_at(_run_section(data, "hold2"))
    return (
        f"swing-up success {_pct(s[12.0])} after 12 s and {_pct(s[15.0])} after 15 s of "
        "experience (bench preset, held exploration)"
    )


def _mcpilco_native(data: dict[str, Any]) -> str:
    s = _success_at(_run_section(data, "native"))
    return f"rollout compiled (`native`): success {_pct(s[12.0])} after 12 s of experience"


def _mcpilco_fresh(data: dict[str, Any]) -> str:
    s = _success_at(_run_section(data, "fresh100"))
    return (
        f"on seeds no setting was chosen on (`native` rollout): success {_pct(s[9.0])} / "
        f"{_pct(s[12.0])} / {_pct(s[15.0])} after 9 / 12 / 15 s of experience"
    )


DMC_SECTION = "mcpilco/DMCCartpoleSwingUp-v0 (snap140)"  # the dm-control headline's section


def _mcpilco_dmc_fresh(data: dict[str, Any]) -> str:
    s = _success_at(data["runs"][DMC_SECTION])
    return (
        f"dm-control's cart-pole (end stops declared), seeds no setting was chosen on: success "
        f"{_pct(s[7.0])} / {_pct(s[11.0])} / {_pct(s[15.0])} after 7 / 11 / 15 s of experience"
    )


def _mcpilco_step(data: dict[str, Any]) -> str:
    row = next(
        t
        for t in data["timing"]
        if t["n_points"] == 100 and t["num_particles"] == 400 and t["threads"] == 2
    )
    line = (
        f"{row['compiled_s_per_step_wall']:.3f} s per policy-optimisation step "
        f"(`{row['compile_backend']}`, 400 particles, N = 100, 2 threads; eager "
        f"{row['s_per_step_wall']:.3f} s)"
    )
    large = [  # the cart-pole at the bench preset's largest GP
        t
        for t in data["timing"]
        if t["n_points"] == 250 and t["num_particles"] == 400 and t["threads"] == 2
        and t.get("env_id", row.get("env_id")) == row.get("env_id")
        and "compiled_s_per_step_wall" in t
    ]  # fmt: skip
    if large:
        line += f", {large[0]['compiled_s_per_step_wall']:.3f} s at N = 250"
    own = {(m["env_id"], m["n_points"]): m["s_per_step"] for m in data.get("reference_steps", [])}
    ratios = [
        own[(t["env_id"], t["n_points"])] / t["compiled_s_per_step_wall"]
        for t in data["timing"]
        if (t.get("env_id"), t["n_points"]) in own
        and t.get("mpk_degree") == 1
        and "compiled_s_per_step_wall" in t
    ]
    if ratios:  # the arm spec against the reference's own arm task, same kernel
        line += (
            f"; arm spec (UR10, RBF + MPK p = 1) {min(ratios):.0f}-{max(ratios):.0f}x the "
            "reference's step on its UR5 task"
        )
    return line


def _mcpilco_gpu(data: dict[str, Any]) -> str:
    steps = [t["s_per_step_wall"] for t in data["timing"] if t.get("cuda_graph")]
    return f"{min(steps):.3f}-{max(steps):.3f} s per step on an H100 (400-4,000 particles)"


def _per_method_seeds(data: dict[str, Any]) -> str:
    return "; ".join(
        f"{name} {seed_ranges(m['seeds'])}" for name, m in data["methods"].items() if m["seeds"]
    )


def _ratio(data: dict[str, Any], name: str) -> str:
    """Method ``name``'s experience to 90 % success over MC-PILCO's, or its lower bound."""
    r = data["headline"]["ratios"][name]
    value, bound = r["value"], r["lower_bound"]
    if value is not None:
        return f"{value:,.0f}x"
    return f"> {bound:,.0f}x" if bound >= 10 else f"> {bound:.2f}x"


def _compare(data: dict[str, Any]) -> str:
    return (
        f"experience to 90 % success: MC-PILCO {data['headline']['mcpilco_t90_s']:.0f} s; "
        f"SAC needs {_ratio(data, 'sac')} as much, TD3 {_ratio(data, 'td3')}, "
        f"PPO {_ratio(data, 'ppo')}, TorchRL PILCO {_ratio(data, 'pilco')}"
    )


def _compare_tracking(data: dict[str, Any]) -> str:
    sac = data["methods"]["sac"]
    return (
        "experience until every joint's tracking error is halved in 90 % of the seeds: "
        f"MC-PILCO {data['headline']['mcpilco_t90_s']:.0f} s; SAC needs {_ratio(data, 'sac')} "
        f"as much (best success rate {100 * sac['best_success']:.0f} % within "
        f"{sac['budget_s']:,.0f} s)"
    )


def _compare_reaching(data: dict[str, Any]) -> str:
    m, sac = data["methods"]["mcpilco"], data["methods"]["sac"]
    pos = {k: 1e3 * a["final_info_median"]["position_error"] for k, a in (("m", m), ("s", sac))}
    return (
        "experience until 90 % of the targets are reached (1 cm, 0.05 rad), identification "
        f"frames included: MC-PILCO {data['headline']['mcpilco_t90_s']:.0f} s; SAC needs "
        f"{_ratio(data, 'sac')} as much (best success rate {100 * sac['best_success']:.0f} % "
        f"within {sac['budget_s']:,.0f} s; final position error {pos['s']:.0f} mm against "
        f"MC-PILCO's {pos['m']:.1f} mm)"
    )


def _compare_balance(data: dict[str, Any]) -> str:
    def t100(method: str) -> str:
        t = data["methods"][method]["t100_s"]
        return "not reached" if t is None else f"{t:.1f} s"

    m = data["methods"]["mcpilco"]
    line = (
        f"experience until all {len(m['seeds'])} seeds balance at once: MC-PILCO {t100('mcpilco')}"
    )
    if "pilco" in data["methods"]:
        return line + f", TorchRL PILCO {t100('pilco')} (its example's settings)"
    return line + "; TorchRL PILCO not measured"


TRACKING_SECTION = "mcpilco/UR10-v0 (positions)"  # the UR10 tracking headline's section
PUSHES_SECTION = "mcpilco/UR10-v0 (positions-pushes)"  # the same seeds under pushes, no filter
FILTERED_SECTION = "mcpilco/UR10-v0 (positions-pushes-filtered)"  # pushes, push filter on
KERNELS_SECTION = "UR10-v0_positions"  # the kernel comparison on the shipped task's runs
CONTROL_SECTIONS = {  # the same seeds learned with each kernel: label -> section
    "RBF + MPK (p = 1)": TRACKING_SECTION,
    "RBF": "mcpilco/UR10-v0 (positions-rbf)",
    "rigid body": "mcpilco/UR10-v0 (positions-rigid)",
}


def _tracking_figure(sec: dict[str, Any]) -> str:
    """The tracking RMS after a section's last policy trial against the controller alone:
    all joints and per joint."""
    from mcpilco.experiments.mcpilco.tracking import overall

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


def _tracking(data: dict[str, Any]) -> str:
    return "UR10 tracking " + _tracking_figure(data["runs"][TRACKING_SECTION])


def _tracking_pushes(data: dict[str, Any]) -> str:
    from mcpilco.experiments.mcpilco.tracking import overall

    sec, unfiltered = data["runs"][FILTERED_SECTION], data["runs"][PUSHES_SECTION]
    k = len(unfiltered["tracking"]) - 1
    return (
        "UR10 tracking under pushes, push filter on, "
        + _tracking_figure(sec)
        + f"; without the filter all joints {overall(unfiltered, k)['ratio']:.2f} x"
    )


def _tracking_kernels(data: dict[str, Any]) -> str:
    from mcpilco.experiments.mcpilco.bench import kernel_label
    from mcpilco.experiments.mcpilco.rmse import KERNEL_ARGS

    rows = data["kernels"][KERNELS_SECTION]["kernels"]
    cells = ", ".join(
        f"{kernel_label(**KERNEL_ARGS[k])} {1e3 * v['all_joints_mean']:.1f}"
        for k, v in rows.items()
    )
    halved = ", ".join(
        f"{name} "
        + " / ".join(str(row["seeds_halved"]) for row in data["runs"][key]["tracking"])
        + f" of {len(data['runs'][key]['seeds'])}"
        for name, key in CONTROL_SECTIONS.items()
    )
    return (
        "UR10 multi-step prediction RMSE over 4 s, all joints [mrad], GPs of the position and "
        f"velocity changes: {cells}; control, seeds with every joint's tracking error halved "
        f"after policy trials 1 / 2 / 3: {halved}"
    )


def _gp_speed(data: dict[str, Any]) -> str:
    s = data["speedup_vs_gpytorch"]
    return (
        f"cached predictor {s['cached32']:.1f}x (float32) / {s['cached64']:.1f}x (float64) "
        f"faster than GPyTorch, within {data['max_abs_diff_cached64_vs_gpytorch']:.0e}"
    )


def _gp_gpu(data: dict[str, Any]) -> str:
    s = data["speedup_vs_gpytorch"]
    return f"on an H100: {s['cached32']:.1f}x (float32) / {s['cached64']:.1f}x (float64)"


def _volterra(data: dict[str, Any]) -> str:
    exp2 = data["summary"]["exp2"]
    fits = " / ".join(f"{exp2[f'r{r}_snr20']['sed_mpk_tied']['mean']:.1f}" for r in (3, 4, 5))
    s2 = data["summary"]["exp1"]["setup2"]
    return (
        f"SED-MPK mean Fit {fits} % at r = 3 / 4 / 5, 20 dB; Setup 2 median Fit MPK "
        f"{s2['mpk']['median']:.1f} %, PK {s2['pk']['median']:.1f} %"
    )


def _volterra_seeds(data: dict[str, Any]) -> str:
    m = data["meta"]
    b = m["base_seed"]
    return f"{b}-{b + m['runs_exp1'] - 1} (exp. 1), {b}-{b + m['runs_exp2'] - 1} (exp. 2)"


def _median(xs: Sequence[float]) -> float:
    s = sorted(xs)
    n = len(s)
    return s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


def _id_scara(data: dict[str, Any]) -> str:
    nmse = data["scara"]["nmse"]
    med = {k: [_median(col) for col in zip(*v, strict=True)] for k, v in nmse.items()}
    gip = med["GIP"]
    rbf = min(r / g for r, g in zip(med["RBF"], gip, strict=True))
    nn = min(r / g for r, g in zip(med["NN"], gip, strict=True))
    return (
        f"SCARA: GIP median nMSE {min(gip):.1e}-{max(gip):.1e} per joint, "
        f">= {rbf:.0f}x below RBF and >= {nn:.0f}x below NN"
    )


def _id_scara_seeds(data: dict[str, Any]) -> str:
    cfg = data["config"]
    return f"seed {cfg.get('seed', 0)}, {cfg['runs']} Monte Carlo runs"


def _id_ur10(data: dict[str, Any]) -> str:
    u = data["ur10"]
    ratio = [a / b for a, b in zip(u["nmse"]["GIP+F"], u["noise_floor"], strict=True)]
    return (
        f"UR10 from motor currents: GIP+F within {min(ratio[:4]):.1f}-{max(ratio[:4]):.1f}x "
        "of the noise floor on joints 1-4"
    )


def _collision(data: dict[str, Any]) -> str:
    est = data["estimators"]
    fc = est["FC"]["rmse"]["quasi_static"]
    sp = max(est["SP"]["thresholds"]["max"])
    return (
        f"FC quasi-static RMSE {min(fc):.2f}-{max(fc):.2f} A; largest threshold "
        f"FC {max(est['FC']['thresholds']['max']):.2f} A against SP {sp:.2f} A"
    )


def _collision_seeds(data: dict[str, Any]) -> str:
    return f"seed {data['config']['seed']}"


def _quasi_static(data: dict[str, Any]) -> str:
    return f"stiction band of the rest current at one pose: {data['stiction_band_A']:.2f} A"


def _seed_field(data: dict[str, Any]) -> str:
    seed = data.get("seed", (data.get("config") or {}).get("seed"))
    return NOT_RECORDED if seed is None else f"seed {seed}"


def _structure(data: dict[str, Any]) -> str:
    mc = data["monte_carlo"]
    return (
        f"structure identification: {mc['percent_correct']:.0f} % of {mc['triplets']} "
        f"triplets correct on {mc['robots']} random robots"
    )


def _fk_seeds(data: dict[str, Any]) -> str:
    met = data["goal"]["met_all"]
    chain = data["summary"]["chain"]["mean"][:3]
    poly = data["summary"]["polynomial"]["mean"][:3]
    n = len(data["seeds"])
    return (
        f"FK from 100 designed samples, mean RMSE: chain model {_mm(chain)} "
        f"(goal met on {met['chain']} of {n} seeds), one GP {_mm(poly)} "
        f"({met['polynomial']} of {n})"
    )


def _controller(data: dict[str, Any]) -> str:
    last = data["controller"]["rounds"][-1]
    t = last["rmse_true"]
    return (
        f"kinematic controller after {last['round']} online refits: {_mm(t[:3])}, {t[-1]:.3f} rad"
    )


def _controller_chain(data: dict[str, Any]) -> str:
    first = data["controller"]["rounds"][0]
    t = first["rmse_true"]
    return f"controller on the chain model, before any refit: {_mm(t[:3])}, {t[-1]:.3f} rad"


def _reaching(data: dict[str, Any]) -> str:
    mc, ctrl = data["summary"]["mcpilco"][-1], data["summary"]["controller"][-1]

    def one(t: dict[str, Any]) -> str:
        return (
            f"{1000 * t['position_median']:.1f} mm, {t['orientation_median']:.3f} rad "
            f"({t['reached']} / {t['targets']} within 1 cm and 0.05 rad)"
        )

    return (
        f"MC-PILCO reaching through the learned kinematics, median after trial {mc['trial']}: "
        f"{one(mc)}; gradient controller on the same data: {one(ctrl)}"
    )


def _markers(data: dict[str, Any]) -> str:
    o = data["overall"]
    xyz = " / ".join(f"{x:.1f}" for x in o["position_rmse_per_axis_mm_without_gross"])
    return (
        f"rendered ArUco markers: {_pct(o['detection_rate'])} detected, {xyz} mm and "
        f"{o['geodesic_rms_without_gross']:.3f} rad without gross errors "
        f"({_pct(o['gross_fraction'])} gross)"
    )


def _diagnosis(data: dict[str, Any]) -> str:
    s = data["summary"]
    return (
        f"effect ranked first in {s['top1_counts']} single-effect cases (top-3: "
        f"{s['top3_counts']}); position-dependent friction said unexplained in "
        f"{s['off_library_unexplained_counts']}; false alarms {s['false_alarm_counts']} controls"
    )


def _torque_constants(data: dict[str, Any]) -> str:
    s = data["summary"]
    covered = round(s["ci95_coverage"] * s["estimated_joints"])
    return (
        f"k_t 95% intervals hold the truth on {covered}/{s['estimated_joints']} joints; "
        f"{s['controls_missing_effect_named']}/{s['controls']} controls name an effect; "
        f"damping named in {s['damping_named']}/{s['damping_cases']}"
    )


def _diagnosis_speed(data: dict[str, Any]) -> str:
    rows = data["case"].get("training_rows", "?")
    times = ", ".join(
        f"{r['start']} {r['wall_s']:.0f} s wall ({r['cpu_s']:.0f} s CPU)" for r in data["records"]
    )
    return f"3 joints, {rows} training rows: {times}"


def _sweep(data: dict[str, Any]) -> str:
    by = {}
    for s in data["summary"]:
        by.setdefault(s["backend"], []).append(s)
    parts = []
    for backend, rows in by.items():
        start = [r["startup_s"] for r in rows]
        gap = [r["dispatch_gap_s"] for r in rows]
        parts.append(
            f"{backend}: start {min(start):.0f}-{max(start):.0f} s, "
            f"{1e3 * min(gap):.0f}-{1e3 * max(gap):.0f} ms between jobs"
        )
    return "sweep runner overhead, " + "; ".join(parts)


def _no_seeds(data: dict[str, Any]) -> str:
    return "-"


def _robustness(data: dict[str, Any]) -> str:
    outcomes = [c["outcome"] for c in data["cases"]]
    fuzz = sum(f["inputs"] for f in data["fuzz"])
    crash = outcomes.count("crash") + sum(f.get("crash", 0) for f in data["fuzz"])
    silent = outcomes.count("silent wrong") + sum(f.get("silent wrong", 0) for f in data["fuzz"])
    return (
        f"{len(outcomes)} bad inputs to the console scripts and {fuzz} fuzzed inputs: "
        f"{crash} crashes, {silent} silent wrong answers"
    )


# The headline figures cited by the README and docs/, in the README's order.
REGISTRY: tuple[Headline, ...] = (
    Headline(
        "MC-PILCO, cart-pole swing-up",
        "mcpilco_cartpole.json",
        _mcpilco_default,
        "mcpilco_cartpole.md",
        key="runs (hold2)",
        seeds=lambda d: seed_ranges(_run_section(d, "hold2")["seeds"]),
    ),
    Headline(
        "MC-PILCO, compiled rollout",
        "mcpilco_cartpole.json",
        _mcpilco_native,
        "mcpilco_cartpole.md",
        key="runs (native)",
        seeds=lambda d: seed_ranges(_run_section(d, "native")["seeds"]),
    ),
    Headline(
        "MC-PILCO, fresh seeds",
        "mcpilco_cartpole.json",
        _mcpilco_fresh,
        "mcpilco_cartpole.md",
        key="runs (fresh100)",
        seeds=lambda d: seed_ranges(_run_section(d, "fresh100")["seeds"]),
    ),
    Headline(
        "MC-PILCO, dm-control cart-pole",
        "mcpilco_cartpole.json",
        _mcpilco_dmc_fresh,
        "mcpilco_cartpole.md",
        key="runs (DMC snap140)",
        seeds=lambda d: seed_ranges(d["runs"][DMC_SECTION]["seeds"]),
    ),
    Headline(
        "MC-PILCO, Gymnasium InvertedPendulum-v5",
        "compare_InvertedPendulum-v5_noisefloor110.json",
        _compare_balance,
        "compare_InvertedPendulum-v5_noisefloor110.md",
        seeds=_per_method_seeds,
    ),
    Headline(
        "MC-PILCO, UR10 tracking",
        "mcpilco_tracking.json",
        _tracking,
        "mcpilco_tracking.md",
        key=TRACKING_SECTION,
        seeds=lambda d: seed_ranges(d["runs"][TRACKING_SECTION]["seeds"]),
    ),
    Headline(
        "MC-PILCO, UR10 tracking under pushes",
        "mcpilco_tracking.json",
        _tracking_pushes,
        "mcpilco_tracking.md",
        key=FILTERED_SECTION,
        seeds=lambda d: seed_ranges(d["runs"][FILTERED_SECTION]["seeds"]),
    ),
    Headline(
        "MC-PILCO, UR10 GP kernels",
        "mcpilco_tracking.json",
        _tracking_kernels,
        "mcpilco_tracking.md",
        key=f"kernels {KERNELS_SECTION}",  # tracking_bench.kernels_entry (not imported here)
        seeds=lambda d: seed_ranges(r["seed"] for r in d["kernels"][KERNELS_SECTION]["per_run"]),
    ),
    Headline(
        "MC-PILCO, speed (CPU)",
        "mcpilco_cartpole.json",
        _mcpilco_step,
        "mcpilco_cartpole.md",
        key="timing",
        seeds=_no_seeds,
    ),
    Headline(
        "MC-PILCO, speed (GPU)",
        "h100/mcpilco_cartpole.json",
        _mcpilco_gpu,
        "h100/mcpilco_cartpole.md",
        seeds=_no_seeds,
    ),
    Headline(
        "Baselines (SB3, TorchRL PILCO)",
        "compare_CartpoleSwingUp-v0_hold2_sb3.json",
        _compare,
        "compare_CartpoleSwingUp-v0_hold2_sb3.md",
        seeds=_per_method_seeds,
    ),
    Headline(
        "Baselines, UR10 tracking (SB3 SAC)",
        "compare_UR10-v0_positions.json",
        _compare_tracking,
        "compare_UR10-v0_positions.md",
        seeds=_per_method_seeds,
    ),
    Headline(
        "Baselines, marker-camera reaching (SB3 SAC)",
        "compare_MarkerCameraReach-v0.json",
        _compare_reaching,
        "compare_MarkerCameraReach-v0.md",
        seeds=_per_method_seeds,
    ),
    Headline(
        "GP core, predictor speed (CPU)",
        "bench_gp_predictor.json",
        _gp_speed,
        "bench_gp_predictor.json",
        seeds=_no_seeds,
    ),
    Headline(
        "GP core, predictor speed (GPU)",
        "h100/bench_gp_predictor.json",
        _gp_gpu,
        "h100/bench_gp_predictor.json",
        seeds=_no_seeds,
    ),
    Headline(
        "Kernels: Volterra identification",
        "volterra.json",
        _volterra,
        "volterra.md",
        seeds=_volterra_seeds,
    ),
    Headline(
        "Inverse dynamics",
        "inverse_dynamics.json",
        _id_scara,
        "inverse_dynamics.md",
        key="scara",
        seeds=_id_scara_seeds,
    ),
    Headline(
        "Inverse dynamics",
        "inverse_dynamics.json",
        _id_ur10,
        "inverse_dynamics.md",
        key="ur10_gip_f",
        seeds=lambda d: f"seed {d['config'].get('seed', 0)}",
    ),
    Headline(
        "Collision detection",
        "collision_5000/collision.json",
        _collision,
        "collision_5000/collision.md",
        seeds=_collision_seeds,
    ),
    Headline(
        "Collision detection, stiction",
        "collision_quasi_static.json",
        _quasi_static,
        "collision_quasi_static.md",
        seeds=_seed_field,
    ),
    Headline(
        "Kinematics from markers",
        "kinematics.json",
        _structure,
        "kinematics.md",
        seeds=lambda d: "random robots from seed " + str(d["seed"]),
    ),
    Headline(
        "Kinematics from markers",
        "kinematics_c_seeds.json",
        _fk_seeds,
        "kinematics_c_seeds.md",
    ),
    Headline(
        "Kinematics from markers",
        "kinematics.json",
        _controller,
        "kinematics.md",
        seeds=_seed_field,
    ),
    Headline(
        "Kinematics from markers",
        "kinematics_d_chain/kinematics.json",
        _controller_chain,
        "kinematics_d_chain/kinematics.md",
        seeds=_seed_field,
    ),
    Headline(
        "Kinematics: MC-PILCO reaching",
        "kinematics_reaching.json",
        _reaching,
        "kinematics_reaching.md",
    ),
    Headline(
        "Kinematics: rendered markers",
        "marker_detection.json",
        _markers,
        "marker_detection.md",
        seeds=_seed_field,
    ),
    Headline(
        "Diagnosis on simulated robot logs, nominal start",
        "diagnosis_robot_logs.json",
        _diagnosis,
        "diagnosis_robot_logs.md",
    ),
    Headline(
        "Diagnosis of motor-current logs (torque constants)",
        "torque_constants.json",
        _torque_constants,
        "torque_constants.md",
    ),
    Headline(
        "Diagnosis speed",
        "diagnosis_speed.json",
        _diagnosis_speed,
        "diagnosis_speed.md",
    ),
    Headline(
        "Sweeps",
        "sweep_overhead.json",
        _sweep,
        "sweep_overhead.md",
        seeds=_no_seeds,
    ),
    Headline(
        "Robustness",
        "robustness.json",
        _robustness,
        "robustness.md",
        seeds=_no_seeds,
    ),
)
"""Every headline figure of the index; see :class:`Headline`."""
