"""Model diagnosis: compare a model with measurements, find the missing physical effect.

The loop (:func:`run_diagnosis` runs it on files; console script ``mcpilco-diagnose``):

1. compare: :func:`fit_metrics` (nMSE, RMSE, NRMSE fit %), :func:`~.plots.plot_time`;
2. where it fails: :func:`residual_report` (binned residuals, velocity reversals,
   autocorrelation, worst windows and regions in words) against the noise floor
   (:func:`heldout_floor`: measurement noise plus the noise of estimated ``qd``/``qdd``);
3. which effect is missing: :func:`diagnose` scores every candidate of :mod:`.effects` on
   every joint by the log-evidence it adds (:mod:`mcpilco.models.gp.linear_gp`), confirms
   the best on held-out trajectories, groups look-alikes;
4. add it: ``model = model.add(CoulombFriction(joint=2))`` (a new version);
5. watch the error fall: :func:`~.plots.plot_waterfall`, :func:`~.plots.write_rerun`.
"""

from mcpilco.models.diagnosis.analysis import (
    InputNoise,
    ResidualReport,
    fit_metrics,
    input_noise,
    metrics_table,
    noise_floor,
    position_noise,
    residual_report,
)
from mcpilco.models.diagnosis.data import Trajectories, as_trajectories, load_trajectories
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
    ViscousFriction,
    default_library,
    parse_effect,
)
from mcpilco.models.diagnosis.model import DiagnosisModel
from mcpilco.models.diagnosis.search import (
    Candidate,
    Diagnosis,
    FloorCheck,
    auto_improve,
    diagnose,
    floor_check,
    heldout_floor,
    heldout_rmse,
    next_version,
    refine_shape,
    score_candidates,
    score_effect,
)
from mcpilco.models.diagnosis.start_models import (
    LEARNED_STARTS,
    GIPStart,
    LearnedStart,
    NominalStart,
    RBFStart,
)
from mcpilco.models.diagnosis.workflow import run_diagnosis
from mcpilco.models.gp.linear_gp import JointGP

__all__ = [
    "EFFECTS",
    "LEARNED_STARTS",
    "Armature",
    "Candidate",
    "Cogging",
    "CoulombFriction",
    "DeadZone",
    "Delay",
    "Diagnosis",
    "DiagnosisModel",
    "Effect",
    "FloorCheck",
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
    "TorqueOffset",
    "Trajectories",
    "ViscousFriction",
    "as_trajectories",
    "auto_improve",
    "default_library",
    "diagnose",
    "fit_metrics",
    "floor_check",
    "heldout_floor",
    "heldout_rmse",
    "input_noise",
    "load_trajectories",
    "metrics_table",
    "next_version",
    "noise_floor",
    "parse_effect",
    "position_noise",
    "refine_shape",
    "residual_report",
    "run_diagnosis",
    "score_candidates",
    "score_effect",
]
