"""Summary, Markdown table and boxplots of the Volterra benchmark's per-run results.

:func:`collect` groups the per-run Fit% by experiment, configuration and kernel and
summarises them (runs, failures, median, mean, quartiles); :func:`markdown_table` and
:func:`plot_exp1` / :func:`plot_exp2` present them
(:func:`mcpilco.experiments.identification.volterra.run_benchmark` writes them).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

ORACLE = "ls_oracle"
"""Key of the experiment-1 reference estimator (least squares on the true monomials,
:func:`mcpilco.experiments.identification.volterra.oracle_prediction`) in the results."""


def result_order(res: dict) -> tuple:
    """Sort key: experiment, then configuration (numeric order for ``r{r}_snr{snr}``), run."""
    cfg = res["config"]
    if res["experiment"] == 2:
        r, snr = cfg[1:].split("_snr")
        return (2, int(r), float(snr), "", res["run"])
    return (res["experiment"], 0, 0.0, cfg, res["run"])


def collect(results: list[dict], experiments: tuple[int, ...], exp1: dict, exp2: dict) -> dict:
    """Per-configuration lists of Fit% (ordered by run) and summary statistics."""
    per: dict[str, dict[str, dict[str, list]]] = {}
    for res in sorted(results, key=result_order):
        key = f"exp{res['experiment']}"
        cfg = per.setdefault(key, {}).setdefault(res["config"], {})
        for kind, fit in res["fit"].items():
            cfg.setdefault(kind, []).append(fit)
    summary: dict[str, dict] = {}
    for ek, configs in per.items():
        for cname, kinds in configs.items():
            for kind, fits in kinds.items():
                vals = np.array([f for f in fits if f is not None], dtype=float)
                summary.setdefault(ek, {}).setdefault(cname, {})[kind] = {
                    "runs": len(fits),
                    "failed": int(sum(f is None for f in fits)),
                    "median": float(np.median(vals)) if vals.size else None,
                    "mean": float(vals.mean()) if vals.size else None,
                    "q25": float(np.percentile(vals, 25)) if vals.size else None,
                    "q75": float(np.percentile(vals, 75)) if vals.size else None,
                }
    return {"fits": per, "summary": summary}


def _fmt(x: float | None) -> str:
    return "—" if x is None else f"{x:.1f}"


def markdown_table(summary: dict, meta: dict) -> str:
    """Markdown report: median / mean Fit% per kernel and configuration."""
    lines = ["# Volterra series identification benchmark (thesis section 6.5)", ""]
    lines.append(
        f"Command: `{meta['command']}`; base seed {meta['base_seed']}, "
        f"{meta['jobs']} worker process(es), wall time {meta['wall_s']:.0f} s"
        + (
            f" ({meta['runs_reused']} runs reused from earlier result files, not counted)"
            if meta.get("runs_reused")
            else ""
        )
        + f"; total fit+predict compute over all runs {meta.get('compute_s', 0.0):.0f} s "
        "(1 thread per run)."
    )
    lines.append("")
    if "exp1" in summary:
        c = meta["exp1"]
        lines += [
            "## Experiment 1: system (6.36), m = 6, r = 3",
            "",
            f"{c['n_train']} train / {c['n_test']} test samples, sigma_n = {c['noise_std']:g}; "
            f"ML on {'all' if c['ml_points'] is None else c['ml_points']} training samples, "
            f"Adam {c['adam_iters']} it (lr {c['adam_lr']}) + L-BFGS {c['lbfgs_iters']} it. "
            "Fit% on the noiseless test output.",
            "",
            "| setup | kernel | runs | median Fit% | mean Fit% | IQR |",
            "|---|---|---:|---:|---:|---|",
        ]
        for cname, kinds in summary["exp1"].items():
            for kind, s in kinds.items():
                fail = f" ({s['failed']} failed)" if s["failed"] else ""
                lines.append(
                    f"| {cname} | {kind.upper()} | {s['runs']}{fail} | {_fmt(s['median'])} | "
                    f"{_fmt(s['mean'])} | [{_fmt(s['q25'])}, {_fmt(s['q75'])}] |"
                )
        if any(ORACLE in kinds for kinds in summary["exp1"].values()):
            lines += [
                "",
                f"{ORACLE.upper()}: least squares on the 14 monomials of (6.36), the true "
                "structure (no kernel); a reference for what the data allow.",
            ]
        lines.append("")
    if "exp2" in summary:
        c = meta["exp2"]
        lines += [
            "## Experiment 2: Wiener system (6.38), m = 70",
            "",
            f"{c['n_train']} train / {c['n_test']} test samples, unit Gaussian input; "
            "SNR = 10 log10(var(z_train) / sigma_n^2). Hyperparameters by marginal likelihood on "
            f"a random subset of {min(c['ml_points'] or c['n_train'], c['n_train'])} training "
            f"samples (Adam {c['adam_iters']} it, "
            f"lr {c['adam_lr']}, + L-BFGS {c['lbfgs_iters']} it), prediction conditioned on all "
            f"{c['n_train']}.",
            "",
            "| r | SNR (dB) | kernel | runs | median Fit% | mean Fit% | IQR |",
            "|---:|---:|---|---:|---:|---:|---|",
        ]
        for cname, kinds in summary["exp2"].items():
            r, snr = cname[1:].split("_snr")
            for kind, s in kinds.items():
                fail = f" ({s['failed']} failed)" if s["failed"] else ""
                lines.append(
                    f"| {r} | {snr} | {kind.upper().replace('_', '-')} | "
                    f"{s['runs']}{fail} | {_fmt(s['median'])} | {_fmt(s['mean'])} | "
                    f"[{_fmt(s['q25'])}, {_fmt(s['q75'])}] |"
                )
        lines.append("")
    return "\n".join(lines)


# a kernel's name under its box, in words
KERNEL_LABELS: dict[str, str] = {
    "mpk": "MPK",
    "sed_mpk_tied": "SED-MPK",
    "sed_mpk": "SED-MPK (untied)",
}


def _box(ax, groups: list[list[float]], labels: list[str], title: str) -> None:
    data = [[v for v in g if v is not None] or [np.nan] for g in groups]
    ax.boxplot(data, tick_labels=labels)
    finite = [v for g in data for v in g if np.isfinite(v)]
    if finite:
        lo = max(min(finite) - 5.0, -100.0)
        ax.set_ylim(lo, 102.0)
    ax.set_title(title)
    ax.set_ylabel("Fit %")
    ax.grid(axis="y", alpha=0.3)


def plot_exp1(fits: dict, path: Path) -> None:
    """Boxplots of Fit% per kernel, one panel per setup."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    configs = list(fits)
    fig, axes = plt.subplots(1, len(configs), figsize=(5 * len(configs), 4), squeeze=False)
    for ax, cname in zip(axes[0], configs, strict=True):
        kinds = list(fits[cname])
        n = len(fits[cname][kinds[0]])
        _box(ax, [fits[cname][k] for k in kinds], [k.upper() for k in kinds], f"{cname} ({n} runs)")
    fig.suptitle("Experiment 1: system (6.36)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_exp2(fits: dict, path: Path) -> None:
    """Boxplots of Fit% per order and kernel, one panel per SNR."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    by_snr: dict[str, list[str]] = {}
    for cname in fits:
        by_snr.setdefault(cname.split("_snr")[1], []).append(cname)
    fig, axes = plt.subplots(1, len(by_snr), figsize=(7 * len(by_snr), 4), squeeze=False)
    for ax, (snr, cnames) in zip(axes[0], by_snr.items(), strict=True):
        groups, labels = [], []
        for cname in cnames:
            for kind, vals in fits[cname].items():
                groups.append(vals)
                name = KERNEL_LABELS.get(kind, kind.upper())
                labels.append(f"{name}\norder {cname.split('_')[0].lstrip('r')}")
        n = max(len(g) for g in groups)
        _box(ax, groups, labels, f"SNR {snr} dB ({n} runs)")
    fig.suptitle("Experiment 2: Wiener system (6.38)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
