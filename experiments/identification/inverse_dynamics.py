"""The inverse-dynamics benchmark: estimators GIP, RBF, NN, FE, PP, SP (thesis section 3.4).

Parts (the names in double backquotes are attributes of the options object):

``scara``
    Monte Carlo over ``runs`` experiments (thesis 3.4.1). Each run perturbs the kinematic
    parameters of the data-generating SCARA (every DH ``a``, ``d`` by ``U(-0.05, 0.05)`` m and
    ``alpha``, ``theta`` by ``U(-5, 5)`` deg) while FE/PP/SP keep the nominal model (model
    bias); training and test trajectories are two independent sums of ``n_sinusoids``
    sinusoids per joint with random amplitudes, phases and angular velocities in
    ``[-2, 2]`` rad/s; torques from the exact inverse dynamics (``mj_inverse``, rotor inertia
    included, no friction) plus Gaussian noise of std ``noise`` N m; ``n_train`` training
    and ``n_test`` test samples, ``dt`` s apart. Output: nMSE per joint per estimator
    (boxplot PNG + table). Each run is a sweep job (:mod:`mcpilco.experiments.infra.sweep`) in
    the sweep runner's processes or on Ray, its result kept in
    ``runs_dir/scara/run<i>.json``: a rerun computes only the runs without one.
``efficiency``
    Data efficiency without model bias (thesis Fig. 3.3): the nominal robot generates the
    data; GMSE (sum over joints of the test MSE) vs training-set size ``sizes`` for GIP,
    PP, RBF, NN (nested random subsets of one training set); log-log PNG.
``ur10``
    ``mcpilco/UR10-v0`` data (thesis 3.4.2): ``ur10_train`` samples of random exploration
    (friction, motor-current noise, causal ``qdd``), test = a new exploration plus the tool
    circle; targets the motor currents ``i``. GP estimators are conditioned on
    ``ur10_subset`` rows taken with a constant step; FE and NN use all rows. PP/SP/FE use
    the nominal UR10 with friction columns (viscous, Coulomb). nMSE per joint vs the noise
    floor ``sigma_i^2 / Var(i)``.
``timing``
    GIP hyperparameter training (all ``timing_n`` rows of UR10 data, 6 joints) and
    prediction at ``timing_n`` points, next to one fp64 Cholesky of that size (and the 6
    batched ones of the 6 joint GPs) on the same machine.

The SCARA is ``mcpilco.envs.arms.scara()`` with a 3 kg tool on the last link (centre of mass
8 cm off the joint-4 axis, ``no_tool`` to drop it): without it the joint-4 torque has a
standard deviation of ~0.03 N m, so the 0.01 N m noise alone gives joint 4 an nMSE floor of
~10% and no estimator can reach 1% there.

GP hyperparameters: marginal likelihood (Adam ``adam_iters`` then L-BFGS ``lbfgs_iters``)
on a random subset of ``hyper_points`` rows, then the GP is conditioned on all rows
(``GPInverseDynamics(hyper_points=...)``); every GP estimator gets the same budget.

:func:`run_benchmark` takes the options of ``mcpilco-bench-inverse-dynamics`` (an
``argparse.Namespace`` or any object with those attributes, lists already parsed) and
writes, after every part, ``inverse_dynamics.json``, ``inverse_dynamics.md`` and the
figures of :mod:`mcpilco.experiments.identification.inverse_dynamics_report`; with
``append`` the parts of an earlier JSON that this call does not run are kept.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import platform
import statistics
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from mcpilco.envs.arm_builder import ArmSpec, LinkInertia, arm_to_xml, solid_cylinder_inertia
from mcpilco.envs.arm_data import collect, inverse_dynamics_samples, make_arm_env
from mcpilco.envs.arm_env import SumOfSinusoids
from mcpilco.envs.arms import scara, ur10
from mcpilco.experiments.identification.inverse_dynamics_report import (
    goals,
    markdown,
    plot_efficiency,
    plot_scara,
    plot_ur10,
)
from mcpilco.experiments.infra.sweep import Job, SweepRunner
from mcpilco.experiments.results import Headline, Result, ResultLayout, read_result, write_result
from mcpilco.models.inverse_dynamics import (
    FisherianEstimator,
    GIPEstimator,
    GIPFrictionEstimator,
    InverseDynamicsEstimator,
    NNEstimator,
    PPEstimator,
    RBFEstimator,
    SPEstimator,
    gmse,
    nmse,
)
from mcpilco.models.inverse_dynamics.inputs import as_joint_states
from mcpilco.models.kernels import GIPKernel

PARTS = ("scara", "efficiency", "ur10", "timing")
"""Parts of the benchmark, in the order they run."""

ESTIMATORS = ("FE", "PP", "SP", "GIP", "RBF", "NN")
"""Estimators of the ``scara`` part by default."""

FRICTION_BLOCKS = ("rigid", "armature", "viscous", "coulomb")
"""Regressor blocks of FE/PP/SP with friction (the ``ur10`` part)."""

FloatArray = np.ndarray


def scara_with_tool(mass: float = 3.0, com: tuple[float, float, float] = (0.08, 0.0, -0.05)):
    """``scara()`` with its last link replaced by a tool of ``mass`` kg at ``com`` (frame {4})."""
    arm = scara()
    tool = LinkInertia(mass, com, solid_cylinder_inertia(mass, 0.05, 0.15, "x"))
    return dataclasses.replace(arm, links=(*arm.links[:-1], tool))


def without_limits(arm: ArmSpec) -> ArmSpec:
    """A copy without joint ranges (``mj_inverse`` must not see joint-limit forces)."""
    joints = tuple(dataclasses.replace(j, range=None) for j in arm.joints)
    return dataclasses.replace(arm, joints=joints)


def perturb_kinematics(
    arm: ArmSpec, rng: np.random.Generator, length: float = 0.05, angle_deg: float = 5.0
) -> ArmSpec:
    """Every DH ``a``, ``d`` + ``U(-length, length)`` m, ``alpha``, ``theta`` +
    ``U(-angle, angle)`` (thesis 3.4.1); joint ranges removed (see :func:`without_limits`)."""
    da = math.radians(angle_deg)
    joints = tuple(
        dataclasses.replace(
            j,
            a=j.a + rng.uniform(-length, length),
            d=j.d + rng.uniform(-length, length),
            alpha=j.alpha + rng.uniform(-da, da),
            theta=j.theta + rng.uniform(-da, da),
            range=None,
        )
        for j in arm.joints
    )
    return dataclasses.replace(arm, joints=joints)


def sinusoid_reference(
    nominal: ArmSpec,
    rng: np.random.Generator,
    n_sinusoids: int = 200,
    omega_max: float = 2.0,
    spread: float = 0.35,
) -> SumOfSinusoids:
    """Sum of ``n_sinusoids`` sinusoids per joint (thesis 3.4.1) around the middle of the joint
    range: amplitudes ``a ~ U(-1, 1)``, angular velocities ``w ~ U(-omega_max, omega_max)``,
    phases ``U(-pi, pi)``; amplitudes scaled so the standard deviation of ``q_j`` is ``spread``
    times half the joint range."""
    ranges = nominal.joint_ranges
    centre, half = ranges.mean(1), 0.5 * (ranges[:, 1] - ranges[:, 0])
    n = centre.shape[0]
    a = rng.uniform(-1.0, 1.0, (n, n_sinusoids))
    w = rng.uniform(-omega_max, omega_max, (n, n_sinusoids))
    phi = rng.uniform(-math.pi, math.pi, (n, n_sinusoids))
    a = a * (spread * half / np.sqrt(0.5 * (a**2).sum(1)))[:, None]
    return SumOfSinusoids(centre, a, w, phi)


def simulated_data(
    real: ArmSpec,
    reference: SumOfSinusoids,
    n: int,
    dt: float,
    noise: float,
    rng: np.random.Generator,
) -> tuple[FloatArray, FloatArray]:
    """``X (n, 3n_j) = [q, qd, qdd]`` and noisy torques ``y`` along ``reference`` on ``real``."""
    out = inverse_dynamics_samples(real, reference, np.arange(n) * dt, noise_std=noise, rng=rng)
    return np.concatenate([out["q"], out["qd"], out["qdd"]], axis=1), out["tau"]


def make_estimator(
    name: str,
    args: argparse.Namespace,
    nominal_xml: str,
    joint_types: str,
    friction: bool,
    nn_hidden: int | None = None,
    nn_epochs: int | None = None,
) -> InverseDynamicsEstimator:
    """One estimator with the benchmark's budget (``args``); ``friction`` adds the viscous and
    Coulomb columns to FE/PP/SP."""
    gp = dict(
        adam_iters=args.adam_iters,
        lbfgs_iters=args.lbfgs_iters,
        hyper_points=args.hyper_points,
        seed=args.seed,
    )
    blocks = FRICTION_BLOCKS if friction else ("rigid", "armature")
    nn = dict(
        hidden=args.nn_hidden if nn_hidden is None else nn_hidden,
        max_epochs=args.nn_epochs if nn_epochs is None else nn_epochs,
        patience=args.nn_patience,
        batch_size=args.nn_batch,
        seed=args.seed,
    )
    factories: dict[str, Callable[[], InverseDynamicsEstimator]] = {
        "FE": lambda: FisherianEstimator(nominal_xml, blocks=blocks),
        "PP": lambda: PPEstimator(nominal_xml, blocks=blocks, **gp),
        "SP": lambda: SPEstimator(nominal_xml, blocks=blocks, **gp),
        "GIP": lambda: GIPEstimator(joint_types, **gp),
        "GIP-std": lambda: GIPEstimator(joint_types, standardize_x=True, **gp),
        "GIP+F": lambda: GIPFrictionEstimator(joint_types, **gp),
        "RBF": lambda: RBFEstimator(**gp),
        "NN": lambda: NNEstimator(**nn),
    }
    if name not in factories:
        raise ValueError(f"unknown estimator {name!r}; choose from {sorted(factories)}")
    return factories[name]()


def fit_predict(
    est: InverseDynamicsEstimator, X: FloatArray, y: FloatArray, X_test: FloatArray
) -> tuple[FloatArray, float, float]:
    """Fit, predict; returns ``(mean, fit seconds, predict seconds)``."""
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est.fit(X, y)
        t1 = time.perf_counter()
        mean, _ = est.predict(X_test)
    return mean, t1 - t0, time.perf_counter() - t1


def nominal_scara(args: argparse.Namespace) -> ArmSpec:
    """The nominal SCARA (joint ranges kept: they set the reference's centre and spread)."""
    return scara() if args.no_tool else scara_with_tool()


SCARA_OPTIONS = (
    "seed", "no_tool", "n_sinusoids", "n_train", "n_test", "dt", "noise", "estimators",
    "gip_std", "adam_iters", "lbfgs_iters", "hyper_points", "nn_hidden", "nn_epochs",
    "nn_patience", "nn_batch",
)  # fmt: skip
"""Options of the ``scara`` part's runs (the arguments of their sweep jobs)."""


def scara_run(run: int, options: dict[str, Any]) -> dict[str, Any]:
    """Monte Carlo run ``run`` of the ``scara`` part (``options``: :data:`SCARA_OPTIONS`):
    noise floor, nMSE per joint and fit seconds per estimator. A sweep job."""
    args = argparse.Namespace(**options)
    nominal = nominal_scara(args)
    xml = arm_to_xml(without_limits(nominal).without_friction())
    rng = np.random.default_rng([args.seed, run])
    real = perturb_kinematics(nominal, rng)
    ref_train = sinusoid_reference(nominal, rng, args.n_sinusoids)
    ref_test = sinusoid_reference(nominal, rng, args.n_sinusoids)
    X, y = simulated_data(real, ref_train, args.n_train, args.dt, args.noise, rng)
    Xt, yt = simulated_data(real, ref_test, args.n_test, args.dt, args.noise, rng)
    out: dict[str, Any] = {"floor": (args.noise**2 / yt.var(0)).tolist(), "nmse": {}, "fit_s": {}}
    for name in list(args.estimators) + (["GIP-std"] if args.gip_std else []):
        est = make_estimator(name, args, xml, nominal.joint_types, friction=False)
        mean, t_fit, _ = fit_predict(est, X, y, Xt)
        out["nmse"][name] = nmse(yt, mean).tolist()
        out["fit_s"][name] = t_fit
    return out


def part_scara(
    args: argparse.Namespace, bar: tqdm, runner: SweepRunner | None = None
) -> dict[str, Any]:
    """Monte Carlo nMSE with model bias (see the module docstring); the runs are sweep jobs
    of ``runner`` (default: in this process) kept in ``args.runs_dir/scara``."""
    runner = runner if runner is not None else SweepRunner(progress=False)
    nominal = nominal_scara(args)
    names = list(args.estimators) + (["GIP-std"] if args.gip_std else [])
    options = {k: getattr(args, k) for k in SCARA_OPTIONS}
    jobs = [
        Job(f"run{run}", scara_run, {"run": run, "options": options}, cpus=args.threads)
        for run in range(args.runs)
    ]
    sweep = runner.run(jobs, Path(args.runs_dir) / "scara", desc="scara runs")
    bar.update(len(jobs) * len(names))
    runs = list(sweep.results.values())
    return {
        "joint_types": nominal.joint_types,
        "nmse": {k: [r["nmse"][k] for r in runs] for k in names},
        "fit_seconds": {k: [r["fit_s"][k] for r in runs] for k in names},
        "noise_floor": [r["floor"] for r in runs],
        "n_train": args.n_train,
        "n_test": args.n_test,
        "runs": len(runs),
        "failed_runs": [f.key for f in sweep.failed],
    }


def part_efficiency(args: argparse.Namespace, bar: tqdm) -> dict[str, Any]:
    """GMSE vs training size without model bias (see the module docstring)."""
    nominal = nominal_scara(args)
    xml = arm_to_xml(without_limits(nominal).without_friction())
    real = without_limits(nominal)  # no model bias
    rng = np.random.default_rng([args.seed, 1000])
    n_max = max(args.sizes)
    X, y = simulated_data(
        real, sinusoid_reference(nominal, rng, args.n_sinusoids), n_max, args.dt, args.noise, rng
    )
    Xt, yt = simulated_data(
        real,
        sinusoid_reference(nominal, rng, args.n_sinusoids),
        args.n_test,
        args.dt,
        args.noise,
        rng,
    )
    order = rng.permutation(n_max)
    out: dict[str, list[float]] = {k: [] for k in args.efficiency_estimators}
    for size in sorted(args.sizes):
        rows = np.sort(order[:size])
        for name in args.efficiency_estimators:
            bar.set_postfix_str(f"efficiency N={size} {name}")
            est = make_estimator(name, args, xml, nominal.joint_types, friction=False)
            mean, _, _ = fit_predict(est, X[rows], y[rows], Xt)
            out[name].append(gmse(yt, mean))
            bar.update(1)
    sizes = sorted(args.sizes)
    summary = {}
    if "GIP" in out and "RBF" in out:
        target = out["RBF"][-1]
        reach = next((s for s, g in zip(sizes, out["GIP"], strict=True) if g <= target), None)
        summary = {
            "rbf_gmse_at_max": target,
            "gip_samples_to_reach_rbf_max": reach,
            "ratio": None if reach is None else sizes[-1] / reach,
        }
    return {
        "sizes": sizes,
        "gmse": out,
        "n_test": args.n_test,
        "noise_gmse_floor": float(yt.shape[1] * args.noise**2),
        "summary": summary,
    }


def _ur10_arrays(duration: float, seed: int, program: str) -> dict[str, FloatArray]:
    arrays, _ = collect("ur10", program, duration=duration, seed=seed)
    return arrays


def part_ur10(args: argparse.Namespace, bar: tqdm) -> dict[str, Any]:
    """UR10 env data, motor-current targets (see the module docstring)."""
    env = make_arm_env("ur10")
    dt = env.dt
    noise_std = np.asarray(env.current_noise_std, dtype=np.float64)
    arm = ur10()
    xml = arm_to_xml(without_limits(arm).without_friction())
    bar.set_postfix_str("ur10 collecting")
    train = _ur10_arrays(args.ur10_train * dt, args.seed, "exploration")
    test_expl = _ur10_arrays(args.ur10_test_exploration * dt, args.seed + 1, "exploration")
    # the circle sets its own duration (radius 30 cm at 30 mm/s: ~63 s)
    test_circle = _ur10_arrays(60.0, args.seed + 2, "circle") if args.ur10_circle else None

    def xy(a: dict[str, FloatArray]) -> tuple[FloatArray, FloatArray]:
        return np.concatenate([a["q"], a["qd"], a["qdd"]], axis=1), a["i"]

    X, y = xy(train)
    tests = [xy(test_expl)] + ([xy(test_circle)] if test_circle is not None else [])
    Xt = np.concatenate([t[0] for t in tests])
    yt = np.concatenate([t[1] for t in tests])
    step = max(X.shape[0] // args.ur10_subset, 1)
    Xs, ys = X[::step][: args.ur10_subset], y[::step][: args.ur10_subset]
    floor = (noise_std**2 / yt.var(0)).tolist()
    out: dict[str, Any] = {
        "n_train": int(X.shape[0]),
        "n_gp": int(Xs.shape[0]),
        "n_test": int(Xt.shape[0]),
        "n_test_circle": 0 if test_circle is None else int(tests[1][0].shape[0]),
        "noise_floor": floor,
        "current_noise_std": noise_std.tolist(),
        "nmse": {},
        "fit_seconds": {},
    }
    bar.update(1)
    for name in args.ur10_estimators:
        bar.set_postfix_str(f"ur10 {name}")
        est = make_estimator(
            name,
            args,
            xml,
            arm.joint_types,
            friction=True,
            nn_hidden=args.ur10_nn_hidden,
            nn_epochs=args.ur10_nn_epochs,
        )
        full = name in ("FE", "NN")
        mean, t_fit, _ = fit_predict(est, X if full else Xs, y if full else ys, Xt)
        out["nmse"][name] = nmse(yt, mean).tolist()
        out["fit_seconds"][name] = t_fit
        bar.update(1)
    return out


def cholesky_seconds(n: int, batch: int = 1, repeats: int = 5) -> float:
    """Median seconds of ``torch.linalg.cholesky`` of ``batch`` SPD ``n x n`` fp64 matrices."""
    g = torch.Generator().manual_seed(0)
    a = torch.randn(batch, n, n, generator=g, dtype=torch.float64)
    spd = a @ a.mT / n + torch.eye(n, dtype=torch.float64)
    torch.linalg.cholesky(spd)
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        torch.linalg.cholesky(spd)
        samples.append(time.perf_counter() - t0)
    return statistics.median(samples)


def gip_gram_seconds(kernel: GIPKernel, xbar: torch.Tensor, repeats: int = 2) -> dict[str, float]:
    """Seconds of one Gram matrix ``K(xbar, xbar)`` forward + backward (a random ``dL/dK``):
    the blocked :func:`~mcpilco.models.kernels.product.linear_product_gram` used by
    ``GIPKernel`` against plain autograd through its MPK factors (one full-size tensor per
    factor and partial product). Median of ``repeats``; ``ratio`` = autograd / blocked."""
    g = torch.randn(*kernel.batch_shape, xbar.shape[0], xbar.shape[0], dtype=xbar.dtype)

    def seconds(fn: Callable[[], torch.Tensor]) -> float:
        samples = []
        for _ in range(repeats):
            kernel.zero_grad(set_to_none=True)
            t0 = time.perf_counter()
            (fn() * g).sum().backward()
            samples.append(time.perf_counter() - t0)
        return statistics.median(samples)

    with torch.enable_grad():
        blocked = seconds(lambda: kernel.forward(xbar, xbar))
        plain = seconds(lambda: kernel.mpk_product(xbar, xbar))
    kernel.zero_grad(set_to_none=True)
    return {"blocked": blocked, "autograd": plain, "ratio": plain / blocked}


def part_timing(args: argparse.Namespace, bar: tqdm) -> dict[str, Any]:
    """GIP training / prediction time at N = ``--timing-n`` on UR10 data vs the Cholesky floor."""
    n = args.timing_n
    bar.set_postfix_str("timing collecting")
    env = make_arm_env("ur10")
    a = _ur10_arrays(2 * n * env.dt, args.seed + 10, "exploration")
    X = np.concatenate([a["q"], a["qd"], a["qdd"]], axis=1)
    y = a["i"]
    X, y, Xt = X[::2][:n], y[::2][:n], X[1::2][:n]
    est = GIPEstimator(
        ur10().joint_types, adam_iters=args.timing_adam_iters, lbfgs_iters=args.timing_lbfgs_iters
    )
    mean, t_fit, t_pred = fit_predict(est, X, y, Xt)
    bar.update(1)
    chol1 = cholesky_seconds(n, 1)
    chol6 = cholesky_seconds(n, y.shape[1])
    iters = args.timing_adam_iters + args.timing_lbfgs_iters
    xbar = torch.as_tensor(est.gp_inputs(as_joint_states(X, 6)), dtype=torch.float64)
    gram = gip_gram_seconds(est.gp_.model_.covar_module, xbar)
    return {
        "gram_forward_backward_seconds": gram,
        "n": int(X.shape[0]),
        "joints": int(y.shape[1]),
        "adam_iters": args.timing_adam_iters,
        "lbfgs_iters": args.timing_lbfgs_iters,
        "train_seconds": t_fit,
        "train_seconds_per_iteration": t_fit / max(iters, 1),
        "predict_seconds": t_pred,
        "cholesky_seconds": chol1,
        "cholesky_batch_seconds": chol6,
        "torch_threads": torch.get_num_threads(),
    }


PLOTS = {  # part -> its figure's file name and plot function
    "scara": ("inverse_dynamics_scara_nmse.png", plot_scara),
    "efficiency": ("inverse_dynamics_efficiency.png", plot_efficiency),
    "ur10": ("inverse_dynamics_ur10_nmse.png", plot_ur10),
}


def write_outputs(results: dict[str, Any], out_dir: Path, append: bool) -> str:
    """Write the JSON, PNGs and Markdown of ``results``; with ``append`` the parts of an
    existing JSON that ``results`` lacks are kept. Returns the Markdown."""
    json_path = out_dir / "inverse_dynamics.json"
    merged = dict(results)
    if append and json_path.exists():
        earlier = read_result(json_path).payload()
        for part in PARTS:
            if part not in merged and part in earlier:
                merged[part] = earlier[part]
    merged["goals"] = goals(merged)
    for part, (fname, fn) in PLOTS.items():
        if part in merged:
            fn(merged[part], out_dir / fname)
            merged[part]["png"] = fname
    write_result(json_path, RESULT_LAYOUTS[0], merged)
    text = markdown(merged)
    (out_dir / "inverse_dynamics.md").write_text(text)
    return text


def run_benchmark(
    args: argparse.Namespace, parts: Sequence[str], runner: SweepRunner | None = None
) -> dict[str, Any]:
    """Run ``parts`` (of :data:`PARTS`) with the options ``args`` and write the outputs to
    ``args.out_dir`` after every part.

    ``args``: the options of ``mcpilco-bench-inverse-dynamics`` with the lists parsed
    (``estimators``, ``efficiency_estimators``, ``ur10_estimators``: names; ``sizes``:
    ints). ``runner`` runs the ``scara`` part's Monte Carlo runs (default: in this process).
    Returns ``{"results", "markdown", "failed"}`` (``failed``: the failed scara runs).
    """
    unknown = [p for p in parts if p not in PARTS]
    if unknown:
        raise ValueError(f"unknown part(s) {unknown}; choose from {PARTS}")
    torch.set_num_threads(args.threads)
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    n_est = len(args.estimators) + int(args.gip_std)
    total = {
        "scara": args.runs * n_est,
        "efficiency": len(args.sizes) * len(args.efficiency_estimators),
        "ur10": 1 + len(args.ur10_estimators),
        "timing": 1,
    }
    bar = tqdm(total=sum(total[p] for p in parts), disable=args.no_progress, desc="bench")
    config = {k: v for k, v in vars(args).items()}
    results: dict[str, Any] = {
        "config": config,
        "machine": f"{platform.machine()} {os.cpu_count()} CPUs, {platform.python_version()}, "
        f"torch {torch.__version__}",
    }
    t0 = time.perf_counter()
    runners = {
        "scara": lambda a, b: part_scara(a, b, runner),
        "efficiency": part_efficiency,
        "ur10": part_ur10,
        "timing": part_timing,
    }
    text = ""
    for part in parts:
        t_part = time.perf_counter()
        results[part] = runners[part](args, bar)
        results[part]["seconds"] = time.perf_counter() - t_part
        results[part]["config"] = config
        results["seconds"] = time.perf_counter() - t0
        text = write_outputs(results, out_dir, args.append)  # after every part
    bar.close()
    failed = results.get("scara", {}).get("failed_runs", [])
    return {"results": results, "markdown": text, "failed": failed}


# -- result file and headline rows of the results index -----------------------------------

RESULT_LAYOUTS = (ResultLayout("inverse_dynamics", config=("config", "goals")),)
"""The layout of ``inverse_dynamics.json`` (:mod:`mcpilco.experiments.results`)."""


def _scara_row(r: Result) -> str:
    nmse = r["scara"]["nmse"]
    med = {k: [statistics.median(col) for col in zip(*v, strict=True)] for k, v in nmse.items()}
    gip = med["GIP"]
    rbf = min(a / g for a, g in zip(med["RBF"], gip, strict=True))
    nn = min(a / g for a, g in zip(med["NN"], gip, strict=True))
    return (
        f"SCARA: GIP median nMSE {min(gip):.1e}-{max(gip):.1e} per joint, "
        f">= {rbf:.0f}x below RBF and >= {nn:.0f}x below NN"
    )


def _ur10_row(r: Result) -> str:
    u = r["ur10"]
    ratio = [a / b for a, b in zip(u["nmse"]["GIP+F"], u["noise_floor"], strict=True)]
    return (
        f"UR10 from motor currents: GIP+F within {min(ratio[:4]):.1f}-{max(ratio[:4]):.1f}x "
        "of the noise floor on joints 1-4"
    )


HEADLINES = (
    Headline(
        "Inverse dynamics",
        "inverse_dynamics.json",
        _scara_row,
        "inverse_dynamics.md",
        part="scara",
        seeds=lambda r: (
            f"seed {r['config'].get('seed', 0)}, {r['config']['runs']} Monte Carlo runs"
        ),
    ),
    Headline(
        "Inverse dynamics",
        "inverse_dynamics.json",
        _ur10_row,
        "inverse_dynamics.md",
        part="ur10_gip_f",
        seeds=lambda r: f"seed {r['config'].get('seed', 0)}",
    ),
)
"""The inverse-dynamics benchmark's rows of the results index."""


def replot(result: Result, json_path: Path) -> list[Path]:
    """Redraw the inverse-dynamics figures next to the result file, from the file."""
    out, paths = Path(json_path).parent, []
    for part, (fname, fn) in PLOTS.items():
        if part in result:
            fn(result[part], out / fname)
            paths.append(out / fname)
    return paths
