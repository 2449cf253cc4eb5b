"""Tables and plots of the kinematics learning benchmark
(:mod:`mcpilco.experiments.kinematics.bench`).

:func:`markdown_report` and :func:`plot_results` render the result dictionary of a run (the
parts of :mod:`mcpilco.experiments.kinematics.parts` that it holds, each with the command that
produced it); :func:`fk_seed_markdown` renders the seed study of part (c).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.experiments.kinematics.parts import ERR_NAMES, POSE_NAMES, PROPS

__all__ = ["THESIS_TABLE_2_1", "fk_seed_markdown", "markdown_report", "plot_results"]

# thesis Table 2.1 (real UR10): FK GP RMSE of x, y, z [m] and gamma, beta, alpha [rad]
THESIS_TABLE_2_1 = (0.0052, 0.0051, 0.0069, 0.0169, 0.0265, 0.0358)


def _selection_text(part: dict[str, Any]) -> str:
    """How a part's training samples were taken from ``D_tr`` (random when not recorded)."""
    if part.get("train_selection", "random") == "random":
        return "drawn at random, as in the thesis"
    return "picked by the greedy design on the prior variance of k_l"


def _protocol_line(part: dict[str, Any]) -> list[str]:
    """The marker protocol a part (b-d) ran with, as a Markdown line."""
    mp = part.get("marker_protocol")
    if mp is None:  # no protocol recorded: random orientations, every marker seen
        return ["Markers: uniformly random orientations, every marker seen from any side.", ""]
    face, vis = mp["facing_cone"], mp["visibility_cone"]
    text = (
        "uniformly random orientations"
        if face is None
        else f"attached facing the camera at home (within {face:g} deg)"
    )
    text += (
        ", every marker seen from any side"
        if vis is None
        else f"; a marker turned more than {vis:g} deg from the camera is not seen, and the "
        "waypoints (and targets) show every marker"
    )
    return [f"Markers: {text}.", ""]


def fk_seed_markdown(study: dict[str, Any], command: str) -> str:
    """Markdown table of :func:`fk_seed_study`."""

    def mm(v: list[float]) -> str:  # x, y, z cells in mm
        return " | ".join(f"{1e3 * x:.1f}" for x in v[:3])

    def rad(v: list[float]) -> str:  # gamma, beta, alpha cells in rad
        return " | ".join(f"{x:.3f}" for x in v[3:6])

    lines = [
        f"# FK GP over {len(study['seeds'])} seeds (part (c), thesis Table 2.1)",
        "",
        f"Command: `{command}`",
        "",
        *_protocol_line(study),
        f"{study['n_train']} training samples of D_tr per seed "
        f"({_selection_text(study)}), tested on D_test. RMSE "
        "against the measured poses: x, y, z in mm, gamma, beta, alpha in rad. Nine: the GP "
        "on all nine rotation elements projected onto SO(3) (same positions). Chain (beyond "
        "the thesis): one-joint GPs on the relative poses of consecutive markers of the "
        "identified chain, composed (`ChainForwardKinematicsGP`; the same frames, every "
        "marker in them).",
        "",
        "| seed | identified | x | y | z | gamma | beta | alpha | nine: gamma | beta | alpha "
        "| chain: x | y | z | gamma | beta | alpha | RBF x | y | z | noise x | y | z |",
        "|---|---|" + "---:|" * 21,
    ]
    rows = [(str(r["seed"]), "yes" if r["identified"] else "no", r) for r in study["rows"]]
    summ = study["summary"]
    for label, pick in (("mean", "mean"), ("min", "min"), ("max", "max")):
        rows.append(
            (
                label,
                "",
                {
                    k: summ[k][pick]
                    for k in ("polynomial", "nine_elements", "chain", "rbf", "noise")
                },
            )  # fmt: skip
        )
    for seed, ident, r in rows:
        lines.append(
            f"| {seed} | {ident} | {mm(r['polynomial'])} | {rad(r['polynomial'])} | "
            f"{rad(r['nine_elements'])} | {mm(r['chain'])} | {rad(r['chain'])} | "
            f"{mm(r['rbf'])} | {mm(r['noise'])} |"
        )
    g = study["goal"]
    n = len(study["seeds"])

    def per(key: str) -> str:  # seeds meeting the goal, per pose element
        met = g["met_per_axis"][key]
        return ", ".join(f"{name} {c}/{n}" for name, c in zip(POSE_NAMES, met, strict=True))

    lines += [
        "",
        f"Goal (<= {1e3 * g['position']:.0f} mm on x, y, z and <= {g['angle']} rad on each "
        f"angle), seeds meeting it: five elements {per('polynomial')}; all six on "
        f"{g['met_all']['polynomial']}/{n}. Nine elements {per('nine_elements')}; all six on "
        f"{g['met_all']['nine_elements']}/{n}. Chain {per('chain')}; all six on "
        f"{g['met_all']['chain']}/{n}.",
        "",
    ]

    def against_truth(key: str) -> str:  # mean and range over the seeds, x / y / z in mm
        t = summ[key]
        return (
            "mean "
            + " / ".join(f"{1e3 * x:.1f}" for x in t["mean"][:3])
            + " mm, range "
            + " / ".join(
                f"{1e3 * a:.1f}-{1e3 * b:.1f}"
                for a, b in zip(t["min"][:3], t["max"][:3], strict=True)
            )
            + " mm"
        )

    lines += [
        f"Against the truth: five elements {against_truth('polynomial_true')}; chain "
        f"{against_truth('chain_true')}.",
    ]
    return "\n".join(lines) + "\n"


def plot_results(res: dict[str, Any], out: Path) -> dict[str, str]:
    """Write the PNG plots of the parts in ``res`` under ``out``; returns their paths by name
    (``confusion``: part a, ``noise``: part b, ``controller``: part d)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = {}
    if "monte_carlo" in res:
        fig, axes = plt.subplots(1, 4, figsize=(14, 4.0))
        for ax, name in zip(axes, PROPS, strict=True):
            cm = np.array(res["monte_carlo"]["confusion"][name])
            ax.imshow(cm, cmap="Blues")
            for (i, j), v in np.ndenumerate(cm):
                ax.text(j, i, str(v), ha="center", va="center", fontsize=12)
            ax.set_xticks([0, 1], ["1", "2"])
            ax.set_yticks([0, 1], ["1", "2"])
            ax.set_xlabel("target class")
            ax.set_ylabel("output class")
            ax.set_title(f"Eq. {name}")
        fig.suptitle(f"Monte Carlo, {res['monte_carlo']['robots']} robots (thesis Fig. 2.4)")
        fig.tight_layout()
        paths["confusion"] = str(out / "kinematics_confusion.png")
        fig.savefig(paths["confusion"], dpi=100)
        plt.close(fig)
    if "noise_vs_samples" in res:
        rows = res["noise_vs_samples"]["rows"]
        fig, axes = plt.subplots(1, 3, figsize=(14, 3.6))
        for rep in sorted({r["repeat"] for r in rows}):
            rr = [r for r in rows if r["repeat"] == rep]
            s = [r["samples"] for r in rr]
            axes[0].plot(s, [r["misclassified"] for r in rr], "o-", label=f"repeat {rep}")
            for ax, name, xi in ((axes[1], "linear", 0.02), (axes[2], "angle", 0.1)):
                for c, color in (("r1", "tab:green"), ("r2", "tab:red")):
                    ax.plot(s, [r[f"{name}_{c}_mean"] for r in rr], "-", color=color)
                    ax.fill_between(
                        s,
                        [r[f"{name}_{c}_min"] for r in rr],
                        [r[f"{name}_{c}_max"] for r in rr],
                        color=color,
                        alpha=0.15,
                    )
                ax.axhline(xi, color="k", ls="--", lw=1)
        axes[0].set_ylabel("misclassified triplets")
        axes[1].set_ylabel("f_r linear revolute test (2.18) [m]")
        axes[2].set_ylabel("f_r non-linear test (2.19) [rad]")
        axes[1].set_yscale("log")
        axes[2].set_yscale("log")
        for ax in axes:
            ax.set_xlabel("samples")
        axes[0].legend()
        fig.suptitle("UR10 with noise: green f_r1 (connected), red f_r2 (not) (thesis Fig. 2.6)")
        fig.tight_layout()
        paths["noise"] = str(out / "kinematics_noise_vs_samples.png")
        fig.savefig(paths["noise"], dpi=100)
        plt.close(fig)
    if "controller" in res:
        rows = res["controller"]["rounds"]
        fig, ax = plt.subplots(figsize=(6, 3.6))
        for r in rows:
            ax.semilogy(range(1, 6), r["position_error_norm"], "o-", label=f"round {r['round']}")
        ax.set_xlabel("target")
        ax.set_ylabel("reached position error [m]")
        ax.legend()
        ax.set_title("Gradient kinematic controller (thesis Table 2.2)")
        fig.tight_layout()
        paths["controller"] = str(out / "kinematics_controller.png")
        fig.savefig(paths["controller"], dpi=100)
        plt.close(fig)
    return paths


def _fmt(values, digits=4) -> str:
    """Table cells of ``values``, ``digits`` decimals."""
    return " | ".join(f"{v:.{digits}f}" for v in values)


def _part_command(res: dict[str, Any], part: dict[str, Any]) -> list[str]:
    """``Command: ...`` line for a part produced by another command (merged results)."""
    cmd = part.get("command")
    return [f"Command: `{cmd}`", ""] if cmd and cmd != res["command"] else []


def markdown_report(res: dict[str, Any]) -> str:
    """The Markdown report of a run: one section per part in ``res``."""
    lines = [
        "# Kinematics learning benchmark (thesis chapter 2)",
        "",
        f"Command: `{res['command']}`",
        "",
    ]
    if "monte_carlo" in res:
        mc = res["monte_carlo"]
        lines += [
            "## (a) Monte Carlo, noiseless (section 2.6.1)",
            "",
            *_part_command(res, mc),
            f"{mc['robots']} robots x {mc['triplets'] // max(mc['robots'], 1)} triplets, "
            f"T = {mc['samples']}: **{mc['percent_correct']:.2f}% of {mc['triplets']} triplets "
            f"correct** ({mc['misclassified_triplets']} misclassified); structure recovered "
            f"from shuffled data on {mc['structures_recovered']} / {mc['robots']} robots.",
            "",
            "| test | TP | FP | FN | TN |",
            "|---|---|---|---|---|",
        ]
        for k in PROPS:
            (tp, fp), (fn, tn) = mc["confusion"][k]
            lines.append(f"| Eq. {k} | {tp} | {fp} | {fn} | {tn} |")
        lines.append("")
    if "noise_vs_samples" in res:
        lines += [
            "## (b) UR10 with noise: misclassified triplets vs samples (Fig. 2.6)",
            "",
            *_part_command(res, res["noise_vs_samples"]),
            *_protocol_line(res["noise_vs_samples"]),
            "| repeat | samples | misclassified / triplets | f_r1 lin (mean) | f_r2 lin (min) "
            "| f_r1 ang (mean) | f_r2 ang (min) |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in res["noise_vs_samples"]["rows"]:
            lines.append(
                f"| {r['repeat']} | {r['samples']} | {r['misclassified']} / {r['triplets']} | "
                f"{r['linear_r1_mean']:.4f} | {r['linear_r2_min']:.4f} | "
                f"{r['angle_r1_mean']:.4f} | {r['angle_r2_min']:.4f} |"
            )
        lines.append("")
    if "identification" in res:
        idn = res["identification"]
        lines += [
            "## UR10 structure identified on D_tr",
            "",
            f"{idn['samples']} samples: correct = **{idn['correct']}**, types "
            f"`{idn['joint_types']}`, {idn['seconds']:.1f} s."
            + (f" Frames dropped for a missing marker: {idn['dropped_frames']}."
               if idn.get("dropped_frames") else "")
            + (f" Error: {idn['error']}" if idn.get("error") else "")
            + (f" Note: {idn['note']}." if idn.get("note") else ""),
            "",
        ]  # fmt: skip
    if "fk_gp" in res:
        fk = res["fk_gp"]
        head = " | ".join(ERR_NAMES)
        lines += [
            f"## (c) FK GP, {fk['n_train']} training samples, {fk['n_test']} test samples "
            "(Table 2.1)",
            "",
            f"Training samples {_selection_text(fk)}.",
            "",
            *_part_command(res, fk),
            *(_protocol_line(fk) if res.get("measurement", "ideal") == "ideal" else []),
            *(
                [
                    f"Measurement: **{res['measurement']}** (rendered images + ArUco "
                    "detection). End marker found in "
                    f"{fk['end_marker_measured']['train']} of "
                    f"{fk['end_marker_measured']['train_frames']} D_tr frames and "
                    f"{fk['end_marker_measured']['test']} of "
                    f"{fk['end_marker_measured']['test_frames']} D_test frames; training "
                    "samples and test samples are drawn from those.",
                    "",
                ]
                if res.get("measurement", "ideal") != "ideal"
                else []
            ),
            f"| model | {head} |",
            "|---|" + "---|" * 7,
            f"| thesis Table 2.1 (real UR10) | {_fmt(THESIS_TABLE_2_1)} | - |",
            f"| polynomial k_R/k_l vs measured | {_fmt(fk['polynomial_rmse_measured'])} |",
            f"| polynomial k_R/k_l vs true | {_fmt(fk['polynomial_rmse_true'])} |",
        ]
        if "trimmed_rmse_true" in fk:
            lines += [
                f"| polynomial, outlier-trimmed (LOO score > {fk['trimmed_threshold']:g}, "
                f"{fk['trimmed_outliers']} of {fk['n_train']} dropped), vs measured | "
                f"{_fmt(fk['trimmed_rmse_measured'])} |",
                f"| polynomial, outlier-trimmed, vs true | {_fmt(fk['trimmed_rmse_true'])} |",
            ]
        if "nine_elements_rmse_true" in fk:
            lines += [
                "| polynomial, nine elements + SO(3) projection, vs measured | "
                f"{_fmt(fk['nine_elements_rmse_measured'])} |",
                "| polynomial, nine elements + SO(3) projection, vs true | "
                f"{_fmt(fk['nine_elements_rmse_true'])} |",
            ]
        if "chain_rmse_true" in fk:
            lines += [
                "| chain of one-joint GPs (every marker of the same frames), vs measured | "
                f"{_fmt(fk['chain_rmse_measured'])} |",
                f"| chain of one-joint GPs, vs true | {_fmt(fk['chain_rmse_true'])} |",
            ]
        elif "chain_error" in fk:
            cells = " - |" * 7
            lines.append(f"| chain of one-joint GPs: not fitted ({fk['chain_error']}) |{cells}")
        lines += [
            f"| RBF on raw q vs measured | {_fmt(fk['rbf_rmse_measured'])} |",
            f"| RBF on raw q vs true | {_fmt(fk['rbf_rmse_true'])} |",
            f"| measurement noise (measured vs true) | {_fmt(fk['measurement_noise_rmse'])} |",
        ]
        rows = fk.get("noise_free_training_rmse_true") or {
            f"{fk['n_train']} samples of D_tr": fk["polynomial_noiseless_training_rmse_true"]
        }
        for name, v in rows.items():
            lines.append(f"| polynomial, noise-free training: {name}, vs true | {_fmt(v)} |")
        lines += [
            f"| polynomial vs true, {fk['small_beta_test_samples']} test samples with "
            f"abs(beta) < 1 | {_fmt(fk['polynomial_rmse_true_small_beta'])} |",
        ]
        if "nine_elements_rmse_true_small_beta" in fk:
            lines.append(
                "| nine elements vs true, same samples | "
                f"{_fmt(fk['nine_elements_rmse_true_small_beta'])} |"
            )
        lines += [
            "| measurement noise, same samples | "
            f"{_fmt(fk['measurement_noise_rmse_small_beta'])} |",
            "",
            "Units: m for x, y, z; rad for gamma, beta, alpha and the geodesic angle "
            "between the predicted and the reference orientation.",
            "",
        ]
        if "measurement_noise" in fk:
            mn = fk["measurement_noise"]
            lines += [
                f"End-marker measurement noise on D_test: {_fmt(mn['position_rmse_per_axis'])} m "
                f"per axis, {mn['position_rmse_3d']:.4f} m as a 3-D norm, "
                f"{mn['geodesic_rmse']:.4f} rad geodesic (RMS). The marker is "
                f"{mn['distance_mean']:.2f} m from the camera on average "
                f"({mn['distance_range'][0]:.2f}-{mn['distance_range'][1]:.2f} m), mean "
                f"abs(cos theta) = {mn['abs_cos_incidence_mean']:.2f}: noise scale "
                f"f = {mn['scale_mean']:.2f} on average (1 = {mn['reference_position_std']:.4g} m "
                f"per axis and {mn['reference_angle_std']:.4g} rad per rotation-vector component "
                "at 2 m, face-on).",
                "",
            ]
        if fk.get("feature_rank", {}).get("D_tr") is not None:
            r = fk["feature_rank"]
            lines += [
                f"Numerical rank (1e-8) of the {r['monomials']} monomials of k_R on D_tr: "
                f"{r['D_tr']}; on as many i.i.d. configurations in the waypoint box: "
                f"{r['iid_same_size']}.",
                "",
            ]
    if "controller" in res:
        c = res["controller"]
        lines += [
            f"## (d) Controller, 5 targets, GP on {c['n_train']} samples of D_tr (Table 2.2)",
            "",
            f"Training samples {_selection_text(c)}.",
            "",
            *_part_command(res, c),
            *_protocol_line(c),
            f"Extra starts: {c.get('starts', 0)} nearest data configurations; q_des clipped to "
            f"the data's joint box: {c.get('limit_to_data', False)}; orientation error in e_p: "
            f"{c.get('orientation', 'ypr')}; rotation outputs: "
            f"{c.get('rotation_outputs', 'five')}; FK model: {c.get('fk_model', 'end')}; "
            "online rounds start from: "
            f"{c.get('refine', 'restart')}; frames measured at rest after each reference: "
            f"{c.get('hold', 0)}. RMSE of the reached pose (one frame at arrival) "
            "as measured by the camera (as in the thesis) and against the true pose.",
            "",
            f"| data | {' | '.join(ERR_NAMES)} |",
            "|---|" + "---|" * 7,
            "| thesis D_tr | 0.0065 | 0.0111 | 0.0228 | 0.1853 | 0.0853 | 0.1167 | - |",
            "| thesis D̄_tr | 0.0017 | 0.0016 | 0.0020 | 0.0988 | 0.0269 | 0.0419 | - |",
        ]
        for r in c["rounds"]:
            seen = r.get("arrivals_seen", 5)
            label = "measured" if seen == 5 else f"measured ({seen} of 5 arrivals seen)"
            lines.append(
                f"| round {r['round']} ({r['n_data']} samples), {label} | "
                + ("- | " * 7 if r["rmse"] is None else f"{_fmt(r['rmse'])} |")
            )
            if "rmse_true" in r:
                lines.append(f"| round {r['round']}, true | {_fmt(r['rmse_true'])} |")
        lines.append("")
        if c["rounds"] and "predicted_error" in c["rounds"][0]:
            lines += ["| round | predicted e_p per target | true position error [m] | start |",
                      "|---|---|---|---|"]  # fmt: skip
            for r in c["rounds"]:
                lines.append(
                    f"| {r['round']} | {', '.join(f'{v:.4f}' for v in r['predicted_error'])} | "
                    f"{', '.join(f'{v:.4f}' for v in r['position_error_norm_true'])} | "
                    f"{', '.join('prev' if v < 0 else str(v) for v in r['chosen_start'])} |"
                )
            lines.append("")
    lines.append(f"Total time: {res['seconds']:.0f} s.")
    return "\n".join(lines) + "\n"
