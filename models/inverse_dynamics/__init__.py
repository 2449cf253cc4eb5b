"""Inverse-dynamics estimators: GIP, RBF, NN and rigid-body (FE, PP, SP) (thesis ch. 3).

One interface (:class:`InverseDynamicsEstimator`): ``fit(X, y)`` with ``X`` a
:class:`~mcpilco.models.robot_data.Trajectories` or an ``(N, 3n)`` array ``[q, qd, qdd]`` and
``y`` the joint torques ``(N, n)``; ``predict(X) -> (mean, var)`` as numpy ``(N, n)`` arrays
(``var`` is ``None`` for the neural network).

=================================  =========================================================
estimator                          model
=================================  =========================================================
:class:`GIPEstimator`              GP, GIP kernel on ``F(q, qd, qdd)`` (eq. 3.8, 3.11)
:class:`GIPFrictionEstimator`      GIP + linear kernel on the joint's ``[qd, sign qd]``
:class:`NystromGIPEstimator`       GIP on every row: Nystroem features, Bayesian linear reg.
:class:`LagrangianEstimator`       the rigid-body terms of a chain's Lagrangian, every row
:class:`ChainEstimator`            a serial chain's inertias and kinematics, every row
:class:`RBFEstimator`              GP, RBF-ARD kernel on ``[q, qd, qdd]``
:class:`NNEstimator`               MLP 2 x 400, Adam, early stopping
:class:`FisherianEstimator`        least squares on the nominal regressor (FE, eq. 3.2)
:class:`PPEstimator`               GP, linear kernel on the nominal regressor (eq. 3.6)
:class:`SPEstimator`               PP + RBF (eq. 3.7)
=================================  =========================================================

The model-based estimators take the NOMINAL robot as a ``pinocchio.Model`` or an MJCF/URDF
path or text (:func:`load_pinocchio_model`); their features come in composable blocks
(:class:`RigidBodyFeatures`: ``rigid``, ``armature``, ``viscous``, ``coulomb``).
"""

from mcpilco.models.inverse_dynamics.base import InverseDynamicsEstimator, gmse, nmse
from mcpilco.models.inverse_dynamics.gp_estimators import (
    GIPEstimator,
    GIPFrictionEstimator,
    GPInverseDynamics,
    NystromGIPEstimator,
    PPEstimator,
    RBFEstimator,
    SPEstimator,
    rbf_kernel,
)
from mcpilco.models.inverse_dynamics.inputs import (
    JointStates,
    as_joint_states,
    as_targets,
    input_names,
    stack_states,
)
from mcpilco.models.inverse_dynamics.kernels import RowLinearKernel
from mcpilco.models.inverse_dynamics.nn import NNEstimator
from mcpilco.models.inverse_dynamics.rigid_body import (
    FEATURE_BLOCKS,
    LOCAL_BLOCKS,
    FisherianEstimator,
    RigidBodyFeatures,
    load_pinocchio_model,
    pseudo_inertia,
)
from mcpilco.models.inverse_dynamics.rigid_span import (
    MAX_RIGID_FEATURES,
    ChainEstimator,
    LagrangianEstimator,
    armature_columns,
    chain_columns,
    difference_noise,
    joint_local_columns,
    lagrangian_columns,
    lagrangian_parameters,
)

__all__ = [
    "FEATURE_BLOCKS",
    "MAX_RIGID_FEATURES",
    "LOCAL_BLOCKS",
    "FisherianEstimator",
    "GIPEstimator",
    "GIPFrictionEstimator",
    "NystromGIPEstimator",
    "GPInverseDynamics",
    "InverseDynamicsEstimator",
    "JointStates",
    "ChainEstimator",
    "LagrangianEstimator",
    "NNEstimator",
    "PPEstimator",
    "RBFEstimator",
    "RowLinearKernel",
    "RigidBodyFeatures",
    "SPEstimator",
    "as_joint_states",
    "as_targets",
    "gmse",
    "input_names",
    "armature_columns",
    "difference_noise",
    "joint_local_columns",
    "chain_columns",
    "lagrangian_columns",
    "lagrangian_parameters",
    "load_pinocchio_model",
    "pseudo_inertia",
    "nmse",
    "rbf_kernel",
    "stack_states",
]
