"""Figures and the Markdown report of the inverse-dynamics benchmark.

:func:`plot_scara` (nMSE boxplots per joint with the noise floor), :func:`plot_efficiency`
(test GMSE against the training-set size), :func:`plot_ur10` (nMSE per joint on the UR10
motor currents), :func:`goals` (the benchmark's targets, recorded, not asserted) and
:func:`markdown`, on the results dict of
:func:`mcpilco.experiments.identification.inverse_dynamics.run_benchmark`.
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

# an estimator's name in the figures' legends, in words (the tables keep the short names)
ESTIMATOR_LABELS: dict[str, str] = {
    "FE": "rigid body, least squares (FE)",
    "PP": "GP, rigid-body prior (PP)",
    "SP": "GP, rigid-body prior + RBF (SP)",
    "GIP": "GP, GIP kernel",
    "RBF": "GP, RBF kernel",
    "NN": "neural network (MLP)",
    "GIP+F": "GP, GIP kernel + friction",
}


def _summary(values: Sequence[Sequence[float]]) -> list[tuple[float, float, float]]:
    """Per joint: (median, first quartile, third quartile)."""
    arr = np.asarray(values, dtype=np.float64)
    q = np.percentile(arr, [50, 25, 75], axis=0)
    return [tuple(float(v) for v in q[:, j]) for j in range(arr.shape[1])]


def plot_scara(res: dict[str, Any], path: Path) -> None:
    """Boxplots of the ``scara`` part's test nMSE per joint and estimator, log scale."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(res["nmse"])
    n = len(res["nmse"][names[0]][0])
    fig, axes = plt.subplots(1, n, figsize=(3.2 * n, 3.6), sharey=True)
    floor = np.median(np.asarray(res["noise_floor"]), axis=0)
    for j, ax in enumerate(np.atleast_1d(axes)):
        data = [np.asarray(res["nmse"][k])[:, j] for k in names]
        ax.boxplot(data, tick_labels=names)
        ax.axhline(floor[j], color="gray", ls=":", label="noise floor")
        ax.set_yscale("log")
        ax.set_title(f"joint {j + 1} ({res['joint_types'][j]})")
        ax.tick_params(axis="x", rotation=45)
        ax.grid(True, which="both", alpha=0.3)
    np.atleast_1d(axes)[0].set_ylabel("test nMSE")
    np.atleast_1d(axes)[0].legend(fontsize=7)
    fig.suptitle(f"SCARA, {res['runs']} runs, {res['n_train']} training samples, model bias")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_efficiency(res: dict[str, Any], path: Path) -> None:
    """Test GMSE against the training-set size (log-log) with the noise floor."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 4))
    for name, vals in res["gmse"].items():
        ax.loglog(res["sizes"], vals, "o-", label=ESTIMATOR_LABELS.get(name, name))
    ax.axhline(res["noise_gmse_floor"], color="gray", ls=":", label="noise")
    ax.set_xlabel("training samples")
    ax.set_ylabel("test GMSE [N^2 m^2]")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    ax.set_title("SCARA data efficiency (no model bias)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_ur10(res: dict[str, Any], path: Path) -> None:
    """Bars of the ``ur10`` part's test nMSE per joint and estimator with the noise floor."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(res["nmse"])
    n = len(res["noise_floor"])
    fig, ax = plt.subplots(figsize=(10, 4))
    width = 0.8 / max(len(names), 1)
    joints = np.arange(1, n + 1)
    for k, name in enumerate(names):
        x = joints + (k - len(names) / 2 + 0.5) * width
        ax.bar(x, res["nmse"][name], width, label=ESTIMATOR_LABELS.get(name, name))
    ax.plot(joints, res["noise_floor"], "k_", ms=20, mew=2, label="noise floor")
    ax.set_yscale("log")
    ax.set_xlabel("joint")
    ax.set_ylabel("test nMSE (motor currents)")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # beside the bars
    ax.set_title(f"UR10 env: {res['n_train']} train ({res['n_gp']} for the GPs)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fmt(v: float) -> str:
    """A table number in scientific notation."""
    return f"{v:.2e}"


def markdown(results: dict[str, Any]) -> str:
    """The Markdown report of the results dict."""
    lines = ["# Inverse dynamics benchmark (thesis section 3.4)", ""]
    cfg = results["config"]
    lines.append(
        f"Machine: {results['machine']}; torch threads {cfg['threads']}; seed {cfg['seed']}; "
        f"total {results['seconds']:.0f} s."
    )
    lines.append("")
    if "scara" in results:
        res = results["scara"]
        n = len(res["noise_floor"][0])
        lines += [
            f"## SCARA ({res['joint_types']}), {res['runs']} Monte Carlo runs, model bias",
            "",
            f"{res['n_train']} training / {res['n_test']} test samples; test nMSE per joint: "
            "median [first quartile, third quartile]; fit time median.",
            "",
            "| estimator | " + " | ".join(f"joint {j + 1}" for j in range(n)) + " | fit s |",
            "|---" * (n + 2) + "|",
        ]
        for name, vals in res["nmse"].items():
            cells = [f"{_fmt(m)} [{_fmt(a)}, {_fmt(b)}]" for m, a, b in _summary(vals)]
            t = statistics.median(res["fit_seconds"][name])
            lines.append(f"| {name} | " + " | ".join(cells) + f" | {t:.1f} |")
        floor = np.median(np.asarray(res["noise_floor"]), axis=0)
        lines.append("| noise floor | " + " | ".join(_fmt(v) for v in floor) + " | |")
        lines.append("")
        goals = results.get("goals", {}).get("scara", {})
        for k, v in goals.items():
            lines.append(f"- {k}: {v}")
        lines.append("")
    if "efficiency" in results:
        res = results["efficiency"]
        lines += [
            "## Data efficiency (SCARA, no model bias): test GMSE",
            "",
            "| N | " + " | ".join(res["gmse"]) + " |",
            "|---" * (len(res["gmse"]) + 1) + "|",
        ]
        for k, size in enumerate(res["sizes"]):
            lines.append(
                f"| {size} | " + " | ".join(_fmt(v[k]) for v in res["gmse"].values()) + " |"
            )
        lines += ["", f"- noise GMSE floor: {_fmt(res['noise_gmse_floor'])}"]
        for k, v in res["summary"].items():
            lines.append(f"- {k}: {v}")
        lines.append("")
    if "ur10" in results:
        res = results["ur10"]
        n = len(res["noise_floor"])
        lines += [
            "## UR10 env (motor currents)",
            "",
            f"{res['n_train']} training samples (exploration; GPs on {res['n_gp']} with a "
            f"constant step), {res['n_test']} test samples ({res['n_test_circle']} from the "
            "circle); test nMSE per joint.",
            "",
            "| estimator | " + " | ".join(f"joint {j + 1}" for j in range(n)) + " | fit s |",
            "|---" * (n + 2) + "|",
        ]
        for name, vals in res["nmse"].items():
            t = res["fit_seconds"][name]
            lines.append(f"| {name} | " + " | ".join(_fmt(v) for v in vals) + f" | {t:.1f} |")
        lines.append("| noise floor | " + " | ".join(_fmt(v) for v in res["noise_floor"]) + " | |")
        lines.append("")
    if "timing" in results:
        res = results["timing"]
        lines += [
            f"## Timing: GIP, N = {res['n']}, {res['joints']} joints",
            "",
            "| quantity | seconds |",
            "|---|---|",
            f"| hyperparameter training ({res['adam_iters']} Adam + {res['lbfgs_iters']} "
            f"L-BFGS iterations) | {res['train_seconds']:.2f} |",
            f"| per iteration | {res['train_seconds_per_iteration']:.3f} |",
            f"| prediction of {res['n']} points (mean + variance) | {res['predict_seconds']:.2f} |",
            f"| one fp64 Cholesky {res['n']}x{res['n']} (floor) | {res['cholesky_seconds']:.4f} |",
            f"| {res['joints']} batched Choleskys | {res['cholesky_batch_seconds']:.4f} |",
        ]
        gram = res.get("gram_forward_backward_seconds")
        if gram:
            lines += [
                f"| GIP Gram matrix forward + backward, blocked (used) | {gram['blocked']:.2f} |",
                f"| the same by plain autograd over the MPK factors | {gram['autograd']:.2f} |",
                f"| ratio plain / blocked | {gram['ratio']:.1f}x |",
            ]
        lines.append("")
    return "\n".join(lines) + "\n"


def goals(results: dict[str, Any]) -> dict[str, Any]:
    """The benchmark's targets on the ``scara`` part, each checked (recorded, not asserted)."""
    out: dict[str, Any] = {}
    if "scara" in results:
        res = results["scara"]["nmse"]
        med = {k: np.median(np.asarray(v), axis=0) for k, v in res.items()}
        g: dict[str, Any] = {}
        if "GIP" in med:
            g["GIP median nMSE < 1% on every joint"] = bool(np.all(med["GIP"] < 0.01))
            for other in ("RBF", "NN"):
                if other in med:
                    ratio = med[other] / med["GIP"]
                    g[f"{other}/GIP median nMSE ratio per joint"] = [
                        round(float(r), 1) for r in ratio
                    ]
                    g[f"GIP below {other} by >= 10x on every joint"] = bool(np.all(ratio >= 10))
        out["scara"] = g
    return out
