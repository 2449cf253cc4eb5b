"""The iiwa 14 table (:func:`mcpilco.envs.arms.iiwa14`) against MuJoCo Menagerie's own frames.

The MJCF below is Menagerie's ``kuka_iiwa_14/iiwa14.xml`` (commit ``28ffb48b``, BSD 3-Clause)
as published: its bodies, frames (``pos`` and the unnormalised ``quat`` MuJoCo normalises),
inertials and joint ranges; meshes, collision geoms, the base body's inertial (fixed to the
world) and the position servos left out. The table goes through a DH conversion and the
builder; this file does none of that, so agreement of the masses, the gravity torques, the
mass matrices and the full inverse dynamics (MuJoCo's ``mj_inverse`` of both models, and
pinocchio's RNEA of this file) checks the transcription.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mcpilco.envs.arm_builder import build_arm_model
from mcpilco.envs.arms import iiwa14
from tests.envs.test_panda import mass_matrix

MENAGERIE_IIWA14 = """
<mujoco model="iiwa14_menagerie">
  <compiler angle="radian" autolimits="true"/>
  <default><joint axis="0 0 1"/></default>
  <worldbody>
    <body name="base">
      <body name="link1" pos="0 0 0.1575">
        <inertial mass="5.76" pos="0 -0.03 0.12" diaginertia="0.0333 0.033 0.0123"/>
        <joint name="joint1" range="-2.96706 2.96706"/>
        <body name="link2" pos="0 0 0.2025" quat="0 0 1 1">
          <inertial mass="6.35" pos="0.0003 0.059 0.042" diaginertia="0.0305 0.0304 0.011"/>
          <joint name="joint2" range="-2.0944 2.0944"/>
          <body name="link3" pos="0 0.2045 0" quat="0 0 1 1">
            <inertial mass="3.5" pos="0 0.03 0.13" diaginertia="0.025 0.0238 0.0076"/>
            <joint name="joint3" range="-2.96706 2.96706"/>
            <body name="link4" pos="0 0 0.2155" quat="1 1 0 0">
              <inertial mass="3.5" pos="0 0.067 0.034" diaginertia="0.017 0.0164 0.006"/>
              <joint name="joint4" range="-2.0944 2.0944"/>
              <body name="link5" pos="0 0.1845 0" quat="0 0 1 1">
                <inertial mass="3.5" pos="0.0001 0.021 0.076" diaginertia="0.01 0.0087 0.00449"/>
                <joint name="joint5" range="-2.96706 2.96706"/>
                <body name="link6" pos="0 0 0.2155" quat="1 1 0 0">
                  <inertial mass="1.8" pos="0 0.0006 0.0004" diaginertia="0.0049 0.0047 0.0036"/>
                  <joint name="joint6" range="-2.0944 2.0944"/>
                  <body name="link7" pos="0 0.081 0" quat="0 0 1 1">
                    <inertial mass="1.2" pos="0 0 0.02" diaginertia="0.001 0.001 0.001"/>
                    <joint name="joint7" range="-3.05433 3.05433"/>
                    <site pos="0 0 0.045" name="attachment_site"/>
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
LISTED_MOVING_MASSES = (5.76, 6.35, 3.5, 3.5, 3.5, 1.8, 1.2)  # links 1-7 (base: fixed)
HOME = np.array([0.0, 0.785398, 0.0, -1.5708, 0.0, 0.0, 0.0])  # Menagerie keyframe "home"


def inverse(model: mujoco.MjModel, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """``mj_inverse`` at ``(q, qd, qdd)``: ``M(q) qdd + c(q, qd) + g(q)``."""
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:], data.qacc[:] = q, qd, qdd
    mujoco.mj_inverse(model, data)
    return data.qfrc_inverse.copy()


def random_states(model: mujoco.MjModel, count: int) -> list[tuple[np.ndarray, ...]]:
    rng = np.random.default_rng(1)
    zero = np.zeros(model.nv)
    states = [(HOME, zero, zero)]
    for _ in range(count):
        q = rng.uniform(*model.jnt_range.T)
        states.append((q, rng.normal(size=model.nv), rng.normal(size=model.nv)))
    return states


def test_iiwa14_total_mass_is_the_sum_of_the_listed_masses() -> None:
    model = build_arm_model(iiwa14())
    assert model.nq == 7
    np.testing.assert_allclose(model.body_mass.sum(), sum(LISTED_MOVING_MASSES), rtol=1e-12)


def test_iiwa14_table_matches_menagerie_inverse_dynamics() -> None:
    ours = build_arm_model(iiwa14())
    menagerie = mujoco.MjModel.from_xml_string(MENAGERIE_IIWA14)
    np.testing.assert_allclose(ours.jnt_range, menagerie.jnt_range)
    for q, qd, qdd in random_states(ours, 5):
        tau = inverse(menagerie, q, qd, qdd)
        assert np.abs(tau).max() > 5.0  # the check has something to compare
        np.testing.assert_allclose(inverse(ours, q, qd, qdd), tau, atol=1e-9)
        np.testing.assert_allclose(mass_matrix(ours, q), mass_matrix(menagerie, q), atol=1e-9)


def test_iiwa14_flange_is_menagerie_attachment_site() -> None:
    """The table's last frame ``{7}`` (site ``ee``, where a payload is mounted) is where
    Menagerie puts its ``attachment_site``, at every pose, with the same z axis."""
    ours = build_arm_model(iiwa14())
    menagerie = mujoco.MjModel.from_xml_string(MENAGERIE_IIWA14)
    for q, _, _ in random_states(ours, 5):
        a, b = mujoco.MjData(ours), mujoco.MjData(menagerie)
        a.qpos[:], b.qpos[:] = q, q
        mujoco.mj_kinematics(ours, a)
        mujoco.mj_kinematics(menagerie, b)
        ee, site = ours.site("ee").id, menagerie.site("attachment_site").id
        np.testing.assert_allclose(a.site_xpos[ee], b.site_xpos[site], atol=1e-12)
        np.testing.assert_allclose(
            a.site_xmat[ee].reshape(3, 3)[:, 2], b.site_xmat[site].reshape(3, 3)[:, 2], atol=1e-12
        )


def test_iiwa14_inverse_dynamics_agrees_with_pinocchio(tmp_path) -> None:
    """pinocchio reads Menagerie's frames itself and computes ``tau`` by its own RNEA."""
    pin = pytest.importorskip("pinocchio")
    path = tmp_path / "menagerie_iiwa14.xml"
    path.write_text(MENAGERIE_IIWA14)
    pmodel = pin.buildModelFromMJCF(str(path))
    assert pmodel.nq == 7
    ours = build_arm_model(iiwa14())
    for q, qd, qdd in random_states(ours, 3):
        tau = pin.rnea(pmodel, pmodel.createData(), q, qd, qdd)
        np.testing.assert_allclose(inverse(ours, q, qd, qdd), tau, atol=1e-8)
