"""Model diagnosis: compare a model with measurements, find the missing physical effect.

The loop (:func:`run_diagnosis` runs it on files; console script ``mcpilco-diagnose``):

0. units: motor currents put into torque units with estimated or given torque constants
   (:func:`currents_to_torque`);
1. compare: :func:`fit_metrics` (nMSE, RMSE, NRMSE fit %), :func:`~.plots.plot_time`;
2. where it fails: :func:`residual_report` (binned residuals, velocity reversals,
   whiteness and cross-correlation with the inputs as MATLAB's ``resid`` tests them
   (:func:`whiteness_test`, :func:`cross_correlation_test`), worst windows and regions in
   words) against the noise floor (:func:`heldout_floor`: measurement noise plus the noise of
   estimated ``qd``/``qdd``);
3. which effect is missing: :func:`diagnose` scores every candidate of :mod:`.effects` on
   every joint by the log-evidence it adds (:mod:`mcpilco.models.gp.linear_gp`), confirms
   the best on held-out trajectories, groups look-alikes;
4. add it: ``model = add_effect(model, CoulombFriction(joint=2))`` (a new version);
5. watch the error fall: :func:`~.plots.plot_waterfall`, :func:`~.plots.write_rerun`;
   the run's :class:`DiagnosisReport` (``report.html``, one self-contained file). Parameters
   the data cannot pin down are reported as not identifiable (:mod:`.identifiability`);
6. the corrected robot file: :func:`write_corrected_mjcf` (the effects as MuJoCo physics),
   :func:`refine_with_sysid` (``mujoco.sysid``), :func:`free_run_error` (open-loop replay).
"""

from mcpilco.models.diagnosis.add import add_effect
from mcpilco.models.diagnosis.analysis import (
    CorrelationTest,
    InputNoise,
    ResidualReport,
    at_rest,
    cross_correlation_test,
    fit_metrics,
    held_still,
    input_noise,
    metrics_table,
    noise_floor,
    position_noise,
    residual_report,
    whiteness_test,
)
from mcpilco.models.diagnosis.data import as_trajectories, load_trajectories
from mcpilco.models.diagnosis.effects import (
    EFFECTS,
    Armature,
    Cogging,
    CoulombFriction,
    DeadZone,
    Delay,
    Effect,
    LinkInertia,
    Payload,
    Spring,
    StribeckFriction,
    TorqueOffset,
    TorqueScale,
    ViscousFriction,
    default_library,
    parse_effect,
)
from mcpilco.models.diagnosis.html_report import DiagnosisReport
from mcpilco.models.diagnosis.model import DiagnosisModel
from mcpilco.models.diagnosis.robot_file import CorrectedFile, write_corrected_mjcf
from mcpilco.models.diagnosis.search import (
    Candidate,
    Diagnosis,
    FloorCheck,
    Removal,
    auto_improve,
    backward_step,
    diagnose,
    floor_check,
    heldout_floor,
    heldout_rmse,
    next_version,
    refine_shape,
    score_candidates,
    score_effect,
    stepwise,
)
from mcpilco.models.diagnosis.start_models import (
    LEARNED_STARTS,
    GIPStart,
    LearnedStart,
    NominalStart,
    RBFStart,
)
from mcpilco.models.diagnosis.sysid_refine import (
    FreeRunError,
    free_run_error,
    inverse_dynamics_error,
    refine_with_sysid,
)
from mcpilco.models.diagnosis.units import (
    TorqueConstants,
    currents_to_torque,
    estimate_torque_constants,
    given_torque_constants,
)
from mcpilco.models.diagnosis.workflow import run_diagnosis
from mcpilco.models.gp.linear_gp import JointGP
from mcpilco.models.robot_data import Trajectories

__all__ = [
    "add_effect",
    "at_rest",
    "held_still",
    "EFFECTS",
    "LEARNED_STARTS",
    "Armature",
    "Candidate",
    "Cogging",
    "CorrectedFile",
    "CorrelationTest",
    "CoulombFriction",
    "DeadZone",
    "Delay",
    "Diagnosis",
    "DiagnosisModel",
    "DiagnosisReport",
    "Effect",
    "FloorCheck",
    "FreeRunError",
    "GIPStart",
    "InputNoise",
    "JointGP",
    "LearnedStart",
    "LinkInertia",
    "NominalStart",
    "Payload",
    "RBFStart",
    "ResidualReport",
    "Spring",
    "StribeckFriction",
    "TorqueConstants",
    "TorqueOffset",
    "TorqueScale",
    "Trajectories",
    "ViscousFriction",
    "as_trajectories",
    "Removal",
    "auto_improve",
    "backward_step",
    "cross_correlation_test",
    "currents_to_torque",
    "default_library",
    "diagnose",
    "estimate_torque_constants",
    "fit_metrics",
    "floor_check",
    "free_run_error",
    "given_torque_constants",
    "heldout_floor",
    "heldout_rmse",
    "input_noise",
    "inverse_dynamics_error",
    "load_trajectories",
    "metrics_table",
    "next_version",
    "noise_floor",
    "parse_effect",
    "position_noise",
    "refine_shape",
    "refine_with_sysid",
    "residual_report",
    "run_diagnosis",
    "score_candidates",
    "score_effect",
    "stepwise",
    "write_corrected_mjcf",
    "whiteness_test",
]
