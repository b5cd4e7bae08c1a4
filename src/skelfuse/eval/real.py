"""The real-data report: the fusion presets on a real 3-sensor Azure Kinect take, without ground truth.

The take is andyj1's ``saved_data_2_3dev`` (``../shared/data/azure-kinect-andyj1``): one seated person seen by
three hardware-synced Azure Kinect DKs, 98 frames. ``joints_gen_master.csv`` is in the master camera frame,
``joints_gen_sub1.csv`` / ``joints_gen_sub2.csv`` were mapped into it by the authors (roughly), and
``joints_gen_sync.csv`` is the authors' own fused result, a confidence-gated average (checked on the data:
the mean of the views that are MEDIUM, the master's position where none is): a baseline to beat, not
ground truth. Since every view is already in one frame, the world-from-sensor transforms are identity.

Without ground truth, the report measures what can be measured across views (a lower bound on true error,
since errors that all views share are invisible):

1. cross-view disagreement before fusion: distance between the same joint in two views;
2. distance of each fused output to each view;
3. jitter: RMS over frames and joints of ``|p[t+1] - 2 p[t] + p[t-1]|`` (mm/frame²);
4. leave-one-out: fuse two views and measure the distance to the third view's MEDIUM joints, next to each
   of the two single views' distance to the same joints. Fusion "wins" when the fused pair predicts the
   held-out view better than either view alone. The authors' fused file contains the held-out view, so its
   number is listed for reference only (it is not a held-out test);
5. left/right mirrored output frames, by majority vote of the views (:func:`mirrored_frames`);
6. bone-length CV per group, with its caveat (:data:`BONE_CV_NOTE`).

Metric functions are pure numpy, vectorized over frames and joints: arrays in, numbers out. The cycle:
:func:`load_take` reads the files, :func:`fuse_views` runs one preset over the take, :func:`run_real_eval`
computes every table into a :class:`RealEvalResult` (plain dicts and lists, ``to_dict()`` JSON-serializes
it), :func:`format_markdown` renders it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.eval.metrics import joint_distances
from skelfuse.fusion.mirror import lateral_axes
from skelfuse.fusion.pipeline import Fuser
from skelfuse.fusion.presets import preset
from skelfuse.fusion.transform import apply_transform
from skelfuse.schema.errors import DataError
from skelfuse.schema.skeleton import BONES, JOINT_GROUPS, N_JOINTS, Confidence, J
from skelfuse.sources.recorded import Recording, load_andyj1_csv

__all__ = [
    "AUTHORS_FILE",
    "BONE_CV_NOTE",
    "REPORT_GROUPS",
    "VIEW_FILES",
    "RealEvalResult",
    "RealTake",
    "bone_length_cv",
    "distance_stats",
    "format_markdown",
    "fuse_views",
    "group_bone_cv",
    "jitter_rms",
    "lateral_axes",
    "load_take",
    "locate_take",
    "mirrored_frames",
    "offset_split",
    "repeated_frames",
    "run_real_eval",
]

TAKE_PATH = Path("azure-kinect-andyj1") / "saved_data_2_3dev"
"""Where the 3-sensor take lies below the shared data root."""

VIEW_FILES: dict[str, str] = {
    "master": "joints_gen_master.csv",
    "sub1": "joints_gen_sub1.csv",
    "sub2": "joints_gen_sub2.csv",
}
"""The three sensor views of the take, by the name the report uses."""

AUTHORS_FILE = "joints_gen_sync.csv"
"""The authors' fused result: a confidence-gated average of the three views."""

AUTHORS = "authors"
"""Name of the authors' fused result in every table."""

REPORT_GROUPS: dict[str, np.ndarray] = {
    **JOINT_GROUPS,
    "hands": np.array(
        [J[n] for n in ("HAND_LEFT", "HANDTIP_LEFT", "THUMB_LEFT", "HAND_RIGHT", "HANDTIP_RIGHT", "THUMB_RIGHT")],
        dtype=np.int64,
    ),
    "feet": np.array([J["FOOT_LEFT"], J["FOOT_RIGHT"]], dtype=np.int64),
}
"""The paper's groups (torso / upper_limb / lower_limb) plus hands and feet, as joint indices."""

BONE_CV_NOTE = (
    "Bone-length CV alone does not measure fusion quality on this tracker: k4abt fits a body model, "
    "so within one view all bones keep fixed proportions and change together through one size factor "
    "per frame (CV about 2-5% per view, the same for every bone), and that scale differs between views "
    "by up to 5%. Averaging views naively therefore does not lower bone-length variation, and it makes "
    "hand bones worse because the views' hand guesses disagree. Read it next to the cross-view "
    "distances."
)

MIRROR_NOTE = (
    "A frame is mirrored when its lateral axis (left minus right shoulder plus left minus right hip) points "
    "against the lateral axis of a strict majority of the views (dot product < 0); a tie or missing joints "
    "leave the frame undecided. A single view is judged against the other views. A skeleton's own geometry "
    "cannot tell: a tracker that mirrors a person seen from behind mirrors the face too, so the views are "
    "the reference."
)


# ------------------------------------------------------------------------------------------------ data


@dataclass(frozen=True)
class RealTake:
    """The 3-sensor take as aligned arrays (frames match by order).

    Attributes
    ----------
    view_names : tuple of str
        ``("master", "sub1", "sub2")``.
    positions : (S, T, 32, 3) float64, mm, master camera frame
    confidence : (S, T, 32) uint8
    authors_positions : (T, 32, 3) float64, the authors' fused result
    recordings : the loaded recordings, views first, then the authors' file
    """

    view_names: tuple[str, ...]
    positions: np.ndarray
    confidence: np.ndarray
    authors_positions: np.ndarray
    recordings: tuple[Recording, ...]

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[1])


def locate_take(data_dir: str | Path) -> Path:
    """Find the take's folder from the shared data root, the andyj1 folder, or the take folder itself."""
    data_dir = Path(data_dir)
    tried = [data_dir / TAKE_PATH, data_dir / TAKE_PATH.name, data_dir]
    for candidate in tried:
        if all((candidate / name).is_file() for name in (*VIEW_FILES.values(), AUTHORS_FILE)):
            return candidate
    raise DataError(
        "the real 3-sensor take was not found; looked for "
        f"{', '.join([*VIEW_FILES.values(), AUTHORS_FILE])} in: {', '.join(str(p) for p in tried)}. "
        "Pass --data pointing at the shared data folder (the one holding azure-kinect-andyj1/, usually "
        "../shared/data from the project root) or at azure-kinect-andyj1/saved_data_2_3dev itself."
    )


def load_take(data_dir: str | Path) -> RealTake:
    """Load the three views and the authors' fused file; check: one person, the same frame count."""
    folder = locate_take(data_dir)
    recordings = [load_andyj1_csv(folder / name, sensor_id=view) for view, name in VIEW_FILES.items()]
    recordings.append(load_andyj1_csv(folder / AUTHORS_FILE, sensor_id=AUTHORS))
    counts = {rec.sensor_id: rec.n_frames for rec in recordings}
    if len(set(counts.values())) != 1:
        raise DataError(
            f"{folder}: the files hold different frame counts {counts}; frames match by order, so they must "
            "agree (check that joints_gen_master.csv's doubled frames were detected)"
        )
    singles = [rec.single_body() for rec in recordings]
    return RealTake(
        view_names=tuple(VIEW_FILES),
        positions=np.stack([pos for pos, _ in singles[:-1]]),
        confidence=np.stack([conf for _, conf in singles[:-1]]),
        authors_positions=singles[-1][0],
        recordings=tuple(recordings),
    )


def repeated_frames(positions: np.ndarray) -> int:
    """How many frames of a (T, J, 3) sequence are exact copies of the frame before (a stalled writer)."""
    positions = np.asarray(positions)
    if positions.shape[0] < 2:
        return 0
    same = (positions[1:] == positions[:-1]) | (np.isnan(positions[1:]) & np.isnan(positions[:-1]))
    return int(same.reshape(positions.shape[0] - 1, -1).all(axis=1).sum())


# --------------------------------------------------------------------------------------------- metrics


def offset_split(a: np.ndarray, b: np.ndarray, joints: Sequence[int] | np.ndarray) -> tuple[float, float]:
    """Split the disagreement of two (T, J, 3) views into a constant offset and the rest.

    Returns the mean over ``joints`` of ``|mean over frames of (a - b)|`` (the constant per-joint offset,
    e.g. from a calibration error) and the median distance left after removing that offset (mm).
    """
    diff = (np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64))[:, np.asarray(joints)]
    offset = np.nanmean(diff, axis=0)  # (K, 3)
    residual = np.sqrt(np.sum((diff - offset) ** 2, axis=-1))
    return float(np.mean(np.sqrt(np.sum(offset**2, axis=-1)))), float(np.nanmedian(residual))


def distance_stats(
    distances: np.ndarray, joints: Sequence[int] | np.ndarray, mask: np.ndarray | None = None
) -> dict[str, float | int]:
    """Mean, median and 90th percentile of (T, J) distances over all frames and the given joints.

    Parameters
    ----------
    distances : (T, J) mm, NaN where either side was missing (not counted).
    joints : joint indices to pool.
    mask : (T, J) bool, optional; only True entries count (e.g. "the reference joint is MEDIUM").

    Returns
    -------
    dict with ``mean``, ``median``, ``p90`` (mm; NaN when no sample) and ``n`` (samples pooled).
    """
    joints = np.asarray(joints, dtype=np.int64)
    values = np.asarray(distances, dtype=np.float64)[:, joints]
    keep = np.isfinite(values)
    if mask is not None:
        keep &= np.asarray(mask, dtype=bool)[:, joints]
    sample = values[keep]
    if sample.size == 0:
        return {"mean": math.nan, "median": math.nan, "p90": math.nan, "n": 0}
    return {
        "mean": float(sample.mean()),
        "median": float(np.median(sample)),
        "p90": float(np.percentile(sample, 90)),
        "n": int(sample.size),
    }


def jitter_rms(positions: np.ndarray, joints: Sequence[int] | np.ndarray) -> float:
    """RMS of the second difference of positions over time, pooled over frames and joints (mm/frame²).

    ``|p[t+1] - 2 p[t] + p[t-1]|`` for every interior frame t and joint; triples with a NaN are skipped.
    A constant velocity gives 0, so this sees trembling and jumps, not smooth motion.
    """
    positions = np.asarray(positions, dtype=np.float64)[:, np.asarray(joints, dtype=np.int64)]
    if positions.shape[0] < 3:
        return math.nan
    second = positions[2:] - 2.0 * positions[1:-1] + positions[:-2]
    norms = np.sqrt(np.sum(second**2, axis=-1))
    norms = norms[np.isfinite(norms)]
    return float(np.sqrt(np.mean(norms**2))) if norms.size else math.nan


def mirrored_frames(candidate: np.ndarray, views: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which frames of a skeleton sequence are left/right mirrored relative to the majority of views.

    Parameters
    ----------
    candidate : (T, J, 3) positions (a fused output or one view).
    views : (S, T, J, 3) the views that vote (leave the candidate out when it is one of them).

    Returns
    -------
    mirrored : (T,) bool
        A strict majority of the views that have a lateral axis in that frame point against the candidate's
        (dot product of the unit lateral axes < 0). See :data:`MIRROR_NOTE`.
    decided : (T,) bool
        False where the candidate has no lateral axis or the vote ties (then ``mirrored`` is False).
    """
    own = lateral_axes(candidate)  # (T, 3)
    others = lateral_axes(views)  # (S, T, 3)
    dots = np.einsum("tk,stk->st", own, others)  # NaN where either axis is missing
    against = np.sum(dots < 0, axis=0)
    along = np.sum(dots > 0, axis=0)
    return against > along, against != along


def bone_lengths(positions: np.ndarray) -> np.ndarray:
    """(..., J, 3) -> (..., 31) length in mm of every bone (parent, child) of ``skeleton.BONES``."""
    positions = np.asarray(positions, dtype=np.float64)
    return np.sqrt(np.sum((positions[..., BONES[:, 1], :] - positions[..., BONES[:, 0], :]) ** 2, axis=-1))


def bone_length_cv(positions: np.ndarray) -> np.ndarray:
    """(T, J, 3) -> (31,) coefficient of variation (std / mean over frames, ddof=0) of every bone's length."""
    lengths = bone_lengths(positions)
    valid = np.isfinite(lengths)
    count = valid.sum(axis=0)
    filled = np.where(valid, lengths, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = filled.sum(axis=0) / count
        var = np.where(valid, (lengths - mean) ** 2, 0.0).sum(axis=0) / count
        return np.sqrt(var) / mean


def group_bone_cv(cv: np.ndarray, joints: Sequence[int] | np.ndarray) -> float:
    """Mean CV of the bones that end in one of ``joints`` (a group's bones; the root, pelvis, has none)."""
    in_group = np.isin(BONES[:, 1], np.asarray(joints, dtype=np.int64))
    values = np.asarray(cv)[in_group]
    values = values[np.isfinite(values)]
    return float(values.mean()) if values.size else math.nan


# ----------------------------------------------------------------------------------------------- fusion


def fuse_views(
    positions: np.ndarray, confidence: np.ndarray, preset_name: str, eps_mm: float | None = None
) -> np.ndarray:
    """Run one fusion preset frame by frame over already-aligned views of one person.

    Parameters
    ----------
    positions : (S, T, J, 3) mm, all views in one frame (world_from_sensor = identity)
    confidence : (S, T, J) uint8
    preset_name : a name of :data:`skelfuse.fusion.presets.PAPER_PRESETS`
    eps_mm : DBSCAN radius, mm; None keeps the preset's own

    Returns
    -------
    (T, J, 3) float64 fused positions, NaN where the fuser had no estimate.
    """

    positions = np.asarray(positions, dtype=np.float64)
    n_sensors, n_frames = positions.shape[:2]
    world_from_sensor = np.broadcast_to(np.eye(4), (n_sensors, 4, 4)).copy()
    world = apply_transform(world_from_sensor, np.moveaxis(positions, 0, 1))  # (T, S, J, 3)
    conf = np.moveaxis(np.asarray(confidence, dtype=np.uint8), 0, 1)  # (T, S, J)
    fuser = Fuser(preset(preset_name, eps_mm=eps_mm), n_bodies=1)
    out = np.full((n_frames, N_JOINTS, 3), np.nan)
    for t in range(n_frames):
        result = fuser.step(world[t][None], conf[t][None], dt_s=1 / 30)
        out[t] = result.positions[0]
    return out


# ----------------------------------------------------------------------------------------------- report


@dataclass
class RealEvalResult:
    """Every table of the real-data report, as plain dicts and lists (see :meth:`to_dict`).

    Stats dicts hold ``mean``, ``median``, ``p90`` (mm) and ``n`` (samples). Group keys are those of
    :data:`REPORT_GROUPS`. Method keys are preset names (A1..A5, fused from all three views), view names
    (master, sub1, sub2) and ``"authors"``.

    Attributes
    ----------
    data_dir : the take's folder.
    n_frames, views, presets, eps_mm, groups : what was run.
    data_facts : per view: MEDIUM share per group, frames dropped as written twice, frames that repeat the
        frame before.
    disagreement : ``{"master-sub1": {group: stats}}``, all joints; ``disagreement_medium`` the same
        over joints MEDIUM in both views.
    fused_to_view : ``{method: {view: {group: stats}}}``, all joints (method = preset or authors).
    jitter : ``{method_or_view: {group: mm/frame²}}``.
    leave_one_out : ``{held_out_view: {method: {group: stats}}}``, at the held-out view's MEDIUM joints;
        methods: presets (fusing the two other views), the two other views alone, and ``authors``
        (which includes the held-out view: reference only).
    leave_one_out_wins : ``{held_out_view: {preset: {group: bool}}}`` fused mean below both single views'.
    mirrored : ``{method_or_view: {"fraction": f, "mirrored": n, "undecided": n}}``.
    bone_cv : ``{method_or_view: {group: CV}}`` (fraction, not %).
    notes : caveats to print with the tables.
    """

    data_dir: str
    n_frames: int
    views: list[str]
    presets: list[str]
    eps_mm: float | None
    groups: list[str]
    data_facts: dict[str, Any] = field(default_factory=dict)
    disagreement: dict[str, Any] = field(default_factory=dict)
    disagreement_medium: dict[str, Any] = field(default_factory=dict)
    fused_to_view: dict[str, Any] = field(default_factory=dict)
    jitter: dict[str, Any] = field(default_factory=dict)
    leave_one_out: dict[str, Any] = field(default_factory=dict)
    leave_one_out_wins: dict[str, Any] = field(default_factory=dict)
    mirrored: dict[str, Any] = field(default_factory=dict)
    bone_cv: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-serializable dict (NaN becomes None, numpy scalars become Python numbers)."""
        return _jsonable(asdict(self))


def _jsonable(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    return value


def run_real_eval(
    data_dir: Path, *, presets: Sequence[str] = ("A1", "A2", "A3", "A4", "A5", "skelfuse"), eps_mm: float | None = None
) -> RealEvalResult:
    """Run every preset over the real 3-sensor take and compute the report's tables.

    Parameters
    ----------
    data_dir : the shared data root (holding ``azure-kinect-andyj1/``), the andyj1 folder or the take folder.
    presets : fusion presets to run (names of ``skelfuse.fusion.presets``).
    eps_mm : DBSCAN radius for every preset, mm; None keeps each preset's own (100 mm for A3-A5, 75 for skelfuse).

    Raises
    ------
    DataError
        The take is not there (the message says where it looked) or its files are malformed.
    """
    take = load_take(data_dir)
    views, conf = take.positions, take.confidence
    names = list(take.view_names)
    groups = REPORT_GROUPS
    medium = conf >= Confidence.MEDIUM  # (S, T, J)
    result = RealEvalResult(
        data_dir=str(locate_take(data_dir)),
        n_frames=take.n_frames,
        views=names,
        presets=list(presets),
        eps_mm=None if eps_mm is None else float(eps_mm),
        groups=list(groups),
    )

    _add_view_facts(result, take, medium)

    fused = {name: fuse_views(views, conf, name, eps_mm) for name in presets}
    outputs = {**fused, AUTHORS: take.authors_positions}
    for method, output in outputs.items():
        result.fused_to_view[method] = {
            view: {g: distance_stats(joint_distances(output, views[s]), joints) for g, joints in groups.items()}
            for s, view in enumerate(names)
        }

    sequences = {**{name: views[s] for s, name in enumerate(names)}, **outputs}
    for method, sequence in sequences.items():
        result.jitter[method] = {g: jitter_rms(sequence, joints) for g, joints in groups.items()}
        cv = bone_length_cv(sequence)
        result.bone_cv[method] = {g: group_bone_cv(cv, joints) for g, joints in groups.items()}

    for method, output in outputs.items():
        flags, decided = mirrored_frames(output, views)
        result.mirrored[method] = _mirror_row(flags, decided)
    for s, name in enumerate(names):
        flags, decided = mirrored_frames(views[s], np.delete(views, s, axis=0))
        result.mirrored[name] = _mirror_row(flags, decided)

    _add_leave_one_out(result, take, presets, eps_mm, medium)

    result.notes = _notes(result, take)
    return result


def _add_view_facts(result: RealEvalResult, take: RealTake, medium: np.ndarray) -> None:
    """Facts about the data (MEDIUM share, duplicates, repeats, the authors' file against the master) and the
    views' disagreement with each other, into ``result``."""
    views, names, groups = take.positions, list(take.view_names), REPORT_GROUPS
    for s, name in enumerate(names):
        result.data_facts[name] = {
            "medium_share": {g: float(medium[s][:, joints].mean()) for g, joints in groups.items()},
            "duplicates_dropped": take.recordings[s].duplicates_dropped,
            "repeated_frames": repeated_frames(views[s]),
        }
    equals_master = (take.authors_positions == views[0]).all(axis=-1)  # (T, J)
    result.data_facts[AUTHORS] = {
        "repeated_frames": repeated_frames(take.authors_positions),
        "equals_master_share": {
            "all": float(equals_master.mean()),
            **{g: float(equals_master[:, joints].mean()) for g, joints in groups.items()},
        },
    }

    for a, b in combinations(range(len(names)), 2):
        key = f"{names[a]}-{names[b]}"
        dist = joint_distances(views[a], views[b])
        result.disagreement[key] = {g: distance_stats(dist, joints) for g, joints in groups.items()}
        both = medium[a] & medium[b]
        result.disagreement_medium[key] = {g: distance_stats(dist, joints, both) for g, joints in groups.items()}
        offset_mm, residual_mm = offset_split(views[a], views[b], groups["torso"])
        result.data_facts.setdefault("torso_offsets", {})[key] = {
            "constant_offset_mm": offset_mm,
            "residual_median_mm": residual_mm,
        }


def _add_leave_one_out(
    result: RealEvalResult, take: RealTake, presets: Sequence[str], eps_mm: float | None, medium: np.ndarray
) -> None:
    """Each view held out in turn, scored against the fusion of the others (and each other view alone)."""
    views, conf, names, groups = take.positions, take.confidence, list(take.view_names), REPORT_GROUPS
    for h, held_out in enumerate(names):
        rest = [s for s in range(len(names)) if s != h]
        target = views[h]
        table: dict[str, Any] = {}
        for name in presets:
            pair_fused = fuse_views(views[rest], conf[rest], name, eps_mm)
            table[name] = _group_table(pair_fused, target, medium[h], groups)
        for s in rest:
            table[names[s]] = _group_table(views[s], target, medium[h], groups)
        table[AUTHORS] = _group_table(take.authors_positions, target, medium[h], groups)
        result.leave_one_out[held_out] = table
        result.leave_one_out_wins[held_out] = {
            name: {
                g: bool(
                    table[name][g]["n"] > 0 and all(table[name][g]["mean"] < table[names[s]][g]["mean"] for s in rest)
                )
                for g in groups
            }
            for name in presets
        }


def _notes(result: RealEvalResult, take: RealTake) -> list[str]:
    """What a reader of the report must know about these numbers and this take."""
    names = list(take.view_names)
    return [
        "Cross-view numbers cannot see errors all views share: they are lower bounds on true error.",
        "Leave-one-out targets are the held-out view's MEDIUM joints only (LOW joints are the tracker's "
        "guesses); n = samples (frames x joints). The authors' fused file includes the held-out view, so its "
        "leave-one-out row is for reference, not a held-out test.",
        f"joints_gen_master.csv writes every frame twice ({take.recordings[0].duplicates_dropped} copies "
        f"dropped); after that {result.data_facts[names[0]]['repeated_frames']} of its "
        f"{take.n_frames - 1} frame transitions repeat the previous frame exactly (a stalled writer), so the "
        "master's jitter mixes zero steps with double steps and its frames can trail the subs' by one.",
        "The authors' fused file equals the master exactly on "
        f"{100 * result.data_facts[AUTHORS]['equals_master_share']['all']:.0f}% of all joint samples "
        "(it is the mean of the views that are MEDIUM, and the master's position where none is), so its "
        "jitter and distances follow the master's there.",
        _offset_note(result.data_facts["torso_offsets"]),
        MIRROR_NOTE,
        BONE_CV_NOTE,
    ]


def _offset_note(offsets: Mapping[str, Mapping[str, float]]) -> str:
    parts = ", ".join(
        f"{pair} {row['constant_offset_mm']:.0f} mm offset, {row['residual_median_mm']:.1f} mm rest"
        for pair, row in offsets.items()
    )
    return (
        "The views' torso disagreement is mostly a constant offset per joint (the authors' rough mapping "
        f"of the subs into the master frame): {parts} (median after removing the offset). Well-calibrated "
        "views agree to a median 10-11 mm. Fusion cannot remove an offset, so leave-one-out here mostly "
        "measures calibration: a fused pair cannot beat its better member when the other one is offset."
    )


def _group_table(
    estimate: np.ndarray, target: np.ndarray, mask: np.ndarray, groups: Mapping[str, np.ndarray]
) -> dict[str, dict[str, float | int]]:
    dist = joint_distances(estimate, target)
    return {g: distance_stats(dist, joints, mask) for g, joints in groups.items()}


def _mirror_row(flags: np.ndarray, decided: np.ndarray) -> dict[str, float | int]:
    n_decided = int(decided.sum())
    return {
        "fraction": float(flags.sum() / n_decided) if n_decided else math.nan,
        "mirrored": int(flags.sum()),
        "undecided": int((~decided).sum()),
    }


# --------------------------------------------------------------------------------------------- markdown


def _fmt(value: Any, digits: int = 1) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    return f"{value:.{digits}f}"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return lines


def _stat_cell(stats: Mapping[str, Any], key: str = "median") -> str:
    if not stats.get("n"):
        return "n/a"
    return f"{_fmt(stats[key])} ({_fmt(stats['p90'])})" if key == "median" else _fmt(stats[key])


def format_markdown(result: RealEvalResult) -> str:
    """Render the report as markdown: a heading and one table per measure, then the notes."""
    groups = result.groups
    views = result.views
    eps = "each preset's own (100 mm for A3-A5, 75 for skelfuse)" if result.eps_mm is None else f"{result.eps_mm:g} mm"
    lines = [
        f"# Real 3-sensor take: {Path(result.data_dir).name}",
        "",
        f"{result.n_frames} frames, views {', '.join(views)}, presets {', '.join(result.presets)}, "
        f"eps {eps}. Distances in mm.",
        "",
        "## Data: share of MEDIUM joints per group",
        "",
    ]
    lines += _table(["view", *groups, "copies dropped", "repeated frames"], _data_rows(result))

    lines += ["", "## Cross-view disagreement before fusion: median (p90), all joints", ""]
    lines += _table(
        ["pair", *groups],
        [[pair, *[_stat_cell(row[g]) for g in groups]] for pair, row in result.disagreement.items()],
    )
    lines += ["", "Same, only where both views are MEDIUM:", ""]
    lines += _table(
        ["pair", *groups],
        [[pair, *[_stat_cell(row[g]) for g in groups]] for pair, row in result.disagreement_medium.items()],
    )

    lines += ["", "## Distance of the fused output (3 views) to each view: median (p90), all joints", ""]
    rows = [
        [method, view, *[_stat_cell(per_view[view][g]) for g in groups]]
        for method, per_view in result.fused_to_view.items()
        for view in views
    ]
    lines += _table(["method", "view", *groups], rows)

    lines += ["", "## Jitter: RMS second difference (mm/frame²)", ""]
    lines += _table(
        ["sequence", *groups],
        [[method, *[_fmt(row[g], 2) for g in groups]] for method, row in result.jitter.items()],
    )

    lines += [
        "",
        "## Leave-one-out: mean distance to the held-out view's MEDIUM joints (n samples)",
        "",
        "Presets fuse the two other views; a '*' marks a preset that beats both single views. "
        "'authors' includes the held-out view (reference only).",
        "",
    ]
    lines += _table(["held out", "method", *groups], _leave_one_out_rows(result))

    lines += ["", "## Left/right mirrored frames (vs. the majority of views)", ""]
    lines += _table(
        ["sequence", "mirrored fraction", "mirrored", "undecided"],
        [
            [method, _fmt(row["fraction"], 3), str(row["mirrored"]), str(row["undecided"])]
            for method, row in result.mirrored.items()
        ],
    )

    lines += ["", "## Bone-length CV per group (%)", ""]
    lines += _table(
        ["sequence", *groups],
        [
            [method, *[_fmt(100 * v if v is not None else None, 1) for v in (row[g] for g in groups)]]
            for method, row in result.bone_cv.items()
        ],
    )
    lines += ["", "## Notes", ""]
    lines += [f"- {note}" for note in result.notes]
    return "\n".join(lines) + "\n"


def _data_rows(result: RealEvalResult) -> list[list[str]]:
    """The data table's rows: per view, its MEDIUM share per group, copies dropped, repeated frames."""
    groups = result.groups
    rows = []
    for view in result.views:
        facts = result.data_facts[view]
        rows.append(
            [
                view,
                *[_fmt(100 * facts["medium_share"][g], 0) + "%" for g in groups],
                str(facts["duplicates_dropped"]),
                str(facts["repeated_frames"]),
            ]
        )
    return rows


def _leave_one_out_rows(result: RealEvalResult) -> list[list[str]]:
    """The leave-one-out table's rows: per held-out view and method, mean (n) per group, '*' for a win."""
    groups = result.groups
    rows = []
    for held_out, table in result.leave_one_out.items():
        wins = result.leave_one_out_wins[held_out]
        for method, row in table.items():
            cells = []
            for g in groups:
                stats = row[g]
                mark = "*" if wins.get(method, {}).get(g) else ""
                cells.append(f"{_fmt(stats['mean'])}{mark} ({stats['n']})" if stats["n"] else "n/a")
            rows.append([held_out, method, *cells])
    return rows
