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

Rigid-body effects (:attr:`Effect.shared`: a link's inertial parameters, a payload) move
several joints with *one* weight vector: ``tau_j += Y_{b,j} w`` for every joint ``j`` the
body moves, ``Y_b`` the body's columns of the joint-torque regressor of the robot file
(:meth:`FeatureContext.body_columns`). They are scored and fitted on the stacked joints
(:mod:`.shared`), so their estimates describe one body.

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
payload       Payload            point mass at the flange: the last body's   ``m >= 0``
                                 regressor columns times ``G`` (``[m, m p]``;
                                 one weight vector for every joint)
inertia       LinkInertia        link ``b``'s regressor columns on joints    pseudo-inertia
                                 ``1..b``, identifiable part (one weight      positive
                                 vector for every joint)                      definite
armature      Armature           ``qdd_j``                                    ``I_a >= 0``
deadzone      DeadZone           ``tanh(tau_hat_j / (c rms(tau_hat_j)))``     ``delta >= 0``
                                 (backlash: the load is lost while the
                                 transmitted torque crosses zero; scan ``c``)
delay         Delay              inputs read ``d = k dt`` earlier (scan       ``d >= 0``
                                 ``k = 1..K``, then continuous ``k``):
                                 measured output lags states
============  =================  ==========================================  ================

Dry friction at rest (Coulomb, Stribeck) is *set-valued*: a joint that sticks is held by any
torque in ``[-F_s, F_s]`` (``F_s = F_c`` for Coulomb), whatever balances the others, so
no function of the states predicts it. The block is ``0`` (the centre of the set) on the rows
where the joint is at rest as far as the data can tell (:func:`.analysis.at_rest`: the
sign of its velocity is not known), and the model's prediction
there is the measurement projected onto ``[m - F_s, m + F_s]`` (``m`` the rest of the
prediction): its error is the distance of the residual to the interval
(:meth:`~.model.DiagnosisModel.set_valued`), in fitting, in held-out errors and in the noise
floor alike.

``tau_hat`` is the torque predicted by the start model (nominal physics or the learned
model of version 0). A fitted parameter has the *wrong sign* when its posterior mean lies
more than ``Z95`` (1.96) posterior standard deviations on the unphysical side; such
candidates are shown but never recommended.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from mcpilco.models.stats import Z95

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
    "INERTIAL_PARAMS",
    "LinkInertia",
    "Param",
    "ParamEstimate",
    "Payload",
    "PositionLevel",
    "RigidBody",
    "Spring",
    "StribeckFriction",
    "TorqueOffset",
    "TorqueScale",
    "ViscousFriction",
    "default_library",
    "effect_from_spec",
    "flange_map",
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

    A weight's estimate is its posterior mean and ``Z95`` posterior standard deviations. A
    shape value fitted by profile log-evidence (:mod:`.profile`) carries its 95%
    likelihood-ratio ``interval`` ``(lo, hi)`` (not symmetric; ``ci95`` is then the larger
    distance from ``value`` to an end), ``limited`` when an end is the search limit rather
    than a crossing (the data do not pin that side down). ``unidentified``: why the data
    cannot pin it down (:mod:`.identifiability`), empty when they can.
    """

    name: str
    value: float
    ci95: float
    unit: str
    wrong_sign: bool = False
    unidentified: str = ""
    interval: tuple[float, float] | None = None
    limited: bool = False

    def text(self) -> str:
        if self.unidentified:
            return f"{self.name}: not identifiable from these data ({self.unidentified})"
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
        return cls(
            name,
            float(value),
            float(ci),
            unit,
            False,
            interval=(float(lo), float(hi)),
            limited=limited,
        )


def _fmt(x: float) -> str:
    return f"{x:.3g}"


@dataclass(frozen=True)
class RigidBody:
    """What the inertial candidates read of the nominal robot file.

    Attributes:
        parameters: ``(n_b, 10)`` inertial parameters of every body (pinocchio's order
            :data:`INERTIAL_PARAMS`, about the body's joint frame origin, in that frame).
        flange_pos, flange_rot: pose of the flange frame in the last body's frame:
            position ``(3,)`` [m] and rotation ``(3, 3)``.
    """

    parameters: FloatArray
    flange_pos: FloatArray
    flange_rot: FloatArray


@dataclass
class FeatureContext:
    """What a feature block may read, per sample: ``q, qd, qdd (N, n)``, the start model's
    torque ``base (N, n)`` (read it through :meth:`start_torque`: ``None`` until first used
    when ``base_fn`` computes it, as a learned start's prediction is costly and only a
    dead-zone reads it), ``joint_types``, the output group (``tau``/``i``), and, when a
    robot file is known, a callable returning the joint-torque regressor of every body
    ``(N, n, 10 n_b)`` (``regressor``; evaluated once, on first use) and the nominal body
    data (``rigid``)."""

    q: FloatArray
    qd: FloatArray
    qdd: FloatArray
    base: FloatArray | None
    joint_types: str
    output: str = "tau"
    regressor: Callable[[], FloatArray] | None = None
    rigid: RigidBody | None = None
    _regressor: FloatArray | None = dataclasses.field(default=None, repr=False)
    base_fn: Callable[[], FloatArray] | None = dataclasses.field(default=None, repr=False)
    at_rest: NDArray[np.bool_] | None = None  # (N, n) :func:`.analysis.at_rest` of the rows

    def rest(self, joint: int) -> NDArray[np.bool_]:
        """``(N,)`` rows where joint ``joint`` (1-based) is at rest as far as the data can tell
        (:attr:`at_rest`; without it, where ``qd_j == 0``)."""
        if self.at_rest is None:
            return self.qd[:, joint - 1] == 0.0
        return self.at_rest[:, joint - 1]

    def start_torque(self) -> FloatArray:
        """``tau_hat (N, n)``, the start model's torque (computed once, on first use)."""
        if self.base is None:
            if self.base_fn is None:
                raise ValueError("this feature context has no start-model torque")
            self.base = self.base_fn()
        return self.base

    def body_columns(self, body: int) -> FloatArray | None:
        """``(N, n, 10)``: body ``body``'s (1-based) columns of the joint-torque regressor, or
        ``None`` without a robot file."""
        if self.regressor is None:
            return None
        if self._regressor is None:
            self._regressor = self.regressor()
        return self._regressor[:, :, 10 * (body - 1) : 10 * body]

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
    shared: ClassVar[bool] = False  # one weight vector for all its output joints
    needs_robot: ClassVar[bool] = False  # its columns come from the robot file's regressor
    shape_params: ClassVar[dict[str, Param]] = {}  # how a shape field is reported
    # shape fields whose lower limit is the physical form (a smoothing width): refined to
    # the smallest value of their likelihood interval (:func:`~.search.refine_shape`)
    sharp_shapes: ClassVar[tuple[str, ...]] = ()

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

    @property
    def place(self) -> str:
        """Where the effect sits, in words: ``"on joint 2"`` (``"on every joint"``)."""
        return "on every joint" if self.joint is None else f"on joint {self.joint}"

    def same_slot(self, other: Effect) -> bool:
        """Same effect type on the same joint (the model holds at most one of each)."""
        return type(self) is type(other) and self.joint == other.joint

    def same_family(self, other: Effect) -> bool:
        """Same physical family (:attr:`family`, else the key) on the same joint: two forms
        of one torque, of which a model holds one. The last link's inertia and the payload
        are both the last body's inertia (:meth:`last_body`)."""
        if self.last_body() and other.last_body():
            return True
        return (self.family or self.key) == (other.family or other.key) and (
            self.joint == other.joint
        )

    def last_body(self) -> bool:
        """Whether the effect changes the last body's inertial parameters."""
        return False

    def relinearised(self, mean: FloatArray) -> Effect | None:
        """For a block linearised about a shape value: the effect re-expanded about the one
        its fitted weights ``mean`` imply (``None``: nothing to re-expand)."""
        return None

    def stick_bound(self, mean: FloatArray) -> float | None:
        """Half-width ``F`` of the set-valued torque ``[-F, F]`` the effect holds a joint at
        rest with, from its fitted weights ``mean`` (``None``: not set-valued)."""
        return None

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
            wrong = p.sign > 0 and mean[k] < -Z95 * sd[k]
            out.append(
                ParamEstimate(
                    p.name,
                    float(mean[k]),
                    float(Z95 * sd[k]),
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


EPS_SCAN: tuple[float, ...] = (0.0001, 0.0003, 0.001) + tuple(
    round(0.003 * 2 ** (k / 2), 5) for k in range(7)
)
"""Smoothing velocities ``eps`` of ``tanh(qd / eps)`` scanned [rad/s or m/s]: 0.003 to 0.024 in
steps of sqrt(2), fine enough that a true Coulomb between two values does not lose to Stribeck,
and below them 1e-4 to 1e-3 in steps of about 3 (a sharp sign: slow joints, fine encoders)."""
EPS_BOUNDS = (1e-5, 0.1)  # limits of a refined ``eps`` [rad/s or m/s]


@dataclass(frozen=True)
class _DryFriction(Effect):
    """Dry friction: a set-valued torque (module docstring, *dry friction at rest*)."""

    family: ClassVar[str] = "dry friction"
    sharp_shapes: ClassVar[tuple[str, ...]] = ("eps",)  # eps -> 0: the sign of Coulomb's law

    def _sliding(self, ctx: FeatureContext) -> FloatArray:
        """``tanh(qd_j / eps)`` while sliding, 0 (the centre of the set) at rest."""
        qd = ctx.qd[:, self.joint - 1]
        return np.where(ctx.rest(self.joint), 0.0, np.tanh(qd / self.eps))

    def stick_bound(self, mean: FloatArray) -> float:
        """``F_s``: the breakaway torque, the sum of the weights (``F_c``, plus ``F_s - F_c``
        for Stribeck), never below 0."""
        return max(float(np.sum(mean)), 0.0)


@dataclass(frozen=True)
class CoulombFriction(_DryFriction):
    """Coulomb friction ``F_c tanh(qd_j / eps)`` while sliding (``eps`` [rad/s or m/s] smooths
    the sign; scanned over :data:`EPS_SCAN` when not given), any torque in ``[-F_c, F_c]`` at
    rest."""

    eps: float | None = None
    key: ClassVar[str] = "coulomb"
    title: ClassVar[str] = "Coulomb friction"
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
        return _col(self._sliding(ctx))


STRIBECK_SCAN: tuple[float, ...] = (0.02, 0.05, 0.1, 0.2)
"""Stribeck velocities ``v_s`` scanned [rad/s or m/s]."""
STRIBECK_BOUNDS = (0.005, 0.5)  # limits of a refined ``v_s`` [rad/s or m/s]


@dataclass(frozen=True)
class StribeckFriction(_DryFriction):
    """Stribeck friction ``(F_c + (F_s - F_c) exp(-(qd/v_s)^2)) tanh(qd / eps)`` while
    sliding (stiction), any torque in ``[-F_s, F_s]`` at rest."""

    velocity: float | None = None
    eps: float | None = None
    key: ClassVar[str] = "stribeck"
    title: ClassVar[str] = "Stribeck friction / stiction"
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
        s = self._sliding(ctx)
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
            ParamEstimate("A", amp, Z95 * sd, ctx.unit("{F}", self.joint)),
            ParamEstimate("phi", float(math.atan2(mean[1], mean[0])), Z95 * sd_phi, "rad"),
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


INERTIAL_PARAMS = ("m", "mc_x", "mc_y", "mc_z", "I_xx", "I_xy", "I_yy", "I_xz", "I_yz", "I_zz")
"""Order of a body's 10 inertial parameters ``phi_b`` (pinocchio's regressor; inertia about
the body's joint frame origin)."""
MAX_NONPHYSICAL = 0.1
"""Largest fraction of a link's fitted change that may be given up to make it physical."""
RANK_TOL = 1e-7
"""Singular values of a link's scaled regressor below this fraction of the largest are
directions the data cannot see (structural rank deficiency)."""


def _tuple2(x: Any) -> tuple[tuple[float, ...], ...] | None:
    return None if x is None else tuple(tuple(float(v) for v in row) for row in x)


def _tuple1(x: Any) -> tuple[float, ...] | None:
    return None if x is None else tuple(float(v) for v in x)


@dataclass(frozen=True)
class LinkInertia(Effect):
    """Changed inertial parameters of link ``joint`` (the body moved by that joint):
    ``tau += Y_b(q, qd, qdd) dphi_b`` on joints ``1..b``, ``Y_b`` the body's ``(n, 10)``
    columns of the joint-torque regressor (pinocchio's ``computeJointTorqueRegressor``).

    Identifiable part (calibrated on the training rows)
        The stacked columns ``Y_b`` (all rows, all joints) are rank-deficient: some
        combinations of the 10 parameters move no joint. With ``D`` their column rms and
        ``Y_b D^-1 = U S V^T`` (singular values above :data:`RANK_TOL` of the largest kept,
        ``V_r``), the block is ``Y_b B`` with ``B = D^-1 V_r`` and weights ``z``; the fitted
        change is ``dphi = B z`` (the directions the data cannot see stay at their nominal
        values) and any ``dphi`` with the same torques has ``z = V_r^T D dphi``.

    One weight vector ``z`` for every joint it moves (:attr:`Effect.shared`), so the
    estimates describe one body:

    * ``s``: the change along the nominal parameters, ``dphi ~ s phi_b`` in the data's
      metric, ``s = z_0^T S^2 z / z_0^T S^2 z_0`` with ``z_0 = V_r^T D phi_b`` (a link 40 %
      heavier, centre of mass unchanged, has ``s = 0.4``);
    * ``dm``: the mass change, when identifiable: ``e_m = V_r^T D``-row space holds the mass
      direction, ``e_m = D V_r a``, then ``dm = a^T z``; otherwise not reported;
    * ``nonphysical``: the fraction of the fitted change (in the posterior's metric) that
      must be given up before the corrected body ``phi_b + dphi`` (unseen directions free)
      has a positive semi-definite pseudo-inertia
      :func:`~mcpilco.models.inverse_dynamics.pseudo_inertia` (:meth:`consistency`); ``0``:
      the estimate is a physical body. Above :data:`MAX_NONPHYSICAL` no physical body has
      these torques: the fit is flagged (shown, never recommended). A small fraction is
      tolerated because thin links have pseudo-inertias with eigenvalues near zero that a
      slight bias of the estimated ``qdd`` pushes below it.
    """

    basis: tuple[tuple[float, ...], ...] | None = None
    scale: tuple[float, ...] | None = None
    singular: tuple[float, ...] | None = None
    last: bool | None = None
    key: ClassVar[str] = "inertia"
    title: ClassVar[str] = "inertial parameters"
    family: ClassVar[str] = "body inertia"
    shared: ClassVar[bool] = True
    needs_robot: ClassVar[bool] = True
    params: ClassVar[tuple[Param, ...]] = (Param("s", "", 0), Param("dm", "kg", 0))

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "basis", _tuple2(self.basis))
        object.__setattr__(self, "scale", _tuple1(self.scale))
        object.__setattr__(self, "singular", _tuple1(self.singular))

    @property
    def variant_label(self) -> str:
        return f"link {self.joint} inertia"

    @property
    def place(self) -> str:
        return f"of link {self.joint}"

    def outputs(self, n_joints: int) -> list[int]:
        if self.joint > n_joints:
            raise ValueError(f"{self.label}: link {self.joint} but the model has {n_joints}")
        return list(range(self.joint))

    def in_gip_span(self, joint_types: str) -> bool:
        return True  # rigid-body torques: the GIP kernel is built to span them (thesis 3.3)

    def calibrate(self, ctx: FeatureContext) -> Effect:
        if self.basis is not None:
            return self
        cols = ctx.body_columns(self.joint)
        if cols is None:
            return self
        y = cols[:, : self.joint, :].reshape(-1, 10)
        d = np.sqrt(np.mean(y**2, axis=0))
        d = np.where(d > 0, d, 1.0)
        _, sv, vt = np.linalg.svd(y / d, full_matrices=False)
        keep = sv > RANK_TOL * sv[0] if sv.size and sv[0] > 0 else np.zeros(sv.size, bool)
        last = ctx.rigid is not None and self.joint == ctx.rigid.parameters.shape[0]
        return dataclasses.replace(self, basis=vt[keep], scale=d, singular=sv[keep], last=last)

    def last_body(self) -> bool:
        return bool(self.last)

    def _bases(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(B (10, r), E (10, r), S (r,))``: ``dphi = B z``, ``z = E^T dphi``."""
        v = np.asarray(self.basis, dtype=np.float64).reshape(-1, 10).T
        d = np.asarray(self.scale, dtype=np.float64)
        return v / d[:, None], v * d[:, None], np.asarray(self.singular, dtype=np.float64)

    def columns(self, ctx: FeatureContext, output: int) -> FloatArray | None:
        cols = ctx.body_columns(self.joint)
        if cols is None or self.basis is None:
            return None
        return cols[:, output, :] @ self._bases()[0]

    def change(self, z: FloatArray) -> FloatArray:
        """``dphi = B z`` (10 values, :data:`INERTIAL_PARAMS`) of block weights ``z``."""
        return self._bases()[0] @ np.asarray(z, dtype=np.float64)

    def consistency(self, phi: FloatArray, mean: FloatArray, cov: FloatArray) -> float:
        """Fraction ``rho`` of the fitted change that must be given up for a physical body:
        the smallest ``d^2 = (z - mean)^T cov^-1 (z - mean)`` with ``z = E^T (phi' - phi)``
        over physical bodies ``phi'`` (pseudo-inertia ``J = L L^T``, ``L`` lower triangular:
        a smooth least-squares problem in the 10 entries of ``L``, started from the nominal
        body and from the nominal body scaled by ``1 + s``), over
        ``d_0^2 = mean^T cov^-1 mean`` (the nominal body itself, ``z = 0``): ``0 <= rho <= 1``,
        ``0`` when the estimate is a physical body or the nominal body lies within the 95 %
        ellipsoid (``d_0^2 <= chi^2_r``)."""
        from scipy.optimize import least_squares
        from scipy.stats import chi2

        from mcpilco.models.inverse_dynamics.rigid_body import pseudo_inertia

        _, e, sv = self._bases()
        w, v = np.linalg.eigh(0.5 * (cov + cov.T))
        keep = w > w.max(initial=0.0) * 1e-12
        whiten = (v[:, keep] / np.sqrt(w[keep])).T  # x = whiten z: cov^-1 = whiten^T whiten
        phi = np.asarray(phi, dtype=np.float64)
        d0 = float(np.sum((whiten @ mean) ** 2))
        if d0 <= chi2.ppf(0.95, max(int(keep.sum()), 1)):
            return 0.0  # the nominal body itself lies within the 95 % ellipsoid
        tril = np.tril_indices(4)
        # phi = T vec(J): the parameters are linear in the pseudo-inertia J = L L^T
        T = np.stack([_phi_of_j(np.eye(16)[k].reshape(4, 4)) for k in range(16)], axis=1)
        unit = np.zeros((len(tril[0]), 4, 4))
        unit[np.arange(len(tril[0])), tril[0], tril[1]] = 1.0
        proj = whiten @ e.T

        def low(params: FloatArray) -> FloatArray:
            out = np.zeros((4, 4))
            out[tril] = params
            return out

        def resid(params: FloatArray) -> FloatArray:
            m = low(params)
            return proj @ (T @ (m @ m.T).ravel() - phi) - whiten @ mean

        def jac(params: FloatArray) -> FloatArray:
            m = low(params)
            d = unit @ m.T + np.transpose(unit @ m.T, (0, 2, 1))  # dJ / dparams
            return proj @ T @ d.reshape(len(d), 16).T

        if np.linalg.eigvalsh(pseudo_inertia(phi + self.change(mean)))[0] >= 0:
            return 0.0
        z0 = e.T @ phi
        s = float(z0 @ (sv**2 * mean)) / float(z0 @ (sv**2 * z0)) if np.any(z0) else 0.0
        best = d0
        for factor in {1.0, max(1.0 + s, 1e-3)}:
            jm = pseudo_inertia(phi) * factor
            start = np.linalg.cholesky(jm + 1e-12 * np.trace(jm) * np.eye(4))[tril]
            res = least_squares(resid, start, jac=jac, method="trf", max_nfev=200)
            best = min(best, float(np.sum(res.fun**2)))
        return best / d0

    def estimates(
        self, mean: FloatArray, cov: FloatArray, ctx: FeatureContext, output: int
    ) -> list[ParamEstimate]:
        if ctx.rigid is None or self.basis is None:
            return []
        b, e, sv = self._bases()
        phi = np.asarray(ctx.rigid.parameters[self.joint - 1], dtype=np.float64)
        z0 = e.T @ phi
        g = (sv**2 * z0) / float(z0 @ (sv**2 * z0)) if np.any(z0) else np.zeros_like(z0)
        out = [_linear_estimate("s", g, mean, cov, "× nominal")]
        e_m = np.eye(10)[0]
        a, *_ = np.linalg.lstsq(e, e_m, rcond=None)
        if np.linalg.norm(e @ a - e_m) < 1e-6:
            out.append(_linear_estimate("dm", a, mean, cov, "kg"))
        rho = self.consistency(phi, mean, cov)
        out.append(
            ParamEstimate("nonphysical", rho, 0.0, "", wrong_sign=bool(rho > MAX_NONPHYSICAL))
        )
        return out


def _phi_of_j(jm: FloatArray) -> FloatArray:
    """The 10 parameters of a pseudo-inertia ``J`` (inverse of ``pseudo_inertia``; linear):
    ``m = J_33``, ``h = J_{:3,3}``, ``I = tr(Sigma) 1 - Sigma``."""
    sigma = 0.5 * (jm[:3, :3] + jm[:3, :3].T)
    inertia = np.trace(sigma) * np.eye(3) - sigma
    h = 0.5 * (jm[:3, 3] + jm[3, :3])
    return np.array(
        [jm[3, 3], *h, inertia[0, 0], inertia[0, 1], inertia[1, 1],
         inertia[0, 2], inertia[1, 2], inertia[2, 2]]
    )  # fmt: skip


def _linear_estimate(
    name: str, g: FloatArray, mean: FloatArray, cov: FloatArray, unit: str, sign: int = 0
) -> ParamEstimate:
    """``g^T w`` of weights ``w ~ N(mean, cov)`` with its 95 % interval."""
    value = float(g @ mean)
    sd = math.sqrt(max(float(g @ cov @ g), 0.0))
    return ParamEstimate(name, value, Z95 * sd, unit, bool(sign > 0 and value < -Z95 * sd))


def flange_map(pos: FloatArray, rot: FloatArray) -> FloatArray:
    """``G (10, 4)``: the last body's parameter change ``dphi = G [m, m p]`` of a point mass
    ``m`` at ``p`` in the flange frame (pose ``pos, rot`` in the body frame), to first order
    in ``p``. With ``o = pos`` and ``u = rot p``: ``dphi = [m, m (o + u),
    m (|o|^2 1 - o o^T) + m (2 o^T u 1 - o u^T - u o^T)]``, dropping the ``m |p|^2`` terms."""
    o = np.asarray(pos, dtype=np.float64)

    def vech(a: FloatArray) -> list[float]:
        return [a[0, 0], a[0, 1], a[1, 1], a[0, 2], a[1, 2], a[2, 2]]

    cols = [[1.0, *o, *vech(float(o @ o) * np.eye(3) - np.outer(o, o))]]
    for i in range(3):
        u = np.asarray(rot, dtype=np.float64)[:, i]
        sym = 2.0 * float(o @ u) * np.eye(3) - np.outer(o, u) - np.outer(u, o)
        cols.append([0.0, *u, *vech(sym)])
    return np.array(cols).T


RELINEARISE_STEPS = 3
"""Most re-expansions of the payload's point mass about its fitted offset."""


@dataclass(frozen=True)
class Payload(Effect):
    """A payload at the flange: a mass ``m`` at offset ``p`` (flange frame) with its own
    isotropic inertia ``I_p`` about its centre (a sphere, a cube), the last body's
    parameters changed by ``G [m, m d] + I_p [0, 0, 0, 0, 1, 0, 1, 0, 0, 1]``
    (:func:`flange_map` about ``p = p_0 + d``, first order in ``d``), acting on every joint's
    torque through the last body's regressor columns with one weight vector
    ``[m, m d, I_p]`` for all joints (:attr:`Effect.shared`). Only ``m >= 0`` is enforced:
    the small ``I_p`` is the direction in which a bias of estimated ``qdd`` shows first.
    Scoring re-expands about the fitted offset (``p_0 <- p_0 + (m d) / m``, at most
    :data:`RELINEARISE_STEPS` times while the evidence rises), so the dropped ``m |d|^2``
    terms vanish for a point mass away from the flange. Its torques lie in those of
    :class:`LinkInertia` of the last link: the two are one physical family
    (:meth:`Effect.same_family`), alternatives of each other, and the data prefer the
    payload when the change looks like a point mass."""

    offset: tuple[float, ...] | None = None
    key: ClassVar[str] = "payload"
    title: ClassVar[str] = "payload"
    family: ClassVar[str] = "body inertia"
    all_joints: ClassVar[bool] = True
    shared: ClassVar[bool] = True
    needs_robot: ClassVar[bool] = True
    params: ClassVar[tuple[Param, ...]] = (Param("m", "kg", +1),)

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "offset", _tuple1(self.offset))

    @property
    def place(self) -> str:
        return "at the flange"

    def last_body(self) -> bool:
        return True

    def shape_text(self) -> str:
        if self.offset is None:
            return ""
        return "p0=(" + ", ".join(f"{v:.3g}" for v in self.offset) + ") m"

    def _p0(self) -> FloatArray:
        return np.zeros(3) if self.offset is None else np.asarray(self.offset, dtype=np.float64)

    def relinearised(self, mean: FloatArray) -> Payload | None:
        """The payload expanded about the fitted offset ``p_0 + (m d) / m`` (``None`` when
        the fitted mass is not positive)."""
        if not mean[0] > 0:
            return None
        return dataclasses.replace(self, offset=self._p0() + np.asarray(mean[1:4]) / mean[0])

    def columns(self, ctx: FeatureContext, output: int) -> FloatArray | None:
        if ctx.rigid is None:
            return None
        last = ctx.rigid.parameters.shape[0]
        cols = ctx.body_columns(last)
        if cols is None:
            return None
        rot = np.asarray(ctx.rigid.flange_rot, dtype=np.float64)
        pos = np.asarray(ctx.rigid.flange_pos, dtype=np.float64) + rot @ self._p0()
        own = np.zeros((10, 1))
        own[[4, 6, 9], 0] = 1.0  # I_p added to I_xx, I_yy, I_zz: an isotropic body
        return cols[:, output, :] @ np.concatenate([flange_map(pos, rot), own], axis=1)

    def in_gip_span(self, joint_types: str) -> bool:
        return True  # rigid-body torques: the GIP kernel is built to span them (thesis 3.3)

    def change(self, w: FloatArray, ctx: FeatureContext) -> FloatArray | None:
        """The last body's 10 inertial parameters' change (:data:`INERTIAL_PARAMS`, about
        its joint frame) of weights ``w = [m, m d, I_p]``; ``None`` without a robot."""
        if ctx.rigid is None:
            return None
        rot = np.asarray(ctx.rigid.flange_rot, dtype=np.float64)
        pos = np.asarray(ctx.rigid.flange_pos, dtype=np.float64) + rot @ self._p0()
        w = np.asarray(w, dtype=np.float64)
        own = np.zeros(10)
        own[[4, 6, 9]] = w[4]
        return flange_map(pos, rot) @ w[:4] + own

    def estimates(
        self, mean: FloatArray, cov: FloatArray, ctx: FeatureContext, output: int
    ) -> list[ParamEstimate]:
        out = [_linear_estimate("m", np.eye(len(mean))[0], mean, cov, "kg", sign=+1)]
        m, sd_m = float(mean[0]), math.sqrt(max(float(cov[0, 0]), 0.0))
        if m > 2.0 * Z95 * sd_m:  # the offset p = (m p) / m, delta method, when m is clear
            p0 = self._p0()
            for i, axis in enumerate("xyz", start=1):
                g = np.zeros(len(mean))
                g[0], g[i] = -mean[i] / m**2, 1.0 / m
                est = _linear_estimate(f"p_{axis}", g, mean, cov, "m")
                out.append(dataclasses.replace(est, value=float(p0[i - 1] + mean[i] / m)))
        # I_p's sign is not enforced: the bias of an estimated qdd shows first in it
        out.append(_linear_estimate("I_p", np.eye(len(mean))[4], mean, cov, "kg·m²"))
        return out


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
        LinkInertia,
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


@dataclass(frozen=True)
class TorqueScale(Effect):
    """A free scale of the start model's torque, ``alpha tau_hat_j``; not a candidate.

    Motor currents put into torque units with an estimated constant (:mod:`.units`),
    ``y = k_hat i``, miss the true torque by ``(k_hat / k - 1) tau``: a scaled copy of the
    joint's torque, gravity included, whose mean looks like an offset and whose shape like a
    spring, cogging or a payload. The loop's first version holds this block on every joint
    whose constant was estimated, so candidates are scored against a model whose scale is
    still free (their evidence and intervals then include the ``k_t`` uncertainty);
    ``alpha ~ k_hat / k - 1``.
    """

    key: ClassVar[str] = "scale"
    title: ClassVar[str] = "torque-constant error"
    needs_base: ClassVar[bool] = True
    params: ClassVar[tuple[Param, ...]] = (Param("alpha", "", 0),)

    def columns(self, ctx: FeatureContext, output: int) -> FloatArray:
        return _col(ctx.start_torque()[:, self.joint - 1])


LEVEL_DEGREE = 3
"""Highest Legendre degree in ``q_j`` of :class:`PositionLevel`."""


@dataclass(frozen=True)
class PositionLevel(Effect):
    """The level of an effect in the model varying with its joint's position; not a
    candidate: the shape check of a named effect (:func:`~.search.shape_check`).

    ``phi_e(x) [P_1(s), ..., P_K(s)]`` (every column of the effect's block ``phi_e`` times
    the Legendre polynomials of ``s = (2 q_j - lo - hi) / (hi - lo)``, clipped to
    ``[-1, 1]``; ``[lo, hi]`` the training range of ``q_j``; ``K`` =
    :data:`LEVEL_DEGREE`): with the effect itself, its parameters become smooth functions of
    ``q_j`` over the range the data visit. A library effect has a constant level (a
    friction, an armature, a damping do not change along the joint's travel): when this
    block is significant beside it, the torque has the effect's shape but not its form
    (friction that varies with position, a position-dependent inertia), and the named
    effect only explains part of it.
    """

    of: Effect | None = None
    lo: float | None = None
    hi: float | None = None
    key: ClassVar[str] = "level"
    title: ClassVar[str] = "position-dependent level"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.of is None or self.of.joint != self.joint:
            raise ValueError("level: give the effect it modulates (of) on the same joint")

    def shape_text(self) -> str:
        return "" if self.of is None else f"of {self.of.variant_label}"

    def calibrate(self, ctx: FeatureContext) -> Effect:
        if self.lo is not None:
            return self
        q = ctx.q[:, self.joint - 1]
        return dataclasses.replace(
            self, of=self.of.calibrate(ctx), lo=float(q.min()), hi=float(q.max())
        )

    def columns(self, ctx: FeatureContext, output: int) -> FloatArray | None:
        base = self.of.columns(ctx, output)
        if base is None or self.lo is None or not self.hi > self.lo:
            return None
        q = ctx.q[:, self.joint - 1]
        x = np.clip((2.0 * q - self.lo - self.hi) / (self.hi - self.lo), -1.0, 1.0)
        legendre = np.polynomial.legendre.legvander(x, LEVEL_DEGREE)[:, 1:]
        return np.concatenate([base * legendre[:, [k]] for k in range(LEVEL_DEGREE)], axis=1)


MODEL_ONLY_EFFECTS: dict[str, type[Effect]] = {TorqueScale.key: TorqueScale}
"""Blocks the loop puts in a model itself (never candidates), by key."""


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
    known = {**EFFECTS, **MODEL_ONLY_EFFECTS}
    if key not in known:
        raise ValueError(f"unknown effect {key!r}; known effects: {', '.join(known)}")
    profile = []
    for p in spec.pop("profile", ()):
        p = dict(p)
        if p.get("interval") is not None:
            p["interval"] = tuple(p["interval"])
        profile.append(ParamEstimate(**p))
    return known[key](**spec, profile=tuple(profile))


def default_library(n_joints: int, rigid_body: bool = True) -> list[Effect]:
    """Every effect on every joint; ``rigid_body``: also the candidates that read the robot
    file's regressor (every link's inertia, the payload once)."""
    out: list[Effect] = []
    for cls in EFFECTS.values():
        if cls.needs_robot and not rigid_body:
            continue
        if cls.all_joints:
            out.append(cls())
            continue
        out += [cls(joint=j) for j in range(1, n_joints + 1)]
    return out
