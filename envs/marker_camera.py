"""A fixed camera observing fiducial markers on a robot arm (thesis chapter 2 setup).

Gymnasium environment ``mcpilco/MarkerCamera-v0``; the arm comes from the DH-table builder
(:mod:`mcpilco.envs.arm_builder`), one MuJoCo site per marker and a camera in the world.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike, NDArray

from mcpilco.envs.arm_builder import ArmSpec, build_arm_spec
from mcpilco.envs.cartpole_task import validate_action
from mcpilco.envs.marker_detection import (
    MARKER_FRACTION,
    ArucoMarkerDetector,
    camera_matrix,
    marker_texture,
)

__all__ = [
    "MEASUREMENTS",
    "MarkerCameraEnv",
    "NOISE_DEFAULTS",
    "camera_rotation",
    "matrix_to_ypr",
    "ypr_to_matrix",
]

FloatArray = NDArray[np.float64]

NOISE_DEFAULTS: dict[str, float] = dict(
    position_noise=0.002,
    angle_noise=0.007,
    noise_reference_distance=2.0,
    incidence_gain=1.0,
    outlier_prob=0.0,
    outlier_position=0.1,
    encoder_noise=1e-4,
    time_offset=0.005,
)
"""Measurement-noise defaults (see the table in :class:`MarkerCameraEnv`)."""

MEASUREMENTS = ("ideal", "aruco")
"""How marker poses are measured: the noise model, or rendered images + ArUco detection."""


def ypr_to_matrix(o: ArrayLike) -> FloatArray:
    """``Rz(gamma) Ry(beta) Rx(alpha)`` of ``o = [gamma, beta, alpha]`` ``(..., 3)``."""
    o = np.asarray(o, dtype=np.float64)
    cg, cb, ca = np.cos(o[..., 0]), np.cos(o[..., 1]), np.cos(o[..., 2])
    sg, sb, sa = np.sin(o[..., 0]), np.sin(o[..., 1]), np.sin(o[..., 2])
    R = np.stack(
        [
            cg * cb, cg * sb * sa - sg * ca, cg * sb * ca + sg * sa,
            sg * cb, sg * sb * sa + cg * ca, sg * sb * ca - cg * sa,
            -sb, cb * sa, cb * ca,
        ],
        axis=-1,
    )  # fmt: skip
    return R.reshape(*o.shape[:-1], 3, 3)


def matrix_to_ypr(R: ArrayLike) -> FloatArray:
    """``[gamma, beta, alpha]`` with ``R = Rz(gamma) Ry(beta) Rx(alpha)`` (thesis eq. 2.20)."""
    R = np.asarray(R, dtype=np.float64)
    return np.stack(
        [
            np.arctan2(R[..., 1, 0], R[..., 0, 0]),
            np.arctan2(-R[..., 2, 0], np.hypot(R[..., 2, 1], R[..., 2, 2])),
            np.arctan2(R[..., 2, 1], R[..., 2, 2]),
        ],
        axis=-1,
    )


def camera_rotation(position: ArrayLike, look_at: ArrayLike) -> FloatArray:
    """World rotation of an OpenCV-style camera frame (z optical axis, x right, y down)."""
    z = np.asarray(look_at, dtype=np.float64) - np.asarray(position, dtype=np.float64)
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("the camera must not look straight up or down")
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _random_rotations(rng: np.random.Generator, n: int) -> FloatArray:
    """``n`` uniformly distributed rotation matrices (normalised Gaussian quaternions)."""
    quats = rng.standard_normal((n, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    out = np.empty((n, 9))
    for i, qt in enumerate(quats):
        mujoco.mju_quat2Mat(out[i], qt)
    return out.reshape(n, 3, 3)


def _small_rotations(omega: FloatArray) -> FloatArray:
    """Rotation matrices ``exp([omega]_x)`` (Rodrigues) for rotation vectors ``(n, 3)``."""
    out = np.empty((omega.shape[0], 9))
    for i, w in enumerate(omega):
        angle = float(np.linalg.norm(w))
        qt = np.array([1.0, 0.0, 0.0, 0.0])
        if angle > 0:
            mujoco.mju_axisAngle2Quat(qt, w / angle, angle)
        mujoco.mju_quat2Mat(out[i], qt)
    return out.reshape(-1, 3, 3)


class MarkerCameraEnv(gym.Env):
    """Reach a target pose with an arm whose structure is only seen through marker poses.

    ## Description
    A fixed camera (eye-to-hand; thesis section 2.2) observes a serial arm built from a DH
    table (default: the UR10 of :func:`mcpilco.envs.arms.ur10`; ``arm="random"`` gives
    :func:`mcpilco.envs.arms.random_arm` with revolute and prismatic joints, seeded by
    ``arm_seed``). One fiducial marker is rigidly attached to every link, the fixed base
    included (``n + 1`` markers for ``n`` joints; MuJoCo sites ``marker0..markern``, marker
    ``j`` on body ``link{j}``, marker 0 on the world). Marker placements are unknown: at
    every reset each marker gets a random position (``U(-marker_offset, marker_offset)^3``
    plus a random point along the link's ``a`` segment) and a uniformly random orientation.
    Marker identities and the joint order are shuffled by a random permutation per episode,
    so the kinematic structure is unknown to the agent (``info`` gives the permutations for
    evaluation only). The camera frame is OpenCV-like (``z`` optical axis, ``x`` right,
    ``y`` down), placed at ``camera_position`` and looking at ``camera_look_at`` (default:
    2 m in front of the robot, as in the thesis). Poses use yaw-pitch-roll
    ``R = Rz(gamma) Ry(beta) Rx(alpha)``.

    ## Action Space
    ``Box(-1, 1, (n,), float32)``: joint position increments in the *shuffled* joint order
    of the observation; observed joint ``s`` (true joint ``joint_permutation[s]``) moves by
    ``action[s] * max_increment`` (rad; ``max_increment_prismatic`` m for ``P`` joints).
    The low-level controller is ideal: the reference is clipped to the joint range and the
    joint positions are set to it (``qpos`` directly, kinematics only, no dynamics).

    ## Observation Space
    ``Box(-inf, inf, (6 (n + 1) + n + 6,), float64)``:

    | Num                     | Observation                                   | Unit      |
    |-------------------------|-----------------------------------------------|-----------|
    | 6s .. 6s+2              | position ``x, y, z`` of observed marker ``s`` | m         |
    | 6s+3 .. 6s+5            | ``gamma, beta, alpha`` of observed marker ``s``| rad      |
    | 6(n+1) .. 6(n+1)+n-1    | measured position of observed joint ``s``     | rad or m  |
    | 6(n+1)+n .. end         | target pose ``[x, y, z, gamma, beta, alpha]``  | m, rad   |

    (``s = 0..n`` for markers; all poses in the camera frame.)

    ## Measurement noise (defaults in :data:`NOISE_DEFAULTS`)

    | argument                     | default  | meaning                                     |
    |------------------------------|----------|---------------------------------------------|
    | ``position_noise``           | 0.002 m  | std per coordinate at ``d0``, face-on        |
    | ``angle_noise``              | 0.007 rad| std of the rotation-vector error, same       |
    | ``noise_reference_distance`` | 2.0 m    | ``d0``                                      |
    | ``incidence_gain``           | 1.0      | ``kappa``: both stds x ``f`` (below)         |
    | ``outlier_prob``             | 0.0      | probability that a marker pose is an outlier |
    | ``outlier_position``         | 0.1 m    | outlier position error std (and a random     |
    |                              |          | rotation of 0.3..pi rad)                    |
    | ``encoder_noise``            | 1e-4     | encoder std (rad; a tenth of it in m, ``P``) |
    | ``time_offset``              | 0.005 s  | the camera sees the arm this much earlier    |
    |                              |          | than the encoders (linear interpolation     |
    |                              |          | within the last step, ``dt = 0.1`` s)       |
    | ``visibility_cone``          | ``None`` | markers turned more than this from their     |
    |                              |          | line of sight to the camera [deg] are not    |
    |                              |          | seen (NaN rows); ``None``: all are seen      |

    ``f = (d / d0)^2 (1 + kappa (1 - |cos theta|))``, with ``theta`` the angle between the
    marker normal (its ``z`` axis) and the optical axis and ``d`` the camera-marker distance
    (:meth:`measurement_noise_std` gives both stds at a configuration). The position error
    is isotropic (``position_noise * f`` on each camera axis, so its 3-D norm is ``sqrt(3)``
    times that), the orientation error a rotation vector with ``angle_noise * f`` per
    component (geodesic RMS ``sqrt(3)`` times that). Face-on at ``d0 = 2`` m this is 2 mm per
    axis (3.5 mm as a 3-D norm) and 0.012 rad geodesic, AprilTag-like (thesis section
    2.4.2); grazing incidence doubles it. ``f`` grows with the distance and the incidence,
    so over a trajectory the noise is usually larger than these face-on figures (the
    end-marker noise of the ``mcpilco-bench-kinematics`` data is in ``results/kinematics.md``).
    ``|cos theta|`` also treats a marker seen from behind as face-on. A real detector would not
    see it: with ``visibility_cone`` set, a marker whose normal is more than that angle from its
    line of sight to the camera (:meth:`facing_cosines`) reads as a row of NaN and
    ``info["detected"]`` is False for it; without it (the default) the env returns every
    marker. ``marker_facing_cone`` (below) attaches the markers facing the camera, as one does
    on a real robot. Noise is drawn from the env's ``np_random`` (deterministic under
    ``reset(seed=...)``; the same draws with and without ``visibility_cone``).

    ## Rewards
    ``reward = -cost``, ``cost = ||l_ee - l*|| + orientation_weight * angle(R_ee^T R*)``
    [m]: the distance between the (true, noise-free) end-effector marker pose and the target
    pose, with the geodesic angle weighted by ``orientation_weight`` = 0.1 m/rad.

    ## Starting State
    At reset: new marker placements and permutations; joint positions and the target's
    joint configuration drawn uniformly in ``start_centre +- start_range`` (``start_centre``
    defaults to zero; clipped to the joint ranges; prismatic joints uniformly in their
    range); the target pose is the end-effector marker pose at the target configuration
    (always reachable). With ``marker_seed`` set, the placements and permutations are drawn
    once from that seed instead (facing the camera at ``start_centre`` with a facing cone) and
    kept at every reset: one robot with its markers attached, the same in every env made with
    that seed, whatever the reset seeds.

    ## Episode End
    No termination; ``gym.make`` truncates after 100 steps (``mcpilco/MarkerCamera-v0``) or
    20 (``mcpilco/MarkerCameraReach-v0``, below).

    ## Reaching task (``mcpilco/MarkerCameraReach-v0``)
    The same env registered for model-free learners: the UR10 with its markers attached once
    (``marker_seed=0``, facing the camera within 40 deg at the camera-facing home
    ``[0, -pi/2, pi/2, 0, pi/2, 0]``), kept in chain order (``shuffle=False``), every marker
    seen, start and target configurations uniform in home +- 1 rad, increments of at most
    0.2 rad per 0.1 s step, 20-step episodes. ``info["success"]`` says the end marker is
    within ``success_tolerance`` (1 cm and 0.05 rad) of the target pose.

    ## Info
    ``cost``; ``position_error`` [m]; ``orientation_error`` [rad]; ``success``
    (``position_error <= success_tolerance[0]`` and ``orientation_error <=
    success_tolerance[1]``, default 1 cm and 0.05 rad); ``marker_permutation``
    (observed marker slot ``s`` shows chain marker ``marker_permutation[s]``, 0 = base);
    ``joint_permutation`` (observed joint ``s`` is chain joint ``joint_permutation[s]``);
    ``ee_slot`` (the observed slot of the end-effector marker); ``q`` (true joint
    positions, chain order); ``marker_poses`` (true poses ``(n + 1, 6)``, chain order);
    ``target_q`` (chain order); ``detected`` (markers found in the frame, chain order;
    all True with ``measurement="ideal"`` and no ``visibility_cone``); ``t`` [s].

    ## Arguments
    ``arm`` (``"ur10"``, ``"scara"``, ``"random"`` or an :class:`ArmSpec`); ``n_joints``,
    ``joint_types``, ``p_prismatic``, ``arm_seed`` (random arms); ``camera_position``,
    ``camera_look_at``; ``marker_offset``; ``max_increment``, ``max_increment_prismatic``;
    ``start_range``, ``start_centre``; ``dt``; ``orientation_weight``; the noise arguments
    above; ``shuffle`` (False keeps chain order); ``marker_seed``; ``success_tolerance``;
    ``render_mode`` (``"rgb_array"``, offscreen); ``measurement``, ``marker_size``,
    ``image_size``, ``fovy``, ``pixel_noise``, ``marker_facing_cone``, ``visibility_cone``
    (below, above).

    ## Rendered markers (``measurement="aruco"``, optional; needs OpenCV and offscreen GL)
    Instead of the noise model above, every observation renders the camera image with MuJoCo
    and estimates the marker poses with OpenCV's ArUco detector and ``solvePnP``
    (:mod:`mcpilco.envs.marker_detection`); the noise arguments then have no effect except
    ``encoder_noise`` and ``time_offset`` (the image shows the arm at the camera's time).

    | argument             | default       | meaning                                        |
    |----------------------|---------------|------------------------------------------------|
    | ``measurement``      | ``"ideal"``   | ``"ideal"`` (noise model) or ``"aruco"``       |
    | ``marker_size``      | 0.12 m        | side of the square marker face (the black      |
    |                      |               | square is 75 % of it, ArUco ``DICT_4X4_50``,   |
    |                      |               | id = chain index)                              |
    | ``image_size``       | (1920, 1080)  | image width, height [px] (Kinect-2-like)       |
    | ``fovy``             | 54 deg        | vertical field of view (Kinect 2 colour: 54)   |
    | ``pixel_noise``      | 2.0           | std of the Gaussian image noise [grey levels]  |
    | ``marker_facing_cone``| ``None``     | markers face the camera at the start pose      |
    |                      |               | within this angle [deg]; ``None``: uniformly   |
    |                      |               | random ("ideal"), 40 deg ("aruco")             |

    With a facing cone, markers stand in front of their link as seen from the camera at the
    start pose (:meth:`_facing_placements`), so that their own link does not hide them
    there. A marker that is not detected in a frame (turned away, occluded by other links,
    too small) gives a row of NaN in the observation, and ``info["detected"]`` (chain
    order) says which were found.

    ## Version History
    * v0: initial version.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        arm: str | ArmSpec = "ur10",
        n_joints: int = 6,
        joint_types: str | None = None,
        p_prismatic: float = 0.3,
        arm_seed: int = 0,
        camera_position: ArrayLike = (2.0, 0.0, 0.8),
        camera_look_at: ArrayLike = (0.0, 0.0, 0.4),
        marker_offset: float = 0.08,
        max_increment: float = 0.05,
        max_increment_prismatic: float = 0.01,
        start_range: float = math.pi,
        dt: float = 0.1,
        orientation_weight: float = 0.1,
        position_noise: float = NOISE_DEFAULTS["position_noise"],
        angle_noise: float = NOISE_DEFAULTS["angle_noise"],
        noise_reference_distance: float = NOISE_DEFAULTS["noise_reference_distance"],
        incidence_gain: float = NOISE_DEFAULTS["incidence_gain"],
        outlier_prob: float = NOISE_DEFAULTS["outlier_prob"],
        outlier_position: float = NOISE_DEFAULTS["outlier_position"],
        encoder_noise: float = NOISE_DEFAULTS["encoder_noise"],
        time_offset: float = NOISE_DEFAULTS["time_offset"],
        shuffle: bool = True,
        render_mode: str | None = None,
        measurement: str = "ideal",
        marker_size: float = 0.12,
        image_size: tuple[int, int] = (1920, 1080),
        fovy: float = 54.0,
        pixel_noise: float = 2.0,
        marker_facing_cone: float | None = None,
        visibility_cone: float | None = None,
        marker_seed: int | None = None,
        start_centre: ArrayLike | None = None,
        success_tolerance: tuple[float, float] = (0.01, 0.05),
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}")
        if measurement not in MEASUREMENTS:
            raise ValueError(f"measurement must be one of {MEASUREMENTS}, got {measurement!r}")
        width, height = (int(v) for v in image_size)
        if not (marker_size > 0 and width >= 16 and height >= 16 and 0 < fovy < 180):
            raise ValueError(
                f"need marker_size > 0, image_size >= (16, 16) and 0 < fovy < 180, got "
                f"{marker_size=}, {image_size=}, {fovy=}"
            )
        if not pixel_noise >= 0:
            raise ValueError(f"pixel_noise must be >= 0, got {pixel_noise}")
        if marker_facing_cone is None and measurement == "aruco":
            marker_facing_cone = 40.0
        if marker_facing_cone is not None and not 0 <= marker_facing_cone <= 180:
            raise ValueError(
                f"marker_facing_cone must be in [0, 180] deg, got {marker_facing_cone}"
            )
        if visibility_cone is not None:
            if measurement != "ideal":
                raise ValueError(
                    "visibility_cone applies to measurement='ideal' only (the rendered path's "
                    "detector decides what it sees)"
                )
            if not 0 < visibility_cone <= 180:
                raise ValueError(f"visibility_cone must be in (0, 180] deg, got {visibility_cone}")
        self.visibility_cone = visibility_cone
        self.measurement = measurement
        self.marker_size, self.image_size, self.fovy = (
            float(marker_size),
            (width, height),
            float(fovy),
        )
        self.pixel_noise = float(pixel_noise)
        self.marker_facing_cone = marker_facing_cone
        self._detector = None
        self._camera_renderer = None
        for name, value in dict(
            position_noise=position_noise, angle_noise=angle_noise, encoder_noise=encoder_noise,
            time_offset=time_offset, incidence_gain=incidence_gain, marker_offset=marker_offset,
        ).items():  # fmt: skip
            if not value >= 0:
                raise ValueError(f"{name} must be >= 0, got {value}")
        if not 0.0 <= outlier_prob <= 1.0:
            raise ValueError(f"outlier_prob must be in [0, 1], got {outlier_prob}")
        if not (dt > 0 and time_offset <= dt):
            raise ValueError(f"need dt > 0 and time_offset <= dt, got dt={dt}, {time_offset=}")
        self.arm = self._make_arm(arm, n_joints, joint_types, p_prismatic, arm_seed)
        n = self.arm.n_joints
        self.n_joints, self.n_markers = n, n + 1
        self.prismatic = np.array([j.type == "P" for j in self.arm.joints])
        ranges = self.arm.joint_ranges
        self.q_low, self.q_high = ranges[:, 0], ranges[:, 1]
        self.max_increment = np.where(self.prismatic, max_increment_prismatic, max_increment)
        self.start_range = float(start_range)
        centre = np.zeros(n) if start_centre is None else np.asarray(start_centre, dtype=float)
        if centre.shape != (n,) or not np.all(np.isfinite(centre)):
            raise ValueError(f"start_centre must be {n} finite joint positions, got {start_centre}")
        self.start_centre = np.clip(centre, self.q_low, self.q_high)
        tol = tuple(float(v) for v in success_tolerance)
        if len(tol) != 2 or not all(v > 0 for v in tol):
            raise ValueError(
                "success_tolerance must be (position [m], angle [rad]) > 0, got "
                f"{success_tolerance}"
            )
        self.success_tolerance = tol
        if marker_seed is not None and (isinstance(marker_seed, bool) or int(marker_seed) < 0):
            raise ValueError(f"marker_seed must be an integer >= 0 or None, got {marker_seed!r}")
        self.marker_seed = None if marker_seed is None else int(marker_seed)
        self._markers_fixed = False  # placements drawn from marker_seed yet
        self.dt, self.time_offset = float(dt), float(time_offset)
        self.orientation_weight = float(orientation_weight)
        self.marker_offset = float(marker_offset)
        self.position_noise, self.angle_noise = float(position_noise), float(angle_noise)
        self.noise_reference_distance = float(noise_reference_distance)
        self.incidence_gain = float(incidence_gain)
        self.outlier_prob, self.outlier_position = float(outlier_prob), float(outlier_position)
        self.encoder_noise = np.where(self.prismatic, 0.1, 1.0) * float(encoder_noise)
        self.shuffle = bool(shuffle)
        self.render_mode = render_mode
        self._renderer = None

        self.camera_position = np.asarray(camera_position, dtype=np.float64)
        self.camera_R = camera_rotation(self.camera_position, camera_look_at)  # world <- camera
        self.model = self._build_model()
        self.data = mujoco.MjData(self.model)
        self._site = np.array([self.model.site(f"marker{j}").id for j in range(n + 1)])
        self._a = np.array([j.a for j in self.arm.joints])
        self._body = np.array([self.model.site_bodyid[s] for s in self._site])
        self.detected = np.ones(n + 1, dtype=bool)

        obs_dim = 6 * (n + 1) + n + 6
        self.action_space = spaces.Box(-1.0, 1.0, shape=(n,), dtype=np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(obs_dim,), dtype=np.float64)
        self.marker_permutation = np.arange(n + 1)
        self.joint_permutation = np.arange(n)
        self.q = np.zeros(n)
        self._q_prev = np.zeros(n)
        self.target_q = np.zeros(n)
        self.target_pose = np.zeros(6)
        self._t = 0.0

    # ---------------------------------------------------------------- construction
    @staticmethod
    def _make_arm(
        arm: str | ArmSpec, n_joints: int, joint_types: str | None, p_prismatic: float, seed: int
    ) -> ArmSpec:
        from mcpilco.envs import arms

        if isinstance(arm, ArmSpec):
            return arm
        if arm == "random":
            if joint_types is not None:
                n_joints = len(joint_types)
            return arms.random_arm(n_joints, seed=seed, joint_types=joint_types,
                                   p_prismatic=p_prismatic)  # fmt: skip
        if arm in arms.ARMS:
            return arms.ARMS[arm]()
        raise ValueError(
            f"arm must be 'random', one of {sorted(arms.ARMS)} or an ArmSpec, got {arm!r}"
        )

    def _build_model(self) -> mujoco.MjModel:
        spec = build_arm_spec(self.arm, friction=False, armature=False, floor=True)
        spec.visual.global_.offwidth = max(640, self.image_size[0])
        spec.visual.global_.offheight = max(480, self.image_size[1])
        size = [self.marker_size / 2, self.marker_size / 2, 0.002]
        for j in range(self.arm.n_joints + 1):
            look: dict[str, Any] = dict(rgba=[0.1, 0.1, 0.1, 1.0])
            if self.measurement == "aruco":  # the marker image on the site's +z face
                tex = marker_texture(j)
                h, w, c = tex.shape
                spec.add_texture(name=f"aruco{j}", type=mujoco.mjtTexture.mjTEXTURE_2D,
                                 width=w, height=h, nchannel=c).data = tex.tobytes()  # fmt: skip
                mat = spec.add_material(name=f"aruco{j}")
                mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = f"aruco{j}"
                look = dict(material=f"aruco{j}")
            body = spec.worldbody if j == 0 else spec.body(f"link{j}")
            body.add_site(name=f"marker{j}", type=mujoco.mjtGeom.mjGEOM_BOX, size=size, **look)
        # MuJoCo cameras look along their -z with y up: columns [x, -y, -z] of the CV frame
        R_mj = self.camera_R * np.array([1.0, -1.0, -1.0])
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, R_mj.ravel())
        spec.worldbody.add_camera(name="camera", pos=self.camera_position.tolist(),
                                  quat=quat.tolist(), fovy=self.fovy)  # fmt: skip
        return spec.compile()

    # ---------------------------------------------------------------- kinematics
    def _set_q(self, q: FloatArray) -> None:
        self.data.qpos[:] = q
        mujoco.mj_kinematics(self.model, self.data)

    def marker_transforms(self, q: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """True (noise-free) marker poses at ``q`` (chain order) in the camera frame.

        Returns ``(l, R)``: positions ``(n + 1, 3)`` and rotations ``(n + 1, 3, 3)``. The
        simulator state is restored to the current joint positions afterwards.
        """
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (self.n_joints,):
            raise ValueError(f"q must have shape ({self.n_joints},), got {q.shape}")
        self._set_q(q)
        xpos = self.data.site_xpos[self._site]
        xmat = self.data.site_xmat[self._site].reshape(-1, 3, 3)
        l_c = (xpos - self.camera_position) @ self.camera_R
        R_c = np.einsum("ji,njk->nik", self.camera_R, xmat)
        self._set_q(self.q)
        return l_c, R_c

    def marker_poses(self, q: ArrayLike) -> FloatArray:
        """True marker poses ``(n + 1, 6)`` ``[x, y, z, gamma, beta, alpha]`` at ``q``."""
        l_c, R_c = self.marker_transforms(q)
        return np.concatenate([l_c, matrix_to_ypr(R_c)], axis=1)

    def marker_placements(self) -> tuple[FloatArray, FloatArray]:
        """Marker poses in their body frames: ``pos`` ``(n+1, 3)``, ``R`` ``(n+1, 3, 3)``."""
        pos = self.model.site_pos[self._site].copy()
        R = np.empty((self.n_markers, 9))
        for i, s in enumerate(self._site):
            mujoco.mju_quat2Mat(R[i], self.model.site_quat[s])
        return pos, R.reshape(-1, 3, 3)

    # ---------------------------------------------------------------- measurement
    def _noise_scale(self, l_c: FloatArray, R_c: FloatArray) -> FloatArray:
        d = np.linalg.norm(l_c, axis=1)
        cos_theta = np.abs(R_c[:, 2, 2])  # marker normal . optical axis
        return (d / self.noise_reference_distance) ** 2 * (
            1.0 + self.incidence_gain * (1.0 - cos_theta)
        )

    @staticmethod
    def _facing_cosines(l_c: FloatArray, R_c: FloatArray) -> FloatArray:
        # marker normal (z axis) . unit line of sight from the marker to the camera
        return -np.einsum("mi,mi->m", R_c[:, :, 2], l_c) / np.linalg.norm(l_c, axis=1)

    def facing_cosines(self, q: ArrayLike) -> FloatArray:
        """``cos phi`` of every marker at ``q`` (chain order), ``(n + 1,)``: ``phi`` the angle
        between the marker normal (its ``z`` axis) and its line of sight to the camera; 1 faces
        the camera, < 0 turns its back to it. ``visibility_cone`` hides markers with
        ``phi > visibility_cone``."""
        return self._facing_cosines(*self.marker_transforms(q))

    def noise_scale(self, q: ArrayLike) -> FloatArray:
        """``f = (d / d0)^2 (1 + kappa (1 - |cos theta|))`` of every marker at ``q``
        (chain order), ``(n + 1,)``: the factor on both noise stds (class docstring)."""
        return self._noise_scale(*self.marker_transforms(q))

    def measurement_noise_std(self, q: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Noise stds of every marker at joint positions ``q`` (chain order), outliers aside.

        Returns ``(position_std, angle_std)``, each ``(n + 1,)`` in chain order:
        ``position_noise * f`` [m] per camera axis and ``angle_noise * f`` [rad] per
        rotation-vector component (:meth:`noise_scale`).
        """
        scale = self.noise_scale(q)
        return self.position_noise * scale, self.angle_noise * scale

    def _measure(self) -> tuple[FloatArray, FloatArray]:
        """Noisy marker poses (chain order) and encoder readings (chain order)."""
        rng = self.np_random
        lag = self.time_offset / self.dt
        q_cam = self.q - lag * (self.q - self._q_prev)
        if self.measurement == "aruco":
            poses = self._detect_markers(q_cam)
            q_meas = self.q + rng.standard_normal(self.n_joints) * self.encoder_noise
            return poses, q_meas
        l_c, R_c = self.marker_transforms(q_cam)
        scale = self._noise_scale(l_c, R_c)
        m = self.n_markers
        l_meas = l_c + rng.standard_normal((m, 3)) * (self.position_noise * scale)[:, None]
        omega = rng.standard_normal((m, 3)) * (self.angle_noise * scale)[:, None]
        R_meas = _small_rotations(omega) @ R_c
        outlier = rng.random(m) < self.outlier_prob
        if outlier.any():
            k = int(outlier.sum())
            l_meas[outlier] += rng.standard_normal((k, 3)) * self.outlier_position
            axis = rng.standard_normal((k, 3))
            axis /= np.linalg.norm(axis, axis=1, keepdims=True)
            R_meas[outlier] = (
                _small_rotations(axis * rng.uniform(0.3, np.pi, (k, 1))) @ R_meas[outlier]
            )
        poses = np.concatenate([l_meas, matrix_to_ypr(R_meas)], axis=1)
        q_meas = self.q + rng.standard_normal(self.n_joints) * self.encoder_noise
        if self.visibility_cone is not None:  # same draws as without; hidden markers: NaN
            cos_min = math.cos(math.radians(self.visibility_cone))
            self.detected = self._facing_cosines(l_c, R_c) >= cos_min
            poses[~self.detected] = np.nan
        return poses, q_meas

    def camera_image(self, q: ArrayLike | None = None) -> NDArray[np.uint8]:
        """Noise-free RGB image ``(H, W, 3)`` of the marker camera at ``image_size`` with the
        arm at ``q`` (chain order; default: the current joint positions)."""
        if self._camera_renderer is None:
            width, height = self.image_size
            self._camera_renderer = mujoco.Renderer(self.model, height, width)
        self._set_q(self.q if q is None else np.asarray(q, dtype=np.float64))
        mujoco.mj_camlight(self.model, self.data)
        self._camera_renderer.update_scene(self.data, camera="camera")
        image = self._camera_renderer.render()
        self._set_q(self.q)
        return image

    def _detect_markers(self, q_cam: FloatArray) -> FloatArray:
        """Marker poses ``(n + 1, 6)`` (chain order) detected in the rendered image at
        ``q_cam`` with Gaussian pixel noise; NaN rows for markers not found."""
        image = self.camera_image(q_cam)
        if self.pixel_noise > 0:
            noise = self.np_random.standard_normal(image.shape[:2])[:, :, None] * self.pixel_noise
            image = np.clip(image + noise, 0, 255).astype(np.uint8)
        if self._detector is None:
            K = camera_matrix(*self.image_size, self.fovy)
            self._detector = ArucoMarkerDetector(K, MARKER_FRACTION * self.marker_size)
        found = self._detector.detect(image)
        poses = np.full((self.n_markers, 6), np.nan)
        for j, (l, R) in found.items():
            if j < self.n_markers:
                poses[j] = np.concatenate([l, matrix_to_ypr(R)])
        self.detected = ~np.isnan(poses[:, 0])
        return poses

    def _get_obs(self) -> FloatArray:
        poses, q_meas = self._measure()
        return np.concatenate(
            [
                poses[self.marker_permutation].ravel(),
                q_meas[self.joint_permutation],
                self.target_pose,
            ]
        )

    # ---------------------------------------------------------------- task
    def _pose_errors(self) -> tuple[float, float]:
        l_c, R_c = self.marker_transforms(self.q)
        R_t = ypr_to_matrix(self.target_pose[3:])
        d_pos = float(np.linalg.norm(l_c[-1] - self.target_pose[:3]))
        cos = np.clip((np.trace(R_c[-1].T @ R_t) - 1.0) / 2.0, -1.0, 1.0)
        return d_pos, float(np.arccos(cos))

    def _info(self) -> dict[str, Any]:
        d_pos, d_ang = self._pose_errors()
        cost = d_pos + self.orientation_weight * d_ang
        return dict(
            cost=cost,
            position_error=d_pos,
            orientation_error=d_ang,
            success=d_pos <= self.success_tolerance[0] and d_ang <= self.success_tolerance[1],
            marker_permutation=self.marker_permutation.copy(),
            joint_permutation=self.joint_permutation.copy(),
            ee_slot=int(np.nonzero(self.marker_permutation == self.n_joints)[0][0]),
            q=self.q.copy(),
            marker_poses=self.marker_poses(self.q),
            target_q=self.target_q.copy(),
            detected=self.detected.copy(),
            t=self._t,
        )

    def _random_q(self) -> FloatArray:
        rng = self.np_random
        c, r = self.start_centre, self.start_range
        lo = np.where(self.prismatic, self.q_low, np.maximum(self.q_low, c - r))
        hi = np.where(self.prismatic, self.q_high, np.minimum(self.q_high, c + r))
        return rng.uniform(lo, hi)

    def _fix_markers(self) -> None:
        """Placements and permutations drawn once from ``marker_seed`` (the markers facing
        the camera at ``start_centre`` with a facing cone), kept at every later reset."""
        rng = np.random.default_rng(self.marker_seed)
        self._set_q(self.start_centre)
        self._place_markers(rng)
        if self.shuffle:
            self.marker_permutation = rng.permutation(self.n_markers)
            self.joint_permutation = rng.permutation(self.n_joints)
        self._markers_fixed = True

    def _place_markers(self, rng: np.random.Generator | None = None) -> None:
        """Random marker placements in their body frames (class docstring), drawn from
        ``rng`` (the env's ``np_random`` by default). With a facing cone, call it with the
        start configuration set (the normals are chosen there)."""
        rng = self.np_random if rng is None else rng
        n = self.n_joints
        R = _random_rotations(rng, n + 1)
        along = np.concatenate([[0.0], rng.uniform(0.0, 1.0, n) * self._a])
        pos = rng.uniform(-self.marker_offset, self.marker_offset, (n + 1, 3))
        pos[:, 0] += along
        pos[0] += np.asarray(self.arm.base_pos)
        if self.marker_facing_cone is not None:
            anchor = np.zeros_like(pos)
            anchor[:, 0] = along
            anchor[0] = np.asarray(self.arm.base_pos)
            R, pos = self._facing_placements(rng, pos, anchor)
        for j, s in enumerate(self._site):
            quat = np.zeros(4)
            mujoco.mju_mat2Quat(quat, R[j].ravel())
            self.model.site_pos[s] = pos[j]
            self.model.site_quat[s] = quat
            self.model.site_sameframe[s] = 0  # the compiler may have fused it with the body

    def _facing_placements(
        self, rng: np.random.Generator, pos: FloatArray, anchor: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Rotations (body frames) whose ``z`` normal points to the camera at the current
        configuration within ``marker_facing_cone`` (uniform on that spherical cap, uniform
        spin about the normal); positions in front of the link as seen from the camera (the
        random offset from ``anchor`` (body frames) loses its component along the line of
        sight ``u``, then moves by
        ``1.2 r + marker_size sin(cone) / 2 + 0.02`` m along ``u``; ``r`` the link radius);
        the base marker is lifted to at least ``0.6 marker_size + 0.01`` m above the floor."""
        m = self.n_markers
        body_R = self.data.xmat[self._body].reshape(m, 3, 3)
        world = self.data.xpos[self._body] + np.einsum("mij,mj->mi", body_R, pos)
        to_cam = self.camera_position - world
        to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
        cone = math.radians(self.marker_facing_cone)
        standoff = (
            1.2 * self.arm.radius + 0.5 * self.marker_size * math.sin(min(cone, math.pi / 2)) + 0.02
        )
        cos_max = math.cos(cone)
        cos_t = rng.uniform(cos_max, 1.0, m)
        phi, spin = rng.uniform(0.0, 2 * math.pi, (2, m))
        R_out, pos_out = np.empty((m, 3, 3)), pos.copy()
        for j in range(m):
            # orthonormal frame (e1, e2, to_cam), then the tilted normal and the spin
            e1 = np.cross(to_cam[j], [0.0, 0.0, 1.0] if abs(to_cam[j, 2]) < 0.9 else [1.0, 0, 0])
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(to_cam[j], e1)
            sin_t = math.sqrt(max(0.0, 1.0 - cos_t[j] ** 2))
            z = cos_t[j] * to_cam[j] + sin_t * (math.cos(phi[j]) * e1 + math.sin(phi[j]) * e2)
            x0 = np.cross(e2, z)
            x0 /= np.linalg.norm(x0)
            y0 = np.cross(z, x0)
            x = math.cos(spin[j]) * x0 + math.sin(spin[j]) * y0
            R_world = np.column_stack([x, np.cross(z, x), z])
            R_out[j] = body_R[j].T @ R_world
            # in front of the link as seen from the camera: the random offset without its
            # component along the line of sight, then a stand-off towards the camera
            offset = body_R[j] @ (pos[j] - anchor[j])
            shift = standoff * to_cam[j] - (offset @ to_cam[j]) * to_cam[j]
            pos_out[j] = pos[j] + body_R[j].T @ shift
        # the base marker stands clear of the floor (z = 0)
        pos_out[0, 2] = max(pos_out[0, 2], 0.6 * self.marker_size + 0.01)
        return R_out, pos_out

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[FloatArray, dict[str, Any]]:
        """New marker placements, permutations, start and target (see the class docstring).

        ``options={"q": q0}`` sets the start configuration (chain order).
        """
        super().reset(seed=seed)
        rng = self.np_random
        fixed = self.marker_seed is not None
        if fixed and not self._markers_fixed:
            self._fix_markers()
        facing = self.marker_facing_cone is not None  # placed at the start pose (below)
        if not facing and not fixed:
            self._place_markers()
        if self.shuffle and not fixed:
            self.marker_permutation = rng.permutation(self.n_markers)
            self.joint_permutation = rng.permutation(self.n_joints)
        self.target_q = self._random_q()
        self.q = self._random_q()
        if options and "q" in options:
            q0 = np.asarray(options["q"], dtype=np.float64)
            if q0.shape != (self.n_joints,):
                raise ValueError(f"options['q'] must have shape ({self.n_joints},)")
            self.q = np.clip(q0, self.q_low, self.q_high)
        if facing and not fixed:
            self._set_q(self.q)
            self._place_markers()
        self._q_prev = self.q.copy()
        self.target_pose = self.marker_poses(self.target_q)[-1]
        self._set_q(self.q)
        self._t = 0.0
        return self._get_obs(), self._info()

    def step(self, action: ArrayLike) -> tuple[FloatArray, float, bool, bool, dict[str, Any]]:
        a = np.clip(validate_action(action, self.n_joints), -1.0, 1.0)
        delta = np.empty(self.n_joints)
        delta[self.joint_permutation] = a  # observed slot s drives chain joint perm[s]
        self._q_prev = self.q.copy()
        self.q = np.clip(self.q + delta * self.max_increment, self.q_low, self.q_high)
        self._set_q(self.q)
        self._t += self.dt
        obs = self._get_obs()
        info = self._info()
        return obs, -float(info["cost"]), False, False, info

    # ---------------------------------------------------------------- rendering
    def render(self) -> NDArray[np.uint8] | None:
        """``rgb_array`` image from the marker camera (offscreen; needs an OpenGL backend)."""
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, 480, 640)
        mujoco.mj_camlight(self.model, self.data)  # camera and light poses (not kinematics)
        self._renderer.update_scene(self.data, camera="camera")
        return self._renderer.render()

    def close(self) -> None:
        for name in ("_renderer", "_camera_renderer"):
            renderer = getattr(self, name)
            if renderer is not None:
                renderer.close()
                setattr(self, name, None)
