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
   two frames off, 0.13-0.24 fifty-seven frames off (a real take whose files were paired off in time: 201 of
   862 frames, 0.23).

   The master's pose is fixed, so its half-take agreement is 0 by definition; its verdict rests on its
   residual and point count.

:func:`check_calibration` (``skelfuse calibrate check``) re-runs steps 1-3 on a new take and compares with a
stored calibration: per sensor the residual under the stored calibration, the correction a fresh fit would
apply (rotation deg, translation at the subject mm), and a "moved" warning past the thresholds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from skelfuse.calibration.skeleton_fit import (
    PairEdge,
    calibrate_relative,
    fit_floor,
    fit_pair,
    floor_world_from_master,
    half_mask,
    pair_residuals,
    pose_difference,
    refine_joint,
    sensor_points,
)
from skelfuse.calibration.skeleton_records import (
    FOOT_JOINTS,
    MIDLINE_JOINTS,
    NOMINAL_PELVIS_HEIGHT_MM,
    SIDE_PAIRS,
    CalibrationCheck,
    FloorFit,
    PairFit,
    SensorCheck,
    SensorQuality,
    SkeletonCalibration,
    SkeletonCalibrationOptions,
    VerdictThresholds,
)
from skelfuse.config.calibration_file import CalibrationResult, SensorCalibration, now_iso
from skelfuse.fusion.transform import invert_transform, make_transform
from skelfuse.progress import Progress
from skelfuse.rig.motion_sync import band_pass, estimate_lag, motion_features
from skelfuse.schema.errors import CalibrationError
from skelfuse.schema.skeleton import N_JOINTS

# The records and the fits live in skeleton_records.py and skeleton_fit.py; the records are re-exported here.
__all__ = [
    "FOOT_JOINTS",
    "MIDLINE_JOINTS",
    "NOMINAL_PELVIS_HEIGHT_MM",
    "SIDE_PAIRS",
    "CalibrationCheck",
    "FloorFit",
    "PairFit",
    "PairingCheck",
    "SensorCheck",
    "SensorQuality",
    "SkeletonCalibration",
    "SkeletonCalibrationOptions",
    "VerdictThresholds",
    "calibrate_from_skeletons",
    "check_calibration",
    "pairing_check",
    "skeleton_calibration_result",
    "stack_sensor_takes",
]


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
    edges: Sequence[PairEdge],
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
            trial = fit_pair(_shifted(pos, b, shift, np.nan), _shifted(ok, b, shift, False), a, b, opts, rng)
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
        pick = min(good, key=lambda c: tried[c][1])  # type: ignore[index]  # better(c) holds: tried[c] is a fit, not None
        best = (pick, tried[pick][1])  # type: ignore[index]  # as above
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
        poses, edges = calibrate_relative(pos, conf, ids, m, opts, bar)
        residual, counts, per_edge = pair_residuals(edges, poses, n_sensors)

        # Half-take agreement: the joint refinement on each half of the correspondences.
        # Each pair is split at its own median frame, so a pair seen only late in the take still has halves.
        halves = [
            refine_joint(
                edges, poses, m, opts.refine_sweeps, frame_mask=half_mask(first), min_points=opts.min_half_points
            )
            for first in (True, False)
        ]
        bar.update(note="half-take agreement")

        world_from_master, floor, source = _world_frame(pos, conf, poses, opts, master_world_from_sensor)
        bar.update(note="world frame")
    finally:
        bar.close()

    quality = _sensor_qualities(pos, conf, ids, m, edges, residual, counts, halves, opts)
    pairs = _pair_fits(edges, per_edge, ids)
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


def _world_frame(
    pos: np.ndarray,
    conf: np.ndarray,
    poses: np.ndarray,
    opts: SkeletonCalibrationOptions,
    master_world_from_sensor: np.ndarray | None,
) -> tuple[np.ndarray, FloorFit, str]:
    """world_from_master from the plate when given (the floor fit then only reports its tilt), else from the
    floor; with the floor fit and which of the two set the world ("plate" or "floor")."""
    ok = np.isfinite(pos).all(axis=-1) & (conf >= int(opts.min_confidence))
    plate = None
    if master_world_from_sensor is not None:
        plate = np.asarray(master_world_from_sensor, dtype=np.float64)
        make_transform(plate[:3, :3], plate[:3, 3])  # validates a proper rigid transform
    try:
        floor = fit_floor(pos, ok, poses, opts)
    except CalibrationError:
        if plate is None:
            raise
        floor = FloorFit(np.full(3, np.nan), np.full(3, np.nan), 0, float("nan"), float("nan"))
    if plate is None:
        return floor_world_from_master(floor), floor, "floor"
    plate_up = plate[2, :3]  # world z expressed in the master frame (row 3 of R)
    tilt = float(np.degrees(np.arccos(np.clip(plate_up @ floor.normal, -1, 1))))
    floor = FloorFit(floor.normal, floor.point_mm, floor.n_points, floor.rms_mm, floor.spine_tilt_deg, tilt)
    return plate, floor, "plate"


def _sensor_qualities(
    pos: np.ndarray,
    conf: np.ndarray,
    ids: tuple[str, ...],
    m: int,
    edges: list[PairEdge],
    residual: np.ndarray,
    counts: np.ndarray,
    halves: list[tuple[np.ndarray, np.ndarray]],
    opts: SkeletonCalibrationOptions,
) -> dict[str, SensorQuality]:
    """Per sensor: residual, half-take agreement, pairing check and the verdict they give."""
    quality = {}
    ok_all = np.isfinite(pos).all(axis=-1) & (conf >= int(opts.min_confidence))
    for s, sensor_id in enumerate(ids):
        (p1, f1), (p2, f2) = halves
        half = None
        if s != m and f1[s] and f2[s]:
            half = pose_difference(p1[s], p2[s], sensor_points(edges, s))
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
    return quality


def _pair_fits(edges: list[PairEdge], per_edge: list[float], ids: tuple[str, ...]) -> tuple[PairFit, ...]:
    """The report's record of each fitted sensor pair."""
    return tuple(
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
        fresh, edges = calibrate_relative(pos, conf, ids, m, opts, bar)
    finally:
        bar.close()
    residual_stored, counts, _ = pair_residuals(edges, stored, n_sensors)
    residual_fresh, _, _ = pair_residuals(edges, fresh, n_sensors)
    sensors, warnings = {}, []
    for s, sensor_id in enumerate(ids):
        ref = None if reference_residual_mm is None else reference_residual_mm.get(sensor_id)
        limits = (max_rotation_deg, max_translation_mm, max_residual_growth_mm)
        sensors[sensor_id], notes = _check_sensor(
            s, sensor_id, s == m, fresh, stored, edges, residual_stored, residual_fresh, counts, ref, limits
        )
        warnings += notes
    flagged = [s for s in ids if sensors[s].moved and s != ids[m]]
    if n_sensors > 2 and len(flagged) == n_sensors - 1:
        warnings.append(f"every sensor moved relative to master {ids[m]}: the master itself has probably moved")
    return CalibrationCheck(master=ids[m], sensors=sensors, warnings=tuple(warnings))


def _check_sensor(
    s: int,
    sensor_id: str,
    is_master: bool,
    fresh: np.ndarray,
    stored: np.ndarray,
    edges: list[PairEdge],
    residual_stored: np.ndarray,
    residual_fresh: np.ndarray,
    counts: np.ndarray,
    ref: float | None,
    limits: tuple[float, float, float],
) -> tuple[SensorCheck, list[str]]:
    """One sensor's check against its stored pose: the correction a refit would make, and the warnings."""
    max_rotation_deg, max_translation_mm, max_residual_growth_mm = limits
    warnings = []
    if counts[s]:
        rot, trans = pose_difference(fresh[s], stored[s], sensor_points(edges, s))
    else:
        rot = trans = float("nan")
    reasons = []
    if not is_master and rot > max_rotation_deg:
        reasons.append(f"rotated {rot:.1f}° (> {max_rotation_deg:g}°)")
    if not is_master and trans > max_translation_mm:
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
    check = SensorCheck(
        sensor_id=sensor_id,
        residual_mm=float(residual_stored[s]),
        refit_residual_mm=float(residual_fresh[s]),
        reference_residual_mm=None if ref is None else float(ref),
        correction_rotation_deg=float(rot),
        correction_translation_mm=float(trans),
        n_points=int(counts[s]),
        moved=bool(reasons),
    )
    return check, warnings


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
