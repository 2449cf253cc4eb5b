r"""Volterra series identification benchmark: PK / IPK / MPK / SED-MPK (thesis section 6.5).

Experiment 1 (thesis 6.5.1): the order-3, memory-6 system (6.36)
(:func:`mcpilco.models.volterra.spinelli_system`), 1000 training and 1000 test samples of
zero-mean Gaussian input, measurement noise :math:`\sigma_n = 4`.
Setup 1: train and test input std 4; setup 2: train std 1, test std 4.
Estimators: PK (6.18), IPK (6.23), MPK (6.25) of order 3 and memory 6, trained on the same
data in each run.

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
  initialisation; ``--adam-iters`` adds Adam steps before it). On 2 shared cores one ML
  iteration at N = 1000 costs ~0.2-0.7 s; probes showed Adam (200 it) + L-BFGS reaching the
  same marginal likelihood as L-BFGS alone at 4x the cost;
* experiment 1 trains the hyperparameters on all 1000 training samples, as the thesis does.
  Experiment 2 trains them on a random subset of ``ml_points`` = 500 of the 3500 training
  samples (ML on all 3500 costs ~300 s per fit here; in a probe, r = 4, 20 dB, seed 0, the
  SED-MPK Fit was 93.9 % with the subset and 95.5 % with all samples), then conditions the GP
  on **all** training samples for prediction (posterior mean only, see
  ``VolterraGP.predict``);
* the SED-MPK of experiment 2 is the thesis' special case (6.35),
  :class:`~mcpilco.models.kernels.TiedSEDMPKernel`: one :math:`(\alpha, \beta)` shared by
  every factor of every order, :math:`r + 3` hyperparameters. The general kernel (kind
  ``"sed_mpk"``, its own hierarchical :math:`(\alpha_p, \beta_p)` per factor and order,
  :math:`r(r+1)` more) reached only ~40 % Fit at :math:`r = 4, 5` with this budget;
* run ``i`` uses ``seed = base_seed + i``: the input draw comes from
  ``SeedSequence(seed, spawn_key=(experiment, 1))`` (setups 1 and 2 share the normalised
  draw, the orders of experiment 2 share the input), the noise from
  ``SeedSequence(seed, spawn_key=(experiment, 2, config))``; the three (two) estimators of a
  run see the same data. Results are reproducible for a given ``--base-seed``;
* every run is a sweep job (:mod:`mcpilco.experiments.sweep`) with one torch thread, in
  ``--jobs`` worker processes or on Ray (``--ray [ADDRESS]``); its result is kept in
  ``volterra_runs/exp<e>/<config>/seed<s>.json``, so that a killed or extended benchmark
  recomputes only the runs without one (``--rerun``: all).

Outputs (``--out-dir``, default ``results/``): ``volterra.json`` (config, every per-run Fit,
timings), ``volterra_exp1.png`` and ``volterra_exp2.png`` (boxplots), ``volterra.md``
(median / mean Fit per kernel and setup, with the run counts actually used).

Examples::

    mcpilco-bench-volterra                      # full protocol (100 / 40 runs; 2 h of compute)
    mcpilco-bench-volterra --runs 20 --runs-exp2 6 --jobs 2
    mcpilco-bench-volterra --quick              # experiment 1 only, 2 runs, ~1-2 min
    python -c "from mcpilco.scripts.bench_volterra import quick_benchmark; quick_benchmark()"
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.agents.common.cli import console_main
from mcpilco.experiments.sweep import (
    InProcessBackend,
    Job,
    LocalBackend,
    SweepError,
    SweepRunner,
    add_sweep_arguments,
    runner_from_args,
)

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
#: small budget for ``make demo`` (about 1-2 minutes on 2 cores)
QUICK = {"experiments": (1,), "runs": 2, "exp1": {"ml_points": 250, "lbfgs_iters": 20}}


@dataclass
class Task:
    """One Monte Carlo run of one configuration (all estimators on the same data)."""

    experiment: int
    config: str
    run: int
    seed: int
    params: dict[str, Any] = field(default_factory=dict)


# --------------------------------------------------------------------------------------------
# data
# --------------------------------------------------------------------------------------------
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


ORACLE = "ls_oracle"
"""Key of the experiment-1 reference estimator (:func:`oracle_prediction`) in the results."""


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


# --------------------------------------------------------------------------------------------
# one task
# --------------------------------------------------------------------------------------------
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


# --------------------------------------------------------------------------------------------
# summary and outputs
# --------------------------------------------------------------------------------------------
def _result_order(res: dict) -> tuple:
    """Sort key: experiment, then configuration (numeric order for ``r{r}_snr{snr}``), run."""
    cfg = res["config"]
    if res["experiment"] == 2:
        r, snr = cfg[1:].split("_snr")
        return (2, int(r), float(snr), "", res["run"])
    return (res["experiment"], 0, 0.0, cfg, res["run"])


def collect(results: list[dict], experiments: tuple[int, ...], exp1: dict, exp2: dict) -> dict:
    """Per-configuration lists of Fit% (ordered by run) and summary statistics."""
    per: dict[str, dict[str, dict[str, list]]] = {}
    for res in sorted(results, key=_result_order):
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
                name = kind.upper().replace("SED_MPK_TIED", "SED").replace("SED_MPK", "SED*")
                labels.append(f"{name}\n{cname.split('_')[0]}")
        n = max(len(g) for g in groups)
        _box(ax, groups, labels, f"SNR {snr} dB ({n} runs)")
    fig.suptitle("Experiment 2: Wiener system (6.38)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# --------------------------------------------------------------------------------------------
# driver
# --------------------------------------------------------------------------------------------
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
    with open(paths["json"], "w") as fh:
        json.dump(
            {
                "meta": meta,
                "summary": coll["summary"],
                "fits": coll["fits"],
                "runs": sorted(results, key=_result_order),
            },
            fh,
            indent=1,
            default=_json_default,
        )
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
    """Small-budget benchmark for ``make demo``: ``QUICK`` settings (experiment 1, 2 runs).

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


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    raise TypeError(f"not JSON serialisable: {type(obj)}")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="mcpilco-bench-volterra",
        description="Volterra identification with PK/IPK/MPK/SED-MPK GPs (thesis section 6.5).",
    )
    p.add_argument(
        "--runs",
        type=int,
        default=None,
        help=f"Monte Carlo runs of experiment 1 (default {EXP1['runs']}); also of "
        "experiment 2 unless --runs-exp2 is given",
    )
    p.add_argument(
        "--runs-exp2", type=int, default=None, help=f"runs of experiment 2 (default {EXP2['runs']})"
    )
    p.add_argument("--experiments", type=int, nargs="+", default=[1, 2], choices=[1, 2])
    p.add_argument(
        "--orders",
        type=int,
        nargs="+",
        default=None,
        help=f"experiment-2 Volterra orders (default {EXP2['orders']})",
    )
    p.add_argument(
        "--snrs",
        type=float,
        nargs="+",
        default=None,
        help=f"experiment-2 SNRs in dB (default {EXP2['snrs_db']})",
    )
    add_sweep_arguments(p)  # --jobs N (worker processes, 1 torch thread each), --ray [ADDRESS]
    p.add_argument("--base-seed", type=int, default=0, help="run i uses seed base_seed + i")
    p.add_argument("--out-dir", default="results")
    p.add_argument(
        "--quick",
        action="store_true",
        help=f"small budget for `make demo`: experiments {QUICK['experiments']}, "
        f"{QUICK['runs']} runs",
    )
    p.add_argument("--no-progress", action="store_true")
    p.add_argument(
        "--rerun",
        action="store_true",
        help="recompute the runs that have a result in OUT_DIR/volterra_runs (by default "
        "they are reused, e.g. after an interrupted invocation)",
    )
    # hidden options for tests and budget studies
    for name in ("n-train", "n-test", "ml-points", "adam-iters", "lbfgs-iters"):
        p.add_argument(f"--{name}", type=int, default=None, help=argparse.SUPPRESS)
    return p


@console_main("mcpilco-bench-volterra")
def main(argv: list[str] | None = None) -> int:
    """Command-line entry point (``mcpilco-bench-volterra``)."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        runner = runner_from_args(args, progress=not args.no_progress)
    except SweepError as err:
        parser.error(str(err))
    experiments = tuple(args.experiments)
    runs, runs2 = args.runs, args.runs_exp2
    over1: dict[str, Any] = {}
    if args.quick:
        experiments = QUICK["experiments"]
        runs = QUICK["runs"] if runs is None else runs
        over1.update(QUICK["exp1"])
    common = {
        k: v
        for k, v in {
            "n_train": args.n_train,
            "n_test": args.n_test,
            "ml_points": args.ml_points,
            "adam_iters": args.adam_iters,
            "lbfgs_iters": args.lbfgs_iters,
        }.items()
        if v is not None
    }
    over1.update(common)
    over2 = dict(common)
    if args.orders:
        over2["orders"] = args.orders
    if args.snrs:
        over2["snrs_db"] = args.snrs
    cmd = "mcpilco-bench-volterra " + " ".join(sys.argv[1:] if argv is None else argv)
    res = run_benchmark(
        runs=runs,
        runs_exp2=runs2,
        experiments=experiments,
        out_dir=args.out_dir,
        runner=runner,
        base_seed=args.base_seed,
        exp1_overrides=over1,
        exp2_overrides=over2,
        progress=not args.no_progress,
        rerun=args.rerun,
        command=cmd.strip(),
    )
    print(Path(res["paths"]["markdown"]).read_text())
    for name, path in res["paths"].items():
        print(f"{name}: {path}")
    return 1 if res["failed"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
