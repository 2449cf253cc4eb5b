"""The parts of the kinematics benchmark at tiny sizes
(:mod:`mcpilco.experiments.kinematics.parts`): the data sets, the training-sample selection,
the feature rank, the FK and controller parts."""

import numpy as np
import pytest

from mcpilco.envs.marker_camera import ypr_to_matrix
from mcpilco.experiments.kinematics.parts import (
    controller_part,
    feature_rank,
    fk_gp_part,
    training_indices,
    true_structure,
    ur10_datasets,
)
from mcpilco.experiments.kinematics.trajectories import UR10_HOME


def test_feature_rank_of_a_straight_segment_is_that_of_its_trig_polynomials():
    t = np.linspace(-1.0, 1.0, 50)
    # q1 = q2 = t: products of [1, cos t, sin t] span {1, cos t, sin t, cos 2t, sin 2t}
    assert feature_rank(np.column_stack([t, t])) == 5
    # q2 = 2 t: frequencies 0, 1, 2, 1 +- 2 -> 1 + 2 * 3 = 7 functions
    assert feature_rank(np.column_stack([t, 2 * t])) == 7
    q = np.random.default_rng(0).uniform(-1, 1, (50, 2))
    assert feature_rank(q) == 9  # all 3^2 monomials


def test_training_indices_take_measured_frames_only():
    q = np.random.default_rng(0).uniform(-1, 1, (40, 2))
    valid = np.ones(40, dtype=bool)
    valid[::3] = False  # frames whose end marker was not measured
    drawn = training_indices(q, valid, 10, "random", np.random.default_rng(5), "RR")
    expected = np.random.default_rng(5).choice(np.flatnonzero(valid), 10, replace=False)
    np.testing.assert_array_equal(drawn, expected)
    design = training_indices(q, valid, 10, "design", np.random.default_rng(5), "RR")
    assert valid[design].all() and len(set(design.tolist())) == 10
    assert len(training_indices(q, valid, 99, "design", np.random.default_rng(5), "RR")) == 26
    with pytest.raises(ValueError, match="selection must be one of"):
        training_indices(q, valid, 10, "best", np.random.default_rng(5), "RR")


def _facing_cos(poses):
    """cos of the angle between each marker normal and its line of sight to the camera,
    from the true poses (camera frame, yaw-pitch-roll) alone."""
    normal = ypr_to_matrix(poses[..., 3:])[..., :, 2]
    los = -poses[..., :3] / np.linalg.norm(poses[..., :3], axis=-1, keepdims=True)
    return np.einsum("...i,...i->...", normal, los)


def test_visible_protocol_waypoints_show_every_marker_and_hidden_frames_read_nan():
    data = ur10_datasets(0, 96, facing_cone=40.0, visibility_cone=70.0)
    env = data["env"]
    cos_min = np.cos(np.radians(70.0))
    wp_cos = _facing_cos(np.array([env.marker_poses(q) for q in data["waypoints"]]))
    assert wp_cos.min() >= cos_min  # every marker seen at every waypoint
    home_cos = _facing_cos(env.marker_poses(UR10_HOME))
    assert home_cos.min() >= np.cos(np.radians(40.0)) - 1e-9  # attached facing the camera
    poses, _, q_true = data["train"]
    # the camera sees the arm time_offset earlier: q_cam = q_t - (offset / dt)(q_t - q_{t-1})
    lag = env.time_offset / env.dt
    q_cam = q_true[1:] - lag * (q_true[1:] - q_true[:-1])
    seen = _facing_cos(np.array([env.marker_poses(q) for q in q_cam])) >= cos_min
    observed_seen = np.isfinite(poses[1:, :, 0])[:, np.argsort(env.marker_permutation)]
    np.testing.assert_array_equal(observed_seen, seen)
    # both cones off: random orientations, every marker in every frame
    old = ur10_datasets(0, 48, facing_cone=None, visibility_cone=None)
    assert np.isfinite(old["train"][0]).all()
    assert _facing_cos(np.array([old["env"].marker_poses(q) for q in old["waypoints"]])).min() < 0


def test_controller_with_the_chain_model_learns_from_every_marker():
    data = ur10_datasets(0, 96)
    structure = true_structure(data["env"])
    res = controller_part(
        data, structure, 30, 1, 0, False, steps=5, starts=1, hold=1, fk_model="chain"
    )
    assert res["fk_model"] == "chain"
    r0, r1 = res["rounds"]
    assert r1["n_data"] > r0["n_data"] == 30
    assert all(np.isfinite(r0["rmse_true"])) and len(r0["predicted_error"]) == 5
    with pytest.raises(ValueError, match="fk_model must be one of"):
        controller_part(data, structure, 30, 0, 0, False, fk_model="tip")


def test_fk_part_reports_a_chain_that_cannot_be_fitted_and_goes_on():
    data = ur10_datasets(0, 96)
    structure = true_structure(data["env"])
    poses = data["train"][0]
    poses[:, structure.markers[2]] = np.nan  # marker 2 never seen: links 2 and 3 have no frame
    res = fk_gp_part(data, structure, 20, 0, diagnostics=False)
    assert "chain_rmse_true" not in res and "too few frames for link 2" in res["chain_error"]
    assert len(res["polynomial_rmse_measured"]) == 7  # the other models still ran
