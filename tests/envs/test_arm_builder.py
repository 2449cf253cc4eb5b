"""The DH-table arm builder against independent truth: DH products written here and
pinocchio's RNEA on the same MJCF."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from mcpilco.envs.arm_builder import ArmSpec, DHJoint, LinkInertia, arm_to_xml, build_arm_model
from mcpilco.envs.arms import panda, random_arm, scara, ur10

ARMS = {
    "ur10": ur10(),
    "scara": scara(),
    "panda": panda(),
    "random_rrrrrr": random_arm(6, seed=1, joint_types="RRRRRR"),
    "random_prrpr": random_arm(5, seed=2, joint_types="PRRPR"),
    "random_mixed": random_arm(7, seed=3),
}


def dh_matrix(a: float, alpha: float, d: float, theta: float) -> np.ndarray:
    """Standard DH: Rz(theta) Tz(d) Tx(a) Rx(alpha), written out element by element."""
    ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
    return np.array(
        [
            [ct, -st * ca, st * sa, a * ct],
            [st, ct * ca, -ct * sa, a * st],
            [0.0, sa, ca, d],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def random_q(arm: ArmSpec, rng: np.random.Generator) -> np.ndarray:
    lo, hi = arm.joint_ranges.T
    return rng.uniform(np.maximum(lo, -math.pi), np.minimum(hi, math.pi))


@pytest.mark.parametrize("name", sorted(ARMS))
def test_site_poses_equal_dh_product(name: str) -> None:
    arm = ARMS[name]
    model = build_arm_model(arm)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    for _ in range(10):
        q = random_q(arm, rng)
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        t = np.eye(4)  # base at the world origin
        for i, (joint, qi) in enumerate(zip(arm.joints, q, strict=True), start=1):
            theta = joint.theta + (qi if joint.type == "R" else 0.0)
            d = joint.d + (qi if joint.type == "P" else 0.0)
            t = t @ dh_matrix(joint.a, joint.alpha, d, theta)
            sid = model.site(f"link{i}").id
            np.testing.assert_allclose(data.site_xpos[sid], t[:3, 3], atol=1e-12)
            np.testing.assert_allclose(data.site_xmat[sid].reshape(3, 3), t[:3, :3], atol=1e-12)
        ee = model.site("ee").id
        np.testing.assert_allclose(data.site_xpos[ee], t[:3, 3], atol=1e-12)
        np.testing.assert_allclose(data.site_xmat[ee].reshape(3, 3), t[:3, :3], atol=1e-12)


@pytest.mark.parametrize("name", sorted(ARMS))
def test_mujoco_inverse_dynamics_equals_pinocchio_rnea(name: str, tmp_path) -> None:
    pin = pytest.importorskip("pinocchio")
    arm = ARMS[name].rigid()  # no friction, no armature: pure rigid body, gravity on
    xml = arm_to_xml(arm)
    path = tmp_path / f"{name}.xml"
    path.write_text(xml)
    pmodel = pin.buildModelFromMJCF(str(path))
    pdata = pmodel.createData()
    model = mujoco.MjModel.from_xml_string(xml)  # the same text for both
    data = mujoco.MjData(model)
    assert pmodel.nq == model.nq == arm.n_joints
    np.testing.assert_allclose(np.asarray(pmodel.gravity.linear), model.opt.gravity)
    rng = np.random.default_rng(1)
    for _ in range(10):
        q = random_q(arm, rng)
        qd, qdd = rng.normal(size=(2, arm.n_joints))
        data.qpos[:], data.qvel[:], data.qacc[:] = q, qd, qdd
        mujoco.mj_inverse(model, data)
        tau_pin = pin.rnea(pmodel, pdata, q, qd, qdd)
        np.testing.assert_allclose(data.qfrc_inverse, tau_pin, atol=1e-8, rtol=0)


def test_drive_and_friction_parameters_map_to_mujoco() -> None:
    arm = ur10()
    model = build_arm_model(arm)
    for i, joint in enumerate(arm.joints):
        assert model.dof_armature[i] == pytest.approx(joint.rotor_inertia * joint.gear**2)
        assert model.dof_damping[i] == pytest.approx(joint.viscous)
        assert model.dof_frictionloss[i] == pytest.approx(joint.static_friction)
        np.testing.assert_allclose(model.jnt_range[i], joint.range)
        assert model.actuator(f"m{i + 1}").trnid[0] == model.joint(f"j{i + 1}").id
    off = build_arm_model(arm, friction=False, armature=False)
    assert not off.dof_damping.any() and not off.dof_frictionloss.any()
    assert not off.dof_armature.any()
    assert model.opt.timestep == pytest.approx(0.002)
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    assert model.nbody == 7 and model.body_mass[1:].sum() == pytest.approx(28.435)


def test_ctrl_is_joint_torque() -> None:
    # one free link about a vertical axis: qacc = tau / (I_zz + armature), no gravity torque
    joint = DHJoint(a=0.5, alpha=0.0, d=0.0, rotor_inertia=1e-4, gear=50.0)
    link = LinkInertia(2.0, (-0.25, 0.0, 0.0), (0.01, 0.05, 0.05, 0.0, 0.0, 0.0))
    arm = ArmSpec("one", (joint,), (link,))
    model = build_arm_model(arm)
    data = mujoco.MjData(model)
    data.ctrl[0] = 3.0
    mujoco.mj_forward(model, data)
    inertia = 0.05 + 2.0 * 0.25**2 + 1e-4 * 50.0**2
    assert data.qacc[0] == pytest.approx(3.0 / inertia, rel=1e-10)


def test_random_arm_is_seeded_and_xml_round_trips() -> None:
    assert random_arm(5, seed=7) == random_arm(5, seed=7)
    assert random_arm(5, seed=7) != random_arm(5, seed=8)
    model = mujoco.MjModel.from_xml_string(arm_to_xml(scara()))
    assert [model.joint(i).name for i in range(model.njnt)] == ["j1", "j2", "j3", "j4"]
    assert model.jnt_type[2] == mujoco.mjtJoint.mjJNT_SLIDE
    assert scara().joint_types == "RRPR"


def test_bad_tables_are_rejected() -> None:
    with pytest.raises(ValueError, match="joint type"):
        DHJoint(a=0.0, alpha=0.0, d=0.0, type="X")
    with pytest.raises(ValueError, match="LinkInertia per joint"):
        ArmSpec("bad", (DHJoint(0.1, 0.0, 0.0),), ())
    with pytest.raises(ValueError, match="mass"):
        LinkInertia(0.0)
    with pytest.raises(ValueError, match="static_friction"):
        DHJoint(0.1, 0.0, 0.0, coulomb=2.0, static_friction=1.0)
