"""The DBSCAN merge (:func:`skelfuse.fusion.merge.merge_dbscan`) as a compiled loop over joints.

Per joint: label the connected components of "distance <= eps" among its n candidates (with min_samples = 1
every point is a core point, so DBSCAN's clusters are exactly those components), score every component, pick the
winner by the keys of :mod:`skelfuse.fusion.merge` and average its sensor candidates. The numbers follow the
numpy reference (:mod:`skelfuse.fusion.reference.merge`) operation for operation where it matters: the squared
distance is ``(dx^2 + dy^2) + dz^2`` compared with ``eps^2``, the key is ``rank * (3 S + 1) + summed confidence``,
the centroids of a tie are rounded to 1e-6 mm.
"""

from __future__ import annotations

import numba
import numpy as np

from skelfuse.fusion.kernels.signatures import BOOL, FLOAT, HELPER, INT, KERNEL, UINT8, array

_ROUND_SCALE = 1e6  # centroid tie-break resolution: 1e-6 mm, as numpy's round(x, 6) (x * 1e6, rint, / 1e6)


@numba.njit(**HELPER)
def _label_components(points: np.ndarray, n: int, eps_sq: float, label: np.ndarray, stack: np.ndarray) -> None:
    """label[i] = component of candidate i (-1: missing) over the first n rows of points (n, 3)."""
    for i in range(n):
        label[i] = -2  # not visited
    n_labels = 0
    for i in range(n):
        if label[i] != -2:
            continue
        dx = points[i, 0] - points[i, 0]
        dy = points[i, 1] - points[i, 1]
        dz = points[i, 2] - points[i, 2]
        if not (dx * dx + dy * dy + dz * dz <= eps_sq):  # NaN or inf: no neighbour, not even itself
            label[i] = -1
            continue
        label[i] = n_labels
        top = 0
        stack[top] = i
        top += 1
        while top > 0:
            top -= 1
            a = stack[top]
            for b in range(n):
                if label[b] != -2:
                    continue
                dx = points[a, 0] - points[b, 0]
                dy = points[a, 1] - points[b, 1]
                dz = points[a, 2] - points[b, 2]
                if dx * dx + dy * dy + dz * dz <= eps_sq:
                    label[b] = n_labels
                    stack[top] = b
                    top += 1
        n_labels += 1


@numba.njit(**HELPER)
def _pick_winner(points: np.ndarray, label: np.ndarray, n_sensors: int, key: np.ndarray, centroid: np.ndarray) -> int:
    """The winning sensor candidate (its component wins) from the keys; ties by rounded centroid x, y, z."""
    best = 0
    for s in range(1, n_sensors):
        if key[s] > key[best]:
            best = s
    if label[best] < 0:
        return best  # no sensor candidate at all
    n_tied = 0
    n_members = 0
    for s in range(n_sensors):
        if label[s] >= 0 and key[s] == key[best]:
            n_tied += 1
        if label[s] == label[best]:
            n_members += 1
    if n_tied == n_members:
        return best  # only the winner's own members hold the best key
    # Tied components: the smallest centroid of sensor candidates (rounded), x then y then z; then the lowest index.
    for s in range(n_sensors):
        centroid[s, 0] = centroid[s, 1] = centroid[s, 2] = 0.0
    for s in range(n_sensors):
        if label[s] < 0:
            continue
        count = 0
        for t in range(n_sensors):
            if label[t] == label[s]:
                count += 1
                for axis in range(3):
                    centroid[s, axis] += points[t, axis]
        for axis in range(3):
            centroid[s, axis] = np.rint(centroid[s, axis] / count * _ROUND_SCALE) / _ROUND_SCALE
    winner = -1
    for s in range(n_sensors):
        if label[s] < 0 or key[s] != key[best]:
            continue
        if winner < 0:
            winner = s
            continue
        for axis in range(3):
            if centroid[s, axis] < centroid[winner, axis]:
                winner = s
                break
            if centroid[s, axis] > centroid[winner, axis]:
                break
    return winner


@numba.njit(**HELPER)
def _gather(
    positions: np.ndarray,
    confidence: np.ndarray,
    reference: np.ndarray,
    previous: np.ndarray,
    b: int,
    j: int,
    use_ref: bool,
    use_prev: bool,
    points: np.ndarray,
    conf: np.ndarray,
) -> tuple[int, int, int]:
    """Joint (b, j)'s candidates into points (sensors, then the reference and the previous position) and the
    sensors' confidences into conf; returns their count and the reference's and previous position's rows (-1)."""
    S = positions.shape[1]
    for s in range(S):
        for axis in range(3):
            points[s, axis] = positions[b, s, j, axis]
        conf[s] = confidence[b, s, j]
    n = S
    ref_idx = prev_idx = -1
    if use_ref:
        ref_idx = n
        for axis in range(3):
            points[n, axis] = reference[b, j, axis]
        n += 1
    if use_prev:
        prev_idx = n
        for axis in range(3):
            points[n, axis] = previous[b, j, axis]
        n += 1
    return n, ref_idx, prev_idx


@numba.njit(**HELPER)
def _score(
    label: np.ndarray,
    conf: np.ndarray,
    n: int,
    n_sensors: int,
    ref_idx: int,
    prev_idx: int,
    rank: np.ndarray,
    code: np.ndarray,
    conf_sum: np.ndarray,
    key: np.ndarray,
) -> None:
    """key[s] = the key of sensor candidate s's component: rank of its code (n_sensors + span has_ref + 2 span
    has_prev) times (3 S + 1), plus its summed confidence; a missing candidate gets code 0's (below every one)."""
    span = n_sensors + 1
    for c in range(n):
        code[c] = 0
        conf_sum[c] = 0.0
    for s in range(n_sensors):
        if label[s] >= 0:
            code[label[s]] += 1
            conf_sum[label[s]] += conf[s]
    if ref_idx >= 0 and label[ref_idx] >= 0:
        code[label[ref_idx]] += span
    if prev_idx >= 0 and label[prev_idx] >= 0:
        code[label[prev_idx]] += 2 * span
    for s in range(n_sensors):
        if label[s] >= 0:
            key[s] = rank[code[label[s]]] * (3 * n_sensors + 1) + conf_sum[label[s]]
        else:
            key[s] = rank[0] * (3 * n_sensors + 1)


_SIGNATURE = (
    array(FLOAT, 4),  # positions
    array(INT, 3),  # confidence
    array(FLOAT, 3),  # reference
    array(FLOAT, 3),  # previous
    BOOL,  # use_ref
    BOOL,  # use_prev
    FLOAT,  # eps_mm
    array(INT, 1),  # rank
)


@numba.njit(_SIGNATURE, **KERNEL)
def merge_dbscan(
    positions: np.ndarray,
    confidence: np.ndarray,
    reference: np.ndarray,
    previous: np.ndarray,
    use_ref: bool,
    use_prev: bool,
    eps_mm: float,
    rank: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """DBSCAN merge of every joint; arguments and outputs as :func:`skelfuse.fusion.merge.merge_dbscan`.

    Parameters
    ----------
    positions : (B, S, J, 3) float64, mm; confidence : (B, S, J) int64.
    reference, previous : (B, J, 3) float64, mm (any shape when the matching ``use_*`` flag is False).
    rank : (4 (S + 1),) int64, the rank of each cluster code (:func:`skelfuse.fusion.merge.rank_table`).

    Returns
    -------
    merged (B, J, 3) float64, n_agree (B, J) int16, confidence (B, J) uint8, members (B, J, S) bool.
    """
    B, S, J, _ = positions.shape
    n_max = S + 2
    eps_sq = eps_mm * eps_mm
    merged = np.empty((B, J, 3))
    n_agree = np.empty((B, J), dtype=np.int16)
    best_conf = np.empty((B, J), dtype=np.uint8)
    members = np.empty((B, J, S), dtype=np.bool_)
    points = np.empty((n_max, 3))
    conf = np.empty(S, dtype=np.int64)
    label = np.empty(n_max, dtype=np.int64)
    stack = np.empty(n_max, dtype=np.int64)
    code = np.empty(n_max, dtype=np.int64)
    conf_sum = np.empty(n_max)
    key = np.empty(S)
    centroid = np.empty((S, 3))
    for b in range(B):
        for j in range(J):
            n, ref_idx, prev_idx = _gather(
                positions, confidence, reference, previous, b, j, use_ref, use_prev, points, conf
            )
            _label_components(points, n, eps_sq, label, stack)
            _score(label, conf, n, S, ref_idx, prev_idx, rank, code, conf_sum, key)
            winner = _pick_winner(points, label, S, key, centroid)
            win_label = label[winner]
            count = 0
            sx = sy = sz = 0.0
            top = 0
            for s in range(S):
                members[b, j, s] = win_label >= 0 and label[s] == win_label
                if members[b, j, s]:
                    count += 1
                    sx += points[s, 0]
                    sy += points[s, 1]
                    sz += points[s, 2]
                    if conf[s] > top:
                        top = conf[s]
            n_agree[b, j] = count
            best_conf[b, j] = top
            if count > 0:
                merged[b, j, 0] = sx / count
                merged[b, j, 1] = sy / count
                merged[b, j, 2] = sz / count
            else:
                merged[b, j, 0] = merged[b, j, 1] = merged[b, j, 2] = np.nan
    return merged, n_agree, best_conf, members


@numba.njit((array(FLOAT, 4), array(UINT8, 3), INT), **KERNEL)
def select_candidates(
    candidates: np.ndarray, confidence: np.ndarray, min_confidence: int
) -> tuple[np.ndarray, np.ndarray]:
    """The usable candidates (:func:`skelfuse.fusion.pipeline.select_candidates`): NaN, confidence 0 where a
    coordinate is not finite (their sum is not) or the confidence is below ``min_confidence``."""
    B, S, J = candidates.shape[0], candidates.shape[1], candidates.shape[2]
    positions = np.empty((B, S, J, 3))
    out_confidence = np.empty((B, S, J), dtype=np.uint8)
    for b in range(B):
        for s in range(S):
            for j in range(J):
                x, y, z = candidates[b, s, j, 0], candidates[b, s, j, 1], candidates[b, s, j, 2]
                if np.isfinite(x + y + z) and confidence[b, s, j] >= min_confidence:
                    positions[b, s, j, 0], positions[b, s, j, 1], positions[b, s, j, 2] = x, y, z
                    out_confidence[b, s, j] = confidence[b, s, j]
                else:
                    positions[b, s, j, 0] = positions[b, s, j, 1] = positions[b, s, j, 2] = np.nan
                    out_confidence[b, s, j] = 0
    return positions, out_confidence


def warm_up() -> None:
    """Compile (or load) :func:`merge_dbscan` and :func:`select_candidates` for their signatures."""
    positions = np.zeros((1, 2, 1, 3))
    points = np.zeros((1, 1, 3))
    rank = np.zeros(12, dtype=np.int64)
    rank.setflags(write=False)  # as rank_table's cached tables: the same (read-only) signature
    merge_dbscan(positions, np.ones((1, 2, 1), dtype=np.int64), points, points, True, True, 100.0, rank)
    select_candidates(positions, np.ones((1, 2, 1), dtype=np.uint8), 1)
