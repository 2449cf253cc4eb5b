"""The delay scan and the held-out confirmation with a learned (subsampled) start model.

A learned start conditions on a subset of the samples (``max_points``), so a delay must be
scored by moving the *inputs*: shifting the targets would compare log-likelihoods of other
noise samples, which differ by ``~ sqrt(N / 2)`` nats by chance alone (a spurious delay).
"""

import dataclasses
import math

import numpy as np

from mcpilco.experiments.diagnosis.hidden_effects import make_case
from mcpilco.models.diagnosis import DiagnosisModel, GIPStart, as_trajectories, heldout_rmse
from mcpilco.models.diagnosis.effects import Delay
from mcpilco.models.diagnosis.search import (
    EVIDENCE_THRESHOLD,
    heldout_change_pct,
    score_effect,
)


def _gip_model(case, max_points=200):
    start = GIPStart(case.joint_types, span="gip", adam_iters=20, lbfgs_iters=5, max_rounds=0)
    return DiagnosisModel(start, max_points=max_points).fit(case.datasets("train"))


def test_the_delay_scan_reads_only_the_training_samples():
    """No delay in the data, and every sample outside the training subset made noise-free:
    a scan that shifted the targets would read those samples and find a huge 'delay'; the
    scan must score every shift on the same measured samples, so it finds none."""
    noisy = make_case("scara", [], seed=0, duration=8.0)
    clean = make_case("scara", [], seed=0, duration=8.0, noise_frac=1e-6)  # same draws
    train = as_trajectories(noisy.datasets("train"))
    start = GIPStart(noisy.joint_types, span="gip", adam_iters=20, lbfgs_iters=5, max_rounds=0)
    model = DiagnosisModel(start, max_points=200)
    rows = model._training_rows(train)
    assert rows.size == 200 and np.all(np.diff(rows) > 5)  # a subset: rows + k are others
    y = as_trajectories(clean.datasets("train")).y.copy()
    y[rows] = train.y[rows]
    model.fit(dataclasses.replace(train, y=y))
    np.testing.assert_array_equal(model.rows_, rows)
    for j in range(1, model.n_joints + 1):
        cand = score_effect(model, Delay(joint=j))
        assert cand.delta < EVIDENCE_THRESHOLD, (j, cand.delta, cand.effect)


def test_a_delayed_joint_reads_its_inputs_earlier_and_fits_its_samples():
    case = make_case("scara", ["delay:2"], seed=1, duration=8.0)
    k = case.effects[0]["samples"]
    test = as_trajectories(case.datasets("test"))
    v0 = _gip_model(case)
    v1 = v0.with_effect(Delay(joint=2, samples=k))
    # the same measured samples, the states k samples earlier
    np.testing.assert_array_equal(v1.rows_, v0.rows_)
    np.testing.assert_array_equal(v1.joint_context(1).q, v0.train_.q[v0.rows_ - k])
    np.testing.assert_array_equal(v1.joint_context(0).q, v0.train_.q[v0.rows_])
    # predictions mean_j(t - d) of the GP conditioned on (x(t - d), y(t)): at the training
    # rows they reproduce the measured samples to about the noise
    mean, _ = v1.predict(v1.train_, with_var=False)
    fit = math.sqrt(float(np.mean((mean[v1.rows_, 1] - v1.train_.y[v1.rows_, 1]) ** 2)))
    assert fit < 1.5 * case.noise_std[1], fit / case.noise_std[1]
    before, after = heldout_rmse(v0, test)[1], heldout_rmse(v1, test)[1]
    assert after < 0.5 * before, (before / case.noise_std[1], after / case.noise_std[1])


def test_heldout_change_pools_joints_in_noise_units():
    noise = np.array([1.0, 100.0])
    before, after = np.array([1.2, 100.0]), np.array([1.0, 100.0])
    expected = 100.0 * (1.0 / math.sqrt((1.44 + 1.0) / 2) - 1.0)  # -9.5 %, not -0.002 %
    assert math.isclose(heldout_change_pct(before, after, noise, [0, 1]), expected)
    assert math.isclose(heldout_change_pct(before, after, noise, [0]), 100.0 * (1 / 1.2 - 1))
