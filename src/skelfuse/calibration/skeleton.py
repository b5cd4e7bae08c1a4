"""Calibration from the skeletons themselves: a person walks through the shared view for ~30 s.

Beyond the paper (DESIGN.md "Calibration"): no sphere, no marker plate. Frames are synchronized (index t
is the same instant in every sensor), one person is in view, and each sensor's skeleton is in its own
depth-camera frame (x right, y down, z forward, mm).

Cycle
-----
1. **Corresponding points.** For every pair of sensors (a, b) and every frame both track, the same torso
   joint seen by both is one correspondence (b's position → a's position). Only joints with confidence
   MEDIUM or better count (LOW joints are the tracker's guesses for occluded joints; NONE is out of range).
   Torso joints only: they sit inside the trunk, so every view places them nearly alike (per-view offsets
   up to ~11 mm, DESIGN "Real noise"); limbs, hands, feet and face differ by 20-100 mm between views.

   * Mid-line joints :data:`MIDLINE_JOINTS` (pelvis, spine navel, spine chest, neck, head): a left/right
     flip of the tracker does not move them, so they are always used.
   * Side joints :data:`SIDE_PAIRS` (clavicles, shoulders, hips): used only in frames where the two views'
     labels agree. With the current estimate of the pair's transform, per frame, both labelings are
     scored: ``keep = Σ |a_L - T b_L| + |a_R - T b_R|`` and ``swap = Σ |a_L - T b_R| + |a_R - T b_L|``
     over the side pairs both views hold; the side joints of that frame are used when
     ``keep < side_margin * swap``. A frame whose views disagree (one is mirrored) or that is undecided
     is left out, it is not relabelled: a mirrored tracker fit is a body fitted the wrong way round, and
     DESIGN asks to exclude mirrored views.

2. **Pairwise robust fit**, for every pair with at least ``min_pair_points`` mid-line correspondences:
   RANSAC on the mid-line points (flip-proof), then the side joints are added with the labeling test and
   a trimmed refinement (:func:`skelfuse.calibration.rigid.refine_rigid_trimmed`) is run twice (labels
   re-tested against the refined fit in between).

3. **One consistent frame for all sensors.** Sensors need not all overlap the master: a maximum spanning
   tree over the pairs (edge weight = inlier count, Prim from the master) gives initial poses
   ``master_from_sensor`` by composition along the tree; then a joint refinement over *all* pairs at once:
   alternating (block Gauss-Seidel) least squares, each non-master sensor refitted in closed form to the
   current master-frame positions of its partners' corresponding points, until poses change by less than
   1e-3 deg and 0.01 mm in a sweep. This is the point-based pose-graph least squares ``min Σ_pairs Σ_i |M_a p_a,i -
   M_b p_b,i|^2`` with the master fixed; loops in the graph (a-b, b-c, a-c) are closed consistently
   instead of chaining errors down the tree.

4. **World frame.** z up from the floor: in each frame and sensor, the lowest MEDIUM ankle/foot joint
   (along a rough up, the mean pelvis → neck direction) is a floor contact; a plane is fitted to these
   points over the take. A person walking along one line spreads them well along the line but only
   ~200 mm across it (the two feet), so the plane fit is regularized by the spine direction: the normal
   minimizes ``n' (C / σ_floor² + (I - u u') / σ_spine²) n`` (C the scatter of the floor points, u the
   spine up, σ_floor = 30 mm, σ_spine = 2°): the floor decides where it is well spread, the spine
   elsewhere. Three trimmed passes drop points farther than 3 robust sigmas. z points toward the head.
   The floor lies ``foot_joint_height_mm`` below the median height of the contacts (the FOOT joint sits
   ~25-30 mm above the floor when the foot is flat). No foot seen at all: z is the mean spine direction
   and the floor :data:`NOMINAL_PELVIS_HEIGHT_MM` below the mean pelvis (the report says so). Origin: the
   floor under the mean pelvis. x: the
   master's viewing direction (+z) projected on the floor (the master's x axis if it looks straight
   down); y = z × x. With an ArUco plate result (``master_world_from_sensor``), that pose defines the world
   instead, and the floor fit is reported as a check (tilt between the plate's z and the floor normal).

5. **Quality per sensor.** Residual RMS of the final joint fit over the sensor's correspondences
   (distance between two noisy observations of the same joint: about √2 × the per-view error plus the
   per-view offsets), the number of corresponding points, and half-take agreement: the joint refinement
   repeated on the first and on the second half of the correspondences (each pair split at its own
   median frame, so a pair seen only late in the take still has two halves) and
   the two poses compared: rotation difference (deg) and translation difference *at the subject* (the
   distance the sensor's mean observed point moves between the two poses, mm; a translation of the
   camera origin would mix in the rotation's lever arm). DESIGN's real takes: halves agree within
   0.2-1.9° and 6-73 mm; 3-second windows vary by 1-5° and 50-120 mm. Verdict (:class:`VerdictThresholds`):

   * ``good``: half-take ≤ 2° and ≤ 75 mm, residual ≤ 70 mm, ≥ 500 points;
   * ``check``: half-take ≤ 5° and ≤ 150 mm, residual ≤ 120 mm, ≥ 100 points (as stable as a
     3-second window: usable, record a longer walk);
   * ``bad``: anything worse, or no half-take estimate.

   Thin evidence never passes as ``good`` (:func:`pairing_check`): a sensor whose frames hold an inlier in
   under 70 % of the frames it and its best partner both saw gets ``check`` (under 40 %: ``bad``), and a
   sensor whose pair fits far better with its frames shifted in time (residual below 0.75 x, as many
   inlier frames; the shift proposed by the person's motion) gets ``bad`` with the shift and the
   ``--time-offset`` that fixes it. Simulated 2-sensor walks: fraction 1.0 when paired right, 0.76-0.92
   two frames off, 0.13-0.24 fifty-seven frames off (the real take of issue 9: 201 of 862 frames, 0.23).

   The master's pose is fixed, so its half-take agreement is 0 by definition; its verdict rests on its
   residual and point count.

:func:`check_calibration` (``skelfuse calibrate check``) re-runs steps 1-3 on a new take and compares with a
stored calibration: per sensor the residual under the stored calibration, the correction a fresh fit would
apply (rotation deg, translation at the subject mm), and a "moved" warning past the thresholds.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from skelfuse.calibration.rigid import fit_rigid, fit_rigid_ransac, refine_rigid_trimmed, rotation_angle_deg
from skelfuse.config.calibration_file import CalibrationResult, SensorCalibration, now_iso
from skelfuse.fusion.mirror import pair_costs
from skelfuse.fusion.transform import invert_transform, make_transform, transform_points
from skelfuse.progress import Progress
from skelfuse.rig.motion_sync import band_pass, estimate_lag, motion_features
from skelfuse.schema.errors import CalibrationError
from skelfuse.schema.skeleton import N_JOINTS, Confidence, J

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

_SIGMA_FLOOR_MM = 30.0
_SIGMA_SPINE_RAD = np.radians(2.0)


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
        time wrongly drop it: 0.13-0.24 in simulated walks shifted by 57 frames).
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


# ---------------------------------------------------------------------------------------------------- input


def stack_sensor_takes(
    takes: Mapping[str, tuple[np.ndarray, np.ndarray]],
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """Per-sensor ``(positions (T, 32, 3), confidence (T, 32))`` → ``(T, S, 32, 3)``, ``(T, S, 32)``, ids.

    Frames match by index (synchronized capture); takes of different length are cut to the shortest.
    ``Recording.single_body()`` gives exactly such a pair per recorded file.
    """
    if not takes:
        raise ValueError("no sensor takes given")
    ids = tuple(takes)
    for sensor_id, (pos, conf) in takes.items():
        pos, conf = np.asarray(pos), np.asarray(conf)
        if pos.ndim != 3 or pos.shape[1:] != (N_JOINTS, 3) or conf.shape != pos.shape[:2]:
            raise ValueError(
                f"sensor {sensor_id!r}: expected positions (T, {N_JOINTS}, 3) and confidence (T, {N_JOINTS}), "
                f"got {pos.shape} and {conf.shape}"
            )
    n = min(len(takes[s][0]) for s in ids)
    positions = np.stack([np.asarray(takes[s][0], dtype=np.float64)[:n] for s in ids], axis=1)
    confidence = np.stack([np.asarray(takes[s][1])[:n] for s in ids], axis=1)
    return positions, confidence, ids


def _validate(
    positions: np.ndarray, confidence: np.ndarray, sensor_ids: Sequence[str], master: str | None
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...], int]:
    pos = np.asarray(positions, dtype=np.float64)
    conf = np.asarray(confidence)
    if pos.ndim != 4 or pos.shape[2:] != (N_JOINTS, 3):
        raise ValueError(f"positions must have shape (T, S, {N_JOINTS}, 3), got {pos.shape}")
    if conf.shape != pos.shape[:3]:
        raise ValueError(f"confidence must have shape {pos.shape[:3]} (T, S, {N_JOINTS}), got {conf.shape}")
    ids = tuple(str(s) for s in sensor_ids)
    if len(ids) != pos.shape[1]:
        raise ValueError(f"{len(ids)} sensor ids for {pos.shape[1]} sensors in positions")
    if len(set(ids)) != len(ids):
        raise ValueError(f"sensor ids must be unique, got {ids}")
    if len(ids) < 2:
        raise CalibrationError(f"skeleton calibration needs at least 2 sensors, got {len(ids)}")
    master = ids[0] if master is None else master
    if master not in ids:
        raise ValueError(f"master {master!r} is not one of the sensor ids {ids}")
    return pos, conf, ids, ids.index(master)


# ------------------------------------------------------------------------------------------ correspondences


@dataclass
class _Edge:
    a: int
    b: int
    src: np.ndarray  # (N, 3) b's points, b's frame
    dst: np.ndarray  # (N, 3) a's points, a's frame
    frames: np.ndarray  # (N,) frame index
    fit_rms: float
    a_from_b: np.ndarray
    side_frames: int
    mirrored_frames: int


def _midline_pairs(pos: np.ndarray, ok: np.ndarray, a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    both = ok[:, a, MIDLINE_JOINTS] & ok[:, b, MIDLINE_JOINTS]
    frames, k = np.nonzero(both)
    joints = MIDLINE_JOINTS[k]
    return pos[frames, b, joints], pos[frames, a, joints], frames


def _side_pairs(
    pos: np.ndarray, ok: np.ndarray, a: int, b: int, a_from_b: np.ndarray, margin: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    """Side-joint correspondences of the frames where both views' left/right labels agree."""
    left, right = SIDE_PAIRS[:, 0], SIDE_PAIRS[:, 1]
    decidable = ok[:, a][:, left] & ok[:, a][:, right] & ok[:, b][:, left] & ok[:, b][:, right]  # (T, P)
    with np.errstate(invalid="ignore"):
        bl, br = transform_points(a_from_b, pos[:, b][:, left]), transform_points(a_from_b, pos[:, b][:, right])
        al, ar = pos[:, a][:, left], pos[:, a][:, right]
        keep, swap = pair_costs(al, ar, bl, br)
    keep_sum = np.where(decidable, keep, 0.0).sum(axis=1)
    swap_sum = np.where(decidable, swap, 0.0).sum(axis=1)
    any_dec = decidable.any(axis=1)
    agree = any_dec & (keep_sum < margin * swap_sum)
    mirrored = any_dec & (swap_sum < margin * keep_sum)
    side = SIDE_PAIRS.reshape(-1)
    use = agree[:, None] & ok[:, a][:, side] & ok[:, b][:, side]
    frames, k = np.nonzero(use)
    joints = side[k]
    return pos[frames, b, joints], pos[frames, a, joints], frames, int(agree.sum()), int(mirrored.sum())


def _fit_pair(
    pos: np.ndarray, ok: np.ndarray, a: int, b: int, opts: SkeletonCalibrationOptions, rng: np.random.Generator
) -> _Edge | None:
    src_m, dst_m, fr_m = _midline_pairs(pos, ok, a, b)
    if len(src_m) < opts.min_pair_points:
        return None
    try:
        fit = fit_rigid_ransac(
            src_m,
            dst_m,
            threshold_mm=opts.ransac_threshold_mm,
            iterations=opts.ransac_iterations,
            min_inliers=opts.min_pair_points // 2,
            rng=rng,
            trim_fraction=opts.trim_fraction,
        )
    except CalibrationError:
        return None
    a_from_b = fit.matrix
    side_n = mirrored_n = 0
    src, dst, frames = src_m, dst_m, fr_m
    for _ in range(2):
        src_s, dst_s, fr_s, side_n, mirrored_n = _side_pairs(pos, ok, a, b, a_from_b, opts.side_margin)
        src, dst = np.concatenate([src_m, src_s]), np.concatenate([dst_m, dst_s])
        frames = np.concatenate([fr_m, fr_s])
        try:
            fit = refine_rigid_trimmed(
                src,
                dst,
                a_from_b[:3, :3],
                a_from_b[:3, 3],
                threshold_mm=opts.final_threshold_mm,
                trim_fraction=opts.trim_fraction,
                min_inliers=opts.min_pair_points // 2,
            )
        except CalibrationError:
            return None
        a_from_b = fit.matrix
    # Correspondences kept for the joint refinement: inliers of the final pairwise fit, untrimmed.
    resid = np.linalg.norm(transform_points(a_from_b, src) - dst, axis=1)
    keep = resid < opts.final_threshold_mm
    return _Edge(a, b, src[keep], dst[keep], frames[keep], fit.rms_mm, a_from_b, side_n, mirrored_n)


def _spanning_poses(edges: list[_Edge], n_sensors: int, master: int, ids: tuple[str, ...]) -> np.ndarray:
    """Initial master_from_sensor (S, 4, 4) by composition along a maximum spanning tree (Prim, from master)."""
    poses = np.full((n_sensors, 4, 4), np.nan)
    poses[master] = np.eye(4)
    reached = {master}
    while len(reached) < n_sensors:
        best = None
        for e in edges:
            if (e.a in reached) != (e.b in reached) and (best is None or len(e.src) > len(best.src)):
                best = e
        if best is None:
            missing = [ids[s] for s in range(n_sensors) if s not in reached]
            raise CalibrationError(
                f"could not link sensors {', '.join(missing)} to master {ids[master]}: no chain of sensor pairs "
                "saw the person together in enough frames (MEDIUM torso joints). Record a walk that passes "
                "through each sensor's view together with another sensor's, and check that the frames are "
                "synchronized"
            )
        if best.a in reached:  # master_from_b = master_from_a @ a_from_b
            poses[best.b] = poses[best.a] @ best.a_from_b
            reached.add(best.b)
        else:
            poses[best.a] = poses[best.b] @ invert_transform(best.a_from_b)
            reached.add(best.a)
    return poses


def _refine_joint(
    edges: list[_Edge],
    poses: np.ndarray,
    master: int,
    sweeps: int,
    frame_mask: Callable[[_Edge], np.ndarray] | None = None,
    min_points: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """Alternating least squares over all pairs; returns (poses, fitted (S,) bool)."""
    poses = poses.copy()
    n_sensors = len(poses)
    sel = [np.ones(len(e.src), bool) if frame_mask is None else frame_mask(e) for e in edges]
    counts = np.zeros(n_sensors, dtype=np.int64)
    for e, m in zip(edges, sel, strict=True):
        counts[e.a] += m.sum()
        counts[e.b] += m.sum()
    fitted = counts >= min_points
    fitted[master] = True
    for _ in range(sweeps):
        change = 0.0
        for s in range(n_sensors):
            if s == master or not fitted[s]:
                continue
            src, dst = [], []
            for e, m in zip(edges, sel, strict=True):
                if not m.any():
                    continue
                if e.b == s and fitted[e.a]:
                    src.append(e.src[m])
                    dst.append(transform_points(poses[e.a], e.dst[m]))
                elif e.a == s and fitted[e.b]:
                    src.append(e.dst[m])
                    dst.append(transform_points(poses[e.b], e.src[m]))
            if sum(len(x) for x in src) < min_points:
                fitted[s] = False
                continue
            try:
                fit = fit_rigid(np.concatenate(src), np.concatenate(dst))
            except CalibrationError:
                fitted[s] = False
                continue
            new = fit.matrix
            old = poses[s]
            change = max(
                change,
                rotation_angle_deg(new[:3, :3] @ old[:3, :3].T) / 1e-3,
                float(np.linalg.norm(new[:3, 3] - old[:3, 3])) / 1e-2,
            )
            poses[s] = new
        if change < 1.0:  # every pose moved by less than 1e-3 deg and 0.01 mm in this sweep
            break
    return poses, fitted


def _half_mask(first: bool) -> Callable[[_Edge], np.ndarray]:
    def mask(edge: _Edge) -> np.ndarray:
        if not len(edge.frames):
            return np.zeros(0, bool)
        split = np.median(edge.frames)
        below = edge.frames < split
        if not below.any():  # every correspondence in one frame: no halves
            return np.zeros(len(edge.frames), bool) if first else np.ones(len(edge.frames), bool)
        return below if first else ~below

    return mask


def _sensor_points(edges: list[_Edge], s: int) -> np.ndarray:
    pts = [e.src for e in edges if e.b == s] + [e.dst for e in edges if e.a == s]
    return np.concatenate(pts) if pts else np.zeros((0, 3))


def _pose_difference(T1: np.ndarray, T2: np.ndarray, points: np.ndarray) -> tuple[float, float]:
    """(rotation deg, translation at the subject mm): how far the sensor's mean observed point moves."""
    centre = points.mean(axis=0) if len(points) else np.zeros(3)
    return (
        rotation_angle_deg(T1[:3, :3] @ T2[:3, :3].T),
        float(np.linalg.norm(transform_points(T1, centre) - transform_points(T2, centre))),
    )


def _residuals(edges: list[_Edge], poses: np.ndarray, n_sensors: int) -> tuple[np.ndarray, np.ndarray, list[float]]:
    sq = np.zeros(n_sensors)
    count = np.zeros(n_sensors, dtype=np.int64)
    per_edge = []
    for e in edges:
        d2 = np.sum((transform_points(poses[e.b], e.src) - transform_points(poses[e.a], e.dst)) ** 2, axis=1)
        per_edge.append(float(np.sqrt(d2.mean())) if len(d2) else float("nan"))
        for s in (e.a, e.b):
            sq[s] += d2.sum()
            count[s] += len(d2)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(sq / count)
    return rms, count, per_edge


def _calibrate_relative(
    pos: np.ndarray,
    conf: np.ndarray,
    ids: tuple[str, ...],
    master: int,
    opts: SkeletonCalibrationOptions,
    progress: Progress,
) -> tuple[np.ndarray, list[_Edge]]:
    """Steps 1-3: master_from_sensor (S, 4, 4) and the pairwise edges with their correspondences."""
    ok = np.isfinite(pos).all(axis=-1) & (conf >= int(opts.min_confidence))
    rng = np.random.default_rng(opts.seed)
    n_sensors = len(ids)
    edges = []
    for a in range(n_sensors):
        for b in range(a + 1, n_sensors):
            edge = _fit_pair(pos, ok, a, b, opts, rng)
            if edge is not None:
                edges.append(edge)
            progress.update(note=f"{ids[b]} → {ids[a]}")
    poses = _spanning_poses(edges, n_sensors, master, ids)
    poses, _ = _refine_joint(edges, poses, master, opts.refine_sweeps)
    progress.update(note="joint refinement")
    return poses, edges


# ------------------------------------------------------------------------------------------------ the floor


def _fit_floor(
    pos: np.ndarray, ok: np.ndarray, master_from_sensor: np.ndarray, opts: SkeletonCalibrationOptions
) -> FloorFit:
    n_sensors = pos.shape[1]
    spines, pelvises, feet = [], [], []
    for s in range(n_sensors):
        T = master_from_sensor[s]
        both = ok[:, s, J["PELVIS"]] & ok[:, s, J["NECK"]]
        pelvis = transform_points(T, pos[both, s, J["PELVIS"]])
        neck = transform_points(T, pos[both, s, J["NECK"]])
        spines.append(neck - pelvis)
        pelvises.append(pelvis)
        feet.append((transform_points(T, pos[:, s][:, FOOT_JOINTS]), ok[:, s][:, FOOT_JOINTS]))
    spine = np.concatenate(spines)
    if len(spine):
        unit = spine / np.linalg.norm(spine, axis=1, keepdims=True)
        up = unit.mean(axis=0)
        up /= np.linalg.norm(up)
    else:  # no spine seen: the master's -y (Azure Kinect y points down in the image)
        up = np.array([0.0, -1.0, 0.0])
    # Floor contacts: per frame and sensor the lowest foot joint along the spine's up. Grouped by (sensor,
    # joint): each group gets its own height (the ankle sits ~70 mm up, the toe joint ~25 mm, and each view
    # has its own constant offset of the feet, DESIGN "Real noise"), only the normal is shared.
    groups = []
    for points, valid in feet:
        height = np.where(valid, points @ up, np.inf)  # (T, 4)
        lowest = np.argmin(height, axis=1)
        has = np.isfinite(height).any(axis=1)
        for j in range(len(FOOT_JOINTS)):
            sel = has & (lowest == j)
            if sel.sum() >= 3:
                groups.append(points[sel, j])
    pelvis_mean = np.concatenate(pelvises).mean(axis=0) if sum(len(p) for p in pelvises) else np.zeros(3)
    n_contacts = sum(len(g) for g in groups)
    if n_contacts < 30:
        if not len(spine):
            raise CalibrationError(
                f"found only {n_contacts} floor contacts (MEDIUM ankle/foot joints) and no pelvis + neck: the "
                "world's z axis is undetermined; record a walk with the whole body in view, or give the ArUco "
                "plate's master pose"
            )
        # No feet: z from the spine alone, the floor a nominal pelvis height below the mean pelvis.
        return FloorFit(
            normal=up,
            point_mm=pelvis_mean - NOMINAL_PELVIS_HEIGHT_MM * up,
            n_points=0,
            rms_mm=float("nan"),
            spine_tilt_deg=0.0,
        )
    # Contacts of one step (~0.5 s) seen by every sensor are one foot placement, not independent samples:
    # the floor's information is scaled down to one contact per step and view, so that the spine prior keeps
    # its say across a narrow walking line (where the floor has a ~200 mm baseline only).
    n_eff = max(n_contacts / (15.0 * n_sensors), 3.0)
    prior = (np.eye(3) - np.outer(up, up)) / _SIGMA_SPINE_RAD**2
    keep = [np.ones(len(g), bool) for g in groups]
    normal = up
    for _ in range(3):
        scatter = np.zeros((3, 3))
        for g, k in zip(groups, keep, strict=True):
            if k.sum() >= 2:
                d = g[k] - g[k].mean(axis=0)
                scatter += d.T @ d
        _, vecs = np.linalg.eigh(scatter * (n_eff / n_contacts) / _SIGMA_FLOOR_MM**2 + prior)
        normal = vecs[:, 0] * np.sign(vecs[:, 0] @ up)
        resid = [
            (g - g[k].mean(axis=0)) @ normal if k.any() else np.zeros(len(g)) for g, k in zip(groups, keep, strict=True)
        ]
        flat = np.concatenate([r[k] for r, k in zip(resid, keep, strict=True)])
        sigma = max(1.4826 * np.median(np.abs(flat)), 5.0)
        keep = [np.abs(r) <= 3.0 * sigma for r in resid]
    flat = np.concatenate([r[k] for r, k in zip(resid, keep, strict=True)])
    # Floor height: the median height of all kept contacts, less the lowest foot joint's height above it.
    heights = np.concatenate([g[k] @ normal for g, k in zip(groups, keep, strict=True)])
    floor_height = np.median(heights) - opts.foot_joint_height_mm
    point = pelvis_mean - (pelvis_mean @ normal - floor_height) * normal
    return FloorFit(
        normal=normal,
        point_mm=point,
        n_points=len(heights),
        rms_mm=float(np.sqrt(np.mean(flat**2))),
        spine_tilt_deg=float(np.degrees(np.arccos(np.clip(normal @ up, -1, 1)))),
    )


def _world_from_master(floor: FloorFit) -> np.ndarray:
    z = floor.normal
    forward = np.array([0.0, 0.0, 1.0])  # master's viewing direction, master frame
    x = forward - (forward @ z) * z
    if np.linalg.norm(x) < 1e-3:  # master looks straight down: use its image x axis instead
        x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: world axes in master coordinates → p_world = R (p_master - origin)
    return make_transform(R, -R @ floor.point_mm)


# ------------------------------------------------------------------------------------------------ public API


def _make_progress(progress: bool | Progress, total: int, label: str) -> Progress:
    if isinstance(progress, Progress):
        return progress
    return Progress(total, label, enabled=None if progress else False)


def _verdict(
    residual: float,
    n_points: int,
    half: tuple[float, float] | None,
    is_master: bool,
    th: VerdictThresholds,
    pairing: PairingCheck | None = None,
) -> tuple[str, tuple[str, ...]]:
    bad, check = [], []
    if pairing is not None:
        fraction = pairing.inlier_frame_fraction
        if pairing.better_shift_frames is not None:
            bad.append(
                f"frames look paired {pairing.better_shift_frames:+d} frames off: pairwise residual "
                f"{pairing.rms_mm:.0f} mm as paired, {pairing.better_shift_rms_mm:.0f} mm with this sensor's frames "
                f"shifted by {pairing.better_shift_frames:+d}; check the time matching (files without timestamps "
                f"are paired by index) and pass --time-offset ID={pairing.better_shift_frames * 1000 / 30:+.0f} "
                "(ms, at 30 fps) for this sensor"
            )
        if fraction < th.check_inlier_frame_fraction:
            bad.append(
                f"only {fraction:.0%} of the frames both sensors saw fit the pose (thin evidence: frames paired "
                "wrongly in time, or a different person); check the time matching, record a longer walk"
            )
        elif fraction < th.good_inlier_frame_fraction:
            check.append(f"only {fraction:.0%} of the frames both sensors saw fit the pose")
    if not np.isfinite(residual) or n_points < th.check_min_points:
        bad.append(f"{n_points} corresponding points (< {th.check_min_points})")
    elif n_points < th.good_min_points:
        check.append(f"{n_points} corresponding points (< {th.good_min_points})")
    if np.isfinite(residual):
        if residual > th.check_residual_mm:
            bad.append(f"residual {residual:.0f} mm > {th.check_residual_mm:.0f}")
        elif residual > th.good_residual_mm:
            check.append(f"residual {residual:.0f} mm > {th.good_residual_mm:.0f}")
    if not is_master:
        if half is None:
            bad.append("no half-take estimate (too few points in one half)")
        else:
            rot, trans = half
            if rot > th.check_half_rotation_deg or trans > th.check_half_translation_mm:
                bad.append(f"halves disagree by {rot:.1f}° / {trans:.0f} mm")
            elif rot > th.good_half_rotation_deg or trans > th.good_half_translation_mm:
                check.append(f"halves disagree by {rot:.1f}° / {trans:.0f} mm")
    if bad:
        return "bad", tuple(bad + check)
    if check:
        return "check", tuple(check)
    return "good", ()


@dataclass(frozen=True)
class PairingCheck:
    """Whether a sensor's frames are paired with its partner's at the right instants (see :func:`pairing_check`).

    Attributes
    ----------
    partner : the sensor it was checked against (its pair with the most inliers).
    inlier_frame_fraction : frames with an inlier / frames in which both saw the torso.
    rms_mm : the pairwise residual as paired.
    better_shift_frames, better_shift_rms_mm : a shift of this sensor's frames that fits much better, and
        its residual; None when none did.
    tried : the shifts that were refitted.
    """

    partner: str
    inlier_frame_fraction: float
    rms_mm: float
    better_shift_frames: int | None = None
    better_shift_rms_mm: float | None = None
    tried: tuple[int, ...] = ()


def _shifted(array: np.ndarray, column: int, shift: int, fill: float | int) -> np.ndarray:
    """``array`` with ``array[k, column] = array[k + shift, column]`` (``fill`` beyond the ends)."""
    out = array.copy()
    moved = np.full_like(array[:, column], fill)
    if shift >= 0:
        moved[: len(array) - shift] = array[shift:, column]
    else:
        moved[-shift:] = array[: len(array) + shift, column]
    out[:, column] = moved
    return out


def pairing_check(
    pos: np.ndarray,
    ok: np.ndarray,
    edges: Sequence[_Edge],
    sensor: int,
    ids: Sequence[str],
    opts: SkeletonCalibrationOptions,
) -> PairingCheck | None:
    """Is ``sensor`` paired in time with its partners? Frame fraction, and refits at suspicious shifts.

    Evidence that frames are paired wrongly: few of the frames both sensors saw hold an inlier, or the
    person's motion (:mod:`skelfuse.rig.motion_sync`, frame-invariant joint distances) matches best at a
    shift of two frames or more. Only then (so a well paired take costs nothing) the pair is refitted with
    this sensor's frames shifted around the motion's best shift (±3 frames) and to its next peaks (at most
    five, within ``max_pairing_shift_frames``); the shift with the lowest residual below
    ``repaired_residual_ratio`` times the residual as paired, with at least as many inlier frames, is
    reported: the motion proposes, the geometry decides (a periodic motion alone would be ambiguous).
    """
    mine = [e for e in edges if sensor in (e.a, e.b)]
    if not mine:
        return None
    edge = max(mine, key=lambda e: len(e.src))
    a, b = edge.a, edge.b
    partner = a if sensor == b else b
    covisible = int((ok[:, a][:, MIDLINE_JOINTS] & ok[:, b][:, MIDLINE_JOINTS]).any(axis=1).sum())
    n_inlier_frames = len(np.unique(edge.frames))
    fraction = n_inlier_frames / covisible if covisible else 0.0
    th = opts.verdict
    lag = estimate_lag(
        band_pass(motion_features(np.where(ok[:, a, :, None], pos[:, a], np.nan))),
        band_pass(motion_features(np.where(ok[:, b, :, None], pos[:, b], np.nan))),
        max_lag=th.max_pairing_shift_frames,
    )
    # a periodic motion alone is no evidence: it matches a step off about as well as it matches as paired
    motion_says_off = (
        lag.found
        and abs(lag.lag) >= 2
        and not lag.ambiguous
        and not (np.isfinite(lag.score_at_zero) and lag.score_at_zero >= 0.8 * lag.score)
    )
    suspicious = fraction < th.good_inlier_frame_fraction or motion_says_off
    if not suspicious or not lag.found:
        return PairingCheck(ids[partner], fraction, edge.fit_rms)
    candidates = [p for p in lag.peaks if p != 0][:5]
    rng = np.random.default_rng(opts.seed)
    tried: dict[int, tuple[int, float] | None] = {}

    def refit(shift: int) -> tuple[int, float] | None:
        # frame k of a is paired with frame k + shift of b
        if shift not in tried:
            trial = _fit_pair(_shifted(pos, b, shift, np.nan), _shifted(ok, b, shift, False), a, b, opts, rng)
            tried[shift] = None if trial is None else (len(np.unique(trial.frames)), trial.fit_rms)
        return tried[shift]

    def better(shift: int) -> bool:
        got = refit(shift)
        return got is not None and got[0] >= n_inlier_frames and got[1] < th.repaired_residual_ratio * edge.fit_rms

    # the motion's best shift is good to a few frames: search around it; the other peaks as they are
    near_best = [c for c in range(lag.lag - 3, lag.lag + 4) if c != 0]
    good = [c for c in dict.fromkeys(near_best + candidates) if better(c)]
    best: tuple[int, float] | None = None
    if good:
        pick = min(good, key=lambda c: tried[c][1])  # type: ignore[index]
        best = (pick, tried[pick][1])  # type: ignore[index]
    candidates = sorted(tried)
    if best is None:
        return PairingCheck(ids[partner], fraction, edge.fit_rms, tried=tuple(candidates))
    # as this sensor's shift: b's frames move by -shift to line up with a's; a's by +shift to line up with b's
    shift = -best[0] if sensor == b else best[0]
    return PairingCheck(ids[partner], fraction, edge.fit_rms, shift, best[1], tuple(candidates))


def calibrate_from_skeletons(
    positions: np.ndarray,
    confidence: np.ndarray,
    sensor_ids: Sequence[str],
    master: str | None = None,
    *,
    master_world_from_sensor: np.ndarray | None = None,
    options: SkeletonCalibrationOptions | None = None,
    progress: bool | Progress = True,
) -> SkeletonCalibration:
    """Calibrate every sensor from one person walking through the shared views (see the module docstring).

    Parameters
    ----------
    positions : (T, S, 32, 3) array, mm
        Each sensor's skeleton of the one person, in that sensor's own camera frame; frames synchronized
        (index t = the same instant for all sensors); NaN where a sensor did not track the person.
        :func:`stack_sensor_takes` builds it from per-sensor ``(T, 32, 3)`` arrays.
    confidence : (T, S, 32) array of :class:`Confidence` values.
    sensor_ids : S ids (device serials), in the order of axis 1.
    master : id of the sensor whose frame anchors the relative poses; default the first.
    master_world_from_sensor : (4, 4) or None
        The master's world pose from an ArUco plate (sensor-to-marker calibration). Given: the world is the
        plate's and the floor fit is only reported as a check. None: the world comes from the floor.
    options : :class:`SkeletonCalibrationOptions` (defaults when None).
    progress : True draws a progress bar on stderr when it is a terminal, False is silent, or a
        :class:`Progress` to drive.

    Returns
    -------
    :class:`SkeletonCalibration`; ``report()`` gives the human-readable summary.

    Raises
    ------
    ValueError
        Wrong shapes or ids.
    CalibrationError
        Fewer than 2 sensors; a sensor that no chain of overlapping pairs links to the master; no floor
        contacts and no plate pose.
    """
    pos, conf, ids, m = _validate(positions, confidence, sensor_ids, master)
    opts = options or SkeletonCalibrationOptions()
    n_frames, n_sensors = pos.shape[:2]
    n_pairs = n_sensors * (n_sensors - 1) // 2
    bar = _make_progress(progress, n_pairs + 3, "skeleton calibration")
    try:
        poses, edges = _calibrate_relative(pos, conf, ids, m, opts, bar)
        residual, counts, per_edge = _residuals(edges, poses, n_sensors)

        # Half-take agreement: the joint refinement on each half of the correspondences.
        # Each pair is split at its own median frame, so a pair seen only late in the take still has halves.
        halves = [
            _refine_joint(
                edges, poses, m, opts.refine_sweeps, frame_mask=_half_mask(first), min_points=opts.min_half_points
            )
            for first in (True, False)
        ]
        bar.update(note="half-take agreement")

        ok = np.isfinite(pos).all(axis=-1) & (conf >= int(opts.min_confidence))
        plate = None
        if master_world_from_sensor is not None:
            plate = np.asarray(master_world_from_sensor, dtype=np.float64)
            make_transform(plate[:3, :3], plate[:3, 3])  # validates a proper rigid transform
        try:
            floor = _fit_floor(pos, ok, poses, opts)
        except CalibrationError:
            if plate is None:
                raise
            floor = FloorFit(np.full(3, np.nan), np.full(3, np.nan), 0, float("nan"), float("nan"))
        if plate is None:
            world_from_master = _world_from_master(floor)
            source = "floor"
        else:
            world_from_master = plate
            source = "plate"
            plate_up = plate[2, :3]  # world z expressed in the master frame (row 3 of R)
            tilt = float(np.degrees(np.arccos(np.clip(plate_up @ floor.normal, -1, 1))))
            floor = FloorFit(floor.normal, floor.point_mm, floor.n_points, floor.rms_mm, floor.spine_tilt_deg, tilt)
        bar.update(note="world frame")
    finally:
        bar.close()

    quality = {}
    ok_all = np.isfinite(pos).all(axis=-1) & (conf >= int(opts.min_confidence))
    for s, sensor_id in enumerate(ids):
        (p1, f1), (p2, f2) = halves
        half = None
        if s != m and f1[s] and f2[s]:
            half = _pose_difference(p1[s], p2[s], _sensor_points(edges, s))
        pairing = None if s == m else pairing_check(pos, ok_all, edges, s, ids, opts)
        verdict, reasons = _verdict(float(residual[s]), int(counts[s]), half, s == m, opts.verdict, pairing)
        quality[sensor_id] = SensorQuality(
            sensor_id=sensor_id,
            residual_mm=float(residual[s]),
            n_points=int(counts[s]),
            half_rotation_deg=None if half is None else half[0],
            half_translation_mm=None if half is None else half[1],
            verdict=verdict,
            reasons=reasons,
            inlier_frame_fraction=None if pairing is None else pairing.inlier_frame_fraction,
            better_shift_frames=None if pairing is None else pairing.better_shift_frames,
            better_shift_rms_mm=None if pairing is None else pairing.better_shift_rms_mm,
        )
    pairs = tuple(
        PairFit(
            sensor_a=ids[e.a],
            sensor_b=ids[e.b],
            a_from_b=e.a_from_b,
            n_points=len(e.src),
            n_frames=len(np.unique(e.frames)),
            rms_mm=e.fit_rms,
            rms_joint_mm=r,
            side_frames=e.side_frames,
            mirrored_frames=e.mirrored_frames,
        )
        for e, r in zip(edges, per_edge, strict=True)
    )
    return SkeletonCalibration(
        sensor_ids=ids,
        master=ids[m],
        world_from_sensor={sensor_id: world_from_master @ poses[s] for s, sensor_id in enumerate(ids)},
        master_from_sensor={sensor_id: poses[s] for s, sensor_id in enumerate(ids)},
        quality=quality,
        pairs=pairs,
        floor=floor,
        world_source=source,
        n_frames=n_frames,
    )


def check_calibration(
    world_from_sensor: Mapping[str, np.ndarray],
    positions: np.ndarray,
    confidence: np.ndarray,
    sensor_ids: Sequence[str],
    master: str | None = None,
    *,
    reference_residual_mm: Mapping[str, float] | None = None,
    max_rotation_deg: float = 2.0,
    max_translation_mm: float = 30.0,
    max_residual_growth_mm: float = 15.0,
    options: SkeletonCalibrationOptions | None = None,
    progress: bool | Progress = False,
) -> CalibrationCheck:
    """Has a sensor moved since it was calibrated? Compare a stored calibration with a new walking take.

    A fresh relative fit (steps 1-3 of the module docstring) is run on the new take with ``master`` held at
    its stored pose; for each other sensor the fresh pose is compared with the stored one (the correction:
    rotation deg, translation at the subject mm), and the residual of the stored calibration over the
    fresh fit's correspondences is compared with the residual stored at calibration time.

    A sensor is reported as moved when its correction exceeds ``max_rotation_deg`` or
    ``max_translation_mm``. A residual grown by more than ``max_residual_growth_mm`` over
    ``reference_residual_mm`` gives a warning of its own but does not mark the sensor moved: residuals are
    shared by both sensors of each pair, so one moved sensor raises its partners' residuals as well.
    Corrections are relative to the master: when *every* other sensor is
    flagged, the master itself has probably moved. A 30 s take is needed for the 2° / 30 mm defaults
    (DESIGN: 3-second windows scatter by 1-5° and 50-120 mm).

    Parameters
    ----------
    world_from_sensor : id → (4, 4) stored calibration.
    positions, confidence, sensor_ids, master : the new take, as for :func:`calibrate_from_skeletons`.
    reference_residual_mm : id → residual stored at calibration time (:meth:`SkeletonCalibration.residuals_mm`).
    max_rotation_deg, max_translation_mm, max_residual_growth_mm : thresholds of the "moved" warning.

    Returns
    -------
    :class:`CalibrationCheck`.

    Raises
    ------
    CalibrationError
        A sensor of the take has no stored pose, or the take cannot link every sensor to the master.
    """
    pos, conf, ids, m = _validate(positions, confidence, sensor_ids, master)
    missing = [s for s in ids if s not in world_from_sensor]
    if missing:
        raise CalibrationError(
            f"the stored calibration has no pose for sensor(s) {', '.join(missing)} (it has "
            f"{', '.join(world_from_sensor) or 'none'}); calibrate them first"
        )
    opts = options or SkeletonCalibrationOptions()
    n_sensors = len(ids)
    stored_world = np.stack([np.asarray(world_from_sensor[s], dtype=np.float64) for s in ids])
    stored = invert_transform(stored_world[m]) @ stored_world  # master_from_sensor
    bar = _make_progress(progress, n_sensors * (n_sensors - 1) // 2 + 1, "calibration check")
    try:
        fresh, edges = _calibrate_relative(pos, conf, ids, m, opts, bar)
    finally:
        bar.close()
    residual_stored, counts, _ = _residuals(edges, stored, n_sensors)
    residual_fresh, _, _ = _residuals(edges, fresh, n_sensors)
    sensors, warnings = {}, []
    for s, sensor_id in enumerate(ids):
        if counts[s]:
            rot, trans = _pose_difference(fresh[s], stored[s], _sensor_points(edges, s))
        else:
            rot = trans = float("nan")
        ref = None if reference_residual_mm is None else reference_residual_mm.get(sensor_id)
        reasons = []
        if s != m and rot > max_rotation_deg:
            reasons.append(f"rotated {rot:.1f}° (> {max_rotation_deg:g}°)")
        if s != m and trans > max_translation_mm:
            reasons.append(f"shifted {trans:.0f} mm at the subject (> {max_translation_mm:g} mm)")
        if reasons:
            warnings.append(f"sensor {sensor_id} looks moved: {'; '.join(reasons)}; recalibrate it")
        if ref is not None and residual_stored[s] - ref > max_residual_growth_mm:
            # Not by itself "moved": a residual is shared by both sensors of every pair, so one moved sensor
            # raises its partners' residuals too. The correction says which one moved.
            warnings.append(
                f"sensor {sensor_id}: residual {residual_stored[s]:.0f} mm vs {ref:.0f} mm at calibration "
                f"(+{max_residual_growth_mm:g} allowed): the rig or the tracking changed since"
            )
        if not counts[s]:
            warnings.append(f"sensor {sensor_id}: no corresponding points in this take; it could not be checked")
        sensors[sensor_id] = SensorCheck(
            sensor_id=sensor_id,
            residual_mm=float(residual_stored[s]),
            refit_residual_mm=float(residual_fresh[s]),
            reference_residual_mm=None if ref is None else float(ref),
            correction_rotation_deg=float(rot),
            correction_translation_mm=float(trans),
            n_points=int(counts[s]),
            moved=bool(reasons),
        )
    flagged = [s for s in ids if sensors[s].moved and s != ids[m]]
    if n_sensors > 2 and len(flagged) == n_sensors - 1:
        warnings.append(f"every sensor moved relative to master {ids[m]}: the master itself has probably moved")
    return CalibrationCheck(master=ids[m], sensors=sensors, warnings=tuple(warnings))


def _finite_or_none(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def skeleton_calibration_result(cal: SkeletonCalibration) -> CalibrationResult:
    """A :class:`~skelfuse.calibration.skeleton.SkeletonCalibration` as a file-ready CalibrationResult
    (method "skeleton"; each sensor's verdict, half-take agreement and reasons in its notes)."""
    date = now_iso()
    sensors = {}
    for sensor_id in cal.sensor_ids:
        q = cal.quality[sensor_id]
        notes = f"verdict {q.verdict}"
        if sensor_id == cal.master:
            notes += "; master"
        elif q.half_rotation_deg is not None:
            notes += f"; half-take {q.half_rotation_deg:.2f} deg / {q.half_translation_mm:.0f} mm"
        if q.reasons:
            notes += f"; {'; '.join(q.reasons)}"
        sensors[sensor_id] = SensorCalibration(
            cal.world_from_sensor[sensor_id], "skeleton", _finite_or_none(q.residual_mm), int(q.n_points), date, notes
        )
    verdicts = ", ".join(f"{s} {cal.quality[s].verdict}" for s in cal.sensor_ids)
    world = "ArUco plate (master pose given)" if cal.world_source == "plate" else "floor from the feet"
    notes = f"skeleton walk of {cal.n_frames} frames; world: {world}; verdicts: {verdicts}"
    return CalibrationResult(sensors, "skeleton", cal.master, date, notes)
