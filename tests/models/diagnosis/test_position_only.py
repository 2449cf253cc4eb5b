"""Position-only files: qd/qdd estimated by the documented Savitzky-Golay filter.

Truth is analytic (``q = A sin(w t)``) or the simulator's exact states.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from mcpilco.models.diagnosis.data import (
    DERIVATIVE_WINDOW,
    choose_derivative_filter,
    derivative_filter,
    estimate_derivatives,
    load_trajectories,
)

A, W, DT, N = 0.8, 2 * math.pi * 0.5, 0.004, 2500
STEP = 2 * math.pi / 2**17  # encoder step [rad]
NOISE = 0.3  # encoder reading noise [counts]


def encoder(q, rng):
    return np.round((q + rng.normal(0.0, NOISE * STEP, q.shape)) / STEP) * STEP


def analytic(rng):
    t = np.arange(N) * DT
    q = np.stack([A * np.sin(W * t), 0.5 * A * np.cos(2 * W * t)], axis=1)
    qd = np.stack([A * W * np.cos(W * t), -A * W * np.sin(2 * W * t)], axis=1)
    qdd = np.stack([-A * W**2 * np.sin(W * t), -2 * A * W**2 * np.cos(2 * W * t)], axis=1)
    return t, q, qd, qdd


def test_filter_follows_the_sample_time():
    for dt in (0.002, 0.004, 0.008):
        f = derivative_filter(dt)
        assert f.window % 2 == 1 and abs((f.window - 1) * dt - 0.1) <= 1.01 * dt
        assert f.order == 4 and f.lag == 0.0
        assert 5.0 < f.bandwidth_qd < 12.0 and 5.0 < f.bandwidth_qdd < 12.0
    assert derivative_filter(0.05).window == 7  # never shorter than order + 3


def test_estimates_match_the_analytic_derivatives():
    """Interior errors: qd within 2e-3 rad/s (0.1 % of A w), qdd within 0.25 rad/s^2
    (3 % of A w^2), and their rms within 0.7..1.4 x the filter's noise gain."""
    rng = np.random.default_rng(0)
    t, q, qd, qdd = analytic(rng)
    qd_hat, qdd_hat, filt = estimate_derivatives(t, encoder(q, rng))
    m = filt.window // 2
    e1, e2 = (qd_hat - qd)[m:-m], (qdd_hat - qdd)[m:-m]
    assert np.abs(e1).max() < 2e-3
    assert np.abs(e2).max() < 0.25
    sigma_q = STEP * math.sqrt(NOISE**2 + 1 / 12)
    for err, gain in ((e1, filt.noise_gain_qd), (e2, filt.noise_gain_qdd)):
        ratio = np.sqrt((err**2).mean(axis=0)) / (gain * sigma_q)
        assert ((ratio > 0.7) & (ratio < 1.4)).all(), ratio
    # zero lag: the error does not correlate with the derivative of the estimated signal
    lag = (e1[:, 0] @ qdd[m:-m, 0]) / (qdd[m:-m, 0] @ qdd[m:-m, 0])
    assert abs(lag) < 1e-5  # [s]


def write_csv(path, t, q, tau, **extra):
    cols = {"t": t}
    cols.update({f"q{j + 1}": q[:, j] for j in range(q.shape[1])})
    for g, arr in extra.items():
        cols.update({f"{g}{j + 1}": arr[:, j] for j in range(q.shape[1])})
    cols.update({f"tau{j + 1}": tau[:, j] for j in range(q.shape[1])})
    pd.DataFrame(cols).to_csv(path, index=False)
    return path


def test_position_only_file_loads_with_a_record_of_the_estimate(tmp_path):
    rng = np.random.default_rng(1)
    t, q, qd, qdd = analytic(rng)
    tau = np.cos(t)[:, None].repeat(2, axis=1)
    q_meas = encoder(q, rng)
    only_q = write_csv(tmp_path / "q_only.csv", t, q_meas, tau)
    full = write_csv(tmp_path / "full.csv", t, q, tau, qd=qd, qdd=qdd)
    traj = load_trajectories([only_q, full])
    est, given = traj.estimated
    assert given is None
    assert est.groups == ("qd", "qdd") and est.filter == choose_derivative_filter(t, q_meas)
    assert est.filter.sample_time == pytest.approx(DT, rel=1e-9)
    a, b = traj.segments
    m = est.filter.window // 2
    assert np.abs(traj.qd[a[0] + m : a[1] - m] - qd[m:-m]).max() < 2e-3
    # files with qd/qdd are used unchanged
    np.testing.assert_allclose(traj.qd[b[0] : b[1]], qd, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(traj.qdd[b[0] : b[1]], qdd, rtol=1e-12, atol=1e-12)
    assert traj.select([1]).estimated == [None]
    assert traj.select([0]).estimated == [est]
    first, last = traj.split_time(0.5)
    assert first.estimated == traj.estimated == last.estimated


def test_given_qd_is_differentiated_once_for_a_missing_qdd(tmp_path):
    rng = np.random.default_rng(2)
    t, q, qd, qdd = analytic(rng)
    tau = np.zeros_like(q)
    traj = load_trajectories([write_csv(tmp_path / "q_qd.csv", t, q, tau, qd=qd)])
    assert traj.estimated[0].groups == ("qdd",)
    np.testing.assert_array_equal(traj.qd, qd)
    m = traj.estimated[0].filter.window // 2
    assert np.abs(traj.qdd - qdd)[m:-m].max() < 1e-3


def test_non_uniform_sampling_is_refused(tmp_path):
    rng = np.random.default_rng(3)
    t, q, _, _ = analytic(rng)
    t = t.copy()
    t[100:] += 0.001  # one interval of 5 ms among 4 ms ones
    path = write_csv(tmp_path / "jitter.csv", t, q, np.zeros_like(q))
    with pytest.raises(ValueError, match="non-uniform sampling: interval 0.005 s at row 100"):
        load_trajectories([path])


def test_simulated_log_round_trip(tmp_path):
    from mcpilco.envs.arms import random_arm
    from mcpilco.envs.robot_logs import simulate_log, write_log

    arm = random_arm(3, seed=1, joint_types="RRR").rigid()
    log = simulate_log(arm, duration=3.0, seed=0)
    for suffix in (".csv", ".parquet"):
        traj = load_trajectories([write_log(tmp_path / f"log{suffix}", log)])
        np.testing.assert_array_equal(traj.q, log.table[["q1", "q2", "q3"]].to_numpy())
        np.testing.assert_array_equal(traj.y, log.table[["tau1", "tau2", "tau3"]].to_numpy())
        m = traj.estimated[0].filter.window // 2
        scale = np.abs(log.truth.qd).max(axis=0)
        assert (np.abs(traj.qd - log.truth.qd)[m:-m].max(axis=0) < 0.01 * scale).all()


def test_interior_drops_the_edge_rows_of_estimated_segments_only(tmp_path):
    """The filter's edge fit errs far more than its central estimate (analytic truth); the
    interior keeps exactly the central rows of an estimated file and every row of a file that
    gave its derivatives, and is its own interior."""
    rng = np.random.default_rng(4)
    t, q, qd, qdd = analytic(rng)
    tau = np.zeros_like(q)
    only_q = write_csv(tmp_path / "q_only.csv", t, encoder(q, rng), tau)
    full = write_csv(tmp_path / "full.csv", t, q, tau, qd=qd, qdd=qdd)
    traj = load_trajectories([only_q, full])
    m = traj.edge_rows(0)
    assert m == traj.estimated[0].filter.window // 2 and traj.edge_rows(1) == 0
    err = np.sqrt(np.mean((traj.qdd[:N] - qdd) ** 2, axis=1))
    edges = np.concatenate([err[:m], err[-m:]])
    assert np.sqrt(np.mean(edges**2)) > 3 * np.sqrt(np.mean(err[m:-m] ** 2))
    inner = traj.interior()
    assert inner.n_samples == 2 * N - 2 * m and inner.n_segments == 2
    np.testing.assert_array_equal(inner.t[: N - 2 * m], t[m:-m])
    np.testing.assert_array_equal(inner.qdd[: N - 2 * m], traj.qdd[m : N - m])
    np.testing.assert_array_equal(inner.qdd[N - 2 * m :], qdd)
    assert inner.edge_rows(0) == 0 and inner.estimated[0].filter == traj.estimated[0].filter
    assert inner.interior() is inner


def test_the_span_is_chosen_against_the_noise_of_the_encoder():
    """Slow motion read by a coarse encoder gets a longer window, and its qdd is closer to
    the analytic one than with the shortest span; exact positions keep the shortest span
    (no noise to trade), and so does motion too fast for the longer windows."""
    rng = np.random.default_rng(5)
    t = np.arange(N) * DT
    slow = 0.5 * 2 * math.pi * 0.2
    q = np.stack([A * np.sin(slow * t), A * np.cos(1.3 * slow * t)], axis=1)
    qdd = -np.stack([slow**2 * q[:, 0], (1.3 * slow) ** 2 * q[:, 1]], axis=1)
    step = 2 * math.pi / 2**13
    coarse = np.round((q + rng.normal(0.0, NOISE * step, q.shape)) / step) * step
    chosen = choose_derivative_filter(t, coarse)
    short = derivative_filter(DT, DERIVATIVE_WINDOW)
    assert chosen.window > short.window
    m = chosen.window // 2
    errors = []
    for filt in (chosen, short):
        _, qdd_hat, _ = estimate_derivatives(t, coarse, window=(filt.window - 1) * DT)
        errors.append(np.sqrt(np.mean((qdd_hat - qdd)[m:-m] ** 2, axis=0)))
    assert (errors[0] < errors[1] / 3).all(), errors
    assert choose_derivative_filter(t, q).window == short.window
    fast = np.stack([0.3 * np.sin(2 * math.pi * 3 * t), 0.2 * np.cos(2 * math.pi * 4 * t)], 1)
    fast = np.round((fast + rng.normal(0.0, NOISE * step, q.shape)) / step) * step
    assert choose_derivative_filter(t, fast).window == short.window
