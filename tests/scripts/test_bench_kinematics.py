"""Smoke tests of scripts/bench_kinematics.py at tiny sizes: the parts run and write their
JSON, Markdown and PNG files (the statistical claims live in the benchmark, not here)."""

import json

import numpy as np
import pytest

from mcpilco.envs.marker_camera import ypr_to_matrix
from mcpilco.scripts.bench_kinematics import (
    UR10_HOME,
    _feature_rank,
    controller_part,
    fk_gp_part,
    main,
    training_indices,
    true_structure,
    ur10_datasets,
    ur10_waypoints,
)


def test_feature_rank_of_a_straight_segment_is_that_of_its_trig_polynomials():
    t = np.linspace(-1.0, 1.0, 50)
    # q1 = q2 = t: products of [1, cos t, sin t] span {1, cos t, sin t, cos 2t, sin 2t}
    assert _feature_rank(np.column_stack([t, t])) == 5
    # q2 = 2 t: frequencies 0, 1, 2, 1 +- 2 -> 1 + 2 * 3 = 7 functions
    assert _feature_rank(np.column_stack([t, 2 * t])) == 7
    q = np.random.default_rng(0).uniform(-1, 1, (50, 2))
    assert _feature_rank(q) == 9  # all 3^2 monomials


def test_bench_monte_carlo_part_is_exact_on_noiseless_robots(tmp_path):
    rc = main(["--parts", "a", "--robots", "1", "--out-dir", str(tmp_path), "--no-progress"])
    assert rc == 0
    res = json.loads((tmp_path / "kinematics.json").read_text())
    mc = res["monte_carlo"]
    assert mc["triplets"] == 75 and mc["misclassified_triplets"] == 0  # noiseless: exact
    assert mc["structures_recovered"] == 1
    assert (tmp_path / "kinematics_confusion.png").stat().st_size > 0
    assert "100.00% of 75 triplets" in (tmp_path / "kinematics.md").read_text()


def test_bench_merge_keeps_the_parts_not_run(tmp_path):
    out = ["--out-dir", str(tmp_path), "--no-progress"]
    assert main(["--parts", "a", "--robots", "1", *out]) == 0
    path = tmp_path / "kinematics.json"
    res = json.loads(path.read_text())
    row = {f"{n}_{c}_{s}": 0.01 for n in ("linear", "angle") for c in ("r1", "r2")
           for s in ("mean", "min", "max")}  # fmt: skip
    row.update(repeat=0, samples=25, triplets=126, misclassified=3)
    res["noise_vs_samples"] = dict(rows=[row], command="an earlier run of part b")
    path.write_text(json.dumps(res))
    assert main(["--parts", "a", "--robots", "1", "--merge", *out]) == 0
    merged = json.loads(path.read_text())
    assert merged["noise_vs_samples"]["rows"] == [row]
    assert merged["monte_carlo"]["command"].endswith("--merge --out-dir " + str(tmp_path)
                                                     + " --no-progress")  # fmt: skip
    md = (tmp_path / "kinematics.md").read_text()
    assert "Command: `an earlier run of part b`" in md and "| 0 | 25 | 3 / 126 |" in md
    assert main(["--parts", "a", "--robots", "1", *out]) == 0  # without --merge: dropped
    assert "noise_vs_samples" not in json.loads(path.read_text())


@pytest.mark.slow
def test_bench_kinematics_tiny_run_writes_outputs(tmp_path):
    rc = main(
        [
            "--parts", "abcd", "--robots", "1", "--samples", "72", "--sizes", "36", "72",
            "--repeats", "1", "--fk-train", "20", "--ctrl-train", "25", "--online-rounds", "1",
            "--ctrl-steps", "5", "--ctrl-refine", "previous", "--ctrl-hold", "2",
            "--out-dir", str(tmp_path), "--no-progress",
        ]
    )  # fmt: skip
    assert rc == 0
    res = json.loads((tmp_path / "kinematics.json").read_text())
    assert res["monte_carlo"]["misclassified_triplets"] == 0
    assert [r["samples"] for r in res["noise_vs_samples"]["rows"]] == [36, 72]
    assert len(res["fk_gp"]["polynomial_rmse_measured"]) == 7  # 6 pose + geodesic
    assert len(res["fk_gp"]["nine_elements_rmse_true"]) == 7
    assert len(res["fk_gp"]["trimmed_rmse_true"]) == 7
    assert len(res["fk_gp"]["noise_free_training_rmse_true"]) == 4
    rounds = res["controller"]["rounds"]
    assert len(rounds) == 2 and rounds[1]["chosen_start"] == [-1] * 5  # refined from round 0
    assert rounds[1]["n_data"] - rounds[0]["n_data"] >= 5 * 2  # + the frames held at rest
    for key in ("noise_vs_samples", "fk_gp", "controller"):  # the default marker protocol
        assert res[key]["marker_protocol"] == {"facing_cone": 40.0, "visibility_cone": 70.0}
    assert res["fk_gp"]["train_selection"] == "design"
    assert res["controller"]["train_selection"] == "random"
    assert "turned more than 70 deg" in (tmp_path / "kinematics.md").read_text()
    for name in ("kinematics_confusion.png", "kinematics_noise_vs_samples.png",
                 "kinematics_controller.png", "kinematics.md"):  # fmt: skip
        assert (tmp_path / name).stat().st_size > 0


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


def test_bench_kinematics_rendered_measurement_only_for_parts_a_and_c(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["--parts", "cd", "--measurement", "aruco", "--out-dir", str(tmp_path)])
    assert "parts a and c only" in capsys.readouterr().err


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
    # the earlier protocol (both cones off): random orientations, every marker in every frame
    old = ur10_datasets(0, 48, facing_cone=None, visibility_cone=None)
    assert np.isfinite(old["train"][0]).all()
    assert _facing_cos(np.array([old["env"].marker_poses(q) for q in old["waypoints"]])).min() < 0


def test_waypoint_rejection_sampling_keeps_accepted_draws_and_gives_up_clearly():
    rng = np.random.default_rng(0)
    wp = ur10_waypoints(rng, 1.0, count=5, accept=lambda q: q[0] > 0.0)
    assert wp.shape == (5, 6) and (wp[:, 0] > 0).all()
    assert np.abs(wp - UR10_HOME).max() <= 1.0
    with pytest.raises(ValueError, match="waypoints accepted"):
        ur10_waypoints(rng, 1.0, count=2, accept=lambda q: False, max_draws=50)


def test_fk_seed_study_writes_its_table_and_counts_the_goal_from_its_rows(tmp_path, capsys):
    out = ["--out-dir", str(tmp_path), "--no-progress", "--runs-dir", str(tmp_path / "runs")]
    assert main(["--fk-seeds", "0", "1", "--samples", "72", "--fk-train", "20", *out]) == 0
    study = json.loads((tmp_path / "kinematics_c_seeds.json").read_text())
    assert [r["seed"] for r in study["rows"]] == [0, 1]
    row1 = json.loads((tmp_path / "runs" / "c_seeds" / "seed1.json").read_text())["result"]
    assert row1 == study["rows"][1]  # one result file per seed
    assert not (tmp_path / "kinematics.json").exists()  # the study writes only its own files
    limits = np.array([0.006] * 3 + [0.04] * 3)
    for key in ("polynomial", "nine_elements", "chain"):
        table = np.array([r[key][:6] for r in study["rows"]])
        assert study["goal"]["met_per_axis"][key] == (table <= limits).sum(0).tolist()
        np.testing.assert_allclose(study["summary"][key]["mean"][:6], table.mean(0))
    assert "| mean |" in (tmp_path / "kinematics_c_seeds.md").read_text()
    with pytest.raises(SystemExit):
        main(["--fk-seeds", "0", "--merge", *out])
    assert "--fk-seeds" in capsys.readouterr().err


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
