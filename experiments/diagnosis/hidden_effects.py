"""Robot data with hidden effects: nominal torques of a UR10/SCARA plus injected physics.

The nominal torques are MuJoCo's exact inverse dynamics (``mj_inverse``, armature included)
along random sums of sinusoids faded in and out (they start and end at rest, so the
velocity reverses and crosses zero many times); the hidden effects are added on top, then
Gaussian noise of std ``noise_frac * rms(tau_j)`` per joint. The nominal robot file (MJCF,
no friction) is written next to the data: it is what a user would hold.

Injected effects (``key``, torque added on joint ``j``; shape values drawn at random):

=========  ================================================================================
viscous    ``F_v qd``
coulomb    ``F_c tanh(qd / eps)``, ``eps ~ U(0.005, 0.02)``
stribeck   ``(F_c + (F_s - F_c) exp(-(qd/v_s)^2)) tanh(qd/eps)``, ``F_s/F_c ~ U(2, 4)``,
           ``v_s ~ U(0.03, 0.2)``
offset     ``tau_0`` (random sign)
spring     ``k (q - q_0)``, ``q_0`` uniform in the visited range
cogging    ``A sin(n q + phi)``, ``n ~ U{3..24}``, ``phi ~ U(0, 2 pi)``
armature   ``I_a qdd``
deadzone   ``delta tanh(tau / (c rms tau))``, ``c ~ U(0.01, 0.1)``
delay      ``tau_j(x(t - d))``, ``d = k dt``, ``k ~ U{1..6}`` (integer samples)
payload    a point mass ``m ~ U(0.5, 3)`` kg at a random offset (<= 5 cm) on the last link:
           the torque of the changed robot minus the nominal one (every joint)
=========  ================================================================================

Magnitudes: every effect but delay and payload is scaled so that the rms of its torque is
``snr * sigma_j`` with ``snr ~ U(3, 8)``; delay and payload have physical sizes and are
redrawn until some joint sees at least ``2 sigma_j``.

:func:`make_case` generates a case (:class:`Case`), :func:`write_case` writes it as files:
``train_k``, ``test_k`` (dataset schema of :mod:`mcpilco.models.robot_data`), ``robot.xml``
(the nominal model) and ``truth.json`` (the hidden answer).
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.envs.arm_builder import ArmSpec, LinkInertia, arm_to_xml, inertia_matrix
from mcpilco.envs.arm_data import inverse_dynamics_samples, make_program
from mcpilco.envs.arms import scara, ur10
from mcpilco.models.robot_data import make_dataset, save_dataset

EFFECT_KEYS = (
    "viscous",
    "coulomb",
    "stribeck",
    "offset",
    "spring",
    "cogging",
    "armature",
    "deadzone",
    "delay",
    "payload",
)
"""Effects the generator can inject."""

ROBOTS = {"scara": scara, "ur10": ur10}
"""Robots a case can be made for (factories of :mod:`mcpilco.envs.arms`)."""


@dataclasses.dataclass
class Case:
    """A generated case: training and test arrays, the nominal MJCF and the truth."""

    robot: str
    train: list[dict[str, np.ndarray]]
    test: list[dict[str, np.ndarray]]
    nominal_xml: str
    joint_types: str
    noise_std: np.ndarray
    effects: list[dict[str, Any]]
    seed: int

    def datasets(self, which: str = "train") -> list[Any]:
        """The arrays as validated ``Trajectories`` objects."""
        return [make_dataset(a) for a in getattr(self, which)]

    def truth(self) -> list[str]:
        """Labels ``key:joint`` (``payload``) of the injected effects."""
        return [
            e["key"] if e["joint"] is None else f"{e['key']}:{e['joint']}" for e in self.effects
        ]


def _centre(arm: ArmSpec) -> np.ndarray:
    """Middle of each finite joint range (0 for an unbounded joint)."""
    r = arm.joint_ranges
    c = np.where(np.isfinite(r).all(axis=1), 0.5 * (r[:, 0] + r[:, 1]), 0.0)
    return c


def _reference(arm: ArmSpec, rng: np.random.Generator, duration: float) -> Any:
    """A random faded sum of sinusoids around :func:`_centre` (the program of one file)."""
    kw = dict(amplitude=0.8, speed_fraction=0.3, n_sinusoids=6, omega_range=(0.3, 2.0))
    return make_program(arm, "sinusoids", rng, _centre(arm), duration, sinusoid_kwargs=kw)


def _with_payload(arm: ArmSpec, mass: float, offset: np.ndarray) -> ArmSpec:
    """The arm with a point mass (a 1 cm sphere) ``mass`` at ``offset`` in the last link frame
    (relative to that link's centre of mass); inertia combined by the parallel-axis theorem."""
    link = arm.links[-1]
    c = np.array(link.com)
    p = c + offset
    m_new = link.mass + mass
    c_new = (link.mass * c + mass * p) / m_new

    def shift(m: float, d: np.ndarray) -> np.ndarray:
        return m * (float(d @ d) * np.eye(3) - np.outer(d, d))

    sphere = 0.4 * mass * 0.01**2 * np.eye(3)
    inertia = (
        inertia_matrix(link.inertia) + shift(link.mass, c - c_new) + sphere + shift(mass, p - c_new)
    )
    flat = (
        inertia[0, 0],
        inertia[1, 1],
        inertia[2, 2],
        inertia[0, 1],
        inertia[0, 2],
        inertia[1, 2],
    )
    new_link = LinkInertia(m_new, tuple(c_new.tolist()), tuple(float(v) for v in flat))
    return dataclasses.replace(arm, links=(*arm.links[:-1], new_link))


def _draw_effect(
    key: str, joint: int | None, rng: np.random.Generator, arm: ArmSpec
) -> dict[str, Any]:
    """The specification of effect ``key`` on ``joint`` (random when None; ``payload``: every
    joint) with its shape values drawn from ``rng`` (module docstring)."""
    n = arm.n_joints
    if key == "payload":
        joint = None
    elif joint is None:
        joint = int(rng.integers(1, n + 1))
    spec: dict[str, Any] = {"key": key, "joint": joint, "snr": float(rng.uniform(3.0, 8.0))}
    if key == "coulomb":
        spec["eps"] = float(rng.uniform(0.005, 0.02))
    elif key == "stribeck":
        spec.update(
            eps=float(rng.uniform(0.005, 0.02)),
            ratio=float(rng.uniform(2.0, 4.0)),
            v_s=float(rng.uniform(0.03, 0.2)),
        )
    elif key == "offset":
        spec["sign"] = float(rng.choice([-1.0, 1.0]))
    elif key == "spring":
        spec["u0"] = float(rng.uniform(0.0, 1.0))
    elif key == "cogging":
        spec.update(order=int(rng.integers(3, 25)), phase=float(rng.uniform(0, 2 * math.pi)))
    elif key == "deadzone":
        spec["width"] = float(rng.uniform(0.01, 0.1))
    elif key == "delay":
        spec["samples"] = int(rng.integers(1, 7))
    elif key == "payload":
        spec.update(mass=float(rng.uniform(0.5, 3.0)), offset=rng.uniform(-0.05, 0.05, 3).tolist())
    elif key not in ("viscous", "armature"):
        raise ValueError(f"unknown effect {key!r}; choose from {EFFECT_KEYS}")
    return spec


def _shape(spec: dict[str, Any], d: dict[str, np.ndarray], q_range: np.ndarray) -> np.ndarray:
    """Unit-free shape of a scalable effect on its joint (``(N,)``)."""
    j = spec["joint"] - 1
    q, qd, qdd, tau = d["q"][:, j], d["qd"][:, j], d["qdd"][:, j], d["tau_nominal"][:, j]
    key = spec["key"]
    if key == "viscous":
        return qd
    if key == "coulomb":
        return np.tanh(qd / spec["eps"])
    if key == "stribeck":
        s = np.tanh(qd / spec["eps"])
        return s * (1.0 + (spec["ratio"] - 1.0) * np.exp(-((qd / spec["v_s"]) ** 2)))
    if key == "offset":
        return spec["sign"] * np.ones_like(q)
    if key == "spring":
        q0 = q_range[j, 0] + spec["u0"] * (q_range[j, 1] - q_range[j, 0])
        return q - q0
    if key == "cogging":
        return np.sin(spec["order"] * q + spec["phase"])
    if key == "armature":
        return qdd
    if key == "deadzone":
        rms = float(np.sqrt(np.mean(d["tau_nominal"][:, j] ** 2)))
        return np.tanh(tau / (spec["width"] * rms))
    raise ValueError(key)


def make_case(
    robot: str = "scara",
    effects: Sequence[str] | None = None,
    n_effects: int = 1,
    seed: int = 0,
    n_train: int = 2,
    n_test: int = 1,
    duration: float = 20.0,
    sample_time: float = 0.01,
    noise_frac: float = 0.02,
) -> Case:
    """Generate a case.

    Args:
        robot: ``"scara"`` or ``"ur10"``.
        effects: ``["coulomb:2", "payload", "cogging"]`` (joint random when omitted); ``[]``
            = the control case with no effect; ``None`` = ``n_effects`` random distinct keys.
        seed: seeds everything (trajectories, effects, noise).
        n_train, n_test: number of files (each its own random trajectory).
        duration, sample_time: per file [s].
        noise_frac: noise std of joint ``j`` as a fraction of the rms nominal torque.
    """
    if robot not in ROBOTS:
        raise ValueError(f"robot must be one of {sorted(ROBOTS)}, got {robot!r}")
    rng = np.random.default_rng(seed)
    arm = ROBOTS[robot]().without_friction()
    times = np.arange(0.0, duration, sample_time)
    files = []
    for _ in range(n_train + n_test):
        ref = _reference(arm, rng, duration)
        d = inverse_dynamics_samples(arm, ref, times)
        d["tau_nominal"] = d["tau"].copy()
        d["_ref"] = ref
        files.append(d)
    allq = np.concatenate([f["q"] for f in files])
    q_range = np.stack([allq.min(0), allq.max(0)], axis=1)
    rms = np.sqrt(np.mean(np.concatenate([f["tau"] for f in files]) ** 2, axis=0))
    sigma = noise_frac * rms
    if effects is None:
        keys = rng.choice(EFFECT_KEYS, size=n_effects, replace=False).tolist()
        requested: list[tuple[str, int | None]] = [(k, None) for k in keys]
    else:
        requested = []
        for text in effects:
            parts = text.split(":")
            requested.append((parts[0], int(parts[1]) if len(parts) > 1 else None))
    specs: list[dict[str, Any]] = []
    for key, joint in requested:
        for _attempt in range(20):
            spec = _draw_effect(key, joint, rng, arm)
            if (
                any(s["key"] == spec["key"] and s["joint"] == spec["joint"] for s in specs)
                and joint is None
            ):
                continue
            ok = _inject(spec, files, arm, times, sigma, q_range, dry_run=True)
            if ok or joint is not None:
                break
        specs.append(spec)
        _inject(spec, files, arm, times, sigma, q_range)
    for f in files:
        f["tau"] = f["tau"] + sigma * rng.standard_normal(f["tau"].shape)
    keep = ("t", "q", "qd", "qdd", "tau")
    arrays = [{k: f[k] for k in keep} for f in files]
    return Case(
        robot=robot,
        train=arrays[:n_train],
        test=arrays[n_train:],
        nominal_xml=arm_to_xml(arm, friction=False),
        joint_types=arm.joint_types,
        noise_std=sigma,
        effects=specs,
        seed=seed,
    )


def _inject(
    spec: dict[str, Any],
    files: list[dict[str, Any]],
    arm: ArmSpec,
    times: np.ndarray,
    sigma: np.ndarray,
    q_range: np.ndarray,
    dry_run: bool = False,
) -> bool:
    """Add the effect's torque to every file (``dry_run``: only check it is >= 2 sigma on
    some joint). Scalable effects are sized to ``snr * sigma_j`` over all files."""
    key = spec["key"]
    if key in ("delay", "payload"):
        adds = []
        for f in files:
            if key == "delay":
                j = spec["joint"] - 1
                dt = times[1] - times[0]
                d = inverse_dynamics_samples(
                    arm, f["_ref"], np.clip(times - spec["samples"] * dt, 0.0, None)
                )
                add = np.zeros_like(f["tau"])
                add[:, j] = d["tau"][:, j] - f["tau_nominal"][:, j]
            else:
                heavy = _with_payload(arm, spec["mass"], np.array(spec["offset"]))
                d = inverse_dynamics_samples(heavy, f["_ref"], times)
                add = d["tau"] - f["tau_nominal"]
            adds.append(add)
        size = np.sqrt(np.mean(np.concatenate(adds) ** 2, axis=0)) / sigma
        if dry_run:
            return bool(size.max() >= 2.0)
        spec["size_over_noise"] = size.round(2).tolist()
        for f, add in zip(files, adds, strict=True):
            f["tau"] = f["tau"] + add
        return True
    j = spec["joint"] - 1
    shapes = [_shape(spec, f, q_range) for f in files]
    rms = float(np.sqrt(np.mean(np.concatenate(shapes) ** 2)))
    if rms == 0:
        return False
    gain = spec["snr"] * sigma[j] / rms
    spec["parameter"] = float(gain)
    if dry_run:
        return True
    for f, s in zip(files, shapes, strict=True):
        f["tau"][:, j] = f["tau"][:, j] + gain * s
    return True


def write_case(case: Case, out: str | Path, fmt: str = "csv") -> dict[str, Any]:
    """Write ``train_k.<fmt>``, ``test_k.<fmt>``, ``robot.xml`` and ``truth.json`` under
    ``out``; returns the truth dict."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"robot": case.robot, "joint_types": case.joint_types}
    for k, a in enumerate(case.train, 1):
        save_dataset(a, out / f"train_{k}.{fmt}", metadata=meta)
    for k, a in enumerate(case.test, 1):
        save_dataset(a, out / f"test_{k}.{fmt}", metadata=meta)
    (out / "robot.xml").write_text(case.nominal_xml)
    truth = {
        "robot": case.robot,
        "seed": case.seed,
        "joint_types": case.joint_types,
        "noise_std": case.noise_std.tolist(),
        "effects": case.effects,
        "labels": case.truth(),
    }
    (out / "truth.json").write_text(json.dumps(truth, indent=1))
    return truth
