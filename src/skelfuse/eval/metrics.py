"""Error metrics of a skeleton against a reference, as in Lee et al. 2022 (section 2.3, Appendices A/B).

Pure numpy: arrays in, arrays out, no I/O. Everything is vectorized over frames and joints.

The cycle of an evaluation:

1. ``joint_distances(estimate, reference)``: the Euclidean distance of every joint in every frame, (T, J) mm.
2. ``ErrorAccumulator.add(estimate, reference)``: sums of the distances and of their squares per joint, plus
   how many frames were valid, how many the estimate left NaN while the reference had a value (counted, never
   silently dropped) and how many the reference itself lacked. Accumulators of several takes add up (``+``),
   so frames pool across takes, directions and worker processes.
3. ``ErrorAccumulator.stats()`` -> ``ErrorStats``: per joint AE (mean distance), RMSE (root mean square
   distance) and STD (population standard deviation of the distance, ddof=0), so ``RMSE² = AE² + STD²``.
4. ``mean_stats([...])`` averages per-joint metrics over gestures or sensor combinations with equal weight
   (as the paper averages its per-gesture tables and its sensor combinations), and ``group_means`` averages a
   per-joint metric over the joints of a group (the paper's torso / upper limb / lower limb figures are the
   means of its per-joint Appendix values).

``lag_error_curve`` / ``best_lag`` measure how late an output trails the reference: the time shift, in frames,
that minimizes the mean distance between the shifted output and the reference. ``swap_counts`` counts frames
where an output has a left/right pair the wrong way round. ``jitter_sums`` / ``jitter_rms`` measure how much an
output shakes: the RMS of its second difference over time (mm/frame², the discrete acceleration).
``angular_errors`` / ``angle_stats`` score joint orientations (degrees of the rotation between estimate and
truth); ``view_orientation_agreement`` compares fused orientations with each view's on real recordings, where
there is no truth.

References
----------
Lee, S.-h. et al. "Markerless 3D Skeleton Tracking Algorithm by Merging Multiple Inaccurate Skeleton Data from
Multiple RGB-D Sensors", Sensors 22(9), 3155, 2022, section 2.3 (error = distance to the reference joint, and
its standard deviation) and Appendices A/B (RMSE and STD per joint and gesture).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from skelfuse.fusion.mirror import pair_costs
from skelfuse.fusion.orientation import aim_directions, quat_angle_deg, swing_onto_aims

__all__ = [
    "ErrorAccumulator",
    "ErrorStats",
    "angle_stats",
    "angular_errors",
    "best_lag",
    "error_stats",
    "group_means",
    "jitter_rms",
    "jitter_sums",
    "joint_distances",
    "lag_error_curve",
    "mean_stats",
    "swap_counts",
    "view_orientation_agreement",
]


def _check_pair(estimate: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    estimate = np.asarray(estimate, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64)
    if estimate.shape != reference.shape or estimate.ndim < 2 or estimate.shape[-1] != 3:
        raise ValueError(
            f"estimate and reference must have the same shape (..., J, 3); got {estimate.shape} and "
            f"{reference.shape}. Check that both are world positions in mm of the same joints and frames."
        )
    return estimate, reference


def joint_distances(estimate: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Euclidean distance between estimated and reference joints.

    Parameters
    ----------
    estimate, reference : (..., J, 3) array
        Joint positions in mm; NaN marks a missing joint.

    Returns
    -------
    (..., J) float64 array
        Distance in mm, NaN wherever either side is missing.
    """
    estimate, reference = _check_pair(estimate, reference)
    return np.sqrt(np.sum((estimate - reference) ** 2, axis=-1))


@dataclass(frozen=True)
class ErrorStats:
    """Per-joint error statistics.

    Attributes
    ----------
    ae_mm, rmse_mm, std_mm : (J,) float64
        Mean distance, root mean square distance, population standard deviation of the distance (mm).
        NaN for a joint without a single valid frame.
    n_frames : (J,) int64
        Frames where both estimate and reference had the joint.
    n_missing : (J,) int64
        Frames where the reference had the joint but the estimate was NaN (an output failure, reported).
    n_ref_missing : (J,) int64
        Frames where the reference lacked the joint (not scored).
    """

    ae_mm: np.ndarray
    rmse_mm: np.ndarray
    std_mm: np.ndarray
    n_frames: np.ndarray
    n_missing: np.ndarray
    n_ref_missing: np.ndarray


@dataclass
class ErrorAccumulator:
    """Running sums of joint distances over frames, mergeable across takes and processes.

    Attributes
    ----------
    n_frames, n_missing, n_ref_missing : (J,) int64
        See ``ErrorStats``.
    sum_mm, sum_sq_mm2 : (J,) float64
        Sum of the valid distances and of their squares.
    """

    n_frames: np.ndarray
    n_missing: np.ndarray
    n_ref_missing: np.ndarray
    sum_mm: np.ndarray
    sum_sq_mm2: np.ndarray

    @classmethod
    def zeros(cls, n_joints: int) -> ErrorAccumulator:
        """An empty accumulator for ``n_joints`` joints."""

        def count() -> np.ndarray:
            return np.zeros(n_joints, dtype=np.int64)

        return cls(count(), count(), count(), np.zeros(n_joints), np.zeros(n_joints))

    @property
    def n_joints(self) -> int:
        return int(self.n_frames.shape[0])

    def add(self, estimate: np.ndarray, reference: np.ndarray) -> ErrorAccumulator:
        """Add the frames of one take.

        Parameters
        ----------
        estimate, reference : (T, J, 3) array
            Joint positions in mm, NaN = missing; J must match the accumulator.

        Returns
        -------
        ErrorAccumulator
            ``self``, for chaining.
        """
        estimate, reference = _check_pair(estimate, reference)
        if estimate.shape[-2] != self.n_joints:
            raise ValueError(f"expected {self.n_joints} joints per frame, got {estimate.shape[-2]}")
        estimate = estimate.reshape(-1, self.n_joints, 3)
        reference = reference.reshape(-1, self.n_joints, 3)
        ref_ok = np.isfinite(reference).all(axis=-1)
        est_ok = np.isfinite(estimate).all(axis=-1)
        valid = ref_ok & est_ok
        distance = np.where(
            valid,
            joint_distances(np.where(valid[..., None], estimate, 0.0), np.where(valid[..., None], reference, 0.0)),
            0.0,
        )
        self.n_frames += valid.sum(axis=0)
        self.n_missing += (ref_ok & ~est_ok).sum(axis=0)
        self.n_ref_missing += (~ref_ok).sum(axis=0)
        self.sum_mm += distance.sum(axis=0)
        self.sum_sq_mm2 += (distance**2).sum(axis=0)
        return self

    def __add__(self, other: ErrorAccumulator) -> ErrorAccumulator:
        if other.n_joints != self.n_joints:
            raise ValueError(f"cannot add accumulators of {self.n_joints} and {other.n_joints} joints")
        return ErrorAccumulator(
            self.n_frames + other.n_frames,
            self.n_missing + other.n_missing,
            self.n_ref_missing + other.n_ref_missing,
            self.sum_mm + other.sum_mm,
            self.sum_sq_mm2 + other.sum_sq_mm2,
        )

    def stats(self) -> ErrorStats:
        """AE, RMSE and STD per joint from the sums (NaN where a joint has no valid frame)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            n = np.where(self.n_frames > 0, self.n_frames, np.nan)
            mean = self.sum_mm / n
            mean_sq = self.sum_sq_mm2 / n
        # E[d²] - E[d]² can dip a hair below zero by rounding when all distances are equal.
        std = np.sqrt(np.maximum(mean_sq - mean**2, 0.0))
        std = np.where(np.isfinite(mean), std, np.nan)
        return ErrorStats(
            mean,
            np.sqrt(mean_sq),
            std,
            self.n_frames.copy(),
            self.n_missing.copy(),
            self.n_ref_missing.copy(),
        )


def error_stats(estimate: np.ndarray, reference: np.ndarray) -> ErrorStats:
    """Per-joint AE / RMSE / STD of a (T, J, 3) estimate against a (T, J, 3) reference (``ErrorStats``)."""
    estimate, reference = _check_pair(estimate, reference)
    return ErrorAccumulator.zeros(estimate.shape[-2]).add(estimate, reference).stats()


def mean_stats(items: Sequence[ErrorStats]) -> ErrorStats:
    """Average per-joint AE / RMSE / STD over several stats with equal weight; counts are summed.

    This is how the paper combines its per-gesture tables and its sensor combinations (section 3.3: "the
    average value of all combinations"). A joint that is NaN in any item is NaN in the mean, on purpose.
    """
    if not items:
        raise ValueError("mean_stats needs at least one ErrorStats")
    return ErrorStats(
        np.mean([s.ae_mm for s in items], axis=0),
        np.mean([s.rmse_mm for s in items], axis=0),
        np.mean([s.std_mm for s in items], axis=0),
        np.sum([s.n_frames for s in items], axis=0),
        np.sum([s.n_missing for s in items], axis=0),
        np.sum([s.n_ref_missing for s in items], axis=0),
    )


def group_means(
    values: np.ndarray, joints: Sequence[int] | np.ndarray, groups: Mapping[str, Iterable[int]]
) -> dict[str, np.ndarray]:
    """Mean of a per-joint metric over the joints of each group.

    Parameters
    ----------
    values : (..., K) array
        A metric for the K joints listed in ``joints`` (last axis).
    joints : (K,) ints
        The joint index (e.g. SDK index) of each column of ``values``.
    groups : mapping of group name -> joint indices
        Every joint of a group must be among ``joints``.

    Returns
    -------
    dict of group name -> (...) array
        Plain mean over the group's columns (NaN propagates: an unscored joint makes its group NaN).
    """
    values = np.asarray(values, dtype=np.float64)
    column = {int(j): k for k, j in enumerate(np.asarray(joints).tolist())}
    out: dict[str, np.ndarray] = {}
    for name, members in groups.items():
        members = [int(j) for j in members]
        missing = [j for j in members if j not in column]
        if missing:
            raise ValueError(f"group {name!r} has joints {missing} that are not among the evaluated {joints}")
        out[name] = values[..., [column[j] for j in members]].mean(axis=-1)
    return out


def lag_error_curve(
    estimate: np.ndarray, reference: np.ndarray, shifts: Sequence[int] | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Sum and count of joint distances between the output and the reference shifted by each lag.

    For a lag ``k`` the output at frame ``t`` is compared with the reference at frame ``t - k``: a positive
    lag that fits best means the output is late by ``k`` frames.

    Parameters
    ----------
    estimate, reference : (T, J, 3) array
        Positions in mm of the joints to pool (e.g. one joint group), NaN = missing.
    shifts : (K,) ints
        Candidate lags in frames, each with ``|k| < T``.

    Returns
    -------
    sums, counts : (K,) float64, (K,) int64
        Sum of the valid distances and their number for each lag; add them over takes, then ``best_lag``.
    """
    estimate, reference = _check_pair(estimate, reference)
    n_frames = estimate.shape[0]
    shifts = np.asarray(shifts, dtype=np.int64)
    sums = np.zeros(shifts.shape[0])
    counts = np.zeros(shifts.shape[0], dtype=np.int64)
    for idx, k in enumerate(shifts.tolist()):
        if abs(k) >= n_frames:
            continue
        if k >= 0:
            d = joint_distances(estimate[k:], reference[: n_frames - k])
        else:
            d = joint_distances(estimate[: n_frames + k], reference[-k:])
        ok = np.isfinite(d)
        sums[idx] = d[ok].sum()
        counts[idx] = int(ok.sum())
    return sums, counts


def best_lag(sums: np.ndarray, counts: np.ndarray, shifts: Sequence[int] | np.ndarray) -> tuple[float, float]:
    """The lag that minimizes the mean distance, refined to sub-frame by a parabola through its neighbours.

    Returns
    -------
    lag_frames, error_mm : float, float
        The refined lag (NaN when no lag had a valid frame) and the mean distance at the best integer lag.
        At the ends of the search range no refinement is done (the true lag may lie outside it).
    """
    shifts = np.asarray(shifts, dtype=np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):
        curve = np.where(np.asarray(counts) > 0, np.asarray(sums) / np.asarray(counts), np.nan)
    if not np.isfinite(curve).any():
        return float("nan"), float("nan")
    best = int(np.nanargmin(curve))
    lag = float(shifts[best])
    if 0 < best < len(curve) - 1 and np.isfinite(curve[best - 1 : best + 2]).all():
        left, mid, right = curve[best - 1], curve[best], curve[best + 1]
        denom = left - 2.0 * mid + right
        if denom > 0:
            lag += float(0.5 * (left - right) / denom) * float(shifts[best + 1] - shifts[best])
    return lag, float(curve[best])


def swap_counts(estimate: np.ndarray, reference: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How often an output has a left/right pair the wrong way round.

    A pair is swapped in a frame when exchanging its two labels brings the estimate closer to the reference:
    ``|eL - rR| + |eR - rL| < |eL - rL| + |eR - rR|``.

    Parameters
    ----------
    estimate, reference : (T, J, 3) array
        Positions in mm of all joints (indexed by ``pairs``), NaN = missing.
    pairs : (P, 2) ints
        (left, right) joint indices.

    Returns
    -------
    n_swapped, n_valid : (P,) int64, (P,) int64
        Frames with the pair swapped, and frames where all four positions were finite.
    """
    estimate, reference = _check_pair(estimate, reference)
    pairs = np.asarray(pairs, dtype=np.int64)
    e_left, e_right = estimate[:, pairs[:, 0]], estimate[:, pairs[:, 1]]
    r_left, r_right = reference[:, pairs[:, 0]], reference[:, pairs[:, 1]]
    keep, swap = pair_costs(e_left, e_right, r_left, r_right)
    valid = np.isfinite(keep) & np.isfinite(swap)
    return (valid & (swap < keep)).sum(axis=0), valid.sum(axis=0)


def jitter_sums(positions: np.ndarray) -> tuple[float, int]:
    """Sum of squared second differences of a trajectory, for an RMS jitter pooled over takes.

    The second difference ``x[t+1] - 2 x[t] + x[t-1]`` is the discrete acceleration in mm/frame². Its RMS over
    frames and joints measures shake: white noise of standard deviation s per axis gives ``s * sqrt(18)``
    (``sqrt(6)`` per axis, three axes), and smooth motion at 30 fps only a few mm/frame². Compare an output
    with the exact truth's own value, which is the motion's real acceleration.

    Parameters
    ----------
    positions : (T, J, 3) array
        Positions in mm, NaN = missing; a second difference counts only where all three frames are finite.

    Returns
    -------
    sum_sq_mm2, count : float, int
        Sum of the squared Euclidean norms of the valid second differences (mm²/frame⁴) and their number.
    """
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[-1] != 3:
        raise ValueError(f"positions must be (T, J, 3) mm, got shape {positions.shape}")
    if positions.shape[0] < 3:
        return 0.0, 0
    second = positions[2:] - 2.0 * positions[1:-1] + positions[:-2]
    norm_sq = np.sum(second**2, axis=-1)
    ok = np.isfinite(norm_sq)
    return float(norm_sq[ok].sum()), int(ok.sum())


def jitter_rms(sum_sq_mm2: float, count: int) -> float:
    """RMS second difference (mm/frame²) from ``jitter_sums`` (added over takes); NaN without a sample."""
    return float(np.sqrt(sum_sq_mm2 / count)) if count > 0 else float("nan")


def angular_errors(estimate: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Angle of the rotation from each reference orientation to the estimate, degrees in [0, 180].

    Parameters
    ----------
    estimate, reference : (..., 4) unit quaternions w, x, y, z (q and -q are the same orientation); NaN = none.

    Returns
    -------
    (...) float64 degrees; NaN where either is missing.
    """
    estimate = np.asarray(estimate, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64)
    if estimate.shape != reference.shape or estimate.shape[-1:] != (4,):
        raise ValueError(
            f"estimate and reference must be (..., 4) quaternions of one shape, got {estimate.shape}, {reference.shape}"
        )
    return quat_angle_deg(estimate, reference)


def angle_stats(errors_deg: np.ndarray) -> dict[str, float]:
    """Median, p90 and count of the finite angular errors (deg); NaN figures when there are none."""
    values = np.asarray(errors_deg, dtype=np.float64).ravel()
    values = values[np.isfinite(values)]
    if values.size == 0:
        return {"median_deg": float("nan"), "p90_deg": float("nan"), "n": 0}
    return {
        "median_deg": float(np.median(values)),
        "p90_deg": float(np.percentile(values, 90)),
        "n": int(values.size),
    }


def view_orientation_agreement(
    fused_orientations: np.ndarray,
    fused_positions: np.ndarray,
    view_orientations: np.ndarray,
    *,
    twist_only: bool = False,
) -> np.ndarray:
    """How far each view's joint orientations are from the fused ones, degrees: the real-data counterpart of
    :func:`angular_errors`, where no truth exists (ground-truth-free; errors the views share are invisible).

    Parameters
    ----------
    fused_orientations : (T, 32, 4) fused world quaternions of one person (NaN = none).
    fused_positions : (T, 32, 3) the fused positions, mm (for ``twist_only``).
    view_orientations : (T, S, 32, 4) that person's views' quaternions in the world frame
        (:func:`skelfuse.fusion.orientation.views_to_world`); NaN = not seen. Views the realignment flipped
        should be NaN here: their frames face the other way.
    twist_only : bool
        Swing each view onto the fused bones first, so that only the twist about the bone is compared (the
        swing follows the fused positions by construction).

    Returns
    -------
    (T, S, 32) float64 degrees, NaN where either is missing.
    """
    fused = np.asarray(fused_orientations, dtype=np.float64)
    views = np.asarray(view_orientations, dtype=np.float64)
    if views.ndim != 4 or fused.shape != (views.shape[0], *views.shape[2:]):
        raise ValueError(
            f"view_orientations must be (T, S, 32, 4) and fused_orientations (T, 32, 4); got {views.shape}, "
            f"{fused.shape}"
        )
    if twist_only:
        views = swing_onto_aims(views, aim_directions(fused_positions)[:, None])
    return quat_angle_deg(views, fused[:, None])


def nan_for_none(value: Any) -> Any:
    """What results' ``to_dict()`` wrote for NaN (``None``: JSON has no NaN) read back as NaN, in nested dicts
    and lists, so that a formatter gets the floats it was written for."""
    if value is None:
        return math.nan
    if isinstance(value, dict):
        return {k: nan_for_none(v) for k, v in value.items()}
    if isinstance(value, list):
        return [nan_for_none(v) for v in value]
    return value


def none_for_nan(value: Any) -> Any:
    """NaN written as ``None`` (JSON has no NaN), numpy scalars as Python ones, in nested dicts and lists: the
    inverse of :func:`nan_for_none`."""
    if isinstance(value, dict):
        return {k: none_for_nan(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [none_for_nan(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
