"""How far apart two sensors' clocks (or frame pairings) are, estimated from the person's motion. Pure.

Two views of one person see the same motion in different camera frames. Quantities that a rigid
transform leaves unchanged agree between the views: distances between joints (pelvis to wrists, ankles and
head, wrist to wrist, ankle to ankle) and the pelvis speed. :func:`motion_features` computes them per frame;
:func:`estimate_lag` slides one view's features over the other's on a common frame grid and takes the
shift with the highest mean Pearson correlation (masked for missing frames, computed for every shift at
once with FFTs).

What it can and cannot tell: it finds the shift where the *pose changes* line up, so it needs motion
(a person standing still gives no peak) and non-periodic motion (a steady gait correlates at every step,
about one second apart: :attr:`LagEstimate.ambiguous` says when a second peak comes close). The answer is
in whole frames; within a frame the device timestamps (or the grouping tolerance) decide.

Cycle::

    a = grid_features(times_a, motion_features(positions_a), period_us)
    b = grid_features(times_b, motion_features(positions_b), period_us)
    est = estimate_lag(band_pass(a.values), band_pass(b.values))   # b's frame k + lag shows a's frame k
    offset_us = a.start_us - b.start_us - est.lag * period_us   # add to b's times to match a's clock
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skelfuse.schema.skeleton import J

_DISTANCE_PAIRS = np.array(
    [
        [J["PELVIS"], J["WRIST_LEFT"]],
        [J["PELVIS"], J["WRIST_RIGHT"]],
        [J["PELVIS"], J["ANKLE_LEFT"]],
        [J["PELVIS"], J["ANKLE_RIGHT"]],
        [J["PELVIS"], J["HEAD"]],
        [J["WRIST_LEFT"], J["WRIST_RIGHT"]],
        [J["ANKLE_LEFT"], J["ANKLE_RIGHT"]],
    ],
    dtype=np.int64,
)
"""Joint pairs whose distance is a motion feature (left/right symmetric pairs, so a mirrored view agrees)."""

MIN_OVERLAP_FRAMES = 60
"""Shifts where the two views overlap in fewer frames than this are not considered (2 s at 30 fps)."""
AMBIGUOUS_RATIO = 0.9
"""A second peak (at least 5 frames from the best) reaching this fraction of the best makes it ambiguous."""


def motion_features(positions: np.ndarray) -> np.ndarray:
    """(T, 32, 3) one person's joints, mm → (T, F) frame-invariant features (NaN where a joint is missing).

    F = 8: seven joint distances (:data:`_DISTANCE_PAIRS`, symmetric in left/right) and the pelvis speed
    (central difference, mm per frame).
    """
    pos = np.asarray(positions, dtype=np.float64)
    dist = np.linalg.norm(pos[:, _DISTANCE_PAIRS[:, 0]] - pos[:, _DISTANCE_PAIRS[:, 1]], axis=-1)
    # left/right symmetric: a mirrored view swaps wrists and ankles; sort each symmetric pair
    dist[:, 0:2] = np.sort(dist[:, 0:2], axis=1)
    dist[:, 2:4] = np.sort(dist[:, 2:4], axis=1)
    speed = np.full((len(pos), 1), np.nan)
    if len(pos) >= 3:
        speed[1:-1, 0] = np.linalg.norm(pos[2:, 0] - pos[:-2, 0], axis=-1) / 2.0
    return np.concatenate([dist, speed], axis=1)


@dataclass(frozen=True)
class GridFeatures:
    """Features on a regular frame grid: row k is time ``start_us + k * period_us`` (NaN where no frame)."""

    start_us: int
    period_us: float
    values: np.ndarray


def grid_features(times_us: np.ndarray, features: np.ndarray, period_us: float) -> GridFeatures:
    """Place per-frame ``features`` (T, F) at their times on a grid of ``period_us`` from the first time."""
    times = np.asarray(times_us, dtype=np.int64)
    if len(times) == 0:
        return GridFeatures(0, float(period_us), np.zeros((0, features.shape[1])))
    start = int(times.min())
    index = np.rint((times - start) / period_us).astype(np.int64)
    grid = np.full((int(index.max()) + 1, features.shape[1]), np.nan)
    grid[index] = features
    return GridFeatures(start, float(period_us), grid)


def _xcorr(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """C[L + len(x) - 1] = sum_k x[k] y[k + L] for L in -(len(x)-1) .. len(y)-1, columns independent."""
    n = len(x) + len(y) - 1
    size = 1 << (n - 1).bit_length()
    fx = np.fft.rfft(x, size, axis=0)
    fy = np.fft.rfft(y, size, axis=0)
    c = np.fft.irfft(np.conj(fx) * fy, size, axis=0)
    # c[m] = sum_k x[k] y[k + m] (circular); negative shifts wrap to the end
    return np.concatenate([c[size - (len(x) - 1) :], c[: len(y)]]) if len(x) > 1 else c[: len(y)]


def band_pass(features: np.ndarray, short: int = 5, long: int = 45) -> np.ndarray:
    """Moving average over ``short`` frames minus over ``long`` frames, per column (NaN-aware).

    Keeps the pose changes of about 0.2-1.5 s and removes the slow trends (walking toward a sensor changes
    every distance a little) that would correlate at any shift, and the white jitter.
    """
    x = np.asarray(features, dtype=np.float64)
    valid = np.isfinite(x)
    values = np.where(valid, x, 0.0)

    def average(width: int) -> np.ndarray:
        # centred window [k - width // 2, k + (width - 1) // 2], clipped at the ends, by cumulative sums
        n = len(x)
        lo = np.clip(np.arange(n) - width // 2, 0, n)
        hi = np.clip(np.arange(n) + (width - 1) // 2 + 1, 0, n)
        csum = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(values, axis=0)])
        ccount = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(valid, axis=0)])
        num, den = csum[hi] - csum[lo], ccount[hi] - ccount[lo]
        out = np.full_like(num, np.nan)
        enough = den >= width / 2
        out[enough] = num[enough] / den[enough]
        return out

    if len(x) == 0:
        return x.copy()
    return average(short) - average(long)


@dataclass(frozen=True)
class LagEstimate:
    """Result of :func:`estimate_lag`.

    Attributes
    ----------
    lag : int
        Best shift in frames: frame ``k`` of ``a`` matches frame ``k + lag`` of ``b`` (0 when not ``found``).
    correlation : float
        Mean Pearson correlation of the features at ``lag`` (1 = identical motion).
    score : float
        Significance of that correlation, Fisher z times sqrt(overlap - 3): it decides between shifts, so a
        short chance overlap does not beat a long real one.
    score_at_zero : float
        The score at shift 0 (NaN when the views do not overlap enough there).
    second_best : float
        Highest score at least 5 frames away from ``lag``.
    overlap : int
        Frames both views hold at ``lag``.
    peaks : tuple of int
        The best local maxima of the score (up to 5, best first): candidate shifts.
    found : bool
        Some shift had enough overlap and motion to correlate.
    """

    lag: int
    correlation: float
    score: float
    score_at_zero: float
    second_best: float
    overlap: int
    peaks: tuple[int, ...]
    found: bool

    @property
    def ambiguous(self) -> bool:
        """A second shift scores almost as well (periodic motion): do not trust ``lag`` alone."""
        return bool(self.found and self.second_best >= AMBIGUOUS_RATIO * self.score)


def lag_correlations(
    a: np.ndarray, b: np.ndarray, *, min_overlap: int = MIN_OVERLAP_FRAMES
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lags, mean correlation per lag, overlap per lag) of grid features ``a`` (Ka, F) and ``b`` (Kb, F).

    Correlation is NaN where the overlap is below ``min_overlap`` or a feature does not vary.
    """
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    ma, mb = np.isfinite(a).astype(np.float64), np.isfinite(b).astype(np.float64)
    both = np.concatenate([a, b])
    finite = np.isfinite(both)
    count = finite.sum(axis=0)
    centre = np.where(count > 0, np.where(finite, both, 0.0).sum(axis=0) / np.maximum(count, 1), 0.0)
    x, y = np.where(ma > 0, a - centre, 0.0), np.where(mb > 0, b - centre, 0.0)
    n = _xcorr(ma, mb)
    sa, sb = _xcorr(x, mb), _xcorr(ma, y)
    saa, sbb, sab = _xcorr(x * x, mb), _xcorr(ma, y * y), _xcorr(x, y)
    with np.errstate(invalid="ignore", divide="ignore"):
        var_a = n * saa - sa * sa
        var_b = n * sbb - sb * sb
        r = (n * sab - sa * sb) / np.sqrt(var_a * var_b)
        floor = 1e-6 * np.maximum(n, 1) ** 2  # a feature that does not vary in the overlap says nothing
        valid = (n >= min_overlap - 0.5) & (var_a > floor) & (var_b > floor) & np.isfinite(r)
        n_valid = valid.sum(axis=1)
        mean_r = np.where(n_valid > 0, np.where(valid, r, 0.0).sum(axis=1) / np.maximum(n_valid, 1), np.nan)
    overlap = np.rint(n.max(axis=1)).astype(np.int64) if n.size else np.zeros(0, np.int64)
    lags = np.arange(-(len(a) - 1), len(b))
    return lags, mean_r, overlap


def estimate_lag(
    a: np.ndarray, b: np.ndarray, *, max_lag: int | None = None, min_overlap: int | None = None
) -> LagEstimate:
    """The frame shift of ``b`` against ``a`` (band-passed grid features) with the most significant match.

    ``max_lag`` bounds |lag| (None: any shift). ``min_overlap`` (default: a third of the shorter view, at
    least :data:`MIN_OVERLAP_FRAMES`) is the fewest common frames a shift needs.
    """
    none = LagEstimate(0, float("nan"), float("nan"), float("nan"), float("nan"), 0, (), False)
    if len(a) == 0 or len(b) == 0:
        return none
    if min_overlap is None:
        min_overlap = max(MIN_OVERLAP_FRAMES, min(len(a), len(b)) // 3)
    lags, r, overlap = lag_correlations(a, b, min_overlap=min_overlap)
    with np.errstate(invalid="ignore"):
        score = np.arctanh(np.clip(r, -0.999, 0.999)) * np.sqrt(np.maximum(overlap - 3, 1))
    if max_lag is not None:
        score = np.where(np.abs(lags) <= max_lag, score, np.nan)
    at_zero = float(score[lags == 0][0]) if (lags == 0).any() else float("nan")
    if not np.isfinite(score).any():
        return LagEstimate(0, float("nan"), float("nan"), at_zero, float("nan"), 0, (), False)
    best = int(np.nanargmax(score))
    far = np.abs(lags - lags[best]) >= 5
    second = float(np.nanmax(score[far])) if np.isfinite(score[far]).any() else float("nan")
    filled = np.where(np.isfinite(score), score, -np.inf)
    left = np.r_[-np.inf, filled[:-1]]
    right = np.r_[filled[1:], -np.inf]
    maxima = np.nonzero(np.isfinite(filled) & (filled >= left) & (filled >= right))[0]
    peaks = tuple(int(lags[i]) for i in maxima[np.argsort(-filled[maxima])][:5])
    return LagEstimate(
        int(lags[best]), float(r[best]), float(score[best]), at_zero, second, int(overlap[best]), peaks, True
    )
