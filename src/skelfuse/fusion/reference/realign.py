"""The numpy form of the temporal realignment: the test reference of :func:`skelfuse.fusion.realign.realign_temporal`
(the live path runs :mod:`skelfuse.fusion.kernels.realign` and never imports this module). The rules are documented
in :mod:`skelfuse.fusion.realign`.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from skelfuse.fusion.mirror import mirror_views
from skelfuse.fusion.realign import CENTRE_JOINTS, N_COUNTERS, reference_positions
from skelfuse.schema.skeleton import N_JOINTS, PAPER_REALIGN_PAIRS, Confidence

_N_PAIRS = len(PAPER_REALIGN_PAIRS)
_LEFT, _RIGHT = PAPER_REALIGN_PAIRS[:, 0], PAPER_REALIGN_PAIRS[:, 1]
_PAIR_BOTH = np.concatenate([_LEFT, _RIGHT, _RIGHT, _LEFT])  # (4P,) labels as given, then swapped
_ONES3 = np.ones(3)  # x @ ones sums the last axis of 3 faster than x.sum(-1)
_ONES_P = np.ones(_N_PAIRS)
_ONES_J = np.ones(N_JOINTS)
_ONES_2P = np.ones(2 * _N_PAIRS)
_PAIR_JOINTS = np.concatenate([_LEFT, _RIGHT])  # (2P,) left joints, then right joints
# Weights over the four cost blocks (keep left, keep right, swap left, swap right): swap - keep per pair.
_SWAP_MINUS_KEEP = np.array([-1.0, -1.0, 1.0, 1.0])


def pair_votes(positions: np.ndarray, anchor: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each view's left/right vote against an anchor (B, 2P, 3): ``(swap - keep) / max(2 |anchor_L - anchor_R|, 1)``
    summed over the pairs that decide (both of the view's joints and both anchors exist); returns the margin
    (B, S), whether a pair decided (B, S) and the views that hold both joints of a pair (B,)."""
    both = positions[:, :, _PAIR_BOTH]  # (B, S, 4P, 3): left, right, then the swapped labels
    n_views = (~np.isnan(both[:, :, :_N_PAIRS, 0] + both[:, :, _N_PAIRS : 2 * _N_PAIRS, 0])).any(axis=2).sum(axis=1)
    diff = both - np.concatenate([anchor, anchor], axis=1)[:, None]
    cost = np.sqrt((diff * diff) @ _ONES3)  # (B, S, 4P): keep costs, then swap costs
    pair_delta = _SWAP_MINUS_KEEP @ cost.reshape(*cost.shape[:2], 4, _N_PAIRS)  # (B, S, P) swap - keep
    width = anchor[:, :_N_PAIRS] - anchor[:, _N_PAIRS:]  # (B, P, 3): anchor left - right
    width = np.sqrt((width * width) @ _ONES3)
    pair_delta = pair_delta / np.maximum(2.0 * width, 1.0)[:, None]  # each pair's vote in [-1, 1]
    # A pair decides only where both of the view's joints and both anchors exist: NaN propagates.
    decidable = pair_delta == pair_delta
    margin = np.where(decidable, pair_delta, 0.0) @ _ONES_P  # (B, S)
    return margin, decidable.any(axis=2), n_views.astype(np.int64)


def realign_temporal(
    positions: np.ndarray,
    confidence: np.ndarray,
    previous: np.ndarray,
    streak: np.ndarray,
    recovery_frames: int = 10,
    recovery_share: float = 0.75,
    majority_recovery_frames: int | None = None,
    max_jump_mm: float | None = None,
    sensor_positions: np.ndarray | None = None,
    rear_view_cos: float | None = None,
    rear_view_frames: int = 3,
    credit_frames: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`skelfuse.fusion.realign.realign_temporal` in numpy: every body, view and pair at once."""
    B = positions.shape[0]
    streak = np.asarray(streak, dtype=np.int32)
    if streak.shape[1] < N_COUNTERS:  # counters from before the rear-view rule: its streak starts at 0
        streak = np.concatenate([streak, np.zeros((B, N_COUNTERS - streak.shape[1]), np.int32)], axis=1)
    if max_jump_mm is not None:
        jumped = teleported(positions, previous, max_jump_mm)
        if jumped.any():
            previous = np.where(jumped[:, None, None], np.nan, previous)
    # Evidence of a view: its MEDIUM-or-better joints, all 32 (a rear view sees face, hands and arms in
    # front of the chest occluded, LOW or NONE).
    evidence = (confidence >= int(Confidence.MEDIUM)) @ _ONES_J  # (B, S), float: whole counts
    anchor = previous[:, _PAIR_JOINTS]  # (B, 2P, 3): the anchor's left joints, then its right joints
    # Views that see at least one whole pair. An anchor only knows the views it was built from: once more
    # views see the body than ever did since its cold start, the body starts cold again, so a start seen
    # by the rear sensors alone is re-decided when the front ones join.
    margin, decided, n_views = pair_votes(positions, anchor)
    more_views = n_views > streak[:, 2]
    warm = not (math.isnan(anchor.sum()) or more_views.any())  # usual: every pair anchored, no new view
    if warm:
        has_prev = None
    else:
        prev_ok = ~np.isnan(anchor[:, :_N_PAIRS, 0] + anchor[:, _N_PAIRS:, 0])  # (B, P)
        prev_ok &= ~more_views[:, None]
        has_prev = prev_ok.any(axis=1)  # (B,)
        reference = reference_positions(positions, confidence)
        # Cold-start seed: most MEDIUM joints, then most present pair joints, then the lowest index.
        pairs = positions[:, :, _PAIR_JOINTS]  # (B, S, 2P, 3)
        present = ~np.isnan(pairs[..., 0])
        seed = (evidence * (2 * _N_PAIRS + 1) + present @ _ONES_2P).argmax(axis=1)  # (B,)
        seed_pairs = pairs[np.arange(B), seed]  # (B, 2P, 3)
        seed_ok = ~np.isnan(seed_pairs[:, :_N_PAIRS, 0] + seed_pairs[:, _N_PAIRS:, 0])
        use_seed = np.tile(seed_ok & ~has_prev[:, None], 2)[..., None]
        static = reference[:, _PAIR_JOINTS]
        anchor = np.where(np.tile(prev_ok, 2)[..., None], anchor, np.where(use_seed, seed_pairs, static))
        margin, decided, _ = pair_votes(positions, anchor)
    flips = margin < 0.0
    if has_prev is None and not flips.any():  # warm and no view disagrees: nothing to flip, the anchor earns credit
        counters = np.zeros((B, N_COUNTERS), dtype=np.int32)
        counters[:, 0] = recovery_count(streak[:, 0], False, vouched(decided, streak[:, 2]), credit_frames)
        counters[:, 2] = streak[:, 2]
        return positions, confidence, flips, counters
    against = (evidence * flips).sum(axis=1)  # (B,) evidence of the views the anchor would flip
    total = (evidence * decided).sum(axis=1)
    # Rear-view rule: views facing away from their own sensor are not mirrored; count those the anchor would
    # flip (rear_against) and those it keeps (rear_for).
    rear_against = rear_for = np.zeros(B)
    if sensor_positions is not None and rear_view_cos is not None:
        rear = (facing_cosine(positions, sensor_positions) < rear_view_cos) & decided  # NaN compares False
        rear_against = (rear & flips) @ np.ones(flips.shape[1])
        rear_for = (rear & ~flips) @ np.ones(flips.shape[1])
    confirmed = rear_for > rear_against  # a rear view vouches for the anchor: no majority overturns it
    # Recovery: a clear majority against the anchor for recovery_frames frames in a row wins. Evidence
    # counts are whole numbers and the share exceeds 1/2, so the 0.5 floor only rules out total == 0.
    majority = (against >= np.maximum(recovery_share * total, 0.5)) & ~confirmed
    simple = (2.0 * against > total) & ~confirmed
    disproved = rear_against > rear_for
    if has_prev is not None:
        majority &= has_prev
        simple &= has_prev
        disproved_now = disproved & ~has_prev
        disproved &= has_prev
    # Views seen since the cold start: unchanged while anchored (no more views than before, or it would
    # have started cold), this frame's count after a cold start.
    views_seen = streak[:, 2] if has_prev is None else np.where(has_prev, streak[:, 2], n_views)
    unanimous = vouched(decided, views_seen) & ~flips.any(axis=1)
    count = recovery_count(streak[:, 0], majority, unanimous, credit_frames)
    new_streak = np.stack(
        [
            count if has_prev is None else count * has_prev,  # a cold start starts without credit
            (streak[:, 1] + 1) * simple,
            views_seen,
            (streak[:, 3] + 1) * disproved,
        ],
        axis=1,
    ).astype(np.int32)
    # The anchor's credit (a negative recovery count) holds off the rear-view rule for as many frames more, at
    # most recovery_frames: a rear view facing away is stronger evidence than a majority.
    credit = np.minimum(-np.minimum(new_streak[:, 0], 0), recovery_frames)
    follow = (new_streak[:, 0] >= recovery_frames) | (new_streak[:, 3] >= rear_view_frames + credit)
    if majority_recovery_frames is not None:
        follow |= new_streak[:, 1] >= majority_recovery_frames
    new_streak[follow, :2] = 0
    new_streak[follow, 3] = 0
    if has_prev is not None:
        # Cold start: the group holding more rear views facing away wins; without such a vote, the group with
        # more MEDIUM evidence (the seed's on a tie).
        by_evidence = (2 * against > total) & (rear_against == rear_for)
        follow = np.where(has_prev, follow, disproved_now | by_evidence)
    mirrored = flips ^ (follow[:, None] & decided) if follow.any() else flips
    if not mirrored.any():
        return positions, confidence, mirrored, new_streak
    out_positions, out_confidence = mirror_views(positions, confidence, mirrored)
    return out_positions, out_confidence, mirrored, new_streak


def recovery_count(count: np.ndarray, majority: ArrayLike, unanimous: ArrayLike, credit_frames: int) -> np.ndarray:
    """The recovery rule's counter (B,) after one frame: +1 for a frame in which a clear ``majority`` of the
    evidence disagreed with the anchor, -1 down to ``-credit_frames`` for a frame in which every decided view
    agreed with it (``unanimous``); any other frame ends a run of disagreement (a positive count drops to 0)
    and keeps the credit. The body follows the majority once the count reaches the recovery frames, so an
    anchor that every view vouched for recently outlasts that many more frames of disagreement."""
    kept = np.minimum(count, 0)
    return np.where(majority, count + 1, np.where(unanimous, np.maximum(kept - 1, -credit_frames), kept))


def vouched(decided: np.ndarray, views_seen: np.ndarray) -> np.ndarray:
    """(B,) bool: enough views decided for their agreement with the anchor to earn it credit: at least two, and
    every view that has seen the body since its cold start (``views_seen``). The views left of a body that lost
    one (to someone else, or to the tracker) would otherwise vouch for an anchor they made themselves: a lone
    rear view that the recovery rule followed earns the mirrored anchor credit against the front view's return."""
    return decided.sum(axis=1) >= np.maximum(views_seen, 2)


def facing_cosine(positions: np.ndarray, sensor_positions: np.ndarray) -> np.ndarray:
    """(B, S) cosine between the facing of each view's skeleton, as labelled, and the horizontal direction from
    that body to the view's own sensor: +1 faces its sensor, -1 faces away from it.

    The facing is ``left x up`` (world z up), ``left`` the sum of the hip and shoulder vectors from the right
    joint to the left one; the body's position is the mean of those four joints. NaN where one is missing.
    ``positions`` (B, S, J, 3) world mm; ``sensor_positions`` (S, 3) or each body's own (B, S, 3), world mm.
    """
    quad = positions[:, :, CENTRE_JOINTS]  # (B, S, 4, 3): shoulder L, R, hip L, R
    left = quad[:, :, 0] - quad[:, :, 1] + quad[:, :, 2] - quad[:, :, 3]  # (B, S, 3)
    # np.add.reduce / 4 is what ndarray.mean computes, without its Python-level wrapper (hot path).
    to_sensor = np.asarray(sensor_positions, dtype=np.float64) - np.add.reduce(quad, axis=2) / 4  # (S|B,S, 3)
    # forward = left x z = (left_y, -left_x, 0); its dot with the horizontal direction to the sensor:
    dot = left[..., 1] * to_sensor[..., 0] - left[..., 0] * to_sensor[..., 1]
    norms = np.hypot(left[..., 0], left[..., 1]) * np.hypot(to_sensor[..., 0], to_sensor[..., 1])
    return dot / np.maximum(norms, 1e-9)


def teleported(positions: np.ndarray, previous: np.ndarray, max_jump_mm: float) -> np.ndarray:
    """(B,) bool: the body's centre (mean of shoulders and hips) lies more than ``max_jump_mm`` from the centre of
    ``previous`` (B, J, 3) in every view that has all four: a jump every view makes. One view of someone else (a
    neighbour, a tracker that lost the body) does not make the body jump. False where either centre is unknown."""
    # np.add.reduce / 4 is ndarray.mean over the four joints, without its Python-level wrapper (hot path).
    then = np.add.reduce(previous[:, CENTRE_JOINTS], axis=1) / 4  # (B, 3), NaN unless all four are known
    now = np.add.reduce(positions[:, :, CENTRE_JOINTS], axis=2) / 4  # (B, S, 3)
    step = now - then[:, None]
    d2 = (step * step) @ _ONES3  # (B, S), NaN where a centre is unknown
    known = d2 == d2
    far = d2 > max_jump_mm * max_jump_mm  # NaN compares False
    return known.any(axis=1) & (far == known).all(axis=1)
