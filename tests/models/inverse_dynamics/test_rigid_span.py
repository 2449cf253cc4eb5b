"""The rigid-body terms of a serial chain's Lagrangian from its joint types: they hold the
inverse dynamics of random arms exactly (pinocchio RNEA, an independent implementation),
hold no viscous, Coulomb or offset torque on one joint, lie in the GIP kernel's span, and
the regression over them refits on new targets as a fresh fit does."""

import numpy as np
import pytest

from mcpilco.models.inverse_dynamics import (
    GIPEstimator,
    JointStates,
    LagrangianEstimator,
    lagrangian_columns,
    lagrangian_parameters,
)


def _random_states(n: int, rows: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    q = rng.uniform(-2.5, 2.5, (rows, n))
    return np.concatenate([q, rng.normal(0, 1.5, (rows, n)), rng.normal(0, 4, (rows, n))], 1)


def _rnea(joint_types: str, seed: int):
    from mcpilco.envs.arm_builder import arm_to_xml
    from mcpilco.envs.arms import random_arm
    from mcpilco.models.diagnosis import NominalStart

    arm = random_arm(len(joint_types), seed=seed, joint_types=joint_types).rigid()
    nominal = NominalStart(arm_to_xml(arm, friction=False))
    n = len(joint_types)
    return lambda X: nominal.torque(X[:, :n], X[:, n : 2 * n], X[:, 2 * n :])


@pytest.mark.parametrize(
    ("joint_types", "seed"), [("RR", 1), ("RRR", 2), ("RRR", 5), ("PRR", 3), ("RRPR", 4)]
)
def test_lagrangian_holds_the_inverse_dynamics_of_random_arms(joint_types, seed):
    rnea = _rnea(joint_types, seed)
    n = len(joint_types)
    X, Xt = _random_states(n, 1500, 0), _random_states(n, 500, 1)
    est = LagrangianEstimator(joint_types).fit(X, rnea(X))
    yt = rnea(Xt)
    err = np.sqrt(np.mean((est.predict(Xt)[0] - yt) ** 2, axis=0)) / yt.std(axis=0)
    assert np.all(err < 1e-7), err


@pytest.mark.parametrize("joint", [0, 2])
def test_lagrangian_holds_no_viscous_coulomb_or_offset_torque_on_one_joint(joint):
    """Each torque on one joint alone, fitted: most of it is left on new states (a
    rigid-body torque would leave nothing: the previous test)."""
    X, Xt = _random_states(3, 1500, 0), _random_states(3, 500, 1)
    for make in (
        lambda X: X[:, 3 + joint],
        lambda X: np.sign(X[:, 3 + joint]),
        lambda X: np.ones(len(X)),
    ):
        y, yt = np.zeros((len(X), 3)), np.zeros((len(Xt), 3))
        y[:, joint], yt[:, joint] = make(X), make(Xt)
        est = LagrangianEstimator("RRR").fit(
            X, y + 0.01 * np.random.default_rng(2).normal(size=y.shape)
        )
        err = np.sqrt(np.mean((est.predict(Xt)[0][:, joint] - yt[:, joint]) ** 2))
        assert err > 0.7 * np.sqrt(np.mean(yt[:, joint] ** 2)), err


def test_lagrangian_columns_lie_in_the_gip_span():
    """An exact GIP GP (thesis eq. 3.11) fitted on noise-free parameter torques reproduces
    them on new states."""
    params = lagrangian_parameters("RR")
    X, Xt = _random_states(2, 400, 0), _random_states(2, 100, 1)
    cols = [lagrangian_columns(JointStates(*np.split(A, 3, axis=1)), params, "RR") for A in (X, Xt)]
    pick = [0, 5, len(params) - 1]
    gp = GIPEstimator("RR", adam_iters=60, lbfgs_iters=30, noise_min=1e-10)
    gp.fit(X, cols[0][:, :, pick].sum(axis=2).T)
    want = cols[1][:, :, pick].sum(axis=2).T
    err = np.abs(gp.predict(Xt)[0] - want).max(axis=0) / np.abs(want).max(axis=0)
    assert np.all(err < 1e-2), err


def test_refit_targets_equals_a_fresh_fit_and_big_chains_are_refused():
    X = _random_states(2, 600, 0)
    rnea = _rnea("RR", 1)
    noise = 0.01 * np.random.default_rng(0).normal(size=(600, 2))
    est = LagrangianEstimator("RR").fit(X, rnea(X))
    est.refit_targets(X, rnea(X) + noise)
    fresh = LagrangianEstimator("RR").fit(X, rnea(X) + noise)
    np.testing.assert_allclose(est.predict_mean(X), fresh.predict_mean(X), rtol=1e-8, atol=1e-10)
    with pytest.raises(ValueError, match="parameters"):
        LagrangianEstimator("RRRRRR")


@pytest.mark.parametrize(("joint_types", "seed"), [("RRPR", 4), ("RRRRRRR", 2), ("RPRRRRR", 6)])
def test_chain_columns_at_the_true_kinematics_hold_the_inverse_dynamics(joint_types, seed):
    """At a random arm's own DH numbers and vertical gravity, the chain's columns times the
    least-squares inertial parameters reproduce pinocchio's RNEA (an independent
    implementation) on new states, to the digits of the MJCF text pinocchio reads (the DH
    numbers are rounded there: about 1e-6 of the torque)."""
    import torch

    from mcpilco.envs.arms import random_arm
    from mcpilco.models.inverse_dynamics import chain_columns

    n = len(joint_types)
    arm = random_arm(n, seed=seed, joint_types=joint_types).rigid()
    kin = torch.tensor([[j.alpha, j.a, j.theta, j.d] for j in arm.joints], dtype=torch.float64)
    rnea = _rnea(joint_types, seed)
    X, Xt = _random_states(n, 600, 0), _random_states(n, 300, 1)

    def cols(A):
        parts = (torch.as_tensor(p) for p in np.split(A, 3, axis=1))
        return chain_columns(kin, torch.zeros(2, dtype=torch.float64), joint_types, *parts)

    C = cols(X).numpy()
    pi = np.linalg.lstsq(np.concatenate(list(C)), rnea(X).T.reshape(-1), rcond=None)[0]
    yt = rnea(Xt)
    err = np.abs(np.einsum("anp,p->na", cols(Xt).numpy(), pi) - yt).max(0) / np.abs(yt).max(0)
    assert np.all(err < 1e-4), err


@pytest.mark.slow
def test_chain_estimator_finds_the_kinematics_of_a_random_arm():
    """From the grid's and random starts the search reaches the exact minimum on an arm
    whose twists are not right angles: noise-free RNEA torques of a random arm are
    reproduced on new states, with 44 parameters for 4 joints (40 inertial, 4
    armatures)."""
    from mcpilco.models.inverse_dynamics import ChainEstimator

    rnea = _rnea("RRPR", 4)
    X, Xt = _random_states(4, 1000, 0), _random_states(4, 300, 1)
    est = ChainEstimator("RRPR", search_rows=300).fit(X, rnea(X))
    yt = rnea(Xt)
    err = np.abs(est.predict(Xt)[0] - yt).max(0) / np.abs(yt).max(0)
    assert est.n_features_ == 44 and np.all(err < 1e-5), err


@pytest.mark.slow
@pytest.mark.parametrize(
    ("joint_types", "seed", "restarts"), [("RRRRRRR", 2, None), ("RRRRRR", 7, 12)]
)
def test_chain_estimator_finds_the_kinematics_of_a_random_six_or_seven_joint_arm(
    joint_types, seed, restarts
):
    from mcpilco.models.inverse_dynamics import ChainEstimator

    n = len(joint_types)
    rnea = _rnea(joint_types, seed)
    X, Xt = _random_states(n, 2000, 0), _random_states(n, 300, 1)
    # twists off the quarter-turn grid: random starts find them (the grid search covers arm
    # tables with right-angle axes); the default 10 find the 7R arm, the 6R arm needs 12 (its
    # 10 default starts missed its global minimum: not enough for every random arm)
    kw = {} if restarts is None else {"restarts": restarts}
    est = ChainEstimator(joint_types, **kw).fit(X, rnea(X))
    yt = rnea(Xt)
    err = np.abs(est.predict(Xt)[0] - yt).max(0) / np.abs(yt).max(0)
    assert np.all(err < 1e-3), err  # the refinement's L-BFGS stops at 1e-5..3e-4 (6R seed 7)


@pytest.mark.slow
def test_chain_estimator_per_joint_follows_per_joint_units():
    """Motor currents ``i_a = tau_a / k_a``: with a parameter vector per joint the chain
    fits them exactly on new states."""
    from mcpilco.models.inverse_dynamics import ChainEstimator

    rnea = _rnea("RRPR", 4)
    X, Xt = _random_states(4, 1000, 0), _random_states(4, 300, 1)
    k = np.array([0.5, 2.0, 7.0, 1.3])
    est = ChainEstimator("RRPR", search_rows=300, per_joint=True).fit(X, rnea(X) / k)
    yt = rnea(Xt) / k
    err = np.abs(est.predict(Xt)[0] - yt).max(0) / np.abs(yt).max(0)
    assert np.all(err < 1e-5), err


def _table_rnea(name: str):
    """RNEA of a robot table without friction (its rotor inertias kept: MuJoCo's
    ``armature``), by pinocchio through the nominal start."""
    from mcpilco.envs.arm_builder import arm_to_xml
    from mcpilco.envs.arms import ARMS
    from mcpilco.models.diagnosis import NominalStart

    arm = ARMS[name]().without_friction()
    nominal = NominalStart(arm_to_xml(arm, friction=False))
    n = arm.n_joints
    return arm, lambda X: nominal.torque(X[:, :n], X[:, n : 2 * n], X[:, 2 * n :])


@pytest.mark.parametrize("name", ["panda", "iiwa14"])
def test_chain_and_armature_columns_hold_a_public_arm_table_exactly(name):
    """The Panda's frames are modified DH (Menagerie's bodies), the iiwa's have offsets;
    both are standard-DH chains to the chain's columns, and the Panda's armature (0.1 on
    every joint, a torque on each joint alone) is the armature columns': at the table's DH
    numbers, least squares over both reproduce pinocchio's RNEA on new states; without
    the armature columns the Panda's wrist keeps a large error."""
    import torch

    from mcpilco.models.inverse_dynamics import armature_columns, chain_columns

    arm, rnea = _table_rnea(name)
    kin = torch.tensor([[j.alpha, j.a, j.theta, j.d] for j in arm.joints], dtype=torch.float64)
    X, Xt = _random_states(7, 600, 0), _random_states(7, 300, 1)

    def cols(A, armature):
        q, qd, qdd = (torch.as_tensor(p) for p in np.split(A, 3, axis=1))
        C = chain_columns(kin, torch.zeros(2, dtype=torch.float64), "R" * 7, q, qd, qdd)
        return (torch.cat([C, armature_columns(qdd)], 2) if armature else C).numpy()

    yt = rnea(Xt)
    errs = []
    for armature in (True, False):
        C = cols(X, armature)
        pi = np.linalg.lstsq(np.concatenate(list(C)), rnea(X).T.reshape(-1), rcond=None)[0]
        pred = np.einsum("anp,p->na", cols(Xt, armature), pi)
        errs.append(np.abs(pred - yt).max(0) / np.abs(yt).max(0))
    assert np.all(errs[0] < 1e-9), errs[0]
    if name == "panda":
        assert errs[1][4:].min() > 0.05, errs[1]


@pytest.mark.slow
@pytest.mark.parametrize(("restarts", "grid_starts"), [(12, 0), (0, 6)])
def test_chain_estimator_finds_the_panda_from_random_or_grid_starts(restarts, grid_starts):
    """Noise-free torques of the Panda table (modified-DH frames, armature on every joint):
    the search from random starts alone, or from the grid search's alone, and the fit
    reproduce pinocchio's RNEA on new states (to 1e-4 of each joint's torque range: from the
    grid's starts the refinement's L-BFGS stops at 2e-5)."""
    from mcpilco.models.inverse_dynamics import ChainEstimator

    _, rnea = _table_rnea("panda")
    X, Xt = _random_states(7, 2000, 0), _random_states(7, 300, 1)
    est = ChainEstimator("R" * 7, restarts=restarts, grid_starts=grid_starts).fit(X, rnea(X))
    yt = rnea(Xt)
    err = np.abs(est.predict(Xt)[0] - yt).max(0) / np.abs(yt).max(0)
    assert est.n_features_ == 77 and np.all(err < 1e-4), err


def _grid_arm(joint_types: str, seed: int):
    """A random arm whose DH twists and offsets are drawn from the grid search's values and
    its lengths from a 0.1 m grid (a real arm's kind of table), with its RNEA by pinocchio."""
    import dataclasses

    from mcpilco.envs.arm_builder import arm_to_xml
    from mcpilco.envs.arms import random_arm
    from mcpilco.models.diagnosis import NominalStart

    rng = np.random.default_rng(seed)
    arm = random_arm(len(joint_types), seed=seed, joint_types=joint_types).rigid()
    quarter = np.array([0.0, np.pi / 2, -np.pi / 2, np.pi])
    joints = tuple(
        dataclasses.replace(
            j,
            alpha=float(rng.choice(quarter)),
            theta=float(rng.choice(quarter)),
            a=float(rng.integers(-4, 5)) / 10,
            d=float(rng.integers(-4, 5)) / 10,
        )
        for j in arm.joints
    )
    arm = dataclasses.replace(arm, joints=joints)
    nominal = NominalStart(arm_to_xml(arm, friction=False))
    n = len(joint_types)
    return lambda X: nominal.torque(X[:, :n], X[:, n : 2 * n], X[:, 2 * n :])


def test_chain_grid_search_recovers_an_arm_with_right_angle_twists():
    """Noise-free torques (pinocchio RNEA) of an arm whose twists and offsets are right
    angles and lengths on the grid: the grid search alone (no random start, no L-BFGS
    descent needed) ends at a point of relative loss below 1e-6, and the fit from it
    reproduces the torques on new states."""
    from mcpilco.models.inverse_dynamics import ChainEstimator

    rnea = _grid_arm("RRR", 3)
    X, Xt = _random_states(3, 600, 0), _random_states(3, 300, 1)
    est = ChainEstimator("RRR", restarts=0, grid_starts=3, search_rows=300).fit(X, rnea(X))
    assert est.grid_loss_ < 1e-6, est.grid_loss_
    yt = rnea(Xt)
    err = np.abs(est.predict(Xt)[0] - yt).max(0) / np.abs(yt).max(0)
    assert est.grid_evaluations_ > 0 and np.all(err < 1e-5), err
    with pytest.raises(ValueError, match="one start at least"):
        ChainEstimator("RR", restarts=0, grid_starts=0)


def test_chain_estimator_fits_on_its_threads_and_restores_the_count():
    """The fit runs on ``threads`` torch threads (its known-kinematics fit still reproduces
    pinocchio's RNEA) and leaves the process's thread count as it found it."""
    import torch

    from mcpilco.envs.arms import random_arm
    from mcpilco.models.inverse_dynamics import ChainEstimator

    rnea = _rnea("RRR", 2)
    arm = random_arm(3, seed=2, joint_types="RRR").rigid()
    kin = [[j.alpha, j.a, j.theta, j.d] for j in arm.joints]
    X, Xt = _random_states(3, 400, 0), _random_states(3, 100, 1)
    seen = []
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        est = ChainEstimator("RRR", kinematics=kin, gravity=[0.0, 0.0], threads=1)
        search = est._solve
        est._solve = lambda *a: (seen.append(torch.get_num_threads()), search(*a))[1]
        est.fit(X, rnea(X))
        after = torch.get_num_threads()
    finally:
        torch.set_num_threads(before)
    yt = rnea(Xt)
    err = np.abs(est.predict(Xt)[0] - yt).max(0) / np.abs(yt).max(0)
    assert seen == [1] and after == 2 and np.all(err < 1e-5), (seen, after, err)
    with pytest.raises(ValueError, match="threads"):
        ChainEstimator("RR", threads=0)


def test_difference_noise_recovers_white_noise_on_smooth_signals():
    """Smooth signals of very different sizes (0.05 to 50, sampled at 4 ms) plus white
    Gaussian noise of known std per column, with jumps where files are joined: the median
    second difference gives each column's noise std (to 5%); rows out of time order give
    about the signal's own scale instead."""
    from mcpilco.models.inverse_dynamics import difference_noise

    rng = np.random.default_rng(0)
    t = np.arange(20000) * 0.004
    amp = np.array([0.05, 1.0, 50.0])
    sigma = np.array([0.03, 0.01, 0.2])
    clean = amp * np.sin(2 * np.pi * np.array([0.3, 0.7, 0.5]) * t[:, None] + 1.0)
    clean[10000:] += 5 * amp  # two files joined: one jump
    y = clean + sigma * rng.standard_normal(clean.shape)
    assert np.allclose(difference_noise(y), sigma, rtol=0.05), difference_noise(y)
    shuffled = difference_noise(y[rng.permutation(y.shape[0])])
    assert np.all(shuffled > 0.5 * np.sqrt(np.mean((y - y.mean(0)) ** 2, axis=0))), shuffled


def test_chain_search_weighs_joints_by_their_noise():
    """Noise-free torques on random rows (no time order): each joint's search scale is of
    the size of its torques; the same arm along a smooth trajectory with white noise of
    known std: its noise std (to 10%)."""
    from mcpilco.models.inverse_dynamics import ChainEstimator

    rnea = _rnea("RR", 1)
    X = _random_states(2, 400, 0)
    y = rnea(X)
    fast = dict(restarts=0, grid_starts=1, search_rows=200, refine_rows=200)
    est = ChainEstimator("RR", **fast).fit(X, y)
    rms = np.sqrt(np.mean(y**2, axis=0))
    assert np.all(est.search_scale_ <= rms) and np.all(est.search_scale_ > 0.5 * rms)
    t = np.arange(2000)[:, None] * 0.004
    q = np.sin(2 * np.pi * np.array([0.4, 0.6]) * t)
    qd = 2 * np.pi * np.array([0.4, 0.6]) * np.cos(2 * np.pi * np.array([0.4, 0.6]) * t)
    qdd = -((2 * np.pi * np.array([0.4, 0.6])) ** 2) * q
    Xs = np.concatenate([q, qd, qdd], 1)
    sigma = np.array([0.05, 0.01])
    ys = rnea(Xs) + sigma * np.random.default_rng(1).standard_normal((2000, 2))
    est = ChainEstimator("RR", **fast).fit(Xs, ys)
    assert np.allclose(est.search_scale_, sigma, rtol=0.1), est.search_scale_


def _trajectory(rows: int, phase: float) -> np.ndarray:
    """``[q, qd, qdd]`` of three joints along sines of 0.35, 0.5 and 0.65 Hz (4 ms)."""
    t = np.arange(rows)[:, None] * 0.004
    w = 2 * np.pi * np.array([0.35, 0.5, 0.65])
    q = 1.2 * np.sin(w * t + phase)
    qd, qdd = 1.2 * w * np.cos(w * t + phase), -(w**2) * q
    return np.concatenate([q, qd, qdd], 1)


@pytest.mark.parametrize(("right_angles", "seed"), [(True, 3), (False, 2)])
def test_chain_sets_quarter_turns_only_where_the_arm_has_them(right_angles, seed):
    """Noisy torques along a smooth trajectory: an arm whose twists and offsets are right
    angles ends with every fitted twist and offset exactly on a quarter turn
    (``snapped_``); a random arm whose twists are not keeps its fitted angles (the snapped
    loss rises many times past the allowance). Either predicts its RNEA (pinocchio) on new
    states to within the noise."""
    from mcpilco.models.inverse_dynamics import ChainEstimator

    rnea = _grid_arm("RRR", seed) if right_angles else _rnea("RRR", seed)
    X, Xt = _trajectory(3000, 0.0), _trajectory(1000, 1.0)
    sigma = 0.02
    y = rnea(X) + sigma * np.random.default_rng(0).standard_normal(X[:, :3].shape)
    fast = dict(restarts=0, grid_starts=2, search_rows=300, refine_rows=1000)
    est = ChainEstimator("RRR", **fast).fit(X, y)
    angles = est.kinematics_[:, [0, 2]] / (np.pi / 2)
    on_grid = np.allclose(angles, np.round(angles), atol=1e-9)
    assert est.snapped_ == right_angles == on_grid, (est.snap_cost_, est.kinematics_)
    if not right_angles:
        assert est.snap_cost_ > 10, est.snap_cost_
    err = np.sqrt(np.mean((est.predict_mean(Xt) - rnea(Xt)) ** 2, axis=0))
    assert np.all(err < sigma), err


def test_chain_search_is_not_bent_by_friction():
    """Torques of a random RRR arm along a smooth trajectory plus, on one joint, dry
    friction far above the noise and damping (no chain holds them):
    the kinematics search projects them out, so that the chain refitted on the torques
    without them (``refit_targets`` keeps the kinematics) predicts the arm's inverse
    dynamics on new states to within the noise."""
    from mcpilco.models.inverse_dynamics import ChainEstimator

    rnea = _rnea("RRR", 2)
    X, Xt = _trajectory(3000, 0.0), _trajectory(1000, 1.0)
    qd2 = X[:, 4]
    local = 2.0 * np.tanh(qd2 / 0.01) + 0.5 * qd2
    sigma = 0.02
    y = rnea(X) + sigma * np.random.default_rng(0).standard_normal(X[:, :3].shape)
    y[:, 1] += local
    est = ChainEstimator("RRR", restarts=0, grid_starts=2, search_rows=300).fit(X, y)
    y_clean = y.copy()
    y_clean[:, 1] -= local
    est.refit_targets(X, y_clean)
    err = np.sqrt(np.mean((est.predict_mean(Xt) - rnea(Xt)) ** 2, axis=0))
    assert np.all(err < sigma), err
