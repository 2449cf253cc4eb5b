r"""The particle rollout written by hand in C++: ``backend="native"`` of
:func:`~mcpilco.agents.mc_pilco.fast.use_fast_rollout`, for any task layout.

The same maths as :class:`~mcpilco.agents.mc_pilco.fast.chained.TorchRollout` (the parts'
step protocols, chained by hand through time), evaluated by one C++ function per shard for
the whole forward loop and one for the whole backward loop (``native_rollout.cpp``), instead
of ``2 H`` steps of tensor ops per shard. The task is data, not code: the state layout
(``n`` coordinates; plain ones and angles, which enter the policy and the GP as ``(sin,
cos)``; speed-integration pairs and unpaired coordinates), the ``A`` action bounds, the
``m`` GP outputs over ``d = F_x + A`` inputs and the saturating cost's terms (index, the
state it tracks if any, target, length scale, mode plain / wrap / abs) are arrays the C++
loop reads. What the loop buys:

* particles in tiles of 16 (the extension's ``tile()``): a tile's whole time step (policy,
  GP posterior, sampling, integration, cost) runs on data that stays in the core's caches;
  a group of tiles runs each time step together, output by output, so that one output's
  constant matrices serve the whole group while they are cached (``NativeModel.group()``:
  as many tiles as fit with them in half the L2 cache the C++ reads at run time, at most 8;
  ``set_group`` overrides it; a tile's arithmetic, hence its result, does not depend on it);
* denormal floats flushed to zero while the loops run (x86 MXCSR, the caller's setting
  restored): the kernel values at the exponential's floor make denormal products, which
  many CPUs handle by slow microcode assists;
* the products with the GP's constant matrices, ``[V; m] = [L^{-1} Phi, L^{-1}; alpha^T Phi,
  alpha^T] [psi; r]`` forward and ``dR = [L^{-1} Phi, L^{-1}]^T V (-2 g_v) + alpha_aug g_m``
  backward (glossary of :mod:`~mcpilco.models.gp.fused`; ``dV = -2 g_v V`` is never formed:
  the per-particle factor is applied to the product), per output, use one register-blocked
  kernel over the constant matrix packed once per GP fit, by blocks of 6 rows
  (``row_block()``; 6 x 16 accumulators: one 16-float vector per row with AVX-512, two
  8-float vectors without, the same sums lane by lane and so the same bits,
  ``vector_floats()``) with each block's own range of columns: the zeros
  of the triangular factor are skipped row block by row block (about ``N^2 / 2 + F N``
  multiply-adds per particle and output, each way). Each block's results are consumed in
  registers: ``r = exp(E)`` of the kernel's exponents (a row whose exponents are all below
  the exponential's floor gets ``exp(-87)`` without evaluating it), ``||V||^2`` of the
  variance, ``dpsi`` and ``dE = dr o r`` of the backward, without a second pass over the tile;
* a training point whose RBF kernel value is below ``exp(-69)`` for every particle of a
  tile is left out of that tile's products, forward (its column) and backward (its block of
  rows, when the whole block is such points): with the degree-1 MPK the products are the
  exact posterior's floor, so leaving out what adds nothing is the arithmetic left to save
  (:func:`kernel_rows` counts the rows taken);
* the backward loop requests the record of the step it runs next (written in the forward
  loop, long since evicted to memory) a few cache lines between the kernel's blocks, so
  that reading it overlaps the arithmetic;
* no per-op allocation, dispatch or Python between the time steps.

Build: a PyTorch C++ extension (:func:`torch.utils.cpp_extension.load`, with ninja) of
``native_rollout.cpp`` (the loops, no torch headers) and ``native_rollout_ext.cpp`` (the
pybind11 binding: ``torch::Tensor`` arguments, the GIL released while a shard runs, so the
shards run in parallel threads), compiled on first use with ``-O3 -march=native`` (or
for another instruction set of :data:`ISA_FLAGS`: :func:`native_isa`) into :func:`cache_dir`
and rebuilt by ninja only when a source changes. Float32 on the CPU, the
fused RBF (+ MPK of degree 1 or 2) posterior and :class:`~.cost.SaturatingCost` only
(:func:`native_unsupported_reason`); ``use_fast_rollout`` checks the result against the
eager rollout like every fast path.

The engine sees a loss only through :func:`native_model`: the task spec's sizes, index
arrays and the GP's constants, read from the parts' public attributes. A kernel specialised
for some specs (sizes of ``n``, ``m``, ``N``, ``F``; an instruction set) is chosen there or
in the C++ from those sizes; the parts and their step protocols do not change, and the
check against the eager rollout guards every variant alike.

Glossary: as in :mod:`~mcpilco.agents.mc_pilco.fast.base` (``K`` candidates, ``M``
particles, ``S`` shards, ``H`` horizon) and :mod:`~mcpilco.models.gp.fused` (``N`` training
points, ``F`` MPK features, ``m`` outputs, ``d`` GP inputs).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import platform
import shutil
import subprocess
import threading
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import torch
from torch import Tensor

from mcpilco.agents.mc_pilco.dynamics import integration_matrices
from mcpilco.agents.mc_pilco.fast.base import ShardedRollout, unsupported_reason

SOURCES = tuple(
    Path(__file__).with_name(name) for name in ("native_rollout_ext.cpp", "native_rollout.cpp")
)
"""The extension's C++ sources (the binding, then the loops)."""

HEADER = Path(__file__).with_name("native_rollout.h")  # included by both sources

BASE_FLAGS = ("-O3", "-fno-math-errno")
"""Compiler flags of every build (no ``-ffast-math``: NaN must propagate, the loss restarts on
a NaN cost); :data:`ISA_FLAGS` adds the instruction set."""

ISA_FLAGS = {"native": ("-march=native",), "avx2": ("-march=x86-64-v3",)}
"""The instruction sets the extension is built for, by name: ``native``, the CPU it is built
on (its AVX-512 where it has it; the default), and ``avx2``, x86-64-v3 (AVX2 and FMA, no
AVX-512: what every x86-64 CPU from about 2015 on runs). The products' kernel keeps 16-float
accumulators where the build has AVX-512 and 8-float ones where it has not, with the same
multiply-adds per lane in the same order (the same results); ``avx2`` is how a CPU without
AVX-512 is timed on one with it."""

ISA_ENV = "MCPILCO_NATIVE_ISA"  # the environment variable that names the default build's ISA

STAGE_NAMES = (
    "forward: policy and GP inputs",
    "forward: RBF exponents and exp (W_aug)",
    "forward: [V; mean] and variance ([B; alpha_aug])",
    "forward: sample, integrate, cost",
    "backward: cost, integration, sample",
    "backward: dR (B^T)",
    "backward: RBF inputs (W_t)",
    "backward: GP inputs and policy",
)
"""The stages of the loops that :func:`stage_seconds` clocks, in the C++ ``Stage`` order."""

_LIBS: dict[str, ModuleType] = {}  # the loaded extensions by ISA name
_LIB_ERRORS: dict[str, str] = {}  # why building one failed, by ISA name
_LIB_LOCK = threading.Lock()


def native_isa(isa: str | None = None) -> str:
    """The instruction set of :data:`ISA_FLAGS` to build for: ``isa``, else
    ``$MCPILCO_NATIVE_ISA``, else ``native``."""
    name = isa or os.environ.get(ISA_ENV) or "native"
    if name not in ISA_FLAGS:
        where = "isa" if isa else f"${ISA_ENV}"
        raise ValueError(f"{where} must be one of {', '.join(ISA_FLAGS)}, got {name!r}")
    return name


def cxx_flags(isa: str | None = None) -> tuple[str, ...]:
    """The compiler flags of the build for ``isa`` (:func:`native_isa`)."""
    return (*BASE_FLAGS[:1], *ISA_FLAGS[native_isa(isa)], *BASE_FLAGS[1:])


def cache_dir() -> Path:
    """Where the extensions are built: ``$MCPILCO_NATIVE_CACHE``, else PyTorch's extension
    folder (``$TORCH_EXTENSIONS_DIR``, else ``~/.cache/torch_extensions``,
    :func:`torch.utils.cpp_extension.get_default_build_root`); the extension is in its
    subfolder :func:`extension_name`."""
    env = os.environ.get("MCPILCO_NATIVE_CACHE")
    if env:
        return Path(env)
    from torch.utils.cpp_extension import get_default_build_root

    return Path(os.environ.get("TORCH_EXTENSIONS_DIR") or get_default_build_root())


def _cpu_key() -> str:
    """What ``-march=native`` compiles for: the CPU's model and feature flags (Linux), else
    the platform's processor name; part of the extension's name, so that a cache shared
    between machines never hands one an extension built for another CPU."""
    try:
        with open("/proc/cpuinfo") as f:
            lines = [ln for ln in f if ln.startswith(("model name", "flags"))]
        return "".join(sorted(set(lines)))
    except OSError:
        return platform.machine() + platform.processor()


def extension_name(cxx: str, isa: str | None = None) -> str:
    """The extension's module name for compiler ``cxx`` and instruction set ``isa``
    (:func:`native_isa`): a hash of the compiler, the flags, the CPU, the torch version and
    the sources' contents (one build folder each), so that two installed versions of the
    package sharing a cache never rebuild each other's."""
    sources = b"".join(path.read_bytes() for path in (*SOURCES, HEADER))
    key = repr((cxx, cxx_flags(isa), _cpu_key(), torch.__version__)).encode() + sources
    return f"mcpilco_native_rollout_{hashlib.sha256(key).hexdigest()[:16]}"


def build_error(isa: str | None = None) -> str | None:
    """Why building the extension for ``isa`` (:func:`native_isa`) failed in this process
    (None: it did not fail)."""
    return _LIB_ERRORS.get(native_isa(isa))


def cpp_compiler_names() -> list[str]:
    """The C++ compilers looked for, in order: ``$CXX`` alone if it is set, else ``g++`` and
    ``clang++`` (the compilers inductor's CPU backend uses too); the one found is the one
    :func:`torch.utils.cpp_extension.load` runs."""
    return [os.environ["CXX"]] if os.environ.get("CXX") else ["g++", "clang++"]


def cpp_compiler() -> str | None:
    """The first of :func:`cpp_compiler_names` found on ``PATH`` (None: none)."""
    return next((name for name in cpp_compiler_names() if shutil.which(name)), None)


def _ninja_dir() -> str | None:
    """The folder of the ``ninja`` binary of the ``ninja`` Python package (a dependency; it
    is on ``PATH`` only in an activated environment), None without the package."""
    try:
        import ninja
    except ImportError:
        return None
    return getattr(ninja, "BIN_DIR", None)


BUILD_LOCK_NAME = "mcpilco_build.lock"  # the flock every process builds under
TORCH_LOCK_NAME = "lock"  # the lock file torch.utils.cpp_extension leaves in a build folder


@contextlib.contextmanager
def build_lock(build: Path) -> Iterator[None]:
    """Hold an exclusive ``fcntl.flock`` on ``build/mcpilco_build.lock`` while the extension
    is built or loaded.

    PyTorch's own build lock is a file that exists while a process builds; a process killed
    during the build leaves it behind and every later build waits on it for ever. An flock is
    released by the kernel when its holder dies, so under it the only process that can hold
    PyTorch's lock is this one: a lock file found there was left by a killed build and is
    removed before the build starts."""
    fd = os.open(build / BUILD_LOCK_NAME, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        (build / TORCH_LOCK_NAME).unlink(missing_ok=True)
        yield
    finally:
        os.close(fd)  # releases the flock


def load_library(isa: str | None = None) -> ModuleType:
    """The compiled rollout extension for instruction set ``isa`` (:func:`native_isa`),
    built on first use (see the module docstring).

    Raises ``RuntimeError`` (with the compiler's message) if no C++ compiler is found, the
    build fails or the extension does not load (e.g. an unwritable cache folder); a failure
    other than a missing compiler is remembered for the process."""
    isa = native_isa(isa)
    with _LIB_LOCK:
        if isa in _LIBS:
            return _LIBS[isa]
        if isa in _LIB_ERRORS:
            raise RuntimeError(_LIB_ERRORS[isa])
        cxx = cpp_compiler()
        if cxx is None:
            # not remembered: a compiler installed (or CXX set) later in the process is used
            raise RuntimeError(f"no C++ compiler found ({' or '.join(cpp_compiler_names())})")
        from torch.utils import cpp_extension

        name = extension_name(cxx, isa)
        build = cache_dir() / name
        before = {key: os.environ.get(key) for key in ("CXX", "PATH")}
        try:
            build.mkdir(parents=True, exist_ok=True)
            os.environ["CXX"] = cxx  # the compiler cpp_extension runs
            if shutil.which("ninja") is None:  # the ninja package's binary, off PATH
                os.environ["PATH"] = os.pathsep.join(filter(None, (_ninja_dir(), before["PATH"])))
            with build_lock(build):
                lib = cpp_extension.load(
                    name,
                    [str(p) for p in SOURCES],
                    extra_cflags=list(cxx_flags(isa)),
                    build_directory=str(build),
                    verbose=False,
                )
        except (OSError, ImportError) as err:  # unwritable cache, unloadable module
            _LIB_ERRORS[isa] = f"{type(err).__name__}: {err}"
            raise RuntimeError(_LIB_ERRORS[isa]) from err
        except (RuntimeError, subprocess.SubprocessError) as err:  # the compiler's message
            said = [getattr(err, key, None) for key in ("stderr", "output")]
            said = [x.decode(errors="replace") if isinstance(x, bytes) else x for x in said]
            detail = " ".join(x.strip() for x in said if x)
            _LIB_ERRORS[isa] = f"{cxx}: {err} {detail}".strip()[:4000]
            raise RuntimeError(_LIB_ERRORS[isa]) from err
        finally:
            for key, value in before.items():
                if value is None:
                    os.environ.pop(key, None)
                else:
                    os.environ[key] = value
        _LIBS[isa] = lib
        return lib


def stage_seconds(reset: bool = False) -> dict[str, float]:
    """Seconds the loops spent in each of :data:`STAGE_NAMES` since the last reset (or the
    library's load), summed over the shards' threads; ``reset``: start the clocks again.
    Every loop keeps these clocks (two clock reads per output and tile step, well under one
    percent of a step)."""
    return dict(zip(STAGE_NAMES, load_library().stage_seconds(reset), strict=True))


def kernel_rows(reset: bool = False) -> tuple[int, int]:
    """``(taken, all)``: the rows of RBF kernel values (one per training point, GP output,
    tile of particles and time step) that the forward loops took into the products with the
    GP's constant matrices since the last reset (or the library's load), and all of them. A
    row is left out, forward and backward, where every particle of the tile has its kernel
    value at or below ``exp(-69)`` (``KERNEL_FLOOR``, 1e-30): it would add less than 1e-20
    to the posterior. ``reset``: count again from zero."""
    taken, total = load_library().kernel_rows(reset)
    return int(taken), int(total)


def native_unsupported_reason(
    policy: Any, dynamics: Any, cost: Any, device: torch.device
) -> str | None:
    """Why the native rollout cannot run this loss (None: it can): the chained rollout's
    conditions (:func:`~mcpilco.agents.mc_pilco.fast.base.unsupported_reason`: the
    package's policy, dynamics over the fused GP posterior and
    :class:`~mcpilco.agents.mc_pilco.cost.SaturatingCost`, on the CPU), float32 throughout,
    an RBF or RBF + MPK kernel of degree 1 or 2, and a working C++ toolchain.
    Any state layout, number of actions, GP outputs and training points."""
    reason = unsupported_reason(policy, dynamics, cost, device)
    if reason is not None:
        return reason
    pred = dynamics.delta_model
    if policy.weights.dtype != torch.float32 or pred.dtype != torch.float32:
        return "it runs in float32 only"
    if pred.p not in (0, 1, 2):
        return f"it takes RBF or RBF + MPK kernels of degree 1 or 2, not MPK degree {pred.p}"
    layout = dynamics.layout
    if policy.layout != layout or cost.state_dim != layout.n:
        return "the policy, dynamics and cost have different state layouts"
    if pred.m != layout.output_dim or pred.input_dim != layout.feature_dim + policy.action_dim:
        return (
            f"the GP has {pred.m} outputs over {pred.input_dim} inputs, the layout needs "
            f"{layout.output_dim} over {layout.feature_dim + policy.action_dim}"
        )
    try:
        load_library()
    except RuntimeError as err:
        return f"the native library is not available ({err})"
    return None


def oscillator_coefficients(layout: Any, dt: float) -> Tensor:
    """``(a_pp, a_pv, a_vp, a_vv, z_p, z_v)`` per known oscillator of ``layout`` (float64,
    ``(n_osc * 6,)``): its block of the integration's ``A`` and offset ``z``
    (:func:`~mcpilco.agents.mc_pilco.dynamics.speed_integration`)."""
    if not layout.oscillators:
        return torch.empty(0, dtype=torch.float64)
    A_t, _, z = integration_matrices(dt, layout, torch.float64, "cpu")
    A = A_t.T
    return torch.tensor(
        [[A[p, p], A[p, v], A[v, p], A[v, v], z[p], z[v]] for p, v, _, _ in layout.oscillators],
        dtype=torch.float64,
    ).reshape(-1)


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


def packed_gp(pred: Any, rb: int) -> list[list[Tensor]]:
    """The fused GP posterior's constant matrices packed for the C++ rollout
    (:func:`pack_blocks`; 4 tensors per output): per output ``b``, ``W_aug`` (``N`` rows,
    ``d + 2`` columns), the forward matrix ``[B; alpha_aug]`` with ``B = [L^{-1} Phi,
    L^{-1}]`` (``N + 1`` rows; a block of rows ``r .. r + rb - 1 < N`` needs columns
    ``< F + r + rb``), the backward matrix ``B^T`` (``F + N`` rows, ``N`` columns; a block of
    rows ``j .. j + rb - 1`` needs columns ``>= j - F``; ``alpha_aug`` goes to the loop
    unpacked, :func:`native_model`) and ``W_t`` (``d + 1`` rows)."""
    m, n, d = pred.m, pred.n, pred.input_dim
    F = pred.row_blocks.features
    linv = pred.linv.dense().to(torch.float64).expand(m, n, n)
    B = torch.cat([pred.linv_phi.to(torch.float64), linv], dim=2) if F else linv
    alpha_aug = pred.row_blocks.alpha.to(torch.float64)  # (m, 1, F + N)
    packed: list[list[Tensor]] = [[], [], [], []]
    nblk = lambda rows: -(-rows // rb)  # noqa: E731
    for b in range(m):
        packed[0] += pack_blocks(pred.W_aug[b], [0] * nblk(n), [d + 2] * nblk(n), rb)
        fwd = torch.cat([B[b], alpha_aug[b]], dim=0)  # (N + 1, F + N)
        ends = [F + n if r + rb > n else min(F + r + rb, F + n) for r in range(0, n + 1, rb)]
        packed[1] += pack_blocks(fwd, [0] * len(ends), ends, rb)
        begs = [max(0, j - F) for j in range(0, F + n, rb)]
        packed[2] += pack_blocks(fwd.T[:, :n], begs, [n] * len(begs), rb)
        packed[3] += pack_blocks(pred.W_t[b], [0] * nblk(d + 1), [n] * nblk(d + 1), rb)
    return packed


def native_model(lib: ModuleType, policy: Any, dynamics: Any, cost: Any) -> Any:
    """The extension's ``NativeModel`` of one loss: the task layout, the action bounds, the
    cost's terms and the GP posterior's constants (float32, int32 index arrays; the packed
    matrices of :func:`packed_gp` and ``alpha_aug = [alpha^T Phi, alpha^T]`` per output)."""
    pred, layout = dynamics.delta_model, dynamics.layout
    f32, i32 = torch.float32, torch.int32
    m, d = pred.m, pred.input_dim

    def ints(values) -> Tensor:
        return torch.tensor(list(values), dtype=i32)

    def floats(t) -> Tensor:
        return torch.as_tensor(t).detach().to(f32).reshape(-1).contiguous()

    def per_output(t) -> Tensor:  # (m,), a shared value repeated
        return torch.broadcast_to(floats(t), (m,)).contiguous()

    none = torch.empty(0, dtype=f32)
    p = pred.p
    ls = torch.tensor(cost.length_scales, dtype=torch.float64)
    index = [
        ints(layout.plain_idx),
        ints(layout.angle_idx),
        ints(layout.position_idx),
        ints(layout.velocity_idx),
        ints(layout.delta_idx),
        ints(cost.idx),
        ints(cost.modes),
        pred.idx_a.to(i32).contiguous(),
        pred.idx_c.to(i32).contiguous(),
        ints(cost.refs),
        ints(k for k, *_ in cost.barriers),
        ints(i for p, v, _, _ in layout.oscillators for i in (p, v)),
    ]
    values = [
        floats(policy.u_mid),
        floats(policy.u_half),
        floats(torch.tensor(cost.targets, dtype=torch.float64)),
        floats(ls),
        floats(ls * ls),
        floats(pred.x_mean),
        floats(pred.x_scale),
        per_output(pred.y_mean),
        per_output(pred.y_scale),
        floats(pred.inv_l2),
        per_output(pred.outputscale),
        floats(pred.mp_sigma_diag) if p else none,
        floats(pred.mp_sigma2) if p else none,
        per_output(dynamics.noise_variance) if dynamics.sample_noise else none,
        none if dynamics.delta_bound is None else per_output(dynamics.delta_bound),
        floats(pred.row_blocks.alpha),
        floats(torch.tensor([lo for _, lo, _, _ in cost.barriers], dtype=torch.float64)),
        floats(torch.tensor([hi for _, _, hi, _ in cost.barriers], dtype=torch.float64)),
        floats(torch.tensor([1.0 / w for *_, w in cost.barriers], dtype=torch.float64)),
        floats(oscillator_coefficients(layout, float(dynamics.dt))),
    ]
    sizes = [
        layout.n, policy.action_dim, m, d, layout.feature_dim, policy.num_basis, pred.n, p,
        pred.row_blocks.features,
    ]  # fmt: skip
    packed = packed_gp(pred, int(lib.row_block()))
    return lib.NativeModel(sizes, index, values, float(dynamics.dt), packed)


class NativeRollout(ShardedRollout):
    """A :class:`~mcpilco.agents.mc_pilco.fast.base.ShardedRollout` (shards, split and join,
    the dropout inputs) with each shard's forward and backward loops run by
    the C++ extension. Each forward keeps its saved tensors in a float32 buffer of
    ``H x K x ceil(M / (S K 16)) x record`` floats (about ``2 m N + F + n_b`` floats per
    particle and step: ``r`` and ``V`` of each output, ``psi``, the policy's activations),
    returned to a pool by its backward."""

    def __init__(
        self,
        policy,
        dynamics,
        cost,
        rows: int,
        delta_dim: int | None = None,
        shards: int = 1,
        isa: str | None = None,
    ) -> None:
        reason = native_unsupported_reason(policy, dynamics, cost, torch.device("cpu"))
        if reason is not None:
            raise ValueError(f"the native rollout cannot run this loss: {reason}")
        out = dynamics.layout.output_dim
        if delta_dim is not None and delta_dim != out:
            raise ValueError(f"the native rollout needs delta_dim {out}, got {delta_dim}")
        super().__init__(policy, dynamics, cost, rows, shards)
        self.isa = native_isa(isa)
        self.lib = load_library(self.isa)
        self.model = native_model(self.lib, policy, dynamics, cost)
        self._per = self.shard_rows // self.candidates
        self.tiles_per = -(-self._per // int(self.lib.tile()))
        self.record = int(self.model.record_floats())
        self._buffers: list[Tensor] = []

    def _theta(self, theta: tuple[Tensor, ...]) -> list[Tensor]:
        return [t.detach().to(torch.float32).contiguous() for t in theta]

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
        self.model.forward(
            self.candidates, self._per, x, noise, nu, [b.contiguous() for b in bits],
            float(keep[0]), float(keep[1]), *th, costs, rec,
        )  # fmt: skip
        return list(costs), (rec, th, horizon)

    def backward_shard(self, state, g_costs, grads):
        """One shard's backward loop: ``grads`` (the policy-parameter gradients) plus this
        shard's ``dJ/dtheta`` for ``g = dJ/dcosts`` (H, KM/S)."""
        rec, th, horizon = state
        g_costs = g_costs.to(torch.float32).contiguous()
        out = [g.to(torch.float32).contiguous().clone() for g in grads]
        self.model.backward(self.candidates, self._per, horizon, rec, *th, g_costs, *out)
        self._buffers.append(rec)
        return [o.to(g.dtype) for o, g in zip(out, grads, strict=True)]


__all__ = [
    "BASE_FLAGS",
    "ISA_FLAGS",
    "STAGE_NAMES",
    "NativeRollout",
    "build_error",
    "cache_dir",
    "cpp_compiler",
    "cpp_compiler_names",
    "cxx_flags",
    "extension_name",
    "kernel_rows",
    "load_library",
    "native_isa",
    "native_model",
    "native_unsupported_reason",
    "pack_blocks",
    "packed_gp",
    "stage_seconds",
]
