"""Kinematics learning from a fixed camera and fiducial markers (thesis chapter 2).

* :mod:`~mcpilco.models.kinematics.structure` -- structure identification: the prismatic and
  revolute tests on triplets (marker, marker, joint signal), eqs. 2.17-2.19, and the
  iterative algorithm of Fig. 2.3 -> :class:`KinematicStructure`.
* :mod:`~mcpilco.models.kinematics.forward` -- forward kinematics GP with the polynomial
  kernels ``k_R`` / ``k_l`` (eqs. 2.22-2.23) and the gradient kinematic controller (2.24).
* :mod:`~mcpilco.models.kinematics.chain` -- beyond the thesis: the end-marker FK composed
  from one-joint GPs along the identified marker chain (every marker of each frame used).
* :mod:`~mcpilco.models.kinematics.rotations` -- yaw-pitch-roll conventions (eq. 2.20).
* :mod:`~mcpilco.models.kinematics.synthetic` -- numpy DH chains with markers (section 2.6).

Inputs are arrays of marker poses ``[x, y, z, gamma, beta, alpha]`` and joint signals; this
package imports nothing from ``mcpilco.envs``.
"""

from mcpilco.models.kinematics.chain import ChainFKPredictor, ChainForwardKinematicsGP
from mcpilco.models.kinematics.forward import (
    FKPredictor,
    ForwardKinematicsGP,
    design_subset,
    fk_features,
    gradient_kinematic_controller,
    multi_start_controller,
    nearest_data_starts,
)
from mcpilco.models.kinematics.rotations import (
    matrix_to_ypr,
    relative_poses,
    wrap_angle,
    ypr_to_matrix,
)
from mcpilco.models.kinematics.structure import (
    KinematicStructure,
    TripletResult,
    classify_all_triplets,
    classify_triplet,
    find_base_marker,
    identify_structure,
    prismatic_test,
    revolute_linear_test,
    revolute_nonlinear_test,
)
from mcpilco.models.kinematics.synthetic import SyntheticChain, random_chain, sum_of_sinusoids

__all__ = [
    "ChainFKPredictor",
    "ChainForwardKinematicsGP",
    "FKPredictor",
    "ForwardKinematicsGP",
    "design_subset",
    "fk_features",
    "gradient_kinematic_controller",
    "multi_start_controller",
    "nearest_data_starts",
    "KinematicStructure",
    "SyntheticChain",
    "TripletResult",
    "classify_all_triplets",
    "classify_triplet",
    "find_base_marker",
    "identify_structure",
    "matrix_to_ypr",
    "prismatic_test",
    "random_chain",
    "relative_poses",
    "revolute_linear_test",
    "revolute_nonlinear_test",
    "sum_of_sinusoids",
    "wrap_angle",
    "ypr_to_matrix",
]
