"""The diagnosis benchmark on simulated robot logs: random arms, random hidden effects.

Each case (:func:`run_case`, seed ``s``) is made the way a real robot's logs are
(:func:`mcpilco.envs.robot_logs.simulate_log`): a random arm (:func:`~mcpilco.envs.arms.
random_arm`, 2-3 joints by default, each prismatic with probability 1/4, random geometry and
masses; its rigid-body table is the nominal robot file), forward-simulated in MuJoCo under PD
+ gravity compensation with the hidden effects as MuJoCo physics or applied forces, an encoder
of :data:`ENCODER_COUNTS` counts per revolution (drawn), torque noise of std drawn
log-uniformly in :data:`TAU_NOISE_RANGE`, files holding only ``t, q, tau`` (``qd``, ``qdd``
estimated by the loader's filter). ``train_files`` logs to fit on and one held-out log, each
``duration`` seconds, every log its own random reference.

Hidden effects (:data:`EFFECT_KINDS`, joint or link drawn uniformly):

==================  ===========================================================================
damping, frictionloss, armature, stiffness, cogging, position_friction
                    scaled so that the rms of the effect's torque along an effect-free probe
                    log of the same arm is ``snr`` times the torque noise, ``snr`` log-uniform
                    in :data:`SNR_RANGE`; ``stiffness``: ``springref`` uniform in the probe's
                    range of ``q_j``; ``cogging``: spatial frequency an integer in 3..24;
                    ``position_friction``: level varies by +-50 % with ``sin(w q_j)``, ``w``
                    uniform in 1..4 /rad (10..40 /m on prismatic joints)
mass                link ``k`` heavier by a factor uniform in :data:`MASS_FACTOR_RANGE`
payload             a sphere of mass uniform in :data:`PAYLOAD_RANGE` kg on the flange, 0-10 cm
                    along its z axis
==================  ===========================================================================

``mass`` and ``payload`` (physical sizes) are redrawn, on another link or joint if need be,
until their torque along the probe log reaches :data:`MIN_SIZE` noise stds on some joint (after
20 draws the last is kept: an arm may barely load any link).
The realised size of each case's effects (``size_over_noise``: rms over the simulated logs of
the applied torque minus the nominal model's inverse dynamics at the true states, per joint,
in torque-noise stds) is recorded.

Roles (:func:`case_plan`): ``control`` (no hidden effect), ``single`` (one effect of the
library, each kind in turn), ``multi`` (two effects of the library, different kinds),
``off_library`` (position-dependent friction, which no candidate represents: the correct
answer is an "unexplained" verdict). A start model (nominal physics from the arm's table, or
a learned GIP / RBF GP) is fitted and the loop runs
(:func:`~mcpilco.models.diagnosis.auto_improve`: diagnose, add the lead, refit, until nothing
is significant); :mod:`mcpilco.experiments.diagnosis.scoring` scores the answer against the
truth. :func:`run_benchmark` runs the cases as sweep jobs and writes JSON, Markdown and a PNG
(confusion of the hidden effect against the effect named first).

Named case sets (:data:`CASE_SETS`, ``--case-set``): a fixed list of cases on one arm of
:data:`mcpilco.envs.arms.ARMS` instead of random arms. Its nominal robot file is the table
without friction (``arm.without_friction()``: the rigid body and the rotor inertias); each case
draws its encoder, noise, references and effects from its seed as above, a kind listed in the
set's ``sizes`` with its value uniform in the given range instead. ``panda``: the Franka Emika
Panda of :func:`~mcpilco.envs.arms.panda` (MuJoCo Menagerie's frames and inertials), with a
payload at the flange, rotor inertia of 0.05-0.3 kg m^2 on three joints (a half to three
times the table's armature), dry friction of 2-3 N m on two joints, a heavier link, damping,
position-dependent friction (off-library) and a control, first on torque logs, then the same
seven on motor-current logs with unknown torque constants (``logs="current"``,
:func:`run_case`: the constants estimated against the nominal model, jointly with a payload
at the flange, and left free in the loop's first version). ``iiwa``: the same fourteen cases
on the KUKA LBR iiwa 14 of :func:`~mcpilco.envs.arms.iiwa14` (MuJoCo Menagerie's frames and
inertials; no armature in the table, so the rotor inertias are all missing inertia), a
second 7-joint arm whose table the loop was not developed on.

Seeds: :data:`DEVELOPMENT_SEEDS` may be looked at while developing the loop; results are
reported on evaluation seeds from :data:`EVALUATION_FIRST_SEED`, on which no setting is chosen.
"""

from __future__ import annotations

import dataclasses
import datetime
import math
import os
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from mcpilco.experiments.diagnosis.scoring import (
    CORRECT_CANDIDATES,
    markdown,
    plot_confusion,
    score_case,
    summarise,
)
from mcpilco.experiments.infra.sweep import Job, SweepRunner
from mcpilco.experiments.results import Headline, Result, ResultLayout, write_result

DEVELOPMENT_SEEDS = range(0, 100)
"""Case seeds that may be looked at while developing the loop."""
EVALUATION_FIRST_SEED = 1000
"""First case seed of the reported evaluation (no setting is chosen on seeds >= this)."""
LIBRARY_KINDS = ("damping", "frictionloss", "armature", "stiffness", "mass", "payload", "cogging")
"""Hidden-effect kinds some candidate names (single cases take them in this order)."""
OFF_LIBRARY_KINDS = ("position_friction",)
"""Hidden-effect kinds no candidate represents."""
EFFECT_KINDS = LIBRARY_KINDS + OFF_LIBRARY_KINDS
"""Every kind a case may hide."""
SCALED_KINDS = ("damping", "frictionloss", "armature", "stiffness", "cogging", "position_friction")
"""Kinds whose value is set from ``snr`` (module docstring)."""
SNR_RANGE = (3.0, 30.0)
"""Range of the log-uniform ``snr`` of the scaled kinds [torque-noise stds]."""
MASS_FACTOR_RANGE = (1.2, 1.6)
"""Range of the uniform mass factor of a heavier link."""
PAYLOAD_RANGE = (0.2, 2.0)
"""Range of the uniform payload mass [kg]."""
MIN_SIZE = 2.0
"""Smallest probe-log torque [noise stds, some joint] of a mass or payload effect."""
ENCODER_COUNTS = (2**15, 2**17, 2**19)
"""Encoder counts per revolution a case draws from (prismatic joints: 1e6 counts/m)."""
TAU_NOISE_RANGE = (0.02, 0.1)
"""Range of the log-uniform torque-noise std [N m or N]."""
MAX_DRAWS = 20
"""Draws of a case's arm (and of its effects) before giving up when every simulation diverges."""
RANKING_KEPT = 10
"""Candidates of the first diagnosis's ranking kept in a record."""


class CaseSet(NamedTuple):
    """A named, fixed list of cases on one arm (module docstring).

    Attributes:
        arm: a table of :data:`mcpilco.envs.arms.ARMS`.
        cases: ``(role, kinds, logs)`` of each case, in order; a kind listed twice acts on
            two different joints (links); ``logs``: ``"torque"`` or ``"current"`` (motor
            currents with unknown torque constants, :func:`run_case`).
        sizes: kind -> ``(low, high)``: its value is drawn uniformly in this range instead of
            from ``snr`` (or :data:`MASS_FACTOR_RANGE`, :data:`PAYLOAD_RANGE`).
    """

    arm: str
    cases: tuple[tuple[str, tuple[str, ...], str], ...]
    sizes: dict[str, tuple[float, float]]


LOG_KINDS = ("torque", "current")
"""What a case's files log: joint torques, or motor currents with unknown torque constants."""
_ARM_CASES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("control", ()),
    ("single", ("payload",)),
    ("multi", ("armature", "armature", "armature")),
    ("multi", ("frictionloss", "frictionloss")),
    ("single", ("mass",)),
    ("single", ("damping",)),
    ("off_library", ("position_friction",)),
)  # a 7-joint arm set's effects, on torque logs and then on current logs
CASE_SETS: dict[str, CaseSet] = {
    "panda": CaseSet(
        arm="panda",
        cases=tuple((role, kinds, logs) for logs in LOG_KINDS for role, kinds in _ARM_CASES),
        sizes={"armature": (0.05, 0.3), "frictionloss": (2.0, 3.0)},
    ),
    "iiwa": CaseSet(
        arm="iiwa14",
        cases=tuple((role, kinds, logs) for logs in LOG_KINDS for role, kinds in _ARM_CASES),
        sizes={"armature": (0.05, 0.3), "frictionloss": (2.0, 3.0)},
    ),
}
"""Named case sets (``--case-set``)."""
TORQUE_CONSTANT_RANGE = (-1.0, 0.5)
"""Range of ``log10 |k_t|`` [N m/A or N/A] of a current case's joints (uniform; random sign:
a motor mounted reversed)."""


# ----------------------------------------------------------------------------- the plan
def case_plan(
    per_kind: int = 3, controls: int = 5, multi: int = 5, off_library: int = 5
) -> list[tuple[str, list[str]]]:
    """``(role, kinds)`` of every case: ``per_kind`` single cases of each of
    :data:`LIBRARY_KINDS`, ``controls`` without an effect, ``multi`` with two kinds
    (:data:`LIBRARY_KINDS` ``i`` and ``i + 3``, cyclically), ``off_library`` with
    position-dependent friction. The roles are interleaved in proportion (case ``i`` of a
    role with ``n`` cases sits at ``i / n`` of the plan; on ties: control, single, multi,
    off-library), so that the first cases of the plan already mix every role."""
    if min(per_kind, controls, multi, off_library) < 0:
        raise ValueError(
            f"case counts must be >= 0, got per_kind={per_kind}, controls={controls}, "
            f"multi={multi}, off_library={off_library}"
        )
    k = len(LIBRARY_KINDS)
    queues: list[list[tuple[str, list[str]]]] = [
        [("control", [])] * controls,
        [("single", [LIBRARY_KINDS[i % k]]) for i in range(per_kind * k)],
        [("multi", [LIBRARY_KINDS[i % k], LIBRARY_KINDS[(i + 3) % k]]) for i in range(multi)],
        [
            ("off_library", [OFF_LIBRARY_KINDS[i % len(OFF_LIBRARY_KINDS)]])
            for i in range(off_library)
        ],
    ]
    keyed = [(i / len(q), r, case) for r, q in enumerate(queues) for i, case in enumerate(q)]
    return [case for _, _, case in sorted(keyed, key=lambda x: (x[0], x[1]))]


# ----------------------------------------------------------------------------- effects
def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def effect_torque(arm: Any, effects: Sequence[Any], log: Any) -> np.ndarray:
    """``(N, n)`` the torque of ``effects`` along ``log``: its noise-free applied torque minus
    the nominal model's inverse dynamics (``mj_inverse``) at its true states (a log simulated
    with ``effects``), or the true model's minus the nominal one's inverse dynamics (a log
    simulated without them; MuJoCo-body effects only)."""
    import mujoco

    from mcpilco.envs.robot_logs import build_models

    nominal, true, _ = build_models(arm, effects)
    truth = log.truth
    simulated = tuple(truth.effects) == tuple(effects)

    def inverse(model: Any) -> np.ndarray:
        data = mujoco.MjData(model)
        out = np.zeros_like(truth.q)
        for k in range(truth.q.shape[0]):
            data.qpos[:], data.qvel[:], data.qacc[:] = truth.q[k], truth.qd[k], truth.qdd[k]
            mujoco.mj_inverse(model, data)
            out[k] = data.qfrc_inverse
        return out

    if simulated:
        return truth.tau - inverse(nominal)
    return inverse(true) - inverse(nominal)


def draw_effect(
    kind: str,
    arm: Any,
    probe: Any,
    rng: np.random.Generator,
    tau_noise: float,
    value_range: tuple[float, float] | None = None,
) -> Any:
    """A :class:`~mcpilco.envs.robot_logs.HiddenEffect` of ``kind`` on a random joint (link),
    its size drawn as in the module docstring from the effect-free ``probe`` log's true
    states, or uniformly in ``value_range`` when given (the value itself: N m s/rad, N m,
    kg m^2, ...; the mass factor; the payload's kg)."""
    from mcpilco.envs.robot_logs import FRICTION_VELOCITY, HiddenEffect

    n = arm.n_joints
    truth = probe.truth
    if kind in SCALED_KINDS:
        j = int(rng.integers(1, n + 1))
        q, qd, qdd = truth.q[:, j - 1], truth.qd[:, j - 1], truth.qdd[:, j - 1]
        prismatic = arm.joint_types[j - 1] == "P"
        ref = 0.0
        if kind == "damping":
            shape = qd
        elif kind == "frictionloss":
            shape = np.tanh(qd / FRICTION_VELOCITY)
        elif kind == "armature":
            shape = qdd
        elif kind == "stiffness":
            ref = float(rng.uniform(q.min(), q.max()))
            shape = q - ref
        elif kind == "cogging":
            ref = float(rng.integers(3, 25))
            shape = np.sin(ref * q)
        else:  # position_friction
            ref = float(rng.uniform(10.0, 40.0) if prismatic else rng.uniform(1.0, 4.0))
            shape = (1.0 + 0.5 * np.sin(ref * q)) * np.tanh(qd / FRICTION_VELOCITY)
        snr = _log_uniform(rng, *SNR_RANGE)
        if value_range is not None:
            return HiddenEffect(kind, j, float(rng.uniform(*value_range)), ref)
        return HiddenEffect(kind, j, snr * tau_noise / max(_rms(shape), 1e-12), ref)
    if kind not in ("mass", "payload"):
        raise ValueError(f"unknown hidden-effect kind {kind!r}; use one of {EFFECT_KINDS}")
    effect = None
    for _ in range(20):
        if kind == "mass":
            effect = HiddenEffect(
                "mass",
                int(rng.integers(1, n + 1)),
                float(rng.uniform(*(value_range or MASS_FACTOR_RANGE))),
            )
        else:
            effect = HiddenEffect(
                "payload",
                n,
                float(rng.uniform(*(value_range or PAYLOAD_RANGE))),
                float(rng.uniform(0.0, 0.1)),
            )
        size = np.sqrt(np.mean(effect_torque(arm, [effect], probe) ** 2, axis=0)) / tau_noise
        if size.max() >= MIN_SIZE:
            break
    return effect


# ----------------------------------------------------------------------------- one case
def make_start(
    kind: str, nominal_xml: str, joint_types: str, iters: int, inducing: int | None = None
) -> Any:
    """The start model of a case: nominal physics from the arm's table (``"nominal"``), or a
    GIP / RBF GP learned on the training files (the table then serves the payload candidate's
    frame and, on current logs, the torque-constant estimate of
    :func:`~mcpilco.models.diagnosis.currents_to_torque`: such a case is not one without a
    robot file);
    ``inducing``: a GIP start fitted on every row with that many Nystroem rows
    (:class:`~mcpilco.models.diagnosis.GIPStart`)."""
    from mcpilco.models.diagnosis import LEARNED_STARTS, NominalStart

    if kind == "nominal":
        return NominalStart(nominal_xml)
    if kind not in LEARNED_STARTS:
        raise ValueError(f"start must be nominal or one of {sorted(LEARNED_STARTS)}, got {kind!r}")
    if inducing is not None and kind != "gip":
        raise ValueError(f"inducing is a setting of the gip start, not of {kind!r}")
    extra = {} if inducing is None else {"inducing": inducing}
    return LEARNED_STARTS[kind](
        joint_types, robot=nominal_xml, adam_iters=iters, lbfgs_iters=max(iters // 3, 1), **extra
    )


def _trajectories(logs: Sequence[Any], names: Sequence[str]) -> Any:
    """The logs' tables (``t, q, tau``) as the loader reads them: ``qd``/``qdd`` estimated."""
    from mcpilco.models.diagnosis import as_trajectories
    from mcpilco.models.robot_data import from_frame

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the loader keeps its warnings
        return as_trajectories(
            [from_frame(log.table, source=name) for log, name in zip(logs, names, strict=True)]
        )


def run_case(
    seed: int,
    role: str,
    kinds: Sequence[str],
    duration: float = 5.0,
    train_files: int = 2,
    min_joints: int = 2,
    max_joints: int = 3,
    start: str = "nominal",
    max_points: int = 600,
    iters: int = 100,
    max_steps: int = 4,
    inducing: int | None = None,
    arm: str = "random",
    sizes: dict[str, Sequence[float]] | None = None,
    logs: str = "torque",
) -> dict[str, Any]:
    """Simulate one case (module docstring), run the loop on it and score it.

    Args:
        seed: seeds everything (arm, effects, references, noise).
        role: ``control``, ``single``, ``multi`` or ``off_library`` (recorded).
        kinds: the hidden effects' kinds (:data:`EFFECT_KINDS`); ``[]``: a control.
        duration: seconds per log.
        train_files: logs to fit on (one more is held out).
        min_joints, max_joints: range of the arm's joint count.
        start: ``nominal``, ``gip`` or ``rbf``.
        max_points, iters: GP rows and Adam iterations of a learned start.
        max_steps: most effects the loop adds.
        inducing: a GIP start fitted on every row with this many Nystroem rows
            (:func:`make_start`).
        arm: ``"random"`` (a random arm of ``min_joints..max_joints`` joints, its rigid
            table the nominal robot file) or a table of :data:`mcpilco.envs.arms.ARMS`
            (its table without friction the nominal robot file).
        sizes: kind -> ``(low, high)``, the range its value is drawn from
            (:func:`draw_effect`); other kinds as in the module docstring.
        logs: ``"torque"``, or ``"current"``: the files hold motor currents ``i = tau / k_t``
            instead (``k_t`` per joint, ``log10 |k_t|`` uniform in
            :data:`TORQUE_CONSTANT_RANGE`, random sign; current noise ``tau_noise / |k_t|``,
            the same noise in torque units), the constants unknown to the loop: estimated
            against the nominal model (:func:`~mcpilco.models.diagnosis.currents_to_torque`),
            a joint whose constant is not identifiable diagnosed in A.

    Returns:
        the record: the case (arm, noise, effects and their realised size), the loop's
        answer (first ranking, named effect, added effects and their parameters, verdicts,
        the parameters of a joint diagnosed in A put back into torque units by the loop's own
        fitted ``k_t`` of that joint and marked ``in_current``,
        held-out RMSE over the noise floor before and after, and after without the smear
        intervals of dry friction, :func:`~mcpilco.models.diagnosis.search.smear_judged`) and
        seconds; scored by
        :func:`score_record`.
    """
    from mcpilco.envs.arm_builder import arm_to_xml
    from mcpilco.envs.arms import ARMS, random_arm
    from mcpilco.envs.robot_logs import SimulationDiverged, simulate_log
    from mcpilco.models.diagnosis import DiagnosisModel, auto_improve, currents_to_torque
    from mcpilco.models.diagnosis.effects import MODEL_ONLY_EFFECTS

    for k in kinds:
        if k not in EFFECT_KINDS:
            raise ValueError(f"unknown hidden-effect kind {k!r}; use one of {EFFECT_KINDS}")
    if logs not in LOG_KINDS:
        raise ValueError(f"logs must be one of {LOG_KINDS}, got {logs!r}")
    if not 1 <= min_joints <= max_joints:
        raise ValueError(f"need 1 <= min_joints <= max_joints, got {min_joints}, {max_joints}")
    if arm != "random" and arm not in ARMS:
        raise ValueError(f"arm must be 'random' or one of {sorted(ARMS)}, got {arm!r}")
    ranges = {k: (float(v[0]), float(v[1])) for k, v in (sizes or {}).items()}
    t0, c0 = time.perf_counter(), time.process_time()
    rng = np.random.default_rng(seed)
    table = None if arm == "random" else ARMS[arm]().without_friction()
    for _ in range(MAX_DRAWS):
        if table is None:
            n = int(rng.integers(min_joints, max_joints + 1))
            robot = random_arm(n, seed=int(rng.integers(2**31))).rigid()
        else:
            robot, n = table, table.n_joints
        counts = int(rng.choice(ENCODER_COUNTS))
        tau_noise = _log_uniform(rng, *TAU_NOISE_RANGE)
        log_seeds = [int(s) for s in rng.integers(2**31, size=train_files + 1)]
        sim = dict(duration=duration, counts_per_rev=counts, tau_noise=tau_noise)
        try:  # an arm whose controller the simulation cannot follow: draw another arm
            probe = simulate_log(robot, [], seed=log_seeds[0], **sim)
            break
        except SimulationDiverged:
            continue
    else:
        raise RuntimeError(f"seed {seed}: {MAX_DRAWS} draws of the arm all diverged")
    k_true: np.ndarray | None = None
    units: dict[str, Any] = {}
    for _ in range(MAX_DRAWS):
        effects: list[Any] = []
        for k in kinds:
            e = draw_effect(k, robot, probe, rng, tau_noise, ranges.get(k))
            while any(e.kind == o.kind and e.joint == o.joint for o in effects):
                e = draw_effect(k, robot, probe, rng, tau_noise, ranges.get(k))
            effects.append(e)
        try:
            if logs == "current":  # the same motion and effects, logged as motor currents
                k_true = 10 ** rng.uniform(*TORQUE_CONSTANT_RANGE, n) * rng.choice([-1.0, 1.0], n)
                units = {"torque_constants": k_true, "current_noise": tau_noise / np.abs(k_true)}
            sims = [simulate_log(robot, effects, seed=s, **sim, **units) for s in log_seeds]
            break
        except SimulationDiverged:  # a draw the simulated arm cannot follow: draw again
            continue
    else:
        raise RuntimeError(f"seed {seed}: {MAX_DRAWS} draws of {list(kinds)} all diverged")
    size = np.sqrt(
        np.mean(np.concatenate([effect_torque(robot, effects, log) for log in sims]) ** 2, axis=0)
    )
    names = [f"seed{seed}_train{k + 1}" for k in range(train_files)] + [f"seed{seed}_test"]
    train = _trajectories(sims[:-1], names[:-1])
    test = _trajectories(sims[-1:], names[-1:])
    t_sim = time.perf_counter() - t0

    xml = arm_to_xml(robot, friction=False)
    start_model = make_start(start, xml, robot.joint_types, iters, inducing)
    train, test, constants = currents_to_torque(train, test, start_model)
    model = DiagnosisModel(
        start_model, [] if constants is None else constants.effects(), max_points=max_points
    )
    model.fit(train)
    versions, diags = auto_improve(model, test, max_steps=max_steps)
    first, last = diags[0], diags[-1]
    final = versions[-1]
    by_label = {e.variant_label: e for e in final.effects}
    parameters = [
        {
            "key": by_label[p["effect"]].key,
            "joint": by_label[p["effect"]].joint,
            "name": p["name"],
            "value": p["value"],
            "ci95": p["ci95"],
            "output": p["output"],
        }
        for p in final.parameters()
        if p["effect"] in by_label
    ]
    joint_k = _joint_constants(constants, final)
    if constants is not None and joint_k is not None:  # joints in A: parameters in N m again
        for p in parameters:
            out = p["output"]
            if isinstance(out, int) and p["key"] != "scale" and constants.in_current[out - 1]:
                scale = abs(joint_k[out - 1])
                p.update(value=p["value"] * scale, ci95=p["ci95"] * scale, in_current=True)
    truth = []
    for e in effects:
        d = dataclasses.asdict(e)
        if e.kind == "mass":
            d["nominal_link_mass"] = robot.links[e.joint - 1].mass
        truth.append(d)
    ranking = [[c.effect.key, c.effect.joint] for c in first.candidates[:RANKING_KEPT]]
    named = None if first.best is None else [first.best.effect.key, first.best.effect.joint]
    added = [[e.key, e.joint] for e in final.effects if e.key not in MODEL_ONLY_EFFECTS]
    verdict = last.verdict()
    rec: dict[str, Any] = {
        "seed": seed,
        "role": role,
        "arm": robot.joint_types,
        "arm_name": robot.name,
        "n_joints": n,
        "encoder_counts_per_rev": counts,
        "tau_noise": tau_noise,
        "rows": {"train": int(train.n_samples), "test": int(test.n_samples)},
        "start": start,
        "inducing": inducing,
        "logs": logs,
        "torque_constants": None if k_true is None else k_true.tolist(),
        "torque_constants_estimated": None if constants is None else constants.value.tolist(),
        "torque_constants_ci95": None if constants is None else constants.ci95.tolist(),
        "torque_constants_joint": joint_k,
        "torque_constants_in_current": (
            None
            if constants is None
            else [int(j) + 1 for j in np.flatnonzero(constants.in_current)]
        ),
        "effects": truth,
        "size_over_noise": (size / tau_noise).round(2).tolist(),
        "ranking": ranking,
        "ranking_delta": [round(c.delta, 1) for c in first.candidates[:RANKING_KEPT]],
        "named": named,
        "first_verdict": first.verdict(),
        "added": added,
        "added_variants": [e.variant_label for e in final.effects],
        "versions": [v.describe() for v in versions],
        "parameters": parameters,
        "verdict": verdict,
        "ratio_before": first.base.ratio.tolist(),
        "ratio_after": last.base.ratio.tolist(),
        "ratio_after_plain": (last.base.rmse / last.base.floor).tolist(),  # no smear intervals
        "floor_after": last.base.floor.tolist(),
        "data_warnings": list(dict.fromkeys(train.warnings + test.warnings)),
        "simulate_seconds": t_sim,
    }
    rec["seconds"] = time.perf_counter() - t0
    rec["cpu_seconds"] = time.process_time() - c0  # every thread of this process
    return rec


def _joint_constants(constants: Any, model: Any) -> list[float] | None:
    """``k_t`` per joint as the final ``model`` has it: the estimate ``k_hat`` corrected by
    the free scale fitted jointly with the effects, ``k_hat / (1 + alpha)`` (``k_hat`` where
    the model holds no scale; ``None`` without constants)."""
    if constants is None:
        return None
    alpha = {
        p["effect"]: p["value"] for p in model.parameters() if p["effect"].startswith("scale:")
    }
    return [
        float(k / (1.0 + alpha.get(f"scale:{j + 1}", 0.0))) for j, k in enumerate(constants.value)
    ]


def score_record(rec: dict[str, Any]) -> dict[str, Any]:
    """:func:`~.diagnosis_scoring.score_case` of a :func:`run_case` record (scored when the
    report is written, so a kept record is rescored by the current tables)."""
    return score_case(
        rec["effects"],
        rec["n_joints"],
        rec["ranking"],
        rec["named"],
        rec["added"],
        rec["verdict"],
        rec["parameters"],
        rec["size_over_noise"],
    )


# ----------------------------------------------------------------------------- the run
def run_benchmark(
    runner: SweepRunner,
    *,
    per_kind: int = 3,
    controls: int = 5,
    multi: int = 5,
    off_library: int = 5,
    cases: int | None = None,
    first_seed: int = EVALUATION_FIRST_SEED,
    duration: float = 5.0,
    train_files: int = 2,
    min_joints: int = 2,
    max_joints: int = 3,
    start: str = "nominal",
    max_points: int = 600,
    iters: int = 100,
    out: str | Path = "results/diagnosis",
    runs_dir: str | Path = "runs/bench_diagnosis",
    command: str | None = None,
    config: dict[str, Any] | None = None,
    case_set: str | None = None,
    seeds: Sequence[int] | None = None,
) -> dict[str, Any] | None:
    """Run the cases of :func:`case_plan`, or of the named :data:`CASE_SETS` entry
    ``case_set`` (the first ``cases`` of either when given; seeds ``first_seed, first_seed +
    1, ...`` in plan order; with ``seeds``, only those, seed ``s`` as the plan's case
    ``(s - first_seed) mod len(plan)``, the case it is when the plan repeats from
    ``first_seed`` on) as sweep jobs of ``runner``, each record kept in
    ``runs_dir/<arm>/<start>/seed<s>.json`` (``<arm>``: ``random`` or the case set's arm; a
    rerun computes only the cases without one), and write ``out`` + ``.json`` (``command``,
    ``measured`` date, ``config``, ``seeds``, the summary, every record, the failed cases),
    ``.md`` and ``_confusion.png``.

    Returns ``{"summary", "records", "markdown", "sweep"}``, or None when no case finished.
    """
    if case_set is not None and case_set not in CASE_SETS:
        raise ValueError(f"case_set must be one of {sorted(CASE_SETS)}, got {case_set!r}")
    named = CASE_SETS.get(case_set) if case_set is not None else None
    if named is None:
        plan = [(r, k, "torque") for r, k in case_plan(per_kind, controls, multi, off_library)]
        arm, sizes = "random", None
    else:
        plan = [(role, list(kinds), logs) for role, kinds, logs in named.cases]
        arm, sizes = named.arm, dict(named.sizes)
    if cases is not None:
        plan = plan[:cases]
    if not plan:
        raise ValueError("the plan has no case: give --per-kind, --controls, --multi or --cases")
    if seeds is None:
        seeds = [first_seed + k for k in range(len(plan))]
    else:
        seeds = list(dict.fromkeys(int(x) for x in seeds))
        plan = [plan[(x - first_seed) % len(plan)] for x in seeds]
    common = {
        "duration": duration,
        "train_files": train_files,
        "min_joints": min_joints,
        "max_joints": max_joints,
        "start": start,
        "max_points": max_points,
        "iters": iters,
        "arm": arm,
        "sizes": sizes,
    }
    jobs = [
        Job(
            f"seed{s}",
            run_case,
            {**common, "seed": s, "role": role, "kinds": list(kinds), "logs": logs},
        )
        for s, (role, kinds, logs) in zip(seeds, plan, strict=True)
    ]
    sweep = runner.run(jobs, Path(runs_dir) / arm / start, desc="cases")
    print(sweep.summary())
    records = [{**r, "score": score_record(r)} for r in sweep.results.values()]
    if not records:
        return None
    summary = summarise(records)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    title = (
        f"Diagnosis on simulated robot logs ({len(records)} cases"
        + ("" if named is None else f", case set {case_set}")
        + f", seeds {min(seeds)}..{max(seeds)}, {start} start)"
    )
    png = plot_confusion(records, out.with_name(out.name + "_confusion.png"), title)
    payload: dict[str, Any] = {
        "command": command,
        "measured": datetime.datetime.now(datetime.UTC).date().isoformat(),
        "config": config,
        "seeds": seeds,
        "correct_candidates": {k: [list(m) for m in v] for k, v in CORRECT_CANDIDATES.items()},
        "summary": summary,
        "cases": records,
    }
    if sweep.failed:
        payload["failed"] = [f.key for f in sweep.failed]
    write_result(out.with_suffix(".json"), RESULT_LAYOUTS[0], payload)
    arms_text = (
        f"Random arms ({min_joints}-{max_joints} joints)"
        if named is None
        else f"The {arm} table (nominal: without friction)"
    )
    intro = (
        f"{arms_text} simulated in MuJoCo under a PID joint servo + gravity "
        f"compensation; {train_files} training logs and 1 held-out log of {duration:g} s each, "
        + (
            "t, q and tau only"
            if all(r.get("logs", "torque") == "torque" for r in records)
            else "t, q and tau, or t, q and motor currents i with unknown torque constants "
            "(logs: current)"
        )
        + ". Roles: control (no effect), single, multi (two effects), "
        'off_library (position-dependent friction: correct verdict "unexplained"). '
        f"Confusion of hidden effect against the effect named first: ![confusion]({png.name})."
        + (f" Failed cases: {', '.join(payload['failed'])}." if sweep.failed else "")
        + (
            f" Seeds {min(seeds)}..{max(seeds)} are evaluation seeds (from "
            f"{EVALUATION_FIRST_SEED}), run with settings chosen on the development seeds "
            f"{DEVELOPMENT_SEEDS.start}..{DEVELOPMENT_SEEDS.stop - 1} only."
            if min(seeds) >= EVALUATION_FIRST_SEED
            else f" Seeds {min(seeds)}..{max(seeds)} are not evaluation seeds (from "
            f"{EVALUATION_FIRST_SEED}): not a report."
        )
    )
    text = markdown(records, summary, title, intro)
    out.with_suffix(".md").write_text(text)
    return {"summary": summary, "records": records, "markdown": text, "sweep": sweep}


# ----------------------------------------------------------------------------- speed

SPEED_EFFECT = ("damping", 2, 0.5)
"""Hidden effect of the speed case: viscous damping 0.5 N m s/rad on joint 2."""


def speed_case(
    directory: str | Path,
    seed: int = 0,
    n_joints: int = 3,
    train_files: int = 3,
    duration: float = 10.0,
) -> dict[str, Any]:
    """Write the speed case: a rigid random arm (``n_joints`` revolute joints, arm seed
    ``seed``) with :data:`SPEED_EFFECT`, simulated by
    :func:`~mcpilco.envs.robot_logs.simulate_log` (position-only files: ``t, q, tau``);
    ``train_files`` training logs of ``duration`` s (seeds ``seed..``; 3 x 10 s at 4 ms:
    7,503 rows) and one held-out log, and the nominal MJCF (no friction).

    Returns:
        ``{"train": [paths], "test": [path], "model": path, "joint_types", "rows"}``
        (``rows``: training rows).
    """
    from mcpilco.envs.arm_builder import arm_to_xml
    from mcpilco.envs.arms import random_arm
    from mcpilco.envs.robot_logs import HiddenEffect, simulate_log, write_log

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    arm = random_arm(n_joints, seed=seed, joint_types="R" * n_joints).rigid()
    xml = directory / "arm.xml"
    xml.write_text(arm_to_xml(arm, friction=False))
    effect = [HiddenEffect(*SPEED_EFFECT)]
    paths, rows = [], 0
    for k in range(train_files + 1):
        log = simulate_log(arm, effect, duration=duration, seed=seed + k)
        paths.append(str(write_log(directory / f"log{k}.csv", log)))
        rows += len(log.table) if k < train_files else 0
    return {
        "train": paths[:-1],
        "test": paths[-1:],
        "model": str(xml),
        "joint_types": "R" * n_joints,
        "rows": rows,
    }


def time_diagnosis(case: dict[str, Any], start: str, auto: int = 3) -> dict[str, Any]:
    """Run :func:`~mcpilco.models.diagnosis.run_diagnosis` on ``case`` (:func:`speed_case`)
    with a nominal or a GIP start and ``--auto auto``, without plots; its wall and CPU
    seconds (``time.process_time``: every thread of this process), verdict and versions."""
    import tempfile
    import warnings

    from mcpilco.models.diagnosis import run_diagnosis

    learned = None if start == "nominal" else (start, case["joint_types"])
    with tempfile.TemporaryDirectory() as out, warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # position-only files: estimated qd
        t0, c0 = time.perf_counter(), time.process_time()
        summary = run_diagnosis(
            case["train"],
            case["test"],
            model=case["model"],
            learned=learned,
            auto=auto,
            out=out,
            plots=False,
            rerun=False,
            log=lambda text: None,
        )
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    robot = Path(case["model"])
    return {
        "start": start,
        "wall_s": wall,
        "cpu_s": cpu,
        "versions": [v.replace(str(robot), robot.name) for v in summary["versions"]],
        "rmse_over_floor": summary["rmse_over_floor"][-1],
        "verdict": summary["verdict"],
    }


SPEED_STAGES = (
    "start-model fit",
    "candidate scoring (joint effects)",
    "inertial candidates (links, payload)",
    "shape refinement and held-out confirmation",
    "floor checks (held-out noise floor)",
    "start-model refits (backfitting)",
    "next versions (effect GPs refitted)",
    "report and the rest",
)
"""Rows of the speed breakdown (:func:`stage_breakdown`), disjoint, in this order."""


def stage_breakdown(case: dict[str, Any], start: str, auto: int = 3) -> list[dict[str, Any]]:
    """Where the time of :func:`time_diagnosis` goes: the run repeated under ``cProfile``,
    its seconds split into :data:`SPEED_STAGES` by the cumulative time of the functions that
    do each (the start model's ``fit`` and ``refit``, ``score_candidates`` less the shared
    rigid-body scoring ``score_shared_variant``, ``diagnose`` less the scoring and its floor
    checks, ``heldout_floor``, ``next_version`` less the start refits; the rest is loading,
    the first fit of the effect GPs, metrics and the report). The profiler slows the run
    down: the shares, not the seconds, carry over to the timed run.

    Returns:
        one ``{"stage", "seconds", "share"}`` per stage (``seconds`` under the profiler).
    """
    import cProfile
    import pstats

    from mcpilco.models.diagnosis import search, start_models

    def key(fn: Any) -> tuple[str, int, str]:
        code = fn.__code__
        return code.co_filename, code.co_firstlineno, code.co_name

    def unwrap(fn: Any) -> Any:
        while hasattr(fn, "__wrapped__"):
            fn = fn.__wrapped__
        return fn

    prof = cProfile.Profile()
    prof.enable()
    try:
        time_diagnosis(case, start, auto=auto)
    finally:
        prof.disable()
    stats = pstats.Stats(prof).stats
    fns = {
        "fit": start_models.LearnedStart.fit,
        "refit": start_models.LearnedStart.refit,
        "score": search.score_candidates,
        "shared": search.score_shared_variant,
        "diagnose": unwrap(search.diagnose),
        "floor_check": search.floor_check,
        "floor": search.heldout_floor,
        "next": search.next_version,
    }
    keys = {name: key(fn) for name, fn in fns.items()}

    def cum(name: str, caller: str | None = None) -> float:
        entry = stats.get(keys[name])
        if entry is None:
            return 0.0
        if caller is None:
            return float(entry[3])
        edge = entry[4].get(keys[caller])
        return 0.0 if edge is None else float(edge[3])

    total = float(max(ct for _, _, _, ct, _ in stats.values()))
    rows = [
        cum("fit"),
        cum("score") - cum("shared"),
        cum("shared"),
        cum("diagnose") - cum("score") - cum("floor_check", "diagnose"),
        cum("floor") + cum("floor_check", "diagnose") - cum("floor", "floor_check"),
        cum("refit"),
        cum("next") - cum("refit"),
    ]
    rows.append(total - sum(rows))
    return [
        {"stage": stage, "seconds": sec, "share": sec / total if total > 0 else 0.0}
        for stage, sec in zip(SPEED_STAGES, rows, strict=True)
    ]


def run_speed(
    out: str | Path = "results/diagnosis_speed",
    seed: int = 0,
    starts: tuple[str, ...] = ("nominal", "gip"),
    auto: int = 3,
    workdir: str | Path | None = None,
    train_files: int = 3,
    duration: float = 10.0,
    breakdown: bool = True,
) -> dict[str, Any]:
    """Time the diagnosis loop on the speed case (:func:`speed_case`: 3 joints, 7,503
    training rows) with each start in ``starts`` (:func:`time_diagnosis`), say where the
    time goes (``breakdown``: :func:`stage_breakdown`, a second, profiled run per start) and
    write ``out`` ``.json`` and ``.md``. The targets: nominal start under 10 s, GIP start
    under 60 s (``train_files``, ``duration``: a smaller case, :func:`speed_case`).

    Returns:
        ``{"case", "records", "markdown"}``.
    """
    import platform
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        case = speed_case(workdir or tmp, seed=seed, train_files=train_files, duration=duration)
        records = [time_diagnosis(case, s, auto=auto) for s in starts]
        if breakdown:
            for r in records:
                r["breakdown"] = stage_breakdown(case, r["start"], auto=auto)
    info = {
        "seed": seed,
        "effect": list(SPEED_EFFECT),
        "joints": len(case["joint_types"]),
        "training_rows": case["rows"],
        "auto": auto,
        "cpu_count": os.cpu_count(),
        "load_average_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
        "machine": platform.processor() or platform.machine(),
    }
    text = speed_markdown(info, records)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "command": "mcpilco-bench-diagnosis --speed",
        "seeds": [seed],
        "measured": datetime.date.today().isoformat(),
        "case": info,
        "records": records,
    }
    write_result(out.with_suffix(".json"), RESULT_LAYOUTS[1], payload)
    out.with_suffix(".md").write_text(text)
    return {"case": info, "records": records, "markdown": text}


def speed_markdown(info: dict[str, Any], records: list[dict[str, Any]]) -> str:
    """The speed report of :func:`run_speed` (``info``: its case, ``records``: one per
    start) as Markdown."""
    load = info["load_average_1min"]
    lines = [
        f"# Diagnosis speed ({info['joints']} joints, {info['training_rows']} training rows, "
        f"seed {info['seed']})",
        "",
        f"Hidden effect: {info['effect'][0]} {info['effect'][2]} on joint {info['effect'][1]}; "
        f"`run_diagnosis(..., auto={info['auto']}, plots=False)`; {info['cpu_count']} cores, "
        f"load average {'n/a' if load is None else f'{load:.1f}'} when it ended (wall time "
        "depends on the other jobs; CPU time less so).",
        "",
        "| start | wall [s] | CPU [s] | versions | RMSE / floor (last) | verdict |",
        "|---|---|---|---|---|---|",
    ]
    for r in records:
        added = r["versions"][-1].split(" + ", 1)[-1]
        ratio = ", ".join(f"{x:.2f}" for x in r["rmse_over_floor"])
        lines.append(
            f"| {r['start']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | {len(r['versions'])} "
            f"({added}) | {ratio} | {r['verdict'].split(':', 1)[-1].split(' (')[0].strip()} |"
        )
    timed = [r for r in records if r.get("breakdown")]
    if timed:
        lines += [
            "",
            "Where the time goes (a second run of each start under `cProfile`, which slows it "
            "down: seconds under the profiler, and the share of that run):",
            "",
            "| stage | " + " | ".join(r["start"] for r in timed) + " |",
            "|---|" + "---|" * len(timed),
        ]
        for k, stage in enumerate(SPEED_STAGES):
            cells = [
                f"{r['breakdown'][k]['seconds']:.1f} s ({100 * r['breakdown'][k]['share']:.0f}%)"
                for r in timed
            ]
            lines.append(f"| {stage} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


# -- result files and headline rows of the results index ----------------------------------

RESULT_LAYOUTS = (
    ResultLayout("diagnosis", config=("config", "seeds"), cases=("cases",)),
    ResultLayout("diagnosis_speed", config=("case", "seeds"), cases=("records",)),
)
"""The layouts of ``diagnosis_robot_logs.json`` and ``diagnosis_speed.json``
(:mod:`mcpilco.experiments.results`)."""


def _diagnosis_row(r: Result) -> str:
    s = r["summary"]
    return (
        f"effect ranked first in {s['top1_counts']} single-effect cases (top-3: "
        f"{s['top3_counts']}); position-dependent friction said unexplained in "
        f"{s['off_library_unexplained_counts']}; false alarms {s['false_alarm_counts']} controls"
    )


def _case_set_row(r: Result) -> str:
    s = r["summary"]
    ci = s["verdict_correct_rate"]["ci95"]
    logs = "; ".join(
        f"{k.split('_')[2]} logs {v['k']}/{v['n']}"
        for k, v in s.items()
        if k.startswith("verdict_correct_") and k.endswith("_logs")
    )
    return (
        f"verdict right in {s['verdict_correct_counts']} cases (95 % CI {ci[0]:.2f}-{ci[1]:.2f}; "
        f"{logs}); false alarms {s['false_alarm_counts']} controls; held-out error at the "
        f"floor in {s['at_floor_after_counts']} cases with library effects"
    )


def _speed_row(r: Result) -> str:
    rows = r["case"].get("training_rows", "?")
    times = ", ".join(
        f"{x['start']} {x['wall_s']:.0f} s wall ({x['cpu_s']:.0f} s CPU)" for x in r["records"]
    )
    return f"3 joints, {rows} training rows: {times}"


HEADLINES = (
    Headline(
        "Diagnosis on simulated robot logs, nominal start",
        "diagnosis_robot_logs.json",
        _diagnosis_row,
        "diagnosis_robot_logs.md",
    ),
    Headline(
        "Diagnosis on the Franka Emika Panda (7 joints, torque and current logs), nominal start",
        "diagnosis_panda.json",
        _case_set_row,
        "diagnosis_panda.md",
    ),
    Headline(
        "Diagnosis on the KUKA LBR iiwa 14 (7 joints, torque and current logs), nominal start",
        "diagnosis_iiwa.json",
        _case_set_row,
        "diagnosis_iiwa.md",
    ),
    Headline("Diagnosis speed", "diagnosis_speed.json", _speed_row, "diagnosis_speed.md"),
)
"""The diagnosis benchmark's rows of the results index."""


def replot(result: Result, json_path: Path) -> list[Path]:
    """Redraw the confusion figure of a diagnosis result file next to it (a speed file has
    no figure)."""
    if result.kind != "diagnosis":
        return []
    records, seeds = result["cases"], result["seeds"]
    title = (
        f"Diagnosis on simulated robot logs ({len(records)} cases, seeds "
        f"{seeds[0]}..{seeds[-1]}, {result['config']['start']} start)"
    )
    json_path = Path(json_path)
    return [plot_confusion(records, json_path.with_name(json_path.stem + "_confusion.png"), title)]
