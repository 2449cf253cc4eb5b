r"""Rendered fiducial markers and their detection: the optional image path of MarkerCamera-v0.

Instead of perturbing the true marker poses with a noise model, the camera image is rendered
with MuJoCo (offscreen; ``MUJOCO_GL=egl`` or ``osmesa``) with an ArUco texture on every marker
and the poses are estimated from the image, as a real setup would (thesis section 2.2; the
thesis used AprilTags and a Kinect 2):

1. corners ``c_i`` (pixels) of every visible marker by OpenCV's ArUco detector (dictionary
   ``DICT_4X4_50``, sub-pixel corner refinement), then moved to the intersections of lines
   fitted to the sub-pixel edges of the four sides (:func:`refine_corners_by_edges`);
2. the pose ``(R, l)`` of the marker frame in the camera frame: the candidates of
   ``cv2.solvePnPGeneric`` with ``SOLVEPNP_IPPE_SQUARE`` (two planar solutions) and
   ``SOLVEPNP_SQPNP``, each scored by its own RMS reprojection error; the best wins. It is
   dropped above 2 px RMS, or when a rival of a clearly different rotation fits almost as
   well (the planar ambiguity; see :class:`ArucoMarkerDetector`). The objective:

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


def _edge_line(
    gray: NDArray[np.float32], a: NDArray[np.float64], b: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Line ``(point, direction)`` through the sub-pixel edge between the black border
    (inside) and the white quiet zone (outside) along the side ``a -> b`` of a clockwise
    quad: at 13 stations over the middle 60 % of the side, the intensity profile along
    the outward normal (``+-3`` px, bilinear) crosses the mid level of its own extremes;
    a least-squares line through the crossings. None with fewer than 6 crossings."""
    from scipy.ndimage import map_coordinates

    side = b - a
    length = float(np.hypot(*side))
    if length < 8.0:
        return None
    d = side / length
    normal = np.array([d[1], -d[0]])  # outward for a clockwise quad (image y down)
    stations = a + np.linspace(0.2, 0.8, 13)[:, None] * side
    offsets = np.arange(-3.0, 3.0001, 0.25)
    pts = stations[:, None, :] + offsets[None, :, None] * normal  # (13, S, 2) as (x, y)
    prof = map_coordinates(gray, [pts[..., 1].ravel(), pts[..., 0].ravel()], order=1)
    prof = prof.reshape(len(stations), len(offsets))
    found = []
    for i, p in enumerate(prof):
        lo, hi = p[: len(p) // 2].min(), p[len(p) // 2 :].max()
        if hi - lo < 20.0:  # no clear dark-to-bright edge (occluded, too blurred)
            continue
        mid = 0.5 * (lo + hi)
        above = np.nonzero(p >= mid)[0]
        k = int(above[0]) if len(above) else 0
        if k == 0 or p[k - 1] >= mid:
            continue
        t = (mid - p[k - 1]) / (p[k] - p[k - 1])  # linear interpolation of the crossing
        found.append(stations[i] + (offsets[k - 1] + t * 0.25) * normal)
    if len(found) < 6:
        return None
    e = np.array(found)
    centre = e.mean(0)
    _, _, vt = np.linalg.svd(e - centre)
    return centre, vt[0]


def refine_corners_by_edges(
    gray: NDArray, corners: NDArray[np.float64], max_shift: float = 1.5
) -> NDArray[np.float64]:
    """Corners ``(4, 2)`` (clockwise: ArUco's order) as intersections of lines fitted to the
    sub-pixel edges of the marker's sides (:func:`_edge_line`).

    Blur rounds a square's corners, and a corner detector then places them inside the
    square (the marker looks smaller, so farther away); a straight edge's mid-level
    crossing is unbiased under symmetric blur, so its line intersections are not. The
    input corners are returned unchanged if a side has too few edge points or a corner
    would move by more than ``max_shift`` px. ``gray``: ``(H, W)`` grey image (converted to
    float32 unless it already is).
    """
    g = np.asarray(gray, dtype=np.float32)
    lines = [_edge_line(g, corners[i], corners[(i + 1) % 4]) for i in range(4)]
    if any(line is None for line in lines):
        return corners
    out = np.empty_like(corners)
    for i in range(4):  # corner i joins side i-1 and side i
        (p1, d1), (p2, d2) = lines[i - 1], lines[i]
        A = np.column_stack([d1, -d2])
        if abs(np.linalg.det(A)) < 1e-6:
            return corners
        t = np.linalg.solve(A, p2 - p1)
        out[i] = p1 + t[0] * d1
    if np.abs(out - corners).max() > max_shift:
        return corners
    return out


class ArucoMarkerDetector:
    """Marker poses in the camera frame from one image (module docstring).

    Args:
        K: ``(3, 3)`` camera intrinsics (:func:`camera_matrix`).
        marker_length: side ``L`` of the black square [m].
        min_perimeter_rate: the detector's smallest marker perimeter over the image's largest
            side (OpenCV's ``minMarkerPerimeterRate``; smaller finds smaller markers).
        max_reprojection_error: RMS corner reprojection error [px] above which a detection
            is dropped (a failed pose solution).
        min_ambiguity_ratio, ambiguity_angle: drop a detection when the best candidate pose
            whose rotation differs from the chosen one by more than ``ambiguity_angle``
            [rad] reprojects less than ``min_ambiguity_ratio`` times worse (the planar pose
            ambiguity of small, distant markers; near face-on the two IPPE solutions are
            close and both harmless). ``min_ambiguity_ratio = 0`` keeps all. The default 3
            trades detections kept against gross errors (3-D error > 0.1 m or angle
            > 0.3 rad) on the UR10 trajectory of ``mcpilco-bench-markers``
            (``results/marker_detection.md``).
        edge_refinement: move the corners to the intersections of lines fitted to the
            sides' sub-pixel edges (:func:`refine_corners_by_edges`).
    """

    def __init__(
        self,
        K: NDArray[np.float64],
        marker_length: float,
        min_perimeter_rate: float = 0.01,
        max_reprojection_error: float = 2.0,
        min_ambiguity_ratio: float = 3.0,
        ambiguity_angle: float = 0.3,
        edge_refinement: bool = True,
    ) -> None:
        cv2 = require_cv2()
        if not marker_length > 0:
            raise ValueError(f"marker_length must be > 0, got {marker_length}")
        self._cv2 = cv2
        self.K = np.asarray(K, dtype=np.float64)
        self.marker_length = float(marker_length)
        self.max_reprojection_error = float(max_reprojection_error)
        self.min_ambiguity_ratio = float(min_ambiguity_ratio)
        self.ambiguity_angle = float(ambiguity_angle)
        self.edge_refinement = bool(edge_refinement)
        self.last_ambiguity = (math.inf, 0.0)
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
        gray_f = gray.astype(np.float32) if self.edge_refinement else None  # once per image
        ids = ids.ravel().tolist()
        out: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
        for marker_id, c in zip(ids, corners, strict=True):
            if ids.count(marker_id) > 1:
                continue
            quad = c.reshape(4, 2).astype(np.float64)
            if self.edge_refinement:
                quad = refine_corners_by_edges(gray_f, quad)
            pose = self._solve(quad)
            if pose is not None:
                out[int(marker_id)] = pose
        return out

    def _reprojection_rms(self, rvec: NDArray, tvec: NDArray, corners: NDArray) -> float:
        """RMS distance [px] between ``corners`` and the projected square at ``(rvec, tvec)``."""
        proj, _ = self._cv2.projectPoints(self._object_points, rvec, tvec, self.K, None)
        return float(np.sqrt(((proj.reshape(4, 2) - corners) ** 2).sum(1).mean()))

    def _solve(
        self, corners: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """Pose from the 4 corners (module docstring): candidates are IPPE's two planar
        solutions and SQPnP's; each is scored by its own RMS reprojection error (the errors
        that ``solvePnPGeneric`` reports for IPPE do not always belong to its solutions).
        The best wins; None when its error exceeds ``max_reprojection_error``, or when the
        best candidate whose rotation differs by more than ``ambiguity_angle`` fits less
        than ``min_ambiguity_ratio`` times worse (ambiguous)."""
        cv2 = self._cv2
        cands = []
        for flag in (cv2.SOLVEPNP_IPPE_SQUARE, cv2.SOLVEPNP_SQPNP):
            n, rvecs, tvecs, _ = cv2.solvePnPGeneric(
                self._object_points, corners, self.K, None, flags=flag
            )
            for k in range(n):
                if np.all(np.isfinite(rvecs[k])) and float(np.ravel(tvecs[k])[2]) > 0:
                    err = self._reprojection_rms(rvecs[k], tvecs[k], corners)
                    cands.append((err, cv2.Rodrigues(rvecs[k])[0], np.ravel(tvecs[k])))
        if not cands:
            return None
        cands.sort(key=lambda c: c[0])
        err, R, l = cands[0]
        if err > self.max_reprojection_error:
            return None
        ratio, spread = math.inf, 0.0
        for err_b, R_b, _ in cands[1:]:  # the best rival that is a different rotation
            cos = (np.trace(R.T @ R_b) - 1.0) / 2.0
            angle = float(np.arccos(np.clip(cos, -1.0, 1.0)))
            if angle > self.ambiguity_angle:
                ratio, spread = err_b / max(err, 1e-3), angle
                break
        self.last_ambiguity = (ratio, spread)
        if ratio < self.min_ambiguity_ratio:
            return None
        return l.astype(np.float64), R.astype(np.float64)
