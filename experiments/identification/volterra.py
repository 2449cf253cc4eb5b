r"""The Volterra series identification benchmark: PK / IPK / MPK / SED-MPK (thesis 6.5).

Experiment 1 (thesis 6.5.1): the order-3, memory-6 system (6.36)
(:func:`mcpilco.models.volterra.spinelli_system`), 1000 training and 1000 test samples of
zero-mean Gaussian input, measurement noise :math:`\sigma_n = 4`.
Setup 1: train and test input std 4; setup 2: train std 1, test std 4.
Estimators: PK (6.18), IPK (6.23), MPK (6.25) of order 3 and memory 6, trained on the same
data in each run, and the least-squares oracle on the true monomials (:data:`ORACLE`).

Experiment 2 (thesis 6.5.2): the Wiener system (6.38)
(:func:`mcpilco.models.volterra.wiener_system`) with :math:`r = 2..5`, memory 70 (71 lagged
inputs), 3500 training and 3500 test samples of unit Gaussian input, SNR 5 dB and 20 dB, where
:math:`\mathrm{SNR} = 10\log_{10}(\mathrm{var}(z_{train}) / \sigma_n^2)`, i.e.
:math:`\sigma_n = \mathrm{std}(z_{train})\,10^{-\mathrm{SNR}/20}` computed on each run's noiseless
training output. Estimators: MPK (6.25) for :math:`r = 2, 3` (as in the thesis' figure 6.3)
and the SED-MPK (6.30) in the special case (6.35) the thesis uses, all :math:`\alpha_p`
(:math:`\beta_p`) equal (kind ``"sed_mpk_tied"``), for :math:`r = 2..5` (figures 6.3-6.4).

Metric: Fit% :math:`= 100(1-\|z-\hat z\|_1/\|z-\bar z\|_1)` on the noiseless test output.

Protocol and compute-saving choices:

* every record (training and test) starts from rest (:math:`u_k = 0` for :math:`k<0`), so the
  zero-padded regressors of :func:`~mcpilco.models.volterra.lag_matrix` are exact;
* inputs are scaled by one scalar (the training input std) before the kernel, outputs are
  standardised with the training statistics;
* hyperparameters are trained by exact marginal likelihood through ``GPRegressor.fit`` with
  L-BFGS only (strong-Wolfe line search, 30 iterations, from the kernels' default
  initialisation); ``adam_iters`` adds Adam steps before it, which reach the same marginal
  likelihood at several times the cost;
* experiment 1 trains the hyperparameters on all 1000 training samples, as the thesis does.
  Experiment 2 trains them on a random subset of ``ml_points`` = 500 of the 3500 training
  samples (the marginal likelihood costs :math:`O(N^3)` per iteration), then conditions the
  GP on **all** training samples for prediction (posterior mean only, see
  ``VolterraGP.predict``);
* the SED-MPK of experiment 2 is the thesis' special case (6.35),
  :class:`~mcpilco.models.kernels.TiedSEDMPKernel`: one :math:`(\alpha, \beta)` shared by
  every factor of every order, :math:`r + 3` hyperparameters. The general kernel (kind
  ``"sed_mpk"``, its own hierarchical :math:`(\alpha_p, \beta_p)` per factor and order,
  :math:`r(r+1)` more) is much harder to train within this budget;
* run ``i`` uses ``seed = base_seed + i``: the input draw comes from
  ``SeedSequence(seed, spawn_key=(experiment, 1))`` (setups 1 and 2 share the normalised
  draw, the orders of experiment 2 share the input), the noise from
  ``SeedSequence(seed, spawn_key=(experiment, 2, config))``; the three (two) estimators of a
  run see the same data. Results are reproducible for a given ``base_seed``;
* every run is a sweep job (:mod:`mcpilco.experiments.infra.sweep`) with one torch thread; its
  result is kept in ``volterra_runs/exp<e>/<config>/seed<s>.json``, so that a killed or
  extended benchmark recomputes only the runs without one (``rerun``: all).

:func:`run_benchmark` writes ``volterra.json`` (config, every per-run Fit, timings),
``volterra_exp1.png`` and ``volterra_exp2.png`` (boxplots) and ``volterra.md`` (median /
mean Fit per kernel and setup, with the run counts actually used;
:mod:`mcpilco.experiments.identification.volterra_report`).
"""

from __future__ import annotations

import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.experiments.identification.volterra_report import (
    ORACLE,
    collect,
    markdown_table,
    plot_exp1,
    plot_exp2,
    result_order,
)
from mcpilco.experiments.infra.sweep import InProcessBackend, Job, LocalBackend, SweepRunner
from mcpilco.experiments.results import Headline, Result, ResultLayout, write_result

# one config per experiment: every default of the benchmark lives here
EXP1 = {
    "memory": 6,
    "order": 3,
    "n_train": 1000,
    "n_test": 1000,
    "noise_std": 4.0,
    "setups": {
        "setup1": {"train_std": 4.0, "test_std": 4.0},
        "setup2": {"train_std": 1.0, "test_std": 4.0},
    },
    "kinds": ["pk", "ipk", "mpk"],
    "runs": 100,
    "ml_points": None,
    "adam_iters": 0,
    "adam_lr": 0.05,
    "lbfgs_iters": 30,
}
EXP2 = {
    "memory": 70,
    "orders": [2, 3, 4, 5],
    "snrs_db": [5.0, 20.0],
    "n_train": 3500,
    "n_test": 3500,
    "input_std": 1.0,
    "kinds": ["mpk", "sed_mpk_tied"],
    # kinds run only for some orders (others: every order); the thesis compares MPK and
    # SED-MPK at r = 2, 3 (figure 6.3) and shows SED-MPK alone for r = 3, 4, 5 (figure 6.4)
    "kind_orders": {"mpk": [2, 3]},
    "runs": 40,
    "ml_points": 500,
    "adam_iters": 0,
    "adam_lr": 0.05,
    "lbfgs_iters": 30,
}
#: small budget for a quick check: experiment 1 only, two runs, fewer ML points
QUICK = {"experiments": (1,), "runs": 2, "exp1": {"ml_points": 250, "lbfgs_iters": 20}}


@dataclass
class Task:
    """One Monte Carlo run of one configuration (all estimators on the same data)."""

    experiment: int
    config: str
    run: int
    seed: int
    params: dict[str, Any] = field(default_factory=dict)


def _rng(seed: int, *key: int) -> np.random.Generator:
    """Independent stream ``key`` of run seed ``seed``.

    ``SeedSequence(seed, spawn_key=key)``: the input stream is ``(experiment, 1)``, the noise
    stream ``(experiment, 2, config)``. (Not ``default_rng([seed, *key])``: entropy lists are
    zero-padded, so ``[s, 1]`` and ``[s, 1, 0]`` would give the *same* stream and the noise
    would equal the input.)
    """
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


def exp1_data(
    seed: int,
    train_std: float,
    test_std: float,
    n_train: int,
    n_test: int,
    noise_std: float,
    config_index: int,
) -> dict[str, np.ndarray]:
    """Training / test records of system (6.36); noise on the training output only."""
    from mcpilco.models.volterra import spinelli_system

    rng_u = _rng(seed, 1, 1)
    u_train = train_std * rng_u.standard_normal(n_train)
    u_test = test_std * rng_u.standard_normal(n_test)
    rng_e = _rng(seed, 1, 2, config_index)
    z_train = spinelli_system(u_train)
    y_train = z_train + noise_std * rng_e.standard_normal(n_train)
    return {
        "u_train": u_train,
        "y_train": y_train,
        "u_test": u_test,
        "z_test": spinelli_system(u_test),
    }


def exp2_data(
    seed: int,
    order: int,
    snr_db: float,
    n_train: int,
    n_test: int,
    input_std: float,
    config_index: int,
) -> dict[str, Any]:
    r"""Training / test records of the Wiener system (6.38) at the given SNR.

    :math:`\sigma_n = \mathrm{std}(z_{train})\,10^{-\mathrm{SNR}/20}`.
    """
    from mcpilco.models.volterra import wiener_system

    rng_u = _rng(seed, 2, 1)
    u_train = input_std * rng_u.standard_normal(n_train)
    u_test = input_std * rng_u.standard_normal(n_test)
    z_train = wiener_system(u_train, order)
    noise_std = float(z_train.std() * 10.0 ** (-snr_db / 20.0))
    rng_e = _rng(seed, 2, 2, config_index)
    y_train = z_train + noise_std * rng_e.standard_normal(n_train)
    return {
        "u_train": u_train,
        "y_train": y_train,
        "u_test": u_test,
        "z_test": wiener_system(u_test, order),
        "noise_std": noise_std,
    }


def make_tasks(
    experiments: tuple[int, ...], runs1: int, runs2: int, base_seed: int, exp1: dict, exp2: dict
) -> list[Task]:
    """All (experiment, configuration, run) tasks."""
    tasks: list[Task] = []
    # run index outermost: an interrupted benchmark has balanced run counts per configuration
    for i in range(runs1 if 1 in experiments else 0):
        for ci, (name, setup) in enumerate(exp1["setups"].items()):
            params = {**setup, "config_index": ci}
            tasks.append(Task(1, name, i, base_seed + i, params))
    for i in range(runs2 if 2 in experiments else 0):
        ci = 0
        for r in exp2["orders"]:
            for snr in exp2["snrs_db"]:
                params = {"order": r, "snr_db": snr, "config_index": ci}
                tasks.append(Task(2, config_name(r, snr), i, base_seed + i, params))
                ci += 1
    return tasks


def oracle_prediction(data: dict[str, np.ndarray]) -> np.ndarray:
    r"""Test output of least squares on the 14 monomials that (6.36) really holds.

    :math:`\hat c = \arg\min_c \|y - \Phi c\|_2` with :math:`\Phi` =
    :func:`~mcpilco.models.volterra.spinelli_monomials` of the training input, then
    :math:`\hat z = \Phi_{test} \hat c`. It knows the structure no kernel is given, so its Fit
    bounds what the GP estimators can be expected to reach on the same data.
    """
    from mcpilco.models.volterra import spinelli_monomials

    coef, *_ = np.linalg.lstsq(spinelli_monomials(data["u_train"]), data["y_train"], rcond=None)
    return spinelli_monomials(data["u_test"]) @ coef


def config_name(order: int, snr_db: float) -> str:
    """Key of an experiment-2 configuration, e.g. ``r3_snr20``."""
    return f"r{order}_snr{snr_db:g}"


def run_task(task: Task | dict[str, Any], exp1: dict, exp2: dict) -> dict[str, Any]:
    """Fit every estimator of the task's experiment on the same data; Fit% and timings.
    ``task``: a :class:`Task` or its dict (as in a sweep job)."""
    import torch

    from mcpilco.models.volterra import VolterraGP, fit_percent

    if isinstance(task, dict):
        task = Task(**task)
    p = task.params
    if task.experiment == 1:
        cfg = exp1
        data = exp1_data(
            task.seed,
            p["train_std"],
            p["test_std"],
            cfg["n_train"],
            cfg["n_test"],
            cfg["noise_std"],
            p["config_index"],
        )
        order = cfg["order"]
    else:
        cfg = exp2
        order = p["order"]
        data = exp2_data(
            task.seed,
            order,
            p["snr_db"],
            cfg["n_train"],
            cfg["n_test"],
            cfg["input_std"],
            p["config_index"],
        )
    out: dict[str, Any] = {
        "experiment": task.experiment,
        "config": task.config,
        "run": task.run,
        "seed": task.seed,
        "fit": {},
        "seconds": {},
        "error": {},
    }
    if "noise_std" in data:
        out["noise_std"] = data["noise_std"]
    kind_orders = cfg.get("kind_orders", {})
    for kind in cfg["kinds"]:
        if kind in kind_orders and order not in kind_orders[kind]:
            continue
        torch.manual_seed(task.seed)
        t0 = time.perf_counter()
        try:
            est = VolterraGP(
                kind,
                order,
                cfg["memory"],
                ml_points=cfg["ml_points"],
                adam_iters=cfg["adam_iters"],
                adam_lr=cfg["adam_lr"],
                lbfgs_iters=cfg["lbfgs_iters"],
                seed=task.seed,
            )
            est.fit(data["u_train"], data["y_train"])
            z_hat = est.predict(data["u_test"])
            out["fit"][kind] = fit_percent(data["z_test"], z_hat)
        except (RuntimeError, ValueError, FloatingPointError) as exc:  # recorded, not hidden
            out["fit"][kind] = None
            out["error"][kind] = f"{type(exc).__name__}: {exc}"
        out["seconds"][kind] = time.perf_counter() - t0
    if task.experiment == 1:  # reference: least squares on the true monomials (no kernel)
        t0 = time.perf_counter()
        out["fit"][ORACLE] = fit_percent(data["z_test"], oracle_prediction(data))
        out["seconds"][ORACLE] = time.perf_counter() - t0
    return out


def task_job(task: Task, exp1: dict, exp2: dict) -> Job:
    """The sweep job of ``task`` (:func:`run_task`, one thread), keyed
    ``exp<e>/<config>/seed<s>``; only its own experiment's settings are in its arguments."""
    cfg = {k: v for k, v in (exp1 if task.experiment == 1 else exp2).items() if k != "runs"}
    kwargs = {
        "task": asdict(task),
        "exp1": cfg if task.experiment == 1 else {},
        "exp2": cfg if task.experiment == 2 else {},
    }
    return Job(f"exp{task.experiment}/{task.config}/seed{task.seed}", run_task, kwargs)


def run_benchmark(
    *,
    runs: int | None = None,
    runs_exp2: int | None = None,
    experiments: tuple[int, ...] = (1, 2),
    out_dir: str | Path = "results",
    jobs: int = 1,
    base_seed: int = 0,
    exp1_overrides: dict | None = None,
    exp2_overrides: dict | None = None,
    progress: bool = True,
    command: str | None = None,
    rerun: bool = False,
    runner: SweepRunner | None = None,
) -> dict:
    """Run the benchmark and write JSON, PNG(s) and the Markdown table to ``out_dir``.

    Args:
        runs: Monte Carlo runs of experiment 1 (default ``EXP1["runs"]`` = 100); also of
            experiment 2 when ``runs_exp2`` is None and ``runs`` is given.
        runs_exp2: runs of experiment 2 (default ``EXP2["runs"]`` = 40).
        experiments: subset of ``(1, 2)``.
        out_dir: output folder (created).
        jobs: worker processes (1: in this process) when no ``runner`` is given.
        base_seed: run ``i`` uses seed ``base_seed + i``.
        exp1_overrides, exp2_overrides: entries replacing those of ``EXP1`` / ``EXP2``
            (e.g. ``{"n_train": 100}``, ``{"orders": [3]}``).
        progress: tqdm bar over runs.
        command: the command line recorded in the outputs.
        rerun: recompute the runs that have a result in ``out_dir/volterra_runs`` (by
            default they are reused: those of the same experiment, configuration, seed and
            settings); the wall time counts this invocation only.
        runner: the sweep runner (default: ``jobs`` local processes).

    Returns:
        ``{"summary": ..., "paths": {"json", "markdown", "exp1_png", "exp2_png"}, "wall_s",
        "failed"}`` (``failed``: keys of the runs whose job failed, see their
        ``.error.txt``).
    """
    experiments = tuple(sorted(set(experiments)))
    if not experiments or any(e not in (1, 2) for e in experiments):
        raise ValueError(f"experiments must be a non-empty subset of (1, 2), got {experiments}")
    exp1 = {**EXP1, **(exp1_overrides or {})}
    exp2 = {**EXP2, **(exp2_overrides or {})}
    runs1 = EXP1["runs"] if runs is None else int(runs)
    runs2 = (EXP2["runs"] if runs is None else int(runs)) if runs_exp2 is None else int(runs_exp2)
    if runs1 < 1 or runs2 < 1:
        raise ValueError(f"runs must be >= 1, got runs={runs1}, runs_exp2={runs2}")
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    if runner is None:
        backend = LocalBackend(jobs) if jobs > 1 else InProcessBackend()
        runner = SweepRunner(backend, progress=progress, log=print)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    tasks = make_tasks(experiments, runs1, runs2, base_seed, exp1, exp2)
    t0 = time.perf_counter()
    sweep = runner.run(
        [task_job(t, exp1, exp2) for t in tasks],
        out / "volterra_runs",
        rerun=rerun,
        desc="volterra runs",
    )
    results = list(sweep.results.values())
    n_reused = len(sweep.skipped)
    wall = time.perf_counter() - t0

    coll = collect(results, experiments, exp1, exp2)
    meta = {
        "command": command
        or f"run_benchmark(runs={runs1}, runs_exp2={runs2}, "
        f"experiments={experiments}, jobs={runner.slots()}, base_seed={base_seed})",
        "experiments": list(experiments),
        "runs_exp1": runs1 if 1 in experiments else 0,
        "runs_exp2": runs2 if 2 in experiments else 0,
        "base_seed": base_seed,
        "jobs": runner.slots(),
        "backend": sweep.backend,
        "wall_s": wall,
        "runs_reused": n_reused,
        "runs_failed": [f.key for f in sweep.failed],
        "compute_s": float(sum(sum(r["seconds"].values()) for r in results)),
        "exp1": exp1,
        "exp2": exp2,
        "snr_definition": "SNR = 10 log10(var(z_train) / sigma_n^2)",
        "fit_definition": "100 (1 - ||z - z_hat||_1 / ||z - mean(z)||_1), noiseless test output",
    }
    paths = {"json": str(out / "volterra.json"), "markdown": str(out / "volterra.md")}
    payload = {
        "meta": meta,
        "summary": coll["summary"],
        "fits": coll["fits"],
        "runs": sorted(results, key=result_order),
    }
    write_result(paths["json"], RESULT_LAYOUTS[0], payload, command=meta.get("command"))
    Path(paths["markdown"]).write_text(markdown_table(coll["summary"], meta) + "\n")
    if "exp1" in coll["fits"]:
        paths["exp1_png"] = str(out / "volterra_exp1.png")
        plot_exp1(coll["fits"]["exp1"], Path(paths["exp1_png"]))
    if "exp2" in coll["fits"]:
        paths["exp2_png"] = str(out / "volterra_exp2.png")
        plot_exp2(coll["fits"]["exp2"], Path(paths["exp2_png"]))
    if sweep.failed:
        print(sweep.summary(), file=sys.stderr)
    return {
        "summary": coll["summary"],
        "paths": paths,
        "wall_s": wall,
        "failed": [f.key for f in sweep.failed],
    }


def quick_benchmark(out_dir: str | Path = "results/volterra_quick", jobs: int = 2) -> dict:
    """Small-budget benchmark: ``QUICK`` settings (experiment 1, 2 runs).

    Returns the :func:`run_benchmark` dict (``summary``, ``paths``, ``wall_s``).
    """
    return run_benchmark(
        runs=QUICK["runs"],
        experiments=QUICK["experiments"],
        out_dir=out_dir,
        jobs=jobs,
        exp1_overrides=QUICK["exp1"],
        command=f"quick_benchmark(out_dir={str(out_dir)!r}, jobs={jobs})",
    )


# -- result file and headline rows of the results index -----------------------------------

RESULT_LAYOUTS = (
    ResultLayout(
        "volterra",
        config=("meta",),
        cases=("fits", "runs"),
        seeds=lambda p: sorted({r["seed"] for r in p.get("runs", []) if "seed" in r}),
    ),
)
"""The layout of ``volterra.json`` (:mod:`mcpilco.experiments.results`)."""


def _volterra_row(r: Result) -> str:
    exp2 = r["summary"]["exp2"]
    fits = " / ".join(f"{exp2[f'r{k}_snr20']['sed_mpk_tied']['mean']:.1f}" for k in (3, 4, 5))
    s2 = r["summary"]["exp1"]["setup2"]
    return (
        f"SED-MPK mean Fit {fits} % at r = 3 / 4 / 5, 20 dB; Setup 2 median Fit MPK "
        f"{s2['mpk']['median']:.1f} %, PK {s2['pk']['median']:.1f} %"
    )


def _volterra_seeds(r: Result) -> str:
    m = r["meta"]
    b = m["base_seed"]
    return f"{b}-{b + m['runs_exp1'] - 1} (exp. 1), {b}-{b + m['runs_exp2'] - 1} (exp. 2)"


HEADLINES = (
    Headline(
        "Kernels: Volterra identification",
        "volterra.json",
        _volterra_row,
        "volterra.md",
        seeds=_volterra_seeds,
    ),
)
"""The Volterra benchmark's row of the results index."""


def replot(result: Result, json_path: Path) -> list[Path]:
    """Redraw ``volterra_exp1.png`` / ``volterra_exp2.png`` next to the result file."""
    out, paths = Path(json_path).parent, []
    for exp, fn in (("exp1", plot_exp1), ("exp2", plot_exp2)):
        if exp in result["fits"]:
            fn(result["fits"][exp], out / f"volterra_{exp}.png")
            paths.append(out / f"volterra_{exp}.png")
    return paths
