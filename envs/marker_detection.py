r"""Rendered fiducial markers and their detection: the optional image path of MarkerCamera-v0.

Instead of perturbing the true marker poses with a noise model, the camera image is rendered
with MuJoCo (offscreen; ``MUJOCO_GL=egl`` or ``osmesa``) with an ArUco texture on every marker
and the poses are estimated from the image, as a real setup would (thesis section 2.2; the
thesis used AprilTags and a Kinect 2):

1. corners ``c_i`` (pixels) of every visible marker by OpenCV's ArUco detector (dictionary
   ``DICT_4X4_50``, sub-pixel corner refinement);
2. the pose ``(R, l)`` of the marker frame in the camera frame by ``cv2.solvePnPGeneric``
   with ``SOLVEPNP_IPPE_SQUARE`` (the planar square of side ``L``; of its two solutions the
   one with the lower reprojection error; SQPnP where IPPE fails; dropped above 2 px RMS):

   .. math::

      \min_{R, l} \sum_{i=1}^{4} \lVert c_i - \pi(K (R\, o_i + l)) \rVert^2, \qquad
      o_i \in \{(\mp L/2, \pm L/2, 0)\},

   with the pinhole intrinsics ``K`` of the MuJoCo camera (:func:`camera_matrix`) and
   ``pi`` the perspective division.

Symbols: ``K`` intrinsics (``f`` focal length [px], ``c_x, c_y`` principal point [px]);
``L`` the side of the black square of the marker [m]; the marker frame is OpenCV's ArUco
frame (origin at the centre, ``x`` right and ``y`` up in the marker image, ``z`` out of the
face), which is the MuJoCo site frame of the marker (its ``+z`` face carries the texture).

OpenCV is an optional dependency (``pip install 'mcpilco[vision]'``); only this path needs it.
"""

from __future__ import annotations

import math
from types import ModuleType

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "ARUCO_DICTIONARY",
    "ArucoMarkerDetector",
    "camera_matrix",
    "marker_texture",
    "require_cv2",
]

ARUCO_DICTIONARY = "DICT_4X4_50"
"""ArUco dictionary of the rendered markers (marker ``j`` of the chain has id ``j``)."""

MARKER_FRACTION = 0.75
"""Side of the black square ``L`` over the side of the textured face (the rest is a white
quiet zone that the detector needs around the black border)."""


def require_cv2() -> ModuleType:
    """Import OpenCV or raise an ImportError that says how to install it."""
    try:
        import cv2
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise ImportError(
            "the rendered marker path needs OpenCV: pip install 'mcpilco[vision]' "
            "(opencv-python-headless)"
        ) from exc
    if not hasattr(cv2, "aruco"):  # pragma: no cover - very old OpenCV builds
        raise ImportError("this OpenCV build has no aruco module; install opencv>=4.7")
    return cv2


def marker_texture(marker_id: int, pixels: int = 240) -> NDArray[np.uint8]:
    """RGB texture ``(pixels, pixels, 3)`` of ArUco marker ``marker_id``: the black square
    (:data:`MARKER_FRACTION` of the side) centred on a white face."""
    cv2 = require_cv2()
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, ARUCO_DICTIONARY))
    n_ids = dictionary.bytesList.shape[0]
    if not 0 <= marker_id < n_ids:
        raise ValueError(f"marker_id must be in [0, {n_ids}), got {marker_id}")
    inner = int(round(MARKER_FRACTION * pixels))
    if inner < 6 or (pixels - inner) % 2:
        raise ValueError(f"pixels={pixels} gives a marker of {inner} px; use an even size >= 8")
    face = np.full((pixels, pixels), 255, dtype=np.uint8)
    m = (pixels - inner) // 2
    face[m : m + inner, m : m + inner] = cv2.aruco.generateImageMarker(dictionary, marker_id, inner)
    return np.repeat(face[:, :, None], 3, axis=2)


def camera_matrix(width: int, height: int, fovy_deg: float) -> NDArray[np.float64]:
    """Pinhole intrinsics ``K`` of a MuJoCo camera rendered at ``width x height`` pixels.

    ``f = (height / 2) / tan(fovy / 2)`` (square pixels); the principal point is the image
    centre in OpenCV's convention (pixel centres at integer coordinates):
    ``c_x = width / 2 - 1/2``, ``c_y = height / 2 - 1/2``.
    """
    if width <= 0 or height <= 0 or not 0.0 < fovy_deg < 180.0:
        raise ValueError(
            f"need width, height > 0 and 0 < fovy < 180, got {width, height, fovy_deg}"
        )
    f = 0.5 * height / math.tan(math.radians(fovy_deg) / 2.0)
    return np.array([[f, 0.0, width / 2 - 0.5], [0.0, f, height / 2 - 0.5], [0.0, 0.0, 1.0]])


class ArucoMarkerDetector:
    """Marker poses in the camera frame from one image (module docstring).

    Args:
        K: ``(3, 3)`` camera intrinsics (:func:`camera_matrix`).
        marker_length: side ``L`` of the black square [m].
        min_perimeter_rate: the detector's smallest marker perimeter over the image's largest
            side (OpenCV's ``minMarkerPerimeterRate``; smaller finds smaller markers).
        max_reprojection_error: RMS corner reprojection error [px] above which a detection
            is dropped (a failed pose solution).
    """

    def __init__(
        self,
        K: NDArray[np.float64],
        marker_length: float,
        min_perimeter_rate: float = 0.01,
        max_reprojection_error: float = 2.0,
    ) -> None:
        cv2 = require_cv2()
        if not marker_length > 0:
            raise ValueError(f"marker_length must be > 0, got {marker_length}")
        self._cv2 = cv2
        self.K = np.asarray(K, dtype=np.float64)
        self.marker_length = float(marker_length)
        self.max_reprojection_error = float(max_reprojection_error)
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        params.minMarkerPerimeterRate = float(min_perimeter_rate)
        params.polygonalApproxAccuracyRate = 0.05  # small markers (default 0.03 misses some)
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, ARUCO_DICTIONARY))
        self._detector = cv2.aruco.ArucoDetector(dictionary, params)
        h = self.marker_length / 2.0
        self._object_points = np.array(
            [[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]], dtype=np.float64
        )

    def detect(
        self, image: NDArray[np.uint8]
    ) -> dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]]:
        """``{marker id: (l, R)}`` for every marker found in ``image`` (RGB ``(H, W, 3)`` or
        grey ``(H, W)``, uint8): position ``l`` ``(3,)`` [m] and rotation ``R`` ``(3, 3)`` of
        the marker frame in the camera frame. A marker found twice is dropped (ambiguous)."""
        cv2 = self._cv2
        image = np.asarray(image)
        if image.dtype != np.uint8 or image.ndim not in (2, 3):
            raise ValueError(
                f"image must be uint8 (H, W) or (H, W, 3), got {image.dtype} {image.shape}"
            )
        gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
        corners, ids, _ = self._detector.detectMarkers(gray)
        if ids is None:
            return {}
        ids = ids.ravel().tolist()
        out: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
        for marker_id, c in zip(ids, corners, strict=True):
            if ids.count(marker_id) > 1:
                continue
            pose = self._solve(c.reshape(4, 2).astype(np.float64))
            if pose is not None:
                out[int(marker_id)] = pose
        return out

    def _solve(
        self, corners: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """Pose from the 4 corners: the IPPE square solution with the lower reprojection
        error; SQPnP when IPPE fails (it does on exactly fronto-parallel squares); None when
        the RMS reprojection error stays above ``max_reprojection_error``."""
        cv2 = self._cv2
        best = None
        for flag in (cv2.SOLVEPNP_IPPE_SQUARE, cv2.SOLVEPNP_SQPNP):
            n, rvecs, tvecs, errs = cv2.solvePnPGeneric(
                self._object_points, corners, self.K, None, flags=flag
            )
            for k in range(n):
                err = float(np.ravel(errs)[k])
                if best is None or err < best[0]:
                    best = (err, rvecs[k], tvecs[k])
            if best is not None and best[0] <= self.max_reprojection_error:
                break
        if best is None or best[0] > self.max_reprojection_error:
            return None
        R, _ = cv2.Rodrigues(best[1])
        return np.ravel(best[2]).astype(np.float64), R.astype(np.float64)
