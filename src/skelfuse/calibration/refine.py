"""Calibration refinement from a person walking through, on the depth-level fusion's person clouds.

The paper (Carraro et al., Sec. 3.3) refines its calibration by ICP on the clouds of a person walking through
the space. :func:`skelfuse.fusion.depth.icp.refine_poses_from_walk` is that algorithm (pure); this module gives
it its input and reports on it:

- :func:`walk_frames` turns the person clouds of a recording (``skelfuse record`` of a rig in depth or hybrid
  mode: the workers' ``.../clouds`` payloads) into instants holding one cloud per sensor (the biggest body a
  sensor saw: one walker), keeping instants seen by at least two sensors, evenly spread over the take;
- :func:`simulated_walk` makes the same from the simulator (a walking person, the paper's rig, capsule bodies
  ray-cast per sensor), with every sensor but the reference knocked off its true pose by a known amount, so
  the refinement can be scored against the truth (:func:`pose_errors`);
- :func:`refine_report` is the quality table: per sensor the correction applied, the ICP residual before and
  after, the points paired, the held-out gap before and after, the agreement of the two halves of the take,
  and a verdict.

Verdicts rest on evidence the ICP did not fit. The ICP residual is what the ICP minimizes, so it falls
whatever happens to the pose (it can fall while a sensor's true error grows). The
walk is split in two folds (alternate instants); each fold's refined pose is scored on the other fold's clouds
(:func:`heldout_gap_mm`: how far the sensor's points lie from the other sensors' points of the same instant),
against the starting pose on the same clouds. A sensor whose held-out gap does not fall by
:data:`MIN_HELDOUT_GAIN` is rated "no improvement" and keeps its starting pose; otherwise the agreement of the
two folds' poses rates it "improved", "check" or "bad". "improved" says the clouds line up better on
instants the ICP did not see, not that the pose is now exact.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from skelfuse.fusion.camera import Intrinsics
from skelfuse.fusion.depth.icp import IcpResult, refine_poses_from_walk, walk_normals
from skelfuse.fusion.transform import invert_transform, transform_points
from skelfuse.service.sim_clouds import sensor_person_clouds
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.rig import paper_rig
from skelfuse.wire.clouds import PersonCloudsFrame

MIN_POINTS = 200
"""A sensor's cloud with fewer points does not count as seeing the walker in that instant."""
GOOD_HALVES_DEG, GOOD_HALVES_MM = 0.5, 15.0
"""Verdict "improved" (the held-out gap fell) when the poses refined on each fold also agree within these."""
CHECK_HALVES_DEG, CHECK_HALVES_MM = 1.5, 40.0
"""Verdict "check" (improved, but the folds disagree) up to these; beyond: "bad" (the walk does not pin the
pose down)."""
MIN_HELDOUT_GAIN = 0.05
"""A refined pose counts as an improvement only if it lowers the held-out gap by this fraction (and by
:data:`MIN_HELDOUT_GAIN_MM`): below that, the change is within what refitting noisy clouds gives from an
exact pose (from exact poses, refitting raises the gap: ``skelfuse calibrate refine --sim --perturb-deg 0
--perturb-mm 0``)."""
MIN_HELDOUT_GAIN_MM = 0.5
HELDOUT_GATE_MM = 150.0
"""Held-out gaps are capped here, so that points of body parts the other sensors do not see count as a
constant, not as an outlier that dominates the mean (wider than the ICP's 80 mm pairing gate, so that a pose
the ICP made worse still shows)."""
NO_IMPROVEMENT = "no improvement"


def walk_frames(
    clouds: Iterable[PersonCloudsFrame],
    sensor_ids: Sequence[str],
    *,
    tolerance_us: int,
    max_frames: int,
) -> list[list[np.ndarray]]:
    """Instants of a recording's person clouds: T lists of one (N, 3) sensor-frame cloud per sensor (empty
    where a sensor saw nobody), instants seen by at least two sensors, at most ``max_frames`` evenly spread.

    Frames of the sensors are matched by device time within ``tolerance_us`` (wired sync: the subordinates'
    delays are below it), as the fusion node groups them.
    """
    column = {sid: i for i, sid in enumerate(sensor_ids)}
    stamped = sorted(
        (frame.device_timestamp_us, column[frame.sensor_id], frame) for frame in clouds if frame.sensor_id in column
    )
    instants: list[list[np.ndarray]] = []
    anchor = None
    for time_us, s, frame in stamped:
        if anchor is None or time_us - anchor > tolerance_us:
            anchor = time_us
            instants.append([np.zeros((0, 3)) for _ in sensor_ids])
        biggest = max(frame.clouds, key=len, default=np.zeros((0, 3)))
        if len(biggest) > len(instants[-1][s]):
            instants[-1][s] = biggest
    seen = [frame for frame in instants if sum(len(c) >= MIN_POINTS for c in frame) >= 2]
    if len(seen) > max_frames:
        seen = [seen[i] for i in np.linspace(0, len(seen) - 1, max_frames).round().astype(int)]
    return seen


@dataclass(frozen=True)
class SimulatedWalk:
    """A simulated walk-through for scoring the refinement against the truth."""

    frames: list[list[np.ndarray]]
    sensor_ids: tuple[str, ...]
    true_poses: np.ndarray
    perturbed_poses: np.ndarray
    reference: int


def _rotation(axis: np.ndarray, degrees: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    angle = np.radians(degrees)
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def simulated_walk(
    *, n_frames: int, perturb_deg: float, perturb_mm: float, seed: int = 0, n_sensors: int = 4, voxel_mm: float = 15.0
) -> SimulatedWalk:
    """A person walking (``walking`` gesture, 4 s) seen by the paper's rig, ``n_frames`` instants evenly
    spread, each sensor's cloud ray-cast from the true pose (NFOV 2x2 binned, the simulator's depth noise);
    every sensor but the first (the reference) perturbed about its own centre by ``perturb_deg`` about a random
    axis and ``perturb_mm`` along a random direction."""
    rng = np.random.default_rng(seed)
    sensors = paper_rig(n_sensors)
    motion = make_gesture("walking", duration_s=4.0, seed=seed)
    picks = np.linspace(0, motion.n_frames - 1, n_frames).round().astype(int)
    binned = Intrinsics.azure_kinect_nfov(binned=True)
    frames = []
    for t in picks:
        row = []
        for s, sensor in enumerate(sensors):
            clouds = sensor_person_clouds(
                sensor,
                motion.positions[t][None],
                voxel_mm=voxel_mm,
                intrinsics=binned,
                rng=np.random.default_rng([seed, s, int(t)]),
            )
            row.append(clouds.get(0, np.zeros((0, 3))))
        frames.append(row)
    true_poses = np.stack([s.world_from_sensor for s in sensors])
    perturbed = true_poses.copy()
    for s in range(1, n_sensors):
        rotation = _rotation(rng.normal(size=3), perturb_deg)
        direction = rng.normal(size=3)
        perturbed[s, :3, :3] = rotation @ true_poses[s, :3, :3]
        perturbed[s, :3, 3] = true_poses[s, :3, 3] + perturb_mm * direction / np.linalg.norm(direction)
    return SimulatedWalk(frames, tuple(s.sensor_id for s in sensors), true_poses, perturbed, 0)


CAPTURE_CENTRE_MM = np.array([0.0, 0.0, 1000.0])
"""Where the pose errors are measured: the paper rig's capture area centre, 1 m up (mm, world)."""


def pose_errors(poses: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(S,) rotation error, degrees, and (S,) displacement, mm, of the capture area's centre
    (:data:`CAPTURE_CENTRE_MM`) seen through ``poses`` instead of ``truth``: where a person standing there would
    be misplaced by each sensor (what fusion feels; a sensor's own position error is larger, by the lever of
    its distance)."""
    poses, truth = np.asarray(poses, np.float64), np.asarray(truth, np.float64)
    delta = np.einsum("sij,sjk->sik", poses, invert_transform(truth))
    cos = np.clip((np.trace(delta[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)
    moved = np.einsum("sij,j->si", delta[:, :3, :3], CAPTURE_CENTRE_MM) + delta[:, :3, 3]
    return np.degrees(np.arccos(cos)), np.linalg.norm(moved - CAPTURE_CENTRE_MM, axis=1)


@dataclass(frozen=True)
class Refinement:
    """What :func:`refine` made of a walk."""

    sensor_ids: tuple[str, ...]
    reference: int
    before: np.ndarray
    after: np.ndarray
    results: list[IcpResult | None]
    halves: tuple[np.ndarray, np.ndarray] | None  # the poses refined on each fold (alternate instants)
    n_frames: int
    heldout_before_mm: np.ndarray  # (S,) held-out gap of the starting poses (mean over the two folds)
    heldout_after_mm: np.ndarray  # (S,) held-out gap of each fold's refined pose on the other fold
    improved: np.ndarray  # (S,) bool: the held-out gap fell enough; else ``after`` keeps the starting pose


def heldout_gap_mm(frames: list[list[np.ndarray]], poses: np.ndarray, sensor: int) -> float:
    """Mean distance, mm, from each of ``sensor``'s points (through its pose) to the nearest point the other
    sensors saw in the same instant (through theirs), capped at :data:`HELDOUT_GATE_MM`; NaN when no instant
    has the sensor and another one seeing the person."""
    gaps = []
    for clouds in frames:
        mine = np.asarray(clouds[sensor], dtype=np.float64).reshape(-1, 3)
        others = [
            transform_points(poses[j], np.asarray(c, np.float64).reshape(-1, 3))
            for j, c in enumerate(clouds)
            if j != sensor and len(c) >= MIN_POINTS
        ]
        if len(mine) < MIN_POINTS or not others:
            continue
        tree = cKDTree(np.concatenate(others), balanced_tree=False)  # midpoint splits: faster, same distances
        distance, _ = tree.query(transform_points(poses[sensor], mine))
        gaps.append(np.minimum(distance, HELDOUT_GATE_MM))
    return float(np.concatenate(gaps).mean()) if gaps else float("nan")


def refine(
    frames: list[list[np.ndarray]], poses: np.ndarray, sensor_ids: Sequence[str], *, reference: int, passes: int = 3
) -> Refinement:
    """:func:`refine_poses_from_walk` on the whole walk and on each fold (alternate instants); each fold's pose
    is scored on the other fold (:func:`heldout_gap_mm`), and a sensor keeps its starting pose unless that
    held-out gap falls (module docstring)."""
    if len(frames) < 4:
        raise ValueError(
            f"{len(frames)} instant(s) seen by two sensors or more; a refinement needs a walk-through of at least "
            "4 (two folds of 2: one to fit, one to check)"
        )
    poses = np.asarray(poses, dtype=np.float64)
    normals = walk_normals(frames)  # once: the folds refine the same clouds again
    whole, results = refine_poses_from_walk(frames, poses, reference=reference, passes=passes, normals=normals)
    folds = (frames[0::2], frames[1::2])
    fitted = (
        refine_poses_from_walk(folds[0], poses, reference=reference, passes=passes, normals=normals[0::2])[0],
        refine_poses_from_walk(folds[1], poses, reference=reference, passes=passes, normals=normals[1::2])[0],
    )
    n_sensors = poses.shape[0]
    before, after = np.full(n_sensors, np.nan), np.full(n_sensors, np.nan)
    for s in range(n_sensors):
        if s == reference or results[s] is None:
            continue
        before[s] = np.mean([heldout_gap_mm(folds[1 - k], poses, s) for k in range(2)])
        after[s] = np.mean([heldout_gap_mm(folds[1 - k], fitted[k], s) for k in range(2)])
    with np.errstate(invalid="ignore"):
        improved = (after < (1.0 - MIN_HELDOUT_GAIN) * before) & (after < before - MIN_HELDOUT_GAIN_MM)
    kept = np.where(improved[:, None, None], whole, poses)
    kept[reference] = poses[reference]
    return Refinement(tuple(sensor_ids), reference, poses, kept, results, fitted, len(frames), before, after, improved)


def verdict(halves_deg: float, halves_mm: float, *, improved: bool = True) -> str:
    """ "no improvement" unless the held-out gap fell; then the agreement of the two folds' poses decides."""
    if not improved:
        return NO_IMPROVEMENT
    if not (np.isfinite(halves_deg) and np.isfinite(halves_mm)):
        return "check"
    if halves_deg <= GOOD_HALVES_DEG and halves_mm <= GOOD_HALVES_MM:
        return "improved"
    if halves_deg <= CHECK_HALVES_DEG and halves_mm <= CHECK_HALVES_MM:
        return "check"
    return "bad"


def refine_report(refinement: Refinement, truth: np.ndarray | None = None) -> tuple[str, dict[str, str]]:
    """The quality table (markdown) and each sensor's verdict; with ``truth`` also the pose error against it
    before and after. Millimetres of a pose (correction, agreement, error) are those of the capture area's
    centre (:func:`pose_errors`)."""
    r = refinement
    moved_deg, moved_mm = pose_errors(r.after, r.before)
    if r.halves is not None:
        halves_deg, halves_mm = pose_errors(r.halves[0], r.halves[1])
    else:
        halves_deg = halves_mm = np.full(len(r.sensor_ids), np.nan)
    header = (
        "| sensor | correction ° / mm | ICP residual before → after (fitted), mm | pairs | "
        "held-out gap before → after, mm | folds agree ° / mm | verdict |"
    )
    rule = "|---|---|---|---:|---|---|---|"
    if truth is not None:
        err_before = pose_errors(r.before, truth)
        err_after = pose_errors(r.after, truth)
        header += " error vs truth, before → after, ° / mm |"
        rule += "---|"
    lines = [header, rule]
    verdicts = {}
    for s, sensor_id in enumerate(r.sensor_ids):
        result = r.results[s]
        if s == r.reference:
            cells = [sensor_id + " (reference)", "—", "—", "—", "—", "—", "reference"]
            verdicts[sensor_id] = "reference"
        elif result is None:
            cells = [sensor_id, "—", "—", "0", "—", "—", "bad (saw too little)"]
            verdicts[sensor_id] = "bad"
        else:
            v = verdict(float(halves_deg[s]), float(halves_mm[s]), improved=bool(r.improved[s]))
            verdicts[sensor_id] = v
            cells = [
                sensor_id,
                f"{moved_deg[s]:.2f} / {moved_mm[s]:.1f}",
                f"{result.rmse_before_mm:.1f} → {result.rmse_after_mm:.1f}",
                str(result.n_pairs),
                f"{r.heldout_before_mm[s]:.1f} → {r.heldout_after_mm[s]:.1f}",
                "—" if np.isnan(halves_deg[s]) else f"{halves_deg[s]:.2f} / {halves_mm[s]:.1f}",
                v + (" (pose kept)" if v == NO_IMPROVEMENT else ""),
            ]
        if truth is not None:
            cells.append(
                f"{err_before[0][s]:.2f} / {err_before[1][s]:.1f} → {err_after[0][s]:.2f} / {err_after[1][s]:.1f}"
            )
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines), verdicts
