r"""The particle rollout written by hand in C++: ``backend="native"`` of
:meth:`~mcpilco.agents.mc_pilco.loss.MCPilcoLoss.compile_step`.

The same maths as :mod:`~mcpilco.agents.mc_pilco.direct_compile` (the parts' analytic
backward passes, chained by hand through time), evaluated by one C++ function per shard for
the whole forward loop and one for the whole backward loop (``native_rollout.cpp``), instead
of ``2 H`` calls of inductor-compiled graphs per shard. What that buys:

* particles in tiles of 16 (the library's ``mcp_tile()``): a tile's whole time step
  (policy, GP posterior, sampling, integration, cost) runs on data that stays in the
  core's caches;
* the products with the GP's constant matrices, ``[V; m] = [L^{-1} Phi, L^{-1}; alpha^T Phi,
  alpha^T] R`` forward and ``dR = [...]^T [dV; g_m]`` backward (glossary of
  :mod:`~mcpilco.models.gp.fused`), use one register-blocked kernel over the constant matrix
  packed once per GP fit, by blocks of 6 rows (``mcp_row_block()``; 6 x 16 accumulators)
  with each block's own range of columns: the zeros of the triangular factor are skipped
  row block by row block (about ``N^2 / 2 + F N`` multiply-adds per particle and output,
  each way);
* no per-op allocation, dispatch or Python between the time steps.

The C++ file has no torch headers: it is compiled on first use with the system's C++
compiler (``-O3 -march=native``, 2-3 s), cached by the hash of its source and flags under
:func:`cache_dir`, and called through ``ctypes`` (which releases the GIL, so the shards run
in parallel threads). Float32 only, one state layout (:data:`NATIVE_LAYOUT`) only
(:func:`native_unsupported_reason`); ``compile_step`` checks the result against the eager
rollout like every compiled path.

Glossary: as in :mod:`~mcpilco.agents.mc_pilco.direct_compile` (``K`` candidates, ``M``
particles, ``S`` shards, ``H`` horizon) and :mod:`~mcpilco.models.gp.fused` (``N`` training
points, ``F`` MPK features, ``m = 2`` outputs, ``d = 6`` GP inputs).
"""

from __future__ import annotations

import ctypes
import hashlib
import math
import os
import platform
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from mcpilco.agents.mc_pilco.cost import MODE_PLAIN, MODE_WRAP
from mcpilco.agents.mc_pilco.direct_compile import DirectRollout, unsupported_reason
from mcpilco.agents.mc_pilco.features import StateLayout

SOURCE = Path(__file__).with_name("native_rollout.cpp")
"""The C++ source of the rollout."""

CXX_FLAGS = ("-O3", "-march=native", "-fno-math-errno", "-shared", "-fPIC")
"""Compiler flags (no ``-ffast-math``: NaN must propagate, the loss restarts on a NaN cost)."""

NATIVE_LAYOUT = StateLayout(
    n=4, plain_idx=(0, 1, 3), angle_idx=(2,), position_idx=(0, 2), velocity_idx=(1, 3)
)
"""The one state layout the C++ loop is written for: ``[p, p_dot, a, a_dot]`` with the angle
``a`` (a cart-pole or any such 1-D base with a pendulum)."""

_LIB: ctypes.CDLL | None = None
_LIB_ERROR: str | None = None
_LIB_LOCK = threading.Lock()


class _Packed(ctypes.Structure):
    _fields_ = [
        ("a", ctypes.c_void_p),
        ("beg", ctypes.c_void_p),
        ("end", ctypes.c_void_p),
        ("off", ctypes.c_void_p),
        ("blocks", ctypes.c_int),
    ]


class _Gp(ctypes.Structure):
    _fields_ = [
        *((name, ctypes.c_int) for name in ("m", "n", "d", "p", "f")),
        *(
            (name, ctypes.c_void_p)
            for name in (
                "idx_a",
                "idx_c",
                "x_mean",
                "x_scale",
                "y_mean",
                "y_scale",
                "inv_l2",
                "outputscale",
                "sig_diag",
                "sig2",
                "noise_var",
                "bound",
            )
        ),  # fmt: skip
        ("w_aug", _Packed * 2),
        ("fwd", _Packed * 2),
        ("bwd", _Packed * 2),
        ("w_t", _Packed * 2),
    ]


class _Pol(ctypes.Structure):
    _fields_ = [("nb", ctypes.c_int), ("u_max", ctypes.c_float)]


class _Cost(ctypes.Structure):
    _fields_ = [
        ("l_x", ctypes.c_float),
        ("l_theta", ctypes.c_float),
        ("dt", ctypes.c_float),
        ("wrap", ctypes.c_int),
    ]


class _Shard(ctypes.Structure):
    _fields_ = [(name, ctypes.c_int) for name in ("horizon", "K", "per", "tiles_per")]


def cache_dir() -> Path:
    """Where the compiled library is kept: ``$MCPILCO_NATIVE_CACHE``, else
    ``$XDG_CACHE_HOME/mcpilco/native`` (``~/.cache/mcpilco/native``)."""
    env = os.environ.get("MCPILCO_NATIVE_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "mcpilco" / "native"


def _cpu_key() -> str:
    """What ``-march=native`` compiles for: the CPU's model and feature flags (Linux), else
    the platform's processor name; part of the cache key, so that a cache shared between
    machines never hands one a library built for another CPU."""
    try:
        with open("/proc/cpuinfo") as f:
            lines = [ln for ln in f if ln.startswith(("model name", "flags"))]
        return "".join(sorted(set(lines)))
    except OSError:
        return platform.machine() + platform.processor()


def build_error() -> str | None:
    """Why building the library failed in this process (None: it did not fail)."""
    return _LIB_ERROR


def cpp_compiler_names() -> list[str]:
    """The C++ compilers looked for, in order: ``$CXX`` alone if it is set, else ``g++`` and
    ``clang++`` (the compilers inductor's CPU backend uses too)."""
    return [os.environ["CXX"]] if os.environ.get("CXX") else ["g++", "clang++"]


def cpp_compiler() -> str | None:
    """The first of :func:`cpp_compiler_names` found on ``PATH`` (None: none)."""
    return next((name for name in cpp_compiler_names() if shutil.which(name)), None)


def _build(cxx: str) -> Path:
    """The library's path in :func:`cache_dir`, compiled there by ``cxx`` unless it is
    already (raises ``RuntimeError`` with the compiler's message if the build fails)."""
    source = SOURCE.read_bytes()
    key = repr((cxx, CXX_FLAGS, _cpu_key())).encode()
    target = cache_dir() / f"native_rollout_{hashlib.sha256(source + key).hexdigest()[:16]}.so"
    if target.exists():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=".so", dir=target.parent)
    os.close(fd)
    cmd = [cxx, *CXX_FLAGS, "-o", tmp, str(SOURCE)]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        os.unlink(tmp)
        raise RuntimeError(f"{' '.join(cmd)} failed: {done.stderr.strip()[:2000]}")
    os.replace(tmp, target)  # atomic: a concurrent build writes the same bytes
    return target


def load_library() -> ctypes.CDLL:
    """The compiled rollout library, built on first use (see the module docstring).

    Raises ``RuntimeError`` (with the compiler's message) if no C++ compiler is found, the
    build fails or the library does not load (e.g. an unwritable cache folder); a failure
    other than a missing compiler is remembered for the process."""
    global _LIB, _LIB_ERROR
    with _LIB_LOCK:
        if _LIB is not None:
            return _LIB
        if _LIB_ERROR is not None:
            raise RuntimeError(_LIB_ERROR)
        cxx = cpp_compiler()
        if cxx is None:
            # not remembered: a compiler installed (or CXX set) later in the process is used
            raise RuntimeError(f"no C++ compiler found ({' or '.join(cpp_compiler_names())})")
        try:
            lib = ctypes.CDLL(str(_build(cxx)))
        except (OSError, subprocess.SubprocessError) as err:  # unwritable cache, bad .so
            _LIB_ERROR = f"{type(err).__name__}: {err}"
            raise RuntimeError(_LIB_ERROR) from err
        except RuntimeError as err:
            _LIB_ERROR = str(err)
            raise
        lib.mcp_record_floats.restype = ctypes.c_int64
        lib.mcp_record_floats.argtypes = [ctypes.c_int] * 5
        lib.mcp_row_block.restype = ctypes.c_int
        lib.mcp_tile.restype = ctypes.c_int
        lib.mcp_forward.restype = ctypes.c_int
        lib.mcp_backward.restype = ctypes.c_int
        _LIB = lib
        return lib


def native_unsupported_reason(
    policy: Any, dynamics: Any, cost: Any, device: torch.device
) -> str | None:
    """Why the native rollout cannot run this loss (None: it can): the direct backend's
    conditions (:func:`~mcpilco.agents.mc_pilco.direct_compile.unsupported_reason`), float32
    throughout, one action, a GP of 2 outputs over the 6 cart-pole inputs (RBF, or RBF plus a
    degree-2 MPK, the package's two kernels) with at most 511 training points, and a working
    C++ compiler."""
    reason = unsupported_reason(policy, dynamics, cost, device)
    if reason is not None:
        return reason
    pred = dynamics.delta_model
    if policy.weights.dtype != torch.float32 or pred.dtype != torch.float32:
        return "it runs in float32 only"
    if policy.weights.shape[-1] != 1:
        return f"it needs one action, the policy has {policy.weights.shape[-1]}"
    if float(policy.u_mid.abs().max()) != 0.0:
        return "it needs symmetric action bounds"
    if dynamics.layout != NATIVE_LAYOUT:
        return f"it needs the state layout {NATIVE_LAYOUT}, got {dynamics.layout}"
    if (
        cost.idx != (0, 2)
        or cost.targets != (0.0, math.pi)
        or cost.modes[0] != MODE_PLAIN
        or cost.modes[1] == MODE_PLAIN
    ):
        return f"it needs a cost on x_0 (target 0) and the angle x_2 (target pi), got {cost}"
    if pred.m != 2 or pred.input_dim != 6:
        return f"it needs a GP of 2 outputs over 6 inputs, got {pred.m} over {pred.input_dim}"
    if pred.p not in (0, 2):
        return f"it takes RBF or RBF + degree-2 MPK kernels, not MPK degree {pred.p}"
    if pred.n + 1 > 512:
        return f"it takes at most 511 training points, the GP has {pred.n}"
    try:
        load_library()
    except RuntimeError as err:
        return f"the native library is not available ({err})"
    return None


def pack_blocks(
    A: Tensor, beg: list[int], end: list[int], rb: int
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Pack ``A (rows, cols)`` for the C++ kernel ``gemm_tile``: rows padded with zeros to a
    multiple of ``rb``; block ``b`` (rows ``rb b .. rb b + rb - 1``) keeps columns
    ``beg[b] .. end[b] - 1``, column by column, its ``rb`` rows' entries together. Returns
    the packed float32 values and the int32 ``beg``, ``end`` and int64 offsets of the
    blocks."""
    rows, cols = A.shape
    blocks = -(-rows // rb)
    if len(beg) != blocks or len(end) != blocks:
        raise ValueError(f"{blocks} blocks need as many column ranges")
    Ap = A.new_zeros(blocks * rb, cols)
    Ap[:rows] = A
    parts, offs, o = [], [], 0
    for b in range(blocks):
        part = Ap[b * rb : (b + 1) * rb, beg[b] : end[b]].T.reshape(-1)
        parts.append(part)
        offs.append(o)
        o += part.numel()
    return (
        torch.cat(parts).to(torch.float32).contiguous(),
        torch.tensor(beg, dtype=torch.int32),
        torch.tensor(end, dtype=torch.int32),
        torch.tensor(offs, dtype=torch.int64),
    )


def _ptr(t: Tensor | None) -> int | None:
    return None if t is None else t.data_ptr()


class NativeGP:
    """The fused GP posterior's constants, packed for the C++ rollout (kept alive here).

    Per output ``b``: ``W_aug`` (``N`` rows, 8 columns), the forward matrix ``[B; alpha_aug]``
    with ``B = [L^{-1} Phi, L^{-1}]`` (``N + 1`` rows; a block of rows ``r .. r + rb - 1 < N``
    needs columns ``< F + r + rb``), the backward matrix ``[B; alpha_aug]^T`` (``F + N`` rows;
    a block of rows ``j .. j + rb - 1`` needs columns ``>= j - F``) and ``W_t`` (``d + 1``
    rows); ``rb`` rows per block (the library's ``mcp_row_block()``)."""

    def __init__(self, dynamics, rb: int) -> None:
        pred = dynamics.delta_model
        f32 = torch.float32
        m, n, d, p = pred.m, pred.n, pred.input_dim, pred.p
        blocks = pred.row_blocks
        F = blocks.features
        linv = pred.linv.dense().to(torch.float64).expand(m, n, n)
        if F:
            B = torch.cat([pred.linv_phi.to(torch.float64), linv], dim=2)  # (m, N, F + N)
        else:
            B = linv
        alpha_aug = blocks.alpha.to(torch.float64)  # (m, 1, F + N)
        keep: list[Tensor] = []
        packed = {"w_aug": [], "fwd": [], "bwd": [], "w_t": []}

        def add(kind: str, A: Tensor, beg: list[int], end: list[int]) -> None:
            a, bg, en, off = pack_blocks(A, beg, end, rb)
            keep.extend([a, bg, en, off])
            packed[kind].append(
                _Packed(a.data_ptr(), bg.data_ptr(), en.data_ptr(), off.data_ptr(), len(beg))
            )

        nblk = lambda rows: -(-rows // rb)  # noqa: E731
        for b in range(m):
            add("w_aug", pred.W_aug[b], [0] * nblk(n), [d + 2] * nblk(n))
            fwd = torch.cat([B[b], alpha_aug[b]], dim=0)  # (N + 1, F + N)
            ends = [F + n if r + rb > n else min(F + r + rb, F + n) for r in range(0, n + 1, rb)]
            add("fwd", fwd, [0] * len(ends), ends)
            bwd = fwd.T  # (F + N, N + 1)
            begs = [max(0, j - F) for j in range(0, F + n, rb)]
            add("bwd", bwd, begs, [n + 1] * len(begs))
            add("w_t", pred.W_t[b], [0] * nblk(d + 1), [n] * nblk(d + 1))
        vec = lambda t: t.to(f32).reshape(-1).contiguous()  # noqa: E731

        def per_output(t: Tensor) -> Tensor:  # (m,), a shared value repeated
            return torch.broadcast_to(t.to(f32).reshape(-1), (m,)).contiguous()

        self.tensors = {
            "idx_a": pred.idx_a.to(torch.int32).contiguous(),
            "idx_c": pred.idx_c.to(torch.int32).contiguous(),
            "x_mean": vec(pred.x_mean),
            "x_scale": vec(pred.x_scale),
            "y_mean": per_output(pred.y_mean),
            "y_scale": per_output(pred.y_scale),
            "inv_l2": vec(pred.inv_l2),
            "outputscale": per_output(pred.outputscale),
            "sig_diag": vec(pred.mp_sigma_diag) if p else None,
            "sig2": vec(pred.mp_sigma2) if p else None,
            "noise_var": per_output(dynamics.noise_variance) if dynamics.sample_noise else None,
            "bound": None if dynamics.delta_bound is None else per_output(dynamics.delta_bound),
        }
        self._keep = keep
        self.struct = _Gp(
            m, n, d, p, F,
            *(_ptr(self.tensors[k]) for k in (
                "idx_a", "idx_c", "x_mean", "x_scale", "y_mean", "y_scale", "inv_l2",
                "outputscale", "sig_diag", "sig2", "noise_var", "bound",
            )),
            (_Packed * 2)(*packed["w_aug"]),
            (_Packed * 2)(*packed["fwd"]),
            (_Packed * 2)(*packed["bwd"]),
            (_Packed * 2)(*packed["w_t"]),
        )  # fmt: skip
        self.features = F


class NativeRollout(DirectRollout):
    """:class:`~mcpilco.agents.mc_pilco.direct_compile.DirectRollout`'s interface (shards,
    split and join, the dropout inputs) with each shard's forward and backward loops run by
    the C++ library. Each forward keeps its saved tensors in a float32 buffer of
    ``H x K x ceil(M / (S K 16)) x record`` floats (about 2.8 kB per particle and step at
    ``N = 100``), returned to a pool by its backward."""

    def __init__(
        self, policy, dynamics, cost, rows: int, delta_dim: int = 2, shards: int = 1
    ) -> None:
        reason = native_unsupported_reason(policy, dynamics, cost, torch.device("cpu"))
        if reason is not None:
            raise ValueError(f"the native rollout cannot run this loss: {reason}")
        if delta_dim != 2:
            raise ValueError(f"the native rollout needs delta_dim 2, got {delta_dim}")
        self._init_shards(policy, dynamics, cost, rows, shards)
        self.lib = load_library()
        self.gp = NativeGP(dynamics, int(self.lib.mcp_row_block()))
        nb = policy.num_basis
        self.pol = _Pol(nb, float(policy.u_half[0]))
        self.cost_params = _Cost(
            float(cost.length_scales[0]),
            float(cost.length_scales[1]),
            float(dynamics.dt),
            int(cost.modes[1] == MODE_WRAP),
        )
        per = self.shard_rows // self.candidates
        self.tiles_per = -(-per // int(self.lib.mcp_tile()))
        pred = dynamics.delta_model
        self.record = int(self.lib.mcp_record_floats(nb, pred.m, pred.n, self.gp.features, pred.p))
        self._per = per
        self._buffers: list[Tensor] = []

    def _shard_struct(self, horizon: int) -> _Shard:
        return _Shard(horizon, self.candidates, self._per, self.tiles_per)

    def _theta(self, theta: tuple[Tensor, ...]) -> list[Tensor]:
        c, log_l, w = (t.detach().to(torch.float32).contiguous() for t in theta)
        return [c, log_l, w]

    def forward_shard(self, x, noise, nu, bits, keep, theta):
        """One shard's forward loop: costs ``(H, KM/S)`` and the state its backward needs."""
        horizon = noise.shape[0]
        size = horizon * self.candidates * self.tiles_per * self.record
        try:
            rec = self._buffers.pop()
        except IndexError:
            rec = torch.empty(size, dtype=torch.float32)
        if rec.numel() != size:
            rec = torch.empty(size, dtype=torch.float32)
        costs = torch.empty(horizon, self.shard_rows, dtype=torch.float32)
        th = self._theta(theta)
        x, noise, nu = (t.to(torch.float32).contiguous() for t in (x, noise, nu))
        byte_ptrs = (ctypes.c_void_p * horizon)(*(b.data_ptr() for b in bits))
        status = self.lib.mcp_forward(
            ctypes.byref(self.gp.struct), ctypes.byref(self.pol), ctypes.byref(self.cost_params),
            ctypes.byref(self._shard_struct(horizon)),
            ctypes.c_void_p(x.data_ptr()), ctypes.c_void_p(noise.data_ptr()),
            ctypes.c_void_p(nu.data_ptr()), byte_ptrs,
            ctypes.c_float(float(keep[0])), ctypes.c_float(float(keep[1])),
            *(ctypes.c_void_p(t.data_ptr()) for t in th),
            ctypes.c_void_p(costs.data_ptr()), ctypes.c_void_p(rec.data_ptr()),
        )  # fmt: skip
        if status != 0:
            raise RuntimeError(f"native rollout forward failed (status {status})")
        return list(costs), (rec, th, horizon)

    def backward_shard(self, state, g_costs, grads):
        """One shard's backward loop: ``grads`` (the policy-parameter gradients) plus this
        shard's ``dJ/dtheta`` for ``g = dJ/dcosts`` (H, KM/S)."""
        rec, th, horizon = state
        g_costs = g_costs.to(torch.float32).contiguous()
        out = [g.to(torch.float32).contiguous().clone() for g in grads]
        status = self.lib.mcp_backward(
            ctypes.byref(self.gp.struct), ctypes.byref(self.pol), ctypes.byref(self.cost_params),
            ctypes.byref(self._shard_struct(horizon)), ctypes.c_void_p(rec.data_ptr()),
            *(ctypes.c_void_p(t.data_ptr()) for t in th),
            ctypes.c_void_p(g_costs.data_ptr()),
            *(ctypes.c_void_p(g.data_ptr()) for g in out),
        )  # fmt: skip
        if status != 0:
            raise RuntimeError(f"native rollout backward failed (status {status})")
        self._buffers.append(rec)
        return [o.to(g.dtype) for o, g in zip(out, grads, strict=True)]


__all__ = [
    "NativeRollout",
    "build_error",
    "cpp_compiler",
    "cpp_compiler_names",
    "load_library",
    "native_unsupported_reason",
    "pack_blocks",
]
