"""Figures and the Markdown report of the collision-detection benchmark.

:func:`plot_rmse` (thesis Fig. 4.2), :func:`plot_scenario` (thesis Fig. 4.3),
:func:`plot_roc` (detection rate against false alarms per minute), :func:`goals` (the
benchmark's targets, recorded, not asserted) and :func:`markdown`, all on the results dict
of :func:`mcpilco.experiments.collision.bench.run_benchmark`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

ESTIMATOR_NAMES = ("PP", "SP", "FC")
"""Current estimators of the benchmark (:data:`mcpilco.models.collision.ESTIMATORS`)."""

# an estimator's and a threshold rule's names in the figures' legends, in words
ESTIMATOR_LABELS: dict[str, str] = {
    "PP": "GP, rigid body + friction (PP)",
    "PP-sign": "GP, rigid body + sign friction (PP)",
    "SP": "GP, PP + RBF (SP)",
    "FC": "GP, PP + gated RBF at rest (FC)",
}
RULE_LABELS: dict[str, str] = {
    "max": "threshold max |s|",
    "variance": "threshold k sigma(x)",
}


def _plt() -> Any:
    """``matplotlib.pyplot`` on the file-only Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_rmse(results: dict[str, Any], path: Path) -> None:
    """Thesis Fig. 4.2: RMSE per joint, dynamic (top) and quasi-static (bottom)."""
    plt = _plt()
    names = [n for n in (*ESTIMATOR_NAMES, "PP-sign") if n in results["estimators"]]
    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    n = len(results["estimators"][names[0]]["rmse"]["all"])
    x = np.arange(1, n + 1)
    width = 0.8 / len(names)
    noise = np.asarray(results["current_noise_std"])
    for ax, regime in zip(axes, ("dynamic", "quasi_static"), strict=True):
        for k, name in enumerate(names):
            vals = results["estimators"][name]["rmse"][regime]
            label = ESTIMATOR_LABELS.get(name, name)
            ax.bar(x + (k - (len(names) - 1) / 2) * width, vals, width, label=label)
        ax.plot(x, noise, "k_", ms=25, mew=2, label="noise std")
        title = "|qd_j| >= sigma_v (dynamic)" if regime == "dynamic" else "|qd_j| < sigma_v"
        ax.set_title(f"{title}, sigma_v = {results['config']['rmse_sigma_v']:g} rad/s")
        ax.set_ylabel("RMSE of i_hat [A]")
        ax.grid(axis="y", alpha=0.3)
    axes[1].set_xticks(x, [f"joint {j}" for j in x])
    axes[0].legend(ncol=len(names) + 1, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_scenario(results: dict[str, Any], sets: dict[str, Any], path: Path) -> None:
    """Thesis Fig. 4.3: i1 with the SP and FC estimates; s with sigma_CD; pushes shaded."""
    plt = _plt()
    sc = sets["scenario"]
    t = sc["t"]
    names = [n for n in ("SP", "FC") if n in results["estimators"]]
    fig, axes = plt.subplots(1 + len(names), 1, figsize=(10, 2.4 * (1 + len(names))), sharex=True)
    axes = np.atleast_1d(axes)
    j = results["config"]["scenario_joint"] - 1
    axes[0].plot(t, sc["i"][:, j], color="0.4", lw=0.6, label=f"i{j + 1} measured")
    for k, name in enumerate(names):
        sig = results["estimators"][name]["_signals"]["scenario"]
        axes[0].plot(t, sig["i_hat"][:, j], lw=0.9, color=f"C{k}", label=f"{name} estimate")
        ax = axes[k + 1]
        thr = results["estimators"][name]["thresholds"]["max"][j]
        ax.plot(t, sig["s"][:, j], lw=0.6, color=f"C{k}", label=f"s{j + 1} ({name})")
        ax.axhline(thr, color="C3", ls="--", lw=1, label=f"sigma_CD = {thr:.2f} A")
        ax.axhline(-thr, color="C3", ls="--", lw=1)
        ax.set_ylabel("[A]")
        ax.legend(loc="upper left", fontsize=8)
    axes[0].set_ylabel("[A]")
    axes[0].legend(loc="upper left", fontsize=8)
    for ax in axes:
        for p in sets["scenario_pushes"]:
            ax.axvspan(p.t_start, p.t_start + p.duration, color="0.85", zorder=0)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("t [s] (circle tracking, then rest; pushes shaded)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_roc(results: dict[str, Any], path: Path) -> None:
    """Detection rate vs false alarms per minute, thresholds from validation quantiles."""
    plt = _plt()
    ms = results["config"]["roc_persistence"]
    fig, axes = plt.subplots(1, len(ms), figsize=(6 * len(ms), 4.5), squeeze=False)
    for ax, m in zip(axes[0], ms, strict=True):
        for k, (name, res) in enumerate(results["estimators"].items()):
            for rule, style in (("max", "-o"), ("variance", "--s")):
                pts = res.get("roc", {}).get(f"{rule}/m={m}")
                if not pts:
                    continue
                fa = [max(p["false_alarms_per_minute"], 1e-2) for p in pts]
                rate = [p["rate_all"] for p in pts]
                label = f"{ESTIMATOR_LABELS.get(name, name)}, {RULE_LABELS[rule]}"
                ax.plot(fa, rate, style, color=f"C{k}", label=label)
        ax.set_xscale("log")
        ax.set_xlabel("false alarms per minute on push-free data (0 plotted at 0.01)")
        ax.set_ylabel("fraction of pushes detected")
        ax.set_title(f"persistence m = {m}")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _f(v: Any, digits: int = 2) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return f"{v:.{digits}f}"


def goals(results: dict[str, Any]) -> dict[str, Any]:
    """The benchmark's targets, each ``True`` or ``False`` (recorded, not asserted)."""
    est = results["estimators"]
    g: dict[str, Any] = {}
    if all(n in est for n in ESTIMATOR_NAMES):
        fc = np.asarray(est["FC"]["rmse"]["quasi_static"])
        pp = np.asarray(est["PP"]["rmse"]["quasi_static"])
        sp = np.asarray(est["SP"]["rmse"]["quasi_static"])
        g["FC quasi-static RMSE below PP and SP on every joint"] = bool(
            np.all(fc < pp) and np.all(fc < sp)
        )
        if "PP-sign" in est:
            pps = np.asarray(est["PP-sign"]["rmse"]["quasi_static"])
            g["FC quasi-static RMSE below PP-sign on every joint"] = bool(np.all(fc < pps))
        s_fc = np.asarray(est["FC"]["thresholds"]["max"])
        s_sp = np.asarray(est["SP"]["thresholds"]["max"])
        g["FC sigma_CD below SP on every joint"] = bool(np.all(s_fc < s_sp))
        g["FC sigma_CD below SP, max over joints"] = bool(s_fc.max() < s_sp.max())
    if "FC" in est:
        m = results["config"]["persistence"]
        for mm in m:
            d = est["FC"]["detection"][f"max/m={mm}"]
            g[f"FC max m={mm}: all >=30 N pushes detected"] = d["rate_ge30"] == 1.0
            g[f"FC max m={mm}: zero false alarms on push-free data"] = d["false_alarms"] == 0
            g[f"FC max m={mm}: median latency <= 40 ms"] = d["median_latency"] <= 0.040 + 1e-9
        for m in results["config"]["roc_persistence"]:
            roc = est["FC"]["roc"]
            if f"variance/m={m}" not in roc:
                continue
            better = []
            for pv in roc[f"variance/m={m}"]:
                # max-rule detection at a false-alarm rate <= the variance rule's
                cands = [
                    pm["rate_all"]
                    for pm in roc[f"max/m={m}"]
                    if pm["false_alarms_per_minute"] <= pv["false_alarms_per_minute"] + 1e-12
                ]
                if cands:
                    better.append(pv["rate_all"] >= max(cands))
            key = f"FC m={m}: variance rule detects >= max rule at <= the same false-alarm rate"
            g[key + " (every alpha)"] = bool(all(better)) if better else None
    return g


def markdown(results: dict[str, Any]) -> str:
    """The Markdown report of ``results`` (tables of every figure, goals, timing)."""
    cfg = results["config"]
    est = results["estimators"]
    sizes = results["sizes"]
    lines = [
        "# Collision detection benchmark (UR10, thesis section 4.6)",
        "",
        f"Machine: {results['machine']}; torch threads {cfg['threads']}; seed {cfg['seed']}; "
        f"wall {results['seconds']:.0f} s, CPU {results['cpu_seconds']:.0f} s.",
        "",
        f"Data: training {sizes['train']} samples ({cfg['train_waypoints']} waypoints), GP "
        f"conditioned on {sizes['gp']} rows (constant step), hyperparameters on "
        f"{cfg['hyper_points']} rows ({cfg['adam_iters']} Adam + {cfg['lbfgs_iters']} L-BFGS); "
        f"validation {sizes['validation']} samples ({cfg['test_waypoints']} waypoints + circle + "
        f"rests); push-free {sizes['push_free']} samples "
        f"({sizes['push_free'] * 0.008 / 60:.1f} min); push run {sizes['pushes']} samples with "
        f"{sizes['n_pushes']} pushes ({sizes['n_pushes_rest']} at rest).",
        "",
        "## sigma_v by cross-validation (FC)",
        "",
        "| sigma_v [rad/s] | validation sum of MSE [A^2] |",
        "|---|---|",
    ]
    cv = results["sigma_v_cv"]
    for k, v in cv["scores"].items():
        mark = " (chosen)" if float(k) == cv["best"] else ""
        lines.append(f"| {k}{mark} | {v:.4f} |")
    lines += [
        "",
        f"FC uses sigma_v = {cv['best']:g} rad/s; the RMSE split below uses "
        f"sigma_v = {cfg['rmse_sigma_v']:g} rad/s (thesis value).",
        "",
        "## RMSE of i_hat on the validation set [A] (thesis Fig. 4.2)",
        "",
        "| estimator | regime | " + " | ".join(f"joint {j}" for j in range(1, 7)) + " |",
        "|---|---|" + "---|" * 6,
    ]
    for name, res in est.items():
        for regime in ("quasi_static", "dynamic"):
            vals = " | ".join(_f(v, 3) for v in res["rmse"][regime])
            lines.append(f"| {name} | {regime.replace('_', '-')} | {vals} |")
    noise = " | ".join(_f(v, 3) for v in results["current_noise_std"])
    lines += [f"| noise std | | {noise} |", ""]
    lines += [
        "PP-sign = PP with the exact sign(qd) feature (reference; see COULOMB_VELOCITY in "
        "models/collision/estimators.py).",
        "",
        "## Thresholds sigma_CD = max |s| on the validation set [A] (thesis: FC 1.28, SP 2.10, "
        "PP 2.09)",
        "",
        "| estimator | " + " | ".join(f"joint {j}" for j in range(1, 7)) + " | max |",
        "|---|" + "---|" * 7,
    ]
    for name, res in est.items():
        if "max" in res.get("thresholds", {}):
            thr = res["thresholds"]["max"]
            lines.append(f"| {name} | " + " | ".join(_f(v) for v in thr) + f" | {_f(max(thr))} |")
    lines += [
        "",
        "## Detection (push run) and false alarms (push-free run)",
        "",
        "| estimator | rule | m | detected all | >= 30 N | moving | at rest | >= 30 N at rest | "
        "median latency [ms] | false alarms / min (count) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, res in est.items():
        for key, d in res.get("detection", {}).items():
            rule, m = key.split("/m=")
            lines.append(
                f"| {name} | {rule} | {m} | {_f(d['rate_all'])} | {_f(d['rate_ge30'])} | "
                f"{_f(d['rate_moving'])} | {_f(d['rate_rest'])} | {_f(d['rate_ge30_rest'])} | "
                f"{_f(1000 * d['median_latency'], 0)} | {_f(d['false_alarms_per_minute'], 3)} "
                f"({d['false_alarms']}) |"
            )
    lines += ["", "## Missed pushes (FC, max rule, m = 1)", ""]
    if "FC" in est and "max/m=1" in est["FC"]["detection"]:
        d = est["FC"]["detection"]["max/m=1"]
        thr = np.asarray(est["FC"]["thresholds"]["max"])
        rows = [
            (r, det)
            for r, det in zip(results["push_records"], d["detected"], strict=True)
            if not det
        ]
        lines += [
            "| t [s] | force [N] | link | at rest | max_j peak abs(tau_ext_j)/K_eq_j [A] | "
            "max_j ratio to sigma_CD,j |",
            "|---|---|---|---|---|---|",
        ]
        for r, _ in rows:
            peak = np.asarray(r["peak_tau_ext_A"])
            lines.append(
                f"| {r['t_start']:.1f} | {r['force']:.0f} | {r['link']} | {r['at_rest']} | "
                f"{peak.max():.2f} | {(peak / thr).max():.2f} |"
            )
        if not rows:
            lines.append("(none)")
    lines += ["", "## Detection vs false alarms (thresholds from validation quantiles)", ""]
    lines += [
        "| estimator | rule | m | alpha | detected | false alarms / min |",
        "|---|---|---|---|---|---|",
    ]
    for name, res in est.items():
        for key, pts in res.get("roc", {}).items():
            rule, m = key.split("/m=")
            for p in pts:
                lines.append(
                    f"| {name} | {rule} | {m} | {p['alpha']:g} | {_f(p['rate_all'])} | "
                    f"{_f(p['false_alarms_per_minute'], 3)} |"
                )
    lines += ["", "## Thesis Fig. 4.3 scenario (max rule, m = 1)", ""]
    for name, res in est.items():
        if "scenario" in res:
            s = res["scenario"]
            det = ", ".join("yes" if d else "no" for d in s["detected"])
            lines.append(
                f"- {name}: pushes detected [{det}] (3 moving, 2 at rest); false alarms "
                f"{s['false_alarms']}"
            )
    lines += ["", "## Goals", ""]
    lines += [f"- {k}: {v}" for k, v in results["goals"].items()]
    lines += ["", "## Timing [s]", ""]
    lines += [f"- {k}: {v:.1f}" for k, v in results["timing"].items()]
    return "\n".join(lines) + "\n"


def strip(obj: Any) -> Any:
    """JSON-ready copy (drops ``_signals``, converts numpy)."""
    if isinstance(obj, dict):
        return {k: strip(v) for k, v in obj.items() if not str(k).startswith("_")}
    if isinstance(obj, list | tuple):
        return [strip(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj
