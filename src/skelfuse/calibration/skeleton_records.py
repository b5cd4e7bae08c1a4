"""The records of the skeleton calibration (:mod:`skelfuse.calibration.skeleton`): its options and thresholds,
the per-pair, per-sensor and floor fits, the result and the check, and the joint sets the fits use.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from skelfuse.schema.skeleton import Confidence, J

MIDLINE_JOINTS = np.array([J[n] for n in ("PELVIS", "SPINE_NAVEL", "SPINE_CHEST", "NECK", "HEAD")], dtype=np.int64)
"""Torso joints on the body's mid-line: a left/right flip leaves them in place."""

SIDE_PAIRS = np.array(
    [
        [J["CLAVICLE_LEFT"], J["CLAVICLE_RIGHT"]],
        [J["SHOULDER_LEFT"], J["SHOULDER_RIGHT"]],
        [J["HIP_LEFT"], J["HIP_RIGHT"]],
    ],
    dtype=np.int64,
)
"""(left, right) torso joints used where both views' labels agree."""

FOOT_JOINTS = np.array([J[n] for n in ("ANKLE_LEFT", "ANKLE_RIGHT", "FOOT_LEFT", "FOOT_RIGHT")], dtype=np.int64)
"""Joints whose lowest one per frame is taken as a floor contact."""

NOMINAL_PELVIS_HEIGHT_MM = 950.0
"""Floor height below the mean pelvis when no foot is seen (an adult standing; a guess, reported as such)."""

SIGMA_FLOOR_MM = 30.0
SIGMA_SPINE_RAD = np.radians(2.0)


@dataclass(frozen=True)
class VerdictThresholds:
    """Limits of the per-sensor verdict (see the module docstring). ``good`` needs every ``good_*``."""

    good_half_rotation_deg: float = 2.0
    good_half_translation_mm: float = 75.0
    good_residual_mm: float = 70.0
    good_min_points: int = 500
    check_half_rotation_deg: float = 5.0
    check_half_translation_mm: float = 150.0
    check_residual_mm: float = 120.0
    check_min_points: int = 100
    good_inlier_frame_fraction: float = 0.7
    check_inlier_frame_fraction: float = 0.4
    repaired_residual_ratio: float = 0.75
    max_pairing_shift_frames: int = 150


@dataclass(frozen=True)
class SkeletonCalibrationOptions:
    """Parameters of :func:`calibrate_from_skeletons` and :func:`check_calibration`.

    Attributes
    ----------
    min_confidence : joints below this confidence are left out (default MEDIUM: LOW and NONE out).
    ransac_threshold_mm : RANSAC inlier distance on the mid-line points, mm.
    ransac_iterations : RANSAC samples per pair.
    final_threshold_mm : inlier distance of the trimmed refinement, mm (about 3x a good residual).
    trim_fraction : share of the worst inliers dropped at each refinement step.
    side_margin : side joints of a frame are used when ``keep < side_margin * swap`` (see the module doc).
    min_pair_points : fewest mid-line correspondences for a pair to be fitted at all.
    min_half_points : fewest correspondences a sensor needs in each half for the half-take agreement.
    foot_joint_height_mm : height of the lowest foot joint above the floor when standing, mm.
    refine_sweeps : most sweeps of the joint (all-pairs) refinement.
    seed : seeds RANSAC, so a calibration is reproducible.
    verdict : thresholds of the per-sensor verdict.
    """

    min_confidence: Confidence = Confidence.MEDIUM
    ransac_threshold_mm: float = 120.0
    ransac_iterations: int = 400
    final_threshold_mm: float = 80.0
    trim_fraction: float = 0.1
    side_margin: float = 0.6
    min_pair_points: int = 50
    min_half_points: int = 50
    foot_joint_height_mm: float = 30.0
    refine_sweeps: int = 100
    seed: int = 0
    verdict: VerdictThresholds = field(default_factory=VerdictThresholds)


@dataclass(frozen=True)
class PairFit:
    """One pair of sensors that saw the person together.

    Attributes
    ----------
    sensor_a, sensor_b : sensor ids; the fit maps b's frame to a's (``a_from_b``).
    a_from_b : (4, 4) pairwise robust fit, mm.
    n_points : correspondences the final pairwise fit used (inliers).
    n_frames : frames contributing at least one inlier.
    rms_mm : residual RMS of the pairwise fit, mm.
    rms_joint_mm : residual RMS of the same correspondences under the final joint (all-pairs) poses, mm.
    side_frames : frames whose side joints (clavicles, shoulders, hips) were used (labels agreed).
    mirrored_frames : frames whose side joints were left out because the views' labels disagreed.
    """

    sensor_a: str
    sensor_b: str
    a_from_b: np.ndarray
    n_points: int
    n_frames: int
    rms_mm: float
    rms_joint_mm: float
    side_frames: int
    mirrored_frames: int


@dataclass(frozen=True)
class SensorQuality:
    """How far to trust one sensor's pose.

    Attributes
    ----------
    sensor_id : str
    residual_mm : RMS distance between this sensor's joints and its partners' same joints under the final
        poses, mm (NaN when the sensor had no correspondences).
    n_points : correspondences over all its pairs.
    half_rotation_deg, half_translation_mm : disagreement of the fits on the first and second half of the
        take (translation at the subject); None where a half had too few points.
    verdict : "good", "check" or "bad".
    reasons : why the verdict is not "good" (empty when it is).
    inlier_frame_fraction : of the frames in which this sensor and its best partner both saw the torso, the
        share that hold an inlier of their pairwise fit (about 1 for a well paired take; frames paired in
        time wrongly drop it far below).
    better_shift_frames, better_shift_rms_mm : where pairing this sensor's frames a few frames off fits much
        better (see :func:`pairing_check`): the shift (frames of this sensor to move later) and the pairwise
        residual there; None when the pairing as given is the best one tried.
    """

    sensor_id: str
    residual_mm: float
    n_points: int
    half_rotation_deg: float | None
    half_translation_mm: float | None
    verdict: str
    reasons: tuple[str, ...] = ()
    inlier_frame_fraction: float | None = None
    better_shift_frames: int | None = None
    better_shift_rms_mm: float | None = None


@dataclass(frozen=True)
class FloorFit:
    """The floor found from the feet, in the master's frame.

    Attributes
    ----------
    normal : (3,) unit normal pointing up (toward the head), master frame.
    point_mm : (3,) a point on the floor (under the mean pelvis), master frame, mm.
    n_points : floor contacts used after trimming.
    rms_mm : RMS distance of the contacts from their plane, mm.
    spine_tilt_deg : angle between the floor normal and the mean spine direction, deg.
    plate_tilt_deg : angle between the given world's z and the floor normal (ArUco plate given), else None.
    """

    normal: np.ndarray
    point_mm: np.ndarray
    n_points: int
    rms_mm: float
    spine_tilt_deg: float
    plate_tilt_deg: float | None = None


@dataclass(frozen=True)
class SkeletonCalibration:
    """Result of :func:`calibrate_from_skeletons`.

    Attributes
    ----------
    sensor_ids : tuple of ids in input order.
    master : id of the sensor whose frame anchors the fit.
    world_from_sensor : dict id → (4, 4), mm, world z up.
    master_from_sensor : dict id → (4, 4), the relative poses (the master's is the identity).
    quality : dict id → :class:`SensorQuality`.
    pairs : the pairwise fits (:class:`PairFit`).
    floor : :class:`FloorFit`.
    world_source : "floor" or "plate" (``master_world_from_sensor`` given).
    n_frames : frames in the take.
    """

    sensor_ids: tuple[str, ...]
    master: str
    world_from_sensor: dict[str, np.ndarray]
    master_from_sensor: dict[str, np.ndarray]
    quality: dict[str, SensorQuality]
    pairs: tuple[PairFit, ...]
    floor: FloorFit
    world_source: str
    n_frames: int

    def world_from_sensor_array(self, order: Sequence[str] | None = None) -> np.ndarray:
        """(S, 4, 4) poses in ``order`` (default: input order), for :func:`apply_transform`."""
        return np.stack([self.world_from_sensor[s] for s in (order or self.sensor_ids)])

    def residuals_mm(self) -> dict[str, float]:
        """Per-sensor residual, mm: store it with the calibration for :func:`check_calibration`."""
        return {s: q.residual_mm for s, q in self.quality.items()}

    def report(self) -> str:
        """Human-readable summary: one line per sensor, the pairs, the floor."""
        lines = [
            f"Skeleton calibration: {len(self.sensor_ids)} sensors, master {self.master}, {self.n_frames} frames, "
            f"world from the {'ArUco plate' if self.world_source == 'plate' else 'floor (feet) and master view'}",
            f"{'sensor':<20} {'verdict':<7} {'residual':>9} {'points':>7} {'half-take':>18}",
        ]
        for sensor_id in self.sensor_ids:
            q = self.quality[sensor_id]
            if sensor_id == self.master:
                half = "(master)"
            elif q.half_rotation_deg is None:
                half = "n/a"
            else:
                half = f"{q.half_rotation_deg:.2f}° {q.half_translation_mm:.0f} mm"
            lines.append(
                f"{sensor_id:<20} {q.verdict:<7} {q.residual_mm:>6.1f} mm {q.n_points:>7d} {half:>18}"
                + (f"  ({'; '.join(q.reasons)})" if q.reasons else "")
            )
        lines.append("pairs (b → a): inliers, frames, pairwise / joint RMS, frames with side joints / mirrored:")
        for p in self.pairs:
            lines.append(
                f"  {p.sensor_b} → {p.sensor_a}: {p.n_points} pts, {p.n_frames} frames, "
                f"{p.rms_mm:.1f} / {p.rms_joint_mm:.1f} mm, side {p.side_frames} / mirrored {p.mirrored_frames}"
            )
        f = self.floor
        if f.n_points == 0:
            floor = (
                "floor: no foot contacts (feet not seen at MEDIUM confidence): z is the mean spine direction and the "
                f"floor a nominal {NOMINAL_PELVIS_HEIGHT_MM:.0f} mm below the mean pelvis; "
                "record the feet or use a plate"
            )
        else:
            floor = (
                f"floor: {f.n_points} foot contacts, plane RMS {f.rms_mm:.0f} mm, "
                f"{f.spine_tilt_deg:.1f}° from the mean spine direction"
            )
        if f.plate_tilt_deg is not None:
            floor += f", {f.plate_tilt_deg:.1f}° from the plate's z"
        lines.append(floor)
        lines.append(
            "verdicts: good = half-take fits agree within 2° / 75 mm and residual ≤ 70 mm; check = within 5° / "
            "150 mm (record a longer walk through every shared view); bad = do not use"
        )
        return "\n".join(lines)


@dataclass(frozen=True)
class SensorCheck:
    """One sensor in :func:`check_calibration`.

    Attributes
    ----------
    sensor_id : str
    residual_mm : residual RMS under the stored calibration on the new take, mm (NaN: no correspondences).
    refit_residual_mm : residual RMS after a fresh fit on the new take, mm.
    reference_residual_mm : the residual stored at calibration time, or None.
    correction_rotation_deg, correction_translation_mm : what the fresh fit changes relative to the stored
        calibration (translation at the subject), NaN where the sensor could not be fitted.
    n_points : correspondences on the new take.
    moved : the sensor exceeds a threshold (see ``warnings``).
    """

    sensor_id: str
    residual_mm: float
    refit_residual_mm: float
    reference_residual_mm: float | None
    correction_rotation_deg: float
    correction_translation_mm: float
    n_points: int
    moved: bool


@dataclass(frozen=True)
class CalibrationCheck:
    """Result of :func:`check_calibration`: per sensor, and the warnings to show."""

    master: str
    sensors: dict[str, SensorCheck]
    warnings: tuple[str, ...]

    @property
    def moved(self) -> tuple[str, ...]:
        """Ids of the sensors that look moved."""
        return tuple(s for s, c in self.sensors.items() if c.moved)

    def report(self) -> str:
        lines = [
            f"Calibration check against a new take (master {self.master} held fixed):",
            f"{'sensor':<20} {'residual':>9} {'stored':>9} {'refit':>9} {'correction':>18} {'points':>7}",
        ]
        for c in self.sensors.values():
            stored = "-" if c.reference_residual_mm is None else f"{c.reference_residual_mm:.1f}"
            corr = f"{c.correction_rotation_deg:.2f}° {c.correction_translation_mm:.0f} mm"
            lines.append(
                f"{c.sensor_id:<20} {c.residual_mm:>9.1f} {stored:>9} {c.refit_residual_mm:>9.1f} {corr:>18} "
                f"{c.n_points:>7d}" + ("  MOVED" if c.moved else "")
            )
        lines.extend(f"warning: {w}" for w in self.warnings)
        if not self.warnings:
            lines.append("no sensor moved beyond the thresholds")
        return "\n".join(lines)
