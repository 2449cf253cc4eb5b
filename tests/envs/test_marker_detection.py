"""Rendered ArUco markers of MarkerCamera-v0 (``measurement="aruco"``) against MuJoCo's truth.

The truth is MuJoCo's kinematics (site poses); the estimate comes through an independent
pipeline: OpenGL rendering of the textured markers, OpenCV's ArUco detector and solvePnP.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mcpilco.envs.arm_env import UR10_HOME
from mcpilco.envs.marker_camera import MarkerCameraEnv, ypr_to_matrix
from mcpilco.envs.marker_detection import camera_matrix, marker_texture

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
