"""``skelfuse eval real``: an honest report on any real recording of N >= 2 sensors, without ground truth.

Cycle (:func:`run_rig_eval`)::

    take = open_inputs(specs, ...)                       # any format, frames matched in time
    poses = calibration file | --auto-calibrate | --registered | the MCAP's metadata
    views  (T, S, 32, 3) world, confidence (T, S, 32)    # every instant, each sensor's first body
    fused  (T, 32, 3) per preset                         # the product's own offline fusion (GroupFuser)
    metrics per joint group (torso, arms, hands, legs, head) and per preset against every single view

With ``--auto-calibrate`` the skeleton calibration is fitted on the first half of the instants and every
metric is computed on the second half only, so agreement is not flattered by the fit (the fusion runs
over the whole take; its filters are warm when the second half starts).

The metrics (all in mm unless said; docs/evaluation.md says what each can and cannot show):

``jitter``
    median |p[t+1] - 2 p[t] + p[t-1]| over frames and the group's joints (mm/frame²): trembling and jumps.
``lag``
    per view, the shift (frames) maximizing the correlation of the fused and the view's joint velocities
    over +-10 frames; positive = the fused output is late. A filter that lags shows here.
``agreement``
    median distance of the fused joint to each view's same joint where that view says MEDIUM. Meaningless
    where confidence was assumed (the report says so): then it is the distance to every view.
``gross``
    share of joint-frames where the fused joint lies > 100 mm from every view that has the joint.
``mirrored``
    frames whose left/right axis points against the majority of the views (:func:`eval.real.mirrored_frames`).
``view mirroring``
    per view, the share of instants skelfuse's realignment found it mirrored, and (N >= 3) the share where it
    points against the majority of the others (:mod:`skelfuse.eval.view_mirroring`): the rig's own mirroring
    rate, to set against ``skelfuse eval robustness --mirroring-sweep``.
``dropouts``
    share of instants where some view has the group (not reported NONE) but the fused output has none.
``continuity``
    fused pelvis steps faster than a person moves, and episodes where the fused body followed one view away
    from its path (:mod:`skelfuse.eval.continuity`): a tracker failure the fusion followed, which the gross
    count cannot see (the fused joint sits on the failing view).
``causal / lag 3 / rts``
    a preset with the constant-velocity filter is reported three ways: the live filter's output (its name),
    the fixed-lag smoother at 3 instants (100 ms at 30 fps) and the fixed-interval RTS smoother of offline
    fusion and exports (:mod:`skelfuse.fusion.smoother`).
``orientation``
    per group, the median twist about the bone between each view's joint orientations and the fused ones; per
    aimed joint, the median full angle between them (pooled over the views and per view), beside the median
    angle between the views' own frames (no fused frame can be close to views that disagree with each other).
``track_ids``
    distinct track ids the fused person had over the take (1 = never lost).
``leave-one-out`` (N >= 3)
    fuse all views but one (the pure fuser, same preset) and measure the distance to the held-out view's
    MEDIUM joints, next to each remaining single view's distance to the same joints.

Cross-view metrics cannot see errors every view shares (a tracker's common bias, a person all sensors see
from behind): they are lower bounds on the true error. The simulator (``skelfuse eval paper``) has truth.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.calibration.skeleton import calibrate_from_skeletons
from skelfuse.calibration.takes import take_arrays
from skelfuse.eval.continuity import continuity
from skelfuse.eval.metrics import nan_for_none, view_orientation_agreement
from skelfuse.eval.real import fuse_views, mirrored_frames
from skelfuse.eval.view_mirroring import view_mirroring
from skelfuse.fusion import presets
from skelfuse.fusion.orientation import quat_angle_deg, views_to_world
from skelfuse.fusion.presets import preset
from skelfuse.fusion.transform import apply_transform
from skelfuse.recording.inputs import InputTake
from skelfuse.recording.offline import fuse_recording
from skelfuse.schema.errors import DataError
from skelfuse.schema.skeleton import BODY_REGIONS, JOINT_NAMES, N_JOINTS, ORIENTATION_AIMED, Confidence, J

REPORT_GROUPS: dict[str, np.ndarray] = {
    name: np.concatenate([BODY_REGIONS[r] for r in regions])
    for name, regions in {
        "torso": ("torso",),
        "arms": ("arm",),
        "hands": ("hand",),
        "legs": ("knee", "foot"),
        "head": ("head", "face"),
    }.items()
}
"""The report's joint groups, unions of the body regions (schema): every joint in exactly one."""

DEFAULT_PRESETS = presets.COMPARED_PRESETS
GROSS_MM = 100.0
MAX_LAG_FRAMES = 10
TRACE_JOINT = "WRIST_RIGHT"


# --------------------------------------------------------------------------------------------- metrics


def median_jitter(positions: np.ndarray, joints: np.ndarray) -> float:
    """Median |second difference| (mm/frame²) over frames and ``joints`` of (T, 32, 3); NaN-triples skipped."""
    p = np.asarray(positions, dtype=np.float64)[:, joints]
    if len(p) < 3:
        return math.nan
    second = np.linalg.norm(p[2:] - 2 * p[1:-1] + p[:-2], axis=-1)
    second = second[np.isfinite(second)]
    return float(np.median(second)) if second.size else math.nan


def velocity_lag(
    fused: np.ndarray, view: np.ndarray, joints: np.ndarray, max_lag: int = MAX_LAG_FRAMES, subframe: bool = False
) -> float:
    """The shift (frames) maximizing the correlation of fused and view velocities; + = fused is late.

    Velocities are first differences of the group's joints, pooled over joints and axes; frames with a NaN
    are left out per shift. NaN when fewer than 20 frames overlap at every shift. ``subframe``: the peak is
    refined by a parabola through the correlations at the best shift and its two neighbours (a timing
    measure that slow offsets between the two cannot move: they hardly change the velocities).
    """
    vf = np.diff(np.asarray(fused, dtype=np.float64)[:, joints], axis=0).reshape(len(fused) - 1, -1)
    vv = np.diff(np.asarray(view, dtype=np.float64)[:, joints], axis=0).reshape(len(view) - 1, -1)
    n = len(vf)
    shifts = np.arange(-max_lag, max_lag + 1)
    r = np.full(len(shifts), -np.inf)
    for k, shift in enumerate(shifts.tolist()):
        if abs(shift) >= n:  # no frame overlaps (a take shorter than the shifts)
            continue
        # fused[t + shift] against view[t]: a late fused output matches at a positive shift
        a = vf[max(shift, 0) : n + min(shift, 0)]
        b = vv[max(-shift, 0) : n + min(-shift, 0)]
        ok = np.isfinite(a) & np.isfinite(b)
        if ok.sum() < 20:
            continue
        x, y = a[ok], b[ok]
        denom = math.sqrt(float(np.sum(x * x)) * float(np.sum(y * y)))
        r[k] = float(np.sum(x * y)) / denom if denom > 0 else -math.inf
    if not np.isfinite(r).any():
        return math.nan
    best = int(np.argmax(r))
    lag = float(shifts[best])
    if subframe and 0 < best < len(r) - 1 and np.isfinite(r[best - 1 : best + 2]).all():
        left, mid, right = r[best - 1 : best + 2]
        curvature = left - 2.0 * mid + right
        if curvature < 0:
            lag += float(0.5 * (left - right) / curvature)
    return lag


def gross_share(fused: np.ndarray, views: np.ndarray, joints: np.ndarray, limit_mm: float = GROSS_MM) -> float:
    """Share of (frame, joint) with a fused joint and >= 1 view where the fused is > limit from every view."""
    d = np.linalg.norm(views[:, :, joints] - fused[:, None, joints], axis=-1)  # (T, S, K)
    has_view = np.isfinite(d).any(axis=1)
    has_fused = np.isfinite(fused[:, joints]).all(axis=-1)
    count = has_view & has_fused
    if not count.any():
        return math.nan
    far = np.where(np.isfinite(d), d > limit_mm, True).all(axis=1)
    return float((far & count).sum() / count.sum())


def dropout_share(fused: np.ndarray, views: np.ndarray, joints: np.ndarray) -> float:
    """Share of instants where some view has every joint of the group but the fused output has none of them."""
    view_has = np.isfinite(views[:, :, joints]).all(axis=(-1, -2)).any(axis=1)
    fused_has = np.isfinite(fused[:, joints]).all(axis=-1).any(axis=-1)
    return float((view_has & ~fused_has).sum() / view_has.sum()) if view_has.any() else math.nan


def seen_joints(views: np.ndarray, confidence: np.ndarray, meaningful: bool) -> np.ndarray:
    """(T, S, 32, 3) views with the joints the tracker reported NONE set to NaN: such a joint carries a guessed
    position, it was not seen, so the fused output cannot have dropped it (confidence not meaningful: as is)."""
    if not meaningful:
        return views
    return np.where((np.asarray(confidence) > int(Confidence.NONE))[..., None], views, np.nan)


def median_distance(a: np.ndarray, b: np.ndarray, joints: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Median distance of (T, 32, 3) ``a`` and ``b`` over ``joints`` where both exist (and ``mask`` (T, 32))."""
    d = np.linalg.norm(a[:, joints] - b[:, joints], axis=-1)
    keep = np.isfinite(d)
    if mask is not None:
        keep &= mask[:, joints]
    return float(np.median(d[keep])) if keep.any() else math.nan


# ----------------------------------------------------------------------------------------------- result


@dataclass
class RigEvalResult:
    """Everything :func:`run_rig_eval` measured; ``to_dict()`` is JSON-ready."""

    sensors: list[str]
    formats: dict[str, str]
    time_matching: str
    notes: list[str]
    calibration: str
    n_instants: int
    evaluated: tuple[int, int]
    confidence_meaningful: bool
    presets: list[str]
    groups: dict[str, dict[str, dict[str, Any]]] = field(default_factory=dict)
    mirrored: dict[str, int] = field(default_factory=dict)
    track_ids: dict[str, int] = field(default_factory=dict)
    continuity: dict[str, dict[str, int]] = field(default_factory=dict)
    leave_one_out: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)
    orientation_agreement: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)
    orientation_by_joint: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)
    view_mirroring: dict[str, dict[str, float]] = field(default_factory=dict)
    plots: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return _jsonable(asdict(self))

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RigEvalResult:
        """Read back what :meth:`to_dict` wrote (docs/evidence.md is rendered from the stored JSON); every
        ``None`` among the measured figures was a NaN."""
        measured = ("groups", "leave_one_out", "orientation_agreement", "view_mirroring")
        fields = {k: nan_for_none(v) if k in measured else v for k, v in data.items()}
        return cls(**{**fields, "evaluated": tuple(data["evaluated"])})


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, np.generic):
        return _jsonable(value.item())
    return value


# ----------------------------------------------------------------------------------------------- running


def _fused_person(
    take: InputTake,
    poses: np.ndarray,
    preset_name: str,
    views: np.ndarray,
    eps_mm: float | None,
    smoothing: tuple[str, int | None] = ("none", None),
) -> tuple[np.ndarray, np.ndarray | None, int]:
    """(T, 32, 3) the fused person nearest the views' pelvis per instant, its (T, 32, 4) orientations (None where
    the preset makes none), and how many track ids it had. ``smoothing``: the offline smoother and its lag
    (:func:`skelfuse.recording.fuse_recording`); the default is the live filter's own output."""
    frames = list(
        fuse_recording(
            take,
            world_from_sensor=dict(zip(take.sensor_ids, poses, strict=True)),
            preset_name=preset_name,
            eps_mm=eps_mm,
            progress=False,
            smoother=smoothing[0],
            smoother_lag=smoothing[1],
        )
    )
    if len(frames) != len(views):
        raise DataError(f"internal: {len(frames)} fused instants for {len(views)} grouped instants")
    out = np.full((len(frames), N_JOINTS, 3), np.nan)
    oriented = any(frame.orientations is not None for frame in frames)
    quats = np.full((len(frames), N_JOINTS, 4), np.nan) if oriented else None
    ids: set[int] = set()
    with np.errstate(invalid="ignore"):
        anchor = np.nanmedian(views[:, :, J["PELVIS"]], axis=1) if views.size else np.zeros((0, 3))
    for t, frame in enumerate(frames):
        if frame.n_persons == 0:
            continue
        pelvis = frame.positions[:, J["PELVIS"]]
        d = np.linalg.norm(pelvis - anchor[t], axis=-1) if np.isfinite(anchor[t]).all() else np.zeros(frame.n_persons)
        d = np.where(np.isfinite(d), d, np.inf)
        k = int(np.argmin(d))
        out[t] = frame.positions[k]
        if quats is not None and frame.orientations is not None:
            quats[t] = frame.orientations[k]
        ids.add(int(frame.track_ids[k]))
    return out, quats, len(ids)


def _view_orientations(take: InputTake, poses: np.ndarray) -> np.ndarray:
    """(T, S, 32, 4) each sensor's first body's joint orientations per instant, in the world frame (NaN where the
    sensor had no body), grouped exactly as :func:`take_arrays` groups the positions."""
    ids = take.sensor_ids
    rows = []
    for group in take.groups(None):
        row = np.full((len(ids), N_JOINTS, 4), np.nan)
        for i, sid in enumerate(ids):
            frame = group.frames.get(sid)
            if frame is not None and frame.n_bodies:
                row[i] = frame.orientations[0]
        rows.append(row)
    return views_to_world(np.stack(rows) if rows else np.zeros((0, len(ids), N_JOINTS, 4)), poses)


def _poses(
    take: InputTake,
    calibration: Mapping[str, np.ndarray] | None,
    auto_calibrate: bool,
    positions: np.ndarray,
    confidence: np.ndarray,
) -> tuple[np.ndarray, str, int]:
    """(S, 4, 4) world_from_sensor, how they were obtained, and the first evaluated instant."""
    ids = take.sensor_ids
    if auto_calibrate:
        half = len(positions) // 2
        cal = calibrate_from_skeletons(positions[:half], confidence[:half], ids, progress=False)
        verdicts = ", ".join(f"{s} {cal.quality[s].verdict}" for s in ids)
        return (
            cal.world_from_sensor_array(ids),
            f"skeleton calibration on the first {half} instants (verdicts: {verdicts}); metrics on the rest",
            half,
        )
    if calibration is not None:
        missing = [s for s in ids if s not in calibration]
        if missing:
            raise DataError(
                f"the calibration has no pose for {', '.join(missing)}; it holds {', '.join(calibration)}. "
                "Calibrate with `skelfuse calibrate skeleton` or pass --auto-calibrate"
            )
        return np.stack([np.asarray(calibration[s], dtype=np.float64) for s in ids]), "calibration file", 0
    if take.poses and all(s in take.poses for s in ids):
        what = "identity (--registered: already in one frame)" if take.registered else "the recording's metadata"
        return np.stack([take.poses[s] for s in ids]), what, 0
    raise DataError(
        f"no poses for {', '.join(ids)}: pass --calibration FILE, --auto-calibrate (fit on one half, evaluate on "
        "the other) or --registered (files already in one frame)"
    )


FIXED_LAG_FRAMES = 3
"""The fixed lag ``eval real`` reports beside the causal and the smoothed outputs (100 ms at 30 fps)."""


def smoothing_variants(preset_name: str) -> dict[str, tuple[str, int | None]]:
    """The outputs a preset is reported as: label -> (smoother, lag). A preset whose filter has no velocity model
    is reported as it runs live only."""
    if preset(preset_name).filter != "cv_kalman":
        return {preset_name: ("none", None)}
    return {
        preset_name: ("none", None),
        f"{preset_name} lag {FIXED_LAG_FRAMES}": ("rts", FIXED_LAG_FRAMES),
        f"{preset_name} rts": ("rts", None),
    }


def take_times_s(take: InputTake) -> np.ndarray:
    """(T,) each grouped instant's time, s (the time the take's frames were matched by)."""
    return np.array([group.time_us / 1e6 for group in take.groups(None)], dtype=np.float64)


def run_rig_eval(
    take: InputTake,
    *,
    calibration: Mapping[str, np.ndarray] | None = None,
    auto_calibrate: bool = False,
    presets: Sequence[str] = DEFAULT_PRESETS,
    eps_mm: float | None = None,
    out_dir: Path | None = None,
    progress: bool = True,
) -> RigEvalResult:
    """Evaluate every preset on ``take`` against its single views (see the module docstring).

    Raises DataError for fewer than 2 sensors, no poses, or no instant with a body.
    """
    ids = take.sensor_ids
    if len(ids) < 2:
        raise DataError(f"eval real needs at least 2 sensors; the inputs hold {', '.join(ids)}")
    for name in presets:
        preset(name)  # unknown names fail before any work
    positions, confidence, _ = take_arrays(take, progress=progress)
    poses, how, first = _poses(take, calibration, auto_calibrate, positions, confidence)
    world = apply_transform(poses, positions)  # (T, S, 32, 3)
    meaningful = not take.confidence_unknown
    medium = confidence >= int(Confidence.MEDIUM) if meaningful else np.isfinite(world).all(axis=-1)
    evaluated = slice(first, len(world))
    views = world[evaluated]
    views_s = np.moveaxis(views, 1, 0)  # (S, T, 32, 3)
    seen_views = seen_joints(views, confidence[evaluated], meaningful)
    result = RigEvalResult(
        sensors=list(ids),
        formats=dict(take.formats),
        time_matching=take.clock,
        notes=list(take.notes),
        calibration=how,
        n_instants=len(world),
        evaluated=(first, len(world)),
        confidence_meaningful=meaningful,
        presets=list(presets),
    )
    times_s = take_times_s(take)
    fused_by_preset: dict[str, np.ndarray] = {}
    quats_by_preset: dict[str, np.ndarray] = {}
    for name in presets:
        for label, smoothing in smoothing_variants(name).items():
            fused_all, quats_all, n_ids = _fused_person(take, poses, name, world, eps_mm, smoothing)
            fused_by_preset[label] = fused_all[evaluated]
            if quats_all is not None and label == name:  # orientation agreement: the live output's
                quats_by_preset[label] = quats_all[evaluated]
            result.track_ids[label] = n_ids
            result.continuity[label] = continuity(fused_all[evaluated], views, times_s[evaluated])
    if quats_by_preset:
        view_quats = _view_orientations(take, poses)
        if len(view_quats) != len(world):
            raise DataError(f"internal: {len(view_quats)} instants of orientations for {len(world)} of positions")
        view_quats = view_quats[evaluated]
        for name, quats in quats_by_preset.items():
            result.orientation_agreement[name] = _orientation_agreement(
                quats, fused_by_preset[name], view_quats, views, ids
            )
            result.orientation_by_joint[name] = _orientation_by_joint(
                quats, fused_by_preset[name], view_quats, views, ids
            )
    candidates = {**fused_by_preset, **{f"view {s}": views[:, i] for i, s in enumerate(ids)}}
    result.groups.update(_agreement_groups(candidates, ids, views, medium[evaluated], seen_views))
    for label, seq in candidates.items():
        others = [i for i, s in enumerate(ids) if label != f"view {s}"]
        flags, _ = mirrored_frames(seq, views_s[others])
        result.mirrored[label] = int(flags.sum())
    result.view_mirroring = view_mirroring(world, confidence, ids, poses[:, :3, 3], evaluated=evaluated)
    if len(ids) >= 3:
        result.leave_one_out.update(_leave_one_out(world, views, confidence, medium, evaluated, ids, presets, eps_mm))
    if out_dir is not None:
        result.plots = write_plots(result, fused_by_preset, views, ids, out_dir)
    return result


def _agreement_groups(
    candidates: dict[str, np.ndarray],
    ids: Sequence[str],
    views: np.ndarray,
    medium_evaluated: np.ndarray,
    seen_views: np.ndarray,
) -> dict[str, dict[str, dict[str, Any]]]:
    """Per report group and candidate (each preset's fused person, each view): jitter, agreement with the other
    views, lag, gross errors and dropouts (against ``seen_views``: the views without their NONE joints)."""
    groups: dict[str, dict[str, dict[str, Any]]] = {}
    for group, joints in REPORT_GROUPS.items():
        rows: dict[str, dict[str, Any]] = {}
        for label, seq in candidates.items():
            is_view = label.startswith("view ")
            others = [i for i, s in enumerate(ids) if not (is_view and label == f"view {s}")]
            rows[label] = {
                "jitter": median_jitter(seq, joints),
                "agreement": {
                    ids[i]: median_distance(seq, views[:, i], joints, medium_evaluated[:, i]) for i in others
                },
                "lag": {ids[i]: velocity_lag(seq, views[:, i], joints) for i in others} if not is_view else {},
                "gross": gross_share(seq, views[:, others], joints),
                "dropouts": dropout_share(seq, seen_views, joints) if not is_view else math.nan,
            }
        groups[group] = rows
    return groups


def _leave_one_out(
    world: np.ndarray,
    views: np.ndarray,
    confidence: np.ndarray,
    medium: np.ndarray,
    evaluated: Any,
    ids: Sequence[str],
    presets: Sequence[str],
    eps_mm: float | None,
) -> dict[str, dict[str, dict[str, float]]]:
    """Per preset and held-out view: the fusion of the other views, and each other view, against the held one."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    conf_s = np.moveaxis(confidence, 1, 0)
    for name in presets:
        per_held: dict[str, dict[str, float]] = {}
        for h, held in enumerate(ids):
            rest = [i for i in range(len(ids)) if i != h]
            fused = fuse_views(np.moveaxis(world[:, rest], 1, 0), conf_s[rest], name, eps_mm)[evaluated]
            mask = medium[evaluated][:, h]
            row = {"fused": median_distance(fused, views[:, h], np.arange(N_JOINTS), mask)}
            for i in rest:
                row[f"view {ids[i]}"] = median_distance(views[:, i], views[:, h], np.arange(N_JOINTS), mask)
            per_held[held] = row
        out[name] = per_held
    return out


def _unmirrored(view_quats: np.ndarray, views: np.ndarray, fused: np.ndarray) -> np.ndarray:
    """(T, S, 32, 4) the views' orientations, NaN in the frames where that view is left/right mirrored against the
    fused skeleton (its frames then face the other way)."""
    out = view_quats.copy()
    for i in range(views.shape[1]):
        flipped, _ = mirrored_frames(views[:, i], fused[None])
        out[flipped, i] = np.nan
    return out


def _orientation_agreement(
    fused_quats: np.ndarray, fused: np.ndarray, view_quats: np.ndarray, views: np.ndarray, ids: Sequence[str]
) -> dict[str, dict[str, float]]:
    """Per group and view, the median twist angle (degrees) between the view's joint orientations and the fused
    ones, leaving out the frames where that view is left/right mirrored against the fused skeleton (its frames
    then face the other way). Only the twist about the bone is compared: the swing follows the fused positions
    by construction (:func:`skelfuse.eval.metrics.view_orientation_agreement`)."""
    views_quats = _unmirrored(view_quats, views, fused)
    angles = view_orientation_agreement(fused_quats, fused, views_quats, twist_only=True)  # (T, S, 32)
    out: dict[str, dict[str, float]] = {}
    for group, joints in REPORT_GROUPS.items():
        out[group] = {}
        for i, sid in enumerate(ids):
            values = angles[:, i][:, joints]
            values = values[np.isfinite(values)]
            out[group][sid] = float(np.median(values)) if values.size else math.nan
    return out


def _nanmedian(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(np.median(finite)) if finite.size else math.nan


def _orientation_by_joint(
    fused_quats: np.ndarray, fused: np.ndarray, view_quats: np.ndarray, views: np.ndarray, ids: Sequence[str]
) -> dict[str, dict[str, float]]:
    """Per aimed joint: the median full angle (degrees) between the fused orientation and the views' (``"views"``:
    pooled over the views; one key per view), ``"between views"``: the median angle between every two views' own
    frames, and ``"between A and B"`` per pair of views (a frame within x degrees of both views of a pair needs
    them within 2x of each other). Mirrored frames are left out as in :func:`_orientation_agreement`."""
    views_quats = _unmirrored(view_quats, views, fused)
    angles = view_orientation_agreement(fused_quats, fused, views_quats)  # (T, S, 32), full angle
    n_views = views_quats.shape[1]
    pairs = [(a, b) for a in range(n_views) for b in range(a + 1, n_views)]
    between = np.stack([quat_angle_deg(views_quats[:, a], views_quats[:, b]) for a, b in pairs], axis=1)  # (T, P, 32)
    pair_names = [f"between {ids[a]} and {ids[b]}" for a, b in pairs]
    out: dict[str, dict[str, float]] = {}
    for joint in np.flatnonzero(ORIENTATION_AIMED):
        row = {"views": _nanmedian(angles[:, :, joint])}
        row.update({sid: _nanmedian(angles[:, i, joint]) for i, sid in enumerate(ids)})
        row["between views"] = _nanmedian(between[:, :, joint])
        row.update({name: _nanmedian(between[:, k, joint]) for k, name in enumerate(pair_names)})
        out[JOINT_NAMES[joint]] = row
    return out


# ----------------------------------------------------------------------------------------------- output


def finite_median(values: Any) -> float:
    """The median of the finite numbers among ``values`` (NaN where there is none)."""
    finite = [v for v in values if isinstance(v, float | int) and math.isfinite(v)]
    return float(np.median(finite)) if finite else math.nan


def write_plots(
    result: RigEvalResult, fused: Mapping[str, np.ndarray], views: np.ndarray, ids: Sequence[str], out_dir: Path
) -> list[str]:
    """Two PNGs in ``out_dir``: a joint's trace (fused vs views) and agreement by group and preset."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    joint = J[TRACE_JOINT]
    fig, axes = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    t = np.arange(len(views))
    for axis, ax in enumerate(axes):
        for i, s in enumerate(ids):
            ax.plot(t, views[:, i, joint, axis], lw=0.8, alpha=0.6, label=f"view {s}")
        for name, seq in fused.items():
            ax.plot(t, seq[:, joint, axis], lw=1.4, label=name)
        ax.set_ylabel(f"{'xyz'[axis]} mm")
    axes[0].set_title(f"{JOINT_NAMES[joint]}: fused against the views (world frame)")
    axes[-1].set_xlabel("instant")
    axes[0].legend(fontsize=7, ncol=4)
    fig.tight_layout()
    path = out_dir / "trace.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    paths.append(str(path))

    fig, ax = plt.subplots(figsize=(10, 4))
    groups = list(result.groups)
    labels = list(next(iter(result.groups.values())))
    width = 0.8 / len(labels)
    for k, label in enumerate(labels):
        values = [finite_median(result.groups[g][label]["agreement"].values()) for g in groups]
        ax.bar(np.arange(len(groups)) + k * width, values, width, label=label)
    ax.set_xticks(np.arange(len(groups)) + 0.4 - width / 2, groups)
    ax.set_ylabel("median distance to the views, mm")
    ax.set_title("agreement with the views by joint group (lower bound on error)")
    ax.legend(fontsize=7, ncol=3)
    fig.tight_layout()
    path = out_dir / "agreement.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    paths.append(str(path))
    return paths
