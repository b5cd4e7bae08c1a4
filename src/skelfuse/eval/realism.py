"""How realistic the simulator is: the statistics measured on real Azure Kinect recordings, on any take.

The same functions run on a real take (views already in one frame) and on a simulated one, so the two can be
set side by side (``skelfuse sim check``, ``docs/simulator.md``). Every statistic needs no ground truth: it
compares views with each other, or one view with itself over time, exactly as the real figures of the
design brief's "Real noise" section were measured. Cross-view figures cannot see errors all views share, so
they are lower bounds on the true error, for real and simulated takes alike.

Statistics, per joint group (:data:`GROUPS`, the simulator's noise groups):

- ``disagree_median`` / ``disagree_p90``: distance between the same joint in two views, both MEDIUM (mm).
- ``offset``: the constant per-view offset, ``|mean over frames of (a - b)|`` per joint, averaged over the
  group's joints (mm; two views, both MEDIUM).
- ``rho``, ``slow_sd``, ``white_sd``: the view difference minus its offset is modelled as the difference of two
  independent "AR(1) + white" processes; with autocovariances g0, g1, g2 of that residual (pooled over joints
  and axes) ``rho = g2 / g1``, the slow variance per view is ``g1 / rho / 2`` and the white variance per view
  ``(g0 - g1 / rho) / 2`` (per axis, mm). This is the moment estimator of an ARMA(1,1); it needs no truth.
- ``medium_rate`` / ``low_rate`` / ``none_rate``: share of (frame, joint) samples with that label.
- ``low_episode_median`` / ``low_episode_max``: lengths (frames) of runs of LOW of one joint in one view.
- ``jump_low`` / ``jump_medium``: share of LOW (MEDIUM) samples whose joint moved more than 100 mm since the
  previous frame in the same view, both frames with that label.
- ``hand_partly_none``: share of (frame, hand side) samples where some but not all of the side's hand joints
  (hand, hand tip, thumb) are NONE; the real tracker drops a whole hand at once.

Whole-body figures (group ``body``):

- ``scale_cv``: per view, one size factor per frame (median over bones of the bone's length over its median
  length); its coefficient of variation over frames.
- ``scale_rho``: the AR(1) rho (same estimator) of the log ratio of two views' size factors, which removes
  the pose-dependent shrink both views share.

Pure numpy, arrays in and dicts out.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.calibration.rigid import fit_rigid
from skelfuse.eval.metrics import joint_distances, nan_for_none
from skelfuse.progress import note
from skelfuse.schema.errors import DataError
from skelfuse.schema.skeleton import BODY_REGIONS, BONES, Confidence, J
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.profile import SimProfile
from skelfuse.sim.rig import arc_rig
from skelfuse.sources.recorded import load_andyj1_csv

__all__ = [
    "GROUPS",
    "JUMP_MM",
    "REAL_RANGES",
    "RealRange",
    "SimCheckResult",
    "ar1_white_split",
    "check_rows",
    "episode_lengths",
    "format_markdown",
    "run_sim_check",
    "simulated_take",
    "size_factors",
    "take_statistics",
]

GROUPS: dict[str, np.ndarray] = {name: np.asarray(joints, dtype=np.int64) for name, joints in BODY_REGIONS.items()}
"""Joint groups of the statistics: the simulator's noise groups (torso, head, face, arm, hand, knee, foot)."""

JUMP_MM = 100.0
"""A joint that moves more than this between two frames of one view has jumped (mm)."""

_HAND_SIDES = (
    np.array([J["HAND_LEFT"], J["HANDTIP_LEFT"], J["THUMB_LEFT"]]),
    np.array([J["HAND_RIGHT"], J["HANDTIP_RIGHT"], J["THUMB_RIGHT"]]),
)
_SCALE_BONES = np.isin(BONES[:, 1], np.concatenate([GROUPS["torso"], GROUPS["arm"], GROUPS["knee"], GROUPS["foot"]]))
"""Bones whose lengths give the size factor: torso and limbs (not hands and face, whose joints are guesses)."""


# ------------------------------------------------------------------------------------------- building blocks


def ar1_white_split(residual: np.ndarray) -> tuple[float, float, float]:
    """Split a difference of two views into AR(1) and white parts (moment estimator, no truth needed).

    Parameters
    ----------
    residual : (T, K) one column per joint and axis: view a minus view b, minus its constant offset, NaN where
        either view is missing. Lags are taken within columns; pairs with a NaN are skipped.

    Returns
    -------
    rho, slow_sd, white_sd : the AR(1) coefficient per frame, and per-view per-axis standard deviations (mm)
        of the slow and white parts, assuming the two views are independent and alike (each carries half
        the variance). NaN where there are too few samples or the estimate is degenerate (g1 <= 0).
    """
    x = np.asarray(residual, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, None]

    def autocov(lag: int) -> float:
        a, b = (x, x) if lag == 0 else (x[lag:], x[:-lag])
        prod = a * b
        prod = prod[np.isfinite(prod)]
        return float(prod.mean()) if prod.size > 10 else math.nan

    g0, g1, g2 = autocov(0), autocov(1), autocov(2)
    if not (math.isfinite(g1) and math.isfinite(g2)) or g1 <= 0:
        return math.nan, math.nan, math.nan
    rho = min(max(g2 / g1, 1e-3), 0.999)
    slow_var = g1 / rho
    return rho, math.sqrt(slow_var / 2.0), math.sqrt(max(g0 - slow_var, 0.0) / 2.0)


def episode_lengths(flags: np.ndarray) -> np.ndarray:
    """Lengths of the runs of True along axis 0 of a (T, K) bool array, all columns together (frames)."""
    flags = np.asarray(flags, dtype=bool)
    if flags.ndim == 1:
        flags = flags[:, None]
    padded = np.concatenate([np.zeros((1, flags.shape[1]), bool), flags, np.zeros((1, flags.shape[1]), bool)])
    edges = np.diff(padded.astype(np.int8), axis=0)
    starts = np.nonzero(edges.T == 1)
    ends = np.nonzero(edges.T == -1)
    return ends[1] - starts[1]  # row-major over columns: starts and ends pair up in order


def size_factors(positions: np.ndarray) -> np.ndarray:
    """(T,) one view's size factor per frame: median over torso and limb bones of length / median length."""
    positions = np.asarray(positions, dtype=np.float64)
    lengths = np.linalg.norm(positions[:, BONES[:, 1]] - positions[:, BONES[:, 0]], axis=-1)[:, _SCALE_BONES]
    with np.errstate(invalid="ignore"):
        return np.nanmedian(lengths / np.nanmedian(lengths, axis=0), axis=1)


# ------------------------------------------------------------------------------------------------ statistics


def align_views(positions: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """Every view rigidly fitted onto view 0 over the whole take (torso joints MEDIUM in both views).

    This is the skeleton calibration over a whole take that DESIGN.md "Real noise" calls stable: applied the
    same way to real and simulated takes, it leaves the figures free of each rig's extrinsic error, which
    belongs to calibration, not to the tracker.
    """
    positions = np.array(positions, dtype=np.float64)
    torso = GROUPS["torso"]
    medium = np.asarray(confidence) == Confidence.MEDIUM
    for s in range(1, positions.shape[0]):
        both = (medium[0] & medium[s])[:, torso] & np.isfinite(positions[0][:, torso, 0])
        both &= np.isfinite(positions[s][:, torso, 0])
        if both.sum() < 10:
            continue
        fit = fit_rigid(positions[s][:, torso][both], positions[0][:, torso][both])
        positions[s] = fit.apply(positions[s])
    return positions


def take_statistics(
    positions: np.ndarray, confidence: np.ndarray, *, align: bool = True
) -> dict[tuple[str, str], float]:
    """Every realism statistic of one take.

    Parameters
    ----------
    positions : (S, T, 32, 3) mm, all views in one frame (world or the master's camera), NaN = not tracked
    confidence : (S, T, 32) Confidence values
    align : first fit every view onto view 0 over the whole take (:func:`align_views`)

    Returns
    -------
    ``{(statistic, group): value}``; statistics and groups as in the module docstring. Cross-view figures pool
    every pair of views; per-view figures pool every view.
    """
    positions = np.asarray(positions, dtype=np.float64)
    confidence = np.asarray(confidence)
    if align:
        positions = align_views(positions, confidence)
    n_views = positions.shape[0]
    medium = confidence == Confidence.MEDIUM
    low = confidence == Confidence.LOW
    out: dict[tuple[str, str], float] = {}

    for group, joints in GROUPS.items():
        dists, offsets, residuals = [], [], []
        for a, b in combinations(range(n_views), 2):
            both = (medium[a] & medium[b])[:, joints]
            dist = joint_distances(positions[a][:, joints], positions[b][:, joints])
            dists.append(dist[both & np.isfinite(dist)])
            diff = np.where(both[..., None], positions[a][:, joints] - positions[b][:, joints], np.nan)
            counts = np.isfinite(diff[..., 0]).sum(axis=0)
            with np.errstate(invalid="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # a joint never MEDIUM in both: NaN, skipped
                offset = np.nanmean(np.where(counts[None, :, None] >= 10, diff, np.nan), axis=0)  # (K, 3)
            offsets.extend(np.linalg.norm(offset, axis=-1)[counts >= 10])
            residuals.append((diff - offset).reshape(diff.shape[0], -1))
        pooled = np.concatenate(dists) if dists else np.empty(0)
        out[("disagree_median", group)] = float(np.median(pooled)) if pooled.size else math.nan
        out[("disagree_p90", group)] = float(np.percentile(pooled, 90)) if pooled.size else math.nan
        out[("offset", group)] = float(np.mean(offsets)) if offsets else math.nan
        rho, slow, white = ar1_white_split(np.concatenate(residuals, axis=1)) if residuals else (math.nan,) * 3
        out[("rho", group)], out[("slow_sd", group)], out[("white_sd", group)] = rho, slow, white

        labels = confidence[:, :, joints]
        tracked = np.isfinite(positions[:, :, joints, 0])
        n_samples = max(int(tracked.sum()), 1)
        out[("medium_rate", group)] = float((medium[:, :, joints] & tracked).sum() / n_samples)
        out[("low_rate", group)] = float((low[:, :, joints] & tracked).sum() / n_samples)
        out[("none_rate", group)] = float(((labels == Confidence.NONE) & tracked).sum() / n_samples)
        episodes = np.concatenate([episode_lengths(low[s][:, joints] & tracked[s]) for s in range(n_views)])
        out[("low_episode_median", group)] = float(np.median(episodes)) if episodes.size else math.nan
        out[("low_episode_max", group)] = float(episodes.max()) if episodes.size else math.nan
        step = np.linalg.norm(np.diff(positions[:, :, joints], axis=1), axis=-1)  # (S, T-1, K)
        for name, flags in (("jump_low", low), ("jump_medium", medium)):
            both = flags[:, 1:, joints] & flags[:, :-1, joints] & np.isfinite(step)
            out[(name, group)] = float((step[both] > JUMP_MM).mean()) if both.any() else math.nan

    none = confidence == Confidence.NONE
    tracked_frames = np.isfinite(positions[:, :, J["PELVIS"], 0])
    partly = [none[:, :, side].any(axis=-1) & ~none[:, :, side].all(axis=-1) & tracked_frames for side in _HAND_SIDES]
    out[("hand_partly_none", "hand")] = float(np.sum(partly) / max(2 * int(tracked_frames.sum()), 1))

    factors = np.stack([size_factors(positions[s]) for s in range(n_views)])  # (S, T)
    with np.errstate(invalid="ignore"):
        cvs = np.nanstd(factors, axis=1) / np.nanmean(factors, axis=1)
    out[("scale_cv", "body")] = float(np.nanmean(cvs))
    ratios = [np.log(factors[a] / factors[b]) for a, b in combinations(range(n_views), 2)]
    if ratios:
        stacked = np.stack(ratios, axis=1)
        out[("scale_rho", "body")] = ar1_white_split(stacked - np.nanmean(stacked, axis=0))[0]
    return out


# ------------------------------------------------------------------------------------------- the real ranges


@dataclass(frozen=True)
class RealRange:
    """What real recordings showed for one statistic and group.

    ``low``/``high`` bound the real figures (inclusive); ``source`` says where they were measured and how
    the range was read from the text (the design brief's "Real noise" section and the measurements of three
    real two-view squat takes, which are not shipped with the project, quote them).
    """

    low: float
    high: float
    source: str

    def contains(self, value: float) -> bool:
        return math.isfinite(value) and self.low <= value <= self.high


_D = "DESIGN.md Real noise"
_I = "3 real 2-view squat takes"
REAL_RANGES: dict[tuple[str, str], RealRange] = {
    ("disagree_median", "torso"): RealRange(8.0, 13.5, f"{_D}: median 10-11 mm (±25%)"),
    ("disagree_p90", "torso"): RealRange(16.0, 28.0, f"{_D}: p90 about 22 mm (±25%)"),
    ("disagree_median", "head"): RealRange(9.0, 15.0, f"{_D}: HEAD agrees to about 12 mm (±25%)"),
    ("disagree_median", "face"): RealRange(22.0, 38.0, f"{_D}: face about 30 mm (±25%)"),
    ("disagree_median", "arm"): RealRange(22.0, 36.0, f"{_D}: wrists about 29 mm (±25%)"),
    ("disagree_p90", "arm"): RealRange(48.0, 88.0, f"{_D}: wrists p90 60-70 mm (±25%)"),
    ("disagree_median", "hand"): RealRange(37.0, 61.0, f"{_D}: hands and tips 37-61 mm"),
    ("disagree_median", "foot"): RealRange(37.0, 51.0, f"{_D}: ankles and feet 37-51 mm"),
    ("offset", "torso"): RealRange(0.0, 11.0, f"{_D}: torso up to 11 mm"),
    ("offset", "arm"): RealRange(7.0, 41.0, f"{_D}: elbows and wrists 7-41 mm"),
    ("offset", "knee"): RealRange(15.0, 39.0, f"{_D}: knees 15-39 mm"),
    ("offset", "foot"): RealRange(17.0, 104.0, f"{_D}: ankles and feet 17-104 mm"),
    ("offset", "face"): RealRange(11.0, 63.0, f"{_D}: face 11-63 mm"),
    ("offset", "hand"): RealRange(36.0, 60.0, f"{_I}: about 48 mm (±25%)"),
    **{("rho", g): RealRange(0.8, 0.94, f"{_D}: rho 0.8-0.94") for g in ("torso", "head", "arm", "knee", "foot")},
    ("rho", "face"): RealRange(0.69, 0.74, f"{_I}: face 0.69-0.74"),
    **{("slow_sd", g): RealRange(4.0, 9.0, f"{_D}: slow part 5-9 mm per axis (torso 7-13 mm 3D)") for g in ("torso",)},
    **{("slow_sd", g): RealRange(5.0, 9.0, f"{_D}: slow part 5-9 mm per axis") for g in ("arm", "knee", "foot")},
    **{
        ("white_sd", g): RealRange(1.2, 2.5, f"{_D}: white 1.2-2.5 mm per axis")
        for g in ("torso", "head", "knee", "foot")
    },
    ("white_sd", "arm"): RealRange(2.0, 4.0, f"{_D}: wrists and hands 2-4 mm per axis"),
    ("white_sd", "hand"): RealRange(2.0, 4.0, f"{_D}: wrists and hands 2-4 mm per axis"),
    ("medium_rate", "torso"): RealRange(0.98, 1.0, f"{_D} + {_I}: torso about 100% MEDIUM"),
    ("medium_rate", "head"): RealRange(0.98, 1.0, f"{_D}: head about 100% MEDIUM"),
    ("medium_rate", "knee"): RealRange(0.97, 1.0, f"{_D}: legs 97-100% MEDIUM unoccluded"),
    ("medium_rate", "foot"): RealRange(0.97, 1.0, f"{_D}: legs 97-100% MEDIUM unoccluded"),
    ("none_rate", "hand"): RealRange(0.23, 1.0, f"{_D}: hands NONE 23-100%"),
    ("hand_partly_none", "hand"): RealRange(0.0, 0.2, f"{_I}: a hand partly NONE in 0-20% of frames"),
    ("low_episode_median", "knee"): RealRange(1.0, 1.0, f"{_D}: LOW episodes median 1 frame"),
    ("low_episode_median", "foot"): RealRange(1.0, 1.0, f"{_D}: LOW episodes median 1 frame"),
    ("low_episode_max", "knee"): RealRange(6.0, 15.0, f"{_I}: leg LOW episodes up to 6-15 frames"),
    ("low_episode_max", "foot"): RealRange(6.0, 15.0, f"{_I}: leg LOW episodes up to 6-15 frames"),
    ("jump_low", "knee"): RealRange(0.02, 0.37, f"{_I}: 2-37% of leg LOW frames jump > 100 mm"),
    ("jump_low", "foot"): RealRange(0.02, 0.37, f"{_I}: 2-37% of leg LOW frames jump > 100 mm"),
    **{
        ("jump_medium", g): RealRange(0.0, 0.002, f"{_D}: under 0.2% of MEDIUM frames jump > 100 mm")
        for g in ("torso", "arm", "knee", "foot")
    },
    ("scale_cv", "body"): RealRange(0.02, 0.05, f"{_D}: bone-length CV 2-5% per view"),
    ("scale_rho", "body"): RealRange(0.82, 0.93, f"{_I}: body size factor rho 0.82-0.93"),
}
"""The real figures each simulated statistic is held to. Where the text gives one figure ("about 29 mm") the
range is that figure ±25%; where it gives a span, the span itself."""


@dataclass
class CheckRow:
    """One line of the realism table."""

    statistic: str
    group: str
    real: RealRange
    simulated: list[float] = field(default_factory=list)
    recorded: float = math.nan

    @property
    def value(self) -> float:
        finite = [v for v in self.simulated if math.isfinite(v)]
        return float(np.mean(finite)) if finite else math.nan

    @property
    def inside(self) -> bool:
        return self.real.contains(self.value)


def check_rows(
    simulated: Sequence[Mapping[tuple[str, str], float]], recorded: Mapping[tuple[str, str], float] | None = None
) -> list[CheckRow]:
    """The realism table: every statistic with a real range, its simulated values (one per seed) and, where
    a real take was measured too, its value there."""
    rows = []
    for key, real in REAL_RANGES.items():
        rows.append(
            CheckRow(
                key[0],
                key[1],
                real,
                [float(stats.get(key, math.nan)) for stats in simulated],
                float(recorded.get(key, math.nan)) if recorded else math.nan,
            )
        )
    return rows


def rows_to_dicts(rows: Sequence[CheckRow]) -> list[dict[str, Any]]:
    """JSON-friendly rows (NaN becomes None)."""

    def num(v: float) -> float | None:
        return float(v) if math.isfinite(v) else None

    return [
        {
            "statistic": r.statistic,
            "group": r.group,
            "real_low": r.real.low,
            "real_high": r.real.high,
            "source": r.real.source,
            "simulated": num(r.value),
            "simulated_per_seed": [num(v) for v in r.simulated],
            "recorded_take": num(r.recorded),
            "inside": r.inside,
        }
        for r in rows
    ]


# ------------------------------------------------------------------------------------------------ the check

RECORDED_TAKE = ("azure-kinect-andyj1", "saved_data_2_3dev")
"""The real take shipped in ``../shared/data``: andyj1's 3-sensor take (one seated person, 98 frames, views
mapped into the master camera frame by the authors)."""
RECORDED_VIEWS = ("joints_gen_master.csv", "joints_gen_sub1.csv", "joints_gen_sub2.csv")


def simulated_take(
    profile: SimProfile, *, n_sensors: int, seed: int, duration_s: float = 20.0
) -> tuple[np.ndarray, np.ndarray]:
    """A simulated take set up like the real ones: squats, sensors 45° apart on an arc 2.25 m from the subject.

    Returns
    -------
    positions : (S, T, 32, 3) world mm with the calibrated extrinsics (as a real rig would map them), NaN
        where a view did not track the body
    confidence : (S, T, 32)
    """
    motion = make_gesture("squat", duration_s=duration_s, seed=seed)
    obs = simulate(motion, arc_rig(n_sensors, spread_deg=45.0), profile, seed=seed)
    world = obs.positions_world(calibrated=True)
    world = np.where(obs.tracked[..., None, None], world, np.nan)
    return np.moveaxis(world, 1, 0), np.moveaxis(np.asarray(obs.confidence), 1, 0)


def recorded_take(data_dir: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """The shipped real 3-sensor take as (S, T, 32, 3) positions (master camera frame) and (S, T, 32) labels.

    Raises
    ------
    DataError
        The take's files are not under ``data_dir`` (the shared data root).
    """
    folder = Path(data_dir).joinpath(*RECORDED_TAKE)
    if not all((folder / name).is_file() for name in RECORDED_VIEWS):
        raise DataError(
            f"the real take {'/'.join(RECORDED_TAKE)} is not under {data_dir}; pass --data pointing at the shared "
            "data folder (the one holding azure-kinect-andyj1/), or --no-real to skip the real column"
        )
    singles = [load_andyj1_csv(folder / name, sensor_id=name).single_body() for name in RECORDED_VIEWS]
    return np.stack([pos for pos, _ in singles]).astype(np.float64), np.stack([conf for _, conf in singles])


@dataclass
class SimCheckResult:
    """The realism table of one profile: rows for the two-view takes (one value per seed, judged against the
    real range), the three-view take's value beside them, and the shipped real take's where it was read."""

    profile: str
    seeds: list[int]
    duration_s: float
    rows: list[CheckRow]
    three_view: dict[tuple[str, str], float]
    recorded_dir: str | None

    @property
    def n_inside(self) -> int:
        return sum(r.inside for r in self.rows)

    def to_dict(self) -> dict[str, Any]:
        rows = rows_to_dicts(self.rows)
        for row in rows:
            value = self.three_view.get((row["statistic"], row["group"]), math.nan)
            row["simulated_three_view"] = float(value) if math.isfinite(value) else None
        return {
            "profile": self.profile,
            "seeds": self.seeds,
            "duration_s": self.duration_s,
            "recorded_take": self.recorded_dir,
            "inside": self.n_inside,
            "rows": rows,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SimCheckResult:
        """Read back what :meth:`to_dict` wrote (docs/evidence.md is rendered from the stored JSON)."""
        rows = [nan_for_none(row) for row in data["rows"]]
        return cls(
            profile=data["profile"],
            seeds=list(data["seeds"]),
            duration_s=data["duration_s"],
            rows=[
                CheckRow(
                    r["statistic"],
                    r["group"],
                    RealRange(r["real_low"], r["real_high"], r["source"]),
                    r["simulated_per_seed"],
                    r["recorded_take"],
                )
                for r in rows
            ],
            three_view={(r["statistic"], r["group"]): r["simulated_three_view"] for r in rows},
            recorded_dir=data["recorded_take"],
        )


def run_sim_check(
    profile: SimProfile | None = None,
    *,
    profile_name: str = "azure_kinect (packaged)",
    seeds: Sequence[int] = (0, 1, 2),
    duration_s: float = 20.0,
    data_dir: Any = None,
    progress: bool = False,
) -> SimCheckResult:
    """Simulate the two-view squat takes (one per seed) and a three-view one, measure them, and set them beside
    the real ranges (and the shipped real take, when ``data_dir`` is given)."""
    profile = profile if profile is not None else load_profile()
    stats = []
    for seed in seeds:
        if progress:
            note(f"sim check: two-view squat take, seed {seed} ({duration_s:g} s)")
        stats.append(take_statistics(*simulated_take(profile, n_sensors=2, seed=seed, duration_s=duration_s)))
    if progress:
        note("sim check: three-view squat take")
    three = take_statistics(*simulated_take(profile, n_sensors=3, seed=int(seeds[0]), duration_s=duration_s))
    recorded = None
    if data_dir is not None:
        if progress:
            note(f"sim check: the real take under {data_dir}")
        recorded = take_statistics(*recorded_take(data_dir))
    return SimCheckResult(
        profile=profile_name,
        seeds=[int(s) for s in seeds],
        duration_s=float(duration_s),
        rows=check_rows(stats, recorded),
        three_view=three,
        recorded_dir=None if data_dir is None else str(data_dir),
    )


def _fmt(value: float) -> str:
    if not math.isfinite(value):
        return "n/a"
    return f"{value:.3f}" if abs(value) < 1.0 and value != 0 else f"{value:.1f}"


def format_markdown(result: SimCheckResult) -> str:
    """The realism table as markdown (the source of the table in docs/simulator.md)."""
    seeds = ", ".join(str(s) for s in result.seeds)
    lines = [
        f"Profile: {result.profile}. Simulated: squats, sensors 45° apart on an arc 2.25 m from the subject; "
        f"two-view takes of {result.duration_s:g} s with seeds {seeds} (mean over seeds, judged against the "
        "real range), one three-view take beside it. Real take: "
        + (
            "andyj1 saved_data_2_3dev (3 views, seated, 98 frames; reference only)."
            if result.recorded_dir
            else "not read."
        ),
        "",
        f"**{result.n_inside} of {len(result.rows)} statistics inside the real range.**",
        "",
        "| statistic | group | real range | simulated, 2 views | per seed | 3 views | andyj1 take | inside | "
        "source of the range |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in result.rows:
        per_seed = " / ".join(_fmt(v) for v in row.simulated)
        three = result.three_view.get((row.statistic, row.group), math.nan)
        lines.append(
            f"| {row.statistic} | {row.group} | {_fmt(row.real.low)}-{_fmt(row.real.high)} | {_fmt(row.value)} | "
            f"{per_seed} | {_fmt(three)} | {_fmt(row.recorded)} | {'yes' if row.inside else '**no**'} | "
            f"{row.real.source} |"
        )
    return "\n".join(lines) + "\n"
