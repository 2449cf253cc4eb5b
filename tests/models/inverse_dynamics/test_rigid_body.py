"""Rigid-body features and the Fisherian estimator against the closed-form two-link arm."""

from __future__ import annotations

import numpy as np
import pytest

from mcpilco.models.inverse_dynamics import (
    FisherianEstimator,
    RigidBodyFeatures,
    as_joint_states,
    load_pinocchio_model,
)
from tests.models.inverse_dynamics.two_link import (
    FC,
    FV,
    I2,
    LC2,
    M2,
    random_states,
    two_link_data,
    two_link_mjcf,
)

pin = pytest.importorskip("pinocchio")


@pytest.fixture(scope="module")
def two_link_xml() -> str:
    return two_link_mjcf()


def test_regressor_times_model_parameters_is_the_closed_form(two_link_xml) -> None:
    X, y, _, _ = two_link_data()
    feats = RigidBodyFeatures(two_link_xml, blocks=("rigid",))
    phi = feats.features(as_joint_states(X))
    assert phi.shape == (80, 2, 20)
    np.testing.assert_allclose(phi @ feats.true_parameters(), y, atol=1e-10, rtol=0)
    flat = feats.flat_features(as_joint_states(X))
    np.testing.assert_array_equal(flat.reshape(80, 2, 20), phi)


def test_model_loads_from_text_path_and_model(two_link_xml, tmp_path) -> None:
    path = tmp_path / "arm.xml"
    path.write_text(two_link_xml)
    a = load_pinocchio_model(two_link_xml)
    b = load_pinocchio_model(str(path))
    assert load_pinocchio_model(b) is b
    assert a.nv == b.nv == 2
    with pytest.raises(ValueError, match="MJCF"):
        load_pinocchio_model("<something/>")
    with pytest.raises(ValueError, match="no robot description"):
        load_pinocchio_model(str(tmp_path / "missing.xml"))
    with pytest.raises(TypeError, match="pinocchio.Model"):
        load_pinocchio_model(3.0)


def test_local_blocks_sit_on_their_own_row(two_link_xml) -> None:
    X = random_states(5, 3)
    feats = RigidBodyFeatures(two_link_xml, blocks=("coulomb", "rigid", "viscous", "armature"))
    assert feats.blocks == ("rigid", "armature", "viscous", "coulomb")  # canonical order
    phi = feats.features(as_joint_states(X))
    assert phi.shape == (5, 2, 26)
    qd, qdd = X[:, 2:4], X[:, 4:]
    np.testing.assert_array_equal(phi[:, 0, 20:22], np.stack([qdd[:, 0], 0 * qdd[:, 0]], 1))
    np.testing.assert_array_equal(phi[:, 1, 22:24], np.stack([0 * qd[:, 1], qd[:, 1]], 1))
    np.testing.assert_array_equal(phi[:, 1, 24:26], np.stack([0 * qd[:, 0], np.sign(qd[:, 1])], 1))
    assert feats.feature_names[-1] == "coulomb_2"
    with pytest.raises(ValueError, match="subset"):
        RigidBodyFeatures(two_link_xml, blocks=("rigid", "stiction"))


def test_fe_recovers_identifiable_parameters_and_predicts_exactly(two_link_xml) -> None:
    X, y, Xt, yt = two_link_data()
    fe = FisherianEstimator(two_link_xml, blocks=("rigid",)).fit(X, y)
    w = fe.parameters_
    # link 2, parameters about its joint origin: m2 c_x = m2 lc2, I_yy = I2 + m2 lc2^2
    assert w[11] == pytest.approx(M2 * LC2, abs=1e-9)
    assert w[16] == pytest.approx(I2 + M2 * LC2**2, abs=1e-9)
    # the rest is determined up to the null space of the regressor
    mean, var = fe.predict(Xt)
    np.testing.assert_allclose(mean, yt, atol=1e-8, rtol=0)
    assert var.shape == yt.shape and np.all(var >= 0) and np.all(var < 1e-12)


def test_fe_with_friction_columns_recovers_friction(two_link_xml) -> None:
    X, y, _, _ = two_link_data()
    qd = X[:, 2:4]
    y_f = y + FV * qd + FC * np.sign(qd)
    fe = FisherianEstimator(two_link_xml, blocks=("rigid", "viscous", "coulomb")).fit(X, y_f)
    np.testing.assert_allclose(fe.parameters_[20:22], FV, atol=1e-9)
    np.testing.assert_allclose(fe.parameters_[22:24], FC, atol=1e-9)


def test_fe_rejects_wrong_joint_count(two_link_xml) -> None:
    X = random_states(10, 0)
    X3 = np.concatenate([X[:, :2], X[:, :1], X[:, 2:4], X[:, 2:3], X[:, 4:], X[:, 4:5]], 1)
    with pytest.raises(ValueError, match="2 joints"):
        FisherianEstimator(two_link_xml).fit(X3, np.zeros((10, 3)))


MJCF_WITH_DEFAULT_MASS = """
<mujoco model="two-link">
  <default><joint damping="0.05"/><geom type="capsule" mass="1"/></default>
  <option timestep="0.001"/>
  <worldbody>
    <body name="upper" pos="0 0 2">
      <joint name="shoulder" type="hinge" axis="0 1 0"/>
      <geom fromto="0 0 0 0 0 1" size="0.05"/>
      <body name="lower" pos="0 0 1">
        <joint name="elbow" type="hinge" axis="0 1 0"/>
        <geom fromto="0 0 0 0 0 1" size="0.049"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def test_mjcf_default_class_mass_is_read_as_mujoco_compiles_it():
    """A ``<default>`` geom mass (which pinocchio's importer reads as the density's mass, about
    8 kg here): the model's inverse dynamics equal MuJoCo's ``mj_inverse`` of the same file."""
    import mujoco
    import pinocchio

    model = load_pinocchio_model(MJCF_WITH_DEFAULT_MASS)
    assert [model.inertias[i].mass for i in (1, 2)] == pytest.approx([1.0, 1.0])
    mj = mujoco.MjModel.from_xml_string(MJCF_WITH_DEFAULT_MASS)
    mj.dof_damping[:] = 0.0
    data = mujoco.MjData(mj)
    rng = np.random.default_rng(3)
    for _ in range(4):
        q, qd, qdd = (rng.uniform(-2.0, 2.0, 2) for _ in range(3))
        data.qpos[:], data.qvel[:], data.qacc[:] = q, qd, qdd
        mujoco.mj_inverse(mj, data)
        tau = pinocchio.rnea(model, model.createData(), q, qd, qdd)
        np.testing.assert_allclose(tau, data.qfrc_inverse, rtol=1e-9, atol=1e-9)
