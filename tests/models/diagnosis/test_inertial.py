"""Inertial candidates: the joint-torque regressor of every body, each link's inertia, the
payload at the flange.

Independent truths: MuJoCo's inverse dynamics (``mj_inverse``) with the inertial parameters
read from MuJoCo's own body data; the pseudo-inertia of bodies known to be (un)physical; the
exact parameters of a point mass; logs of :func:`mcpilco.envs.robot_logs.simulate_log` with
a heavier link or a payload (the generator's known truth).
"""

from __future__ import annotations

import json
import warnings

import mujoco
import numpy as np
import pytest

from mcpilco.envs.arm_builder import arm_to_xml
from mcpilco.envs.arms import random_arm, scara, ur10
from mcpilco.envs.robot_logs import HiddenEffect, simulate_log, write_log
from mcpilco.models.diagnosis import (
    DiagnosisModel,
    LinkInertia,
    NominalStart,
    Payload,
    as_trajectories,
    diagnose,
    load_trajectories,
)
from mcpilco.models.diagnosis.effects import FeatureContext, effect_from_spec, flange_map
from mcpilco.models.diagnosis.search import FLOOR_FACTOR
from mcpilco.models.diagnosis.start_models import _Robot
from mcpilco.models.inverse_dynamics import JointStates, RigidBodyFeatures, pseudo_inertia
from mcpilco.models.robot_data import from_frame


def _mujoco_parameters(model: mujoco.MjModel) -> np.ndarray:
    """Every body's 10 parameters (pinocchio's order, about the body origin) from MuJoCo's
    body mass, centre of mass and principal inertia (parallel-axis theorem)."""
    out = []
    for b in range(1, model.nbody):
        m, c = model.body_mass[b], model.body_ipos[b]
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, model.body_iquat[b])
        rot = rot.reshape(3, 3)
        i_c = rot @ np.diag(model.body_inertia[b]) @ rot.T
        i_o = i_c + m * (c @ c * np.eye(3) - np.outer(c, c))
        out.append([m, *(m * c), i_o[0, 0], i_o[0, 1], i_o[1, 1], i_o[0, 2], i_o[1, 2], i_o[2, 2]])
    return np.concatenate(out)


@pytest.mark.parametrize(
    "arm",
    [ur10(), scara(), random_arm(4, seed=2, joint_types="RPRR")],
    ids=["ur10", "scara", "random_RPRR"],
)
def test_regressor_times_body_parameters_is_mujoco_inverse_dynamics(arm):
    xml = arm_to_xml(arm, friction=False, armature=False, torque_limits=False)
    model = mujoco.MjModel.from_xml_string(xml)
    model.jnt_limited[:] = 0  # no limit forces in mj_inverse
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    q, qd, qdd = (rng.uniform(-1.5, 1.5, (25, model.nv)) for _ in range(3))
    reg = RigidBodyFeatures(xml, blocks=("rigid",)).rigid_regressor(JointStates(q, qd, qdd))
    tau = reg @ _mujoco_parameters(model)
    for k in range(q.shape[0]):
        data.qpos[:], data.qvel[:], data.qacc[:] = q[k], qd[k], qdd[k]
        mujoco.mj_inverse(model, data)
        np.testing.assert_allclose(tau[k], data.qfrc_inverse, rtol=0, atol=1e-8)


def _phi(m, c, i_c):
    c = np.asarray(c, float)
    i_o = np.asarray(i_c, float) + m * (c @ c * np.eye(3) - np.outer(c, c))
    return np.array([m, *(m * c), i_o[0, 0], i_o[0, 1], i_o[1, 1], i_o[0, 2], i_o[1, 2], i_o[2, 2]])


def test_pseudo_inertia_is_positive_definite_exactly_for_physical_bodies():
    box = np.diag([1.0 * (0.2**2 + 0.1**2), 1.0 * (0.3**2 + 0.1**2), 1.0 * (0.3**2 + 0.2**2)]) / 12
    good = _phi(1.0, [0.1, -0.2, 0.05], box)
    assert np.linalg.eigvalsh(pseudo_inertia(good))[0] > 0
    triangle = _phi(1.0, [0.1, 0.0, 0.0], np.diag([0.01, 0.02, 0.04]))  # 0.04 > 0.01 + 0.02
    assert np.linalg.eigvalsh(pseudo_inertia(triangle))[0] < 0
    negative = _phi(-0.5, [0.0, 0.0, 0.0], 0.5 * np.eye(3) * 1e-3)
    assert np.linalg.eigvalsh(pseudo_inertia(negative))[0] < 0
    with pytest.raises(ValueError, match="10 inertial parameters"):
        pseudo_inertia(np.zeros(9))


def test_flange_map_is_a_point_mass_to_first_order():
    rng = np.random.default_rng(1)
    pos = np.array([0.3, -0.1, 0.2])
    rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    g = flange_map(pos, rot)
    m = 2.0
    np.testing.assert_allclose(g @ [m, 0, 0, 0], _phi(m, pos, np.zeros((3, 3))), atol=1e-12)
    p = np.array([1e-3, -2e-3, 1.5e-3])
    exact = _phi(m, pos + rot @ p, np.zeros((3, 3)))
    err = np.abs(g @ np.r_[m, m * p] - exact).max()
    assert err <= 2 * m * (p @ p)  # the dropped m |p|^2 terms


def _context(xml: str, n: int, seed: int = 0) -> tuple[FeatureContext, _Robot]:
    robot = _Robot(xml)
    rng = np.random.default_rng(seed)
    q, qd, qdd = (rng.uniform(-2, 2, (400, n)) for _ in range(3))
    ctx = FeatureContext(
        q=q,
        qd=qd,
        qdd=qdd,
        base=np.zeros_like(q),
        joint_types=robot.joint_types,
        regressor=lambda: robot.regressor(q, qd, qdd),
        rigid=robot.rigid_body(),
    )
    return ctx, robot


def test_link_block_spans_its_torques_and_flags_an_unphysical_fit():
    arm = random_arm(3, seed=1, joint_types="RRR").rigid()
    ctx, robot = _context(arm_to_xml(arm, friction=False), 3)
    link = LinkInertia(joint=2).calibrate(ctx)
    assert link.outputs(3) == [0, 1] and link.variant_label == "link 2 inertia"
    assert effect_from_spec(json.loads(json.dumps(link.spec()))) == link  # saved models
    # the last link's inertia and the payload are forms of one body's change; link 2 is not
    last = LinkInertia(joint=3).calibrate(ctx)
    assert last.same_family(Payload()) and Payload().same_family(last)
    assert not link.same_family(Payload()) and not link.same_family(last)
    phi = ctx.rigid.parameters[1]
    z = np.asarray(link.basis) @ (np.asarray(link.scale) * 0.4 * phi)  # z = E^T dphi
    # the identifiable block reproduces the torque of a 40 % heavier link on joints 1, 2
    for j in (0, 1):
        true = ctx.body_columns(2)[:, j, :] @ (0.4 * phi)
        np.testing.assert_allclose(link.columns(ctx, j) @ z, true, atol=1e-9 * np.abs(true).max())
    cov = np.eye(z.size) * 1e-10
    heavier = {p.name: p for p in link.estimates(z, cov, ctx, 0)}
    assert heavier["s"].value == pytest.approx(0.4, abs=1e-9)
    assert heavier["nonphysical"].value == 0 and not heavier["nonphysical"].wrong_sign
    # a link whose mass turns negative (m -> -2 m, the rest unchanged) is no body
    dphi = np.zeros(10)
    dphi[0] = -3.0 * phi[0]
    neg = np.asarray(link.basis) @ (np.asarray(link.scale) * dphi)
    flagged = {p.name: p for p in link.estimates(neg, cov, ctx, 0)}
    assert flagged["nonphysical"].value > 0.1 and flagged["nonphysical"].wrong_sign


def _logs(arm, effects, tmp_path):
    logs = [simulate_log(arm, effects, duration=4.0, seed=s) for s in (0, 1)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return [
            load_trajectories([write_log(tmp_path / f"log{s}.csv", log)])
            for s, log in enumerate(logs)
        ]


def _lead_or_alternative(diag, pred):
    lead = diag.lead
    assert lead is not None, diag.table()
    if pred(lead):
        return lead
    alts = [c for c in diag.alternatives(lead) if pred(c)]
    assert alts, diag.table()
    return alts[0]


@pytest.mark.slow
def test_a_heavier_link_is_named_with_its_change(tmp_path):
    arm = random_arm(3, seed=3, joint_types="RRR").rigid()
    train, test = _logs(arm, [HiddenEffect("mass", 2, 1.4)], tmp_path)
    model = DiagnosisModel(NominalStart(arm_to_xml(arm, friction=False))).fit(train)
    diag = diagnose(model, test)
    cand = _lead_or_alternative(
        diag, lambda c: isinstance(c.effect, LinkInertia) and c.effect.joint == 2
    )
    est = {p.name: p for p in cand.estimates}
    assert abs(est["s"].value - 0.4) <= est["s"].ci95, diag.table()
    assert not est["nonphysical"].wrong_sign
    assert "link 2" in diag.verdict()


@pytest.mark.slow
def test_a_payload_is_named_with_its_mass(tmp_path):
    arm = random_arm(3, seed=3, joint_types="RRR").rigid()
    mass = 1.0
    train, test = _logs(arm, [HiddenEffect("payload", 0, mass, 0.05)], tmp_path)
    model = DiagnosisModel(NominalStart(arm_to_xml(arm, friction=False))).fit(train)
    diag = diagnose(model, test)
    cand = _lead_or_alternative(diag, lambda c: isinstance(c.effect, Payload))
    m = cand.estimates[0]
    assert m.name == "m" and abs(m.value - mass) <= max(m.ci95, 0.02 * mass), diag.table()


def test_a_heavy_payload_is_named_and_reaches_the_floor():
    """A 2 kg payload, hundreds of noise stds on the prismatic joint: the derivative filter's
    edge rows (several N of torque error on the first rows) are left out, so that the model
    with the payload sits at the noise floor on both joints and its mass is recovered."""
    arm = random_arm(2, seed=4, joint_types="PR").rigid()
    mass = 2.0
    logs = [
        simulate_log(arm, [HiddenEffect("payload", 0, mass, 0.05)], duration=3.0, seed=s)
        for s in (0, 1)
    ]
    train, test = [
        as_trajectories([from_frame(log.table, source=f"log{s}")]) for s, log in enumerate(logs)
    ]
    model = DiagnosisModel(NominalStart(arm_to_xml(arm, friction=False))).fit(train)
    diag = diagnose(model, test)
    assert diag.lead is not None and isinstance(diag.lead.effect, Payload), diag.table()
    assert diag.base.ratio[0] > 100, diag.base.ratio
    assert (diag.after.ratio <= FLOOR_FACTOR).all(), diag.after.ratio
    m = diag.lead.estimates[0]
    assert m.name == "m" and abs(m.value - mass) <= m.ci95, diag.table()
