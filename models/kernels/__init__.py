"""Kernels for structured GP regression: linear, PK/IPK, MPK, SED-MPK, GIP, rigid-body dynamics.

All are ``gpytorch.kernels.Kernel`` subclasses with a dense matmul-form ``forward``; see each
class for the maths (thesis chapters 3 and 6).
"""

from mcpilco.models.kernels._base import NO_BATCH, DenseKernel, check_positive_int, weighted_inner
from mcpilco.models.kernels.gip import (
    GIPKernel,
    check_joint_types,
    gip_feature_dim,
    gip_feature_names,
    gip_features,
)
from mcpilco.models.kernels.linear import LinearKernel
from mcpilco.models.kernels.mpk import MPKernel
from mcpilco.models.kernels.polynomial import PolynomialKernel
from mcpilco.models.kernels.rigid_body import (
    RigidBodyDynamicsKernel,
    rigid_body_feature_dim,
    rigid_body_feature_names,
    rigid_body_features,
)
from mcpilco.models.kernels.sed_mpk import SEDMPKernel, TiedSEDMPKernel, sed_matrix
from mcpilco.models.kernels.volterra import VOLTERRA_KINDS, volterra_kernel

__all__ = [
    "NO_BATCH",
    "DenseKernel",
    "GIPKernel",
    "LinearKernel",
    "MPKernel",
    "PolynomialKernel",
    "RigidBodyDynamicsKernel",
    "SEDMPKernel",
    "TiedSEDMPKernel",
    "VOLTERRA_KINDS",
    "check_joint_types",
    "check_positive_int",
    "gip_feature_dim",
    "gip_feature_names",
    "gip_features",
    "rigid_body_feature_dim",
    "rigid_body_feature_names",
    "rigid_body_features",
    "sed_matrix",
    "volterra_kernel",
    "weighted_inner",
]
