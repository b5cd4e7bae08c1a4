"""The numpy form of the DBSCAN merge: the test reference of :func:`skelfuse.fusion.merge.merge_dbscan`.

The live path runs the compiled kernel (:mod:`skelfuse.fusion.kernels.merge`) and never imports this module (an
import-linter contract in pyproject.toml holds it so); the tests compare the two on random inputs, and
``skelfuse bench instant --reference`` times this form in place of the kernel. The rules it implements (weights,
winner, ties, output) are documented in :mod:`skelfuse.fusion.merge`.

For each of the B*J joints at once it builds the (n, n) adjacency of its n candidates, closes it by repeated
boolean matrix squaring (at most ceil(log2(n - 1)) products, each doubling the longest path covered), scores
every cluster, and takes the best one. No Python loop runs over joints or sensors.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from skelfuse.fusion.merge import MergeResult, rank_table

_ROUND_DECIMALS = 6  # centroid tie-break resolution, mm


def cluster_matrix(points: np.ndarray, eps_mm: float) -> np.ndarray:
    """Same-cluster matrix of DBSCAN with min_samples = 1, for many small point sets at once.

    Parameters
    ----------
    points : (N, n, 3) float, mm
        N independent sets of n points; a point with any NaN coordinate is missing.
    eps_mm : float
        Neighbourhood radius, mm (inclusive, like scikit-learn's ``eps``).

    Returns
    -------
    (N, n, n) float64 of 0/1: entry [k, a, b] is 1 when points a and b of set k are valid and in the same
    connected component of "distance <= eps". The diagonal is 1 exactly for the valid points.
    """
    return _same_cluster(np.ascontiguousarray(np.transpose(points, (2, 0, 1))), eps_mm)


def _same_cluster(axes: np.ndarray, eps_mm: float) -> np.ndarray:
    """:func:`cluster_matrix` on points laid out (3, N, n): per-axis differences avoid a slow sum over 3."""
    diff = axes[:, :, :, None] - axes[:, :, None, :]
    diff *= diff
    # NaN compares False, so a missing point has no neighbour, not even itself.
    reach = ((diff[0] + diff[1] + diff[2]) <= eps_mm * eps_mm).astype(np.float64)
    # Squaring a reflexive adjacency doubles the path length it covers; n - 1 hops connect any component. A
    # squaring that adds no pair (the count of nonzero entries is unchanged: entries only grow) shows the
    # relation already closed, so the loop stops there: candidates of a joint lie a few hops apart, so with many
    # sensors most of the ceil(log2(n - 1)) squarings are not needed (bench instant's crowd, line profile: 3.4 of 5
    # per call at 16 x 6, 4 of 7 at 64 x 1).
    linked = np.count_nonzero(reach)
    for _ in range(_closure_steps(axes.shape[2])):
        reach = reach @ reach  # entries count paths: exact integers, far below float overflow for n < 100
        now_linked = np.count_nonzero(reach)
        if now_linked == linked:
            break
        linked = now_linked
    return np.minimum(reach, 1.0)


def _closure_steps(n: int) -> int:
    return max(0, int(np.ceil(np.log2(max(n - 1, 1)))))


@lru_cache(maxsize=64)
def _code_weights(n_sensors: int, use_ref: bool, use_prev: bool) -> np.ndarray:
    """Per-candidate weight whose sum over a cluster's members is its code (see :func:`rank_table`)."""
    span = n_sensors + 1
    weights = [1.0] * n_sensors + [float(span)] * use_ref + [float(2 * span)] * use_prev
    out = np.array(weights)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=64)
def _rows(n: int) -> np.ndarray:
    out = np.arange(n)
    out.setflags(write=False)
    return out


def merge_dbscan(
    positions: np.ndarray,
    confidence: np.ndarray,
    reference: np.ndarray | None = None,
    previous: np.ndarray | None = None,
    eps_mm: float = 100.0,
    reference_weight: float | None = 2.0,
    previous_weight: float | None = 1.0,
) -> MergeResult:
    """:func:`skelfuse.fusion.merge.merge_dbscan` in numpy (its contract, weights, ties and empty cases are
    documented there)."""
    B, S, J, _ = positions.shape
    N = B * J
    sensor_axes = np.transpose(positions, (3, 0, 2, 1)).reshape(3, N, S)  # (3, N, S), a copy
    sensor_conf = np.transpose(confidence, (0, 2, 1)).reshape(N, S).astype(np.float64)
    parts = [sensor_axes]
    use_ref = reference_weight is not None and reference is not None
    use_prev = previous_weight is not None and previous is not None
    span = S + 1
    if use_ref and reference is not None:
        parts.append(np.transpose(reference, (2, 0, 1)).reshape(3, N, 1))
    if use_prev and previous is not None:
        parts.append(np.transpose(previous, (2, 0, 1)).reshape(3, N, 1))
    axes = np.concatenate(parts, axis=2) if len(parts) > 1 else sensor_axes
    same = _same_cluster(axes, eps_mm)  # (N, n, n)
    sensor_same = same[:, :S, :S]  # (N, S, S): only sensor candidates can represent a winning cluster
    n = axes.shape[2]
    valid = same.reshape(N, n * n)[:, : S * (n + 1) : n + 1] > 0  # diagonal: the valid sensor candidates

    # Lexicographic key per sensor candidate's cluster: rank of (score, has_prev, n, has_ref), then
    # summed confidence. Both are sums over members, so two matmuls give them for every cluster at once.
    code = (same[:, :S] @ _code_weights(S, use_ref, use_prev)).astype(np.intp)  # (N, S)
    conf_sum = (sensor_same @ sensor_conf[..., None])[..., 0]  # (N, S)
    rank = rank_table(S, reference_weight if use_ref else None, previous_weight if use_prev else None)[code]
    key = rank * (3 * S + 1) + conf_sum  # a missing candidate has code 0, rank -1: a negative key
    winner = key.argmax(axis=1)
    rows = _rows(N)
    members = sensor_same[rows, winner]  # (N, S) 0/1
    tied = (key == key[rows, winner][:, None]) & valid
    safe_axes = np.where(valid, sensor_axes, 0.0)  # (3, N, S), 0 where missing
    if np.count_nonzero(tied) != np.count_nonzero(members):  # another cluster has the same key somewhere
        winner = _break_ties(tied, sensor_same, safe_axes.transpose(1, 2, 0))
        members = sensor_same[rows, winner]

    n_agree = code[rows, winner] % span
    # 0 / NaN is a quiet NaN: a joint no sensor reports becomes NaN without a division warning.
    sums = (members[:, None, :] @ safe_axes.transpose(1, 2, 0))[:, 0]  # (N, 3)
    merged = sums / np.where(n_agree > 0, n_agree, np.nan)[:, None]
    best_conf = (members * sensor_conf).max(axis=1)
    return MergeResult(
        positions=merged.reshape(B, J, 3),
        n_agree=n_agree.astype(np.int16).reshape(B, J),
        confidence=best_conf.astype(np.uint8).reshape(B, J),
        members=(members > 0).reshape(B, J, S),
    )


def _break_ties(tied: np.ndarray, sensor_same: np.ndarray, safe_pts: np.ndarray) -> np.ndarray:
    """Among tied clusters pick the smallest sensor centroid, x then y then z; returns winner indices (N,).

    Only runs on frames where some joint has a tie, so the common path stays cheap.
    """
    count = np.maximum(sensor_same.sum(axis=2), 1.0)[..., None]
    centroid = np.round((sensor_same @ safe_pts) / count, _ROUND_DECIMALS)  # (N, S, 3)
    for axis in range(3):  # lexicographic over the three axes
        value = np.where(tied, centroid[..., axis], np.inf)
        tied = tied & (value == value.min(axis=1, keepdims=True))
    return tied.argmax(axis=1)
