"""The collision-detection benchmark on the simulated UR10 (thesis section 4.6).

Data: :mod:`mcpilco.experiments.collision.data`. Estimators
(:mod:`mcpilco.models.collision`): PP (eq. 4.7), SP (eq. 3.7), FC (eqs. 4.8-4.10) with
``sigma_v`` chosen by hold-out cross-validation among ``sigma_v_candidates`` (train on the
first 80% of the training run, score on the last 20%), and "PP-sign": PP with the exact
``sign(qd)`` (``coulomb_velocity = 0``), RMSE only. The GPs are conditioned on ``gp_points``
rows of the training run taken with a constant step; hyperparameters by marginal likelihood
on ``hyper_points`` random rows of those.

Detection: thresholds by the thesis rule (``"max"``: ``sigma_CD,j = max |s_j|`` on the
validation set) and by the variance rule (``k_j sigma_j(x)``, ``k_j = max |s_j| / sigma_j``
on the validation set), alarms after ``m`` samples of persistence for every ``m`` in
``persistence``. Scores: detection rate (all pushes, pushes >= 30 N, moving / at rest),
median latency, false alarms per minute on the push-free data; detection rate against false
alarms per minute with thresholds from the validation quantiles ``1 - alpha`` (``alphas``)
for every ``m`` in ``roc_persistence``.

Jobs: the simulated data are kept in ``runs_dir/data.pt``; the ``sigma_v``
cross-validation and each estimator's fit and evaluation are sweep jobs
(:mod:`mcpilco.experiments.infra.sweep`) that read it (a multi-node Ray cluster needs ``runs_dir``
on a shared file system), FC after the cross-validation. Each writes
``runs_dir/<label>.json``: a rerun computes only the jobs without one. The cost is dominated
by the FC predictive variance on every evaluation row.

:func:`run_benchmark` takes the options of ``mcpilco-bench-collision`` (an
``argparse.Namespace`` or any object with those attributes, lists already parsed) and writes
``collision.json``, ``collision.md`` and the figures of
:mod:`mcpilco.experiments.collision.report` to ``out_dir``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from mcpilco.envs.arm_env import Push
from mcpilco.experiments.collision.data import (
    DATA_FILE,
    DATA_OPTIONS,
    load_sets,
    simulated_sets,
)
from mcpilco.experiments.collision.nominal import nominal_model
from mcpilco.experiments.collision.report import (
    goals,
    markdown,
    plot_rmse,
    plot_roc,
    plot_scenario,
    strip,
)
from mcpilco.experiments.infra.sweep import Job, SweepRunner
from mcpilco.experiments.results import Headline, Result, ResultLayout, write_result
from mcpilco.models.collision import (
    CollisionDetector,
    CollisionInputs,
    alarm_flags,
    as_collision_inputs,
    evaluate_detection,
    make_estimator,
    persistent,
    quantile_threshold,
    rmse_split,
    select_sigma_v,
)

FloatArray = np.ndarray


def gp_options(args: argparse.Namespace, hyper_points: int | None = None) -> dict[str, Any]:
    """Keyword arguments of the GP fit of every estimator (``hyper_points``: override)."""
    return dict(
        hyper_points=args.hyper_points if hyper_points is None else hyper_points,
        adam_iters=args.adam_iters,
        lbfgs_iters=args.lbfgs_iters,
        seed=args.seed,
    )


def fit(name: str, xml: str, X: CollisionInputs, y: FloatArray, **kwargs: Any) -> Any:
    """Estimator ``name`` on the nominal model ``xml``, fitted to ``(X, y)``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # L-BFGS fallbacks and jitter notices
        return make_estimator(name, xml, **kwargs).fit(X, y)


def choose_sigma_v(
    args: argparse.Namespace, xml: str, data: dict[str, FloatArray]
) -> dict[str, Any]:
    """Hold-out CV of ``sigma_v`` (first 80% of the training run / last 20%)."""
    X = as_collision_inputs(data)
    y = data["i"]
    cut = int(0.8 * X.n_samples)
    tr = np.arange(0, cut, max(cut // args.cv_points, 1))[: args.cv_points]
    va = np.arange(cut, X.n_samples, max((X.n_samples - cut) // args.cv_validation, 1))
    opts = gp_options(args, min(args.cv_hyper_points, args.cv_points))

    def factory(sigma_v: float) -> Any:
        return make_estimator("FC", xml, sigma_v=sigma_v, **opts)

    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        best, scores = select_sigma_v(
            factory, X.rows(tr), y[tr], X.rows(va), y[va], args.sigma_v_candidates
        )
    return {
        "best": best,
        "scores": {f"{k:g}": v for k, v in scores.items()},
        "n_train": int(tr.size),
        "n_validation": int(va.size),
        "seconds": time.perf_counter() - t0,
    }


def push_records(
    data: dict[str, Any], pushes: list[Push], at_rest: list[bool], gain: FloatArray
) -> list[dict[str, Any]]:
    """Ground truth of every push: magnitude, link, rest/moving, peak ``|tau_ext| / K_eq``."""
    t = data["t"]
    recs = []
    for p, rest in zip(pushes, at_rest, strict=True):
        m = (t >= p.t_start) & (t <= p.t_start + p.duration + 1e-9)
        peak = np.abs(data["tau_ext"][m]).max(axis=0) / gain if m.any() else np.zeros(gain.size)
        recs.append(
            {
                "t_start": p.t_start,
                "duration": p.duration,
                "link": p.link,
                "force": float(np.linalg.norm(p.force)),
                "at_rest": bool(rest),
                "peak_tau_ext_A": peak.tolist(),
            }
        )
    return recs


def score(
    alarm: FloatArray,
    data: dict[str, Any],
    records: list[dict[str, Any]],
    free: dict[str, Any],
    free_alarm: FloatArray,
) -> dict[str, Any]:
    """Detection on the push run (matched to ``records`` by onset) + false alarms/min on
    the push-free run."""
    ev = evaluate_detection(alarm, data["contact"], data["t"])
    starts = np.array([p["start"] for p in ev["pushes"]])
    detected, latency = [], []
    for rec in records:  # runs of contact = pushes, in order; match by onset time
        k = int(np.argmin(np.abs(starts - rec["t_start"])))
        detected.append(bool(ev["pushes"][k]["detected"]))
        latency.append(ev["pushes"][k]["latency"])
    detected_arr = np.array(detected)
    force = np.array([r["force"] for r in records])
    rest = np.array([r["at_rest"] for r in records])
    fa = evaluate_detection(free_alarm, np.zeros_like(free["contact"]), free["t"])

    def rate(mask: FloatArray) -> float:
        return float(detected_arr[mask].mean()) if mask.any() else float("nan")

    lat = [v for v in latency if v is not None]
    return {
        "detected": detected,
        "latency": latency,
        "rate_all": rate(np.ones_like(rest)),
        "rate_ge30": rate(force >= 30.0),
        "rate_moving": rate(~rest),
        "rate_rest": rate(rest),
        "rate_ge30_rest": rate((force >= 30.0) & rest),
        "rate_ge30_moving": rate((force >= 30.0) & ~rest),
        "median_latency": float(np.median(lat)) if lat else float("nan"),
        "false_alarms": fa["false_alarms"],
        "false_alarms_per_minute": fa["false_alarms_per_minute"],
        "push_free_minutes": fa["push_free_minutes"],
        "false_alarms_in_push_run": ev["false_alarms"],
    }


def evaluate_estimator(
    est: Any, sets: dict[str, dict[str, Any]], args: argparse.Namespace, variance: bool
) -> dict[str, Any]:
    """Signals on every set; RMSE split; thresholds; detection tables; ROC points."""
    sigma_v_split = args.rmse_sigma_v
    noise = np.sqrt(np.asarray(est.noise_variance_, dtype=np.float64))
    sig: dict[str, dict[str, FloatArray]] = {}
    t0 = time.perf_counter()
    for key in ("validation", "push_free", "pushes", "scenario"):
        data = sets[key]
        need_var = variance and key != "scenario"  # the scenario uses the max rule only
        mean, var = est.predict(as_collision_inputs(data), return_var=need_var)
        s = data["i"] - mean
        sd = np.sqrt((np.zeros_like(s) if var is None else np.maximum(var, 0.0)) + noise**2)
        sig[key] = {"i_hat": mean, "s": s, "sigma": sd}
    seconds_predict = time.perf_counter() - t0
    val = sets["validation"]
    rmse = rmse_split(val["i"], sig["validation"]["i_hat"], val["qd"], sigma_v_split)
    rules = {"max": sig["validation"]["s"]}
    if variance:
        rules["variance"] = sig["validation"]["s"] / sig["validation"]["sigma"]
    out: dict[str, Any] = {
        "rmse": {k: np.asarray(v).tolist() for k, v in rmse.items()},
        "noise_std": noise.tolist(),
        "predict_seconds": seconds_predict,
        "thresholds": {},
        "detection": {},
        "roc": {},
    }
    recs = sets["push_records"]
    for rule, z in rules.items():
        scale = quantile_threshold(z, 0.0)
        out["thresholds"][rule] = scale.tolist()
        for m in args.persistence:
            alarms = {}
            for key in ("pushes", "push_free"):
                thr = scale if rule == "max" else scale * sig[key]["sigma"]
                alarms[key] = persistent(alarm_flags(sig[key]["s"], thr), m)
            out["detection"][f"{rule}/m={m}"] = score(
                alarms["pushes"], sets["pushes"], recs, sets["push_free"], alarms["push_free"]
            )
        for m in args.roc_persistence:
            roc = []
            for alpha in args.alphas:
                scale_a = quantile_threshold(z, alpha)
                alarms = {}
                for key in ("pushes", "push_free"):
                    thr = scale_a if rule == "max" else scale_a * sig[key]["sigma"]
                    alarms[key] = persistent(alarm_flags(sig[key]["s"], thr), m)
                sc = score(
                    alarms["pushes"], sets["pushes"], recs, sets["push_free"], alarms["push_free"]
                )
                roc.append(
                    {
                        "alpha": alpha,
                        "rate_all": sc["rate_all"],
                        "rate_ge30": sc["rate_ge30"],
                        "false_alarms_per_minute": sc["false_alarms_per_minute"],
                    }
                )
            out["roc"][f"{rule}/m={m}"] = roc
    # the scenario (thesis Fig. 4.3): max rule, m = 1
    sc = sets["scenario"]
    thr = np.asarray(out["thresholds"]["max"])
    alarm = alarm_flags(sig["scenario"]["s"], thr)
    ev = evaluate_detection(alarm, sc["contact"], sc["t"])
    out["scenario"] = {
        "detected": [p["detected"] for p in ev["pushes"]],
        "latency": [p["latency"] for p in ev["pushes"]],
        "false_alarms": ev["false_alarms"],
    }
    out["_signals"] = {k: sig[k] for k in ("scenario",)}
    return out


MODEL_OPTIONS = (
    "seed", "gp_points", "hyper_points", "adam_iters", "lbfgs_iters", "cv_points",
    "cv_validation", "cv_hyper_points", "sigma_v_candidates", "rmse_sigma_v", "persistence",
    "alphas", "roc_persistence",
)  # fmt: skip
"""Options of the cross-validation, the fits and the evaluation (the jobs' arguments)."""


def _gp_rows(train: dict[str, FloatArray], gp_points: int) -> tuple[CollisionInputs, FloatArray]:
    """The GP's conditioning rows: ``gp_points`` rows of the training run, a constant step."""
    X = as_collision_inputs(train)
    step = max(X.n_samples // gp_points, 1)
    rows = np.arange(0, X.n_samples, step)[:gp_points]
    return X.rows(rows), train["i"][rows]


def cv_job(data_path: str, data: dict[str, Any], options: dict[str, Any]) -> dict[str, Any]:
    """The ``sigma_v`` cross-validation (:func:`choose_sigma_v`) as a sweep job; ``data``:
    the :data:`DATA_OPTIONS` of the file (they identify it)."""
    args = argparse.Namespace(**options)
    return choose_sigma_v(args, nominal_model("ur10"), load_sets(data_path)["train"])


def estimator_job(
    label: str,
    name: str,
    kwargs: dict[str, Any],
    data_path: str,
    data: dict[str, Any],
    options: dict[str, Any],
    variance: bool,
    save_detector: str | None = None,
) -> dict[str, Any]:
    """Fit estimator ``name`` (``kwargs``) on the GP rows and evaluate it on every set
    (:func:`evaluate_estimator`; ``PP-sign``: the RMSE split only), as a sweep job; ``data``
    as in :func:`cv_job`. ``save_detector``: also write the FC detector (max rule) there."""
    args = argparse.Namespace(**options)
    sets = dict(load_sets(data_path))
    sets["push_records"] = push_records(
        sets["pushes"], sets["push_list"], sets["push_at_rest"], sets["current_gain"]
    )
    xml = nominal_model("ur10")
    Xs, ys = _gp_rows(sets["train"], args.gp_points)
    t0 = time.perf_counter()
    est = fit(name, xml, Xs, ys, **kwargs)
    fit_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    if label == "PP-sign":  # RMSE only
        mean, _ = est.predict(as_collision_inputs(sets["validation"]), return_var=False)
        val = sets["validation"]
        r = rmse_split(val["i"], mean, val["qd"], args.rmse_sigma_v)
        result = {"rmse": {k: np.asarray(v).tolist() for k, v in r.items()}}
    else:
        result = evaluate_estimator(est, sets, args, variance=variance)
    if save_detector:
        det = CollisionDetector(est, "max", 0.0, args.persistence[0], 0.008)
        det.scale_ = np.asarray(result["thresholds"]["max"])
        det.save(save_detector)
    return {"fit_s": fit_s, "evaluate_s": time.perf_counter() - t0, "result": result}


def run_benchmark(args: argparse.Namespace, runner: SweepRunner) -> dict[str, Any]:
    """Simulate (or read back) the data, run the jobs on ``runner``, write the outputs.

    ``args``: the options of ``mcpilco-bench-collision`` with the list options parsed
    (``estimators``, ``variance_estimators``: names; ``sigma_v_candidates``, ``alphas``:
    floats; ``persistence``, ``roc_persistence``: ints) and ``runs_dir`` a :class:`Path`.
    Returns ``{"results", "markdown", "failed"}`` (``failed``: keys of the failed jobs).
    """
    torch.set_num_threads(args.threads)
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t_wall, t_cpu = time.perf_counter(), time.process_time()
    timing: dict[str, float] = {}
    bar = tqdm(total=5, disable=args.no_progress, desc="simulation")

    t0 = time.perf_counter()
    data_path = args.runs_dir / DATA_FILE
    sets = simulated_sets(args, data_path, bar)
    bar.close()
    timing["simulation"] = time.perf_counter() - t0
    gain = sets["current_gain"]
    sets["push_records"] = push_records(
        sets["pushes"], sets["push_list"], sets["push_at_rest"], gain
    )
    train = sets["train"]
    X = as_collision_inputs(train)
    Xs, _ = _gp_rows(train, args.gp_points)

    common = {
        "data_path": str(data_path),
        "data": {k: getattr(args, k) for k in DATA_OPTIONS},
        "options": {k: getattr(args, k) for k in MODEL_OPTIONS},
    }

    def estimator(label: str, name: str, kw: dict[str, Any]) -> Job:
        save = args.save_detector if label == "FC" else None
        kwargs = {"label": label, "name": name, "kwargs": kw, **common}
        kwargs.update(variance=label in args.variance_estimators, save_detector=save)
        return Job(label, estimator_job, kwargs, cpus=args.threads)

    first = [estimator(name, name, gp_options(args)) for name in args.estimators if name != "FC"]
    if args.pp_sign:
        first.append(estimator("PP-sign", "PP", {**gp_options(args), "coulomb_velocity": 0.0}))
    if "FC" in args.estimators:
        first.insert(0, Job("sigma_v_cv", cv_job, common, cpus=args.threads))
    sweeps = [runner.run(first, args.runs_dir, desc="sigma_v CV and estimators")]
    cv = sweeps[0].results.get("sigma_v_cv", {"best": 1e-2})
    timing["sigma_v_cv"] = cv.get("seconds", 0.0)
    if "FC" in args.estimators and "sigma_v_cv" in sweeps[0].results:
        fc = estimator("FC", "FC", {**gp_options(args), "sigma_v": cv["best"]})
        sweeps.append(runner.run([fc], args.runs_dir, desc="FC"))
    done = {k: v for sw in sweeps for k, v in sw.results.items() if k != "sigma_v_cv"}
    failed = [f for sw in sweeps for f in sw.failed]
    estimators: dict[str, Any] = {}
    for label in [*args.estimators, *(["PP-sign"] if args.pp_sign else [])]:
        if label not in done:
            continue
        res = done[label]["result"]
        if "_signals" in res:  # arrays again for the scenario figure
            res["_signals"] = {
                k: {kk: np.asarray(vv) for kk, vv in v.items()} for k, v in res["_signals"].items()
            }
        estimators[label] = res
        timing[f"fit {label}"] = done[label]["fit_s"]
        timing[f"evaluate {label}"] = done[label]["evaluate_s"]
    for sw in sweeps:
        print(sw.summary())

    results: dict[str, Any] = {
        "config": {k: v for k, v in vars(args).items()},
        "machine": f"{platform.machine()} {os.cpu_count()} CPUs, {platform.python_version()}, "
        f"torch {torch.__version__}",
        "sizes": {
            "train": int(X.n_samples),
            "gp": int(Xs.n_samples),
            "validation": int(sets["validation"]["t"].size),
            "push_free": int(sets["push_free"]["t"].size),
            "pushes": int(sets["pushes"]["t"].size),
            "n_pushes": len(sets["push_list"]),
            "n_pushes_rest": int(sum(sets["push_at_rest"])),
            "quasi_static_fraction_train": (np.abs(train["qd"]) < args.rmse_sigma_v)
            .mean(0)
            .tolist(),
        },
        "current_noise_std": np.asarray(sets["current_noise_std"]).tolist(),
        "current_gain": np.asarray(gain).tolist(),
        "sigma_v_cv": cv,
        "estimators": estimators,
        "push_records": sets["push_records"],
        "scenario_pushes": [dataclasses.asdict(p) for p in sets["scenario_pushes"]],
    }
    results["timing"] = timing
    results["seconds"] = time.perf_counter() - t_wall
    results["cpu_seconds"] = time.process_time() - t_cpu
    results["goals"] = goals(results)
    plot_rmse(results, out_dir / "collision_rmse.png")
    if "FC" in estimators or "SP" in estimators:
        plot_scenario(results, sets, out_dir / "collision_detection.png")
    plot_roc(results, out_dir / "collision_roc.png")
    write_result(out_dir / "collision.json", RESULT_LAYOUTS[0], strip(results))
    text = markdown(results)
    (out_dir / "collision.md").write_text(text)
    return {"results": results, "markdown": text, "failed": [f.key for f in failed]}


# -- result file and headline rows of the results index -----------------------------------

RESULT_LAYOUTS = (
    ResultLayout(
        "collision", config=("config", "goals"), cases=("push_records", "scenario_pushes")
    ),
)
"""The layout of ``collision.json`` (:mod:`mcpilco.experiments.results`)."""


def _collision_row(r: Result) -> str:
    est = r["estimators"]
    fc = est["FC"]["rmse"]["quasi_static"]
    sp = max(est["SP"]["thresholds"]["max"])
    return (
        f"FC quasi-static RMSE {min(fc):.2f}-{max(fc):.2f} A; largest threshold "
        f"FC {max(est['FC']['thresholds']['max']):.2f} A against SP {sp:.2f} A"
    )


HEADLINES = (
    Headline(
        "Collision detection",
        "collision_5000/collision.json",
        _collision_row,
        "collision_5000/collision.md",
        seeds=lambda r: f"seed {r['config']['seed']}",
    ),
)
"""The collision benchmark's row of the results index."""


def replot(result: Result, json_path: Path) -> list[Path]:
    """Redraw ``collision_rmse.png`` and ``collision_roc.png`` next to the result file (the
    scenario figure needs the simulated data, which the file does not hold)."""
    out, payload = Path(json_path).parent, result.payload()
    plot_rmse(payload, out / "collision_rmse.png")
    plot_roc(payload, out / "collision_roc.png")
    return [out / "collision_rmse.png", out / "collision_roc.png"]
