r"""MC-PILCO reaching through the learned kinematics of the marker camera, against the
gradient kinematic controller of thesis chapter 2 on the same data.

Per seed (:func:`reaching_seed`, a sweep job): the UR10 of ``mcpilco/MarkerCamera-v0``
(markers facing the camera at home, a 70 deg visibility cone, the env's AprilTag-like
noise) follows the training trajectory ``D_tr`` through 25 random waypoints
(:func:`~mcpilco.experiments.kinematics.parts.ur10_datasets`); the kinematic structure is
identified from its frames (the true one replaces a wrong identification, which is
recorded). Both agents then get the same 300 random samples of ``D_tr`` and the same 5
random targets (:func:`~mcpilco.experiments.kinematics.parts.reaching_problem`), and the
same model class: the chain of one-joint GPs along the identified marker chain
(:class:`~mcpilco.models.kinematics.ChainForwardKinematicsGP`). Each trial starts at the
first waypoint; the frames of a trial that show the end marker join that agent's data and
its model is refitted before the next trial (``rounds + 1`` trials).

* **MC-PILCO** (:func:`mcpilco_reaching_part`): per target, a closed-loop joint-increment
  policy optimised through the model (:func:`~mcpilco.agents.mc_pilco.reaching.
  optimise_reaching_policy`; from the previous trial's policy for the same target), then run
  on the env for ``H`` steps from the measured joints; 5 more frames at rest.
* **Gradient controller** (:func:`~mcpilco.experiments.kinematics.parts.controller_part`,
  ``fk_model="chain"``): eq. 2.24 on the model from the start and the 4 data configurations
  nearest to the target, the reference clipped to the data's joint box; the env tracks it.

Figures: the true (noise-free) position error ``||l - l*||`` [m] and geodesic orientation
error [rad] of the end marker at the end of each trial, per target, pooled over seeds
(:func:`summarise_reaching`).
"""

from __future__ import annotations

import datetime
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mcpilco.agents.mc_pilco.reaching import ReachingConfig, optimise_reaching_policy
from mcpilco.experiments.infra.sweep import Job, SweepRunner
from mcpilco.experiments.kinematics.parts import (
    FACING_CONE,
    VISIBILITY_CONE,
    controller_part,
    geodesic_errors,
    identify_ur10,
    measured_joints,
    reaching_problem,
    trial_frames,
    true_structure,
    ur10_datasets,
)
from mcpilco.experiments.kinematics.trajectories import drive_to
from mcpilco.experiments.results import Headline, Result, ResultLayout, seed_ranges, write_result
from mcpilco.models.kinematics import ChainForwardKinematicsGP
from mcpilco.models.kinematics.rotations import ypr_to_matrix

__all__ = [
    "AGENTS",
    "mcpilco_reaching_part",
    "reaching_curves",
    "reaching_markdown",
    "reaching_seed",
    "reaching_study",
    "summarise_reaching",
]

AGENTS = ("mcpilco", "controller")
"""Result keys of the two agents of a seed."""

THRESHOLDS = (0.01, 0.05)  # a target counts as reached within 1 cm and 0.05 rad
FRAME_DT = 0.1  # seconds per camera frame, the marker-camera env's step


def mcpilco_reaching_part(
    data: dict[str, Any],
    structure,
    n_train: int,
    rounds: int,
    seed: int,
    config: ReachingConfig | None = None,
    hold: int = 5,
    selection: str = "random",
) -> dict[str, Any]:
    """MC-PILCO on the 5 targets of :func:`reaching_problem`, ``rounds + 1`` trials each
    (module docstring); rows per trial like ``controller_part``'s."""
    cfg = config if config is not None else ReachingConfig()
    env = data["env"]
    problem = reaching_problem(data, structure, n_train, selection, seed)
    X, Y, targets = problem["X"], problem["Y"], problem["targets"]
    joints, types = list(structure.joints), structure.joint_types
    n = len(joints)
    increments = env.max_increment[problem["chain_of_model"]]  # the env's step per joint
    q_start = data["waypoints"][0]
    fk = ChainForwardKinematicsGP(types)
    policies: list[Any] = [None] * len(targets)
    rows = []
    for rnd in range(rounds + 1):
        fk.fit(X, Y)
        model = fk.predictor()
        reached_true, predicted, steps, new_X, new_Y = [], [], [], [], []
        t0 = time.perf_counter()
        for k, target in enumerate(targets):
            q_meas = measured_joints(drive_to(env, q_start)[-1], structure)
            policy, res = optimise_reaching_policy(
                model, types, q_meas, target[:3], ypr_to_matrix(target[3:]), increments, X,
                config=cfg, policy=policies[k], seed=seed * 1000 + 10 * rnd + k,
            )  # fmt: skip
            policies[k] = policy
            predicted.append(res.costs[-1] / cfg.horizon if res.costs else None)
            steps.append(len(res.costs))
            obs_rows = []
            for _ in range(cfg.horizon):
                with torch.no_grad():
                    u = policy(torch.as_tensor(q_meas, dtype=torch.float64)).numpy()
                action = np.zeros(n, dtype=np.float32)
                action[joints] = u
                obs = env.step(action)[0]
                obs_rows.append(obs)
                q_meas = measured_joints(obs, structure)
            for _ in range(hold):  # the camera keeps measuring at rest
                obs_rows.append(env.step(np.zeros(n, dtype=np.float32))[0])
            frames_X, frames_Y = trial_frames(obs_rows, structure)
            new_X += frames_X
            new_Y += frames_Y
            reached_true.append(env.marker_poses(env.q)[-1])
        reached_true = np.array(reached_true)
        rows.append(
            dict(
                round=rnd,
                n_data=len(X),
                position_error_norm_true=np.linalg.norm(
                    reached_true[:, :3] - targets[:, :3], axis=1
                ).tolist(),
                orientation_error_true=geodesic_errors(reached_true, targets).tolist(),
                predicted_cost_per_step=predicted,
                optimisation_steps=steps,
                seconds=time.perf_counter() - t0,
            )
        )
        if new_X:
            X = np.concatenate([X, np.array(new_X)])
            Y = np.concatenate([Y, np.array(new_Y)])
    return dict(
        n_train=n_train,
        horizon=cfg.horizon,
        particles=cfg.particles,
        num_basis=cfg.num_basis,
        hold=hold,
        targets=targets.tolist(),
        rounds=rows,
    )


def reaching_seed(
    seed: int,
    samples: int = 2100,
    n_train: int = 300,
    rounds: int = 3,
    hold: int = 5,
    horizon: int = 20,
    particles: int = 8,
) -> dict[str, Any]:
    """One seed of the study (module docstring): both agents' trial rows."""
    t0 = time.perf_counter()
    data = ur10_datasets(seed, samples, 1.0, 1.0, "ideal", FACING_CONE, VISIBILITY_CONE)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        idn = identify_ur10(data)
    structure = idn["structure"] if idn["correct"] else true_structure(data["env"])
    controller = controller_part(
        data, structure, n_train, rounds, seed, progress=False, hold=hold, fk_model="chain"
    )
    cfg = ReachingConfig(horizon=horizon, particles=particles)
    mcpilco = mcpilco_reaching_part(data, structure, n_train, rounds, seed, cfg, hold)
    return dict(
        seed=seed,
        identification_correct=bool(idn["correct"]),
        mcpilco=mcpilco,
        controller=controller,
        seconds=time.perf_counter() - t0,
    )


def summarise_reaching(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per agent and trial, pooled over seeds and targets: median, quartiles and mean of the
    true position and orientation errors, and the share of targets within
    :data:`THRESHOLDS` (both errors)."""
    out: dict[str, Any] = {}
    for agent in AGENTS:
        trials = []
        for rnd in range(len(rows[0][agent]["rounds"])):
            pos = np.concatenate(
                [r[agent]["rounds"][rnd]["position_error_norm_true"] for r in rows]
            )
            ori = np.concatenate([r[agent]["rounds"][rnd]["orientation_error_true"] for r in rows])
            reached = (pos <= THRESHOLDS[0]) & (ori <= THRESHOLDS[1])
            trials.append(
                dict(
                    trial=rnd + 1,
                    targets=int(pos.size),
                    position_median=float(np.median(pos)),
                    position_quartiles=np.quantile(pos, [0.25, 0.75]).tolist(),
                    position_mean=float(pos.mean()),
                    orientation_median=float(np.median(ori)),
                    orientation_quartiles=np.quantile(ori, [0.25, 0.75]).tolist(),
                    orientation_mean=float(ori.mean()),
                    reached=int(reached.sum()),
                )
            )
        out[agent] = trials
    return out


def reaching_curves(study: dict[str, Any], env_id: str, source: str = "") -> list[dict[str, Any]]:
    """MC-PILCO's learning curves of a study (``kinematics_reaching.json``), one per seed, in
    the comparison format of :mod:`mcpilco.agents.baselines.common`.

    Trial ``k`` (0-based) of a seed is one point: its success rate is the share of the seed's
    targets reached within :data:`THRESHOLDS` at the end of the trial; its experience counts
    every frame the agent saw, ``T_k = (N_id + (k + 1) n_targets (H + hold)) FRAME_DT``, with
    ``N_id`` the frames of the identification trajectory ``D_tr`` (``settings.samples``) and
    ``H + hold`` frames per target and trial (the drives back to the start, resets, are not
    counted). ``final_info_median``: the median over the targets of the true end-marker
    ``position_error`` [m] and ``orientation_error`` [rad], the env's ``info`` keys.
    """
    from mcpilco.agents.baselines.common import make_curve

    samples = int(study["settings"].get("samples", 2100))
    curves = []
    for row in study["rows"]:
        part = row["mcpilco"]
        per_trial = len(part["targets"]) * (int(part["horizon"]) + int(part["hold"]))
        points, frames = [], samples
        for rnd in part["rounds"]:
            pos = np.asarray(rnd["position_error_norm_true"])
            ori = np.asarray(rnd["orientation_error_true"])
            frames += per_trial
            points.append(
                {
                    "steps": frames,
                    "experience_s": frames * FRAME_DT,
                    "success_rate": float(np.mean((pos <= THRESHOLDS[0]) & (ori <= THRESHOLDS[1]))),
                    "episodes": int(pos.size),
                    "kind": "policy",
                    "final_info_median": {
                        "position_error": float(np.median(pos)),
                        "orientation_error": float(np.median(ori)),
                    },
                }
            )
        curves.append(
            make_curve(
                "mcpilco",
                env_id,
                int(row["seed"]),
                FRAME_DT,
                points,
                source=source,
                wall_s=row.get("seconds"),
                complete=True,
            )
        )
    return curves


def reaching_markdown(study: dict[str, Any]) -> str:
    """The study's table: per trial and agent, the errors and the targets reached."""
    names = {
        "mcpilco": "MC-PILCO (policy through the model)",
        "controller": "gradient controller (eq. 2.24)",
    }
    s = study["summary"]
    lines = [
        "| trial | agent | position error median [m] (quartiles) | mean | orientation error "
        "median [rad] (quartiles) | mean | reached (1 cm, 0.05 rad) |",
        "|---|---|---|---|---|---|---|",
    ]
    for i in range(len(s["mcpilco"])):
        for agent in AGENTS:
            t = s[agent][i]
            pq, oq = t["position_quartiles"], t["orientation_quartiles"]
            lines.append(
                f"| {t['trial']} | {names[agent]} | {t['position_median']:.4f} "
                f"({pq[0]:.4f}-{pq[1]:.4f}) | {t['position_mean']:.4f} | "
                f"{t['orientation_median']:.4f} ({oq[0]:.4f}-{oq[1]:.4f}) | "
                f"{t['orientation_mean']:.4f} | {t['reached']} / {t['targets']} |"
            )
    return "\n".join(lines)


def plot_reaching(study: dict[str, Any], path: Path) -> None:
    """Median and quartiles (over every seed's targets) of both errors per trial, both
    agents, legends in words."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seeds = seed_ranges(study["seeds"])
    words = {  # legend words of the agents
        "mcpilco": f"MC-PILCO through the learned kinematics, seeds {seeds}",
        "controller": "gradient kinematic controller (thesis ch. 2), same data",
    }
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for agent, colour in zip(AGENTS, ("C0", "C1"), strict=True):
        trials = study["summary"][agent]
        x = [t["trial"] for t in trials]
        for ax, key in zip(axes, ("position", "orientation"), strict=True):
            med = [t[f"{key}_median"] for t in trials]
            lo = [t[f"{key}_quartiles"][0] for t in trials]
            hi = [t[f"{key}_quartiles"][1] for t in trials]
            ax.plot(x, med, "o-", color=colour, label=words.get(agent, agent))
            ax.fill_between(x, lo, hi, color=colour, alpha=0.2)
    axes[0].set_ylabel("true position error [m]")
    axes[1].set_ylabel("true orientation error [rad]")
    for ax in axes:
        ax.set_xlabel("trial")
        ax.set_xticks([t["trial"] for t in study["summary"]["mcpilco"]])
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(
        f"UR10 marker-camera reaching, {len(study['seeds'])} seeds x 5 targets: median "
        "(band: quartiles over the targets)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def reaching_study(
    seeds: list[int],
    out_dir: str | Path,
    command: str,
    runner: SweepRunner | None = None,
    runs_dir: str | Path = "runs/bench_kinematics",
    **settings: Any,
) -> dict[str, Any]:
    """:func:`reaching_seed` on every seed (sweep jobs of ``runner``, kept in
    ``runs_dir/reaching``), summarised into ``out_dir/kinematics_reaching.{json,md,png}``.

    Raises:
        RuntimeError: when a seed failed (its traceback is in ``runs_dir/reaching``).
    """

    runner = runner if runner is not None else SweepRunner(progress=True)
    jobs = [Job(f"seed{seed}", reaching_seed, {"seed": seed, **settings}) for seed in seeds]
    sweep = runner.run(jobs, Path(runs_dir) / "reaching", desc="reaching seeds")
    if sweep.failed:
        raise RuntimeError(sweep.summary())
    rows = [sweep.results[f"seed{seed}"] for seed in seeds]
    study = dict(
        command=command,
        measured=datetime.date.today().isoformat(),
        seeds=list(seeds),
        settings=settings,
        identification_correct=sum(r["identification_correct"] for r in rows),
        summary=summarise_reaching(rows),
        rows=rows,
    )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_result(out / "kinematics_reaching.json", RESULT_LAYOUTS[0], study)
    plot_reaching(study, out / "kinematics_reaching.png")
    (out / "kinematics_reaching.md").write_text(
        "# MC-PILCO reaching through the learned kinematics vs the gradient controller\n\n"
        f"Command: `{command}`\n\n{reaching_markdown(study)}\n\n"
        "![errors per trial](kinematics_reaching.png)\n"
    )
    return study


# -- result file and headline rows of the results index -----------------------------------

RESULT_LAYOUTS = (
    ResultLayout("kinematics_reaching", config=("seeds", "settings"), cases=("rows",)),
)
"""The layout of ``kinematics_reaching.json`` (:mod:`mcpilco.experiments.results`)."""


def _reaching_row(r: Result) -> str:
    mc, ctrl = r["summary"]["mcpilco"][-1], r["summary"]["controller"][-1]

    def one(t: dict[str, Any]) -> str:
        return (
            f"{1000 * t['position_median']:.1f} mm, {t['orientation_median']:.3f} rad "
            f"({t['reached']} / {t['targets']} within 1 cm and 0.05 rad)"
        )

    return (
        f"MC-PILCO reaching through the learned kinematics, median after trial {mc['trial']}: "
        f"{one(mc)}; gradient controller on the same data: {one(ctrl)}"
    )


HEADLINES = (
    Headline(
        "Kinematics: MC-PILCO reaching",
        "kinematics_reaching.json",
        _reaching_row,
        "kinematics_reaching.md",
    ),
)
"""The reaching study's row of the results index."""


def replot(result: Result, json_path: Path) -> list[Path]:
    """Redraw ``kinematics_reaching.png`` next to the result file, from the file."""
    path = Path(json_path).with_suffix(".png")
    plot_reaching(result.payload(), path)
    return [path]
