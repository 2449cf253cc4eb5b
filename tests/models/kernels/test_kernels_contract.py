"""Every kernel of mcpilco.models.kernels against the shared KernelContract."""

from __future__ import annotations

import torch

from mcpilco.models.kernels import (
    GIPKernel,
    LinearKernel,
    MPKernel,
    PolynomialKernel,
    RigidBodyDynamicsKernel,
    SEDMPKernel,
    TiedSEDMPKernel,
    gip_feature_dim,
    gip_features,
    volterra_kernel,
)
from tests.models.kernels.kernel_contract import KernelContract

EMPTY = torch.Size([])


class TestLinearKernel(KernelContract):
    input_dim = 4

    def make_kernel(self, batch_shape=EMPTY, active_dims=None):
        return LinearKernel(4, batch_shape=batch_shape, active_dims=active_dims)


class TestHomogeneousPolynomialKernel(KernelContract):
    input_dim = 3

    def make_kernel(self, batch_shape=EMPTY, active_dims=None):
        return PolynomialKernel(
            3, 3, homogeneous=True, batch_shape=batch_shape, active_dims=active_dims
        )


class TestInhomogeneousPolynomialKernel(KernelContract):
    input_dim = 3

    def make_kernel(self, batch_shape=EMPTY, active_dims=None):
        return PolynomialKernel(
            2, 3, homogeneous=False, batch_shape=batch_shape, active_dims=active_dims
        )


class TestMPKernelDegree1(KernelContract):
    input_dim = 3

    def make_kernel(self, batch_shape=EMPTY, active_dims=None):
        return MPKernel(1, 3, batch_shape=batch_shape, active_dims=active_dims)


class TestMPKernelDegree2(KernelContract):
    input_dim = 6

    def make_kernel(self, batch_shape=EMPTY, active_dims=None):
        return MPKernel(2, 6, batch_shape=batch_shape, active_dims=active_dims)


class TestMPKernelDegree3Homogeneous(KernelContract):
    input_dim = 3

    def make_kernel(self, batch_shape=EMPTY, active_dims=None):
        return MPKernel(3, 3, homogeneous=True, batch_shape=batch_shape, active_dims=active_dims)


class TestSEDMPKernel(KernelContract):
    input_dim = 5

    def make_kernel(self, batch_shape=EMPTY, active_dims=None):
        return SEDMPKernel(3, memory=4, batch_shape=batch_shape, active_dims=active_dims)


class TestTiedSEDMPKernel(KernelContract):
    input_dim = 5

    def make_kernel(self, batch_shape=EMPTY, active_dims=None):
        return TiedSEDMPKernel(3, memory=4, batch_shape=batch_shape, active_dims=active_dims)


class TestGIPKernel(KernelContract):
    joint_types = "RPR"
    input_dim = gip_feature_dim("RPR")

    def make_kernel(self, batch_shape=EMPTY, active_dims=None):
        return GIPKernel(self.joint_types, batch_shape=batch_shape, active_dims=active_dims)

    def make_inputs(self, n, seed, dtype=torch.float64):
        g = torch.Generator().manual_seed(seed)
        q, qd, qdd = torch.randn(3, n, len(self.joint_types), generator=g, dtype=torch.float64)
        return gip_features(q, qd, qdd, self.joint_types).to(dtype)


class TestRigidBodyDynamicsKernel(KernelContract):
    input_dim = 9  # [q, qd, tau] of "RPR"

    def make_kernel(self, batch_shape=EMPTY, active_dims=None):
        return RigidBodyDynamicsKernel("RPR", batch_shape=batch_shape, active_dims=active_dims)


class TestRigidBodyDynamicsKernelCoulomb(KernelContract):
    input_dim = 6  # [q, qd, tau] of "RR"

    def make_kernel(self, batch_shape=EMPTY, active_dims=None):
        return RigidBodyDynamicsKernel(
            "RR", coulomb_eps=0.2, batch_shape=batch_shape, active_dims=active_dims
        )


class TestVolterraPK(KernelContract):
    input_dim = 3

    def make_kernel(self, batch_shape=EMPTY, active_dims=None):
        return volterra_kernel(
            "pk", order=3, memory=2, batch_shape=batch_shape, active_dims=active_dims
        )


class TestVolterraIPK(KernelContract):
    input_dim = 3

    def make_kernel(self, batch_shape=EMPTY, active_dims=None):
        return volterra_kernel(
            "ipk", order=3, memory=2, batch_shape=batch_shape, active_dims=active_dims
        )


class TestVolterraMPK(KernelContract):
    input_dim = 3

    def make_kernel(self, batch_shape=EMPTY, active_dims=None):
        return volterra_kernel(
            "mpk", order=3, memory=2, batch_shape=batch_shape, active_dims=active_dims
        )


class TestVolterraSEDMPK(KernelContract):
    input_dim = 3

    def make_kernel(self, batch_shape=EMPTY, active_dims=None):
        return volterra_kernel(
            "sed_mpk", order=3, memory=2, batch_shape=batch_shape, active_dims=active_dims
        )


class TestVolterraSEDMPKTied(KernelContract):
    input_dim = 3

    def make_kernel(self, batch_shape=EMPTY, active_dims=None):
        return volterra_kernel(
            "sed_mpk_tied", order=3, memory=2, batch_shape=batch_shape, active_dims=active_dims
        )
