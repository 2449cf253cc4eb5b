"""The headline figure of MC-PILCO on the cart-pole swing-up, drawn from the result files.

``results/mcpilco_cartpole.png`` answers two questions a user asks first, on shared axes:

* left, *how much experience does MC-PILCO need?* The swing-up success rate against seconds
  of interaction, with 95 % Wilson bands over the seeds, for the default settings on the
  development seeds and on seeds no setting was chosen on, and the thesis's Table 5.1;
* right, *against the alternatives?* The same success rate of MC-PILCO, TorchRL's PILCO and
  SB3's SAC / TD3 / PPO on one logarithmic experience axis, with 95 % percentile-bootstrap
  bands over the seeds (each seed's success rate is the unit).

Every other section of the benchmark (ablations, other presets) stays in the Markdown report
and ``mcpilco_cartpole_sections.png``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.experiments.results import Result, read_result, seed_ranges
from mcpilco.models.stats import bootstrap_interval, wilson_interval

# Thesis Table 5.1: MC-PILCO's success rates on PILCO's cart-pole after 3 / 6 / 9 / 12 s of
# training data (the policy trained on that data is the trial scored, so its experience on
# this figure's axis is 3 s more).
THESIS_TABLE_5_1 = {"training_s": (3.0, 6.0, 9.0, 12.0), "success": (0.038, 0.385, 0.692, 0.885)}
TRIAL_S = 3.0  # one cart-pole trial [s]
# The sections of mcpilco_cartpole.json on the headline, with their legends' words.
HEADLINE_SECTIONS = (
    ("mcpilco/CartpoleSwingUp-v0 (hold2)", "MC-PILCO, default settings", "development seeds"),
    (
        "mcpilco/CartpoleSwingUp-v0 (fresh100)",
        "MC-PILCO, default settings, compiled rollout",
        "not used for tuning",
    ),
)
COMPARE_FILE = "compare_CartpoleSwingUp-v0_hold2_sb3.json"  # the baselines on the same task
METHOD_WORDS = {  # legend words of the comparison's methods
    "mcpilco": "MC-PILCO",
    "pilco": "PILCO (TorchRL example settings)",
    "sac": "SAC (SB3)",
    "td3": "TD3 (SB3)",
    "ppo": "PPO (SB3)",
}


def success_band(section: dict[str, Any]) -> dict[str, np.ndarray]:
    """Experience, success rate and its 95 % Wilson band over the seeds of a runs section."""
    rows = section["per_trial"]
    n = np.array([r.get("seeds", len(section["seeds"])) for r in rows])  # seeds scored
    rate = np.array([r["success_rate"] for r in rows])
    k = np.rint(rate * n).astype(int)
    band = np.array([wilson_interval(int(a), int(b)) for a, b in zip(k, n, strict=True)])
    return {
        "t": np.array([r["experience_s"] for r in rows]),
        "rate": rate,
        "lo": band[:, 0],
        "hi": band[:, 1],
    }


def method_band(curves: list[dict[str, Any]], method: str, grid: np.ndarray) -> dict[str, Any]:
    """Mean success rate of ``method``'s seeds on ``grid`` (each seed's last evaluation held)
    with its 95 % percentile-bootstrap band over the seeds."""
    per_seed = []
    for c in curves:
        if c["method"] != method:
            continue
        t = np.array([p["experience_s"] for p in c["points"]])
        s = np.array([p["success_rate"] for p in c["points"]], dtype=float)
        idx = np.searchsorted(t, grid, side="right") - 1
        held = np.where(idx >= 0, s[np.clip(idx, 0, None)], np.nan)
        per_seed.append(np.where(grid <= t[-1], held, np.nan))  # nothing past its budget
    values = np.array(per_seed)
    seen = np.isfinite(values).any(axis=0)
    mean = np.full(grid.shape, np.nan)
    mean[seen] = np.nanmean(values[:, seen], axis=0)
    band = np.array(
        [bootstrap_interval(col, "mean") if np.isfinite(col).any() else (np.nan,) * 2
         for col in values.T]
    )  # fmt: skip
    seeds = sorted({c["seed"] for c in curves if c["method"] == method})
    return {"t": grid, "rate": mean, "lo": band[:, 0], "hi": band[:, 1], "seeds": seeds}


def plot_headline(bench: Result, compare: Result | None, path: str | Path) -> Path:
    """Draw the headline figure (module docstring) to ``path``; the right panel only when the
    comparison's result ``compare`` is given."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = 2 if compare is not None else 1
    fig, axes = plt.subplots(1, panels, figsize=(6.2 * panels, 4.6), squeeze=False)
    ax = axes[0, 0]
    for (key, words, seed_words), colour in zip(HEADLINE_SECTIONS, ("C0", "C2"), strict=True):
        section = bench["runs"][key]
        b = success_band(section)
        label = f"{words}, seeds {seed_ranges(section['seeds'])} ({seed_words})"
        ax.plot(b["t"], 100 * b["rate"], "o-", color=colour, label=label)
        ax.fill_between(b["t"], 100 * b["lo"], 100 * b["hi"], color=colour, alpha=0.18, lw=0)
    thesis_t = np.array(THESIS_TABLE_5_1["training_s"]) + TRIAL_S
    ax.plot(
        thesis_t,
        100 * np.array(THESIS_TABLE_5_1["success"]),
        "k^--",
        label="thesis Table 5.1 (MC-PILCO on PILCO's cart-pole)",
    )
    ax.set_title("How much experience MC-PILCO needs (bands: 95 % Wilson)", fontsize=10)
    ax.set_xlabel("experience [s of interaction]")
    ax.set_ylabel("swing-up success [% of seeds]")
    ax.set_ylim(-3, 103)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7.5, loc="upper left")
    if compare is not None:
        ax = axes[0, 1]
        curves = compare["curves"]
        t_max = max(p["experience_s"] for c in curves for p in c["points"])
        grid = np.geomspace(3.0, t_max, 200)
        for i, method in enumerate(m for m in METHOD_WORDS if m in compare["methods"]):
            b = method_band(curves, method, grid)
            label = f"{METHOD_WORDS[method]}, seeds {seed_ranges(b['seeds'])}"
            ax.step(b["t"], 100 * b["rate"], where="post", color=f"C{i}", label=label)
            ax.fill_between(
                b["t"], 100 * b["lo"], 100 * b["hi"], step="post", color=f"C{i}", alpha=0.12, lw=0
            )
        ax.axhline(90, color="0.4", ls=":", lw=1)
        ax.set_xscale("log")
        ax.set_title("Against the alternatives (bands: 95 % bootstrap over seeds)", fontsize=10)
        ax.set_xlabel("experience [s of interaction, log scale]")
        ax.set_ylabel("success [mean over seeds, %]")
        ax.set_ylim(-3, 103)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7.5, loc="center right")
    fig.suptitle("MC-PILCO, cart-pole swing-up (MuJoCo)", fontsize=11)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def replot_headline(results_dir: str | Path) -> Path:
    """Redraw ``mcpilco_cartpole.png`` from the result files in ``results_dir``."""
    results_dir = Path(results_dir)
    compare_path = results_dir / COMPARE_FILE
    compare = read_result(compare_path) if compare_path.is_file() else None
    bench = read_result(results_dir / "mcpilco_cartpole.json")
    return plot_headline(bench, compare, results_dir / "mcpilco_cartpole.png")
