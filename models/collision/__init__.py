"""Proprioceptive collision detection with GP models of the motor currents (thesis ch. 4).

A GP trained on collision-free data predicts the motor currents ``i_hat``; the monitoring
signal ``s = i - i_hat`` is compared with per-joint thresholds; a collision is flagged when
any joint exceeds its threshold (optionally for ``m`` consecutive samples).

=================================  =========================================================
name                               meaning
=================================  =========================================================
:class:`PPCurrentEstimator`        PP: linear kernel on ``[phi_d_i, sign(qd_i), qd_i]``
                                   (eq. 4.7)
:class:`SPCurrentEstimator`        SP: PP + RBF on ``x = [q, qd, qdd]`` (eq. 3.7)
:class:`FCCurrentEstimator`        FC: PP + ``a_i(x) RBF(x_bar)``, ``x_bar = [q, qd, qdd, e_q,
                                   ed_q, i_c]``, gate ``a_i = 1{|qd_i| < sigma_v}``
                                   (eqs. 4.8-4.10)
:func:`quasi_static_gate`          ``a_i(x)`` (eq. 4.9)
:func:`select_sigma_v`             ``sigma_v`` by hold-out cross-validation
:func:`max_error_threshold`        thesis rule ``sigma_CD = max |s|`` on collision-free data
:func:`quantile_threshold`         ``1 - alpha`` quantile of ``|s|`` or ``|s| / sigma(x)``
:class:`CollisionDetector`         estimator + thresholds (``"max"`` or ``"variance"`` rule,
                                   ``k sigma(x)``) + persistence; save / load
:func:`evaluate_detection`         detection rate, latency, false alarms per minute
:func:`train_detector`             a detector trained and calibrated on collision-free logs
:func:`load_log`                   read and check a logged file (:mod:`.files`)
:func:`plot_detection`             currents, monitoring ratio and alarms of a run
=================================  =========================================================

Nothing here imports ``mcpilco.envs``: data come as
:class:`~mcpilco.models.robot_data.Trajectories` or arrays (schema groups ``q, qd, qdd, i,
i_cmd, e_q, e_qd, contact``).
"""

from mcpilco.models.collision.detector import (
    RULES,
    CollisionDetector,
    Detection,
    alarm_flags,
    evaluate_detection,
    max_error_threshold,
    monitoring_signal,
    persistent,
    quantile_threshold,
    runs,
)
from mcpilco.models.collision.estimators import (
    COULOMB_VELOCITY,
    ESTIMATORS,
    FRICTION_BLOCKS,
    SIGMA_V,
    CurrentEstimator,
    FCCurrentEstimator,
    GatedKernel,
    PPCurrentEstimator,
    SPCurrentEstimator,
    load_estimator,
    make_estimator,
    rmse_split,
    select_sigma_v,
)
from mcpilco.models.collision.files import (
    INTERVAL_COLUMNS,
    InputError,
    check_sample_time,
    load_log,
    train_detector,
    write_intervals,
)
from mcpilco.models.collision.inputs import (
    CONTROLLER_GROUPS,
    STATE_GROUPS,
    CollisionInputs,
    as_collision_inputs,
    quasi_static_gate,
)
from mcpilco.models.collision.plots import plot_detection

__all__ = [
    "CONTROLLER_GROUPS",
    "COULOMB_VELOCITY",
    "ESTIMATORS",
    "FRICTION_BLOCKS",
    "INTERVAL_COLUMNS",
    "RULES",
    "SIGMA_V",
    "STATE_GROUPS",
    "CollisionDetector",
    "CollisionInputs",
    "CurrentEstimator",
    "Detection",
    "FCCurrentEstimator",
    "GatedKernel",
    "InputError",
    "PPCurrentEstimator",
    "SPCurrentEstimator",
    "alarm_flags",
    "as_collision_inputs",
    "check_sample_time",
    "evaluate_detection",
    "load_estimator",
    "load_log",
    "make_estimator",
    "max_error_threshold",
    "monitoring_signal",
    "persistent",
    "plot_detection",
    "quantile_threshold",
    "quasi_static_gate",
    "rmse_split",
    "runs",
    "select_sigma_v",
    "train_detector",
    "write_intervals",
]
