"""Quasi-static friction on the simulated UR10: the thesis's Figure 4.1 experiment.

Only joint 1 moves (quintic rest-to-rest moves of different durations), between rest phases
at ``q1 = 0.52 -> pi/2 -> 2.09 -> pi/2 -> 0.52 -> pi/2`` rad, with the arm stretched
horizontally (``q2 = q3 = 0``; thesis: "all the joints stuck and parallel to the ground").
Joint 1 has a vertical axis, so gravity puts no torque on it and at rest the ideal current
is 0. Stiction (``F_s = 1.3 F_c``, held by MuJoCo's dry-friction constraint) stops the joint
short of its reference; the PD controller's error ``e_q`` then holds a torque
``K_p e_q`` with ``|K_p e_q| <= F_s``, so the measured current at rest depends on how the
joint arrived: the same configuration ``x = (q, 0, 0)`` gives different currents ``i_1``.

:func:`run` rolls the program out; :func:`write_outputs` writes
``collision_quasi_static.png`` (``q1``, ``qd1``, ``i1``; the rest phases at ``pi/2`` shaded),
``collision_quasi_static.json`` and ``.md`` (mean and std of ``i1`` in every rest phase).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.envs.arm_data import PiecewiseTrajectory, QuinticMove, rollout
from mcpilco.envs.arm_env import UR10Env
from mcpilco.experiments.results import Headline, ResultLayout, write_result

__all__ = ["MOVE_SECONDS", "POSE", "REST_POSES", "markdown", "plot", "reference", "run",
           "write_outputs"]  # fmt: skip

# q1 of the rest phases [rad] (thesis section 4.4.2: pi/2, 2.09, pi/2, 0.52, ...)
REST_POSES = (0.52, math.pi / 2, 2.09, math.pi / 2, 0.52, math.pi / 2)
# durations of the five moves between the rest phases [s] (different speeds)
MOVE_SECONDS = (2.0, 3.0, 4.0, 2.5, 3.5)
# joints 2..6 during the experiment (arm stretched horizontally); joint 1 is replaced
POSE = (0.0, 0.0, 0.0, -math.pi / 2, -math.pi / 2, 0.0)


def reference(rest_seconds: float = 4.0) -> tuple[PiecewiseTrajectory, list[tuple[float, float]]]:
    """The joint-1 program and the ``(start, end)`` times of its rest phases [s]."""
    q = np.array(POSE)
    q[0] = REST_POSES[0]
    pieces = [QuinticMove(q, q, rest_seconds)]
    rests = [(0.0, rest_seconds)]
    t = rest_seconds
    for target, move in zip(REST_POSES[1:], MOVE_SECONDS, strict=True):
        q1 = q.copy()
        q1[0] = target
        pieces += [QuinticMove(q, q1, move), QuinticMove(q1, q1, rest_seconds)]
        t += move
        rests.append((t, t + rest_seconds))
        t += rest_seconds
        q = q1
    return PiecewiseTrajectory(pieces), rests


def run(seed: int = 0, rest_seconds: float = 4.0, settle: float = 1.0) -> dict[str, Any]:
    """Roll the program out on ``UR10Env`` (its defaults: friction on, 0.17 A current
    noise); the statistics of each rest phase skip its first ``settle`` seconds."""
    if rest_seconds <= settle:
        raise ValueError(
            f"rest_seconds must be > settle = {settle} s (the start of a rest is settling)"
        )
    env = UR10Env()
    ref, rests = reference(rest_seconds)
    out = rollout(env, ref, seed=seed)
    t, i1 = out["t"], out["i"][:, 0]
    phases = []
    for (a, b), q1 in zip(rests, REST_POSES, strict=True):
        m = (t >= a + settle) & (t <= b)  # skip the settling
        phases.append(
            {
                "q1_ref": q1,
                "start": a,
                "end": b,
                "i1_mean": float(i1[m].mean()),
                "i1_std": float(i1[m].std()),
                "e_q1_mean": float(out["e_q"][m, 0].mean()),
                "max_abs_qd1": float(np.abs(out["qd"][m, 0]).max()),
                "n": int(m.sum()),
            }
        )
    return {
        "seed": seed,
        "kp1": float(env.kp[0]),
        "current_gain1": float(env.current_gain[0]),
        "static_friction1": float(env.arm.joints[0].static_friction),
        "current_noise_std": float(env.current_noise_std[0]),
        "stiction_band_A": float(env.arm.joints[0].static_friction / env.current_gain[0]),
        "phases": phases,
        "arrays": {k: out[k] for k in ("t", "q", "qd", "i")},
    }


def plot(res: dict[str, Any], path: Path) -> None:
    """``q1``, ``qd1`` and ``i1`` against time, the rest phases at ``pi/2`` shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a = res["arrays"]
    t = a["t"]
    fig, axes = plt.subplots(3, 1, figsize=(9, 6.5), sharex=True)
    series = (
        (a["q"][:, 0], "$q_1$ [rad]"),
        (a["qd"][:, 0], r"$\dot q_1$ [rad/s]"),
        (a["i"][:, 0], "$i_1$ [A]"),
    )
    for ax, (y, label) in zip(axes, series, strict=True):
        ax.plot(t, y, lw=0.8, color="C0")
        ax.set_ylabel(label)
        for ph in res["phases"]:
            if abs(ph["q1_ref"] - math.pi / 2) < 1e-9:
                ax.axvspan(ph["start"], ph["end"], color="0.85", zorder=0)
        ax.grid(alpha=0.3)
    for ph in res["phases"]:
        axes[2].hlines(ph["i1_mean"], ph["start"] + 1.0, ph["end"], color="C3", lw=2)
    axes[2].set_xlabel("t [s]")
    axes[0].set_title(
        "UR10 joint 1, rest phases at the same configuration (grey): different currents"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def markdown(res: dict[str, Any]) -> str:
    """The Markdown table of the rest phases of :func:`run`'s result."""
    lines = [
        "# Quasi-static friction on the simulated UR10 (thesis Figure 4.1)",
        "",
        f"Seed {res['seed']}; joint 1: K_p = {res['kp1']:.0f} N m/rad, K_eq = "
        f"{res['current_gain1']:.1f} N m/A, F_s = {res['static_friction1']:.2f} N m "
        f"(stiction band +-{res['stiction_band_A']:.2f} A), current noise std "
        f"{res['current_noise_std']:.2f} A. Gravity torque on joint 1 is 0 in every pose.",
        "",
        "| rest phase | q1 [rad] | mean i1 [A] | std i1 [A] | mean e_q1 [rad] "
        "| max abs qd1 [rad/s] |",
        "|---|---|---|---|---|---|",
    ]
    for k, ph in enumerate(res["phases"]):
        lines.append(
            f"| {k + 1} | {ph['q1_ref']:.3f} | {ph['i1_mean']:+.3f} | {ph['i1_std']:.3f} | "
            f"{ph['e_q1_mean']:+.2e} | {ph['max_abs_qd1']:.1e} |"
        )
    return "\n".join(lines) + "\n"


def write_outputs(res: dict[str, Any], out_dir: str | Path) -> str:
    """Write ``collision_quasi_static.png``, ``.json`` (without the time series) and ``.md``
    of :func:`run`'s result under ``out_dir``; returns the Markdown table."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    plot(res, out / "collision_quasi_static.png")
    summary = {k: v for k, v in res.items() if k != "arrays"}
    write_result(out / "collision_quasi_static.json", RESULT_LAYOUTS[0], summary)
    text = markdown(res)
    (out / "collision_quasi_static.md").write_text(text)
    return text


# -- result file and headline rows of the results index -----------------------------------

RESULT_LAYOUTS = (
    ResultLayout(
        "quasi_static_friction",
        config=("seed", "kp1", "current_gain1", "static_friction1", "current_noise_std"),
        cases=("phases",),
    ),
)
"""The layout of ``collision_quasi_static.json`` (:mod:`mcpilco.experiments.results`)."""

HEADLINES = (
    Headline(
        "Collision detection, stiction",
        "collision_quasi_static.json",
        lambda r: f"stiction band of the rest current at one pose: {r['stiction_band_A']:.2f} A",
        "collision_quasi_static.md",
        seeds=lambda r: f"seed {r['seed']}",
    ),
)
"""The quasi-static friction experiment's row of the results index."""
