"""GIP: feature map, validation, structure, and the 2-link planar arm inverse dynamics."""

from __future__ import annotations

import math

import pytest
import torch
from gpytorch.kernels import RBFKernel, ScaleKernel

from mcpilco.models.kernels import (
    GIPKernel,
    MPKernel,
    gip_feature_dim,
    gip_feature_names,
    gip_features,
)

# --- feature map ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("joint_types", "dim"), [("R", 4), ("P", 3), ("RR", 9), ("RP", 8), ("RRPR", 21)]
)
def test_feature_dim(joint_types, dim):
    n, n_r = len(joint_types), joint_types.count("R")
    assert dim == 2 * n_r + (n - n_r) + n * (n + 1) // 2 + n  # thesis: gamma
    assert gip_feature_dim(joint_types) == dim
    assert len(gip_feature_names(joint_types)) == dim


def test_features_by_hand():
    q = torch.tensor([0.3, 1.2], dtype=torch.float64)
    qd = torch.tensor([2.0, 3.0], dtype=torch.float64)
    qdd = torch.tensor([5.0, 7.0], dtype=torch.float64)
    x = gip_features(q, qd, qdd, "RP")
    expected = [math.cos(0.3), math.sin(0.3), 1.2, 4.0, 6.0, 9.0, 5.0, 7.0]
    torch.testing.assert_close(x, torch.tensor(expected, dtype=torch.float64))
    assert gip_feature_names("RP") == [
        "cos(q1)",
        "sin(q1)",
        "q2",
        "qd1*qd1",
        "qd1*qd2",
        "qd2*qd2",
        "qdd1",
        "qdd2",
    ]


def test_features_batch_dims_and_order():
    q, qd, qdd = torch.randn(3, 4, 5, 4)
    x = gip_features(q, qd, qdd, "PRRP")
    assert x.shape == (4, 5, gip_feature_dim("PRRP"))
    names = gip_feature_names("PRRP")
    torch.testing.assert_close(x[..., names.index("sin(q3)")], torch.sin(q[..., 2]))
    torch.testing.assert_close(x[..., names.index("q4")], q[..., 3])
    torch.testing.assert_close(x[..., names.index("qd2*qd4")], qd[..., 1] * qd[..., 3])


@pytest.mark.parametrize("bad", ["", "RXR", "rr", "R P", "RR2"])
def test_bad_joint_types_raise_value_error(bad):
    with pytest.raises(ValueError, match="joint_types"):
        gip_feature_dim(bad)
    with pytest.raises(ValueError, match="joint_types"):
        GIPKernel(bad)


def test_non_string_joint_types_raise_type_error():
    with pytest.raises(TypeError):
        GIPKernel(["R", "R"])


def test_feature_shape_mismatch_raises():
    with pytest.raises(ValueError, match=r"\(\.\.\., 2\)"):
        gip_features(torch.zeros(5, 3), torch.zeros(5, 3), torch.zeros(5, 3), "RR")
    with pytest.raises(ValueError, match="same shape"):
        gip_features(torch.zeros(5, 2), torch.zeros(4, 2), torch.zeros(5, 2), "RR")


# --- structure -----------------------------------------------------------------------------


def test_gip_is_product_of_mpks_on_the_thesis_blocks():
    """k = prod_b k2_mpk([cos q_b, sin q_b]) * k2_mpk(q_p) * k1_mpk([qdd, qd_v]) (eq. 3.11)."""
    jt = "RPR"
    k = GIPKernel(jt).double()
    with torch.no_grad():
        for p in k.parameters():
            p.normal_(generator=torch.Generator().manual_seed(2))
    q, qd, qdd = torch.randn(3, 6, 3, dtype=torch.float64)
    x = gip_features(q, qd, qdd, jt)
    expected = torch.ones(6, 6, dtype=torch.float64)
    for b, kb in enumerate(k.joint_kernels):
        ref = MPKernel(2, 2 if jt[b] == "R" else 1).double()
        ref.Sigma_diag, ref.sigma2 = kb.Sigma_diag.detach(), kb.sigma2.detach()
        zb = torch.stack([q[:, b].cos(), q[:, b].sin()], -1) if jt[b] == "R" else q[:, b : b + 1]
        expected = expected * ref(zb).to_dense()
    ref = MPKernel(1, 3 + 6).double()
    ref.Sigma_diag, ref.sigma2 = k.dynamics_kernel.Sigma_diag.detach(), k.dynamics_kernel.sigma2
    rows, cols = torch.triu_indices(3, 3)
    expected = expected * ref(torch.cat([qd[:, rows] * qd[:, cols], qdd], -1)).to_dense()
    torch.testing.assert_close(k(x).to_dense(), expected)


# --- independent truth: inverse dynamics of a planar 2R arm --------------------------------

M1, M2, L1, LC1, LC2, I1, I2, G = 1.3, 0.8, 0.9, 0.45, 0.35, 0.09, 0.05, 9.81


def two_link_inverse_dynamics(q, qd, qdd):
    """tau = M(q) qdd + C(q, qd) qd + g(q) of the planar 2R arm, gravity along -y."""
    c2, s2 = torch.cos(q[:, 1]), torch.sin(q[:, 1])
    m11 = M1 * LC1**2 + I1 + M2 * (L1**2 + LC2**2 + 2 * L1 * LC2 * c2) + I2
    m12 = M2 * (LC2**2 + L1 * LC2 * c2) + I2
    m22 = M2 * LC2**2 + I2
    h = M2 * L1 * LC2 * s2
    g1 = (M1 * LC1 + M2 * L1) * G * torch.cos(q[:, 0]) + M2 * LC2 * G * torch.cos(q.sum(1))
    g2 = M2 * LC2 * G * torch.cos(q.sum(1))
    tau1 = m11 * qdd[:, 0] + m12 * qdd[:, 1] - h * (2 * qd[:, 0] * qd[:, 1] + qd[:, 1] ** 2) + g1
    tau2 = m12 * qdd[:, 0] + m22 * qdd[:, 1] + h * qd[:, 0] ** 2 + g2
    return torch.stack([tau1, tau2], -1)


def sample_arm(n, seed):
    g = torch.Generator().manual_seed(seed)
    q = (2 * torch.rand(n, 2, generator=g, dtype=torch.float64) - 1) * math.pi
    qd = (2 * torch.rand(n, 2, generator=g, dtype=torch.float64) - 1) * 2.0
    qdd = (2 * torch.rand(n, 2, generator=g, dtype=torch.float64) - 1) * 4.0
    return q, qd, qdd, two_link_inverse_dynamics(q, qd, qdd)


def nmse(pred, target):
    return (((pred - target) ** 2).mean(0) / target.var(0)).max().item()


def test_gip_rkhs_contains_the_arm_inverse_dynamics_kernel_interpolation():
    """No hyperparameter fitting: with default hyperparameters the GIP interpolant of 200
    noiseless samples is (almost) exact, because the targets lie in the kernel's finite
    dimensional RKHS (150 independent functions on the data, Proposition 3.3.1)."""
    q, qd, qdd, tau = sample_arm(200, 0)
    qt, qdt, qddt, taut = sample_arm(1000, 1)
    k = GIPKernel("RR").double()
    x, xt = gip_features(q, qd, qdd, "RR"), gip_features(qt, qdt, qddt, "RR")
    with torch.no_grad():
        K = k(x).to_dense()
        alpha = torch.linalg.solve(K + 1e-9 * K.diagonal().mean() * torch.eye(200).double(), tau)
        pred = k(xt, x).to_dense() @ alpha
    assert nmse(pred, taut) < 1e-6


@pytest.fixture
def one_thread():
    """Small dense problems run faster on one thread on a shared machine; restore after."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def test_gip_gp_fits_arm_inverse_dynamics_and_beats_rbf(one_thread):
    """GIP GP from 200 noiseless samples, nMSE < 1e-4 on 1000 fresh
    samples; an RBF GP on x = (q, qd, qdd) does more than 10x worse.

    The targets are noiseless and the GIP Gram matrix has rank 150 < 200, so the noise floor
    is raised to 1e-6 (standardised units) to keep K + sigma_n^2 I well conditioned.
    """
    gp_mod = pytest.importorskip("mcpilco.models.gp")
    q, qd, qdd, tau = sample_arm(200, 0)
    qt, qdt, qddt, taut = sample_arm(1000, 1)
    fit = {"adam_iters": 30, "adam_lr": 0.05, "lbfgs_iters": 20}
    noise = {"noise_init": 1e-4, "noise_min": 1e-6}

    gip = gp_mod.GPRegressor(lambda bs: GIPKernel("RR", batch_shape=bs), **noise)
    gip.fit(gip_features(q, qd, qdd, "RR"), tau, **fit)
    gip_mean, _ = gip.predict(gip_features(qt, qdt, qddt, "RR"))

    def rbf(bs):
        return ScaleKernel(RBFKernel(ard_num_dims=6, batch_shape=bs), batch_shape=bs)

    gp_rbf = gp_mod.GPRegressor(rbf, **noise)
    gp_rbf.fit(torch.cat([q, qd, qdd], -1), tau, **fit)
    rbf_mean, _ = gp_rbf.predict(torch.cat([qt, qdt, qddt], -1))

    gip_err, rbf_err = nmse(gip_mean, taut), nmse(rbf_mean, taut)
    assert gip_err < 1e-4, gip_err
    assert rbf_err > 10 * gip_err, (gip_err, rbf_err)


def test_float64_gip_on_float32_inputs_returns_float32():
    k = GIPKernel("RP", batch_shape=torch.Size([2])).double()
    q, qd, qdd = torch.randn(3, 6, 2)
    x = gip_features(q, qd, qdd, "RP")
    K32 = k(x).to_dense()
    assert K32.dtype == torch.float32 and K32.shape == (2, 6, 6)
    torch.testing.assert_close(K32.double(), k(x.double()).to_dense(), rtol=1e-5, atol=1e-5)
