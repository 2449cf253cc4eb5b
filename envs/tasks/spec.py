"""Task specification: what a model-based agent (MC-PILCO) needs to know about an env, as
data. Importing this module does not import torch: a task's torch cost function
(``cost_fn``) is called only when one is given.

A :class:`TaskSpec` turns any Gymnasium env with a continuous action space into an MC-PILCO
task. Everything shape-dependent in the agent (GP inputs and outputs, speed integration,
policy inputs, the cost, the initial particles, the success test) is derived from it.

Glossary (thesis sections 5.3-5.5)
----------------------------------
``x = [x_0 .. x_{n-1}]``
    the state, named by ``state_names``, read from the observation (``obs[obs_indices]``, or
    the observation itself), or per state by ``state_from`` (derived states below).
derived states (``state_from``)
    per state name, how it is read: ``x_j = scale * v + offset`` with ``v = o[index]``
    (selection and scaling) or ``v = atan2(o[sin], o[cos])`` (an angle from the
    ``(cos, sin)`` pair an env observes, e.g. Gymnasium's ``Pendulum-v1``), where ``o`` is
    the observation, or the vector ``info[info]`` when ``info`` names an ``info`` key (e.g.
    the physics state of a dm-control env). An entry is an index or a name: the env's
    ``observation_names`` (or ``<info>_names``) name its entries
    (:class:`mcpilco.envs.dmc.DMControlEnv`).
angles
    coordinates that wrap around: the GP and the policy see ``(sin x_j, cos x_j)`` instead of
    ``x_j`` (thesis 5.5.1, "x_ext").
``(q_i, q_dot_i)`` pairs
    position/velocity pairs: the GP predicts ``Delta q_dot_i`` and ``q_i`` is integrated,
    eq. (5.9) ("speed integration", thesis 5.4.3). Every coordinate in no pair is predicted
    as a change ``Delta x_j`` of its own.
``speed_integration``
    True (default): positions are integrated as above, which assumes a constant
    acceleration over the control period ``T_s``. A held action with a fast inner loop (a
    stiff PD controller) or a fast reference breaks that assumption: for a joint moving as
    ``A sin(w t)`` the trapezoid step ``T_s (qd_t + qd_{t+1}) / 2`` misses the true
    displacement by the factor ``(w T_s / 2) / tan(w T_s / 2)`` (0.8 % at
    ``w T_s = 0.31``), a per-step error that a tracking task's millirad errors cannot afford.
    False: the pairs still say which velocity belongs to which position (joints, the
    rigid-body kernel's inputs), but the GP predicts every position change ``Delta q_i`` as
    well (one more output per pair).
``f(x~) = [x_plain, sin x_angles, cos x_angles]``
    the state features; the GP input is ``[f(x), u]`` (:meth:`TaskSpec.feature_layout`).
``c(x) = 1 - exp(-sum_j d_j(x)^2 / l_j^2)``
    the saturating cost on named state terms with targets ``x*_j`` and length scales ``l_j``;
    ``d_j = x_j - x*_j`` for a plain coordinate, ``wrap(x_j - x*_j)`` for an angle (mode
    ``"wrap"``), or ``|x_j| - |x*_j|`` (mode ``"abs"``, MC-PILCO's unwrapped cart-pole cost,
    which does not reward spinning through the target). A term with a ``reference`` state
    ``r`` measures the tracking error instead: ``x_j - x_r - x*_j`` (wrapped for an angle).
joints (an arm)
    ``joints`` names the joint positions ``q_b`` (each the position of a pair, so its
    velocity ``qd_b`` is known), ``joint_types`` says ``R`` (revolute) or ``P`` (prismatic)
    per joint, and the actions are the joint torques (or torque corrections) ``tau_b``, one
    per joint. ``affine_inputs`` names further states in which the accelerations are affine
    at a fixed configuration (the reference of a PD controller in the loop). The rigid-body
    GP kernel (:mod:`mcpilco.agents.mc_pilco.dynamics`) works on the raw ``[q, qd, tau, w]``
    this declares.
reference
    a joint reference the env tracks, passed at every reset as ``options["reference"]``: a
    sum of sinusoids ``q_r,b(t) = c_b + sum_k A_bk sin(w_bk t + phi_bk)`` with a
    ``duration`` of at least the horizon. With one sinusoid per joint, ``reference.states``
    may name the state pair ``(q_r,b, qd_r,b)`` that holds each joint's reference: then
    ``(q_r - c, qd_r / w)`` rotates by ``w T_s`` per period (a harmonic oscillator, the
    exosystem of the tracking task), which the particle rollout propagates exactly instead
    of learning it (:func:`~mcpilco.agents.mc_pilco.dynamics.speed_integration`); those
    states take no GP output and start exactly on the reference. Without ``states`` the
    GP predicts the reference states like any other.
limits
    ``lo_j <= x_j <= hi_j``: the range a coordinate cannot leave on the system (a rail's end
    stop, a joint limit). Contact with a limit is a regime of its own (an impact, a constraint
    force) that a smooth GP of the free dynamics would blur into its neighbourhood, so a
    transition that touches one is kept out of the dynamics data
    (:meth:`TaskSpec.touches_limit`); the optimised cost can put a barrier at each limit
    (:mod:`mcpilco.agents.mc_pilco.cost`), which keeps the predicted particles, and so the
    policy, off the stops.
termination
    ``{x_j: [lo_j, hi_j]}``: the env ends an episode as soon as a listed coordinate leaves
    its range (an angle by its wrapped value), e.g. a pole that falls past 0.2 rad. The
    particle rollout then treats the set outside as absorbing
    (:class:`~mcpilco.agents.mc_pilco.loss.MCPilcoLoss`): a particle that leaves it stays
    where it left and pays the cost's maximum for every remaining step.
evaluation episodes (``eval_init``, ``eval_steps``)
    episodes of a policy that are not experience, judged by the same success test: each
    starts from the env's reset with the entries of the env's state that ``eval_init``
    names set to ``v ~ U(lo, hi)`` (e.g. a pendulum started hanging, ``theta = pi +- 0.1``;
    :func:`mcpilco.envs.reset_state.set_env_state` says how each kind of env takes them),
    and lasts ``eval_steps`` control steps (default: the env's own episode length, so that a
    policy optimised over a shorter horizon is judged over the env's full episode).
``trial_steps``
    control steps of experience each trial collects: an episode that ends early is followed
    by further episodes (reset by the env's own generator) until that many steps were taken
    in all; default the horizon (one full episode of an env that never terminates).
success
    the env's ``info[info_key]`` at the last step, else every state of the last ``window``
    steps within ``tol`` of its target (angles by wrapped distance), and with
    ``full_horizon`` the episode must not end early; ``tracking_rms`` (state -> bound) also
    needs the episode's tracking RMS of each listed tracked state
    (:meth:`TaskSpec.tracking_rms`) at most its bound.

Task files of the registered envs ship in :mod:`mcpilco.envs.tasks`; a user's own env gets a
spec from a dict, a YAML file, or Python (:meth:`TaskSpec.from_dict`, :meth:`from_yaml`).
Errors name the field (``task.pairs[1]``, ``task.cost.terms[0].state``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

ANGLE_MODES = ("wrap", "abs")
"""Distance of an angle cost term to its target: wrapped difference, or ``|x| - |x*|``."""


MODELS = ("dynamics", "kinematics")
"""What MC-PILCO learns on a task: GP dynamics, or the kinematics seen through markers."""


RESET_SAMPLES = 10
"""Env resets :meth:`TaskSpec.check_reset` samples before any trial."""


class TaskSpecError(ValueError):
    """A task specification field is wrong; the message names the field."""


def _fail(path: str, msg: str) -> TaskSpecError:
    return TaskSpecError(f"task.{path}: {msg}")


def wrap(a: np.ndarray | float) -> np.ndarray:
    """Angles mapped to ``[-pi, pi)``."""
    return np.mod(np.asarray(a, dtype=np.float64) + np.pi, 2.0 * np.pi) - np.pi


@dataclass(frozen=True)
class CostTerm:
    """One term ``(d_j / l_j)^2`` of the saturating cost."""

    state: str
    target: float = 0.0
    length_scale: float = 1.0
    angle_mode: str = "wrap"  # used only when ``state`` is an angle
    reference: str | None = None  # a state tracked by ``state``: d = x - x_ref - target


@dataclass(frozen=True)
class Bound:
    """``|d(x_j, target)| <= tol`` (wrapped distance for an angle)."""

    target: float
    tol: float


@dataclass(frozen=True)
class StateReader:
    """How one state is read (module glossary, derived states): ``scale * v + offset`` with
    ``v = o[index]``, or ``v = atan2(o[sin], o[cos])`` when ``cos`` and ``sin`` are given;
    ``o`` is the observation, or ``info[info]`` when ``info`` is given. Each entry is an
    index or a name of the env's ``observation_names`` (``<info>_names``)."""

    index: int | str | None = None
    cos: int | str | None = None
    sin: int | str | None = None
    scale: float = 1.0
    offset: float = 0.0
    info: str | None = None

    def entries(self) -> tuple[tuple[str, int | str], ...]:
        """``(key, entry)`` of each entry this reader reads."""
        keys = ("index",) if self.index is not None else ("cos", "sin")
        return tuple((k, getattr(self, k)) for k in keys)


READER_KEYS = ("index", "cos", "sin", "scale", "offset", "info")
"""Keys of a ``state_from`` entry (:class:`StateReader`)."""


@dataclass(frozen=True)
class SuccessSpec:
    """Success of an episode; see the module glossary."""

    info_key: str | None = None
    window: int | None = None
    bounds: Mapping[str, Bound] = field(default_factory=dict)
    full_horizon: bool = False
    tracking_rms: Mapping[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class TaskSpec:
    """A task for MC-PILCO, validated at construction (errors name the field).

    Attributes:
        env_id: the Gymnasium id the task belongs to.
        state_names: names of the state coordinates, in order.
        obs_indices: ``state = obs[obs_indices]``; None: the observation is the state.
        state_from: state name -> :class:`StateReader` (derived states, module glossary),
            every state listed; instead of ``obs_indices``. Entries given by name are
            resolved against the env by :meth:`check_env`.
        env_reset_options: ``options`` passed to every ``env.reset`` (an env's own reset
            distribution, e.g. Pendulum-v1's ``{x_init, y_init}``).
        true_state_key: ``info`` key of the noise-free state, used for evaluation (cost,
            success); None: the state read from the observation.
        angles: names of the coordinates that wrap around.
        pairs: ``(position, velocity)`` name pairs (speed integration; an arm's joints).
        speed_integration: integrate the pairs' positions by eq. (5.9) (True) or predict
            their changes with the GP (False); module glossary.
        model: what MC-PILCO learns on this task (:data:`MODELS`): ``"dynamics"``, the GP
            dynamics of :mod:`mcpilco.agents.mc_pilco.trainer` (``mcpilco-train``);
            ``"kinematics"``, the forward kinematics seen through markers, optimised through
            by :mod:`mcpilco.agents.mc_pilco.reaching` (``mcpilco-bench-kinematics
            --reaching-seeds``); such a spec serves the model-free learners and the comparison.
        action_low, action_high: action bounds (the policy's output range).
        dt: control period [s]. horizon: steps per episode and of the particle rollout.
        action_repeat: env steps each action is held for; then ``dt`` is that many env
            steps (a control period coarser than the env's sampling).
        init_mean, init_std: ``x_0 ~ N(mu_0, diag(sigma_0^2))`` of the particles.
        cost_terms: terms of the saturating cost (the evaluation cost; an agent config may
            change the length scales and angle modes of the optimised cost).
        cost_fn: a user's differentiable torch cost ``state (..., n) -> (...)`` used instead
            of ``cost_terms`` in the optimisation (the evaluation still uses ``cost_terms``
            when given, else ``cost_fn`` on numpy input through torch).
        success: the success test (:class:`SuccessSpec`).
        joints: names of an arm's joint positions (module glossary); () for no arm.
        joint_types: ``R`` or ``P`` per joint (None: all revolute).
        affine_inputs: states the accelerations are affine in at a fixed configuration.
        reference: the sum-of-sinusoids joint reference passed to the env at reset
            (keys ``centre``, ``amplitudes``, ``omegas``, ``phases``, ``duration``), or None.
        limits: ``{state name: (lo, hi)}``, the range each listed coordinate cannot leave on
            the system (module glossary); no angle.
        termination: ``{state name: (lo, hi)}``, the range outside which the env ends an
            episode (module glossary; an angle by its wrapped value).
        trial_steps: control steps of experience per trial, across resets (None: the
            horizon; module glossary).
        eval_init: env state entry name -> ``(lo, hi)``: evaluation episodes start with each
            named entry of the env's state drawn from ``U(lo, hi)`` (module glossary); None:
            the env's own reset distribution.
        eval_steps: control steps of an evaluation episode (None: the env's own episode
            length, else the horizon).
    """

    env_id: str
    state_names: tuple[str, ...]
    action_low: tuple[float, ...]
    action_high: tuple[float, ...]
    dt: float
    horizon: int
    obs_indices: tuple[int, ...] | None = None
    true_state_key: str | None = None
    angles: tuple[str, ...] = ()
    pairs: tuple[tuple[str, str], ...] = ()
    init_mean: tuple[float, ...] | None = None
    init_std: tuple[float, ...] | float = 0.01
    cost_terms: tuple[CostTerm, ...] = ()
    cost_fn: Callable[..., Any] | None = None
    success: SuccessSpec = field(default_factory=SuccessSpec)
    joints: tuple[str, ...] = ()
    joint_types: str | None = None
    affine_inputs: tuple[str, ...] = ()
    reference: Mapping[str, Any] | None = None
    action_repeat: int = 1
    limits: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    speed_integration: bool = True
    model: str = "dynamics"
    state_from: Mapping[str, StateReader] | None = None
    env_reset_options: Mapping[str, Any] | None = None
    termination: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    trial_steps: int | None = None
    eval_init: Mapping[str, tuple[float, float]] | None = None
    eval_steps: int | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "_entry_names", {})  # source -> entry names, by check_env
        if self.model not in MODELS:
            raise _fail("model", f"one of {MODELS}, got {self.model!r}")
        if not isinstance(self.speed_integration, bool):
            raise _fail(
                "speed_integration", f"expected true or false, got {self.speed_integration!r}"
            )
        names = tuple(str(n) for n in self.state_names)
        object.__setattr__(self, "state_names", names)
        if not names:
            raise _fail("state_names", "needs at least one state")
        for i, n in enumerate(names):
            if names.index(n) != i:
                raise _fail(f"state_names[{i}]", f"{n!r} listed twice")
        n = len(names)
        if self.obs_indices is not None:
            idx = tuple(int(i) for i in self.obs_indices)
            if len(idx) != n:
                raise _fail("obs_indices", f"needs one index per state ({n}), got {len(idx)}")
            for i, j in enumerate(idx):
                if j < 0:
                    raise _fail(f"obs_indices[{i}]", f"index {j} is negative")
            object.__setattr__(self, "obs_indices", idx)
        angles = tuple(str(a) for a in self.angles)
        for i, a in enumerate(angles):
            if a not in names:
                raise _fail(f"angles[{i}]", f"unknown state name {a!r} (states: {names})")
            if angles.index(a) != i:
                raise _fail(f"angles[{i}]", f"{a!r} listed twice")
        object.__setattr__(self, "angles", angles)
        pairs, used = [], {}
        for i, pair in enumerate(self.pairs):
            if isinstance(pair, str) or len(pair) != 2 or any(p is None for p in pair):
                raise _fail(
                    f"pairs[{i}]",
                    f"needs [position, velocity], got {pair!r} (a velocity needs its position)",
                )
            pos, vel = str(pair[0]), str(pair[1])
            for role, name in (("position", pos), ("velocity", vel)):
                if name not in names:
                    raise _fail(f"pairs[{i}]", f"unknown {role} {name!r} (states: {names})")
                if name in used:
                    raise _fail(f"pairs[{i}]", f"{name!r} is already in pairs[{used[name]}]")
                used[name] = i
            if vel in angles:
                raise _fail(f"pairs[{i}]", f"velocity {vel!r} is listed as an angle")
            pairs.append((pos, vel))
        object.__setattr__(self, "pairs", tuple(pairs))
        low = tuple(float(v) for v in np.atleast_1d(self.action_low))
        high = tuple(float(v) for v in np.atleast_1d(self.action_high))
        if not low or len(low) != len(high):
            raise _fail("action_high", f"needs as many entries as action_low ({len(low)})")
        for i, (lo, hi) in enumerate(zip(low, high, strict=True)):
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise _fail(f"action_low[{i}]", f"needs finite low < high, got [{lo}, {hi}]")
        object.__setattr__(self, "action_low", low)
        object.__setattr__(self, "action_high", high)
        if not (math.isfinite(float(self.dt)) and float(self.dt) > 0):
            raise _fail("dt", f"needs a control period > 0, got {self.dt!r}")
        object.__setattr__(self, "dt", float(self.dt))
        if int(self.horizon) != self.horizon or self.horizon < 1:
            raise _fail("horizon", f"needs a positive integer, got {self.horizon!r}")
        object.__setattr__(self, "horizon", int(self.horizon))
        rep = self.action_repeat
        if isinstance(rep, bool) or not isinstance(rep, int) or rep < 1:
            raise _fail("action_repeat", f"needs a positive integer, got {rep!r}")
        mean = (0.0,) * n if self.init_mean is None else tuple(float(v) for v in self.init_mean)
        if len(mean) != n:
            raise _fail("init_mean", f"needs {n} entries (one per state), got {len(mean)}")
        object.__setattr__(self, "init_mean", mean)
        std = (
            np.broadcast_to(np.asarray(self.init_std, dtype=np.float64), (n,))
            if np.ndim(self.init_std) == 0
            else np.asarray(self.init_std, dtype=np.float64)
        )
        if std.shape != (n,) or not np.all(std >= 0) or not np.all(np.isfinite(std)):
            raise _fail(
                "init_std", f"needs a scalar or {n} finite values >= 0, got {self.init_std}"
            )
        object.__setattr__(self, "init_std", tuple(float(v) for v in std))
        terms = []
        for i, t in enumerate(self.cost_terms):
            t = t if isinstance(t, CostTerm) else _parse_term(t, f"cost.terms[{i}]")
            if t.state not in names:
                raise _fail(
                    f"cost.terms[{i}].state", f"unknown state name {t.state!r} (states: {names})"
                )
            if not (t.length_scale > 0 and math.isfinite(t.length_scale)):
                raise _fail(f"cost.terms[{i}].length_scale", f"needs > 0, got {t.length_scale}")
            if t.angle_mode not in ANGLE_MODES:
                raise _fail(f"cost.terms[{i}].angle_mode", f"one of {ANGLE_MODES}")
            if any(t.state == o.state for o in terms):
                raise _fail(f"cost.terms[{i}].state", f"{t.state!r} has two cost terms")
            if t.reference is not None and t.angle_mode == "abs":
                raise _fail(f"cost.terms[{i}].angle_mode", "a tracking term takes 'wrap'")
            if t.reference is not None and (t.reference not in names or t.reference == t.state):
                raise _fail(
                    f"cost.terms[{i}].reference",
                    f"needs another state name, got {t.reference!r} (states: {names})",
                )
            terms.append(t)
        object.__setattr__(self, "cost_terms", tuple(terms))
        if not terms and self.cost_fn is None:
            raise _fail("cost", "needs cost terms or a cost function")
        if self.cost_fn is not None and not callable(self.cost_fn):
            raise _fail("cost_fn", "must be callable: torch state (..., n) -> cost (...)")
        s = self.success
        for key, b in s.bounds.items():
            if key not in names:
                raise _fail(f"success.bounds.{key}", f"unknown state name (states: {names})")
            if not b.tol > 0:
                raise _fail(f"success.bounds.{key}.tol", f"needs > 0, got {b.tol}")
        if s.window is not None and not 1 <= int(s.window) <= self.horizon:
            raise _fail("success.window", f"needs 1..horizon ({self.horizon}), got {s.window}")
        tracked = {t.state for t in self.cost_terms if t.reference is not None}
        for key, bound in s.tracking_rms.items():
            if key not in tracked:
                raise _fail(
                    f"success.tracking_rms.{key}",
                    f"needs a state a cost term tracks (tracked: {sorted(tracked)})",
                )
            if not (_is_number(bound) and bound > 0):
                raise _fail(f"success.tracking_rms.{key}", f"needs a bound > 0, got {bound!r}")
        if s.info_key is None and not s.bounds and not s.full_horizon and not s.tracking_rms:
            raise _fail("success", "needs an info_key, bounds, full_horizon or tracking_rms")
        object.__setattr__(self, "limits", self._check_ranges("limits", self.limits, False))
        object.__setattr__(
            self, "termination", self._check_ranges("termination", self.termination, True)
        )
        for key in ("trial_steps", "eval_steps"):
            v = getattr(self, key)
            if v is not None and (not isinstance(v, int) or isinstance(v, bool) or v < 1):
                raise _fail(key, f"expected a positive integer number of steps, got {v!r}")
        self._check_eval_init()
        self._check_arm()
        self._check_state_from()
        if self.env_reset_options is not None and not isinstance(self.env_reset_options, Mapping):
            raise _fail("env_reset_options", f"expected a mapping, got {self.env_reset_options!r}")

    def _check_state_from(self) -> None:
        """``state_from``: one :class:`StateReader` per state (a mapping from a task file is
        parsed), each with an entry (``index``, or both ``cos`` and ``sin``) and a finite
        nonzero ``scale`` and finite ``offset``; not together with ``obs_indices``."""
        if self.state_from is None:
            return
        if self.obs_indices is not None:
            raise _fail("state_from", "give obs_indices or state_from, not both")
        if not isinstance(self.state_from, Mapping):
            got = repr(self.state_from)
            raise _fail("state_from", f"expected a mapping state name -> reader, got {got}")
        readers = {}
        for key, r in self.state_from.items():
            path = f"state_from.{key}"
            if key not in self.state_names:
                raise _fail(path, f"unknown state name (states: {self.state_names})")
            readers[str(key)] = _parse_reader(r, path)
        for name in self.state_names:
            if name not in readers:
                raise _fail(
                    f"state_from.{name}",
                    "missing: with state_from every state needs its reader (index, or cos and sin)",
                )
        object.__setattr__(self, "state_from", readers)

    def _check_ranges(self, key: str, ranges: Any, angles: bool) -> dict[str, tuple[float, float]]:
        """``limits`` or ``termination`` (``key``): known state names (an angle only where
        ``angles``), each with finite ``lo < hi``; returned as a plain dict."""
        if not isinstance(ranges, Mapping):
            raise _fail(key, f"expected a mapping state name -> [lo, hi], got {ranges!r}")
        out = {}
        for name, lim in ranges.items():
            if name not in self.state_names:
                raise _fail(f"{key}.{name}", f"unknown state name (states: {self.state_names})")
            if name in self.angles and not angles:
                raise _fail(f"{key}.{name}", "an angle wraps around and has no limits")
            ok = isinstance(lim, Sequence) and not isinstance(lim, str) and len(lim) == 2
            if not ok or not all(_is_number(v) for v in lim):
                raise _fail(f"{key}.{name}", f"needs [lo, hi], got {lim!r}")
            lo, hi = float(lim[0]), float(lim[1])
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise _fail(f"{key}.{name}", f"needs finite lo < hi, got [{lo}, {hi}]")
            out[str(name)] = (lo, hi)
        return out

    def _check_eval_init(self) -> None:
        """``eval_init``: env state entry names, each with finite ``lo <= hi`` (equal: a
        fixed value); stored as a plain dict."""
        if self.eval_init is None:
            return
        if not isinstance(self.eval_init, Mapping) or not self.eval_init:
            got = repr(self.eval_init)
            raise _fail("eval_init", f"expected a mapping env state entry -> [lo, hi], got {got}")
        out = {}
        for name, lim in self.eval_init.items():
            ok = isinstance(lim, Sequence) and not isinstance(lim, str) and len(lim) == 2
            if not ok or not all(_is_number(v) for v in lim):
                raise _fail(f"eval_init.{name}", f"needs [lo, hi], got {lim!r}")
            lo, hi = float(lim[0]), float(lim[1])
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise _fail(f"eval_init.{name}", f"needs finite lo <= hi, got [{lo}, {hi}]")
            out[str(name)] = (lo, hi)
        object.__setattr__(self, "eval_init", out)

    def sample_eval_init(self, rng: np.random.Generator) -> dict[str, float] | None:
        """One draw of ``eval_init`` (entry -> ``v ~ U(lo, hi)``, in the file's order), or
        None without it."""
        if self.eval_init is None:
            return None
        return {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in self.eval_init.items()}

    def _check_arm(self) -> None:
        """The arm fields (module glossary); errors name the field."""
        names = self.state_names
        joints = tuple(str(j) for j in self.joints)
        positions = dict(self.pairs)
        for i, j in enumerate(joints):
            if j not in positions:
                raise _fail(
                    f"joints[{i}]",
                    f"{j!r} is not the position of a pair (pairs: {list(self.pairs)})",
                )
            if joints.index(j) != i:
                raise _fail(f"joints[{i}]", f"{j!r} listed twice")
        object.__setattr__(self, "joints", joints)
        if self.joint_types is not None:
            jt = str(self.joint_types).upper()
            if len(jt) != len(joints) or set(jt) - {"R", "P"}:
                raise _fail(
                    "joint_types",
                    f"needs one letter R or P per joint ({len(joints)}), got {self.joint_types!r}",
                )
            object.__setattr__(self, "joint_types", jt)
        if joints and self.action_dim != len(joints):
            raise _fail(
                "joints",
                f"{len(joints)} joints but {self.action_dim} actions (one torque per joint)",
            )
        affine = tuple(str(a) for a in self.affine_inputs)
        arm = {positions[j] for j in joints}
        for i, a in enumerate(affine):
            if a not in names or a in arm or affine.index(a) != i:
                raise _fail(
                    f"affine_inputs[{i}]",
                    f"needs a state name listed once and no joint velocity, got {a!r}",
                )
        if affine and not joints:
            raise _fail("affine_inputs", "needs joints")
        object.__setattr__(self, "affine_inputs", affine)
        if self.reference is not None:
            object.__setattr__(self, "reference", _check_reference(self))

    @property
    def joint_velocities(self) -> tuple[str, ...]:
        """The velocity paired with each joint position."""
        positions = dict(self.pairs)
        return tuple(positions[j] for j in self.joints)

    @property
    def joint_type_string(self) -> str:
        """``joint_types``, or ``R`` per joint when not given."""
        return self.joint_types if self.joint_types is not None else "R" * len(self.joints)

    # ------------------------------------------------------------------ derived layout
    @property
    def state_dim(self) -> int:
        return len(self.state_names)

    @property
    def action_dim(self) -> int:
        return len(self.action_low)

    def index(self, name: str) -> int:
        """Position of state ``name``."""
        return self.state_names.index(name)

    @property
    def angle_idx(self) -> tuple[int, ...]:
        return tuple(self.index(a) for a in self.angles)

    @property
    def plain_idx(self) -> tuple[int, ...]:
        """Coordinates that enter the features as they are (not angles), in state order."""
        return tuple(i for i, n in enumerate(self.state_names) if n not in self.angles)

    @property
    def integrated_pairs(self) -> tuple[tuple[str, str], ...]:
        """The pairs whose position is integrated, eq. (5.9): all of them, or none without
        ``speed_integration``."""
        return self.pairs if self.speed_integration else ()

    @property
    def position_idx(self) -> tuple[int, ...]:
        """Positions of the integrated pairs."""
        return tuple(self.index(p) for p, _ in self.integrated_pairs)

    @property
    def velocity_idx(self) -> tuple[int, ...]:
        """Velocities of the integrated pairs."""
        return tuple(self.index(v) for _, v in self.integrated_pairs)

    @property
    def delta_idx(self) -> tuple[int, ...]:
        """Coordinates in no pair and no known oscillator: each predicted as its own change
        ``Delta x_j``."""
        taken = set(self.position_idx) | set(self.velocity_idx)
        taken |= {i for p, v, _, _ in self.oscillators for i in (p, v)}
        return tuple(i for i in range(self.state_dim) if i not in taken)

    @property
    def oscillators(self) -> tuple[tuple[int, int, float, float], ...]:
        """``(index of q_r,b, index of qd_r,b, w_b, c_b)`` per joint of a reference that names
        its ``states`` (module glossary), else ()."""
        ref = self.reference
        if ref is None or not ref.get("states"):
            return ()
        return tuple(
            (self.index(p), self.index(v), float(w[0]), float(c))
            for (p, v), w, c in zip(ref["states"], ref["omegas"], ref["centre"], strict=True)
        )

    def reference_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """``(q_r(t), qd_r(t))`` (one entry per joint) of the task's reference."""
        ref = self.reference
        if ref is None:
            raise ValueError(f"{self.env_id}: the task has no reference")
        amp, om, ph = (np.asarray(ref[k]) for k in ("amplitudes", "omegas", "phases"))
        arg = om * t + ph
        q = np.asarray(ref["centre"]) + np.sum(amp * np.sin(arg), axis=-1)
        return q, np.sum(amp * om * np.cos(arg), axis=-1)

    @property
    def output_idx(self) -> tuple[int, ...]:
        """The coordinates whose change the GP predicts: the pairs' velocities, then the
        unpaired coordinates."""
        return self.velocity_idx + self.delta_idx

    @property
    def feature_dim(self) -> int:
        return len(self.plain_idx) + 2 * len(self.angles)

    def feature_names(self) -> list[str]:
        """Names of ``f(x)``: plain coordinates, then ``sin_a, cos_a`` per angle ``a``."""
        plain = [self.state_names[i] for i in self.plain_idx]
        return plain + [f"{p}_{a}" for a in self.angles for p in ("sin", "cos")]

    def gp_input_names(self) -> list[str]:
        return self.feature_names() + [f"u{j}" for j in range(self.action_dim)]

    def gp_output_names(self) -> list[str]:
        return [f"delta_{self.state_names[i]}" for i in self.output_idx]

    def features(self, x: np.ndarray) -> np.ndarray:
        """``f(x)`` in numpy (the torch version is :mod:`mcpilco.agents.mc_pilco.features`)."""
        x = np.asarray(x, dtype=np.float64)
        ang = x[..., list(self.angle_idx)]
        parts = [x[..., list(self.plain_idx)]]
        if self.angles:
            parts.append(np.stack([np.sin(ang), np.cos(ang)], axis=-1).reshape(*x.shape[:-1], -1))
        return np.concatenate(parts, axis=-1)

    # ------------------------------------------------------------------ the env side
    def state_from_obs(self, obs: np.ndarray, info: Mapping[str, Any] | None = None) -> np.ndarray:
        """The state read from an observation (``obs[obs_indices]``, ``obs``, or the derived
        states of ``state_from``; those that read ``info`` need the step's ``info``)."""
        obs = np.asarray(obs, dtype=np.float64)
        if self.state_from is not None:
            readers = self.state_from
            return np.stack([self._read(n, readers[n], obs, info) for n in self.state_names], -1)
        state = obs if self.obs_indices is None else obs[..., list(self.obs_indices)]
        if state.shape[-1] != self.state_dim:
            raise ValueError(
                f"{self.env_id}: the observation has {obs.shape[-1]} entries but the task has "
                f"{self.state_dim} states and no obs_indices"
            )
        return state

    def _read(
        self, name: str, r: StateReader, obs: np.ndarray, info: Mapping[str, Any] | None
    ) -> np.ndarray:
        """State ``name`` by its reader ``r`` (module glossary, derived states)."""
        path = f"state_from.{name}"
        if r.info is None:
            src = obs
        else:
            if info is None or r.info not in info:
                raise _fail(f"{path}.info", f"the env's info has no {r.info!r}")
            src = np.asarray(info[r.info], dtype=np.float64)
        cols = {}
        for key, entry in r.entries():
            j = self._entry_index(path, key, entry, r.info)
            if j >= src.shape[-1]:
                where = "observation" if r.info is None else f"info[{r.info!r}]"
                raise _fail(
                    f"{path}.{key}",
                    f"entry {j} is beyond the {where}'s {src.shape[-1]} entries: this state is "
                    "not observed",
                )
            cols[key] = src[..., j]
        v = cols["index"] if r.index is not None else np.arctan2(cols["sin"], cols["cos"])
        return r.scale * v + r.offset

    def _entry_index(self, path: str, key: str, entry: int | str, source: str | None) -> int:
        """The position of a reader's ``entry``: an index as it is, a name looked up in the
        entry names :meth:`check_env` read from the env."""
        if not isinstance(entry, str):
            return int(entry)
        names = self._entry_names.get(source or "obs")
        attr = "observation_names" if source is None else f"{source}_names"
        if names is None:
            raise _fail(
                f"{path}.{key}",
                f"{entry!r} is a name, but the env names no entries (no attribute {attr}); "
                "give an index",
            )
        if entry not in names:
            raise _fail(f"{path}.{key}", f"unknown entry {entry!r} (the env's {attr}: {names})")
        return names.index(entry)

    def true_state(self, obs: np.ndarray, info: Mapping[str, Any]) -> np.ndarray:
        """The state used for evaluation: ``info[true_state_key]`` or the observed state."""
        if self.true_state_key is not None and self.true_state_key in info:
            return np.asarray(info[self.true_state_key], dtype=np.float64)
        return self.state_from_obs(obs, info)

    def check_env(self, env: Any) -> None:
        """Raise :class:`TaskSpecError` when the env's spaces do not fit the task: an action
        space that is not a flat Box, a state beyond the observation (or an entry name the
        env does not have), actions or a control period that differ. Reads the env's entry
        names for the derived states (``state_from``)."""
        from gymnasium.spaces import Box

        obs_shape = getattr(env.observation_space, "shape", None)
        act_shape = getattr(env.action_space, "shape", None)
        if not isinstance(env.action_space, Box):
            raise _fail(
                "action_low",
                f"{self.env_id}'s action space is {env.action_space}, not a Box: MC-PILCO's "
                "policy outputs continuous actions",
            )
        if obs_shape is None or len(obs_shape) != 1:
            raise _fail("env_id", f"{self.env_id} needs a flat Box observation, got {obs_shape}")
        if act_shape is None or len(act_shape) != 1:
            raise _fail("env_id", f"{self.env_id} needs a flat Box action space, got {act_shape}")
        n_obs = obs_shape[0]
        if self.obs_indices is None and self.state_from is None and n_obs != self.state_dim:
            raise _fail(
                "state_names",
                f"{self.state_dim} states but {self.env_id} observes {n_obs} values; "
                "set obs_indices or state_from",
            )
        for i, j in enumerate(self.obs_indices or ()):
            if j >= n_obs:
                raise _fail(
                    f"obs_indices[{i}]",
                    f"index {j} out of range for {n_obs} observations: this state is not observed",
                )
        if self.state_from is not None:
            base = getattr(env, "unwrapped", env)
            names = {}
            for src in {r.info for r in self.state_from.values()}:
                attr = "observation_names" if src is None else f"{src}_names"
                if getattr(base, attr, None) is not None:
                    names[src or "obs"] = tuple(str(n) for n in getattr(base, attr))
            self._entry_names.clear()
            self._entry_names.update(names)
            for name, r in self.state_from.items():
                for key, entry in r.entries():
                    j = self._entry_index(f"state_from.{name}", key, entry, r.info)
                    if r.info is None and j >= n_obs:
                        raise _fail(
                            f"state_from.{name}.{key}",
                            f"entry {j} is beyond the observation's {n_obs} entries: this "
                            "state is not observed",
                        )
        env_dt = getattr(getattr(env, "unwrapped", env), "dt", None)
        if self.action_repeat > 1 and env_dt is not None:
            if abs(float(env_dt) * self.action_repeat - self.dt) > 1e-9:
                raise _fail(
                    "dt",
                    f"{self.dt} s is not action_repeat ({self.action_repeat}) x the env's "
                    f"step ({env_dt} s)",
                )
        n_joints = getattr(getattr(env, "unwrapped", env), "n_joints", None)
        if self.joints and n_joints is not None and int(n_joints) != len(self.joints):
            raise _fail(
                "joints",
                f"{len(self.joints)} joints {list(self.joints)} but {self.env_id} has {n_joints}",
            )
        if act_shape[0] != self.action_dim:
            raise _fail(
                "action_low",
                f"{self.action_dim} actions but {self.env_id} takes {act_shape[0]}",
            )
        low, high = np.asarray(env.action_space.low), np.asarray(env.action_space.high)
        if np.any(np.asarray(self.action_low) < low - 1e-9) or np.any(
            np.asarray(self.action_high) > high + 1e-9
        ):
            raise _fail(
                "action_low",
                f"bounds {self.action_low}..{self.action_high} exceed the env's "
                f"{low.tolist()}..{high.tolist()}",
            )

    def reset_options(self) -> dict[str, Any] | None:
        """``options`` of ``env.reset``: ``env_reset_options``, and ``{"reference":
        SumOfSinusoids}`` for a task with a reference
        (:class:`mcpilco.envs.arm_env.SumOfSinusoids`); None when neither is given."""
        options = dict(self.env_reset_options) if self.env_reset_options is not None else None
        if self.reference is None:
            return options
        from mcpilco.envs.arm_env import SumOfSinusoids

        ref = self.reference
        arrays = (np.asarray(ref[k], dtype=np.float64) for k in REFERENCE_KEYS[:4])
        reference = SumOfSinusoids(*arrays, duration=float(ref["duration"]))
        return {**(options or {}), "reference": reference}

    def check_reset(self, env: Any, samples: int = RESET_SAMPLES, seed: int = 0) -> None:
        """Refuse, before any trial, a task that cannot be learned as declared, from
        ``samples`` resets of ``env`` (seeds ``seed, seed + 1, ...``): every state must be
        readable from a reset's observation and ``info`` (the derived states), and when
        every sampled initial state already lies in the success set (``success.bounds``)
        of a task judged at the episode's end (a ``window``, no ``full_horizon``), there is
        nothing to learn. A balance task, whose success asks to stay in the set for the
        whole episode, starts inside it by design.

        Raises:
            TaskSpecError: naming the field.
        """
        starts = []
        for k in range(samples):
            obs, info = env.reset(seed=seed + k, options=self.reset_options())
            self.state_from_obs(obs, info)
            starts.append(self.true_state(obs, info))
        if all(self.starts_in_goal(x0) for x0 in starts):
            raise _fail(
                "success.bounds",
                f"all {samples} sampled resets of {self.env_id} already lie in the success set: "
                "nothing to learn as declared (narrow the bounds, check their targets, or for "
                "a balance task set success.full_horizon: true)",
            )

    # ------------------------------------------------------------------ evaluation
    def cost(self, x: np.ndarray) -> np.ndarray:
        """The evaluation cost ``c(x)`` (module glossary) in numpy, ``(..., n) -> (...)``."""
        x = np.asarray(x, dtype=np.float64)
        if not self.cost_terms:
            import torch

            with torch.no_grad():
                return self.cost_fn(torch.as_tensor(x)).numpy()
        s = np.zeros(x.shape[:-1])
        for t in self.cost_terms:
            v = x[..., self.index(t.state)]
            if t.reference is not None:
                v = v - x[..., self.index(t.reference)]
            s = s + (self.distance(t.state, v, t.target, t.angle_mode) / t.length_scale) ** 2
        return 1.0 - np.exp(-s)

    def distance(self, name: str, v: np.ndarray, target: float, mode: str = "wrap") -> np.ndarray:
        """``d(x_j, x*_j)``: plain difference, or for an angle the ``mode`` distance."""
        if name not in self.angles:
            return v - target
        return wrap(v - target) if mode == "wrap" else np.abs(v) - abs(target)

    def tracked_states(self) -> dict[str, str]:
        """State -> the state its cost term tracks (``CostTerm.reference``), for the terms
        that track one (a joint and its reference)."""
        return {t.state: t.reference for t in self.cost_terms if t.reference is not None}

    def tracking_rms(self, states: np.ndarray) -> dict[str, float]:
        """``{state: sqrt(mean_t d_t^2)}`` over an episode's states ``x_1..x_T`` (``states``
        (T+1, n), ``x_0`` left out) for each cost term that tracks a reference state, with
        ``d = x - x_ref`` (wrapped for an angle): the tracking error a controller leaves."""
        x = np.asarray(states, dtype=np.float64)[1:]
        out = {}
        for t in self.cost_terms:
            if t.reference is not None:
                d = x[:, self.index(t.state)] - x[:, self.index(t.reference)]
                if t.state in self.angles:
                    d = wrap(d)
                out[t.state] = float(np.sqrt(np.mean(d**2))) if len(d) else math.nan
        return out

    def touches_limit(self, s: np.ndarray, s1: np.ndarray) -> np.ndarray:
        """Which transitions ``x_t -> x_{t+1}`` (rows of ``s``, ``s1``, shape ``(T, n)``) touch
        a declared limit: ``x_t`` or ``x_{t+1}`` outside ``[lo_j, hi_j]``, or, for the position
        of a pair, the free motion ``x_t + T_s xdot_t`` outside it (the stop was reached
        during the step and stopped the coordinate short). Returns a ``(T,)`` bool array."""
        s, s1 = np.atleast_2d(s), np.atleast_2d(s1)
        hit = np.zeros(len(s), dtype=bool)
        velocity = dict(self.pairs)
        for name, (lo, hi) in self.limits.items():
            j = self.index(name)
            cols = [s[:, j], s1[:, j]]
            if name in velocity:
                cols.append(s[:, j] + self.dt * s[:, self.index(velocity[name])])
            for v in cols:
                hit |= (v < lo) | (v > hi)
        return hit

    @property
    def steps_per_trial(self) -> int:
        """Control steps of experience each trial collects (``trial_steps``, else the
        horizon)."""
        return int(self.horizon if self.trial_steps is None else self.trial_steps)

    def terminated(self, states: np.ndarray) -> np.ndarray:
        """Per state ``(..., n)``, whether it lies outside the ``termination`` ranges (an
        angle by its wrapped value); all False without them."""
        states = np.asarray(states, dtype=np.float64)
        out = np.zeros(states.shape[:-1], dtype=bool)
        for name, (lo, hi) in self.termination.items():
            v = states[..., self.index(name)]
            v = wrap(v) if name in self.angles else v
            out |= (v < lo) | (v > hi)
        return out

    def in_goal(self, states: np.ndarray) -> np.ndarray:
        """Per state, whether every success bound holds (all True without bounds)."""
        states = np.asarray(states, dtype=np.float64)
        ok = np.ones(states.shape[:-1], dtype=bool)
        for name, b in self.success.bounds.items():
            d = self.distance(name, states[..., self.index(name)], b.target)
            ok &= np.abs(d) <= b.tol
        return ok

    def starts_in_goal(self, x0: np.ndarray) -> bool:
        """Whether an episode starting at ``x0`` starts where it should end: the success is
        judged by ``success.bounds`` over the last ``window`` steps (a swing-up, not a balance
        task's whole episode) and ``x0`` already lies within them. Such an episode's success
        is not a success of the policy (an env that resets at a random angle sometimes starts
        upright)."""
        s = self.success
        if not s.bounds or s.window is None or s.full_horizon:
            return False
        return bool(self.in_goal(np.asarray(x0, dtype=np.float64)))

    def is_success(
        self,
        states: np.ndarray,
        last_info: Mapping[str, Any],
        steps: int,
        planned: int | None = None,
    ) -> bool:
        """Success of one episode from its true states after each step ``(T, n)``, the last
        ``info``, the number of steps taken and the number ``planned`` (None: the horizon;
        an evaluation episode of the env's own length plans more). A ``full_horizon`` task
        fails an episode that ended before its planned length."""
        s = self.success
        if s.info_key is not None and s.info_key in last_info:
            return bool(last_info[s.info_key])
        if s.full_horizon and steps < (self.horizon if planned is None else int(planned)):
            return False
        states = np.asarray(states, dtype=np.float64)
        if s.tracking_rms:
            rms = self.tracking_rms(np.concatenate([states[:1], states]))  # x_0 is left out
            if any(rms[k] > bound for k, bound in s.tracking_rms.items()):
                return False
            if not s.bounds:
                return True
        window = states if s.window is None else states[-int(s.window) :]
        if s.window is not None and len(states) < int(s.window):
            return False
        return bool(np.all(self.in_goal(window)))

    # ------------------------------------------------------------------ construction
    def replace(self, **changes: Any) -> TaskSpec:
        """A validated copy with ``changes``."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> TaskSpec:
        """A spec from plain data (the YAML task files' format). Unknown keys are errors."""
        if not isinstance(d, Mapping):
            raise TaskSpecError(f"task: expected a mapping, got {type(d).__name__}")
        d = dict(d)
        known = {f.name for f in dataclasses.fields(cls)} | {"cost"}
        for key in d:
            if key not in known:
                raise _fail(str(key), f"unknown field (fields: {sorted(known)})")
        for key in ("env_id", "state_names", "action_low", "action_high", "dt", "horizon"):
            if key not in d:
                raise _fail(key, "is required")
        _check_types(d)
        _check_numbers(d)
        cost = d.pop("cost", None) or {}
        if not isinstance(cost, Mapping):
            raise _fail("cost", "expected a mapping with 'terms'")
        terms = [_parse_term(t, f"cost.terms[{i}]") for i, t in enumerate(cost.get("terms", []))]
        success = d.pop("success", None) or {}
        if isinstance(success, Mapping):
            bounds = {}
            for key, b in (success.get("bounds") or {}).items():
                if not isinstance(b, Mapping) or "tol" not in b:
                    raise _fail(f"success.bounds.{key}", "needs {target, tol}")
                bounds[str(key)] = Bound(float(b.get("target", 0.0)), float(b["tol"]))
            success = SuccessSpec(
                info_key=success.get("info_key"),
                window=success.get("window"),
                bounds=bounds,
                full_horizon=bool(success.get("full_horizon", False)),
                tracking_rms={str(k): v for k, v in (success.get("tracking_rms") or {}).items()},
            )
        pairs = d.pop("pairs", ()) or ()
        if not isinstance(pairs, Sequence) or isinstance(pairs, str):
            raise _fail("pairs", "expected a list of [position, velocity]")
        return cls(
            **d,
            pairs=tuple(
                tuple(p) if isinstance(p, Sequence) and not isinstance(p, str) else p for p in pairs
            ),  # fmt: skip
            cost_terms=tuple(terms),
            success=success,
        )

    @classmethod
    def from_yaml(cls, path: str | Path) -> TaskSpec:
        """A spec from a YAML task file (:func:`~mcpilco.envs.yaml_files.read_yaml`: an
        empty file is an error)."""
        from mcpilco.envs.yaml_files import read_yaml

        return cls.from_dict(read_yaml(path, "task file"))

    @classmethod
    def for_env(cls, env_id: str) -> TaskSpec:
        """The spec that ships for a registered env (:mod:`mcpilco.envs.tasks`)."""
        from mcpilco.envs.tasks import task_data

        try:
            return cls.from_dict(task_data(env_id))
        except KeyError as err:
            raise ValueError(err.args[0]) from None


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


TASK_NUMBER_RANGES: dict[str, dict[str, Any]] = {
    "dt": {"lo": 0.0, "hi": 3600.0, "lo_open": True},
    "horizon": {"lo": 1, "hi": 10_000_000, "integer": True},
    "action_repeat": {"lo": 1, "hi": 10_000, "integer": True},
    "action_low": {"lo": -1e9, "hi": 1e9},
    "action_high": {"lo": -1e9, "hi": 1e9},
    "init_mean": {"lo": -1e9, "hi": 1e9},
    "init_std": {"lo": 0.0, "hi": 1e6},
    "obs_indices": {"lo": 0, "hi": 1_000_000, "integer": True},
    "cost.terms.target": {"lo": -1e9, "hi": 1e9},
    "cost.terms.length_scale": {"lo": 1e-9, "hi": 1e9},
    "success.window": {"lo": 1, "hi": 10_000_000, "integer": True},
    "success.bounds.target": {"lo": -1e9, "hi": 1e9},
    "success.bounds.tol": {"lo": 0.0, "hi": 1e9, "lo_open": True},
    "success.tracking_rms": {"lo": 0.0, "hi": 1e9, "lo_open": True},
    "limits": {"lo": -1e9, "hi": 1e9},
    "trial_steps": {"lo": 1, "hi": 10_000_000, "integer": True},
    "eval_steps": {"lo": 1, "hi": 10_000_000, "integer": True},
}
"""Range of each number of a task file (a list's entries each): a control period of at most
an hour, magnitudes of at most 1e9, length scales in [1e-9, 1e9] (a smaller one underflows
``d^2 / l^2`` to inf; :func:`mcpilco.envs.numbers.check_number`)."""


def _check_numbers(d: Mapping[str, Any]) -> None:
    """Every number of the plain task data ``d`` finite and within
    :data:`TASK_NUMBER_RANGES` (entries of lists each; the error names the field, e.g.
    ``task.cost.terms[0].length_scale``); a string or a boolean where a number belongs is
    refused as well."""
    from mcpilco.envs.numbers import check_number

    def check(value: Any, path: str, rule: str) -> None:
        items = (
            list(enumerate(value))
            if isinstance(value, Sequence) and not isinstance(value, str)
            else [(None, value)]
        )
        for i, v in items:
            where = path if i is None else f"{path}[{i}]"
            try:
                check_number(v, f"task.{where}", **TASK_NUMBER_RANGES[rule])
            except ValueError as err:
                raise TaskSpecError(str(err)) from None

    for key in ("dt", "horizon", "action_repeat", "action_low", "action_high", "init_mean"):
        if key in d:
            check(d[key], key, key)
    for key in ("init_std", "obs_indices"):
        if d.get(key) is not None:
            check(d[key], key, key)
    cost = d.get("cost")
    terms = cost.get("terms") if isinstance(cost, Mapping) else None
    for i, t in enumerate(terms if isinstance(terms, list) else []):
        for key in ("target", "length_scale"):
            if isinstance(t, Mapping) and key in t:
                check(t[key], f"cost.terms[{i}].{key}", f"cost.terms.{key}")
    success = d.get("success")
    if isinstance(success, Mapping):
        if success.get("window") is not None:
            check(success["window"], "success.window", "success.window")
        for name, b in (
            (success.get("bounds") or {}).items()
            if isinstance(success.get("bounds"), Mapping)
            else ()
        ):
            for key in ("target", "tol"):
                if isinstance(b, Mapping) and key in b:
                    check(b[key], f"success.bounds.{name}.{key}", f"success.bounds.{key}")
        rms = success.get("tracking_rms")
        for name, v in rms.items() if isinstance(rms, Mapping) else ():
            check(v, f"success.tracking_rms.{name}", "success.tracking_rms")
    for key in ("limits", "termination"):
        ranges = d.get(key)
        for name, v in ranges.items() if isinstance(ranges, Mapping) else ():
            check(v, f"{key}.{name}", "limits")
    for key in ("trial_steps", "eval_steps"):
        if d.get(key) is not None:
            check(d[key], key, key)
    init = d.get("eval_init")
    for name, v in init.items() if isinstance(init, Mapping) else ():
        check(v, f"eval_init.{name}", "limits")


def _check_types(d: Mapping[str, Any]) -> None:
    """The plain-data types of a task file's fields, each error naming its field."""

    def seq(key: str, item, what: str, allow_none: bool = False) -> None:
        v = d.get(key)
        if v is None and (allow_none or key not in d):
            return
        if isinstance(v, str) or not isinstance(v, Sequence) or not all(item(e) for e in v):
            raise _fail(key, f"expected a list of {what}, got {v!r}")

    seq("state_names", lambda e: isinstance(e, str) and e != "", "non-empty names")
    seq("angles", lambda e: isinstance(e, str), "state names")
    seq("joints", lambda e: isinstance(e, str), "state names")
    seq("affine_inputs", lambda e: isinstance(e, str), "state names")
    if d.get("reference") is not None and not isinstance(d["reference"], Mapping):
        raise _fail("reference", f"expected a mapping, got {d['reference']!r}")
    seq("action_low", _is_number, "numbers")
    seq("action_high", _is_number, "numbers")
    seq("init_mean", _is_number, "numbers", allow_none=True)
    seq("obs_indices", lambda e: isinstance(e, int) and not isinstance(e, bool), "integers", True)
    seq(
        "pairs",
        lambda e: isinstance(e, Sequence) and not isinstance(e, str),
        "[position, velocity]",
    )
    if not _is_number(d["dt"]):
        raise _fail("dt", f"expected a number of seconds, got {d['dt']!r}")
    if not isinstance(d["horizon"], int) or isinstance(d["horizon"], bool):
        raise _fail("horizon", f"expected an integer number of steps, got {d['horizon']!r}")
    std = d.get("init_std", 0.01)
    if not _is_number(std):
        seq("init_std", _is_number, "numbers")
    if not isinstance(d.get("success") or {}, Mapping):
        raise _fail("success", f"expected a mapping, got {d['success']!r}")


def _parse_reader(r: Any, path: str) -> StateReader:
    """A ``state_from`` entry (:class:`StateReader`, or its mapping in a task file)."""
    if isinstance(r, Mapping):
        extra = set(r) - set(READER_KEYS)
        if extra:
            raise _fail(path, f"unknown keys {sorted(extra)} (keys: {READER_KEYS})")
        r = StateReader(**{str(k): v for k, v in r.items()})
    if not isinstance(r, StateReader):
        raise _fail(path, f"expected a mapping {{index}} or {{cos, sin}}, got {r!r}")
    has_pair = (r.cos is not None, r.sin is not None)
    if r.index is not None and any(has_pair):
        raise _fail(path, "give index, or cos and sin, not both")
    if r.index is None and not all(has_pair):
        missing = "sin" if r.cos is not None else "cos" if r.sin is not None else "index"
        raise _fail(
            f"{path}.{missing}",
            "missing: a state needs an index, or an angle both its cos and its sin entries",
        )
    for key, entry in r.entries():
        is_index = isinstance(entry, int) and not isinstance(entry, bool)
        if not (is_index and entry >= 0) and not (isinstance(entry, str) and entry):
            raise _fail(f"{path}.{key}", f"needs an index >= 0 or an entry name, got {entry!r}")
    for key in ("scale", "offset"):
        v = getattr(r, key)
        if not (_is_number(v) and math.isfinite(v)) or (key == "scale" and v == 0):
            want = "a finite number != 0" if key == "scale" else "a finite number"
            raise _fail(f"{path}.{key}", f"needs {want}, got {v!r}")
    if r.info is not None and not (isinstance(r.info, str) and r.info):
        raise _fail(f"{path}.info", f"needs an info key, got {r.info!r}")
    return dataclasses.replace(r, scale=float(r.scale), offset=float(r.offset))


def _parse_term(t: Any, path: str) -> CostTerm:
    if not isinstance(t, Mapping) or "state" not in t:
        raise _fail(path, f"needs {{state, target, length_scale}}, got {t!r}")
    extra = set(t) - {"state", "target", "length_scale", "angle_mode", "reference"}
    if extra:
        raise _fail(path, f"unknown keys {sorted(extra)}")
    try:
        return CostTerm(
            state=str(t["state"]),
            target=float(t.get("target", 0.0)),
            length_scale=float(t.get("length_scale", 1.0)),
            angle_mode=str(t.get("angle_mode", "wrap")),
            reference=None if t.get("reference") is None else str(t["reference"]),
        )
    except (TypeError, ValueError) as err:
        raise _fail(path, str(err)) from None


REFERENCE_KEYS = ("centre", "amplitudes", "omegas", "phases", "duration")
"""Required fields of a task's sum-of-sinusoids joint reference (module glossary); ``states``
is optional."""

REFERENCE_STATE_TOL = 1e-6
"""Largest ``|mu_0 - r(0)|`` [rad, rad/s] allowed for the initial mean of a reference state
propagated as an oscillator (it starts on the reference)."""


def _check_reference(task: TaskSpec) -> dict[str, Any]:
    """The task's reference as plain data: ``centre`` (n,), ``amplitudes``, ``omegas``,
    ``phases`` (n, K) and ``duration`` [s] of at least the horizon ``H T_s``."""
    ref = task.reference
    if not isinstance(ref, Mapping):
        raise _fail("reference", f"expected a mapping, got {ref!r}")
    unknown = set(ref) - set(REFERENCE_KEYS) - {"states"}
    if unknown:
        raise _fail(
            f"reference.{sorted(unknown)[0]}",
            f"unknown key (keys: {REFERENCE_KEYS + ('states',)})",
        )
    n = len(task.joints)
    if not n:
        raise _fail("reference", "needs joints (the reference has one entry per joint)")
    out: dict[str, Any] = {}
    for key in REFERENCE_KEYS:
        if key not in ref:
            raise _fail(f"reference.{key}", "is required")
        try:
            v = np.asarray(ref[key], dtype=np.float64)
        except (TypeError, ValueError):
            raise _fail(f"reference.{key}", f"expected numbers, got {ref[key]!r}") from None
        if not np.all(np.isfinite(v)):
            raise _fail(f"reference.{key}", f"needs finite values, got {ref[key]!r}")
        out[key] = v
    if out["centre"].shape != (n,):
        raise _fail("reference.centre", f"needs {n} values (one per joint)")
    shape = out["amplitudes"].reshape(n, -1).shape if out["amplitudes"].size % n == 0 else None
    for key in ("amplitudes", "omegas", "phases"):
        if shape is None or out[key].size != shape[0] * shape[1]:
            raise _fail(f"reference.{key}", f"needs {n} rows (one per joint) of K sinusoids")
        out[key] = out[key].reshape(shape).tolist()
    out["centre"] = out["centre"].tolist()
    duration = float(out["duration"])
    if duration < task.horizon * task.dt - 1e-9:
        raise _fail(
            "reference.duration",
            f"{duration} s is shorter than the horizon ({task.horizon} steps x {task.dt} s = "
            f"{task.horizon * task.dt:g} s)",
        )
    out["duration"] = duration
    if ref.get("states") is not None:
        out["states"] = _check_reference_states(task, ref["states"], out)
    return out


def _check_reference_states(task: TaskSpec, states: Any, ref: Mapping[str, Any]) -> list[list[str]]:
    """``reference.states``: one ``[q_r, qd_r]`` pair of state names per joint, states in no
    speed-integration pair, one sinusoid per joint, and the initial mean on the reference."""
    n, names = len(task.joints), task.state_names
    if isinstance(states, str) or not isinstance(states, Sequence) or len(states) != n:
        raise _fail("reference.states", f"needs {n} [position, velocity] pairs (one per joint)")
    paired = {name for pair in task.pairs for name in pair}
    seen: set[str] = set()
    out = []
    for i, pair in enumerate(states):
        if isinstance(pair, str) or not isinstance(pair, Sequence) or len(pair) != 2:
            raise _fail(f"reference.states[{i}]", f"needs [position, velocity], got {pair!r}")
        for name in pair:
            if name not in names:
                raise _fail(f"reference.states[{i}]", f"unknown state name {name!r}")
            if name in paired:
                raise _fail(
                    f"reference.states[{i}]",
                    f"{name!r} is in pairs: a known reference state takes no GP output",
                )
            if name in seen:
                raise _fail(f"reference.states[{i}]", f"{name!r} listed twice")
            seen.add(name)
        out.append([str(pair[0]), str(pair[1])])
    if any(len(row) != 1 for row in ref["amplitudes"]):
        raise _fail(
            "reference.states",
            "needs one sinusoid per joint: with several, (q_r, qd_r) alone is not a state "
            "that determines the reference's future",
        )
    amp, om, ph = (np.asarray(ref[k]) for k in ("amplitudes", "omegas", "phases"))
    r0 = np.asarray(ref["centre"]) + (amp * np.sin(ph))[:, 0]
    rd0 = (amp * om * np.cos(ph))[:, 0]
    for (p, v), want_p, want_v in zip(out, r0, rd0, strict=True):
        for name, want in ((p, want_p), (v, want_v)):
            got = task.init_mean[task.index(name)]
            if abs(got - want) > REFERENCE_STATE_TOL:
                raise _fail(
                    f"init_mean[{task.index(name)}]",
                    f"{name} starts on the reference: needs {want:.12g}, got {got:.12g}",
                )
    return out
