"""Why the learned GIP start misses the noise floor, and the fit that uses every row.

Each case (:func:`run_case`) forward-simulates an effect-free arm the way the diagnosis
benchmark does (:func:`mcpilco.envs.robot_logs.simulate_log`: PD + gravity compensation,
closed loop, an encoder of :data:`ENCODER_COUNTS` counts per revolution, torque noise
log-uniform in :data:`TAU_NOISE_RANGE`, sample time 2 or 4 ms): ``train_files`` logs to fit
on and one held-out log, files holding only ``t, q, tau`` (``qd``, ``qdd`` estimated by the
diagnosis loader's filter). Every variant predicts the held-out torques; its RMSE per joint
is divided by the noise floor, the held-out RMSE of the nominal model (the true rigid-body
model: a perfect model's error) on the same rows and the same estimated derivatives.

Variants (each isolates one suspected cause of the learned start's excess error):

=================  ===========================================================================
``gip``            the learned start as the diagnosis fits it: exact GIP GP (thesis eq. 3.11)
                   on ``points`` rows evenly spaced in time, hyperparameters on ``hyper`` of
                   them (:class:`~mcpilco.models.inverse_dynamics.GIPEstimator`)
``gip_true_x``     the same on the generator's true ``qd``, ``qdd`` (train and test): the
                   share of the error due to derivatives estimated from quantised ``q``
``gip_span``       true ``qd``, ``qdd`` and noise-free torques: a kernel whose span holds the
                   dynamics goes to ~0 (ratios far below 1); a missing term would not
``gip_hyper_all``  hyperparameters on all ``points`` rows: the share due to the subset fit
``gip_rows``       the exact GP on ``big_points`` rows (hyperparameters as ``gip``)
``nystrom``        every row: exact hyperparameters on ``hyper_all`` random rows, Nystroem
                   features on ``inducing`` rows, Bayesian linear regression over all rows
                   (:class:`~mcpilco.models.inverse_dynamics.NystromGIPEstimator`)
``rigid``          every row: Bayesian linear regression over the rigid-body terms of the
                   chain's Lagrangian (:class:`~mcpilco.models.inverse_dynamics.
                   LagrangianEstimator`; the default start where its size allows)
``chain``          every row: Bayesian linear regression over the inertial parameters of a
                   serial chain whose DH kinematics and gravity direction are searched
                   from random starts (:class:`~mcpilco.models.inverse_dynamics.
                   ChainEstimator`; the default start where the Lagrangian is too large)
``chain_true_x``   ``chain`` on the generator's true ``qd``, ``qdd``: the share of the chain's
                   error due to the estimated derivatives
``chain_known``    ``chain`` at the arm's own DH numbers and gravity (no search): the share
                   due to the kinematics search
=================  ===========================================================================

Also recorded: the diagnosis's own noise floor of the nominal model
(:func:`~mcpilco.models.diagnosis.heldout_floor`), CPU and wall seconds of each fit.

The loop on top of the learned start (``--loop``, :func:`loop_case`): the diagnosis
benchmark's case (:func:`mcpilco.experiments.diagnosis.bench.run_case`: a random arm of the
same joint count, effect-free or with one hidden effect of each ``--loop`` kind) with the
default learned GIP start (:class:`~mcpilco.models.diagnosis.GIPStart`, no robot file's
physics): what the loop names and the held-out RMSE over the floor after it.

Settings are chosen on development seeds (:data:`DEVELOPMENT_SEEDS`); ``--report`` runs
seeds from :data:`REPORT_SEEDS_FROM` on. :func:`main` writes JSON, Markdown and PNG.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.experiments.diagnosis.bench import ENCODER_COUNTS, TAU_NOISE_RANGE
from mcpilco.experiments.results import ResultLayout, write_result
from mcpilco.models.files import write_atomic

DEVELOPMENT_SEEDS = range(0, 100)
"""Seeds on which the learned start's settings may be chosen."""
REPORT_SEEDS_FROM = 1000
"""First seed of a report run (``--report``), never used to choose a setting."""
SAMPLE_TIMES = (0.002, 0.004)
"""Sample times a case draws from [s] (physics step 1 ms)."""
EDGE_ROWS = 20
"""Rows dropped at each end of every file (the derivative filter's edge fit)."""
VARIANTS = (
    "gip",
    "gip_true_x",
    "gip_span",
    "gip_hyper_all",
    "gip_rows",
    "nystrom",
    "rigid",
    "chain",
    "chain_true_x",
    "chain_known",
)
"""Every variant :func:`run_case` knows (module docstring)."""


def _simulate(
    n_joints: int, joint_types: str, seed: int, rows: int, files: int, table: str | None = None
) -> dict:
    """An effect-free arm and ``files`` logs of ``rows`` samples (module docstring): a random
    arm of these joint types, or ``table`` (of :data:`~mcpilco.envs.arms.ARMS`) without
    friction (its rotor inertias kept, as the diagnosis benchmark's nominal robot file)."""
    from mcpilco.envs.arm_builder import arm_to_xml
    from mcpilco.envs.arms import ARMS, random_arm
    from mcpilco.envs.robot_logs import SimulationDiverged, simulate_log
    from mcpilco.models.diagnosis import as_trajectories
    from mcpilco.models.robot_data import from_frame

    rng = np.random.default_rng(seed)
    for _ in range(20):
        if table is not None:
            arm = ARMS[table]().without_friction()
        else:
            arm = random_arm(n_joints, seed=int(rng.integers(2**31)), joint_types=joint_types)
            arm = arm.rigid()
        counts = int(rng.choice(ENCODER_COUNTS))
        tau_noise = float(math.exp(rng.uniform(*np.log(TAU_NOISE_RANGE))))
        T = float(rng.choice(SAMPLE_TIMES))
        substeps = int(round(T / 1e-3))
        sim = dict(duration=rows * T, counts_per_rev=counts, tau_noise=tau_noise, substeps=substeps)
        try:
            logs = [
                simulate_log(arm, [], seed=int(rng.integers(2**31)), **sim) for _ in range(files)
            ]
            break
        except SimulationDiverged:
            continue
    else:
        raise RuntimeError(f"seed {seed}: 20 random arms all diverged")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        frames = [from_frame(g.table, source=f"log{k}") for k, g in enumerate(logs)]
        trajs = [as_trajectories([f]) for f in frames]
        train = as_trajectories(frames[:-1])
    return dict(
        arm=arm,
        xml=arm_to_xml(arm, friction=False),
        logs=logs,
        trajs=trajs,
        train=train,
        counts=counts,
        tau_noise=tau_noise,
        sample_time=T,
    )


def _part(case: dict, k: int, true_x: bool, clean: bool) -> tuple[np.ndarray, np.ndarray]:
    """``([q, qd, qdd], y)`` of file ``k`` without its edge rows."""
    sl = slice(EDGE_ROWS, -EDGE_ROWS)
    g, tr = case["logs"][k], case["trajs"][k]
    src = g.truth if true_x else tr
    X = np.concatenate([src.q[sl], src.qd[sl], src.qdd[sl]], axis=1)
    y = (g.truth.tau if clean else tr.y)[sl]
    return X, y


def _rmse(pred: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean((pred - y) ** 2, axis=0))


def _timed(fn: Any) -> tuple[Any, float, float]:
    c0, w0 = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.process_time() - c0, time.perf_counter() - w0


def run_case(
    seed: int,
    n_joints: int,
    joint_types: str,
    rows: int = 2500,
    train_files: int = 2,
    points: int = 600,
    hyper: int = 200,
    big_points: int = 2000,
    hyper_all: int = 600,
    inducing: int = 1500,
    iters: int = 100,
    variants: Sequence[str] = VARIANTS,
    diagnosis_floor: bool = True,
    table: str | None = None,
) -> dict[str, Any]:
    """One case (module docstring): per variant the held-out RMSE / floor per joint, seconds
    (``diagnosis_floor``: also the diagnosis's own floor, a GP fit per joint). ``rigid`` is
    left out where the Lagrangian has more than ``MAX_RIGID_FEATURES`` parameters."""
    from mcpilco.models.diagnosis import DiagnosisModel, NominalStart, heldout_floor
    from mcpilco.models.inverse_dynamics import (
        MAX_RIGID_FEATURES,
        ChainEstimator,
        GIPEstimator,
        LagrangianEstimator,
        NystromGIPEstimator,
        lagrangian_parameters,
    )

    bad = [v for v in variants if v not in VARIANTS]
    if bad:
        raise ValueError(f"unknown variants {bad}; use some of {VARIANTS}")
    case = _simulate(n_joints, joint_types, seed, rows, train_files + 1, table)
    jt = case["arm"].joint_types
    nominal = NominalStart(case["xml"])
    n = n_joints

    def data(true_x: bool, clean: bool) -> tuple:
        parts = [_part(case, k, true_x, clean) for k in range(train_files)]
        X = np.concatenate([p[0] for p in parts])
        y = np.concatenate([p[1] for p in parts])
        Xt, yt = _part(case, train_files, true_x, clean)
        return X, y, Xt, yt

    def floor(Xt: np.ndarray, yt: np.ndarray) -> np.ndarray:
        return _rmse(nominal.torque(Xt[:, :n], Xt[:, n : 2 * n], Xt[:, 2 * n :]), yt)

    X, y, Xt, yt = data(False, False)
    f_est = floor(Xt, yt)
    diag_floor = np.full(n, np.nan)
    if diagnosis_floor:
        nom = DiagnosisModel(nominal).fit(case["train"])
        diag_floor = heldout_floor(nom, case["trajs"][train_files].interior())
    rec: dict[str, Any] = {
        "seed": seed,
        "arm": jt,
        "table": table,
        "n_joints": n,
        "encoder_counts_per_rev": case["counts"],
        "tau_noise": case["tau_noise"],
        "sample_time": case["sample_time"],
        "train_rows": int(X.shape[0]),
        "test_rows": int(Xt.shape[0]),
        "floor": f_est.tolist(),
        "diagnosis_floor": diag_floor.tolist(),
        "variants": {},
    }
    opt = dict(adam_iters=iters, lbfgs_iters=max(iters // 3, 1))
    too_big = len(lagrangian_parameters(jt)) > MAX_RIGID_FEATURES
    for v in [v for v in variants if not (v == "rigid" and too_big)]:
        true_x = v in ("gip_true_x", "gip_span", "chain_true_x")
        clean = v == "gip_span"
        Xv, yv, Xtv, ytv = (X, y, Xt, yt) if not true_x else data(True, clean)
        ref = f_est if not true_x else floor(Xtv, data(True, False)[3])
        if v == "nystrom":
            est = NystromGIPEstimator(jt, inducing=inducing, hyper_points=hyper_all, **opt)
            fit_rows = np.arange(Xv.shape[0])
        elif v == "rigid":
            est = LagrangianEstimator(jt)
            fit_rows = np.arange(Xv.shape[0])
        elif v.startswith("chain"):
            arm = case["arm"]
            known = dict(
                kinematics=[[j.alpha, j.a, j.theta, j.d] for j in arm.joints], gravity=[0.0, 0.0]
            )
            est = ChainEstimator(jt, **(known if v == "chain_known" else {}))
            fit_rows = np.arange(Xv.shape[0])
        else:
            npts = big_points if v == "gip_rows" else points
            fit_rows = np.unique(
                np.round(np.linspace(0, Xv.shape[0] - 1, min(npts, Xv.shape[0]))).astype(int)
            )
            est = GIPEstimator(jt, hyper_points=None if v == "gip_hyper_all" else hyper, **opt)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            _, cpu, wall = _timed(lambda e=est, a=Xv[fit_rows], b=yv[fit_rows]: e.fit(a, b))
            pred = est.predict(Xtv)[0]
        rmse = _rmse(pred, ytv)
        rec["variants"][v] = {
            "rows": int(fit_rows.size),
            "parameters": int(getattr(est, "n_features_", 0)) or None,
            "rmse": rmse.tolist(),
            "ratio": (rmse / ref).tolist(),
            "cpu_s": cpu,
            "wall_s": wall,
        }
        print(f"  {jt} seed {seed} {v:14s} {np.round(rmse / ref, 2)} cpu {cpu:.0f}s", flush=True)
    return rec


def loop_case(seed: int, n_joints: int, kind: str | None, rows: int) -> dict[str, Any]:
    """The diagnosis loop with the default learned GIP start on the diagnosis benchmark's
    case of a random ``n_joints``-joint arm (module docstring): ``kind`` one hidden effect,
    ``None`` a control. ``rows``: samples per file (at the benchmark's 2 ms)."""
    from mcpilco.experiments.diagnosis.bench import run_case as bench_case
    from mcpilco.experiments.diagnosis.bench import score_record

    kinds = [] if kind is None else [kind]
    c0 = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = bench_case(
            seed,
            "control" if kind is None else "single",
            kinds,
            duration=rows * 0.002,
            min_joints=n_joints,
            max_joints=n_joints,
            start="gip",
        )
    rec["cpu_s"] = time.process_time() - c0
    rec["score"] = score_record(rec)
    return rec


CASES: dict[str, tuple[int, str, str | None]] = {
    "3R": (3, "RRR", None),
    "RRPR": (4, "RRPR", None),
    "5R": (5, "RRRRR", None),
    "6R": (6, "RRRRRR", None),
    "7R": (7, "RRRRRRR", None),
    "panda": (7, "RRRRRRR", "panda"),
    "iiwa14": (7, "RRRRRRR", "iiwa14"),
}
"""Arms of the benchmark (joint count, joint types, a table of
:data:`~mcpilco.envs.arms.ARMS` or ``None`` for a random arm per seed)."""


def _seed_label(seeds: Sequence[int]) -> str:
    """Whether the seeds are development seeds (settings may have been chosen on them) or
    report seeds."""
    if seeds and min(seeds) >= REPORT_SEEDS_FROM:
        return f"Report seeds {sorted(set(seeds))} (no setting chosen on them)."
    return (
        f"Development seeds {sorted(set(seeds))}: settings may have been chosen on them; "
        f"report runs use seeds from {REPORT_SEEDS_FROM}."
    )


def markdown(
    info: dict[str, Any],
    records: list[dict[str, Any]],
    loops: Sequence[dict[str, Any]] = (),
) -> str:
    """The comparison as a Markdown table (ratio per joint, max, CPU seconds), and the loop
    cases (:func:`loop_case`) when given."""
    lines = [
        "# Learned GIP start: held-out RMSE over the noise floor",
        "",
        f"Command: `{info['command']}`",
        "",
        _seed_label([r["seed"] for r in [*records, *loops]]),
        "",
        "Effect-free forward-simulated logs (closed loop, q only, quantised encoder, "
        "2-4 ms). Ratio = held-out RMSE / held-out RMSE of the true rigid-body model on the "
        "same rows and estimated derivatives (the floor); `gip_true_x` and `gip_span` use "
        "the generator's true derivatives (`gip_span` also noise-free torques, so its "
        "ratio is against the measured-torque floor). Parameters: of the linear regressions "
        "(`-`: a GP). CPU and wall seconds of the fit on "
        f"{info['cpus']} cores shared with other jobs.",
        "",
        "| seed | arm | T [ms] | counts/rev | train rows | variant | rows | parameters | "
        "RMSE / floor per joint | max | CPU s | wall s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in records:
        for v, d in r["variants"].items():
            ratios = " ".join(f"{x:.2f}" for x in d["ratio"])
            lines.append(
                f"| {r['seed']} | {r.get('table') or r['arm']} | {1000 * r['sample_time']:.0f} | "
                f"{r['encoder_counts_per_rev']} | {r['train_rows']} | {v} | {d['rows']} | "
                f"{d.get('parameters') or '-'} | {ratios} | {max(d['ratio']):.2f} | "
                f"{d['cpu_s']:.0f} | {d['wall_s']:.0f} |"
            )
    if loops:
        lines += [
            "",
            "## The loop on top of the default learned GIP start",
            "",
            "The diagnosis benchmark's cases (random arm, one hidden effect or none) with the "
            "default learned GIP start; named = the first effect the loop names (none: "
            "nothing); ratio = held-out RMSE / floor per joint after the loop.",
            "",
            "| seed | arm | hidden effect | named | added | ratio after per joint | right | "
            "CPU s |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for r in loops:
            hidden = ", ".join(f"{e['kind']}:{e['joint']}" for e in r["effects"]) or "none"
            named = "none" if r["named"] is None else f"{r['named'][0]}:{r['named'][1]}"
            added = ", ".join(f"{k}:{j}" for k, j in r["added"]) or "none"
            ratios = " ".join(f"{x:.2f}" for x in r["ratio_after"])
            right = r["score"].get("verdict_correct")
            lines.append(
                f"| {r['seed']} | {r['arm']} | {hidden} | {named} | {added} | {ratios} | "
                f"{'yes' if right else 'no'} | {r['cpu_s']:.0f} |"
            )
    return "\n".join(lines) + "\n"


def plot(records: list[dict[str, Any]], path: Path) -> Path:
    """Worst joint's held-out RMSE / floor (log scale) and CPU seconds of each variant,
    case by case."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 3.6))
    labels = [f"{r.get('table') or r['arm']} s{r['seed']}" for r in records]
    names = sorted({v for r in records for v in r["variants"]})
    width = 0.8 / max(len(names), 1)
    for k, v in enumerate(names):
        xs = [i + k * width for i, r in enumerate(records) if v in r["variants"]]
        worst = [max(r["variants"][v]["ratio"]) for r in records if v in r["variants"]]
        cpu = [r["variants"][v]["cpu_s"] for r in records if v in r["variants"]]
        ax.bar(xs, worst, width, label=v)
        bx.bar(xs, cpu, width, label=v)
    for a in (ax, bx):
        a.set_xticks([i + 0.4 - width / 2 for i in range(len(records))], labels, fontsize=8)
    ax.axhline(1.2, color="k", lw=0.8, ls="--")
    ax.set_yscale("log")
    ax.set_ylabel("worst joint: held-out RMSE / floor")
    bx.set_ylabel("CPU seconds of the fit")
    ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m mcpilco.experiments.diagnosis.learned_start``: run the cases, write the
    result file and its Markdown table."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--arms", nargs="+", default=list(CASES), choices=list(CASES))
    p.add_argument("--seeds", nargs="+", type=int, default=[0])
    p.add_argument("--rows", type=int, default=2500, help="samples per file")
    p.add_argument("--train-files", type=int, default=2)
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    p.add_argument("--inducing", type=int, default=1500)
    p.add_argument("--hyper-all", type=int, default=600)
    p.add_argument(
        "--no-diagnosis-floor",
        action="store_true",
        help="skip the diagnosis's own noise floor (a GP fit per joint of the nominal model)",
    )
    p.add_argument(
        "--loop",
        nargs="*",
        default=None,
        metavar="KIND",
        help="also run the loop with the default learned start: a control and one case per "
        "hidden-effect kind (e.g. damping frictionloss)",
    )
    p.add_argument("--loop-rows", type=int, default=5000, help="samples per file of a loop case")
    p.add_argument("--report", action="store_true", help=f"seeds >= {REPORT_SEEDS_FROM}")
    p.add_argument("--out", default="results/diagnosis_learned_start")
    a = p.parse_args(argv)
    if a.report:
        bad = [s for s in a.seeds if s < REPORT_SEEDS_FROM]
        if bad:
            print(f"--report: seeds {bad} are below {REPORT_SEEDS_FROM}", file=sys.stderr)
            return 2
    else:
        bad = [s for s in a.seeds if s not in DEVELOPMENT_SEEDS]
        if bad:
            print(f"seeds {bad} are not development seeds (0-99)", file=sys.stderr)
            return 2
    info = {
        "command": "python -m mcpilco.experiments.diagnosis.learned_start "
        + " ".join(sys.argv[1:] if argv is None else argv),
        "cpus": os.cpu_count(),
        "platform": platform.platform(),
    }
    records = []
    for arm in a.arms:
        n, jt, table = CASES[arm]
        for s in a.seeds:
            rec = run_case(
                s,
                n,
                jt,
                rows=a.rows,
                train_files=a.train_files,
                inducing=a.inducing,
                hyper_all=a.hyper_all,
                variants=a.variants,
                diagnosis_floor=not a.no_diagnosis_floor,
                table=table,
            )
            records.append(rec)
            print(json.dumps({k: rec[k] for k in ("seed", "arm", "train_rows")}), flush=True)
    loops = []
    for arm in a.arms if a.loop is not None else []:
        n = CASES[arm][0]
        for s in a.seeds:
            for kind in [None, *a.loop]:
                rec = loop_case(s, n, kind, a.loop_rows)
                loops.append(rec)
                print(
                    f"  loop {rec['arm']} seed {s} {kind}: named {rec['named']} added "
                    f"{rec['added']} ratio {np.round(rec['ratio_after'], 2)} "
                    f"cpu {rec['cpu_s']:.0f}s",
                    flush=True,
                )
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    payload = {"info": info, "records": records, "loops": loops}
    write_result(out.with_suffix(".json"), RESULT_LAYOUTS[0], payload, command=info["command"])
    write_atomic(out.with_suffix(".md"), markdown(info, records, loops))
    if records:
        plot(records, out.with_suffix(".png"))
    return 0


RESULT_LAYOUTS = (
    ResultLayout(
        "diagnosis_learned_start",
        config=("info",),
        cases=("records", "loops"),
        seeds=lambda p: sorted(
            {int(r["seed"]) for key in ("records", "loops") for r in p.get(key, [])}
        ),
    ),
)
"""The layout of ``diagnosis_learned_start.json`` (:mod:`mcpilco.experiments.results`)."""
HEADLINES: tuple = ()  # a study of causes: no row of the results index


if __name__ == "__main__":
    raise SystemExit(main())
