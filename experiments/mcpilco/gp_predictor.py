r"""Cached GP predictor against GPyTorch's own posterior ``model(x)`` in eval mode: timings.

Fits a 2-output GP (ScaleKernel(RBF-ARD)) on N synthetic points in d dimensions, then times one
posterior call (mean and variance) at ``n_test`` points for:

* ``gpytorch``: ``model(x)`` in eval mode with exact settings (prediction caches warm);
* ``fused64`` / ``fused32``: the same posterior as
  :class:`~mcpilco.models.gp.fused.FusedRBFMPKPredictor` (RBF in matmul form, one ``exp``;
  the predictor of the MC-PILCO rollouts), forward only;
* ``cached64`` / ``cached32``: :class:`mcpilco.models.gp.CachedPredictor` in float64 / float32,
  forward only and forward + backward w.r.t. the test inputs;
* ``variance_term64``: a ceiling, the float64 variance term
  :math:`\lVert L^{-1} k(X, x) \rVert^2` alone on a precomputed cross-covariance (the
  :math:`N^2 n / 2` multiply-adds per output that an exact variance through the Cholesky
  factor needs). GPyTorch's time over this one bounds the speed-up of any exact float64
  predictor built on that product; its GFLOP/s are reported next to a dense float64 matmul's.

All timings come from one process with warm-up. The paths are timed in interleaved rounds
(round r times a block of calls of every path in turn), so that a change of load on a shared
machine hits all paths alike; each timing is the median over ``repeats`` rounds of the CPU
time (and, separately recorded, the wall time) per call. :func:`run` returns the results,
:func:`markdown_table` and :func:`summary` render them (``mcpilco-bench-gp`` writes them to
``results/bench_gp_predictor.json``).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import gpytorch
import torch

from mcpilco.experiments.results import Headline, Result, ResultLayout
from mcpilco.models.device import resolve_device
from mcpilco.models.gp import GPRegressor, exact_gp_settings
from mcpilco.models.gp.dense import dense_covar
from mcpilco.models.gp.fused import FusedRBFMPKPredictor

__all__ = ["markdown_table", "run", "summary"]


def _time_interleaved(
    calls: dict[str, tuple[Callable[[], object], int, int]], repeats: int
) -> tuple[dict[str, float], dict[str, float]]:
    """Median seconds per call (CPU, wall) of each ``name: (fn, inner, warmup)``.

    After ``warmup`` calls of each, ``repeats`` rounds each time ``inner`` calls of every
    path in turn; a sample is the mean over its ``inner`` calls.
    """
    for fn, _, warmup in calls.values():
        for _ in range(warmup):
            fn()
    cpu: dict[str, list[float]] = {k: [] for k in calls}
    wall: dict[str, list[float]] = {k: [] for k in calls}
    for _ in range(repeats):
        for name, (fn, inner, _) in calls.items():
            c0, w0 = time.process_time(), time.perf_counter()
            for _ in range(inner):
                fn()
            cpu[name].append((time.process_time() - c0) / inner)
            wall[name].append((time.perf_counter() - w0) / inner)
    return (
        {k: statistics.median(v) for k, v in cpu.items()},
        {k: statistics.median(v) for k, v in wall.items()},
    )


def _make_gp(n_train: int, d: int, m: int, seed: int) -> tuple[GPRegressor, torch.Tensor]:
    """A GP (ScaleKernel(RBF-ARD)) fitted to ``m`` noisy sine outputs of ``n_train`` points
    uniform in ``[-2, 2]^d``; returns it and its inputs."""
    gen = torch.Generator().manual_seed(seed)
    X = torch.rand(n_train, d, generator=gen, dtype=torch.float64) * 4 - 2
    W = torch.randn(d, m, generator=gen, dtype=torch.float64)
    Y = torch.sin(X @ W) + 0.05 * torch.randn(n_train, m, generator=gen, dtype=torch.float64)

    def kernel_factory(batch_shape: torch.Size) -> gpytorch.kernels.Kernel:
        rbf = gpytorch.kernels.RBFKernel(ard_num_dims=d, batch_shape=batch_shape)
        return gpytorch.kernels.ScaleKernel(rbf, batch_shape=batch_shape)

    gp = GPRegressor(kernel_factory).fit(X, Y, adam_iters=30, lbfgs_iters=10)
    return gp, X


def run(
    n_train: int = 500,
    n_test: int = 400,
    d: int = 6,
    m: int = 2,
    repeats: int = 7,
    seed: int = 0,
    device: str = "cpu",
) -> dict:
    """Run the benchmark and return the results dict.

    ``device``: where the calls run (the GP is fitted on the CPU, then the GPyTorch model and
    the predictors are moved there). On a CUDA device every timed call ends with a
    synchronisation, so that its wall time is its latency; CPU time then means nothing.
    """
    dev = resolve_device(device)
    gp, _ = _make_gp(n_train, d, m, seed)
    gen = torch.Generator().manual_seed(seed + 1)
    x64 = torch.rand(n_test, d, generator=gen, dtype=torch.float64) * 4 - 2
    # accuracy reference on the CPU, before the model moves
    m_ref, v_ref = gp.predict_gpytorch(x64)
    # the predictors are extracted on the CPU (where the GP lives), then moved; the fused ones
    # are the same posterior with the RBF in matmul form (what the MC-PILCO rollouts use)
    pred64 = gp.cached_predictor(torch.float64, validate=False)
    pred32 = gp.cached_predictor(torch.float32, validate=False)
    fused64 = FusedRBFMPKPredictor.from_cached(pred64).to(dev)
    fused32 = FusedRBFMPKPredictor.from_cached(pred32).to(dev)
    pred64, pred32 = pred64.to(dev), pred32.to(dev)
    xs = gp._standardize_x(x64).expand(m, n_test, d).to(dev)
    x64 = x64.to(dev)
    x32 = x64.float()
    model = gp.model_.to(dev)
    model.train()  # drops the prediction caches built on the CPU above
    model.eval()
    sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)

    def gpytorch_call() -> None:
        with torch.no_grad(), exact_gp_settings():
            post = model(xs)
            post.mean, post.variance  # noqa: B018 (evaluate both)
        sync()

    def cached(pred: torch.nn.Module, x: torch.Tensor) -> Callable[[], None]:
        def call() -> None:
            with torch.no_grad():
                pred(x)
            sync()

        return call

    def cached_backward(pred: torch.nn.Module, x: torch.Tensor) -> Callable[[], None]:
        xg = x.clone().requires_grad_(True)

        def call() -> None:
            mean, var = pred(xg)
            (mean.sum() + var.sum()).backward()
            sync()

        return call

    # accuracy check against gpytorch (float64, CPU)
    m64, v64 = (t.cpu() for t in pred64(x64))
    max_err = max(float((m64 - m_ref).abs().max()), float((v64 - v_ref).abs().max()))
    mf, vf = (t.cpu() for t in fused64(x64))
    max_err_fused = max(float((mf - m_ref).abs().max()), float((vf - v_ref).abs().max()))

    # the variance's quadratic term alone, ||L^{-1} k(X, x)||^2 on a precomputed
    # cross-covariance: the least work of an exact float64 variance through the Cholesky
    # factor (N^2 n / 2 multiply-adds per output), as a ceiling on any predictor's speed-up
    with torch.no_grad():
        k_cross = dense_covar(pred64.kernel, pred64.train_x.expand(m, n_train, d), xs)

    def variance_term() -> None:
        with torch.no_grad():
            pred64.linv.sq_col_norms(k_cross)
        sync()

    calls = {  # name: (call, calls per block, warm-up calls)
        "gpytorch_eval": (gpytorch_call, 3, 2),
        "cached64": (cached(pred64, x64), 10, 3),
        "cached32": (cached(pred32, x32), 10, 3),
        "fused64": (cached(fused64, x64), 10, 3),
        "fused32": (cached(fused32, x32), 10, 3),
        "cached64_fwd_bwd": (cached_backward(pred64, x64), 5, 2),
        "cached32_fwd_bwd": (cached_backward(pred32, x32), 5, 2),
        "variance_term64": (variance_term, 10, 3),
    }
    # CPU time of this (single-threaded) process is robust to other jobs on a shared machine;
    # wall-clock time is reported too.
    timings, wall = _time_interleaved(calls, repeats)
    ref = timings["gpytorch_eval"]
    tri_flops = 2.0 * m * pred64.linv.multiply_adds(n_test)  # 2 flops per multiply-add
    gemm_gflops = _gemm_gflops(dev, sync)
    return {
        "config": {
            "n_train": n_train,
            "n_test": n_test,
            "d": d,
            "m": m,
            "repeats": repeats,
            "torch_threads": torch.get_num_threads(),
            "device": str(dev),
            "device_name": torch.cuda.get_device_name(dev) if dev.type == "cuda" else "cpu",
            "torch": torch.__version__,
            "gpytorch": gpytorch.__version__,
            "linv_panels": pred64.linv.num_panels,
        },
        "seconds_per_call": timings,
        "clock": "process_time (CPU seconds of this process); paths interleaved per round",
        "wall_seconds_per_call": wall,
        "speedup_vs_gpytorch": {k: ref / v for k, v in timings.items() if k != "gpytorch_eval"},
        "speedup_vs_gpytorch_wall": {
            k: wall["gpytorch_eval"] / v for k, v in wall.items() if k != "gpytorch_eval"
        },
        "variance_term64": {
            "flops": tri_flops,
            "gflops_per_s": tri_flops / timings["variance_term64"] / 1e9,
            "gemm64_reference_gflops_per_s": gemm_gflops,
            "ceiling_speedup_vs_gpytorch": ref / timings["variance_term64"],
        },
        "max_abs_diff_cached64_vs_gpytorch": max_err,
        "max_abs_diff_fused64_vs_gpytorch": max_err_fused,
    }


def _gemm_gflops(dev: torch.device, sync: Callable[[], None], size: int = 1000) -> float:
    """GFLOP/s of one dense float64 ``size``-cube matmul here (median of 5): the machine's
    reference rate for the float64 products above."""
    a = torch.randn(size, size, dtype=torch.float64, device=dev)
    b = torch.randn(size, size, dtype=torch.float64, device=dev)
    a @ b
    sync()
    times = []
    for _ in range(5):
        t = time.perf_counter()
        a @ b
        sync()
        times.append(time.perf_counter() - t)
    return 2.0 * size**3 / statistics.median(times) / 1e9


def markdown_table(result: dict) -> str:
    """Markdown table of the timings."""
    lines = [
        "| path | CPU ms / call | speed-up (CPU) | wall ms / call | speed-up (wall) |",
        "|---|---:|---:|---:|---:|",
    ]
    cpu, wall = result["seconds_per_call"], result["wall_seconds_per_call"]
    for name in cpu:
        lines.append(
            f"| {name} | {cpu[name] * 1e3:.2f} | {cpu['gpytorch_eval'] / cpu[name]:.1f}x "
            f"| {wall[name] * 1e3:.2f} | {wall['gpytorch_eval'] / wall[name]:.1f}x |"
        )
    return "\n".join(lines)


def summary(result: dict) -> str:
    """Two lines on :func:`run`'s ``result``: the speed-ups of the cached and fused predictors
    over GPyTorch (with their accuracy), and the ceiling set by the variance term."""
    c = result["config"]
    f64 = result["speedup_vs_gpytorch"]["fused64"]
    r64 = result["speedup_vs_gpytorch"]["cached64"]
    r32 = result["speedup_vs_gpytorch"]["cached32"]
    vt = result["variance_term64"]
    return (
        f"cached predictor vs gpytorch model(x) in eval mode (N={c['n_train']}, "
        f"{c['n_test']} test points, d={c['d']}, m={c['m']}): float64 {r64:.1f}x, "
        f"float32 {r32:.1f}x faster per call (CPU time; on {c['device']}); "
        f"max |diff| float64 = {result['max_abs_diff_cached64_vs_gpytorch']:.2e}; "
        f"fused RBF posterior, float64: {f64:.1f}x "
        f"(max |diff| {result['max_abs_diff_fused64_vs_gpytorch']:.2e})\n"
        f"ceiling: the float64 variance term ||L^-1 k||^2 alone takes "
        f"{result['seconds_per_call']['variance_term64'] * 1e3:.2f} ms "
        f"({vt['gflops_per_s']:.0f} GFLOP/s; a dense float64 matmul runs at "
        f"{vt['gemm64_reference_gflops_per_s']:.0f} GFLOP/s here), "
        f"{vt['ceiling_speedup_vs_gpytorch']:.1f}x below gpytorch: the speed-up an exact "
        "float64 predictor that forms L^-1 k with this product cannot exceed here"
    )


# -- result file and headline rows of the results index -----------------------------------

RESULT_LAYOUTS = (ResultLayout("gp_predictor", config=("config", "clock")),)
"""The layout of ``bench_gp_predictor.json`` (:mod:`mcpilco.experiments.results`)."""


def _speed_row(r: Result) -> str:
    s = r["speedup_vs_gpytorch"]
    return (
        f"cached predictor {s['cached32']:.1f}x (float32) / {s['cached64']:.1f}x (float64) "
        f"faster than GPyTorch, within {r['max_abs_diff_cached64_vs_gpytorch']:.0e}"
    )


def _gpu_row(r: Result) -> str:
    s = r["speedup_vs_gpytorch"]
    return f"on an H100: {s['cached32']:.1f}x (float32) / {s['cached64']:.1f}x (float64)"


HEADLINES = (
    Headline(
        "GP core, predictor speed (CPU)",
        "bench_gp_predictor.json",
        _speed_row,
        "bench_gp_predictor.json",
        seeds=lambda r: "-",
    ),
    Headline(
        "GP core, predictor speed (GPU)",
        "h100/bench_gp_predictor.json",
        _gpu_row,
        "h100/bench_gp_predictor.json",
        seeds=lambda r: "-",
    ),
)
"""The GP predictor benchmark's rows of the results index."""
