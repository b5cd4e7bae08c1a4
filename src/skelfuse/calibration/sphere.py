"""Sensor-to-sensor calibration from a coloured sphere carried through the space (paper section 2.1.1).

Cycle, per sensor and frame (colour registered to depth, see ``skelfuse.fusion.camera``)::

    colour (BGR) --HSV--> calcBackProject(hue/saturation histogram of the ball) --threshold, open-->
      largest blob (eroded: edge pixels mix ball and background depth)
    depth pixels of the blob --intrinsics--> 3D points (sensor frame, mm)
    RANSAC sphere of KNOWN radius (3-point samples, vectorized) --> Gauss-Newton least squares on the inliers
      --> centre (3,), inliers, RMS radial residual           [detect_sphere_center]

then over all frames::

    centres per sensor (F, 3), NaN where not seen          [sphere_trajectories]
    frames every sensor saw --> rigid fit of each sensor's trajectory to the master's
      (skelfuse.calibration.rigid: Kabsch with the paper's errata fixed: T = mean_M - R mean_p, det +1)
      --> world_from_sensor = world_from_master @ master_from_sensor, residual = RMS of the fitted
      trajectory                                           [calibrate_from_sphere]

The paper's ball is red with a radius of 24 cm and its trajectories hold 1000 points. The world of a
sphere calibration is the master's frame (or ``world_from_master`` when given); the marker calibration
(``skelfuse.calibration.marker``) then puts it on the floor (``calfile.reanchor``).

Real Azure Kinect note: the colour camera is a separate camera; warp colour into the depth camera first
(``k4a_transformation_color_image_to_depth_camera``) so that a colour pixel and a depth pixel are the same ray.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from skelfuse.calibration.rigid import fit_rigid_ransac
from skelfuse.config.calibration_file import CalibrationResult, SensorCalibration, now_iso
from skelfuse.fusion.camera import Intrinsics, lift_mask
from skelfuse.schema.errors import CalibrationError, DataError

PAPER_RADIUS_MM = 240.0
"""The paper's red ball: "a sphere object with a radius of 24 cm"."""

HIST_SIZE = (30, 32)
"""Hue (0-180) and saturation (0-256) bins of the ball's histogram."""
_HIST_RANGES = [0, 180, 0, 256]


@dataclass(frozen=True)
class SphereDetection:
    """One frame's sphere: centre (3,) mm in the sensor frame, inliers used, RMS radial residual mm."""

    center: np.ndarray
    n_inliers: int
    residual_mm: float


# ----------------------------------------------------------------------------------------------------------
# Colour model
# ----------------------------------------------------------------------------------------------------------


def sphere_histogram(color_bgr: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Hue/saturation histogram of the ball, from a region of interest on it (the paper's model).

    Parameters
    ----------
    color_bgr : (H, W, 3) uint8 image showing the ball (or a crop of it).
    mask : (H, W) uint8/bool, optional: the ball's pixels (None: the whole image, e.g. a crop).

    Returns
    -------
    (30, 32) float32 histogram scaled to 0..255, for ``cv2.calcBackProject``.
    """
    hsv = cv2.cvtColor(np.ascontiguousarray(color_bgr, dtype=np.uint8), cv2.COLOR_BGR2HSV)
    m = None if mask is None else (np.asarray(mask) != 0).astype(np.uint8)
    hist = cv2.calcHist([hsv], [0, 1], m, list(HIST_SIZE), _HIST_RANGES)
    cv2.normalize(hist, hist, 0, 255, cv2.NORM_MINMAX)
    return hist


def red_histogram(*, hue_halfwidth: int = 10, min_saturation: int = 90, min_value: int = 40) -> np.ndarray:
    """A histogram of "saturated red" (hue within ``hue_halfwidth`` of 0/180 on OpenCV's 0-180 scale), for
    when no sample of the ball is at hand. A histogram from the real ball (:func:`sphere_histogram`) is
    tighter under the rig's light."""
    hue = np.concatenate([np.arange(0, hue_halfwidth + 1), np.arange(180 - hue_halfwidth, 180)])
    sat = np.arange(min_saturation, 256, 4)
    val = np.arange(min_value, 256, 16)
    h, s, v = np.meshgrid(hue, sat, val, indexing="ij")
    hsv = np.stack([h, s, v], axis=-1).reshape(1, -1, 3).astype(np.uint8)
    hist = cv2.calcHist([hsv], [0, 1], None, list(HIST_SIZE), _HIST_RANGES)
    cv2.normalize(hist, hist, 0, 255, cv2.NORM_MINMAX)
    return hist


def sphere_mask(color_bgr: np.ndarray, hist: np.ndarray, *, threshold: int = 60, erode_px: int = 2) -> np.ndarray:
    """(H, W) bool: the largest blob of pixels whose colour back-projects above ``threshold`` (0-255).

    The blob is opened (3x3) against speckle, then eroded by ``erode_px`` so the ball's silhouette pixels,
    whose depth mixes ball and background on a real sensor, are left out.
    """
    hsv = cv2.cvtColor(np.ascontiguousarray(color_bgr, dtype=np.uint8), cv2.COLOR_BGR2HSV)
    back = cv2.calcBackProject([hsv], [0, 1], hist, _HIST_RANGES, 1)
    binary: np.ndarray = (back > threshold).astype(np.uint8)
    kernel = np.ones((3, 3), np.uint8)
    binary = cv2.morphologyEx(binary, cv2.MORPH_OPEN, kernel)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
    if n <= 1:
        return np.zeros(binary.shape, bool)
    largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    blob = (labels == largest).astype(np.uint8)
    if erode_px > 0:
        blob = cv2.erode(blob, np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8))
    return blob.astype(bool)


# ----------------------------------------------------------------------------------------------------------
# Sphere of known radius
# ----------------------------------------------------------------------------------------------------------


def _centres_from_triples(p: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(K, 3, 3) point triples → (K, 3) centres of the sphere of ``radius`` through them, and (K,) ok.

    Two spheres of a given radius pass through three points, mirror images across their plane; the visible
    cap faces the camera, so the centre is the one farther from the camera origin (the sensor frame's 0).
    """
    a, b, c = p[:, 0], p[:, 1], p[:, 2]
    ab, ac = b - a, c - a
    n = np.cross(ab, ac)
    n2 = np.einsum("ki,ki->k", n, n)
    ok = n2 > 1e-6
    n2 = np.where(ok, n2, 1.0)
    # Circumcentre of the triangle: a + (|ac|^2 (n x ab) + |ab|^2 (ac x n)) / (2 |n|^2)
    circ = a + (
        np.einsum("ki,ki->k", ac, ac)[:, None] * np.cross(n, ab)
        + np.einsum("ki,ki->k", ab, ab)[:, None] * np.cross(ac, n)
    ) / (2 * n2[:, None])
    rho2 = np.einsum("ki,ki->k", circ - a, circ - a)
    h2 = radius**2 - rho2
    ok &= h2 >= 0
    unit_n = n / np.sqrt(n2)[:, None]
    h = np.sqrt(np.clip(h2, 0.0, None))[:, None]
    c1, c2 = circ + h * unit_n, circ - h * unit_n
    far = np.einsum("ki,ki->k", c1, c1) >= np.einsum("ki,ki->k", c2, c2)
    return np.where(far[:, None], c1, c2), ok


def _refine_center(points: np.ndarray, center: np.ndarray, radius: float, iterations: int = 10) -> np.ndarray:
    """Gauss-Newton on ``sum_i (|p_i - c| - r)^2`` over the centre c (radius fixed)."""
    c = center.astype(np.float64).copy()
    for _ in range(iterations):
        diff = points - c
        dist = np.linalg.norm(diff, axis=1)
        dist = np.where(dist > 1e-9, dist, 1e-9)
        resid = dist - radius
        J = -diff / dist[:, None]  # d resid / d c
        step, *_ = np.linalg.lstsq(J, -resid, rcond=None)
        c += step
        if np.linalg.norm(step) < 1e-4:
            break
    return c


def fit_sphere_known_radius(
    points: np.ndarray,
    radius_mm: float,
    *,
    rng: np.random.Generator,
    threshold_mm: float = 10.0,
    iterations: int = 128,
    max_points: int = 1000,
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """RANSAC fit of a sphere of known radius to a point cloud, refined by least squares on the inliers.

    Parameters
    ----------
    points : (N, 3) mm, sensor frame (the camera at the origin: the visible cap faces it).
    radius_mm : the ball's radius, mm.
    rng : seeded generator for the samples.
    threshold_mm : inlier band ``| |p - c| - r | < threshold_mm``.
    iterations : RANSAC samples (3 points each, all hypotheses scored at once).
    max_points : hypotheses are scored on a random subset of this many points (the refinement uses all).

    Returns
    -------
    (center (3,), inliers (N,) bool, rms radial residual of the inliers mm), or None with fewer than 4 points.
    """
    pts = np.asarray(points, dtype=np.float64)
    n = len(pts)
    if n < 4:
        return None
    triples = pts[rng.integers(0, n, size=(iterations, 3))]
    centres, ok = _centres_from_triples(triples, radius_mm)
    if not ok.any():
        return None
    centres = centres[ok]
    score_pts = pts if n <= max_points else pts[rng.choice(n, max_points, replace=False)]
    # |p - c|^2 = |p|^2 - 2 c.p + |c|^2: one (K, 3) @ (3, N) product instead of a (K, N, 3) difference.
    sq = (
        np.einsum("ni,ni->n", score_pts, score_pts)[None, :]
        - 2.0 * centres @ score_pts.T
        + np.einsum("ki,ki->k", centres, centres)[:, None]
    )
    resid = np.abs(np.sqrt(np.clip(sq, 0.0, None)) - radius_mm)
    # MSAC score: truncated residuals, so among hypotheses with equal support the tighter one wins.
    cost = np.minimum(resid, threshold_mm).sum(axis=1)
    center = centres[int(np.argmin(cost))]
    inliers = np.zeros(n, bool)
    for _ in range(3):  # refine, then let the inlier set follow the refined centre
        inliers = np.abs(np.linalg.norm(pts - center, axis=1) - radius_mm) < threshold_mm
        if inliers.sum() < 4:
            return None
        center = _refine_center(pts[inliers], center, radius_mm)
    resid_in = np.linalg.norm(pts[inliers] - center, axis=1) - radius_mm
    return center, inliers, float(np.sqrt(np.mean(resid_in**2)))


def detect_sphere_center(
    color_bgr: np.ndarray,
    depth_mm: np.ndarray,
    intrinsics: Intrinsics,
    radius_mm: float,
    hist: np.ndarray,
    *,
    rng: np.random.Generator | None = None,
    threshold_mm: float = 10.0,
    min_inliers: int = 100,
    min_inlier_ratio: float = 0.5,
    backproject_threshold: int = 60,
) -> tuple[np.ndarray, int, float] | None:
    """The ball's centre in one RGB-D frame (colour registered to depth), sensor frame, mm.

    Parameters
    ----------
    color_bgr : (H, W, 3) uint8.
    depth_mm : (H, W) uint16, mm, 0 = invalid.
    intrinsics : the depth camera's.
    radius_mm : the ball's radius (paper: 240 mm).
    hist : hue/saturation histogram of the ball (:func:`sphere_histogram` or :func:`red_histogram`).
    rng : for RANSAC (default: a fixed seed, so a frame always gives the same answer).
    threshold_mm : RANSAC inlier band on the radial residual, mm (about 3-4x the depth noise).
    min_inliers, min_inlier_ratio : fewer inliers, or a smaller share of the blob's points, → None (a blob
        that is not a ball of this radius: a red shirt, a poster).
    backproject_threshold : back-projection value (0-255) above which a pixel is "ball coloured".

    Returns
    -------
    (center (3,) float64 mm, n_inliers, rms radial residual mm), or None when no ball is found.
    """
    color = np.asarray(color_bgr)
    depth = np.asarray(depth_mm)
    if color.shape[:2] != depth.shape or color.ndim != 3:
        raise DataError(
            f"colour {color.shape} and depth {depth.shape} must be registered (same H x W); warp "
            "colour into the depth camera first (k4a transformation)"
        )
    mask = sphere_mask(color, hist, threshold=backproject_threshold)
    points = lift_mask(depth, mask, intrinsics)
    if len(points) < min_inliers:
        return None
    fit = fit_sphere_known_radius(
        points, radius_mm, rng=rng if rng is not None else np.random.default_rng(0), threshold_mm=threshold_mm
    )
    if fit is None:
        return None
    center, inliers, residual = fit
    n_in = int(inliers.sum())
    if n_in < min_inliers or n_in < min_inlier_ratio * len(points):
        return None
    return center, n_in, residual


# ----------------------------------------------------------------------------------------------------------
# Trajectories and the rig fit
# ----------------------------------------------------------------------------------------------------------


def _progress(label: str, done: int, total: int) -> None:
    if sys.stderr.isatty() or done == total:
        sys.stderr.write(f"\r{label}: {done}/{total}")
        if done == total:
            sys.stderr.write("\n")
        sys.stderr.flush()


def sphere_trajectories(
    frames_by_sensor: Mapping[str, Sequence[tuple[np.ndarray, np.ndarray]]],
    intrinsics_by_sensor: Mapping[str, Intrinsics],
    radius_mm: float,
    hist: np.ndarray,
    *,
    progress: bool = True,
    **detect_options: Any,
) -> dict[str, np.ndarray]:
    """The ball's centre in every frame of every sensor.

    Parameters
    ----------
    frames_by_sensor : sensor id -> sequence of F ``(color_bgr, depth_mm)`` pairs; frame i of every sensor
        is the same instant (hardware-synced captures grouped by device timestamp).
    intrinsics_by_sensor : sensor id -> Intrinsics of its depth camera.
    radius_mm, hist : as in :func:`detect_sphere_center`; ``detect_options`` go to it too.
    progress : write a progress line to stderr.

    Returns
    -------
    sensor id -> (F, 3) float64 centres, mm, sensor frame; NaN rows where the sensor did not find the ball.
    """
    lengths = {sid: len(frames) for sid, frames in frames_by_sensor.items()}
    if len(set(lengths.values())) > 1:
        raise DataError(f"every sensor needs the same number of synchronized frames, got {lengths}")
    missing = [sid for sid in frames_by_sensor if sid not in intrinsics_by_sensor]
    if missing:
        raise DataError(f"no intrinsics for sensor(s) {', '.join(missing)}")
    total = sum(lengths.values())
    done = 0
    out = {}
    for sensor_id, frames in frames_by_sensor.items():
        centres = np.full((len(frames), 3), np.nan)
        for i, (color, depth) in enumerate(frames):
            found = detect_sphere_center(
                color, depth, intrinsics_by_sensor[sensor_id], radius_mm, hist, **detect_options
            )
            if found is not None:
                centres[i] = found[0]
            done += 1
            if progress and (done % 10 == 0 or done == total):
                _progress("sphere detection (frames)", done, total)
        out[sensor_id] = centres
    return out


def calibrate_from_trajectories(
    centres_by_sensor: Mapping[str, np.ndarray],
    master: str,
    *,
    world_from_master: np.ndarray | None = None,
    threshold_mm: float = 30.0,
    min_points: int = 10,
    rng: np.random.Generator | None = None,
) -> CalibrationResult:
    """Rigid fit of every sensor's centre trajectory to the master's (the numeric core of the method).

    Parameters
    ----------
    centres_by_sensor : sensor id -> (F, 3) mm, NaN where unseen (as :func:`sphere_trajectories` returns).
    master : the reference sensor.
    world_from_master : (4, 4), default identity: the world is the master's frame until a marker
        calibration re-anchors it.
    threshold_mm : RANSAC inlier distance for the rigid fit: a wrong detection in one frame is dropped
        rather than pulling the fit.
    min_points : fewest common frames accepted.

    Returns
    -------
    CalibrationResult (method "sphere"): per sensor the pose, the RMS residual of its fitted trajectory in
    mm (master: 0 points, residual None), the number of frames used; ``points_by_sensor`` holds the common
    frames' centres (sensor frames).

    Raises
    ------
    CalibrationError
        Unknown master, too few frames where every sensor saw the ball, or a degenerate trajectory.
    """
    if master not in centres_by_sensor:
        raise CalibrationError(
            f"master sensor {master!r} has no sphere trajectory; sensors: {', '.join(centres_by_sensor)}"
        )
    ids = list(centres_by_sensor)
    stacked = np.stack([np.asarray(centres_by_sensor[sid], dtype=np.float64) for sid in ids])  # (S, F, 3)
    seen = np.asarray(np.isfinite(stacked).all(axis=2))  # (S, F)
    common = seen.all(axis=0)
    if common.sum() < min_points:
        per_sensor = ", ".join(f"{sid}: {int(seen[i].sum())}" for i, sid in enumerate(ids))
        raise CalibrationError(
            f"sphere calibration: only {int(common.sum())} of {stacked.shape[1]} frames show the ball to every "
            f"sensor, need at least {min_points} (frames with the ball found per sensor: {per_sensor}); carry the "
            "ball through the space every sensor sees, check the colour histogram and the radius"
        )
    rng = rng if rng is not None else np.random.default_rng(0)
    base = np.eye(4) if world_from_master is None else np.asarray(world_from_master, dtype=np.float64)
    master_pts = stacked[ids.index(master)][common]
    date = now_iso()
    sensors = {}
    for i, sensor_id in enumerate(ids):
        pts = stacked[i][common]
        if sensor_id == master:
            sensors[sensor_id] = SensorCalibration(base, "sphere", None, int(common.sum()), date, "master")
            continue
        # No trimming: the RANSAC threshold already drops wrong detections, and good centres are all worth keeping.
        fit = fit_rigid_ransac(
            pts, master_pts, threshold_mm=threshold_mm, rng=rng, min_inliers=min_points, trim_fraction=0.0
        )
        notes = f"fitted to master {master}"
        if fit.n < len(pts):
            notes += f"; {len(pts) - fit.n} of {len(pts)} frames rejected as outliers"
        sensors[sensor_id] = SensorCalibration(base @ fit.matrix, "sphere", fit.rms_mm, fit.n, date, notes)
    return CalibrationResult(
        sensors=sensors,
        method="sphere",
        master=master,
        date=date,
        notes=(
            "world = master frame (run the marker calibration to put it on the floor)"
            if world_from_master is None
            else ""
        ),
        points_by_sensor={sid: stacked[i][common] for i, sid in enumerate(ids)},
    )


def calibrate_from_sphere(
    frames_by_sensor: Mapping[str, Sequence[tuple[np.ndarray, np.ndarray]]],
    intrinsics_by_sensor: Mapping[str, Intrinsics],
    radius_mm: float,
    master: str,
    *,
    hist: np.ndarray | None = None,
    world_from_master: np.ndarray | None = None,
    threshold_mm: float = 30.0,
    min_points: int = 10,
    progress: bool = True,
    **detect_options: object,
) -> CalibrationResult:
    """The paper's sensor-to-sensor calibration from synchronized RGB-D frames of a carried ball.

    :func:`sphere_trajectories` then :func:`calibrate_from_trajectories` (see them for the parameters);
    ``hist`` defaults to :func:`red_histogram`.
    """
    centres = sphere_trajectories(
        frames_by_sensor,
        intrinsics_by_sensor,
        radius_mm,
        red_histogram() if hist is None else hist,
        progress=progress,
        **detect_options,
    )
    return calibrate_from_trajectories(
        centres, master, world_from_master=world_from_master, threshold_mm=threshold_mm, min_points=min_points
    )
