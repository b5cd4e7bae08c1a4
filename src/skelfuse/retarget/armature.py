"""A fixed-length armature fitted to one fused person: the one retargeting behind BVH, FBX and VMC.

Fused positions are free points: bone lengths wobble from frame to frame and nothing says how a segment is
turned about its own axis. Animation tools want the opposite: a skeleton with fixed bone offsets and, per
frame, a local rotation of every joint. This module turns the first into the second.

Cycle, per person: gather the person's frames → resample onto a uniform time grid, filling gaps (joints no
sensor saw) by linear interpolation in time (held at the ends) and marking them → bone lengths from the median
over frames → rest offsets in a T-pose (below) → per frame, in parent-before-child order (one loop over the 32
joints, numpy over frames): each joint's global rotation is fitted so its children land on the fused positions,
aiming from where forward kinematics (FK) actually put the joint, so that length errors do not accumulate
down a chain → local rotations ``L[j] = G[parent]ᵀ G[j]`` → FK → retargeting error against the fused
positions.

Rest pose (documented in docs/animation.md): a T-pose in the world axes (x, y, z; z up). The person faces
world -y with its left side towards +x; spine and neck point up (+z), arms straight out sideways (left arm
+x, right arm -x, palms down, thumbs forward), legs straight down (-z), feet forward (-y). The joints with
several children (pelvis, chest, head, wrists) keep their children's relative layout as measured on the
person (the median over frames, in a frame built from the children), turned so that the pelvis's and the
chest's left-right axes are +x and their up axes +z, the face looks to -y and the hands point along the arms.
All local rotations are identity in this rest pose. The root (pelvis) carries the translation.

Rotations per joint:

- one child: the swing that takes the rest bone direction to the fitted bone direction, the twist carried
  over from the parent (minimal rotation); for the upper arms and thighs the twist is taken from the child
  geometry instead: the elbow's (knee's) bend plane fixes the roll of the upper arm (thigh), so the
  elbow/knee bend as a hinge about its rest axis. Near straight limbs (bend < 10°) the bend plane is
  undefined and the minimal-rotation twist is kept, blended in up to 30°.
- several children (pelvis, chest, head, wrists): the best-fit rotation (Kabsch) of the rest offsets of all
  children onto the fused children.
- no child (hand tips, thumbs, feet, face points): identity (nothing in the data turns them).
- With ``orientations`` (the fused orientations, (F, 32, 4) w, x, y, z, world frame) a single-child
  joint's twist is taken from them instead: the constant rotation between our fitted segment frame and the
  given orientation is estimated per person and joint (its chordal mean over frames), and where it is
  consistent over frames (spread < 30°) the twist of the given orientation replaces ours; the bone direction
  is always ours. This needs no knowledge of the k4abt axis convention, only that the orientation of joint j
  turns with the segment from j to its child.

Units: millimetres, world axes (z up). Exporters convert (see :mod:`skelfuse.export.bvh`). The rotation
algebra (axis-angle, Kabsch, quaternions) is in :mod:`skelfuse.retarget.rotations`.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from skelfuse.retarget.rotations import (
    axis_angle_matrix,
    continuous_quaternions,
    kabsch,
    minimal_rotation,
    quaternion_to_matrix,
    unit,
)
from skelfuse.schema.errors import DataError
from skelfuse.schema.frames import FusedFrame
from skelfuse.schema.skeleton import EVAL_JOINTS, JOINT_GROUPS, N_JOINTS, PARENTS, J

REST_FORWARD = np.array([0.0, -1.0, 0.0])
"""The direction the rest pose faces, world axes."""
REST_LEFT = np.array([1.0, 0.0, 0.0])
REST_UP = np.array([0.0, 0.0, 1.0])

CHILDREN: tuple[tuple[int, ...], ...] = tuple(
    tuple(int(c) for c in np.flatnonzero(PARENTS == j)) for j in range(N_JOINTS)
)
"""Children of every joint, in joint order."""

LEAVES = np.array([len(c) == 0 for c in CHILDREN])
"""Joints without children (hand tips, thumbs, feet, face points)."""

# Rest direction of each single-child bone, by child joint (world axes of the rest pose).
_REST_DIRECTION = {
    "SPINE_CHEST": REST_UP,
    "HEAD": REST_UP,
    "SHOULDER_LEFT": REST_LEFT,
    "ELBOW_LEFT": REST_LEFT,
    "WRIST_LEFT": REST_LEFT,
    "HANDTIP_LEFT": REST_LEFT,
    "SHOULDER_RIGHT": -REST_LEFT,
    "ELBOW_RIGHT": -REST_LEFT,
    "WRIST_RIGHT": -REST_LEFT,
    "HANDTIP_RIGHT": -REST_LEFT,
    "KNEE_LEFT": -REST_UP,
    "ANKLE_LEFT": -REST_UP,
    "FOOT_LEFT": REST_FORWARD,
    "KNEE_RIGHT": -REST_UP,
    "ANKLE_RIGHT": -REST_UP,
    "FOOT_RIGHT": REST_FORWARD,
}


@dataclass(frozen=True)
class _Cluster:
    """A joint with several children: how its canonical frame is built from the children (per frame)."""

    joint: int
    primary: tuple[tuple[int, ...], tuple[int, ...]]  # (plus joints, minus joints): mean(plus) - mean(minus)
    primary_axis: np.ndarray  # where the primary vector points in the rest pose
    secondary: tuple[tuple[int, ...], tuple[int, ...]]
    secondary_axis: np.ndarray


_CLUSTERS = (
    _Cluster(
        J["PELVIS"],
        ((J["HIP_LEFT"],), (J["HIP_RIGHT"],)),
        REST_LEFT,
        ((J["SPINE_NAVEL"],), ()),
        REST_UP,
    ),
    _Cluster(
        J["SPINE_CHEST"],
        ((J["CLAVICLE_LEFT"],), (J["CLAVICLE_RIGHT"],)),
        REST_LEFT,
        ((J["NECK"],), ()),
        REST_UP,
    ),
    _Cluster(
        J["HEAD"],
        ((J["EYE_LEFT"], J["EAR_LEFT"]), (J["EYE_RIGHT"], J["EAR_RIGHT"])),
        REST_LEFT,
        ((J["NOSE"],), (J["EAR_LEFT"], J["EAR_RIGHT"])),
        REST_FORWARD,
    ),
    _Cluster(J["WRIST_LEFT"], ((J["HAND_LEFT"],), ()), REST_LEFT, ((J["THUMB_LEFT"],), ()), REST_FORWARD),
    _Cluster(J["WRIST_RIGHT"], ((J["HAND_RIGHT"],), ()), -REST_LEFT, ((J["THUMB_RIGHT"],), ()), REST_FORWARD),
)

# Hinges whose bend plane sets the roll of the segment above them: segment joint → (hinge child, the
# hinge's child, bend axis in the segment's rest frame: rest bone direction × rest direction of the bent child).
_HINGE_TWIST = {
    J["SHOULDER_LEFT"]: (J["ELBOW_LEFT"], J["WRIST_LEFT"], np.cross(REST_LEFT, REST_FORWARD)),
    J["SHOULDER_RIGHT"]: (J["ELBOW_RIGHT"], J["WRIST_RIGHT"], np.cross(-REST_LEFT, REST_FORWARD)),
    J["HIP_LEFT"]: (J["KNEE_LEFT"], J["ANKLE_LEFT"], np.cross(-REST_UP, -REST_FORWARD)),
    J["HIP_RIGHT"]: (J["KNEE_RIGHT"], J["ANKLE_RIGHT"], np.cross(-REST_UP, -REST_FORWARD)),
}
_HINGE_MIN_DEG = 10.0  # below this bend the plane is noise: keep the minimal-rotation twist
_HINGE_FULL_DEG = 30.0  # above this bend the plane sets the twist fully
_ORIENTATION_MAX_SPREAD_DEG = 30.0  # an orientation whose offset to our frame varies more is not used
_SNAP_FRACTION = 0.05  # resampling: a sample this close (share of a step) to a grid time is used as it is
_LEAF_TAIL_FRACTION = 0.5  # End Site / bone tail of a leaf joint: this fraction of its own bone, along it
_MIN_LEAF_TAIL_MM = 20.0

BODY_GROUP = "body"
"""The 16 evaluation joints of the paper (:data:`skelfuse.schema.skeleton.EVAL_JOINTS`)."""


# ----------------------------------------------------------------------------------------------------
# The records.


@dataclass(frozen=True)
class PersonTake:
    """One person's fused positions over a take, as the fused frames gave them (not resampled).

    times_s : (F,) seconds; positions : (F, 32, 3) mm world, NaN where unknown (including frames where the
    person was absent between its first and last appearance); orientations : (F, 32, 4) or None.
    """

    track_id: int
    times_s: np.ndarray
    positions: np.ndarray
    orientations: np.ndarray | None = None


@dataclass(frozen=True)
class Armature:
    """A fixed skeleton: the k4abt hierarchy with one person's bone offsets in the T-pose rest.

    offsets : (32, 3) mm, each joint's rest offset from its parent, world axes of the rest pose (row 0 zero)
    leaf_tails : (32, 3) mm, the tail of each leaf joint's bone in its own frame (BVH End Site), zero elsewhere
    """

    offsets: np.ndarray
    leaf_tails: np.ndarray

    @property
    def bone_lengths(self) -> np.ndarray:
        """(32,) mm; 0 for the root."""
        return np.linalg.norm(self.offsets, axis=-1)


@dataclass(frozen=True)
class FittedMotion:
    """One person's armature and its per-frame rotations, on a uniform time grid.

    times_s : (F,) uniform, step ``frame_time_s``
    root_positions : (F, 3) mm world
    local_rotations : (F, 32, 3, 3): ``G[j] = G[parent] @ L[j]`` (root: ``G[0] = L[0]``)
    global_rotations : (F, 32, 3, 3)
    positions : (F, 32, 3) mm, forward kinematics of the armature (what an exported file reproduces)
    targets : (F, 32, 3) mm, the fused positions on the grid, gaps filled (what was fitted)
    filled : (F, 32) bool, True where the fused data had no value for that joint near that time
    """

    track_id: int
    armature: Armature
    times_s: np.ndarray
    frame_time_s: float
    root_positions: np.ndarray
    local_rotations: np.ndarray
    global_rotations: np.ndarray
    positions: np.ndarray
    targets: np.ndarray
    filled: np.ndarray

    @property
    def n_frames(self) -> int:
        return int(self.times_s.shape[0])

    def retargeting_error(self) -> dict[str, dict[str, float]]:
        """FK versus fused distance per joint group, mm: ``{group: {"median", "p90", "n"}}``.

        Only joint-frames the fused data held (not filled) count. Groups: the paper's three joint groups,
        ``"body"`` (their 16 joints) and ``"all"`` (all 32 joints, hands and face included).
        """
        return retargeting_error(self.positions, self.targets, self.filled)


def retargeting_error(positions: np.ndarray, targets: np.ndarray, filled: np.ndarray) -> dict[str, dict[str, float]]:
    """Distance statistics (median, p90, count) between FK ``positions`` and fused ``targets`` per group."""
    dist = np.linalg.norm(positions - targets, axis=-1)
    valid = ~filled & np.isfinite(dist)
    groups = {**JOINT_GROUPS, BODY_GROUP: EVAL_JOINTS, "all": np.arange(N_JOINTS)}
    out: dict[str, dict[str, float]] = {}
    for name, idx in groups.items():
        values = dist[:, idx][valid[:, idx]]
        if values.size:
            out[name] = {
                "median": float(np.median(values)),
                "p90": float(np.percentile(values, 90)),
                "n": float(values.size),
            }
        else:
            out[name] = {"median": float("nan"), "p90": float("nan"), "n": 0.0}
    return out


# ----------------------------------------------------------------------------------------------------
# Gathering and resampling.


def person_takes(frames: Sequence[FusedFrame]) -> list[PersonTake]:
    """Split fused frames into one :class:`PersonTake` per track id, ordered by track id.

    Frames are sorted by time; each person spans its first to last appearance, NaN where it was absent.
    ``orientations`` come from ``FusedFrame.orientations`` where frames carry them (an optional
    field, read with ``getattr``), else None.
    """
    if not frames:
        raise DataError("no fused frames to export; was the take empty or the file unreadable?")
    ordered = sorted(frames, key=lambda f: f.time_us)
    times = np.array([f.time_us for f in ordered], dtype=np.int64)
    ids = sorted({int(t) for f in ordered for t in np.asarray(f.track_ids)})
    takes = []
    for track_id in ids:
        rows = [np.flatnonzero(np.asarray(f.track_ids) == track_id) for f in ordered]
        present = np.array([r.size > 0 for r in rows])
        first, last = np.flatnonzero(present)[[0, -1]]
        positions = np.full((last - first + 1, N_JOINTS, 3), np.nan)
        orientations = np.full((last - first + 1, N_JOINTS, 4), np.nan)
        any_orientation = False
        for k in range(first, last + 1):
            if rows[k].size:
                positions[k - first] = np.asarray(ordered[k].positions, dtype=np.float64)[rows[k][0]]
                frame_orientations = getattr(ordered[k], "orientations", None)
                if frame_orientations is not None:
                    orientations[k - first] = np.asarray(frame_orientations, dtype=np.float64)[rows[k][0]]
                    any_orientation = True
        takes.append(
            PersonTake(
                track_id,
                (times[first : last + 1] - times[0]) * 1e-6,
                positions,
                orientations if any_orientation else None,
            )
        )
    return takes


def resample(
    times_s: np.ndarray, values: np.ndarray, *, fps: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Put (F, 32, C) samples with NaN gaps onto a uniform grid; fill gaps; mark them.

    The grid starts at the first time, steps ``1 / fps`` (default: the median step of ``times_s``) and
    ends at or before the last time. A valid sample within 5 % of a step of a grid time is taken as it is;
    elsewhere each joint is interpolated linearly in time between its valid samples and held constant before
    its first and after its last one; a joint never seen stays NaN.

    Returns
    -------
    grid_s : (G,); values on the grid : (G, 32, C); filled : (G, 32) True where no valid sample of that
    joint lies within half a step of the grid time.
    """
    times_s = np.asarray(times_s, dtype=np.float64)
    if times_s.ndim != 1 or times_s.shape[0] != values.shape[0] or times_s.shape[0] < 1:
        raise DataError(f"times ({times_s.shape}) and samples ({values.shape}) disagree or are empty")
    if np.any(np.diff(times_s) <= 0):
        raise DataError("frame times must increase strictly; sort the frames and drop duplicates first")
    if fps is not None:
        step = 1.0 / fps
    elif times_s.shape[0] > 1:
        step = float(np.median(np.diff(times_s)))
    else:
        step = 1.0 / 30.0
    n = int(np.floor((times_s[-1] - times_s[0]) / step + 1e-6)) + 1
    grid = times_s[0] + step * np.arange(n)
    out = np.full((n, *values.shape[1:]), np.nan)
    filled = np.ones((n, values.shape[1]), dtype=bool)
    valid = np.isfinite(values).all(axis=-1)
    for joint in range(values.shape[1]):  # np.interp is 1-D: one call per joint and channel
        ok = valid[:, joint]
        if not ok.any():
            continue
        t_ok = times_s[ok]
        for c in range(values.shape[2]):
            out[:, joint, c] = np.interp(grid, t_ok, values[ok, joint, c])
        right = np.minimum(np.searchsorted(t_ok, grid), t_ok.size - 1)
        left = np.maximum(right - 1, 0)
        nearest = np.where(np.abs(grid - t_ok[left]) <= np.abs(grid - t_ok[right]), left, right)
        gap = np.abs(grid - t_ok[nearest])
        filled[:, joint] = gap > 0.5 * step + 1e-9
        # A sample within 5 % of a step of its grid time (timestamps rounded to µs, clock jitter) is taken as
        # it is, not interpolated: the fused values reach the file unchanged.
        snap = gap <= _SNAP_FRACTION * step
        out[snap, joint] = values[ok][nearest[snap], joint]
    return grid, out, filled


# ----------------------------------------------------------------------------------------------------
# The armature.


def _default_offsets() -> np.ndarray:
    """Offsets of the simulator's 1750 mm body, turned into the rest axes (for bones the data never showed)."""
    from skelfuse.sim.gestures import rest_offsets as sim_rest_offsets  # the simulator's scipy: only when used

    sim = sim_rest_offsets(1750.0)  # body frame: x forward, y left, z up
    return sim[:, 0:1] * REST_FORWARD + sim[:, 1:2] * REST_LEFT + sim[:, 2:3] * REST_UP


def _side_vector(
    positions: np.ndarray, spec: tuple[tuple[int, ...], tuple[int, ...]], origin: np.ndarray
) -> np.ndarray:
    plus, minus = spec
    vec = positions[:, list(plus)].mean(axis=1)
    vec = vec - (positions[:, list(minus)].mean(axis=1) if minus else origin)
    return vec


def _frame_from(
    primary: np.ndarray, secondary: np.ndarray, primary_axis: np.ndarray, secondary_axis: np.ndarray
) -> np.ndarray:
    """World-from-canonical rotations (F, 3, 3) mapping the rest axes onto the per-frame vectors."""
    e1 = unit(primary)
    e2 = unit(secondary - np.sum(secondary * e1, axis=-1, keepdims=True) * e1)
    e3 = np.cross(e1, e2)
    world = np.stack([e1, e2, e3], axis=-1)
    rest = np.stack([primary_axis, secondary_axis, np.cross(primary_axis, secondary_axis)], axis=-1)
    return world @ rest.T


def build_armature(targets: np.ndarray) -> Armature:
    """The rest armature of one person from its (F, 32, 3) fused positions (gaps may be NaN).

    Bone lengths are medians over frames; a bone never seen takes the simulator body's length and
    direction (``skelfuse.sim.gestures.rest_offsets``, 1750 mm).
    """
    default = _default_offsets()
    lengths = np.linalg.norm(targets - targets[:, PARENTS.clip(0)], axis=-1)  # (F, 32); root row is 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # "All-NaN slice": a bone never seen, handled below
        median_length = np.nanmedian(lengths, axis=0)
    median_length[0] = 0.0
    unseen = ~np.isfinite(median_length) | (median_length < 1e-6)
    unseen[0] = False
    median_length = np.where(unseen, np.linalg.norm(default, axis=-1), median_length)

    offsets = np.zeros((N_JOINTS, 3))
    for child_name, direction in _REST_DIRECTION.items():
        offsets[J[child_name]] = direction
    for cluster in _CLUSTERS:
        kids = list(CHILDREN[cluster.joint])
        origin = targets[:, cluster.joint]
        frame = _frame_from(
            _side_vector(targets, cluster.primary, origin),
            _side_vector(targets, cluster.secondary, origin),
            cluster.primary_axis,
            cluster.secondary_axis,
        )
        local = np.einsum("fji,fkj->fki", frame, targets[:, kids] - origin[:, None])  # canonical axes
        ok = np.isfinite(local).all(axis=(1, 2))
        for k, kid in enumerate(kids):
            offsets[kid] = np.median(local[ok, k], axis=0) if ok.sum() else default[kid]
    for joint in range(1, N_JOINTS):
        if not np.any(offsets[joint]):
            offsets[joint] = default[joint]
    offsets[1:] = unit(offsets[1:]) * median_length[1:, None]
    tails = np.zeros((N_JOINTS, 3))
    tail_length = np.maximum(_LEAF_TAIL_FRACTION * median_length, _MIN_LEAF_TAIL_MM)
    tails[LEAVES] = unit(offsets[LEAVES]) * tail_length[LEAVES, None]
    return Armature(offsets=offsets, leaf_tails=tails)


def forward_kinematics(
    armature: Armature, root_positions: np.ndarray, local_rotations: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Joint positions (F, 32, 3) and global rotations (F, 32, 3, 3) of the armature.

    ``p[j] = p[parent] + G[parent] @ offset[j]``, ``G[j] = G[parent] @ L[j]``; one loop over the joints
    (parents come first in k4abt order), numpy over frames.
    """
    n = local_rotations.shape[0]
    positions = np.zeros((n, N_JOINTS, 3))
    rotations = np.zeros((n, N_JOINTS, 3, 3))
    positions[:, 0] = root_positions
    rotations[:, 0] = local_rotations[:, 0]
    for joint in range(1, N_JOINTS):
        parent = PARENTS[joint]
        positions[:, joint] = positions[:, parent] + rotations[:, parent] @ armature.offsets[joint]
        rotations[:, joint] = rotations[:, parent] @ local_rotations[:, joint]
    return positions, rotations


def _hinge_twist(rotation: np.ndarray, bone_dir: np.ndarray, bent_dir: np.ndarray, rest_axis: np.ndarray) -> np.ndarray:
    """Roll ``rotation`` (F, 3, 3) about ``bone_dir`` so its rest bend axis lies along the bend normal."""
    normal = np.cross(bone_dir, bent_dir)
    sin_bend = np.linalg.norm(normal, axis=-1)
    normal = unit(normal)
    current = rotation @ rest_axis
    angle = np.arctan2(np.sum(bone_dir * np.cross(current, normal), axis=-1), np.sum(current * normal, axis=-1))
    lo, hi = np.sin(np.radians(_HINGE_MIN_DEG)), np.sin(np.radians(_HINGE_FULL_DEG))
    weight = np.clip((sin_bend - lo) / (hi - lo), 0.0, 1.0)
    angle = np.where(np.isfinite(angle), angle * weight, 0.0)
    return axis_angle_matrix(np.nan_to_num(bone_dir), angle) @ rotation


def _orientation_twist(
    rotation: np.ndarray, bone_dir: np.ndarray, rest_dir: np.ndarray, given: np.ndarray
) -> np.ndarray:
    """Replace the twist of ``rotation`` (F, 3, 3) by the twist of the given orientations (F, 3, 3).

    The constant offset ``C = given^T rotation`` is estimated as the chordal mean over frames; where it is
    consistent (spread below the limit) the candidate ``given @ C`` is swung onto the bone direction.
    """
    ok = np.isfinite(given).all(axis=(1, 2)) & np.isfinite(rotation).all(axis=(1, 2))
    if ok.sum() < 3:
        return rotation
    offsets = np.swapaxes(given[ok], -1, -2) @ rotation[ok]
    u, _, vt = np.linalg.svd(offsets.mean(axis=0))
    mean = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    spread = np.degrees(
        np.arccos(np.clip((np.trace(np.swapaxes(offsets, -1, -2) @ mean, axis1=-2, axis2=-1) - 1) / 2, -1, 1))
    )
    if np.median(spread) > _ORIENTATION_MAX_SPREAD_DEG:
        return rotation
    candidate = given[ok] @ mean
    swung = minimal_rotation(unit(candidate @ rest_dir), bone_dir[ok]) @ candidate
    out = rotation.copy()
    out[ok] = swung
    return out


def solve_rotations(armature: Armature, targets: np.ndarray, *, given: np.ndarray | None = None) -> np.ndarray:
    """Local joint rotations (F, 32, 3, 3) that pose ``armature`` onto ``targets`` (F, 32, 3) mm world.

    The per-frame half of the retargeting (module docstring), shared by the file exports and the live VMC
    stream. Frames are independent, except that ``given`` orientations (F, 32, 3, 3) need several frames
    to calibrate their offset. A joint whose child is unknown (NaN) keeps its parent's rotation (local
    identity); the root must be finite.
    """
    offsets = armature.offsets
    n = targets.shape[0]
    fk = np.zeros((n, N_JOINTS, 3))
    rot = np.zeros((n, N_JOINTS, 3, 3))
    fk[:, 0] = targets[:, 0]
    identity = np.broadcast_to(np.eye(3), (n, 3, 3))
    for joint in range(N_JOINTS):
        parent_rot = identity if joint == 0 else rot[:, PARENTS[joint]]
        kids = CHILDREN[joint]
        if not kids:
            rot[:, joint] = parent_rot
            continue
        aim = targets[:, list(kids)] - fk[:, joint, None]  # from where FK put this joint
        if len(kids) == 1:
            kid = kids[0]
            rest_dir = unit(offsets[kid])
            bone_dir = unit(aim[:, 0])
            fitted = minimal_rotation(parent_rot @ rest_dir, bone_dir) @ parent_rot
            if joint in _HINGE_TWIST:
                hinge, after, axis = _HINGE_TWIST[joint]
                fitted = _hinge_twist(fitted, bone_dir, unit(targets[:, after] - targets[:, hinge]), axis)
            if given is not None:
                fitted = _orientation_twist(fitted, bone_dir, rest_dir, given[:, joint])
            seen = np.isfinite(bone_dir).all(axis=-1)
            rot[:, joint] = np.where(seen[:, None, None], fitted, parent_rot)
        else:
            weights = np.isfinite(aim).all(axis=-1).astype(np.float64)
            fitted = kabsch(np.broadcast_to(offsets[list(kids)], aim.shape), aim, weights)
            rot[:, joint] = np.where((weights.sum(axis=-1) > 0)[:, None, None], fitted, parent_rot)
        for kid in kids:
            fk[:, kid] = fk[:, joint] + rot[:, joint] @ offsets[kid]
    local = rot.copy()
    local[:, 1:] = np.swapaxes(rot[:, PARENTS[1:]], -1, -2) @ rot[:, 1:]
    return local


def fit_motion(
    times_s: np.ndarray,
    positions: np.ndarray,
    *,
    orientations: np.ndarray | None = None,
    fps: float | None = None,
    track_id: int = 0,
) -> FittedMotion:
    """Fit the armature and its per-frame rotations to one person's fused positions.

    Parameters
    ----------
    times_s : (F,) strictly increasing seconds
    positions : (F, 32, 3) mm world (z up), NaN where unknown
    orientations : (F, 32, 4) w, x, y, z world quaternions (the fused orientations), optional: the
        twist of single-child segments is taken from them where they are consistent (module docstring)
    fps : the output rate; default the median rate of ``times_s``
    track_id : carried into the result

    Raises
    ------
    DataError
        When the pelvis was never seen (nothing to hang the armature on) or the input shapes are wrong.
    """
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[1:] != (N_JOINTS, 3):
        raise DataError(f"positions must be (frames, {N_JOINTS}, 3) mm, got {positions.shape}")
    grid, targets, filled = resample(times_s, positions, fps=fps)
    if not np.isfinite(targets[:, 0]).all():
        raise DataError(f"person {track_id}: the pelvis was never tracked, so no armature can be fitted")
    given = None
    if orientations is not None:
        _, quats, _ = resample(times_s, continuous_quaternions(orientations), fps=fps)
        given = quaternion_to_matrix(quats)
    armature = build_armature(targets)
    local = solve_rotations(armature, targets, given=given)
    n = grid.shape[0]
    positions_fk, rotations_fk = forward_kinematics(armature, targets[:, 0], local)
    return FittedMotion(
        track_id=track_id,
        armature=armature,
        times_s=grid,
        frame_time_s=float(grid[1] - grid[0]) if n > 1 else (1.0 / fps if fps else 1.0 / 30.0),
        root_positions=targets[:, 0].copy(),
        local_rotations=local,
        global_rotations=rotations_fk,
        positions=positions_fk,
        targets=targets,
        filled=filled | ~np.isfinite(targets).all(axis=-1),
    )


def fit_frames(frames: Sequence[FusedFrame], *, fps: float | None = None) -> list[FittedMotion]:
    """Fit every person of a sequence of fused frames (one :class:`FittedMotion` per track id)."""
    return [
        fit_motion(take.times_s, take.positions, orientations=take.orientations, fps=fps, track_id=take.track_id)
        for take in person_takes(frames)
    ]


def describe_error(error: dict[str, dict[str, float]]) -> str:
    """One line per group: ``body  median 4.1 mm  p90 9.0 mm``."""
    return "\n".join(
        f"{name:<11} median {stats['median']:6.1f} mm  p90 {stats['p90']:6.1f} mm  ({int(stats['n'])} joint-frames)"
        for name, stats in error.items()
    )


__all__ = [
    "Armature",
    "FittedMotion",
    "PersonTake",
    "build_armature",
    "fit_frames",
    "fit_motion",
    "forward_kinematics",
    "person_takes",
    "resample",
    "retargeting_error",
]
