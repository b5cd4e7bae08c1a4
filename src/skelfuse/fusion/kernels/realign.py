"""The temporal left/right realignment (:func:`skelfuse.fusion.realign.realign_temporal`) as one compiled call.

Per body: the teleport rule, each view's left/right votes against the anchor (the previous pairs; on a cold start
the seed view's or the static reference's, which the caller makes in numpy and passes in on a second call: rare,
and compiled it would lengthen every first start), the recovery, credit and rear-view rules with their counters,
and the mirrored views' labels exchanged. The same arithmetic as the numpy reference (:mod:`skelfuse.fusion.reference.
realign`) up to the order of its sums of three and of the pairs (last bits); the rules are documented in
:mod:`skelfuse.fusion.realign`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from skelfuse.fusion.kernels.signatures import BOOL, FLOAT, HELPER, INT, INT32, KERNEL, UINT8, array


@numba.njit(**HELPER)
def _distance(a: np.ndarray, i: int, b: np.ndarray, k: int) -> float:
    """|a[i] - b[k]| of two (n, 3) point rows, mm."""
    dx = a[i, 0] - b[k, 0]
    dy = a[i, 1] - b[k, 1]
    dz = a[i, 2] - b[k, 2]
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@numba.njit(**HELPER)
def _view_vote(view: np.ndarray, anchor: np.ndarray, left: np.ndarray, right: np.ndarray) -> tuple[float, bool, bool]:
    """One view's margin for keeping its labels (the sum of the deciding pairs' votes in [-1, 1]), whether a pair
    decided, and whether the view holds both joints of a pair. ``anchor`` (2P, 3): left joints, then right."""
    P = left.shape[0]
    margin = 0.0
    decided = sees_pair = False
    for p in range(P):
        lj, rj = left[p], right[p]
        if view[lj, 0] + view[rj, 0] == view[lj, 0] + view[rj, 0]:  # both x present (NaN: not equal)
            sees_pair = True
        keep = _distance(view, lj, anchor, p) + _distance(view, rj, anchor, P + p)
        swap = _distance(view, rj, anchor, p) + _distance(view, lj, anchor, P + p)
        wx, wy, wz = anchor[p, 0] - anchor[P + p, 0], anchor[p, 1] - anchor[P + p, 1], anchor[p, 2] - anchor[P + p, 2]
        vote = (swap - keep) / max(2.0 * math.sqrt(wx * wx + wy * wy + wz * wz), 1.0)
        if vote == vote:  # both of the view's joints and both anchors exist
            margin += vote
            decided = True
    return margin, decided, sees_pair


@numba.njit(**HELPER)
def _centre(view: np.ndarray, centre: np.ndarray) -> tuple[float, float, float]:
    """Mean of the four centre joints (shoulders, hips), NaN unless all four are known."""
    x = y = z = 0.0
    for joint in centre:
        x += view[joint, 0]
        y += view[joint, 1]
        z += view[joint, 2]
    return x / 4, y / 4, z / 4


@numba.njit(**HELPER)
def _teleported(positions: np.ndarray, previous: np.ndarray, centre: np.ndarray, max_jump_mm: float) -> bool:
    """One body's centre lies farther than ``max_jump_mm`` from the previous one in every view that has one."""
    tx, ty, tz = _centre(previous, centre)
    n_known = n_far = 0
    for s in range(positions.shape[0]):
        nx, ny, nz = _centre(positions[s], centre)
        d2 = (nx - tx) * (nx - tx) + (ny - ty) * (ny - ty) + (nz - tz) * (nz - tz)
        if d2 == d2:
            n_known += 1
            if d2 > max_jump_mm * max_jump_mm:
                n_far += 1
    return n_known > 0 and n_far == n_known


@numba.njit(**HELPER)
def _faces_away(view: np.ndarray, sensor: np.ndarray, centre: np.ndarray, rear_view_cos: float) -> bool:
    """The view's skeleton, as labelled, faces away from its sensor (cosine below ``rear_view_cos``)."""
    sl, sr, hl, hr = centre[0], centre[1], centre[2], centre[3]
    lx = view[sl, 0] - view[sr, 0] + view[hl, 0] - view[hr, 0]
    ly = view[sl, 1] - view[sr, 1] + view[hl, 1] - view[hr, 1]
    cx, cy, _ = _centre(view, centre)
    tx, ty = sensor[0] - cx, sensor[1] - cy
    norms = math.hypot(lx, ly) * math.hypot(tx, ty)
    if norms < 1e-9:  # NaN compares False and stays NaN
        norms = 1e-9
    return (ly * tx - lx * ty) / norms < rear_view_cos  # NaN compares False


_SIGNATURE = (
    array(FLOAT, 4),  # positions
    array(UINT8, 3),  # confidence
    array(FLOAT, 3),  # previous
    array(FLOAT, 3),  # cold_anchor
    BOOL,  # use_cold_anchor
    array(INT32, 2),  # streak
    array(FLOAT, 3),  # sensor_positions
    array(INT, 1),  # left
    array(INT, 1),  # right
    array(INT, 1),  # mirror
    array(INT, 1),  # centre
    INT,  # recovery_frames
    INT,  # majority_recovery_frames
    INT,  # rear_view_frames
    INT,  # credit_frames
    FLOAT,  # recovery_share
    FLOAT,  # max_jump_mm
    FLOAT,  # rear_view_cos
    INT,  # medium
)
# The kernel's outputs: positions, confidence, mirrored, counters, and per body whether it needs a cold anchor and
# whether its previous holds any pair.
_OUTPUT = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


@numba.njit(_SIGNATURE, **KERNEL)
def realign_temporal(
    positions: np.ndarray,
    confidence: np.ndarray,
    previous: np.ndarray,
    cold_anchor: np.ndarray,
    use_cold_anchor: bool,
    streak: np.ndarray,
    sensor_positions: np.ndarray,
    left: np.ndarray,
    right: np.ndarray,
    mirror: np.ndarray,
    centre: np.ndarray,
    recovery_frames: int,
    majority_recovery_frames: int,
    rear_view_frames: int,
    credit_frames: int,
    recovery_share: float,
    max_jump_mm: float,
    rear_view_cos: float,
    medium: int,
) -> _OUTPUT:
    """Realign every body's views against its anchor; see :func:`skelfuse.fusion.realign.realign_temporal`.

    Parameters
    ----------
    positions : (B, S, J, 3) float64 mm, NaN = missing; confidence : (B, S, J) uint8; previous : (B, J, 3) float64
    mm, the anchor; cold_anchor : (B, 2P, 3) float64 mm, read where ``use_cold_anchor``: the pairs of a body whose
    previous lacks them (:func:`skelfuse.fusion.realign.cold_anchors`, which needs the has_prev this returns);
    streak : (B, 4) int32 counters; sensor_positions : (B, S, 3) float64 mm, each body's (read only where
    ``rear_view_cos`` is not NaN); left, right : (P,) int64 pair joints; mirror : (J,) int64 the left/right
    permutation; centre : (4,) int64 shoulder L, R, hip L, R; the rules' options (majority_recovery_frames -1: off;
    max_jump_mm inf: off;
    rear_view_cos NaN: off); medium : the MEDIUM confidence.

    Returns
    -------
    positions (B, S, J, 3) float64 and confidence (B, S, J) uint8 with the mirrored views' labels exchanged,
    mirrored (B, S) bool, the new counters (B, 4) int32; needs_cold (B,) bool, bodies left undecided for want of
    a cold anchor (only without ``use_cold_anchor``), and has_prev (B,) bool, the previous holds one of its pairs.
    """
    B, S, J = positions.shape[0], positions.shape[1], positions.shape[2]
    P = left.shape[0]
    out_positions = positions.copy()
    out_confidence = confidence.copy()
    mirrored = np.empty((B, S), dtype=np.bool_)
    counters = np.empty((B, 4), dtype=np.int32)
    needs_cold = np.empty(B, dtype=np.bool_)
    any_prev = np.empty(B, dtype=np.bool_)
    anchor = np.empty((2 * P, 3))
    evidence = np.empty(S)
    margin = np.empty(S)
    decided = np.empty(S, dtype=np.bool_)
    prev_ok = np.empty(P, dtype=np.bool_)
    for b in range(B):
        needs_cold[b] = False
        counters[b, 0] = counters[b, 1] = counters[b, 2] = counters[b, 3] = 0
        for s in range(S):
            mirrored[b, s] = False
        jumped = _teleported(positions[b], previous[b], centre, max_jump_mm)
        for p in range(2 * P):
            joint = left[p] if p < P else right[p - P]
            for k in range(3):
                anchor[p, k] = np.nan if jumped else previous[b, joint, k]
        n_views = 0
        for s in range(S):
            evidence[s] = 0.0
            for j in range(J):
                evidence[s] += confidence[b, s, j] >= medium
            margin[s], decided[s], sees_pair = _view_vote(positions[b, s], anchor, left, right)
            n_views += sees_pair
        more_views = n_views > streak[b, 2]
        has_prev = all_prev = P < 0  # False, typed as a run-time bool (a literal would compile the helpers twice)
        for p in range(P):
            prev_ok[p] = anchor[p, 0] + anchor[P + p, 0] == anchor[p, 0] + anchor[P + p, 0] and not more_views
            has_prev |= prev_ok[p]
            all_prev = prev_ok[p] if p == 0 else all_prev and prev_ok[p]
        any_prev[b] = has_prev
        if not all_prev and not use_cold_anchor and S > 0:  # a cold start (rare): the caller makes the anchor
            needs_cold[b] = True
            continue
        if not all_prev:
            for p in range(2 * P):
                if not prev_ok[p % P]:
                    for k in range(3):
                        anchor[p, k] = cold_anchor[b, p, k]
            for s in range(S):
                margin[s], decided[s], _ = _view_vote(positions[b, s], anchor, left, right)
        against = total = 0.0
        rear_against = rear_for = n_decided = n_flips = S - S  # 0 (a run-time int, as above)
        for s in range(S):
            flip = margin[s] < 0.0
            against += evidence[s] * flip
            total += evidence[s] * decided[s]
            n_decided += decided[s]
            n_flips += flip
            if decided[s] and _faces_away(positions[b, s], sensor_positions[b, s], centre, rear_view_cos):
                rear_against += flip
                rear_for += not flip
        views_seen = int(streak[b, 2]) if has_prev else n_views
        unanimous = n_decided >= max(views_seen, 2) and n_flips == 0
        # The recovery, simple-majority and rear-view counters, and whether the body follows its views.
        confirmed = rear_for > rear_against
        majority = has_prev and not confirmed and against >= max(recovery_share * total, 0.5)
        simple = has_prev and not confirmed and 2.0 * against > total
        disproved = rear_against > rear_for
        kept = min(int(streak[b, 0]), 0)
        count = int(streak[b, 0]) + 1 if majority else (max(kept - 1, -credit_frames) if unanimous else kept)
        count = count if has_prev else 0
        simple_count = int(streak[b, 1]) + 1 if simple else 0
        rear_count = int(streak[b, 3]) + 1 if disproved and has_prev else 0
        credit = min(-min(count, 0), recovery_frames)
        follow = count >= recovery_frames or rear_count >= rear_view_frames + credit
        follow = follow or (majority_recovery_frames >= 0 and simple_count >= majority_recovery_frames)
        if follow:
            count = simple_count = rear_count = 0
        if not has_prev:  # cold start: the rear views facing away decide, else the MEDIUM evidence
            follow = disproved or (2.0 * against > total and rear_against == rear_for)
        counters[b, 0], counters[b, 1], counters[b, 2], counters[b, 3] = count, simple_count, views_seen, rear_count
        for s in range(S):
            mirrored[b, s] = (margin[s] < 0.0) != (follow and decided[s])
            if mirrored[b, s]:
                for j in range(J):
                    out_confidence[b, s, j] = confidence[b, s, mirror[j]]
                    for k in range(3):
                        out_positions[b, s, j, k] = positions[b, s, mirror[j], k]
    return out_positions, out_confidence, mirrored, counters, needs_cold, any_prev


def warm_up() -> None:
    """Compile (or load) :func:`realign_temporal` for its one signature."""
    pairs = np.array([0], dtype=np.int64)
    centre = np.array([0, 1, 0, 1], dtype=np.int64)
    realign_temporal(
        np.zeros((1, 1, 2, 3)),
        np.zeros((1, 1, 2), dtype=np.uint8),
        np.zeros((1, 2, 3)),
        np.zeros((1, 2, 3)),
        True,
        np.zeros((1, 4), dtype=np.int32),
        np.zeros((1, 1, 3)),
        pairs,
        pairs + 1,
        np.array([1, 0], dtype=np.int64),
        centre,
        10,
        -1,
        3,
        0,
        0.75,
        np.inf,
        np.nan,
        2,
    )
