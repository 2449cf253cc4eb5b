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
=================  ===========================================================================

Also recorded: the diagnosis's own noise floor of the nominal model
(:func:`~mcpilco.models.diagnosis.heldout_floor`), CPU and wall seconds of each fit.
Development seeds only (:data:`DEVELOPMENT_SEEDS`); :func:`main` writes JSON and Markdown.
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
SAMPLE_TIMES = (0.002, 0.004)
"""Sample times a case draws from [s] (physics step 1 ms)."""
EDGE_ROWS = 20
"""Rows dropped at each end of every file (the derivative filter's edge fit)."""
VARIANTS = ("gip", "gip_true_x", "gip_span", "gip_hyper_all", "gip_rows", "nystrom")
"""Every variant :func:`run_case` knows (module docstring)."""


def _simulate(n_joints: int, joint_types: str, seed: int, rows: int, files: int) -> dict:
    """An effect-free random arm and ``files`` logs of ``rows`` samples (module docstring)."""
    from mcpilco.envs.arm_builder import arm_to_xml
    from mcpilco.envs.arms import random_arm
    from mcpilco.envs.robot_logs import SimulationDiverged, simulate_log
    from mcpilco.models.diagnosis import as_trajectories
    from mcpilco.models.robot_data import from_frame

    rng = np.random.default_rng(seed)
    for _ in range(20):
        arm = random_arm(n_joints, seed=int(rng.integers(2**31)), joint_types=joint_types).rigid()
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
) -> dict[str, Any]:
    """One case (module docstring): per variant the held-out RMSE / floor per joint, seconds."""
    from mcpilco.models.diagnosis import DiagnosisModel, NominalStart, heldout_floor
    from mcpilco.models.inverse_dynamics import GIPEstimator, NystromGIPEstimator

    bad = [v for v in variants if v not in VARIANTS]
    if bad:
        raise ValueError(f"unknown variants {bad}; use some of {VARIANTS}")
    case = _simulate(n_joints, joint_types, seed, rows, train_files + 1)
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
    nom = DiagnosisModel(nominal).fit(case["train"])
    test = case["trajs"][train_files].interior()
    diag_floor = heldout_floor(nom, test)
    rec: dict[str, Any] = {
        "seed": seed,
        "arm": jt,
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
    for v in variants:
        true_x = v in ("gip_true_x", "gip_span")
        clean = v == "gip_span"
        Xv, yv, Xtv, ytv = (X, y, Xt, yt) if not true_x else data(True, clean)
        ref = f_est if not true_x else floor(Xtv, data(True, False)[3])
        if v == "nystrom":
            est = NystromGIPEstimator(jt, inducing=inducing, hyper_points=hyper_all, **opt)
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
            "rmse": rmse.tolist(),
            "ratio": (rmse / ref).tolist(),
            "cpu_s": cpu,
            "wall_s": wall,
        }
    return rec


CASES = {"3R": (3, "RRR"), "RRPR": (4, "RRPR"), "7R": (7, "RRRRRRR")}
"""Arms of the benchmark (joint count, joint types)."""


def markdown(info: dict[str, Any], records: list[dict[str, Any]]) -> str:
    """The comparison as a Markdown table (ratio per joint, max, CPU seconds)."""
    lines = [
        "# Learned GIP start: held-out RMSE over the noise floor",
        "",
        f"Command: `{info['command']}`",
        "",
        "Effect-free forward-simulated logs (closed loop, q only, quantised encoder, "
        "2-4 ms). Ratio = held-out RMSE / held-out RMSE of the true rigid-body model on the "
        "same rows and estimated derivatives (the floor); `gip_true_x` and `gip_span` use "
        "the generator's true derivatives (`gip_span` also noise-free torques, so its "
        "ratio is against the measured-torque floor). CPU and wall seconds of the fit on "
        f"{info['cpus']} cores shared with other jobs.",
        "",
        "| seed | arm | T [ms] | counts/rev | train rows | variant | rows | RMSE / floor per "
        "joint | max | CPU s | wall s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in records:
        for v, d in r["variants"].items():
            ratios = " ".join(f"{x:.2f}" for x in d["ratio"])
            lines.append(
                f"| {r['seed']} | {r['arm']} | {1000 * r['sample_time']:.0f} | "
                f"{r['encoder_counts_per_rev']} | {r['train_rows']} | {v} | {d['rows']} | "
                f"{ratios} | {max(d['ratio']):.2f} | {d['cpu_s']:.0f} | {d['wall_s']:.0f} |"
            )
    return "\n".join(lines) + "\n"


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
    p.add_argument("--out", default="results/diagnosis_learned_start")
    a = p.parse_args(argv)
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
        n, jt = CASES[arm]
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
            )
            records.append(rec)
            print(json.dumps({k: rec[k] for k in ("seed", "arm", "train_rows")}), flush=True)
            for v, d in rec["variants"].items():
                print(f"  {v:14s} {np.round(d['ratio'], 2)} cpu {d['cpu_s']:.0f}s", flush=True)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    payload = {"info": info, "records": records}
    write_result(out.with_suffix(".json"), RESULT_LAYOUTS[0], payload, command=info["command"])
    write_atomic(out.with_suffix(".md"), markdown(info, records))
    return 0


RESULT_LAYOUTS = (
    ResultLayout(
        "diagnosis_learned_start",
        config=("info",),
        cases=("records",),
        seeds=lambda p: [int(r["seed"]) for r in p.get("records", [])],
    ),
)
"""The layout of ``diagnosis_learned_start.json`` (:mod:`mcpilco.experiments.results`)."""
HEADLINES: tuple = ()  # a study of causes: no row of the results index


if __name__ == "__main__":
    raise SystemExit(main())
