"""Learned start models of the diagnosis loop: the RBF start's kernel against a second,
closed-form implementation; the fit continues until converged (one more round gains less
than converge_nats, or a warning); save/load keeps the kind and budget; a bad start type is
named."""

import warnings

import numpy as np
import pytest

from mcpilco.models.diagnosis import DiagnosisModel, GIPStart, RBFStart


def _planar_data(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    q = rng.uniform(-2, 2, (n, 2))
    qd = rng.normal(0, 1, (n, 2))
    qdd = rng.normal(0, 1, (n, 2))
    y = np.stack([np.sin(q[:, 0]) + 0.3 * qd[:, 0], np.cos(q[:, 1]) + 0.5 * qdd[:, 1]], 1)
    return q, qd, qdd, y + 0.01 * rng.normal(size=y.shape)


def test_rbf_start_kernel_is_the_scaled_ard_rbf_of_standardised_states():
    q, qd, qdd, y = _planar_data(60, 0)
    start = RBFStart("RR", adam_iters=5, lbfgs_iters=2, max_rounds=0)
    start.fit(q, qd, qdd, y)
    gp = start.estimator_.gp_
    x = np.concatenate([q, qd, qdd], 1)
    xs = (x - gp.x_mean_.numpy()) / gp.x_scale_.numpy()
    cov = gp.model_.covar_module
    ell = cov.base_kernel.lengthscale.detach().numpy().reshape(2, 1, 6)
    s2 = cov.outputscale.detach().numpy().reshape(2, 1, 1)
    a, b = xs[:7], xs[10:15]
    d2 = (((a[None, :, None, :] - b[None, None, :, :]) / ell[:, :, None, :]) ** 2).sum(-1)
    expected = s2 * np.exp(-0.5 * d2) * (gp.y_scale_.numpy() ** 2)[:, None, None]
    got = start.kernel((q[:7], qd[:7], qdd[:7]), (q[10:15], qd[10:15], qdd[10:15]))
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-12)
    diag = start.kernel_diag((q[:7], qd[:7], qdd[:7]))
    np.testing.assert_allclose(
        diag, np.broadcast_to(s2[:, :, 0] * gp.y_scale_.numpy()[:, None] ** 2, (2, 7))
    )


@pytest.mark.parametrize("cls", [RBFStart, GIPStart])
def test_learned_start_spec_round_trip_keeps_kind(cls):
    model = DiagnosisModel(cls("RR", adam_iters=7, lbfgs_iters=3))
    again = DiagnosisModel.from_spec(model.spec())
    assert type(again.start) is cls
    assert (again.start.adam_iters, again.start.lbfgs_iters) == (7, 3)
    assert (again.start.converge_nats, again.start.max_rounds) == (0.5, 10)


def test_learned_start_fit_runs_until_one_more_round_gains_little():
    """Independent check of the stopping rule: after ``fit``, a further L-BFGS round of the
    same size, run here by hand, raises the summed log evidence by less than converge_nats;
    without the extra rounds the same tiny budget leaves much more on the table."""
    q, qd, qdd, y = _planar_data(80, 1)

    def next_round_gain(start: RBFStart) -> float:
        gp = start.estimator_.gp_
        x = np.concatenate([q, qd, qdd], 1)
        before = float(gp.log_marginal_likelihood().sum())
        gp.fit(x, y, adam_iters=0, lbfgs_iters=start.lbfgs_iters)
        return float(gp.log_marginal_likelihood().sum()) - before

    short = RBFStart("RR", adam_iters=2, lbfgs_iters=1, max_rounds=0)
    short.fit(q, qd, qdd, y)
    assert short.rounds_ == 0
    assert next_round_gain(short) > 2.0
    converged = RBFStart("RR", adam_iters=2, lbfgs_iters=1, converge_nats=0.5, max_rounds=200)
    converged.fit(q, qd, qdd, y)
    assert converged.rounds_ > 1
    assert next_round_gain(converged) < 0.5


def test_learned_start_warns_when_rounds_run_out():
    q, qd, qdd, y = _planar_data(80, 1)
    start = RBFStart("RR", adam_iters=2, lbfgs_iters=1, max_rounds=1)
    with pytest.warns(RuntimeWarning, match="max_rounds"):
        start.fit(q, qd, qdd, y)


def test_learned_start_rejects_bad_convergence_settings():
    with pytest.raises(ValueError, match="converge_nats"):
        RBFStart("RR", converge_nats=0.0)


def test_start_of_wrong_type_is_named():
    with pytest.raises(TypeError, match="NominalStart, GIPStart or RBFStart"):
        DiagnosisModel("robot.xml")


def test_hyperparameters_on_a_subset_then_the_posterior_of_every_row():
    """``hyper_points``: the kernel is fitted on 30 of 80 rows, the torque is the GP
    posterior mean conditioned on all 80 (closed form with the start's own kernel, noise
    and prior mean), and convergence rounds keep to the subset."""
    q, qd, qdd, y = _planar_data(80, 1)
    start = GIPStart("RR", span="gip", adam_iters=5, lbfgs_iters=2, max_rounds=1, hyper_points=30)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # one round of a tiny budget
        start.fit(q, qd, qdd, y)
    assert start.estimator_.hyper_rows_.size == 30 and start.rounds_ == 1
    assert start.estimator_.gp_.train_x_.shape[0] == 80
    test = _planar_data(7, 2)[:3]
    K = start.kernel((q, qd, qdd), (q, qd, qdd))
    Ks = start.kernel(test, (q, qd, qdd))
    noise, mean = start.noise_variance(), start.prior_mean(q[:1], qd[:1], qdd[:1])[0]
    expected = np.stack(
        [
            mean[j] + Ks[j] @ np.linalg.solve(K[j] + noise[j] * np.eye(80), y[:, j] - mean[j])
            for j in range(2)
        ],
        axis=1,
    )
    np.testing.assert_allclose(start.torque(*test), expected, rtol=1e-6, atol=1e-8)
    assert GIPStart("RR").hyper_points == 200
    with pytest.raises(ValueError, match="hyper_points"):
        GIPStart("RR", hyper_points=1)


def test_gip_start_on_every_row_reads_them_all_and_backfits_its_regression():
    """``inducing``: the diagnosis model hands the start every training row (not its
    ``max_points``), the start's prior mean is its regression's posterior mean (so the
    residual target the joints' GPs see is what the start leaves), the spec keeps the
    setting, and a refit on other targets keeps the kernel and moves the mean."""
    from mcpilco.models.diagnosis import as_trajectories
    from mcpilco.models.robot_data import make_dataset

    q, qd, qdd, y = _planar_data(400, 3)
    t = np.arange(400) * 0.01
    data = as_trajectories(make_dataset({"t": t, "q": q, "qd": qd, "qdd": qdd, "tau": y}))
    start = GIPStart("RR", adam_iters=5, lbfgs_iters=2, inducing=120, hyper_points=40)
    model = DiagnosisModel(start, max_points=50, max_delay_samples=2).fit(data)
    assert model.rows_.size == 50
    assert start.estimator_.blr_.n == 400 - 2 * 2  # every training row
    states = (model.train_.q, model.train_.qd, model.train_.qdd)
    rows = model.rows_
    np.testing.assert_allclose(
        model.target(0), model.train_.y[rows, 0] - start.torque(*states)[rows, 0]
    )
    again = DiagnosisModel.from_spec(model.spec())
    assert again.start.inducing == 120 and again.start.all_rows
    # new targets (another function in the GIP span): the refit follows them, the kernel
    # hyperparameters stay those of the first fit
    other = np.stack([2.0 * np.cos(q[:, 0]) + qdd[:, 1], np.sin(q[:, 1]) * qd[:, 0] ** 2], 1)
    moved = start.refit(q, qd, qdd, other)
    assert np.sqrt(np.mean((moved.torque(q, qd, qdd) - other) ** 2)) < 0.05
    np.testing.assert_allclose(
        moved.kernel((q, qd, qdd), (q[:5], qd[:5], qdd[:5])),
        start.kernel((q, qd, qdd), (q[:5], qd[:5], qdd[:5])),
    )
    assert moved.estimator_.gp_ is not start.estimator_.gp_
    with pytest.raises(ValueError, match="inducing"):
        GIPStart("RR", inducing=0)


def _arm_case(effects: list, seed: int, duration: float = 8.0) -> tuple:
    """Training (2 files) and held-out (1 file) q-only logs of a random 3-joint arm
    forward-simulated with ``effects`` (closed loop, quantised encoder)."""
    from mcpilco.envs.arms import random_arm
    from mcpilco.envs.robot_logs import simulate_log
    from mcpilco.models.diagnosis import as_trajectories
    from mcpilco.models.robot_data import from_frame

    arm = random_arm(3, seed=seed, joint_types="RRR").rigid()
    logs = [
        simulate_log(arm, effects, duration=duration, seed=s, tau_noise=0.05) for s in (1, 2, 3)
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        frames = [from_frame(g.table, source=f"log{k}") for k, g in enumerate(logs)]
        return arm, as_trajectories(frames[:2]), as_trajectories(frames[2:])


@pytest.mark.slow
def test_rigid_gip_start_leaves_damping_for_the_search_and_names_nothing_without_it():
    """The default learned start of a 3-joint arm (the rigid-body span, every row) holds no
    viscous term, so damping on one joint is named on that joint on top of it, as with a
    nominal model; on the same arm without the effect nothing is named."""
    from mcpilco.envs.robot_logs import HiddenEffect
    from mcpilco.models.diagnosis import diagnose

    arm, train, test = _arm_case([], seed=4)
    start = GIPStart("RRR")
    assert start.span == "rigid" and not start.has_kernel
    model = DiagnosisModel(start).fit(train)
    d = diagnose(model, test)
    assert d.best is None, d.table()
    qd = np.concatenate([train.qd[:, 1]])
    damping = 6 * 0.05 / np.sqrt(np.mean(qd**2))  # about six noise stds of torque
    _, train, test = _arm_case([HiddenEffect("damping", 2, float(damping))], seed=4)
    model = DiagnosisModel(GIPStart("RRR")).fit(train)
    d = diagnose(model, test)
    assert d.best is not None and d.best.label == "viscous:2", d.table()


def test_gip_start_beyond_the_lagrangian_size_is_the_chain_and_round_trips():
    """Six and seven joints: ``"auto"`` is the chain with fitted kinematics (the Lagrangian
    has 9,947 / 49,374 parameters), with no start kernel; save/load keeps it; the
    Lagrangian span is refused there, naming the chain."""
    for jt in ("RRRRRR", "RRRPRRR"):
        start = GIPStart(jt)
        assert start.span == "chain" and start.all_rows and not start.has_kernel
        again = DiagnosisModel.from_spec(DiagnosisModel(start).spec())
        assert again.start.span == "chain"
    assert GIPStart("RRR").span == "rigid"
    with pytest.raises(ValueError, match="chain"):
        GIPStart("RRRRRRR", span="rigid")
    with pytest.raises(ValueError, match="inducing"):
        GIPStart("RRRRRR", span="chain", inducing=100)


@pytest.mark.slow
def test_chain_start_names_nothing_without_an_effect_and_damping_with_one():
    """The default learned start of a 6-joint arm (the chain with fitted kinematics, every
    row) holds no viscous term: on an effect-free log nothing is named, and damping on one
    joint is named on that joint, as with a nominal model."""
    from mcpilco.envs.arms import random_arm
    from mcpilco.envs.robot_logs import HiddenEffect, simulate_log
    from mcpilco.models.diagnosis import as_trajectories, diagnose
    from mcpilco.models.robot_data import from_frame

    arm = random_arm(6, seed=3, joint_types="RRRRRR").rigid()

    def case(effects):
        logs = [
            simulate_log(arm, effects, duration=20.0, seed=s, tau_noise=0.05) for s in (1, 2, 3)
        ]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            frames = [from_frame(g.table, source=f"log{k}") for k, g in enumerate(logs)]
            return as_trajectories(frames[:2]), as_trajectories(frames[2:])

    train, test = case([])
    start = GIPStart("RRRRRR")
    assert start.span == "chain"
    d = diagnose(DiagnosisModel(start).fit(train), test)
    assert d.best is None, d.table()
    damping = 6 * 0.05 / np.sqrt(np.mean(train.qd[:, 3] ** 2))  # about six noise stds
    train, test = case([HiddenEffect("damping", 4, float(damping))])
    d = diagnose(DiagnosisModel(GIPStart("RRRRRR")).fit(train), test)
    assert d.best is not None and d.best.label == "viscous:4", d.table()
