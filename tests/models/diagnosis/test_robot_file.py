"""The corrected robot file: effects written back into the MJCF, free-run simulation error,
and the mujoco.sysid refinement.

Independent truth: MuJoCo's own inverse dynamics of the written file against the effects'
torque formulas (:mod:`mcpilco.models.diagnosis.effects`) and pinocchio's joint-torque
regressor (payload), and logs of :func:`mcpilco.envs.robot_logs.simulate_log` whose hidden
effects are known.
"""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest

from mcpilco.envs.arm_builder import arm_to_xml
from mcpilco.envs.arms import random_arm, scara
from mcpilco.envs.robot_logs import HiddenEffect, simulate_log, write_log
from mcpilco.models.diagnosis import (
    Armature,
    Cogging,
    CoulombFriction,
    DiagnosisModel,
    NominalStart,
    Payload,
    Spring,
    StribeckFriction,
    TorqueOffset,
    ViscousFriction,
    add_effect,
    free_run_error,
    load_trajectories,
    run_diagnosis,
    write_corrected_mjcf,
)
from mcpilco.models.diagnosis.effects import INERTIAL_PARAMS, FeatureContext, ParamEstimate
from mcpilco.models.diagnosis.robot_file import PAYLOAD_FALLBACK_RADIUS, FoundEffect
from mcpilco.models.diagnosis.sysid_refine import (
    inverse_dynamics_error,
    refine_with_sysid,
    replay_windows,
)

DAMPING, FRICTION = 0.5, 0.3  # hidden damping on joint 2 [N m s/rad], frictionloss on joint 3


def _est(name: str, value: float, ci: float = 0.01) -> ParamEstimate:
    return ParamEstimate(name, value, ci, "")


def _found(effect, **values) -> FoundEffect:
    return FoundEffect(effect, tuple(_est(k, v) for k, v in values.items()))


def _inverse(model: mujoco.MjModel, q, qd, qdd) -> np.ndarray:
    data = mujoco.MjData(model)
    out = np.empty_like(q)
    for k in range(q.shape[0]):
        data.qpos[:], data.qvel[:], data.qacc[:] = q[k], qd[k], qdd[k]
        mujoco.mj_inverse(model, data)
        out[k] = data.qfrc_inverse
    return out


def _states(n: int, rows: int = 20, seed: int = 0):
    rng = np.random.default_rng(seed)
    return (
        rng.uniform(-1, 1, (rows, n)) * 0.5,
        rng.normal(size=(rows, n)),
        rng.normal(size=(rows, n)),
    )


# ----------------------------------------------------------------------------- the writer
def test_writer_maps_each_effect_to_its_mjcf_attribute():
    arm = scara()  # RRPR; armature J_m K_r^2 in the file, friction left out
    xml = arm_to_xml(arm, friction=False)
    nominal = mujoco.MjModel.from_xml_string(xml)
    model = DiagnosisModel(NominalStart(xml))
    spring = Spring(joint=2, q_ref=0.1)
    found = [
        _found(ViscousFriction(joint=1), F_v=0.7),
        _found(CoulombFriction(joint=2, eps=0.01), F_c=0.3),
        _found(StribeckFriction(joint=4, velocity=0.05, eps=0.01), **{"F_c": 0.2, "F_s-F_c": 0.1}),
        _found(spring, k=5.0, c=0.5),
        _found(Armature(joint=3), I_a=0.02),
        _found(Cogging(joint=1, order=8), A=0.05),
        _found(ViscousFriction(joint=3), F_v=-0.2),
    ]
    corrected = write_corrected_mjcf(model, found)
    m = mujoco.MjModel.from_xml_string(corrected.xml)
    np.testing.assert_allclose(m.dof_damping, [0.7, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(m.dof_frictionloss, [0.0, 0.3, 0.0, 0.2])
    np.testing.assert_allclose(m.jnt_stiffness, [0.0, 5.0, 0.0, 0.0])
    assert m.qpos_spring[1] == pytest.approx(0.1 - 0.5 / 5.0)
    np.testing.assert_allclose(m.dof_armature, nominal.dof_armature + [0.0, 0.0, 0.02, 0.0])
    side = {e["effect"]: e for e in corrected.not_expressed}
    assert side["cogging:1 (n=8)"]["parameters"][0]["value"] == 0.05
    assert "no element" in side["cogging:1 (n=8)"]["reason"]
    assert "F_s - F_c" in side["stribeck:4 (v_s=0.05, eps=0.01)"]["reason"]
    assert "not > 0" in side["viscous:3"]["reason"]  # an unphysical value is not written


def test_written_file_adds_the_effect_torques_to_mujoco_inverse_dynamics():
    """mj_inverse(corrected) - mj_inverse(nominal) = the effects' torques phi^T w at any
    state (viscous, spring, armature: the smooth ones)."""
    arm = random_arm(3, seed=1, joint_types="RRR").rigid()
    xml = arm_to_xml(arm, friction=False)
    effects = [ViscousFriction(joint=1), Spring(joint=2, q_ref=0.2), Armature(joint=3)]
    weights = [np.array([0.7]), np.array([4.0, -0.3]), np.array([0.05])]
    names = [("F_v",), ("k", "c"), ("I_a",)]
    found = [
        FoundEffect(e, tuple(_est(n, float(v)) for n, v in zip(ns, w, strict=True)))
        for e, w, ns in zip(effects, weights, names, strict=True)
    ]
    corrected = write_corrected_mjcf(DiagnosisModel(NominalStart(xml)), found)
    q, qd, qdd = _states(3)
    diff = _inverse(mujoco.MjModel.from_xml_string(corrected.xml), q, qd, qdd) - _inverse(
        mujoco.MjModel.from_xml_string(xml), q, qd, qdd
    )
    ctx = FeatureContext(q=q, qd=qd, qdd=qdd, base=np.zeros_like(q), joint_types="RRR")
    expected = np.zeros_like(q)
    for e, w in zip(effects, weights, strict=True):
        expected[:, e.joint - 1] += e.columns(ctx, e.joint - 1) @ w
    np.testing.assert_allclose(diff, expected, atol=1e-9)


def _payload(m: float, c: np.ndarray, i_c: np.ndarray) -> np.ndarray:
    i_o = i_c + m * (float(c @ c) * np.eye(3) - np.outer(c, c))
    return np.array([m, *(m * c), i_o[0, 0], i_o[0, 1], i_o[1, 1], i_o[0, 2], i_o[1, 2], i_o[2, 2]])


def test_payload_body_reproduces_the_regressor_torque():
    """The payload body written from 10 inertial parameters gives, in MuJoCo, the torque
    pinocchio's joint-torque regressor predicts for them."""
    xml = arm_to_xml(scara().rigid(), friction=False)
    start = NominalStart(xml)
    pi = _payload(0.8, np.array([0.01, -0.02, 0.05]), np.diag([1e-3, 2e-3, 1.5e-3]))
    ests = tuple(_est(n, float(v)) for n, v in zip(INERTIAL_PARAMS, pi, strict=True))
    corrected = write_corrected_mjcf(
        DiagnosisModel(start), [FoundEffect(Payload(), ests, pi, np.eye(10) * 1e-6)]
    )
    assert corrected.notes == [] and corrected.not_expressed == []
    q, qd, qdd = _states(4)
    q[:, 2] = 0.05  # the quill within its stroke
    diff = _inverse(mujoco.MjModel.from_xml_string(corrected.xml), q, qd, qdd) - _inverse(
        mujoco.MjModel.from_xml_string(xml), q, qd, qdd
    )
    expected = start.robot.regressor(q, qd, qdd)[:, :, -10:] @ pi  # the last body's columns
    np.testing.assert_allclose(diff, expected, atol=1e-8)


def test_link_inertial_change_reproduces_the_regressor_torque(monkeypatch):
    """A link 40 % heavier (its 10 parameters times 1.4), written by write_link_inertial
    plugged into the writer table: in MuJoCo the torque changes by pinocchio's regressor
    columns of that link times the change."""
    import pinocchio

    from mcpilco.models.diagnosis.robot_file import WRITERS, write_link_inertial

    xml = arm_to_xml(random_arm(3, seed=1, joint_types="RRR").rigid(), friction=False)
    start = NominalStart(xml)
    pin_model = start.robot.model
    delta = 0.4 * np.asarray(pin_model.inertias[2].toDynamicParameters())
    monkeypatch.setitem(WRITERS, "offset", write_link_inertial)  # a stand-in key on joint 2
    found = FoundEffect(TorqueOffset(joint=2), (_est("m", float(delta[0])),), delta)
    result = write_corrected_mjcf(DiagnosisModel(start), [found])
    corrected, nominal = (mujoco.MjModel.from_xml_string(x) for x in (result.xml, xml))
    assert corrected.body("link2").mass[0] == pytest.approx(1.4 * nominal.body("link2").mass[0])
    first = result.changes[0]
    assert (first.element, first.attribute) == ("body link2", "mass")
    assert first.before == pytest.approx(nominal.body("link2").mass[0])
    q, qd, qdd = _states(3)
    diff = _inverse(corrected, q, qd, qdd) - _inverse(nominal, q, qd, qdd)
    data = pin_model.createData()
    expected = np.stack(
        [
            pinocchio.computeJointTorqueRegressor(pin_model, data, q[k], qd[k], qdd[k])[:, 10:20]
            @ delta
            for k in range(q.shape[0])
        ]
    )
    # the principal axes and moments pass through the MJCF text (about 6 significant digits)
    np.testing.assert_allclose(diff, expected, rtol=1e-4, atol=1e-8)


def test_inconsistent_payload_inertia_is_replaced_and_listed():
    xml = arm_to_xml(scara().rigid(), friction=False)
    pi = _payload(0.5, np.zeros(3), np.diag([1e-3, 1e-3, -1e-3]))
    ests = tuple(_est(n, float(v)) for n, v in zip(INERTIAL_PARAMS, pi, strict=True))
    corrected = write_corrected_mjcf(
        DiagnosisModel(NominalStart(xml)), [FoundEffect(Payload(), ests, pi)]
    )
    m = mujoco.MjModel.from_xml_string(corrected.xml)
    body = m.body("payload")
    assert body.mass[0] == pytest.approx(0.5)
    np.testing.assert_allclose(body.inertia, 0.4 * 0.5 * PAYLOAD_FALLBACK_RADIUS**2)
    (side,) = corrected.not_expressed  # the fitted tensor is listed with the reason
    assert "not physically consistent" in side["reason"] and side["effect"] == "payload"


def test_writer_needs_a_nominal_mjcf_start():
    from mcpilco.models.diagnosis import GIPStart

    with pytest.raises(ValueError, match="nominal MJCF start"):
        write_corrected_mjcf(DiagnosisModel(GIPStart("RRR")), [])


# ----------------------------------------------------------------------------- on logs
@pytest.fixture(scope="module")
def damped(tmp_path_factory):
    """Training and held-out logs (3 s, seeds 0 and 1) of an arm with hidden damping on
    joint 2 and frictionloss on joint 3; the nominal file has the generator's physics
    options (Euler, 1 ms), so that only the hidden effects differ; the model with both."""
    folder = tmp_path_factory.mktemp("damped")
    arm = random_arm(3, seed=1, joint_types="RRR").rigid()
    effects = [HiddenEffect("damping", 2, DAMPING), HiddenEffect("frictionloss", 3, FRICTION)]
    logs = [simulate_log(arm, effects, duration=3.0, seed=s) for s in (0, 1)]
    train, test = (
        load_trajectories([write_log(folder / f"log{s}.csv", log)]) for s, log in enumerate(logs)
    )
    xml = arm_to_xml(arm, friction=False, timestep=1e-3, integrator="Euler")
    (folder / "robot.xml").write_text(xml)
    model = DiagnosisModel(NominalStart(xml)).fit(train)
    model = add_effect(add_effect(model, ViscousFriction(joint=2)), CoulombFriction(joint=3))
    return dict(
        folder=folder, xml=xml, train=train, test=test, model=model, true_xml=logs[1].truth.true_xml
    )


def test_found_damping_and_friction_are_written(damped):
    corrected = write_corrected_mjcf(damped["model"])
    m = mujoco.MjModel.from_xml_string(corrected.xml)
    assert m.dof_damping[1] == pytest.approx(DAMPING, rel=0.05)
    assert m.dof_frictionloss[2] == pytest.approx(FRICTION, rel=0.05)
    assert m.dof_damping[[0, 2]].tolist() == [0.0, 0.0]
    written = {(c.element, c.attribute) for c in corrected.changes}
    assert written == {("joint j2", "damping"), ("joint j3", "frictionloss")}


def test_corrected_file_reproduces_the_log_better_than_the_nominal_in_free_run(damped):
    test = damped["test"]
    corrected = write_corrected_mjcf(damped["model"])
    nominal = free_run_error(damped["xml"], test)
    fixed = free_run_error(corrected.xml, test)
    true = free_run_error(damped["true_xml"], test)
    assert nominal.n_windows == fixed.n_windows == len(replay_windows(test)) >= 4
    # the joints with a hidden effect drift far less; no joint gets worse
    assert (fixed.rmse[1:] < 0.2 * nominal.rmse[1:]).all(), (fixed.rmse, nominal.rmse)
    assert (fixed.rmse <= nominal.rmse).all()
    # and the corrected file is as good as the generator's own model
    assert (fixed.rmse <= 1.5 * true.rmse + 1e-3).all(), (fixed.rmse, true.rmse)
    torque = inverse_dynamics_error(corrected.xml, test)
    assert (torque[1:] < inverse_dynamics_error(damped["xml"], test)[1:]).all()


@pytest.mark.slow
def test_sysid_moves_a_perturbed_value_toward_the_truth(damped):
    """The damping written 2x too large; mujoco.sysid's simulation-error fit brings it back
    within 10% of the truth (frictionloss written at its true value stays within 10%)."""
    found = [
        _found(ViscousFriction(joint=2), F_v=2 * DAMPING),
        _found(CoulombFriction(joint=3, eps=0.01), F_c=FRICTION),
    ]
    corrected = write_corrected_mjcf(damped["model"], found)
    lines: list[str] = []
    refined = refine_with_sysid(corrected, damped["train"], log=lines.append)
    values = {p["attribute"]: p["value"] for p in refined.parameters}
    assert values["damping"] == pytest.approx(DAMPING, rel=0.1), refined.parameters
    assert values["frictionloss"] == pytest.approx(FRICTION, rel=0.1), refined.parameters
    assert refined.cost_end < refined.cost_start
    assert not any(p["at_bound"] for p in refined.parameters)
    m = mujoco.MjModel.from_xml_string(refined.xml)
    assert m.dof_damping[1] == pytest.approx(values["damping"])
    assert any("iter" in line for line in lines)  # progress reached the log


@pytest.mark.slow
def test_run_diagnosis_writes_the_corrected_file_and_reports_free_run(damped, tmp_path):
    lines: list[str] = []
    folder = damped["folder"]
    summary = run_diagnosis(
        [folder / "log0.csv"],
        [folder / "log1.csv"],
        model=folder / "robot.xml",
        add=["viscous:2", "coulomb:3"],
        out=tmp_path,
        plots=False,
        rerun=False,
        sysid=False,
        log=lines.append,
    )
    robot = summary["robot_file"]
    assert (tmp_path / "corrected.xml").is_file() and not (tmp_path / "refined.xml").exists()
    side = json.loads((tmp_path / "corrected_effects.json").read_text())
    assert {w["attribute"] for w in side["written"]} == {"damping", "frictionloss"}
    assert robot["sysid"] == {"skipped": "sysid refinement switched off"}
    free = robot["free_run"]
    assert set(free) == {"nominal", "corrected"}
    assert free["corrected"][1] < free["nominal"][1] and free["corrected"][2] < free["nominal"][2]
    assert any("== 6. the corrected robot file" in line for line in lines)
    assert any(line.strip().startswith("corrected") and "e" in line for line in lines)


def test_robot_file_step_says_what_it_cannot_do(damped, tmp_path):
    """Held-out logs shorter than a replay window: the file is written, the free run is
    reported as skipped with the reason; current logs: no file (the effects are in A)."""
    import dataclasses

    from mcpilco.models.diagnosis.sysid_refine import robot_file_step

    test = damped["test"]
    short, _ = test.split_time(0.1)  # 0.3 s
    lines: list[str] = []
    out = robot_file_step(
        damped["model"], damped["train"], short, tmp_path, sysid=False, log=lines.append
    )
    assert (tmp_path / "corrected.xml").is_file()
    assert "long enough" in out["free_run"]["skipped"]
    assert any("no free-run figures" in line for line in lines)
    currents = dataclasses.replace(test, output="i")
    out = robot_file_step(damped["model"], currents, currents, tmp_path / "i", log=lines.append)
    assert "currents" in out["skipped"] and not (tmp_path / "i").exists()
