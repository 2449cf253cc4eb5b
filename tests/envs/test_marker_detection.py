"""Rendered ArUco markers of MarkerCamera-v0 (``measurement="aruco"``) against MuJoCo's truth.

The truth is MuJoCo's kinematics (site poses); the estimate comes through an independent
pipeline: OpenGL rendering of the textured markers, OpenCV's ArUco detector and solvePnP.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from mcpilco.envs.arm_env import UR10_HOME
from mcpilco.envs.marker_camera import MarkerCameraEnv, ypr_to_matrix
from mcpilco.envs.marker_detection import ArucoMarkerDetector, camera_matrix, marker_texture

cv2 = pytest.importorskip("cv2", reason="the rendered marker path needs OpenCV (mcpilco[vision])")


def _geodesic(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    R = np.swapaxes(ypr_to_matrix(a), -1, -2) @ ypr_to_matrix(b)
    return np.arccos(np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0))


def test_camera_matrix_pinhole():
    # fovy = 90 deg: f = (H / 2) / tan(45 deg) = H / 2; principal point at the centre
    K = camera_matrix(200, 100, 90.0)
    np.testing.assert_allclose(K, [[50.0, 0, 99.5], [0, 50.0, 49.5], [0, 0, 1]], atol=1e-12)
    with pytest.raises(ValueError):
        camera_matrix(0, 100, 60.0)


def test_marker_texture_layout_and_bad_id():
    tex = marker_texture(3, pixels=240)
    assert tex.shape == (240, 240, 3) and tex.dtype == np.uint8
    assert (tex[:30] == 255).all() and (tex[:, -30:] == 255).all()  # white quiet zone
    assert (tex[30:36, 30:210] == 0).all()  # the black border of the marker
    with pytest.raises(ValueError, match="marker_id"):
        marker_texture(50)


def test_bad_arguments():
    with pytest.raises(ValueError, match="measurement"):
        MarkerCameraEnv(measurement="stereo")
    with pytest.raises(ValueError, match="pixel_noise"):
        MarkerCameraEnv(pixel_noise=-1.0)
    with pytest.raises(ValueError, match="marker_facing_cone"):
        MarkerCameraEnv(marker_facing_cone=200.0)


@pytest.mark.parametrize("cone", [0.0, 30.0])
def test_facing_cone_points_markers_at_the_camera(cone):
    env = MarkerCameraEnv(marker_facing_cone=cone)
    env.reset(seed=4, options={"q": np.asarray(UR10_HOME)})
    l_c, R_c = env.marker_transforms(env.q)
    to_cam = -l_c / np.linalg.norm(l_c, axis=1, keepdims=True)  # camera frame
    angle = np.degrees(np.arccos(np.clip(np.einsum("mi,mi->m", R_c[:, :, 2], to_cam), -1, 1)))
    assert (angle <= cone + 1e-6).all(), angle


def test_rendered_image_is_lit(gl_in_process):
    """render() sets the camera and light poses (mj_camlight), so the floor is visible."""
    env = MarkerCameraEnv(render_mode="rgb_array")
    env.reset(seed=0, options={"q": np.asarray(UR10_HOME)})
    img = env.render()
    env.close()
    assert img.shape == (480, 640, 3) and img.mean() > 20.0


def test_detected_poses_match_the_truth(gl_in_process):
    env = MarkerCameraEnv(measurement="aruco", time_offset=0.0, encoder_noise=0.0,
                          pixel_noise=0.0)  # fmt: skip
    n_found, pos_rel, ang = 0, [], []
    for seed in range(3):
        obs, info = env.reset(seed=seed, options={"q": np.asarray(UR10_HOME)})
        m = env.n_markers
        observed = obs[: 6 * m].reshape(m, 6)
        det = info["detected"]
        # NaN rows exactly where nothing was detected (observed slots are permuted)
        np.testing.assert_array_equal(np.isnan(observed).any(1), ~det[env.marker_permutation])
        chain = observed[np.argsort(env.marker_permutation)]
        true = info["marker_poses"]
        n_found += int(det.sum())
        dist = np.linalg.norm(true[det, :3], axis=1)
        pos_rel.extend(np.linalg.norm(chain[det, :3] - true[det, :3], axis=1) / dist)
        ang.extend(_geodesic(chain[det, 3:], true[det, 3:]))
    env.close()
    assert n_found >= 6, n_found  # 21 markers shown facing the camera
    # AprilTag-like accuracy: ~1-2 % of the distance (depth), a few 0.01 rad
    assert np.median(pos_rel) < 0.03, np.median(pos_rel)
    assert np.median(ang) < 0.05, np.median(ang)


def test_face_on_corners_project_to_the_truth(gl_in_process):
    """A marker face-on at 1.5 m: solvePnP's distance within 1 % and the lateral position
    within 2 mm of MuJoCo's (pinhole intrinsics of camera_matrix)."""
    env = MarkerCameraEnv(measurement="aruco", time_offset=0.0, pixel_noise=0.0,
                          marker_facing_cone=0.0)  # fmt: skip
    env.reset(seed=1, options={"q": np.asarray(UR10_HOME)})
    # put the base marker face-on, 1.5 m in front of the camera
    site = env._site[0]
    target = env.camera_position + 1.5 * env.camera_R[:, 2]
    env.model.site_pos[site] = target
    R_world = env.camera_R @ np.diag([1.0, -1.0, -1.0])  # z towards the camera
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, R_world.ravel())
    env.model.site_quat[site] = quat
    poses = env._detect_markers(env.q)
    env.close()
    assert env.detected[0]
    l = poses[0, :3]
    assert abs(l[2] - 1.5) < 0.015 and np.hypot(l[0], l[1]) < 0.002, l
    # orientation: R_c = camera_R^T R_world = diag(1, -1, -1)
    R_det = ypr_to_matrix(poses[0, 3:])
    np.testing.assert_allclose(R_det, np.diag([1.0, -1.0, -1.0]), atol=0.03)


def _project(K: np.ndarray, R: np.ndarray, l: np.ndarray, L: float) -> np.ndarray:
    """Pinhole projection of the 4 corners (ArUco order) of a square of side L at (R, l)."""
    h = L / 2
    obj = np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])
    p = (obj @ R.T + l) @ K.T
    return p[:, :2] / p[:, 2:]


def test_pose_from_exact_corners_and_ambiguity_rejection():
    """Exact projections of a marker tilted by 50 deg at 2 m: the solver recovers the pose
    (analytic truth); an ambiguity ratio that no solution can beat drops it instead."""
    K = camera_matrix(1920, 1080, 54.0)
    c, s = math.cos(math.radians(50)), math.sin(math.radians(50))
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]) @ np.diag([1.0, -1.0, -1.0])
    l = np.array([0.1, -0.05, 2.0])
    corners = _project(K, R, l, 0.09)
    det = ArucoMarkerDetector(K, 0.09)
    l_hat, R_hat = det._solve(corners)
    np.testing.assert_allclose(l_hat, l, atol=1e-6)
    np.testing.assert_allclose(R_hat, R, atol=1e-6)
    ratio, spread = det.last_ambiguity
    assert ratio > 3.0 and spread > 0.3  # the flipped solution is far off and fits worse
    strict = ArucoMarkerDetector(K, 0.09, min_ambiguity_ratio=math.inf)
    assert strict._solve(corners) is None


def test_edge_refinement_recovers_the_corners_of_a_blurred_square():
    """A dark square (true corners known to sub-pixel precision) drawn at 8x and area-
    downsampled, then blurred: the refined corners are within 0.15 px of the truth, and
    closer than the blurred-corner starting guesses moved 0.5 px inwards."""
    from mcpilco.envs.marker_detection import refine_corners_by_edges

    S = 8
    centre, half, angle = np.array([80.3, 71.6]), 19.0, math.radians(17.0)
    c, s = math.cos(angle), math.sin(angle)
    unit = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float)  # clockwise, y down
    truth = centre + half * unit @ np.array([[c, s], [-s, c]])
    big = np.full((160 * S, 160 * S), 255, np.uint8)
    # OpenCV puts pixel centres at integers: small-image point u is (u + 1/2) S - 1/2 in the
    # 8x image, whose pixels INTER_AREA averages in blocks of S x S
    poly = np.round(((truth + 0.5) * S - 0.5) * 16).astype(np.int32)  # 4 fractional bits
    cv2.fillPoly(big, [poly], 0, lineType=cv2.LINE_8, shift=4)
    img = cv2.resize(big, (160, 160), interpolation=cv2.INTER_AREA)
    img = cv2.GaussianBlur(img, (0, 0), 1.0)
    guess = centre + (half - 0.5) * unit @ np.array([[c, s], [-s, c]])
    refined = refine_corners_by_edges(img, guess)
    assert np.abs(refined - truth).max() < 0.15, refined - truth  # rasterisation ~0.1 px
    assert np.abs(guess - truth).max() > 0.5
