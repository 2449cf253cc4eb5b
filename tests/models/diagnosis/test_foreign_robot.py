"""The diagnosis on a robot file this package did not write: Gymnasium's
``inverted_double_pendulum.xml`` (a cart on a slider carrying two hinged poles).

Independent truth: the logs are made here with MuJoCo alone (not with
:func:`mcpilco.envs.robot_logs.simulate_log`): the file with its default joint damping set to 0
is the nominal model; the true robot has a viscous damping of 0.3 N m s/rad on ``hinge2`` and
is forward-simulated (Euler, 1 ms) under a PID joint servo + gravity compensation from the nominal
model, logged every 4 ms with encoder quantisation and torque noise, only t, q and tau kept.
"""

from __future__ import annotations

import os

import mujoco
import numpy as np
import pandas as pd
import pytest

from mcpilco.models.diagnosis import DiagnosisModel, NominalStart, as_trajectories, diagnose
from mcpilco.models.diagnosis.search import FLOOR_FACTOR
from mcpilco.models.robot_data import from_frame

gymnasium = pytest.importorskip("gymnasium")

DAMPING = 0.3  # hidden viscous damping on hinge2 [N m s/rad]
DT = 1e-3  # physics step [s]
EVERY = 4  # physics steps per logged sample
TAU_NOISE = 0.02  # torque noise std [N m or N]
STEP = np.array([1e-5, 2 * np.pi / 2**16, 2 * np.pi / 2**16])  # encoder steps [m, rad, rad]


def _files() -> tuple[str, str]:
    path = os.path.join(
        os.path.dirname(gymnasium.__file__), "envs/mujoco/assets/inverted_double_pendulum.xml"
    )
    src = open(path).read()
    nominal = (
        src.replace('<joint damping="0.05"/>', '<joint damping="0"/>')
        .replace('integrator="RK4" timestep="0.01"', f'integrator="Euler" timestep="{DT}"')
        .replace('limited="true" margin="0.01" ', 'limited="false" ')
    )
    hinge2 = '<joint axis="0 1 0" name="hinge2" pos="0 0 0" type="hinge"/>'
    assert hinge2 in nominal
    true = nominal.replace(hinge2, hinge2[:-2] + f' damping="{DAMPING}"/>')
    return nominal, true


def _log(nominal: mujoco.MjModel, true: mujoco.MjModel, seed: int) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    amp = np.array([0.1, 0.17, 0.2])[:, None]  # per sinusoid, three per joint [m, rad]
    w = 2 * np.pi * rng.uniform(0.2, 0.8, (3, 3))
    ph = rng.uniform(0, 2 * np.pi, (3, 3))

    def ref(t):
        return (amp * np.sin(w * t + ph)).sum(1), (amp * w * np.cos(w * t + ph)).sum(1)

    d, dn = mujoco.MjData(true), mujoco.MjData(nominal)
    d.qpos[:], d.qvel[:] = ref(0.0)
    mujoco.mj_forward(nominal, dn)
    mass = np.zeros((3, 3))
    mujoco.mj_fullM(nominal, dn, mass)
    omega = 2 * np.pi * 3.0  # PD bandwidth [rad/s]
    kp, kd = np.diag(mass) * omega**2, 2 * np.diag(mass) * omega
    rows = []
    for k in range(int(5.0 / DT)):
        q, qd = d.qpos.copy(), d.qvel.copy()
        q_ref, qd_ref = ref(k * DT)
        dn.qpos[:], dn.qvel[:], dn.qacc[:] = q, 0.0, 0.0
        mujoco.mj_inverse(nominal, dn)  # gravity torque of the nominal model
        tau = kp * (q_ref - q) + kd * (qd_ref - qd) + dn.qfrc_inverse
        d.qfrc_applied[:] = tau
        if k % EVERY == 0:
            rows.append((k * DT, *q, *tau))
        mujoco.mj_step(true, d)
    a = np.array(rows)
    q = np.round((a[:, 1:4] + rng.normal(0, 0.3, (len(a), 3)) * STEP) / STEP) * STEP
    tau = a[:, 4:7] + rng.normal(0, TAU_NOISE, (len(a), 3))
    cols = {"t": a[:, 0]}
    cols.update({f"q{j + 1}": q[:, j] for j in range(3)})
    cols.update({f"tau{j + 1}": tau[:, j] for j in range(3)})
    return pd.DataFrame(cols)


def test_hidden_damping_on_a_gymnasium_robot_file_is_found_at_its_value():
    nominal_xml, true_xml = _files()
    nominal = mujoco.MjModel.from_xml_string(nominal_xml)
    true = mujoco.MjModel.from_xml_string(true_xml)
    frames = [_log(nominal, true, s) for s in (0, 1, 2)]
    train = as_trajectories([from_frame(f, source=f"log{s}") for s, f in enumerate(frames[:2])])
    test = as_trajectories([from_frame(frames[2], source="log2")])
    model = DiagnosisModel(NominalStart(nominal_xml)).fit(train)
    diag = diagnose(model, test)
    lead = diag.lead
    assert lead is not None and lead.label == "viscous:3", diag.table()
    f_v = lead.estimates[0]
    assert abs(f_v.value - DAMPING) <= f_v.ci95, (f_v.value, f_v.ci95)
    assert diag.base.ratio[2] > 3.0 and (diag.after.ratio <= FLOOR_FACTOR).all(), (
        diag.base.ratio,
        diag.after.ratio,
    )
