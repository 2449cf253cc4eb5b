"""Simulate a robot file against logs, and refine its written parameters with ``mujoco.sysid``.

Free-run simulation error (:func:`free_run_error`)
    The logged joint torques are replayed open loop in MuJoCo from the logged state and the
    simulated positions are compared with the logged ones. An arm under gravity replayed
    open loop drifts away from the log for reasons that have nothing to do with the model
    (the initial velocity is estimated, the torque is measured with noise and sampled), so
    the replay runs over windows of ``window`` seconds (default :data:`FREE_RUN_WINDOW`)
    re-initialised from the log: ``q(t_s)`` as logged and ``qd(t_s)`` as the loader's
    zero-lag estimate, for consecutive windows ``[t_s, t_s + window]`` of every file (the
    half derivative-filter window at each file end is skipped: the estimate is worst there).
    Inside a window the torque is interpolated linearly between samples at every physics
    step (the logged ``tau_k`` is the torque at ``t_k``); the physics timestep is the file's,
    shortened to ``T / ceil(T / dt)`` so that the samples ``T`` apart fall on steps. The
    error is the RMSE per joint of ``q_sim - q_log`` over every sample after each window's
    first [rad or m].

    The simulation runs on the file's own physics with its actuators replaced by one torque
    motor per joint (``gear = 1``, no limit: ``ctrl`` is the logged joint torque) and one
    ``jointpos`` sensor per joint (:func:`torque_driven_spec`); rollouts use
    :func:`mujoco.rollout.rollout`.

One-step torque error (:func:`inverse_dynamics_error`)
    MuJoCo's inverse dynamics (``mj_inverse``) of the file at the logged ``q`` and the
    estimated ``qd``, ``qdd``, against the logged torque: RMSE per joint. On a joint with
    ``frictionloss`` this is MuJoCo's soft dry-friction constraint at the estimated
    acceleration, which is not the ``tanh`` Coulomb torque the diagnosis fitted: the file's
    one-step error there stays above the diagnosis model's.

Refinement (:func:`refine_with_sysid`)
    The values a :class:`~.robot_file.CorrectedFile` wrote (damping, frictionloss,
    armature, stiffness, springref, payload mass) become :class:`mujoco.sysid.Parameter` s,
    starting at the diagnosis values, bounded to ``[0, max(3 v, v + 10 ci)]`` (``v``: the
    value, ``ci``: its 95 % half-width; ``springref``: ``v +- 0.5``). The replay windows of
    the training logs (at most :data:`SYSID_MAX_WINDOWS`, evenly spread) become
    :class:`mujoco.sysid.ModelSequences`, rolled out in one batch per parameter vector
    (:func:`mujoco.sysid.model_residual`); :func:`mujoco.sysid.optimize`
    minimises ``sum (q_log - q_sim)^2`` over the windows (MuJoCo's least-squares with
    finite-difference Jacobians), and :func:`mujoco.sysid.calculate_intervals` gives 95 %
    intervals from the Jacobian at the optimum (simulation errors are correlated in time,
    so these intervals are optimistic). A value that ends at a bound (within
    :data:`BOUND_FRACTION` of the range) is one the free run does not pin down (a poorly
    excited armature can run to its bound to absorb other errors): it keeps its diagnosis
    value and is reported as such. Needs the ``mujoco[sysid]`` extra
    (``pip install mcpilco[sysid]``).

:func:`robot_file_step` runs the three for :func:`~.workflow.run_diagnosis`: it writes
``corrected.xml``, ``corrected_effects.json`` (the side record) and ``refined.xml``, and
reports the free-run and one-step errors of the nominal, corrected and refined files on the
held-out logs.
"""

from __future__ import annotations

import json
import math
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from mcpilco.models.diagnosis.model import DiagnosisModel
from mcpilco.models.diagnosis.robot_file import (
    PAYLOAD_BODY,
    Change,
    CorrectedFile,
    joint_handles,
    joint_label,
    write_corrected_mjcf,
)
from mcpilco.models.diagnosis.start_models import NominalStart
from mcpilco.models.robot_data import Trajectories
from mcpilco.models.robot_files import read_robot_file, refuse_includes

FloatArray = NDArray[np.float64]

__all__ = [
    "FREE_RUN_WINDOW",
    "FreeRunError",
    "Refinement",
    "free_run_error",
    "inverse_dynamics_error",
    "refine_with_sysid",
    "replay_windows",
    "robot_file_step",
    "torque_driven_spec",
]

FREE_RUN_WINDOW = 0.5  # s: open-loop replay window, re-initialised from the log
SYSID_MAX_WINDOWS = 12  # most training windows a sysid refinement rolls out per evaluation
SYSID_MAX_ITERS = 25  # iterations of MuJoCo's least-squares in a refinement
SYSID_XTOL = 1e-4  # relative step at which the least-squares refinement stops
BOUND_FRACTION = 1e-3  # a refined value this close to a bound (of the range) is not kept
SPRINGREF_SPAN = 0.5  # rad or m: half-width of the springref bounds of a refinement
REFINABLE = ("damping", "frictionloss", "armature", "stiffness", "springref")  # joint values


# ----------------------------------------------------------------------------- simulation


def _as_spec(robot: str | Path | mujoco.MjSpec) -> mujoco.MjSpec:
    if isinstance(robot, mujoco.MjSpec):
        return robot.copy()
    text = str(robot)
    if "<" not in text:
        path = Path(text)
        if not path.is_file():
            raise ValueError(f"no MJCF file at {path}")
        text = read_robot_file(path)  # includes expanded, confined to its folder
    else:
        refuse_includes(text, "the robot description text")
    if "<mujoco" not in text:
        raise ValueError("the robot file must be MJCF (<mujoco>)")
    return mujoco.MjSpec.from_string(text)


def torque_driven_spec(robot: str | Path | mujoco.MjSpec) -> mujoco.MjSpec:
    """A copy of the robot (MJCF path, text or spec) driven by joint torques: its actuators,
    sensors and keyframes removed, one motor ``tau_<k>`` (``gear = 1``, no control limit) and
    one ``jointpos`` sensor ``q_<k>`` per hinge/slide joint, in joint order."""
    spec = _as_spec(robot)
    for key in list(spec.keys):
        spec.delete(key)
    for sensor in list(spec.sensors):
        spec.delete(sensor)
    for act in list(spec.actuators):
        spec.delete(act)
    for k, jnt in enumerate(joint_handles(spec)):
        if not jnt.name:
            jnt.name = f"joint_{k + 1}"
        act = spec.add_actuator(name=f"tau_{k + 1}", target=jnt.name)
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.set_to_motor()
        act.gear = [1.0, 0, 0, 0, 0, 0]
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        spec.add_sensor(
            name=f"q_{k + 1}",
            type=mujoco.mjtSensor.mjSENS_JOINTPOS,
            objtype=mujoco.mjtObj.mjOBJ_JOINT,
            objname=jnt.name,
        )
    return spec


def _compile(spec: mujoco.MjSpec, sample_time: float) -> tuple[mujoco.MjModel, int]:
    """The model with its timestep shortened to ``T / ceil(T / dt)``, and that step count."""
    model = spec.compile()
    sub = max(1, math.ceil(sample_time / model.opt.timestep - 1e-9))
    model.opt.timestep = sample_time / sub
    return model, sub


def replay_windows(traj: Trajectories, window: float = FREE_RUN_WINDOW) -> list[int]:
    """Start rows of the consecutive replay windows of ``window`` seconds in every segment
    (module docstring); each window holds ``round(window / T) + 1`` rows.

    Raises:
        ValueError: a window shorter than two samples, or no segment long enough for one.
    """
    m = int(round(window / traj.sample_time))
    if m < 1:
        raise ValueError(f"window {window} s is shorter than the sample time")
    starts = []
    for s, (a, b) in enumerate(traj.segments):
        edge = traj.edge_rows(s)
        starts += list(range(a + edge, b - edge - m, m))
    if not starts:
        raise ValueError(
            f"no file is long enough for one free-run window of {window} s "
            f"({m + 1} samples plus the derivative filter's ends)"
        )
    return starts


def _window_inputs(
    model: mujoco.MjModel, sub: int, traj: Trajectories, starts: Sequence[int], m: int
) -> tuple[FloatArray, FloatArray]:
    """``(initial states (W, nstate), controls (W, m sub, n))`` of the windows."""
    n = traj.n_joints
    data = mujoco.MjData(model)
    size = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    states = np.empty((len(starts), size))
    controls = np.empty((len(starts), m * sub, n))
    frac = np.arange(m * sub) / sub  # physics step k at sample k / sub
    for w, s in enumerate(starts):
        mujoco.mj_resetData(model, data)
        data.qpos[:] = traj.q[s]
        data.qvel[:] = traj.qd[s]
        mujoco.mj_getState(model, data, states[w], mujoco.mjtState.mjSTATE_FULLPHYSICS)
        tau = traj.y[s : s + m + 1]
        for j in range(n):
            controls[w, :, j] = np.interp(frac, np.arange(m + 1), tau[:, j])
    return states, controls


@dataclass
class FreeRunError:
    """Free-run simulation error of a robot file on logs (module docstring).

    Attributes:
        rmse: ``(n,)`` RMSE of ``q_sim - q_log`` per joint [rad or m].
        window: replay window [s].
        n_windows: windows replayed.
        final: ``(n,)`` RMSE at the windows' last samples.
    """

    rmse: FloatArray
    window: float
    n_windows: int
    final: FloatArray

    def to_dict(self) -> dict[str, Any]:
        return {
            "rmse": self.rmse.tolist(),
            "final_rmse": self.final.tolist(),
            "window_s": self.window,
            "n_windows": self.n_windows,
        }


def _check_joints(model: mujoco.MjModel, traj: Trajectories) -> None:
    if model.nu != traj.n_joints or model.nq != traj.n_joints:
        raise ValueError(
            f"the robot file has {model.nu} hinge/slide joints (nq={model.nq}) but the logs "
            f"have {traj.n_joints} joints"
        )
    if traj.output != "tau":
        raise ValueError("a free-run replay needs joint torques (tau columns), not currents")


def free_run_error(
    robot: str | Path | mujoco.MjSpec,
    traj: Trajectories,
    window: float = FREE_RUN_WINDOW,
    starts: Sequence[int] | None = None,
) -> FreeRunError:
    """Replay the logged torques open loop in ``robot`` (MJCF path, text or spec) over
    windows re-initialised from the log; RMSE of the positions (module docstring).

    Raises:
        ValueError: joint counts that differ, current logs, logs too short for a window.
    """
    spec = torque_driven_spec(robot)
    model, sub = _compile(spec, traj.sample_time)
    _check_joints(model, traj)
    m = int(round(window / traj.sample_time))
    starts = replay_windows(traj, window) if starts is None else list(starts)
    init, ctrl = _window_inputs(model, sub, traj, starts, m)
    from mujoco import rollout

    _, sensordata = rollout.rollout(model, mujoco.MjData(model), init, ctrl)
    q_sim = sensordata[:, sub - 1 :: sub, :]  # after steps sub, 2 sub, ..: samples 1..m
    q_log = np.stack([traj.q[s + 1 : s + m + 1] for s in starts])
    err = q_sim - q_log
    return FreeRunError(
        rmse=np.sqrt(np.mean(err**2, axis=(0, 1))),
        window=m * traj.sample_time,
        n_windows=len(starts),
        final=np.sqrt(np.mean(err[:, -1, :] ** 2, axis=0)),
    )


def inverse_dynamics_error(robot: str | Path | mujoco.MjSpec, traj: Trajectories) -> FloatArray:
    """``(n,)`` RMSE of ``mj_inverse`` of ``robot`` at the logged ``q`` and estimated
    ``qd``, ``qdd`` against the logged torque (module docstring)."""
    model, _ = _compile(torque_driven_spec(robot), traj.sample_time)
    _check_joints(model, traj)
    data = mujoco.MjData(model)
    pred = np.empty_like(traj.y)
    for k in range(traj.n_samples):
        data.qpos[:] = traj.q[k]
        data.qvel[:] = traj.qd[k]
        data.qacc[:] = traj.qdd[k]
        mujoco.mj_inverse(model, data)
        pred[k] = data.qfrc_inverse
    return np.sqrt(np.mean((traj.y - pred) ** 2, axis=0))


# ----------------------------------------------------------------------------- sysid


@dataclass
class Refinement:
    """Result of :func:`refine_with_sysid`.

    Attributes:
        xml: the refined MJCF.
        parameters: per refined value: ``element``, ``attribute``, ``effect``, ``start``
            (diagnosis value), ``value`` (written: refined, or the start when ``at_bound``),
            ``ci95`` (sysid's interval), ``bounds``, ``sysid_value`` (the optimiser's),
            ``at_bound``.
        cost_start, cost_end: ``sum (q_log - q_sim)^2`` over the training windows.
        iterations: least-squares iterations; ``seconds``: wall time.
    """

    xml: str
    parameters: list[dict[str, Any]] = field(default_factory=list)
    cost_start: float = float("nan")
    cost_end: float = float("nan")
    iterations: int = 0
    seconds: float = 0.0
    n_windows: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {
            "parameters": self.parameters,
            "cost_start": self.cost_start,
            "cost_end": self.cost_end,
            "iterations": self.iterations,
            "seconds": self.seconds,
            "n_windows": self.n_windows,
        }


def _setter(change: Change, k: int | None) -> Callable[[mujoco.MjSpec, float], None]:
    """A function writing ``change``'s attribute (a value) into a spec of the same robot."""
    attr = change.attribute
    if k is not None:

        def set_joint(spec: mujoco.MjSpec, value: float) -> None:
            jnt = joint_handles(spec)[k]
            current = getattr(jnt, attr)
            if isinstance(current, np.ndarray):
                current = current.copy()
                current[0] = value
                setattr(jnt, attr, current)
            else:
                setattr(jnt, attr, value)

        return set_joint

    def set_mass(spec: mujoco.MjSpec, value: float) -> None:  # payload: inertia scales with m
        body = spec.body(PAYLOAD_BODY)
        scale = value / body.mass if body.mass > 0 else 1.0
        body.fullinertia = (np.asarray(body.fullinertia) * scale).tolist()
        body.mass = value

    return set_mass


def _refinable(corrected: CorrectedFile) -> list[tuple[Change, Any]]:
    """``(change, setter)`` of every refinable written value."""
    spec = mujoco.MjSpec.from_string(corrected.xml)
    names = [joint_label(spec, k) for k in range(len(joint_handles(spec)))]
    out = []
    for c in corrected.changes:
        if c.attribute in REFINABLE and c.element in names:
            out.append((c, _setter(c, names.index(c.element))))
        elif c.attribute == "mass" and c.element.startswith(f"body {PAYLOAD_BODY}"):
            out.append((c, _setter(c, None)))
    return out


def _bounds(c: Change) -> tuple[float, float]:
    v = float(c.after)
    ci = float(c.ci95) if c.ci95 is not None and math.isfinite(c.ci95) else 0.0
    if c.attribute == "springref":
        return v - SPRINGREF_SPAN, v + SPRINGREF_SPAN
    return 0.0, max(3.0 * v, v + 10.0 * ci, 1e-6)


def refine_with_sysid(
    corrected: CorrectedFile,
    train: Trajectories,
    window: float = FREE_RUN_WINDOW,
    max_windows: int = SYSID_MAX_WINDOWS,
    max_iters: int = SYSID_MAX_ITERS,
    log: Callable[[str], None] = print,
) -> Refinement:
    """Refine the values ``corrected`` wrote by simulation-error fitting with
    :mod:`mujoco.sysid` over replay windows of the training logs (module docstring).

    Args:
        corrected: the corrected file (:func:`~.robot_file.write_corrected_mjcf`).
        train: training trajectories with joint torques.
        window: replay window [s].
        max_windows: most windows (evenly spread over the logs).
        max_iters: least-squares iterations.
        log: receives progress lines (at most one every two seconds).

    Raises:
        ImportError: ``mujoco.sysid`` is unusable (the ``mujoco[sysid]`` extra is missing).
        ValueError: logs too short for a window, or joint counts that differ.
    """
    try:
        from mujoco import sysid
        from mujoco.sysid._src.timeseries import TimeSeries
    except ImportError as err:  # pragma: no cover - depends on the install
        raise ImportError(
            f"mujoco.sysid is unusable ({err}); install the extra: pip install 'mcpilco[sysid]'"
        ) from err
    if not hasattr(sysid, "optimize"):
        raise ImportError(
            "mujoco.sysid is missing its optional dependencies; install the extra: "
            "pip install 'mcpilco[sysid]'"
        )
    t0 = time.perf_counter()
    spec = torque_driven_spec(corrected.xml)
    items = _refinable(corrected)
    result = Refinement(xml=corrected.xml)
    if not items:
        log("   sysid: nothing to refine (no value written that MuJoCo simulates)")
        return result
    model, sub = _compile(spec, train.sample_time)
    _check_joints(model, train)
    spec.option.timestep = model.opt.timestep
    m = int(round(window / train.sample_time))
    starts = replay_windows(train, window)
    if len(starts) > max_windows:
        pick = np.round(np.linspace(0, len(starts) - 1, max_windows)).astype(int)
        starts = [starts[i] for i in pick]
    init, ctrl = _window_inputs(model, sub, train, starts, m)
    t_ctrl = np.arange(m * sub + 1) * model.opt.timestep
    controls, sensors = [], []
    for w, s in enumerate(starts):
        u = np.vstack([ctrl[w], train.y[s + m]])  # the last row is dropped by the rollout
        controls.append(TimeSeries.from_control_names(t_ctrl, u, model))
        sensors.append(
            TimeSeries.from_names(
                np.arange(m + 1) * train.sample_time, train.q[s : s + m + 1], model
            )
        )
    sequences = sysid.ModelSequences(
        "robot", spec, [f"window {w}" for w in range(len(starts))], list(init), controls, sensors
    )
    params = sysid.ParameterDict()
    for i, (c, setter) in enumerate(items):
        lo, hi = _bounds(c)
        params.add(
            sysid.Parameter(
                f"p{i}",
                float(np.clip(c.after, lo, hi)),
                lo,
                hi,
                modifier=lambda sp, p, setter=setter: setter(sp, float(p.value[0])),
            )
        )

    def modify_residual(params_, pred, meas, model_, return_pred_all, state=None, **_):
        rows = pred.data[sub - 1 :: sub][:m]
        cut = TimeSeries(meas.times[1:], meas.data[1:], meas.signal_mapping)
        res = cut.data - rows
        return res, TimeSeries(cut.times, rows, meas.signal_mapping), cut

    windows = sequences.measured_rollout

    def build(p: Any) -> mujoco.MjModel:
        return sysid.apply_param_modifiers(p, spec)

    def residual_fn(x: FloatArray, p: Any) -> Any:
        # every window in one batched rollout per parameter vector; model_residual gives one
        # column per (vector, window): regroup them into one column per vector
        res, pred, meas = sysid.model_residual(
            x, p, build, windows, modify_residual, n_threads=1, resample_true=False
        )
        if x.ndim > 1:
            res = res.T.reshape(x.shape[1], -1).T
        return [res], pred, meas

    x0 = params.as_vector()
    r0 = np.concatenate([np.ravel(a) for a in residual_fn(x0, params)[0]])
    log(
        f"   sysid: {len(items)} values over {len(starts)} windows of {m * train.sample_time:g} "
        f"s; start cost {float(r0 @ r0):.4g}"
    )
    progress = _LogLines(log, "   sysid: ")
    opt, res = sysid.optimize(
        params,
        residual_fn,
        optimizer="mujoco",
        verbose=False,
        max_iters=max_iters,
        output=progress,
        xtol=SYSID_XTOL,
        x_scale="jac",
    )
    x = opt.as_vector()
    r = residual_fn(x, opt)[0]
    _, ci = sysid.calculate_intervals(r, np.atleast_2d(res.jac))
    lo, hi = params.get_bounds()
    at_bound = np.minimum(x - lo, hi - x) <= BOUND_FRACTION * (hi - lo)
    kept = np.where(at_bound, x0, x)  # a value the free run pushed to a bound: not refined
    if at_bound.any():
        opt.update_from_vector(kept)
        r = residual_fn(kept, opt)[0]
    final = mujoco.MjSpec.from_string(corrected.xml)
    for i, (c, setter) in enumerate(items):
        setter(final, float(kept[i]))
        result.parameters.append(
            {
                "element": c.element,
                "attribute": c.attribute,
                "effect": c.effect,
                "start": float(c.after),
                "value": float(kept[i]),
                "ci95": float("nan") if at_bound[i] else float(ci[i]),
                "bounds": [float(lo[i]), float(hi[i])],
                "sysid_value": float(x[i]),
                "at_bound": bool(at_bound[i]),
            }
        )
    final.compile()
    rr = np.concatenate([np.ravel(a) for a in r])
    result.xml = final.to_xml()
    result.cost_start = float(r0 @ r0)
    result.cost_end = float(rr @ rr)
    result.iterations = progress.lines
    result.n_windows = len(starts)
    result.seconds = time.perf_counter() - t0
    return result


class _LogLines:
    """A text stream that sends the optimiser's iteration lines to ``log`` (progress)."""

    def __init__(self, log: Callable[[str], None], prefix: str) -> None:
        self.log, self.prefix, self.buffer, self.lines = log, prefix, "", 0

    def write(self, text: str) -> int:
        self.buffer += text
        while "\n" in self.buffer:
            line, self.buffer = self.buffer.split("\n", 1)
            if line.strip():
                found = re.search(r"after (\d+) iterations", line)
                if found:
                    self.lines = int(found.group(1))
                self.log(self.prefix + " ".join(line.split()))
        return len(text)

    def flush(self) -> None:
        pass


# ----------------------------------------------------------------------------- the step


def robot_file_step(
    model: DiagnosisModel,
    train: Trajectories,
    test: Trajectories,
    out: str | Path,
    *,
    sysid: bool = True,
    window: float = FREE_RUN_WINDOW,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Write the corrected robot file of ``model`` (a nominal MJCF start), refine it with
    ``mujoco.sysid`` (unless ``sysid`` is false) and report, for the nominal, corrected and
    refined files on the held-out logs, the free-run position error next to the one-step
    torque error (module docstring).

    Writes ``out/corrected.xml``, ``out/corrected_effects.json`` and ``out/refined.xml``.
    What cannot be done is logged and returned, not raised: a start model that is not a
    nominal MJCF or logs of motor currents (``skipped``: no file), logs too short for a
    replay window (no refinement / no free-run figures, with the reason).

    Returns:
        ``files`` (paths), ``written``, ``not_expressed``, ``notes``, ``free_run``,
        ``free_run_final`` and ``torque_rmse`` (per file: per joint), ``window_s``,
        ``n_windows``, ``sysid`` (the refinement, or why it was skipped); or ``skipped``.
    """
    reason = None
    if not has_robot_file(model):
        reason = f"the start model is not a nominal MJCF ({model.start.describe()})"
    elif train.output != "tau" or test.output != "tau":
        reason = "the logs hold motor currents: the effects are not in torque units"
    elif train.torque_constants is not None and train.torque_constants.in_current.any():
        joints = [int(j) + 1 for j in np.flatnonzero(train.torque_constants.in_current)]
        reason = f"joints {joints} are diagnosed in A (torque constant not identifiable)"
    if reason is not None:
        log(f"   no corrected robot file: {reason}")
        return {"skipped": reason}
    out = Path(out)
    corrected = write_corrected_mjcf(model)
    xml_path, side_path = corrected.write(out / "corrected.xml", out / "corrected_effects.json")
    log(f"   corrected robot file: {xml_path} (side record: {side_path})")
    for line in corrected.lines():
        log(line)
    files: dict[str, str] = {"nominal": model.start.robot.text, "corrected": corrected.xml}
    summary: dict[str, Any] = {
        "files": {"corrected": str(xml_path), "side": str(side_path)},
        "written": [c.__dict__ for c in corrected.changes],
        "not_expressed": corrected.not_expressed,
        "notes": corrected.notes,
    }
    if not sysid:
        summary["sysid"] = {"skipped": "sysid refinement switched off"}
    elif not _refinable(corrected):
        summary["sysid"] = {"skipped": "no written value to refine"}
    else:
        try:
            ref = refine_with_sysid(corrected, train, window=window, log=log)
        except (ImportError, ValueError) as err:
            summary["sysid"] = {"skipped": str(err)}
        else:
            refined_path = out / "refined.xml"
            refined_path.write_text(ref.xml)
            files["refined"] = ref.xml
            summary["files"]["refined"] = str(refined_path)
            summary["sysid"] = ref.to_dict()
            for p in ref.parameters:
                if p["at_bound"]:
                    log(
                        f"   sysid {p['element']} {p['attribute']}: {p['start']:.4g} kept; the "
                        f"free run pushed it to its bound {p['sysid_value']:.4g} (not pinned "
                        "down by the logs)"
                    )
                else:
                    log(
                        f"   sysid {p['element']} {p['attribute']}: {p['start']:.4g} -> "
                        f"{p['value']:.4g} ± {p['ci95']:.2g}"
                    )
            log(
                f"   sysid: cost {ref.cost_start:.4g} -> {ref.cost_end:.4g} in "
                f"{ref.iterations} iterations ({ref.seconds:.1f} s); {refined_path}"
            )
            record = corrected.side_record()
            record["sysid"] = ref.to_dict()
            side_path.write_text(json.dumps(record, indent=1, default=float))
    if "skipped" in summary["sysid"]:
        log(f"   sysid refinement skipped: {summary['sysid']['skipped']}")
    try:
        starts = replay_windows(test, window)
    except ValueError as err:
        log(f"   no free-run figures: {err}")
        summary["free_run"] = {"skipped": str(err)}
        return summary
    free = {k: free_run_error(x, test, window, starts) for k, x in files.items()}
    torque = {k: inverse_dynamics_error(x, test) for k, x in files.items()}
    n = test.n_joints
    first = next(iter(free.values()))
    log(
        f"   held-out: free run over {first.n_windows} windows of {first.window:g} s "
        "(re-initialised from the log) and one-step torque (mj_inverse)"
    )
    log(
        f"   {'file':<10}"
        + "".join(f"{'q RMSE j' + str(j + 1):>12}" for j in range(n))
        + "".join(f"{'tau RMSE j' + str(j + 1):>13}" for j in range(n))
    )
    for k in files:
        log(
            f"   {k:<10}"
            + "".join(f"{x:>12.3g}" for x in free[k].rmse)
            + "".join(f"{x:>13.4g}" for x in torque[k])
        )
    summary["free_run"] = {k: v.rmse.tolist() for k, v in free.items()}
    summary["free_run_final"] = {k: v.final.tolist() for k, v in free.items()}
    summary["torque_rmse"] = {k: v.tolist() for k, v in torque.items()}
    summary["window_s"] = first.window
    summary["n_windows"] = first.n_windows
    return summary


def has_robot_file(model: DiagnosisModel) -> bool:
    """Whether ``model`` starts from a nominal MJCF (a corrected file can be written)."""
    return isinstance(model.start, NominalStart) and "<mujoco" in model.start.robot.text
