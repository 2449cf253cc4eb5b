"""The library of candidate physical effects: feature blocks with a physical sign constraint.

Each effect adds a torque that is *linear in its parameters* ``w`` on the joints it acts on:

.. math::

    \\tau_i \\mathrel{+}= \\phi_{e,i}(q, \\dot q, \\ddot q)^\\top w_{e,i},

so a GP can score it by adding a linear kernel ``lambda phi phi'^T`` on its block (see
:mod:`mcpilco.models.gp.linear_gp`). Shape parameters that enter non-linearly (the
cogging order, the Stribeck velocity, the dead-zone width, the delay) are found by a *scan*:
one variant per value, marginalised with a uniform prior over the scan (``logsumexp - log G``).
Every one of them is continuous (smoothing ``eps``, Stribeck velocity ``v_s``, dead-zone
width ``c``, cogging order ``n``, delay ``d`` in fractions of a sample;
:attr:`Effect.shape_grid`): it is then refined around the best scan value by a bounded
maximisation of the profile log-evidence, and reported with its likelihood-ratio interval
(:func:`~.search.refine_shape`, :mod:`.profile`); the cogging phase gets its interval from
the same profile.

Effects of one physical *family* on one joint (:attr:`Effect.family`: Coulomb and Stribeck
are both dry friction) describe the same torque in two forms; a model holds at most one of
them, the other being its alternative (:func:`~.search.auto_improve`).

============  =================  ==========================================  ================
key           class              block ``phi`` (row of joint ``j``)          sign constraint
============  =================  ==========================================  ================
viscous       ViscousFriction    ``qd_j``                                     ``F_v >= 0``
coulomb       CoulombFriction    ``tanh(qd_j / eps)`` (scan ``eps``)          ``F_c >= 0``
stribeck      StribeckFriction   ``[tanh(qd_j/eps), tanh(qd_j/eps)            ``F_c, F_s - F_c
                                 exp(-(qd_j/v_s)^2)]`` (scan ``v_s, eps``)    >= 0``
offset        TorqueOffset       ``1`` (asymmetric friction / sensor bias)    none
spring        Spring             ``[q_j - q_ref, 1]``: ``k (q_j - q_0)``      ``k >= 0``
cogging       Cogging            ``[sin(n q_j), cos(n q_j)]`` (scan ``n``)    none (amplitude)
                                 ``= A sin(n q_j + phi)``
payload       Payload            last link's columns of the joint-torque      ``m >= 0``
                                 regressor (pinocchio), on every joint
armature      Armature           ``qdd_j``                                    ``I_a >= 0``
deadzone      DeadZone           ``tanh(tau_hat_j / (c rms(tau_hat_j)))``     ``delta >= 0``
                                 (backlash: the load is lost while the
                                 transmitted torque crosses zero; scan ``c``)
delay         Delay              inputs read ``d = k dt`` earlier (scan       ``d >= 0``
                                 ``k = 1..K``, then continuous ``k``):
                                 measured output lags states
============  =================  ==========================================  ================

``tau_hat`` is the torque predicted by the start model (nominal physics or the learned
model of version 0). A fitted parameter has the *wrong sign* when its posterior mean lies
more than 1.96 posterior standard deviations on the unphysical side; such candidates are
shown but never recommended.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

__all__ = [
    "EFFECTS",
    "Armature",
    "Cogging",
    "CoulombFriction",
    "DeadZone",
    "Delay",
    "Effect",
    "FeatureContext",
    "Param",
    "ParamEstimate",
    "Payload",
    "Spring",
    "StribeckFriction",
    "TorqueOffset",
    "ViscousFriction",
    "default_library",
    "effect_from_spec",
    "parse_effect",
]


@dataclass(frozen=True)
class Param:
    """A parameter of an effect: name, unit template, sign constraint.

    ``unit`` may use ``{F}`` (the output unit: N m, N or A) and ``{x}`` (rad or m).
    ``sign = +1``: physically >= 0; ``0``: any sign.
    """

    name: str
    unit: str
    sign: int = 0


@dataclass(frozen=True)
class ParamEstimate:
    """Estimate ``value +- ci95`` of one parameter, with its unit.

    A weight's estimate is its posterior mean and 1.96 posterior standard deviations. A
    shape value fitted by profile log-evidence (:mod:`.profile`) carries its 95%
    likelihood-ratio ``interval`` ``(lo, hi)`` (not symmetric; ``ci95`` is then the larger
    distance from ``value`` to an end), ``limited`` when an end is the search limit rather
    than a crossing (the data do not pin that side down).
    """

    name: str
    value: float
    ci95: float
    unit: str
    wrong_sign: bool = False
    interval: tuple[float, float] | None = None
    limited: bool = False

    def text(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        if self.interval is None:
            return f"{self.name} = {_fmt(self.value)} ± {_fmt(self.ci95)}{unit}"
        lo, hi = self.interval
        text = f"{self.name} = {_fmt(self.value)}{unit} (95% LR interval {_fmt(lo)} to {_fmt(hi)})"
        return text + (
            " (not pinned down: the interval reaches the search limit)" if self.limited else ""
        )

    @classmethod
    def from_interval(
        cls, name: str, value: float, lo: float, hi: float, unit: str, limited: bool = False
    ) -> ParamEstimate:
        """An estimate with its likelihood-ratio interval ``(lo, hi)``."""
        ci = max(value - lo, hi - value, 0.0)
        return cls(name, float(value), float(ci), unit, False, (float(lo), float(hi)), limited)


def _fmt(x: float) -> str:
    return f"{x:.3g}"


@dataclass
class FeatureContext:
    """What a feature block may read, per sample: ``q, qd, qdd (N, n)``, the start model's
    torque ``base (N, n)`` (read it through :meth:`start_torque`: ``None`` until first used
    when ``base_fn`` computes it, as a learned start's prediction is costly and only a
    dead-zone reads it), ``joint_types``, the output group (``tau``/``i``), and a callable
    returning the last link's regressor columns ``(N, n, 10)`` (or ``None``)."""

    q: FloatArray
    qd: FloatArray
    qdd: FloatArray
    base: FloatArray | None
    joint_types: str
    output: str = "tau"
    last_link_regressor: Callable[[], FloatArray | None] | None = None
    _payload: FloatArray | None = dataclasses.field(default=None, repr=False)
    base_fn: Callable[[], FloatArray] | None = dataclasses.field(default=None, repr=False)

    def start_torque(self) -> FloatArray:
        """``tau_hat (N, n)``, the start model's torque (computed once, on first use)."""
        if self.base is None:
            if self.base_fn is None:
                raise ValueError("this feature context has no start-model torque")
            self.base = self.base_fn()
        return self.base

    def payload_columns(self) -> FloatArray | None:
        if self._payload is None and self.last_link_regressor is not None:
            self._payload = self.last_link_regressor()
        return self._payload

    def unit(self, template: str, joint: int | None) -> str:
        """Fill ``{F}``/``{x}`` for joint ``joint`` (1-based; ``None``: revolute units)."""
        prismatic = joint is not None and self.joint_types[joint - 1] == "P"
        force = "A" if self.output == "i" else ("N" if prismatic else "N·m")
        return template.format(F=force, x="m" if prismatic else "rad")


@dataclass(frozen=True)
class Effect:
    """Base class. ``joint`` is 1-based; ``None`` only for effects acting on every joint."""

    joint: int | None = None
    profile: tuple[ParamEstimate, ...] = dataclasses.field(
        default=(), compare=False, repr=False, kw_only=True
    )  # shape values with their likelihood-ratio intervals (set by the refinement)

    key: ClassVar[str] = ""
    title: ClassVar[str] = ""
    params: ClassVar[tuple[Param, ...]] = ()
    needs_base: ClassVar[bool] = False
    is_shift: ClassVar[bool] = False
    all_joints: ClassVar[bool] = False
    family: ClassVar[str] = ""  # physical family shared by alternative forms ("": the key)
    shape_grid: ClassVar[dict[str, tuple[float, ...]]] = {}  # continuous shape fields: scan
    shape_bounds: ClassVar[dict[str, tuple[float, float]]] = {}  # their outer limits
    shape_params: ClassVar[dict[str, Param]] = {}  # how a shape field is reported

    def __post_init__(self) -> None:
        if self.all_joints:
            if self.joint is not None:
                raise ValueError(f"{self.key} acts on every joint; do not give a joint")
        elif not isinstance(self.joint, int) or isinstance(self.joint, bool) or self.joint < 1:
            raise ValueError(
                f"{self.key}: joint must be a joint number 1..n (1-based), got {self.joint!r}"
            )

    # -- identity
    @property
    def label(self) -> str:
        """``key:joint`` (the CLI spelling), e.g. ``coulomb:2``; ``payload`` for all joints."""
        return self.key if self.joint is None else f"{self.key}:{self.joint}"

    @property
    def variant_label(self) -> str:
        """The label plus the scanned shape value, e.g. ``cogging:2 (n=8)``."""
        shape = self.shape_text()
        return f"{self.label} ({shape})" if shape else self.label

    def shape_text(self) -> str:
        return ""

    def same_slot(self, other: Effect) -> bool:
        """Same effect type on the same joint (the model holds at most one of each)."""
        return type(self) is type(other) and self.joint == other.joint

    def same_family(self, other: Effect) -> bool:
        """Same physical family (:attr:`family`, else the key) on the same joint: two forms
        of one torque, of which a model holds one."""
        return (self.family or self.key) == (other.family or other.key) and (
            self.joint == other.joint
        )

    def shape_bracket(self, name: str) -> tuple[float, float]:
        """Interval in which the continuous shape field ``name`` is refined: between the scan
        values next to its current value (beyond the scan's ends: one scan step further,
        within :attr:`shape_bounds`)."""
        grid = sorted(self.shape_grid[name])
        lo_b, hi_b = self.shape_bounds[name]
        x = float(getattr(self, name))
        below = [g for g in grid if g < x * (1 - 1e-9)]
        above = [g for g in grid if g > x * (1 + 1e-9)]
        step = grid[1] / grid[0] if len(grid) > 1 else 2.0
        lo = below[-1] if below else x / step
        hi = above[0] if above else x * step
        return max(lo, lo_b), min(hi, hi_b)

    def shape_estimate(
        self, name: str, value: float, lo: float, hi: float, ctx: FeatureContext, limited: bool
    ) -> ParamEstimate:
        """The reported estimate of shape field ``name`` at ``value`` with its interval
        ``(lo, hi)`` (:attr:`shape_params` gives its symbol and unit)."""
        p = self.shape_params.get(name, Param(name, ""))
        return ParamEstimate.from_interval(
            p.name, value, lo, hi, ctx.unit(p.unit, self.joint) if p.unit else "", limited
        )

    def with_profile(
        self, estimates: list[ParamEstimate], shape: bool = True
    ) -> list[ParamEstimate]:
        """``estimates`` with the :attr:`profile` entries in place of those of the same name
        (a profile interval replaces an estimate conditional on the shape values), and with
        ``shape`` the other profile entries (the shape values themselves) appended."""
        prof = {p.name: p for p in self.profile}
        out = [prof.pop(e.name, e) for e in estimates]
        return out + list(prof.values()) if shape else out

    def spec(self) -> dict[str, Any]:
        """JSON-serialisable description (see :func:`effect_from_spec`)."""
        return {"key": self.key, **dataclasses.asdict(self)}

    # -- structure
    def outputs(self, n_joints: int) -> list[int]:
        """0-based output joints the effect acts on."""
        if self.joint is None:
            return list(range(n_joints))
        if self.joint > n_joints:
            raise ValueError(f"{self.label}: joint {self.joint} but the model has {n_joints}")
        return [self.joint - 1]

    def is_complete(self) -> bool:
        """All scanned shape values are set."""
        return True

    def variants(self, **scan: Any) -> list[Effect]:
        """The fully specified effects of the scan (``[self]`` when complete)."""
        return [self]

    def calibrate(self, ctx: FeatureContext) -> Effect:
        """Store data-dependent constants (reference position, torque scale); idempotent."""
        return self

    def columns(self, ctx: FeatureContext, output: int) -> FloatArray | None:
        """``(N, p)`` block of output joint ``output`` (0-based); ``None``: no block."""
        raise NotImplementedError

    def in_gip_span(self, joint_types: str) -> bool:
        """Whether every torque this effect can add lies in the function space of the GIP
        kernel of ``joint_types`` (thesis eq. 3.8/3.11): sums of ``[1, qdd, qd_i qd_j]``
        times polynomials of degree <= 2 in ``(cos q_b, sin q_b)`` of each revolute and in
        ``q_b`` of each prismatic joint. Such an effect cannot be *missing* from a GIP model
        fitted on data that hold it; its block only re-weights the GIP prior. Default: no."""
        return False

    def estimates(
        self, mean: FloatArray, cov: FloatArray, ctx: FeatureContext, output: int
    ) -> list[ParamEstimate]:
        """Physical parameters from the posterior ``N(mean, cov)`` of the block's weights."""
        sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        out = []
        for k, p in enumerate(self.params):
            wrong = p.sign > 0 and mean[k] < -1.96 * sd[k]
            out.append(
                ParamEstimate(
                    p.name,
                    float(mean[k]),
                    float(1.96 * sd[k]),
                    ctx.unit(p.unit, self.joint),
                    bool(wrong),
                )
            )
        return out


def _col(x: FloatArray) -> FloatArray:
    return np.asarray(x, dtype=np.float64)[:, None]


@dataclass(frozen=True)
class ViscousFriction(Effect):
    """Viscous friction ``F_v qd_j``."""

    key: ClassVar[str] = "viscous"
    title: ClassVar[str] = "viscous friction"
    params: ClassVar[tuple[Param, ...]] = (Param("F_v", "{F}·s/{x}", +1),)

    def columns(self, ctx: FeatureContext, output: int) -> FloatArray:
        return _col(ctx.qd[:, self.joint - 1])


EPS_SCAN: tuple[float, ...] = tuple(round(0.003 * 2 ** (k / 2), 5) for k in range(7))
"""Smoothing velocities ``eps`` of ``tanh(qd / eps)`` scanned [rad/s or m/s]: 0.003 to 0.024 in
steps of sqrt(2), fine enough that a true Coulomb between two values does not lose to Stribeck."""
EPS_BOUNDS = (0.001, 0.1)  # limits of a refined ``eps`` [rad/s or m/s]


@dataclass(frozen=True)
class CoulombFriction(Effect):
    """Coulomb friction ``F_c tanh(qd_j / eps)`` (``eps`` [rad/s or m/s] smooths the sign;
    scanned over :data:`EPS_SCAN` when not given)."""

    eps: float | None = None
    key: ClassVar[str] = "coulomb"
    title: ClassVar[str] = "Coulomb friction"
    family: ClassVar[str] = "dry friction"
    shape_grid: ClassVar[dict[str, tuple[float, ...]]] = {"eps": EPS_SCAN}
    shape_bounds: ClassVar[dict[str, tuple[float, float]]] = {"eps": EPS_BOUNDS}
    shape_params: ClassVar[dict[str, Param]] = {"eps": Param("eps", "{x}/s")}
    params: ClassVar[tuple[Param, ...]] = (Param("F_c", "{F}", +1),)

    def shape_text(self) -> str:
        return "" if self.eps is None else f"eps={self.eps:.3g}"

    def is_complete(self) -> bool:
        return self.eps is not None

    def variants(self, **scan: Any) -> list[Effect]:
        if self.eps is not None:
            return [self]
        return [dataclasses.replace(self, eps=e) for e in EPS_SCAN]

    def columns(self, ctx: FeatureContext, output: int) -> FloatArray:
        return _col(np.tanh(ctx.qd[:, self.joint - 1] / self.eps))


STRIBECK_SCAN: tuple[float, ...] = (0.02, 0.05, 0.1, 0.2)
"""Stribeck velocities ``v_s`` scanned [rad/s or m/s]."""
STRIBECK_BOUNDS = (0.005, 0.5)  # limits of a refined ``v_s`` [rad/s or m/s]


@dataclass(frozen=True)
class StribeckFriction(Effect):
    """Stribeck friction ``(F_c + (F_s - F_c) exp(-(qd/v_s)^2)) tanh(qd / eps)`` (stiction)."""

    velocity: float | None = None
    eps: float | None = None
    key: ClassVar[str] = "stribeck"
    title: ClassVar[str] = "Stribeck friction / stiction"
    family: ClassVar[str] = "dry friction"
    shape_grid: ClassVar[dict[str, tuple[float, ...]]] = {
        "velocity": STRIBECK_SCAN,
        "eps": EPS_SCAN,
    }
    shape_bounds: ClassVar[dict[str, tuple[float, float]]] = {
        "velocity": STRIBECK_BOUNDS,
        "eps": EPS_BOUNDS,
    }
    shape_params: ClassVar[dict[str, Param]] = {
        "velocity": Param("v_s", "{x}/s"),
        "eps": Param("eps", "{x}/s"),
    }
    params: ClassVar[tuple[Param, ...]] = (Param("F_c", "{F}", +1), Param("F_s-F_c", "{F}", +1))

    def shape_text(self) -> str:
        if self.velocity is None or self.eps is None:
            return ""
        return f"v_s={self.velocity:.3g}, eps={self.eps:.3g}"

    def is_complete(self) -> bool:
        return self.velocity is not None and self.eps is not None

    def variants(self, **scan: Any) -> list[Effect]:
        vs = STRIBECK_SCAN if self.velocity is None else (self.velocity,)
        es = EPS_SCAN if self.eps is None else (self.eps,)
        return [dataclasses.replace(self, velocity=v, eps=e) for v in vs for e in es]

    def columns(self, ctx: FeatureContext, output: int) -> FloatArray:
        qd = ctx.qd[:, self.joint - 1]
        s = np.tanh(qd / self.eps)
        return np.stack([s, s * np.exp(-((qd / self.velocity) ** 2))], axis=1)


@dataclass(frozen=True)
class TorqueOffset(Effect):
    """Constant offset ``tau_0`` (asymmetric friction, sensor or current bias)."""

    key: ClassVar[str] = "offset"
    title: ClassVar[str] = "asymmetric offset"
    params: ClassVar[tuple[Param, ...]] = (Param("tau_0", "{F}", 0),)

    def columns(self, ctx: FeatureContext, output: int) -> FloatArray:
        return np.ones((ctx.q.shape[0], 1))

    def in_gip_span(self, joint_types: str) -> bool:
        return True  # the constant 1


@dataclass(frozen=True)
class Spring(Effect):
    """Spring ``k (q_j - q_0)`` as ``k (q_j - q_ref) + c`` (``q_ref``: mid-range of the
    calibration data; ``q_0 = q_ref - c / k``)."""

    q_ref: float | None = None
    key: ClassVar[str] = "spring"
    title: ClassVar[str] = "spring"
    params: ClassVar[tuple[Param, ...]] = (Param("k", "{F}/{x}", +1), Param("c", "{F}", 0))

    def calibrate(self, ctx: FeatureContext) -> Effect:
        if self.q_ref is not None:
            return self
        q = ctx.q[:, self.joint - 1]
        return dataclasses.replace(self, q_ref=float(0.5 * (q.min() + q.max())))

    def columns(self, ctx: FeatureContext, output: int) -> FloatArray:
        q = ctx.q[:, self.joint - 1]
        return np.stack([q - self.q_ref, np.ones_like(q)], axis=1)

    def in_gip_span(self, joint_types: str) -> bool:
        return joint_types[self.joint - 1] == "P"  # q_b (prismatic); q_b itself is not in
        # the span of (cos q_b, sin q_b)


COGGING_SCAN: tuple[int, ...] = tuple(range(3, 25))
"""Cogging orders ``n`` scanned (cycles per joint revolution/metre); the best is then refined
as a continuous value (a gear ratio makes the joint-side order any number)."""
COGGING_BOUNDS = (1.0, 100.0)  # limits of a refined order ``n``


@dataclass(frozen=True)
class Cogging(Effect):
    """Cogging / position ripple ``a sin(n q_j) + b cos(n q_j) = A sin(n q_j + phi)``:
    amplitude ``A = |(a, b)|``, phase ``phi = atan2(b, a)`` at ``q_j = 0``, order ``n``
    (scanned over :data:`COGGING_SCAN`, then refined as a continuous value)."""

    order: float | None = None
    key: ClassVar[str] = "cogging"
    title: ClassVar[str] = "cogging / position ripple"
    shape_grid: ClassVar[dict[str, tuple[float, ...]]] = {"order": COGGING_SCAN}
    shape_bounds: ClassVar[dict[str, tuple[float, float]]] = {"order": COGGING_BOUNDS}
    shape_params: ClassVar[dict[str, Param]] = {"order": Param("n", "1/{x}")}
    params: ClassVar[tuple[Param, ...]] = (Param("A", "{F}", +1), Param("phi", "rad"))

    def shape_text(self) -> str:
        return "" if self.order is None else f"n={self.order:.4g}"

    def is_complete(self) -> bool:
        return self.order is not None

    def variants(self, **scan: Any) -> list[Effect]:
        if self.order is not None:
            return [self]
        return [dataclasses.replace(self, order=n) for n in COGGING_SCAN]

    def shape_bracket(self, name: str) -> tuple[float, float]:
        """``n +- 1`` (the scan's step), within :attr:`shape_bounds`."""
        lo_b, hi_b = self.shape_bounds[name]
        return max(self.order - 1.0, lo_b), min(self.order + 1.0, hi_b)

    def columns(self, ctx: FeatureContext, output: int) -> FloatArray:
        nq = self.order * ctx.q[:, self.joint - 1]
        return np.stack([np.sin(nq), np.cos(nq)], axis=1)

    def in_gip_span(self, joint_types: str) -> bool:
        # sin/cos(n q) of a revolute joint is a polynomial of degree n in (cos q, sin q)
        return (
            joint_types[self.joint - 1] == "R"
            and self.order is not None
            and float(self.order).is_integer()
            and self.order <= 2
        )

    def estimates(
        self, mean: FloatArray, cov: FloatArray, ctx: FeatureContext, output: int
    ) -> list[ParamEstimate]:
        """``A`` and ``phi`` at this order (delta method); the refinement's profile gives
        ``phi`` its interval over the order's uncertainty too (:meth:`with_profile`)."""
        amp = float(np.hypot(mean[0], mean[1]))
        g = mean[:2] / amp if amp > 0 else np.array([1.0, 0.0])
        sd = math.sqrt(max(float(g @ cov[:2, :2] @ g), 0.0))  # delta method
        h = np.array([-g[1], g[0]]) / amp if amp > 0 else np.zeros(2)  # d phi / d (a, b)
        sd_phi = math.sqrt(max(float(h @ cov[:2, :2] @ h), 0.0)) if amp > 0 else math.pi
        return [
            ParamEstimate("A", amp, 1.96 * sd, ctx.unit("{F}", self.joint)),
            ParamEstimate("phi", float(math.atan2(mean[1], mean[0])), 1.96 * sd_phi, "rad"),
        ]


@dataclass(frozen=True)
class Armature(Effect):
    """Extra reflected inertia ``I_a qdd_j`` (rotor, gearbox)."""

    key: ClassVar[str] = "armature"
    title: ClassVar[str] = "armature inertia"
    params: ClassVar[tuple[Param, ...]] = (Param("I_a", "{F}·s²/{x}", +1),)

    def columns(self, ctx: FeatureContext, output: int) -> FloatArray:
        return _col(ctx.qdd[:, self.joint - 1])

    def in_gip_span(self, joint_types: str) -> bool:
        return True  # 1 * qdd_j


PAYLOAD_PARAMS = ("m", "mc_x", "mc_y", "mc_z", "I_xx", "I_xy", "I_yy", "I_xz", "I_yz", "I_zz")
"""Order of the 10 inertial parameters of a body in pinocchio's regressor."""


@dataclass(frozen=True)
class Payload(Effect):
    """A payload on the last link: change of its 10 inertial parameters (pinocchio's order
    :data:`PAYLOAD_PARAMS`, inertia about the joint frame), acting on every joint's torque.
    One weight vector per output joint (independent GPs); the reported mass is the
    estimate on the joint whose evidence gains most."""

    key: ClassVar[str] = "payload"
    title: ClassVar[str] = "payload on the last link"
    all_joints: ClassVar[bool] = True
    params: ClassVar[tuple[Param, ...]] = (Param("m", "kg", +1),)

    def columns(self, ctx: FeatureContext, output: int) -> FloatArray | None:
        cols = ctx.payload_columns()
        return None if cols is None else cols[:, output, :]

    def in_gip_span(self, joint_types: str) -> bool:
        return True  # rigid-body torques: the GIP kernel is built to span them (thesis 3.3)

    def estimates(
        self, mean: FloatArray, cov: FloatArray, ctx: FeatureContext, output: int
    ) -> list[ParamEstimate]:
        sd = math.sqrt(max(float(cov[0, 0]), 0.0))
        return [ParamEstimate("m", float(mean[0]), 1.96 * sd, "kg", bool(mean[0] < -1.96 * sd))]


DEADZONE_SCAN: tuple[float, ...] = (0.01, 0.03, 0.1)
"""Dead-zone widths scanned, as fractions ``c`` of the rms start-model torque."""


@dataclass(frozen=True)
class DeadZone(Effect):
    """Backlash / dead-zone in the transmission: ``delta tanh(tau_hat_j / (c s_j))``, i.e. an
    extra ``delta`` of drive torque whose sign follows the transmitted torque (the gear teeth
    change flank when it crosses zero); ``s_j`` = rms of the start model's torque."""

    width: float | None = None
    torque_scale: float | None = None
    key: ClassVar[str] = "deadzone"
    title: ClassVar[str] = "backlash / dead-zone"
    needs_base: ClassVar[bool] = True
    shape_grid: ClassVar[dict[str, tuple[float, ...]]] = {"width": DEADZONE_SCAN}
    shape_bounds: ClassVar[dict[str, tuple[float, float]]] = {"width": (0.003, 0.3)}
    shape_params: ClassVar[dict[str, Param]] = {"width": Param("c", "")}  # of rms tau_hat
    params: ClassVar[tuple[Param, ...]] = (Param("delta", "{F}", +1),)

    def shape_text(self) -> str:
        return "" if self.width is None else f"c={self.width:.3g}"

    def is_complete(self) -> bool:
        return self.width is not None

    def variants(self, **scan: Any) -> list[Effect]:
        if self.width is not None:
            return [self]
        return [dataclasses.replace(self, width=c) for c in DEADZONE_SCAN]

    def calibrate(self, ctx: FeatureContext) -> Effect:
        if self.torque_scale is not None:
            return self
        tau = ctx.start_torque()[:, self.joint - 1]
        return dataclasses.replace(self, torque_scale=float(np.sqrt(np.mean(tau**2))) or 1.0)

    def columns(self, ctx: FeatureContext, output: int) -> FloatArray:
        tau = ctx.start_torque()[:, self.joint - 1]
        return _col(np.tanh(tau / (self.width * self.torque_scale)))


@dataclass(frozen=True)
class Delay(Effect):
    """Measurement/input delay: the output lags the states, ``y_j(t) = tau_j(x(t - d))``,
    ``d = samples * dt``; found by a scan over ``samples = 1..max_delay_samples`` of the
    training files, then refined as a continuous number of samples (states between two
    samples linearly interpolated). The measured targets stay, each joint's states are read
    ``d`` earlier: every variant is scored on the same samples."""

    samples: float | None = None
    sample_time: float | None = None
    key: ClassVar[str] = "delay"
    title: ClassVar[str] = "input/measurement delay"
    is_shift: ClassVar[bool] = True
    shape_grid: ClassVar[dict[str, tuple[float, ...]]] = {"samples": (1.0,)}  # scan: variants()
    shape_bounds: ClassVar[dict[str, tuple[float, float]]] = {"samples": (0.05, 1000.0)}
    params: ClassVar[tuple[Param, ...]] = (Param("d", "s", +1),)

    def shape_text(self) -> str:
        return "" if self.samples is None else f"{self.samples:.3g} samples"

    def is_complete(self) -> bool:
        return self.samples is not None

    def variants(self, max_delay_samples: int = 10, **scan: Any) -> list[Effect]:
        if self.samples is not None:
            return [self]
        return [dataclasses.replace(self, samples=k) for k in range(1, max_delay_samples + 1)]

    def shape_bracket(self, name: str) -> tuple[float, float]:
        """``k +- 1`` samples (the scan's step), within :attr:`shape_bounds` (the model
        caps it at its ``max_delay_samples``)."""
        lo_b, hi_b = self.shape_bounds[name]
        return max(self.samples - 1.0, lo_b), min(self.samples + 1.0, hi_b)

    @property
    def delay(self) -> float:
        """``d`` [s] (needs ``sample_time``, set when the model is fitted)."""
        if self.samples is None or self.sample_time is None:
            raise ValueError("the delay is not set; fit the model first")
        return self.samples * self.sample_time

    def columns(self, ctx: FeatureContext, output: int) -> FloatArray | None:
        return None

    def shape_estimate(
        self, name: str, value: float, lo: float, hi: float, ctx: FeatureContext, limited: bool
    ) -> ParamEstimate:
        """The delay ``d`` [s] with its interval (``samples`` times ``sample_time``)."""
        dt = self.sample_time or float("nan")
        return ParamEstimate.from_interval("d", value * dt, lo * dt, hi * dt, "s", limited)

    def estimates(
        self, mean: FloatArray, cov: FloatArray, ctx: FeatureContext, output: int
    ) -> list[ParamEstimate]:
        """``d`` with half a sample as its resolution (a refined delay's profile interval
        replaces it, :meth:`with_profile`)."""
        dt = self.sample_time or float("nan")
        return [ParamEstimate("d", (self.samples or 0) * dt, 0.5 * dt, "s")]


EFFECTS: dict[str, type[Effect]] = {
    cls.key: cls
    for cls in (
        ViscousFriction,
        CoulombFriction,
        StribeckFriction,
        TorqueOffset,
        Spring,
        Cogging,
        Payload,
        Armature,
        DeadZone,
        Delay,
    )
}
"""Every candidate effect by key (the CLI names)."""

_SHAPE_FIELD = {
    "coulomb": "eps",
    "stribeck": "velocity",
    "cogging": "order",
    "deadzone": "width",
    "delay": "samples",
}


def parse_effect(text: str) -> Effect:
    """``"coulomb:2"`` -> ``CoulombFriction(joint=2)``; ``"payload"``; an optional third field
    fixes the scanned shape value: ``"cogging:2:8"`` (order 8), ``"delay:1:3"`` (3 samples).

    Raises:
        ValueError: unknown key (the known ones are listed) or a malformed joint.
    """
    parts = text.strip().split(":")
    key = parts[0].lower()
    if key not in EFFECTS:
        raise ValueError(f"unknown effect {key!r}; known effects: {', '.join(EFFECTS)}")
    cls = EFFECTS[key]
    kwargs: dict[str, Any] = {}
    if len(parts) > 1 and parts[1] != "":
        try:
            kwargs["joint"] = int(parts[1])
        except ValueError as err:
            raise ValueError(f"{text!r}: joint must be an integer, e.g. {key}:2") from err
    elif not cls.all_joints:
        raise ValueError(f"{text!r}: give the joint, e.g. {key}:2")
    if len(parts) > 2:
        if key not in _SHAPE_FIELD:
            raise ValueError(f"{text!r}: {key} has no shape value to fix")
        try:
            value = float(parts[2])
        except ValueError as err:
            raise ValueError(f"{text!r}: the shape value must be a number") from err
        kwargs[_SHAPE_FIELD[key]] = (
            int(value)
            if value.is_integer()
            and key
            in (
                "cogging",
                "delay",
            )
            else value
        )
    return cls(**kwargs)


def effect_from_spec(spec: dict[str, Any]) -> Effect:
    """Inverse of :meth:`Effect.spec`."""
    spec = dict(spec)
    key = spec.pop("key")
    if key not in EFFECTS:
        raise ValueError(f"unknown effect {key!r}; known effects: {', '.join(EFFECTS)}")
    profile = []
    for p in spec.pop("profile", ()):
        p = dict(p)
        if p.get("interval") is not None:
            p["interval"] = tuple(p["interval"])
        profile.append(ParamEstimate(**p))
    return EFFECTS[key](**spec, profile=tuple(profile))


def default_library(n_joints: int, with_payload: bool = True) -> list[Effect]:
    """Every effect on every joint (payload once, when a rigid-body model gives its columns)."""
    out: list[Effect] = []
    for key, cls in EFFECTS.items():
        if cls.all_joints:
            if with_payload and key == "payload":
                out.append(cls())
            continue
        out += [cls(joint=j) for j in range(1, n_joints + 1)]
    return out
