"""Current estimators (PP, FC), the quasi-static gate and the gated kernel.

Ground truth: a one-joint pendulum whose "current" is a known linear function of the
rigid-body terms plus, only while the joint is quasi-static (``|qd| < 0.01`` rad/s), a
known function of the controller error ``e_q`` (a stand-in for the torque stiction holds):
the FC estimator must learn that term, the PP estimator cannot.
"""

from __future__ import annotations

import io
import warnings

import gpytorch
import numpy as np
import pytest
import torch

from mcpilco.models.collision import (
    FCCurrentEstimator,
    GatedKernel,
    PPCurrentEstimator,
    as_collision_inputs,
    load_estimator,
    quasi_static_gate,
    rmse_split,
    select_sigma_v,
)

PENDULUM = """<mujoco><worldbody><body name="link1"><joint name="j1" type="hinge" axis="0 1 0"/>
<inertial pos="0.3 0 0" mass="2" diaginertia="0.01 0.01 0.01"/></body></worldbody></mujoco>"""

SIGMA_TRUE = 0.01
NOISE = 0.05
GP = dict(adam_iters=60, lbfgs_iters=20, seed=0)


def held(e_q: np.ndarray) -> np.ndarray:
    """The quasi-static term: 0.6 A per 2 mrad of position error (like K_p e_q / K_eq)."""
    return 0.6 * e_q / 0.002


def pendulum_data(n: int, seed: int) -> tuple[dict[str, np.ndarray], np.ndarray]:
    rng = np.random.default_rng(seed)
    rest = rng.random(n) < 0.4
    q = rng.uniform(-3.0, 3.0, n)
    speed = np.where(rest, rng.uniform(-0.005, 0.005, n), rng.uniform(0.05, 1.0, n))
    qd = speed * np.where(rest, 1.0, rng.choice([-1.0, 1.0], n))
    qdd = np.where(rest, rng.uniform(-0.05, 0.05, n), rng.uniform(-2.0, 2.0, n))
    e_q = np.where(rest, rng.uniform(-0.002, 0.002, n), rng.normal(0.0, 0.02, n))
    e_qd = rng.normal(0.0, 0.01, n)
    i_cmd = rng.normal(0.0, 1.0, n)  # uninformative here: no leak of i into the inputs
    rigid = 0.8 * qdd + 1.5 * np.cos(q) + 0.3 * np.sin(q) + 0.2 * qd
    i = rigid + (np.abs(qd) < SIGMA_TRUE) * held(e_q) + NOISE * rng.standard_normal(n)
    cols = dict(q=q, qd=qd, qdd=qdd, e_q=e_q, e_qd=e_qd, i_cmd=i_cmd)
    return {k: v[:, None] for k, v in cols.items()}, i[:, None]


@pytest.fixture(scope="module")
def fitted() -> dict[str, object]:
    X, y = pendulum_data(300, 0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pp = PPCurrentEstimator(PENDULUM, **GP).fit(X, y)
        fc = FCCurrentEstimator(PENDULUM, sigma_v=SIGMA_TRUE, **GP).fit(X, y)
    return {"pp": pp, "fc": fc}


def test_gate_is_one_below_sigma_v_only() -> None:
    qd = np.array([[0.0, -0.0099, 0.0099], [0.01, -0.01, 0.5]])
    np.testing.assert_array_equal(quasi_static_gate(qd, 0.01), [[1, 1, 1], [0, 0, 0]])
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="sigma_v"):
            quasi_static_gate(qd, bad)


def test_gated_kernel_is_the_base_kernel_times_the_gates() -> None:
    torch.manual_seed(0)
    n, d = 2, 3
    base = gpytorch.kernels.RBFKernel(batch_shape=torch.Size([n]), active_dims=(0, 1, 2))
    base.lengthscale = torch.tensor([[[0.7]], [[1.9]]])
    k = GatedKernel(base, gate_dims=(3, 4), batch_shape=torch.Size([n])).double()
    x1 = torch.cat([torch.randn(5, d), torch.randint(0, 2, (5, n)).float()], 1).double()
    x2 = torch.cat([torch.randn(4, d), torch.randint(0, 2, (4, n)).float()], 1).double()
    out = k(x1, x2).to_dense()
    for b in range(n):
        ls = float(base.lengthscale[b].detach())
        sq = ((x1[:, None, :d] - x2[None, :, :d]) ** 2).sum(-1)
        truth = torch.exp(-0.5 * sq / ls**2) * x1[:, d + b, None] * x2[None, :, d + b]
        torch.testing.assert_close(out[b], truth)
    diag = k(x1, x1, diag=True)
    torch.testing.assert_close(diag, torch.stack([x1[:, d + b] ** 2 for b in range(n)]))
    with pytest.raises(ValueError, match="batch_shape"):
        GatedKernel(base, gate_dims=(3,), batch_shape=torch.Size([n]))


def test_fc_learns_the_quasi_static_term_pp_cannot(fitted: dict) -> None:
    X, y = pendulum_data(400, 1)
    out = {}
    for name in ("pp", "fc"):
        mean, var = fitted[name].predict(X)
        assert mean.shape == var.shape == (400, 1) and np.all(var >= 0)
        out[name] = rmse_split(y, mean, X["qd"], SIGMA_TRUE)
    held_std = np.std(held(np.random.default_rng(0).uniform(-0.002, 0.002, 10_000)))
    assert out["fc"]["quasi_static"][0] < 2 * NOISE
    assert out["pp"]["quasi_static"][0] > 0.8 * held_std  # ~0.35 A unexplained
    for name in ("pp", "fc"):  # the rigid-body + friction part is in the PP span
        assert out[name]["dynamic"][0] < 1.6 * NOISE


def test_fc_rbf_part_is_switched_off_while_moving(fitted: dict) -> None:
    fc = fitted["fc"]
    base = dict(q=[[0.3]], qdd=[[0.0]], e_qd=[[0.0]], i_cmd=[[0.0]])
    moving = [fc.predict({**base, "qd": [[0.4]], "e_q": [[e]]}, return_var=False)[0] for e in
              (-0.0015, 0.0015)]  # fmt: skip
    np.testing.assert_allclose(moving[0], moving[1], rtol=0, atol=1e-10)
    still = [fc.predict({**base, "qd": [[0.0]], "e_q": [[e]]}, return_var=False)[0] for e in
             (-0.0015, 0.0015)]  # fmt: skip
    jump = float(still[1][0, 0] - still[0][0, 0])
    assert jump == pytest.approx(float(held(np.array(0.003))), abs=0.25)  # 0.9 A


def test_save_load_round_trip_predicts_the_same(fitted: dict) -> None:
    X, _ = pendulum_data(50, 2)
    for est in fitted.values():
        buf = io.BytesIO()
        est.save(buf)
        again = load_estimator(buf.getvalue())
        assert type(again) is type(est)
        m0, v0 = est.predict(X)
        m1, v1 = again.predict(X)
        np.testing.assert_allclose(m1, m0, rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(v1, v0, rtol=1e-6, atol=1e-10)


def test_sigma_v_cross_validation_picks_the_generating_threshold() -> None:
    X, y = pendulum_data(250, 3)
    Xv, yv = pendulum_data(250, 4)
    opts = dict(adam_iters=40, lbfgs_iters=10, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        best, scores = select_sigma_v(
            lambda sv: FCCurrentEstimator(PENDULUM, sigma_v=sv, **opts),
            X,
            y,
            Xv,
            yv,
            candidates=(0.001, SIGMA_TRUE),
        )
    assert best == SIGMA_TRUE
    assert scores[0.001] > 2 * scores[SIGMA_TRUE]


def test_inputs_are_validated_with_named_columns() -> None:
    X, y = pendulum_data(20, 5)
    fc = FCCurrentEstimator(PENDULUM)
    with pytest.raises(ValueError, match="'i_cmd'"):
        fc.fit({k: v for k, v in X.items() if k != "i_cmd"}, y)
    bad = dict(X)
    bad["e_q"] = X["e_q"].copy()
    bad["e_q"][7, 0] = np.nan
    with pytest.raises(ValueError, match="row 7 .*'e_q1'"):
        fc.fit(bad, y)
    with pytest.raises(ValueError, match="shape"):
        fc.fit(X, y[:10])
    with pytest.raises(ValueError, match="shape"):
        as_collision_inputs({**X, "qd": np.zeros((20, 2))})
    with pytest.raises(RuntimeError, match="not fitted"):
        fc.predict(X)
    arr = np.concatenate([X[g] for g in ("q", "qd", "qdd", "e_q", "e_qd", "i_cmd")], axis=1)
    inputs = as_collision_inputs(arr, n_joints=1)
    np.testing.assert_array_equal(inputs.augmented(), arr)
    with pytest.raises(ValueError, match="controller"):
        as_collision_inputs(arr[:, :3], n_joints=1).augmented()
