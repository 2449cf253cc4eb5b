"""The Panda table (:func:`mcpilco.envs.arms.panda`) against MuJoCo Menagerie's own frames.

The MJCF below is Menagerie's ``franka_emika_panda/panda.xml`` (commit ``1b428b08``,
Apache-2.0) as published: its bodies, frames (``pos``/``quat``) and inertials, the hand and
the two fingers as bodies without joints (a rigid gripper), meshes, actuators and the
joints' armature and damping left out. The table goes through a DH conversion, a lumping of
the gripper into link 7 and the builder; this file does none of that, so agreement of the
masses, the gravity torques and the mass matrices checks the transcription.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mcpilco.envs.arm_builder import build_arm_model
from mcpilco.envs.arms import panda

MENAGERIE_PANDA = """
<mujoco model="panda_menagerie">
  <compiler angle="radian" autolimits="true"/>
  <default><joint axis="0 0 1" range="-2.8973 2.8973"/></default>
  <worldbody>
    <body name="link0">
      <inertial mass="0.629769" pos="-0.041018 -0.00014 0.049974"
        fullinertia="0.00315 0.00388 0.004285 8.2904e-7 0.00015 8.2299e-6"/>
      <body name="link1" pos="0 0 0.333">
        <inertial mass="4.970684" pos="0.003875 0.002081 -0.04762"
          fullinertia="0.70337 0.70661 0.0091170 -0.00013900 0.0067720 0.019169"/>
        <joint name="joint1"/>
        <body name="link2" quat="1 -1 0 0">
          <inertial mass="0.646926" pos="-0.003141 -0.02872 0.003495"
            fullinertia="0.0079620 2.8110e-2 2.5995e-2 -3.925e-3 1.0254e-2 7.04e-4"/>
          <joint name="joint2" range="-1.7628 1.7628"/>
          <body name="link3" pos="0 -0.316 0" quat="1 1 0 0">
            <joint name="joint3"/>
            <inertial mass="3.228604" pos="2.7518e-2 3.9252e-2 -6.6502e-2"
              fullinertia="3.7242e-2 3.6155e-2 1.083e-2 -4.761e-3 -1.1396e-2 -1.2805e-2"/>
            <body name="link4" pos="0.0825 0 0" quat="1 1 0 0">
              <inertial mass="3.587895" pos="-5.317e-2 1.04419e-1 2.7454e-2"
                fullinertia="2.5853e-2 1.9552e-2 2.8323e-2 7.796e-3 -1.332e-3 8.641e-3"/>
              <joint name="joint4" range="-3.0718 -0.0698"/>
              <body name="link5" pos="-0.0825 0.384 0" quat="1 -1 0 0">
                <inertial mass="1.225946" pos="-1.1953e-2 4.1065e-2 -3.8437e-2"
                  fullinertia="3.5549e-2 2.9474e-2 8.627e-3 -2.117e-3 -4.037e-3 2.29e-4"/>
                <joint name="joint5"/>
                <body name="link6" quat="1 1 0 0">
                  <inertial mass="1.666555" pos="6.0149e-2 -1.4117e-2 -1.0517e-2"
                    fullinertia="1.964e-3 4.354e-3 5.433e-3 1.09e-4 -1.158e-3 3.41e-4"/>
                  <joint name="joint6" range="-0.0175 3.7525"/>
                  <body name="link7" pos="0.088 0 0" quat="1 1 0 0">
                    <inertial mass="7.35522e-01" pos="1.0517e-2 -4.252e-3 6.1597e-2"
                      fullinertia="1.2516e-2 1.0027e-2 4.815e-3 -4.28e-4 -1.196e-3 -7.41e-4"/>
                    <joint name="joint7"/>
                    <body name="link8" pos="0 0 0.107">
                      <body name="hand" quat="0.9238795 0 0 -0.3826834">
                        <inertial mass="0.73" pos="-0.01 0 0.03" diaginertia="0.001 0.0025 0.0017"/>
                        <body name="left_finger" pos="0 0 0.0584">
                          <inertial mass="0.015" pos="0 0 0"
                            diaginertia="2.375e-6 2.375e-6 7.5e-7"/>
                        </body>
                        <body name="right_finger" pos="0 0 0.0584" quat="0 0 0 1">
                          <inertial mass="0.015" pos="0 0 0"
                            diaginertia="2.375e-6 2.375e-6 7.5e-7"/>
                        </body>
                      </body>
                    </body>
                  </body>
                </body>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""
# the masses listed in Menagerie's panda.xml: links 1-7, hand, two fingers (link0 is fixed)
LISTED_MOVING_MASSES = (
    4.970684, 0.646926, 3.228604, 3.587895, 1.225946, 1.666555, 0.735522, 0.73, 0.015, 0.015
)  # fmt: skip
HOME = np.array([0.0, 0.0, 0.0, -1.57079, 0.0, 1.57079, -0.7853])  # Menagerie keyframe "home"


def gravity(model: mujoco.MjModel, q: np.ndarray) -> np.ndarray:
    """``mj_inverse`` at ``(q, 0, 0)``: the gravity torques."""
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_inverse(model, data)
    return data.qfrc_inverse.copy()


def mass_matrix(model: mujoco.MjModel, q: np.ndarray) -> np.ndarray:
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_forward(model, data)
    out = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, out)
    return out


def test_panda_total_mass_is_the_sum_of_the_listed_masses() -> None:
    model = build_arm_model(panda())
    assert model.nq == 7
    np.testing.assert_allclose(model.body_mass.sum(), sum(LISTED_MOVING_MASSES), rtol=1e-12)


def test_panda_table_matches_menagerie_frames_and_inertials() -> None:
    ours = build_arm_model(panda().rigid())
    menagerie = mujoco.MjModel.from_xml_string(MENAGERIE_PANDA)
    np.testing.assert_allclose(ours.jnt_range, menagerie.jnt_range)
    rng = np.random.default_rng(0)
    poses = [HOME] + [rng.uniform(*ours.jnt_range.T) for _ in range(5)]
    for q in poses:
        g = gravity(menagerie, q)
        assert np.abs(g).max() > 5.0  # the check has something to compare
        np.testing.assert_allclose(gravity(ours, q), g, atol=1e-9)
        np.testing.assert_allclose(mass_matrix(ours, q), mass_matrix(menagerie, q), atol=1e-9)


def test_panda_gravity_at_home_agrees_with_pinocchio(tmp_path) -> None:
    """pinocchio reads Menagerie's frames itself and computes ``g(q)`` by its own RNEA."""
    pin = pytest.importorskip("pinocchio")
    path = tmp_path / "menagerie_panda.xml"
    path.write_text(MENAGERIE_PANDA)
    pmodel = pin.buildModelFromMJCF(str(path))
    assert pmodel.nq == 7
    g_pin = pin.computeGeneralizedGravity(pmodel, pmodel.createData(), HOME)
    np.testing.assert_allclose(gravity(build_arm_model(panda()), HOME), g_pin, atol=1e-8)


def test_panda_joint_one_carries_no_gravity_and_joint_two_by_hand() -> None:
    """Joint 1's axis is vertical: no gravity torque at any pose. Joint 2 (horizontal axis
    through ``(0, 0, 0.333)``) at ``q = 0`` with joint 4 bent: ``tau_2 = -g sum_k m_k x_k``
    summed over links 2..7 (``x_k``: horizontal lever arm along the axis normal), here with
    the world centres of mass of the Menagerie model (a sum written out, not an RNEA)."""
    model = build_arm_model(panda())
    g = gravity(model, HOME)
    assert abs(g[0]) < 1e-9
    menagerie = mujoco.MjModel.from_xml_string(MENAGERIE_PANDA)
    data = mujoco.MjData(menagerie)
    data.qpos[:] = HOME
    mujoco.mj_kinematics(menagerie, data)
    axis = data.xaxis[1]  # joint 2's world axis
    anchor = data.xanchor[1]
    beyond = range(menagerie.jnt_bodyid[1], menagerie.nbody)  # link2 and every body after it
    weight = np.array([0.0, 0.0, -9.81])
    # tau_2 = axis . sum_k (c_k - p) x (m_k g); the actuator supplies the opposite
    tau = sum(
        float(axis @ np.cross(data.xipos[b] - anchor, menagerie.body_mass[b] * weight))
        for b in beyond
    )
    np.testing.assert_allclose(g[1], -tau, rtol=1e-9)
