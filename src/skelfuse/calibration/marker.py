"""Sensor-to-world calibration from a plate of four ArUco markers on the floor (paper section 2.1.2).

Cycle (one RGB-D frame of the master, colour registered to depth, see ``skelfuse.fusion.camera``)::

    cv2.aruco.ArucoDetector on the colour image --> corners of markers 0..3 (missing one: CalibrationError
      naming the ids seen, the ids expected and the dictionary)
    centre of each marker in 3D from depth                                   [detect_plate_markers]
      "plane" (default): least-squares plane through the marker's depth pixels, intersected with the ray
        through the image of its centre (the crossing of the quad's diagonals: perspective maps the centre
        of a square there exactly). Unbiased by perspective and by the depth noise at the quad's border.
      "mean" (the paper's): centroid of the marker's depth pixels lifted to 3D. Pixels sample the near
        half of a tilted marker more densely than the far half, so it is biased by a few mm.
      cross-check, when the marker size is known: solvePnP(SOLVEPNP_IPPE_SQUARE) on the four corners
        (colour only), its translation is the centre; the distance to the depth centre is reported.
    axes: x from marker 2 to marker 1, y from marker 0 to marker 1, z = x × y (floor to ceiling), origin
      at marker 1; orthonormalized                                          [world_from_marker_centres]
    world_from_master = inverse of [x y z | origin]; every other sensor follows through its pose relative
      to the master (calfile.reanchor)                                      [calibrate_world_from_marker]

Orthonormalization: the measured x and y are never exactly perpendicular. Gram-Schmidt keeping x would
trust marker 2 more than marker 0; here the rotation is the nearest one (SVD, polar decomposition) to
[x̂, ŷ, x̂ × ŷ / |x̂ × ŷ|], which splits the disagreement evenly between x and y. The origin stays at
marker 1. ``residual_mm`` says how well the measured centres fit a rectangular plate in that frame.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from skelfuse.config.calibration_file import CalibrationResult, SensorCalibration, now_iso, reanchor
from skelfuse.fusion.camera import Intrinsics, lift_mask
from skelfuse.fusion.transform import invert_transform, make_transform
from skelfuse.schema.errors import CalibrationError, DataError

PLATE_IDS: tuple[int, int, int, int] = (0, 1, 2, 3)
"""ArUco ids playing the paper's markers 0, 1, 2, 3 (1: origin; 2 → 1: x axis; 0 → 1: y axis; 3: check)."""
DEFAULT_DICTIONARY = "DICT_4X4_50"
CENTRE_METHODS = ("plane", "mean")


@dataclass(frozen=True)
class MarkerObservation:
    """One detected marker of the plate.

    Attributes
    ----------
    marker_id : int
    corners : (4, 2) float64 pixel corners in ArUco order (top-left, top-right, bottom-right, bottom-left
        of the printed marker).
    center : (3,) float64, mm, sensor frame: from depth (see the module docstring).
    n_pixels : int, valid depth pixels used.
    center_pnp : (3,) float64 or None: solvePnP (IPPE_SQUARE) centre, when the marker size is known.
    """

    marker_id: int
    corners: np.ndarray
    center: np.ndarray
    n_pixels: int
    center_pnp: np.ndarray | None = None

    @property
    def pnp_discrepancy_mm(self) -> float | None:
        """Distance between the depth centre and the PnP centre, mm (None without PnP)."""
        return None if self.center_pnp is None else float(np.linalg.norm(self.center - self.center_pnp))


def aruco_dictionary(name: str) -> cv2.aruco.Dictionary:
    """``cv2.aruco`` predefined dictionary by name ("DICT_4X4_50", ...); CalibrationError if unknown."""
    value = getattr(cv2.aruco, name, None)
    if not name.startswith("DICT_") or not isinstance(value, int):
        known = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
        raise CalibrationError(f"unknown ArUco dictionary {name!r}; OpenCV knows: {', '.join(known)}")
    return cv2.aruco.getPredefinedDictionary(value)


def _diagonal_crossing(corners: np.ndarray) -> np.ndarray:
    """Intersection of the quad's diagonals (0-2 and 1-3): the image of the square's centre."""
    p0, p1, p2, p3 = (np.append(c, 1.0) for c in corners)
    point = np.cross(np.cross(p0, p2), np.cross(p1, p3))
    if abs(point[2]) < 1e-12:
        return corners.mean(axis=0)
    return point[:2] / point[2]


def _marker_center_from_depth(
    corners: np.ndarray, depth: np.ndarray, intrinsics: Intrinsics, method: str, erode_px: int
) -> tuple[np.ndarray, int]:
    mask: np.ndarray = np.zeros(depth.shape, np.uint8)
    cv2.fillConvexPoly(mask, np.rint(corners).astype(np.int32), 1)
    if erode_px > 0:
        mask = cv2.erode(mask, np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8))
    points = lift_mask(depth, mask, intrinsics)
    if len(points) < 10:
        return np.full(3, np.nan), len(points)
    if method == "mean":
        return points.mean(axis=0), len(points)
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    normal = vt[2]
    u, v = _diagonal_crossing(corners)
    ray = np.array([(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy, 1.0])
    denom = ray @ normal
    if abs(denom) < 1e-9:  # the plate seen edge-on
        return centroid, len(points)
    return ray * (centroid @ normal) / denom, len(points)


def detect_plate_markers(
    color_bgr: np.ndarray,
    depth_mm: np.ndarray,
    intrinsics: Intrinsics,
    *,
    ids: Sequence[int] = PLATE_IDS,
    dictionary: str = DEFAULT_DICTIONARY,
    marker_mm: float | None = None,
    centre_method: str = "plane",
    erode_px: int = 1,
) -> dict[int, MarkerObservation]:
    """Find the plate's markers in one master frame and measure their 3D centres (sensor frame, mm).

    Parameters
    ----------
    color_bgr : (H, W, 3) uint8, registered to depth.
    depth_mm : (H, W) uint16 mm, 0 = invalid.
    intrinsics : the depth camera's (colour registered to it).
    ids : the ArUco ids playing the paper's markers 0, 1, 2, 3 (the fourth may be missing).
    dictionary : cv2.aruco predefined dictionary name.
    marker_mm : printed marker side (black border included), mm; enables the solvePnP cross-check.
    centre_method : "plane" (default) or "mean" (the paper's centroid); see the module docstring.
    erode_px : pixels trimmed off the quad before reading depth (border pixels mix marker and floor).

    Returns
    -------
    ArUco id -> MarkerObservation, for the plate's ids that were found.

    Raises
    ------
    CalibrationError
        One of the three markers that define the axes (paper 0, 1, 2) was not detected, was detected twice,
        or has too few valid depth pixels. The message lists the ids seen, the ids expected and the dictionary.
    """
    if centre_method not in CENTRE_METHODS:
        raise ValueError(f"centre_method must be one of {CENTRE_METHODS}, got {centre_method!r}")
    if len(ids) != 4 or len(set(ids)) != 4:
        raise ValueError(f"ids must be 4 distinct ArUco ids (the paper's markers 0..3), got {tuple(ids)}")
    color = np.ascontiguousarray(color_bgr, dtype=np.uint8)
    depth = np.asarray(depth_mm)
    if color.shape[:2] != depth.shape:
        raise DataError(
            f"colour {color.shape} and depth {depth.shape} must be registered (same H x W); warp "
            "colour into the depth camera first (k4a transformation)"
        )
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), params)
    corners_list, found_ids, rejected = detector.detectMarkers(color)
    seen = [] if found_ids is None else [int(i) for i in np.asarray(found_ids).reshape(-1)]
    context = (
        f"expected ArUco ids {list(ids)} (paper markers 0-3) from {dictionary}, detected "
        f"{sorted(seen) if seen else 'none'} ({len(rejected)} rejected candidate squares)"
    )
    required = ids[:3]
    _check_detected(seen, ids, required, context, dictionary)
    object_points = None if marker_mm is None else _square_corners(marker_mm)
    out = {}
    for corners, marker_id in zip(corners_list, seen, strict=True):
        if marker_id not in ids:
            continue
        quad = np.asarray(corners, dtype=np.float64).reshape(4, 2)
        center, n_pixels = _marker_center_from_depth(quad, depth, intrinsics, centre_method, erode_px)
        if not np.isfinite(center).all():
            if marker_id in required:
                raise CalibrationError(
                    f"marker calibration: marker {marker_id} has only {n_pixels} valid depth pixels; {context}. "
                    "Check the depth range (0.5-3.86 m in NFOV) and that colour is registered to depth"
                )
            continue
        center_pnp = None
        if object_points is not None:
            ok, _, tvec = cv2.solvePnP(object_points, quad, intrinsics.matrix(), None, flags=cv2.SOLVEPNP_IPPE_SQUARE)
            center_pnp = np.asarray(tvec, dtype=np.float64).reshape(3) if ok else None
        out[marker_id] = MarkerObservation(marker_id, quad, center, n_pixels, center_pnp)
    return out


def _check_detected(
    seen: list[int], ids: Sequence[int], required: Sequence[int], context: str, dictionary: str
) -> None:
    """Refuse a detection that misses an axis-defining marker or sees one of the plate's ids twice."""
    missing = [i for i in required if i not in seen]
    if missing:
        raise CalibrationError(
            f"marker calibration: marker id(s) {missing} not found; {context}. Check that the whole plate is "
            f"in the master's colour view, evenly lit, not mirrored, and printed from {dictionary}"
        )
    duplicated = sorted({i for i in seen if i in ids and seen.count(i) > 1})
    if duplicated:
        raise CalibrationError(
            f"marker calibration: id(s) {duplicated} detected more than once; {context}. "
            "Remove other plates or printed markers from the view"
        )


def _square_corners(marker_mm: float) -> np.ndarray:
    """A marker's corners in its own frame, mm, in ArUco's order (top-left, top-right, bottom-right, bottom-left)."""
    half = marker_mm / 2
    return np.array([[-half, half, 0], [half, half, 0], [half, -half, 0], [-half, -half, 0]], dtype=np.float64)


def world_from_marker_centres(
    centres: Mapping[int, np.ndarray], ids: Sequence[int] = PLATE_IDS
) -> tuple[np.ndarray, float]:
    """The paper's world frame from the 3D centres of the plate's markers (sensor frame, mm).

    x: marker 2 → marker 1; y: marker 0 → marker 1; z = x × y; origin: marker 1; orthonormalized by SVD
    (see the module docstring).

    Returns
    -------
    world_from_sensor : (4, 4), mm.
    residual_mm : RMS distance of the measured centres (0, 2, and 3 when present) from a rectangular plate in
        the fitted frame (marker 0 at (0, -|y|), 2 at (-|x|, 0), 3 at (-|x|, -|y|)): a few mm when the
        centres are good.

    Raises
    ------
    CalibrationError
        Markers 0, 1, 2 coincide or lie on one line.
    """
    m0, m1, m2 = (np.asarray(centres[i], dtype=np.float64) for i in ids[:3])
    x = m1 - m2
    y = m1 - m0
    nx, ny = float(np.linalg.norm(x)), float(np.linalg.norm(y))
    z = np.cross(x / max(nx, 1e-12), y / max(ny, 1e-12))
    if nx < 1.0 or ny < 1.0 or np.linalg.norm(z) < 0.1:
        raise CalibrationError(
            f"marker calibration: marker centres 0, 1, 2 are degenerate (|x| = {nx:.1f} mm, "
            f"|y| = {ny:.1f} mm, sin(angle) = {np.linalg.norm(z):.2f}); check the detections"
        )
    axes = np.stack([x / nx, y / ny, z / np.linalg.norm(z)], axis=1)  # columns: world axes in the sensor frame
    U, _, Vt = np.linalg.svd(axes)
    rotation = U @ Vt  # nearest rotation; det +1 since x̂, ŷ, x̂×ŷ form a right-handed (near) basis
    sensor_from_world = make_transform(rotation, m1)
    world_from_sensor = invert_transform(sensor_from_world)
    expected = {ids[0]: (0.0, -ny, 0.0), ids[2]: (-nx, 0.0, 0.0), ids[3]: (-nx, -ny, 0.0)}
    errors = []
    for marker_id, ideal in expected.items():
        if marker_id in centres:
            measured = world_from_sensor[:3, :3] @ np.asarray(centres[marker_id]) + world_from_sensor[:3, 3]
            errors.append(np.linalg.norm(measured - np.array(ideal)))
    return world_from_sensor, float(np.sqrt(np.mean(np.square(errors))))


def calibrate_world_from_marker(
    color_bgr: np.ndarray,
    depth_mm: np.ndarray,
    intrinsics: Intrinsics,
    master: str,
    *,
    calibration: CalibrationResult | None = None,
    ids: Sequence[int] = PLATE_IDS,
    dictionary: str = DEFAULT_DICTIONARY,
    marker_mm: float | None = None,
    centre_method: str = "plane",
) -> tuple[CalibrationResult, dict[int, MarkerObservation]]:
    """Put the rig on the floor: world from the master's view of the marker plate.

    Parameters
    ----------
    color_bgr, depth_mm, intrinsics : one frame of the master (colour registered to depth).
    master : the master's sensor id.
    calibration : a sensor-to-sensor calibration (e.g. :func:`skelfuse.calibration.sphere.calibrate_from_sphere`)
        whose master is ``master``; every sensor in it is re-anchored to the new world. None: the result
        holds the master only.
    ids, dictionary, marker_mm, centre_method : see :func:`detect_plate_markers`.

    Returns
    -------
    (result, observations): the CalibrationResult (method "marker"; the master's entry has method "marker",
    residual = the plate-fit residual, n_points = markers used; the others keep their sphere/skeleton
    metadata), and the marker observations (for the PnP cross-check and display).

    Raises
    ------
    CalibrationError
        Markers not found (see :func:`detect_plate_markers`), a degenerate plate, the master below the
        plate (z = x × y must point from the floor towards the sensor: a mirrored or upside-down plate), or a
        ``calibration`` whose master differs.
    """
    observations = detect_plate_markers(
        color_bgr,
        depth_mm,
        intrinsics,
        ids=ids,
        dictionary=dictionary,
        marker_mm=marker_mm,
        centre_method=centre_method,
    )
    centres = {i: obs.center for i, obs in observations.items()}
    world_from_master, residual = world_from_marker_centres(centres, ids)
    height = world_from_master[2, 3]
    if height <= 0:
        raise CalibrationError(
            f"marker calibration: the master comes out {height:.0f} mm below the plate: z = x × y "
            "points away from the sensor. Check the marker ids' placement (x from 2 to 1, y from "
            "0 to 1) and that the plate lies face up"
        )
    pnp = [obs.pnp_discrepancy_mm for obs in observations.values() if obs.pnp_discrepancy_mm is not None]
    notes = f"plate markers {sorted(observations)} ({dictionary}, {centre_method} centres)"
    if pnp:
        notes += f"; depth vs PnP centres differ by up to {max(pnp):.1f} mm"
    date = now_iso()
    entry = SensorCalibration(world_from_master, "marker", residual, len(observations), date, notes)
    if calibration is None:
        return CalibrationResult({master: entry}, "marker", master, date, notes), observations
    if calibration.master != master:
        raise CalibrationError(
            f"marker calibration: the master is {master!r} but the sensor-to-sensor calibration "
            f"was fitted to {calibration.master!r}; use that sensor's view of the plate"
        )
    moved = reanchor(calibration, world_from_master, note="re-anchored to the marker plate")
    sensors = dict(moved.sensors)
    sensors[master] = entry
    return CalibrationResult(sensors, "marker", master, date, notes, moved.points_by_sensor), observations
