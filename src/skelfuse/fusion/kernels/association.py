"""The association's cost matrix and track assignment (:func:`skelfuse.fusion.association.associate`, steps 2-3) as
compiled loops, with a rectangular Hungarian solver.

:func:`linear_sum_assignment` is the shortest augmenting path method (Crouse 2016, "On implementing 2D rectangular
assignment algorithms", IEEE TAES 52(4), pp. 1685-1686), in the form scipy's ``linear_sum_assignment`` implements
it, so that ties resolve the same way: rows are augmented in order, the columns scanned from the last, and among
equally short paths one that ends at a free column wins. A tall matrix is solved transposed. The tests hold it to
scipy's assignment on random matrices (ties, rectangular, empty, infinite costs).

:func:`match_tracks` adds the descriptors before and the duplicates after it (steps 1-4 in one call).
:func:`person_descriptors` gathers each person's descriptor (the median over its sensors) and sensor count after
the assignment; its numpy form is in the reference too.

:func:`assign_to_tracks` is the cascade of :func:`~skelfuse.fusion.association.associate` (confirmed tracks first,
then the tentative ones with the bodies left), per sensor, with its fast path for sensors where every gated pair
stands alone; the numpy form is :mod:`skelfuse.fusion.reference.association`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from skelfuse.fusion.kernels.signatures import BOOL, FLOAT, HELPER, INT, KERNEL, array

BIG_COST = 1e12
"""Stands for "no cost" (a pair outside the gate) in the assignment matrices; such pairs are rejected after."""


@numba.njit(**HELPER)
def _filled(n: int, value: int) -> np.ndarray:
    """An (n,) int64 array of ``value`` (a loop: numba's np.full compiles per signature)."""
    out = np.empty(n, dtype=np.int64)
    for i in range(n):
        out[i] = value
    return out


@numba.njit(**HELPER, inline="always")
def _augmenting_path(
    cost: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    path: np.ndarray,
    row4col: np.ndarray,
    shortest: np.ndarray,
    row: int,
    in_rows: np.ndarray,
    in_cols: np.ndarray,
    remaining: np.ndarray,
) -> tuple[int, float]:
    """The shortest augmenting path from free ``row``: its sink column (-1: infeasible) and its length."""
    nc = cost.shape[1]
    min_val = 0.0
    n_remaining = nc
    for it in range(nc):
        remaining[it] = nc - it - 1  # from the last column: a constant matrix gives the identity
    for i in range(in_rows.shape[0]):  # loops, not slice assignments (those compile numba's broadcasting)
        in_rows[i] = False
    for j in range(nc):
        in_cols[j] = False
        shortest[j] = math.inf
    sink = -1
    i = row
    while sink == -1:
        index = -1
        lowest = math.inf
        in_rows[i] = True
        for it in range(n_remaining):
            j = remaining[it]
            r = min_val + cost[i, j] - u[i] - v[j]
            if r < shortest[j]:
                path[j] = i
                shortest[j] = r
            # Among equally short, one that reaches a free column ends the search.
            if shortest[j] < lowest or (shortest[j] == lowest and row4col[j] == -1):
                lowest = shortest[j]
                index = it
        min_val = lowest
        if min_val == math.inf:
            return -1, min_val
        j = remaining[index]
        if row4col[j] == -1:
            sink = j
        else:
            i = row4col[j]
        in_cols[j] = True
        n_remaining -= 1
        remaining[index] = remaining[n_remaining]
    return sink, min_val


@numba.njit((array(FLOAT, 2),), **KERNEL)
def linear_sum_assignment(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """The minimum-cost assignment of a (R, C) cost matrix: row indices (ascending), their columns, and a status.

    Status 0: solved; 1: a NaN or -inf cost (nothing solved); 2: infeasible (some row or column cannot be
    assigned at a finite cost). min(R, C) pairs.
    """
    transpose = matrix.shape[1] < matrix.shape[0]
    nr, nc = (matrix.shape[1], matrix.shape[0]) if transpose else (matrix.shape[0], matrix.shape[1])
    cost = np.empty((nr, nc))
    for i in range(nr):
        for j in range(nc):
            cost[i, j] = matrix[j, i] if transpose else matrix[i, j]
            if cost[i, j] != cost[i, j] or cost[i, j] == -math.inf:
                return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64), 1
    if nr == 0 or nc == 0:
        return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64), 0
    u = np.empty(nr)
    v = np.empty(nc)
    for i in range(nr):
        u[i] = 0.0
    for j in range(nc):
        v[j] = 0.0
    shortest = np.empty(nc)
    path = _filled(nc, -1)
    col4row = _filled(nr, -1)
    row4col = _filled(nc, -1)
    in_rows = np.empty(nr, dtype=np.bool_)  # cleared by each search
    in_cols = np.empty(nc, dtype=np.bool_)
    remaining = np.empty(nc, dtype=np.int64)
    for current in range(nr):
        sink, min_val = _augmenting_path(cost, u, v, path, row4col, shortest, current, in_rows, in_cols, remaining)
        if sink < 0:
            return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64), 2
        # The dual variables.
        u[current] += min_val
        for i in range(nr):
            if in_rows[i] and i != current:
                u[i] += min_val - shortest[col4row[i]]
        for j in range(nc):
            if in_cols[j]:
                v[j] -= min_val - shortest[j]
        # Augment along the path.
        j = sink
        while True:
            i = path[j]
            row4col[j] = i
            col4row[i], j = j, col4row[i]
            if i == current:
                break
    if transpose:
        # Pairs by ascending original row (the transposed matrix's columns; distinct, so no ties to break).
        rows = np.empty(nr, dtype=np.int64)
        cols = np.empty(nr, dtype=np.int64)
        n = 0
        for original_row in range(nc):
            for i in range(nr):
                if col4row[i] == original_row:
                    rows[n], cols[n] = original_row, i
                    n += 1
        return rows, cols, 0
    rows = np.empty(nr, dtype=np.int64)
    for i in range(nr):
        rows[i] = i
    return rows, col4row, 0


@numba.njit(**HELPER)
def descriptor_costs(body_desc: np.ndarray, tracks: np.ndarray, min_common_points: int) -> np.ndarray:
    """(S, B, K) mean distance (mm) over the descriptor points a body (S, B, D, 3) and a track (K, D, 3) both have;
    inf with fewer than ``min_common_points`` (at least 1) in common."""
    S, B, D = body_desc.shape[0], body_desc.shape[1], body_desc.shape[2]
    K = tracks.shape[0]
    need = max(min_common_points, 1)
    cost = np.empty((S, B, K))
    for s in range(S):
        for b in range(B):
            for k in range(K):
                total = 0.0
                count = 0
                for d in range(D):
                    dx = body_desc[s, b, d, 0] - tracks[k, d, 0]
                    dy = body_desc[s, b, d, 1] - tracks[k, d, 1]
                    dz = body_desc[s, b, d, 2] - tracks[k, d, 2]
                    dist = math.sqrt(dx * dx + dy * dy + dz * dz)
                    if math.isfinite(dist):
                        total += dist
                        count += 1
                cost[s, b, k] = total / count if count >= need else math.inf
    return cost


@numba.njit(**HELPER)
def _indices(mask: np.ndarray, person: np.ndarray) -> np.ndarray:
    """The indices where a (N,) bool mask holds and ``person`` (N,) is -1 (unassigned), ascending."""
    out = np.empty(mask.shape[0], dtype=np.int64)
    n = 0
    for i in range(mask.shape[0]):
        if mask[i] and person[i] < 0:
            out[n] = i
            n += 1
    return out[:n]


@numba.njit(**HELPER)
def _assign_sensor(
    cost: np.ndarray,
    allowed: np.ndarray,
    usable: np.ndarray,
    in_stage: np.ndarray,
    person: np.ndarray,
    assigned_cost: np.ndarray,
) -> None:
    """One cascade stage for one sensor, in place: its free usable bodies (B,) to the stage's tracks (K,)."""
    B, K = allowed.shape
    simple = True
    gated = np.empty((B, K), dtype=np.bool_)
    for b in range(B):
        for k in range(K):
            gated[b, k] = allowed[b, k] and in_stage[k] and person[b] < 0
    for b in range(B):
        n_gated = 0
        for k in range(K):
            n_gated += 1 if gated[b, k] else 0
        simple = simple and n_gated <= 1
    for k in range(K):
        n_gated = 0
        for b in range(B):
            n_gated += 1 if gated[b, k] else 0
        simple = simple and n_gated <= 1
    if simple:  # every gated pair stands alone: any optimal assignment holds them all (the Hungarian result)
        for b in range(B):
            for k in range(K):
                if gated[b, k]:
                    person[b] = k
                    assigned_cost[b] = cost[b, k]
        return
    rows = _indices(usable, person)
    stage_tracks = np.empty(K, dtype=np.int64)  # a loop, not _indices: in_stage may be read-only (a second compile)
    n_cols = 0
    for k in range(K):
        if in_stage[k]:
            stage_tracks[n_cols] = k
            n_cols += 1
    cols = stage_tracks[:n_cols]
    matrix = np.empty((rows.size, cols.size))
    for r in range(rows.size):
        for c in range(cols.size):
            matrix[r, c] = cost[rows[r], cols[c]] if allowed[rows[r], cols[c]] else BIG_COST
    r_idx, c_idx, _ = linear_sum_assignment(matrix)  # finite costs: always solved
    for n in range(r_idx.size):
        b, k = rows[r_idx[n]], cols[c_idx[n]]
        if allowed[b, k]:
            person[b] = k
            assigned_cost[b] = matrix[r_idx[n], c_idx[n]]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def assign_to_tracks(
    body_desc: np.ndarray,
    usable: np.ndarray,
    tracks: np.ndarray,
    confirmed: np.ndarray,
    gate_mm: np.ndarray,
    min_common_points: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steps 2-3 of the association: the cost matrix, then per sensor the Hungarian assignment of its bodies to
    the tracks under the gate, confirmed tracks first, then the tentative ones with the bodies left.

    Parameters
    ----------
    body_desc : (S, B, D, 3) float64 mm; usable : (S, B) bool; tracks : (K, D, 3) float64 mm predicted
    descriptors; confirmed : (K,) bool; gate_mm : (K,) float64; min_common_points : int.

    Returns
    -------
    person (S, B) int64 track of each body (-1: none), assigned_cost (S, B) float64 (NaN: none), cost (S, B, K).
    """
    cost = descriptor_costs(body_desc, tracks, min_common_points)
    person, assigned_cost = _cascade(cost, usable, confirmed, gate_mm)
    return person, assigned_cost, cost


@numba.njit(**HELPER, inline="always")
def _cascade(
    cost: np.ndarray, usable: np.ndarray, confirmed: np.ndarray, gate_mm: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Step 3 on the (S, B, K) costs: per sensor, the Hungarian assignment under the gate, confirmed tracks first,
    then the tentative ones with the bodies left; returns person (S, B) and assigned_cost (S, B) as
    :func:`assign_to_tracks`. Inlined into its callers (one compiled function less)."""
    S, B, K = cost.shape
    allowed = np.empty((S, B, K), dtype=np.bool_)
    for s in range(S):
        for b in range(B):
            for k in range(K):
                allowed[s, b, k] = usable[s, b] and cost[s, b, k] <= gate_mm[k]
    person = np.empty((S, B), dtype=np.int64)
    assigned_cost = np.empty((S, B))
    for s in range(S):
        for b in range(B):
            person[s, b], assigned_cost[s, b] = -1, np.nan
    tentative = np.empty(K, dtype=np.bool_)
    n_confirmed = 0
    for k in range(K):
        tentative[k] = not confirmed[k]
        n_confirmed += 1 if confirmed[k] else 0
    for stage in range(2):
        in_stage = confirmed if stage == 0 else tentative
        if (n_confirmed if stage == 0 else K - n_confirmed) == 0:
            continue
        for s in range(S):
            _assign_sensor(cost[s], allowed[s], usable[s], in_stage, person[s], assigned_cost[s])
    return person, assigned_cost


_MATCH_TRACKS = (
    array(FLOAT, 4),  # positions
    array(BOOL, 2),  # valid
    array(INT, 1),  # central
    array(INT, 2),  # pairs
    array(FLOAT, 3),  # tracks
    array(BOOL, 1),  # confirmed
    array(FLOAT, 1),  # gate_mm
    INT,  # min_common_points
    FLOAT,  # duplicate_mm
)


@numba.njit(_MATCH_TRACKS, **KERNEL)
def match_tracks(
    positions: np.ndarray,
    valid: np.ndarray,
    central: np.ndarray,
    pairs: np.ndarray,
    tracks: np.ndarray,
    confirmed: np.ndarray,
    gate_mm: np.ndarray,
    min_common_points: int,
    duplicate_mm: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Steps 1-4 of the association: the bodies' torso descriptors, which bodies can be compared,
    :func:`assign_to_tracks`, and the leftovers dropped as duplicates of a body their sensor gave the same track.

    Parameters
    ----------
    positions : (S, B, J, 3) float64 mm; valid : (S, B) bool; central : (C,) int64 joints; pairs : (M, 2) int64
    joint pairs whose midpoints follow (descriptor order); tracks, confirmed, gate_mm, min_common_points: as
    :func:`assign_to_tracks`; duplicate_mm : float (NaN: never drop).

    Returns
    -------
    body_desc (S, B, D, 3), usable (S, B) bool, person (S, B) int64, assigned_cost (S, B), cost (S, B, K),
    duplicates (S, B) bool, leftover (S, B) bool (usable, unassigned, not a duplicate).
    """
    S, B = valid.shape
    C, M = central.shape[0], pairs.shape[0]
    body_desc = np.empty((S, B, C + M, 3))
    usable = np.empty((S, B), dtype=np.bool_)
    for s in range(S):
        for b in range(B):
            n_finite = 0
            for d in range(C + M):
                for c in range(3):
                    if d < C:
                        body_desc[s, b, d, c] = positions[s, b, central[d], c]
                    else:
                        first, second = pairs[d - C, 0], pairs[d - C, 1]
                        body_desc[s, b, d, c] = 0.5 * (positions[s, b, first, c] + positions[s, b, second, c])
                x, y, z = body_desc[s, b, d, 0], body_desc[s, b, d, 1], body_desc[s, b, d, 2]
                n_finite += 1 if math.isfinite(x) and math.isfinite(y) and math.isfinite(z) else 0
            usable[s, b] = valid[s, b] and n_finite >= min_common_points
    cost = descriptor_costs(body_desc, tracks, min_common_points)
    person, assigned_cost = _cascade(cost, usable, confirmed, gate_mm)
    duplicates = np.empty((S, B), dtype=np.bool_)
    leftover = np.empty((S, B), dtype=np.bool_)
    for s in range(S):
        for b in range(B):
            duplicates[s, b] = leftover[s, b] = False
            if not (usable[s, b] and person[s, b] < 0):
                continue
            for other in range(B):  # a track that took another body of this sensor, within duplicate_mm
                k = person[s, other]
                if k >= 0 and cost[s, b, k] <= duplicate_mm:
                    duplicates[s, b] = True
            leftover[s, b] = not duplicates[s, b]
    return body_desc, usable, person, assigned_cost, cost, duplicates, leftover


@numba.njit((array(FLOAT, 4), array(INT, 2), INT), **KERNEL)
def person_descriptors(body_desc: np.ndarray, person: np.ndarray, n_persons: int) -> tuple[np.ndarray, np.ndarray]:
    """Per person, the median over its sensors of their bodies' descriptors, and how many sensors see it.

    Parameters
    ----------
    body_desc : (S, B, D, 3) float64 mm; person : (S, B) int64, row of each body (-1: none; at most one body per
    sensor and row); n_persons : P.

    Returns
    -------
    descriptors (P, D, 3) float64 (NaN where no sensor has the point), n_sensors_seen (P,) int64.
    """
    S, B, D = body_desc.shape[0], body_desc.shape[1], body_desc.shape[2]
    descriptors = np.empty((n_persons, D, 3))
    n_seen = np.empty(n_persons, dtype=np.int64)
    seen = np.empty(S)  # one person's values of one coordinate, sorted as they come (a handful of sensors)
    for p in range(n_persons):
        n_seen[p] = 0
    for s in range(S):
        for b in range(B):
            if person[s, b] >= 0:
                n_seen[person[s, b]] += 1
    for p in range(n_persons):
        for d in range(D):
            for c in range(3):
                count = 0
                for s in range(S):
                    for b in range(B):
                        value = body_desc[s, b, d, c]
                        if person[s, b] != p or not math.isfinite(value):
                            continue
                        at = count
                        while at > 0 and seen[at - 1] > value:
                            seen[at] = seen[at - 1]
                            at -= 1
                        seen[at] = value
                        count += 1
                descriptors[p, d, c] = 0.5 * (seen[(count - 1) // 2] + seen[count // 2]) if count else np.nan
    return descriptors, n_seen


def warm_up() -> None:
    """Run the live path's kernels (:func:`match_tracks`, :func:`person_descriptors`; each compiled for its one
    signature when this module loads, or loaded from the cache) on tiny inputs."""
    desc = np.zeros((1, 2, 7, 3))
    person_descriptors(desc, np.zeros((1, 2), dtype=np.int64), 1)
    match_tracks(
        np.zeros((1, 2, 4, 3)),
        np.ones((1, 2), np.bool_),
        np.arange(2, dtype=np.int64),
        np.array([[2, 3]], dtype=np.int64),
        np.zeros((1, 3, 3)),
        np.ones(1, np.bool_),
        np.full(1, 450.0),
        3,
        250.0,
    )
