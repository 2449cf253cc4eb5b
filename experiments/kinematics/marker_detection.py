r"""Marker poses from rendered images + ArUco detection, against the truth.

The UR10 of ``mcpilco/MarkerCamera-v0`` with ``measurement="aruco"`` follows a trajectory
through 25 random waypoints (``UR10_HOME + U(-span, span)`` per joint, as part (b) of the
kinematics benchmark, :mod:`mcpilco.experiments.kinematics.trajectories`); every frame is
rendered by MuJoCo and the marker poses are estimated by OpenCV
(:mod:`mcpilco.envs.marker_detection`). The time offset is set to 0, so the truth is MuJoCo's
marker pose at the rendered configuration.

Per marker and over all markers (:func:`run`): the detection rate, the position error per
camera axis (RMSE, and the mean ``z`` error = depth bias) [mm], the median 3-D position error
[mm], the geodesic orientation error (median and RMS) [rad], and the share of gross errors
(3-D error > :data:`GROSS_POSITION` or geodesic > :data:`GROSS_ANGLE`: the planar pose
ambiguity, partly hidden markers). Next to them, the env's noise model
(``measurement="ideal"``) at the same frames: its per-axis position std ``position_noise f``
and geodesic RMS ``sqrt(3) angle_noise f``.

:func:`write_outputs` writes ``marker_detection.json``, ``marker_detection.md``,
``marker_detection.png`` (errors against the camera distance, detection rate against the
facing angle) and ``marker_detection_frame.png`` (the frame with the most detections:
estimated marker axes and true centres). Needs OpenCV (``pip install 'mcpilco[vision]'``) and
offscreen OpenGL (``MUJOCO_GL=egl`` or ``osmesa``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.envs.marker_camera import MarkerCameraEnv, ypr_to_matrix
from mcpilco.envs.marker_detection import camera_matrix
from mcpilco.experiments.kinematics.trajectories import ur10_waypoints, waypoint_trajectory
from mcpilco.experiments.results import Headline, Result, ResultLayout, percent, write_result

__all__ = [
    "FACING_BINS",
    "GROSS_ANGLE",
    "GROSS_POSITION",
    "MIN_FRAMES",
    "MarkerBenchSettings",
    "collect",
    "detection_by_facing_angle",
    "error_stats",
    "geodesic",
    "markdown",
    "plot",
    "run",
    "write_outputs",
]

# fewest frames of a run: one per segment between the 25 waypoints
MIN_FRAMES = 24


@dataclass(frozen=True)
class MarkerBenchSettings:
    """Options of a run (the command-line defaults): ``frames`` of the trajectory, ``seed``,
    waypoints ``home +- span`` [rad], ``marker_size`` (face side [m]), ``image_size``
    ``(W, H)`` [px], vertical field of view ``fovy`` [deg], image noise ``pixel_noise`` std
    [grey levels], marker ``facing_cone`` [deg]."""

    frames: int = 300
    seed: int = 0
    span: float = 1.0
    marker_size: float = 0.12
    image_size: tuple[int, int] = (1920, 1080)
    fovy: float = 54.0
    pixel_noise: float = 2.0
    facing_cone: float = 40.0

    def __post_init__(self) -> None:
        if self.frames < MIN_FRAMES:
            raise ValueError(f"frames must be >= {MIN_FRAMES} (one per waypoint segment)")


# 3-D position error [m] above which a detection counts as gross
GROSS_POSITION = 0.1
# geodesic error [rad] above which a detection counts as gross
GROSS_ANGLE = 0.3


def geodesic(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Angle [rad] of ``R(pred)^T R(true)`` for yaw-pitch-roll rows ``(..., 3)``."""
    R_err = np.swapaxes(ypr_to_matrix(pred), -1, -2) @ ypr_to_matrix(true)
    return np.arccos(np.clip((np.trace(R_err, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0))


def collect(
    env: MarkerCameraEnv, seed: int, frames: int, span: float, progress: bool
) -> dict[str, np.ndarray]:
    """Drive ``env`` through the 25 random waypoints of
    :func:`~mcpilco.experiments.kinematics.trajectories.ur10_waypoints` in about ``frames`` frames;
    returns the measured and true poses ``(T, n + 1, 6)`` (chain order), the detection mask
    and the configurations ``(T, n)``."""
    waypoints = ur10_waypoints(np.random.default_rng([seed, 1]), span)
    obs, _ = env.reset(seed=seed, options={"q": waypoints[0]})
    poses, _, q = waypoint_trajectory(env, obs, waypoints, frames, progress)
    measured = poses[:, np.argsort(env.marker_permutation)]  # chain order
    true = np.array([env.marker_poses(qq) for qq in q])  # time_offset = 0: what was imaged
    return dict(measured=measured, true=true, q=q, detected=~np.isnan(measured[..., 0]))


def error_stats(measured: np.ndarray, true: np.ndarray) -> dict[str, Any]:
    """Statistics of the detected poses ``(k, 6)`` against the truth (module docstring)."""
    if len(measured) == 0:
        return dict(detections=0)
    err = measured[:, :3] - true[:, :3]
    norm = np.linalg.norm(err, axis=1)
    ang = geodesic(measured[:, 3:], true[:, 3:])
    gross = (norm > GROSS_POSITION) | (ang > GROSS_ANGLE)
    good = ~gross
    return dict(
        detections=int(len(measured)),
        position_rmse_per_axis_mm=(1e3 * np.sqrt((err**2).mean(0))).tolist(),
        position_rmse_per_axis_mm_without_gross=(1e3 * np.sqrt((err[good] ** 2).mean(0))).tolist()
        if good.any()
        else None,
        depth_bias_mm=float(1e3 * err[:, 2].mean()),
        position_median_3d_mm=float(1e3 * np.median(norm)),
        geodesic_median=float(np.median(ang)),
        geodesic_rms=float(np.sqrt((ang**2).mean())),
        geodesic_rms_without_gross=float(np.sqrt((ang[good] ** 2).mean())) if good.any() else None,
        gross_fraction=float(gross.mean()),
    )


# edges [deg] of the facing-angle bins of detection_by_facing_angle
FACING_BINS = (0.0, 20.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0, 180.0)


def detection_by_facing_angle(facing_deg: np.ndarray, detected: np.ndarray) -> list[dict]:
    """Detection rate of the marker views per bin of the facing angle ``phi`` (between the
    marker normal and its line of sight to the camera, ``MarkerCameraEnv.facing_cosines``;
    > 90 deg: turned away). Misses include views hidden by other links."""
    rows = []
    for lo, hi in zip(FACING_BINS[:-1], FACING_BINS[1:], strict=True):
        inside = (facing_deg >= lo) & (facing_deg < hi)
        views = int(inside.sum())
        rate = float(detected[inside].mean()) if views else None
        rows.append(dict(lo_deg=lo, hi_deg=hi, views=views, detection_rate=rate))
    return rows


def run(settings: MarkerBenchSettings, progress: bool = True) -> dict[str, Any]:
    """Render and detect the markers along the trajectory; the statistics of the module
    docstring, with the annotated frame under ``"_frame"`` and the arrays of :func:`collect`
    under ``"_arrays"`` (both left out of the JSON by :func:`write_outputs`)."""
    env = MarkerCameraEnv(
        measurement="aruco",
        max_increment=0.2,
        time_offset=0.0,
        marker_size=settings.marker_size,
        image_size=tuple(settings.image_size),
        fovy=settings.fovy,
        pixel_noise=settings.pixel_noise,
        marker_facing_cone=settings.facing_cone,
    )
    t0 = time.perf_counter()
    data = collect(env, settings.seed, settings.frames, settings.span, progress)
    seconds = time.perf_counter() - t0
    det, meas, true = data["detected"], data["measured"], data["true"]
    # the env's noise model at the same configurations and frames
    pos_std, ang_std = zip(*(env.measurement_noise_std(q) for q in data["q"]), strict=True)
    pos_std, ang_std = np.array(pos_std), np.array(ang_std)
    per_marker = []
    for j in range(env.n_markers):
        d = det[:, j]
        row = dict(marker=j, detection_rate=float(d.mean()), **error_stats(meas[d, j], true[d, j]))
        if d.any():
            row["ideal_position_std_mm"] = float(1e3 * np.sqrt((pos_std[d, j] ** 2).mean()))
            row["ideal_geodesic_rms"] = float(np.sqrt(3 * (ang_std[d, j] ** 2).mean()))
            row["distance_mean_m"] = float(np.linalg.norm(true[d, j, :3], axis=1).mean())
        per_marker.append(row)
    overall = dict(
        detection_rate=float(det.mean()),
        **error_stats(meas[det], true[det]),
        ideal_position_std_mm=float(1e3 * np.sqrt((pos_std[det] ** 2).mean())),
        ideal_geodesic_rms=float(np.sqrt(3 * (ang_std[det] ** 2).mean())),
    )
    facing = np.degrees(np.arccos(np.clip([env.facing_cosines(q) for q in data["q"]], -1, 1)))
    frame = annotated_frame(env, data)
    env.close()
    return dict(
        _frame=frame,
        config=dict(
            frames=int(det.shape[0]),
            seed=settings.seed,
            span=settings.span,
            marker_size=settings.marker_size,
            image_size=list(settings.image_size),
            fovy=settings.fovy,
            pixel_noise=settings.pixel_noise,
            facing_cone=env.marker_facing_cone,
        ),  # fmt: skip
        seconds=seconds,
        seconds_per_frame=seconds / det.shape[0],
        overall=overall,
        per_marker=per_marker,
        by_facing_angle=detection_by_facing_angle(facing, det),
        _arrays=data,
    )


def annotated_frame(env: MarkerCameraEnv, data: dict[str, np.ndarray]) -> np.ndarray:
    """The frame with the most detections, cropped around the markers: the estimated marker
    frames drawn as axes (x red, y green, z blue; 5 cm) and the true marker centres as
    white circles, with the chain index. RGB ``(h, w, 3)``."""
    import cv2

    t = int(data["detected"].sum(1).argmax())
    img = np.ascontiguousarray(env.camera_image(data["q"][t])[:, :, ::-1])  # BGR for cv2
    K = camera_matrix(*env.image_size, env.fovy)
    uv = []
    for j in range(env.n_markers):
        l_true = data["true"][t, j, :3]
        p = K @ l_true
        c = (int(round(p[0] / p[2])), int(round(p[1] / p[2])))
        uv.append(c)
        cv2.circle(img, c, 6, (255, 255, 255), 2)
        cv2.putText(img, str(j), (c[0] + 8, c[1] - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.8,
                    (0, 255, 255), 2)  # fmt: skip
        if data["detected"][t, j]:
            m = data["measured"][t, j]
            rvec, _ = cv2.Rodrigues(ypr_to_matrix(m[3:]))
            cv2.drawFrameAxes(img, K, None, rvec, m[:3].reshape(3, 1), 0.05, 2)
    uv = np.array(uv)
    lo = np.maximum(uv.min(0) - 120, 0)
    hi = np.minimum(uv.max(0) + 120, [img.shape[1], img.shape[0]])
    return img[lo[1] : hi[1], lo[0] : hi[0], ::-1]


def plot(res: dict[str, Any], path: Path) -> None:
    """Errors against the camera distance and detection rate against the facing angle."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = res["_arrays"]
    det, meas, true = data["detected"], data["measured"], data["true"]
    dist = np.linalg.norm(true[..., :3], axis=-1)
    err = np.linalg.norm(meas[..., :3] - true[..., :3], axis=-1)
    ang = np.full(det.shape, np.nan)
    ang[det] = geodesic(meas[det][:, 3:], true[det][:, 3:])
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.2))
    for j in range(det.shape[1]):
        d = det[:, j]
        if d.any():
            axes[0].scatter(dist[d, j], 1e3 * err[d, j], s=6, label=f"marker {j}")
            axes[1].scatter(dist[d, j], ang[d, j], s=6)
    ideal = res["overall"]
    axes[0].axhline(np.sqrt(3) * ideal["ideal_position_std_mm"], color="k", ls="--",
                    label="noise model, 3-D RMS")  # fmt: skip
    axes[1].axhline(ideal["ideal_geodesic_rms"], color="k", ls="--", label="noise model RMS")
    axes[0].set(xlabel="camera distance [m]", ylabel="3-D position error [mm]", yscale="log",
                title="rendered ArUco detection: position")  # fmt: skip
    axes[1].set(xlabel="camera distance [m]", ylabel="geodesic error [rad]", yscale="log",
                title="orientation")  # fmt: skip
    axes[0].legend(fontsize=7, markerscale=2)
    axes[1].legend(fontsize=7)
    bins = res["by_facing_angle"]
    labels = [f"{b['lo_deg']:.0f}-{b['hi_deg']:.0f}" for b in bins]
    rates = [100 * (b["detection_rate"] or 0.0) for b in bins]
    axes[2].bar(labels, rates, color="tab:blue")
    for i, b in enumerate(bins):
        axes[2].text(i, rates[i] + 1, f"n={b['views']}", ha="center", fontsize=7)
    axes[2].set(xlabel="facing angle: marker normal to line of sight [deg]",
                ylabel="marker views detected [%]", ylim=(0, 100),
                title="detection rate (misses include occlusion)")  # fmt: skip
    axes[2].tick_params(axis="x", labelsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def markdown(res: dict[str, Any], command: str) -> str:
    """The Markdown report of :func:`run`'s result."""
    c = res["config"]
    lines = [
        "# Rendered markers: ArUco detection against the truth (MarkerCamera-v0, UR10)",
        "",
        f"Command: `{command}`; {c['frames']} frames, seed {c['seed']}, waypoints home +- "
        f"{c['span']} rad, marker face {c['marker_size']} m, {c['image_size'][0]}x"
        f"{c['image_size'][1]} px, fovy {c['fovy']} deg, pixel noise {c['pixel_noise']}, "
        f"facing cone {c['facing_cone']} deg; {res['seconds_per_frame']:.3f} s per frame "
        "(render + detect).",
        "",
        "| marker | detected | RMSE x / y / z [mm] | depth bias [mm] | median 3-D [mm] | "
        "geodesic median / RMS [rad] | gross | noise model std / axis [mm] | noise model "
        "geodesic RMS [rad] |",
        "|---|---:|---|---:|---:|---|---:|---:|---:|",
    ]
    for row in [*res["per_marker"], dict(marker="all", **res["overall"])]:
        if not row.get("detections"):
            lines.append(f"| {row['marker']} | {100 * row['detection_rate']:.0f} % | - | - | - "
                         "| - | - | - | - |")  # fmt: skip
            continue
        rm = row["position_rmse_per_axis_mm"]
        lines.append(
            f"| {row['marker']} | {100 * row['detection_rate']:.0f} % | "
            f"{rm[0]:.1f} / {rm[1]:.1f} / {rm[2]:.1f} | {row['depth_bias_mm']:.1f} | "
            f"{row['position_median_3d_mm']:.1f} | {row['geodesic_median']:.3f} / "
            f"{row['geodesic_rms']:.3f} | {100 * row['gross_fraction']:.1f} % | "
            f"{row['ideal_position_std_mm']:.1f} | {row['ideal_geodesic_rms']:.3f} |"
        )
    o = res["overall"]
    if o.get("position_rmse_per_axis_mm_without_gross"):
        rm = o["position_rmse_per_axis_mm_without_gross"]
        lines += [
            "",
            f"Without the gross errors: RMSE {rm[0]:.1f} / {rm[1]:.1f} / {rm[2]:.1f} mm "
            f"(x / y / z), geodesic RMS {o['geodesic_rms_without_gross']:.3f} rad.",
        ]
    lines += [
        "",
        "Detection rate against the facing angle (marker normal to its line of sight to the "
        "camera; misses include markers hidden by other links):",
        "",
        "| facing angle [deg] | views | detected |",
        "|---|---:|---:|",
    ]
    for b in res["by_facing_angle"]:
        rate = "-" if b["detection_rate"] is None else f"{100 * b['detection_rate']:.0f} %"
        lines.append(f"| {b['lo_deg']:.0f}-{b['hi_deg']:.0f} | {b['views']} | {rate} |")
    lines += [
        "",
        f"Gross = 3-D error > {GROSS_POSITION} m or geodesic > {GROSS_ANGLE} rad. The camera "
        "z axis is the depth. Plots: `marker_detection.png` (errors against the distance, "
        "detection rate against the facing angle), `marker_detection_frame.png` (a frame with "
        "the estimated marker axes).",
    ]
    return "\n".join(lines) + "\n"


def write_outputs(res: dict[str, Any], out_dir: str | Path, command: str) -> str:
    """Write the JSON, Markdown and the two PNG files of :func:`run`'s result ``res`` under
    ``out_dir`` (the private entries ``_frame`` and ``_arrays`` are removed from ``res``);
    returns the Markdown report."""
    import cv2

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    plot(res, out / "marker_detection.png")
    cv2.imwrite(str(out / "marker_detection_frame.png"), res.pop("_frame")[:, :, ::-1])
    text = markdown(res, command)
    res.pop("_arrays")
    res["command"] = command
    write_result(out / "marker_detection.json", RESULT_LAYOUTS[0], res)
    (out / "marker_detection.md").write_text(text)
    return text


# -- result file and headline rows of the results index -----------------------------------

RESULT_LAYOUTS = (
    ResultLayout("marker_detection", config=("config",), cases=("per_marker", "by_facing_angle")),
)
"""The layout of ``marker_detection.json`` (:mod:`mcpilco.experiments.results`)."""


def _markers_row(r: Result) -> str:
    o = r["overall"]
    xyz = " / ".join(f"{x:.1f}" for x in o["position_rmse_per_axis_mm_without_gross"])
    return (
        f"rendered ArUco markers: {percent(o['detection_rate'])} detected, {xyz} mm and "
        f"{o['geodesic_rms_without_gross']:.3f} rad without gross errors "
        f"({percent(o['gross_fraction'])} gross)"
    )


HEADLINES = (
    Headline(
        "Kinematics: rendered markers",
        "marker_detection.json",
        _markers_row,
        "marker_detection.md",
        seeds=lambda r: f"seed {r['config']['seed']}",
    ),
)
"""The marker detection benchmark's row of the results index."""
