"""Left/right realignment of the candidates before merging (Lee et al. 2022, section 2.2.1).

A body tracker that sees a person from behind labels the left limbs as right ones. Merging such a view
would average a left elbow with a right elbow. This stage swaps the labels back, per sensor, by comparing
each sensor's joints with a *reference position* built from all sensors.

Reference position of a joint (used here and as the merge's trick-1 candidate): the mean over sensors of
that joint's valid candidates in the best confidence tier present, tiers being MEDIUM or HIGH > LOW > NONE
(NONE only when ``min_confidence`` admits it). The paper says "mean of the MEDIUM candidates, LOW if there
is no MEDIUM"; HIGH (reserved by the SDK) counts as MEDIUM. No valid candidate: NaN.

Two modes:

``realign_paper`` (paper, eq. 4-6), per left/right pair of :data:`PAPER_REALIGN_PAIRS` and per sensor:
    swap the sensor's left and right joint (positions and confidences) when
    ``dist(right_ref, sensor_right) > dist(right_ref, sensor_left)``. Only the right reference is used, as
    in the paper. Missing data never triggers a swap: if the right reference, the sensor's left joint or
    its right joint is missing the comparison is undecided and the pair is left as it is; an exact tie is
    "no problem" (eq. 6 leaves equality open). The reference is computed once, from the unaligned
    candidates, so a mirrored view pulls it toward the wrong side; with half the views mirrored the
    decision is a coin toss.

``realign_body`` (beyond the paper): a tracker flip mirrors the whole skeleton, so decide once per
    sensor. Over the pairs where both references and both of the sensor's joints exist, sum
    ``keep = |ref_R - R| + |ref_L - L|`` and ``swap = |ref_R - L| + |ref_L - R|`` (mm); a sensor is
    mirrored when ``swap < keep``. Its *whole* skeleton is then mirrored (every pair of
    :data:`MIRROR_PAIRS`: hands, feet, face, clavicles too). The decision is repeated ``passes`` times,
    each against a reference recomputed from the previous pass's realigned candidates, so a mirrored view
    stops contaminating the reference. Summing distances (not squares) keeps one wild joint from
    outvoting five consistent pairs. A sensor with no decidable pair is left as it is.

``realign_temporal`` (beyond the paper; our default): the whole-body decision of ``realign_body``, taken
    against a *temporal anchor*: the previous frame's merged skeleton of the same body. A person moves at
    most a few tens of mm between frames while left and right are 150-400 mm apart, so last frame's answer
    is a far better reference than any static vote; with two of four views mirrored (rear views) the
    static mean sits between left and right and cannot decide, the anchor can. Policy, per body:

    Anchor
        Per pair, the previous merged pair where the previous holds both of its joints; otherwise the
        static reference (:func:`reference_positions` of the unaligned candidates). Each sensor's margin
        is then the sum over its decidable pairs of ``(swap - keep) / (2 |anchor_L - anchor_R|)``: by the
        triangle inequality ``|swap - keep|`` never exceeds twice the anchor's width of that pair, so each
        pair votes in [-1, 1] and a pair held wide apart (arms spread) weighs no more than the hips. In
        millimetres, as ``realign_body`` sums them, two arms whose occlusion guesses land on the wrong
        sides would outvote shoulders, hips, knees and ankles and mirror a correct view
        (``test_temporal_two_wild_arms_do_not_outvote_shoulders_hips_and_legs``).
    Initialization (no previous pair at all: the first frame, after a reset, after a loss of track)
        A 2-vs-2 split of views is geometrically ambiguous: a mirrored rear view faces "its" sensor just as a
        correct front view does. The *evidence* of a view is its number of MEDIUM-or-better joints (all
        32: a rear view sees the face, the hands and arms in front of the chest occluded, LOW or NONE).
        The *seed* view is the one with the most evidence (then the most pair joints, then the lowest
        sensor index); every view is decided against the seed's pair joints (pairs the seed lacks fall
        back to the static reference), which splits the views into the seed's group and the flipped
        group. The group holding more evidence is taken as correct, the seed's group on an exact tie.
        Rear views report their hidden torso MEDIUM, as the real tracker does, so the count alone cannot
        settle a 2-vs-2 split: when a view faces away from its sensor (the rear-view rule below) the group
        holding such views wins instead; otherwise a wrong start is fixed by the recovery rule (3-vs-1) or,
        once a rear view stops mirroring, by the rear-view rule (``scripts/tune_fusion.py`` scores cold
        starts on the simulator).
    Restart (more views than built the anchor)
        An anchor only knows the views it was built from. When more views see a body's pairs than ever did
        since its cold start (counter column 2), the body starts cold again: a body first seen by the two
        rear sensors alone, whose anchor is mirrored, is re-decided when the front sensors join, so it does
        not keep the mirrored arms it started with.
    Recovery (a mirrored anchor, from a wrong start or a genuinely fast turn)
        Without a rule, a mirrored anchor would realign every view to itself forever. Each view weighs its
        evidence (above). When the views that disagree with the anchor (would be flipped) hold at least
        ``recovery_share`` of the evidence of all decided views for ``recovery_frames`` frames in a row,
        the body follows the majority: every decided view's decision is inverted in that frame (the anchor
        was mirrored), and the counter restarts. A 2-vs-2 split (share 1/2) never triggers it, so a correct
        anchor is not overturned by the usual two rear views. Tuned on the simulator: 10 frames at 3/4. A
        frame in which a rear view facing away vouches for the anchor (the rear-view rule) resets the count.
        Credit: each frame in which every view agrees with the anchor banks one frame of credit, up to
        ``credit_frames``, where at least two views and every view that has seen the body since its cold start
        decided (:func:`vouched`); a run of disagreement spends the credit before it counts, and the rear-view rule
        waits as many frames more as the credit holds, at most ``recovery_frames`` (:func:`recovery_count`).
        Per instant, views mirrored together and a mirrored anchor look exactly alike: a person side-on
        between two facing sensors with both views mirrored for a while, or a front view 31 deg off the front
        mirrored for a few frames (it then faces away from its sensor, like a rear view that is not mirrored).
        The history tells them apart: views that have just vouched for the anchor outweigh as long a run
        against it. The price: a wrong start that every view vouched for (all views mirrored at the cold
        start) is undone up to ``credit_frames`` frames later.
        An optional slow rule (``majority_recovery_frames``, off by default) follows views that hold MORE
        than half of the evidence for that many frames in a row. It repairs 2-vs-2 misses, but wherever
        rear views outnumber front ones the mirrored views are the majority and it overturns correct
        anchors (3-sensor rigs in the paper evaluation), so it is off unless a rig's layout rules that out.
        A share of 2/3 also fired on correct anchors while a person turned (a rear view stays mirrored a
        little past 110 deg, so three views can be mirrored for a while); longer windows only delayed the
        fix of wrong cold starts.
    Rear views (``sensor_positions`` and ``rear_view_cos``, off unless given)
        A tracker that sees a person from behind and mirrors the skeleton assumes it sees the front: the
        mirrored skeleton faces ITS OWN sensor. A view whose skeleton, as labelled, faces AWAY from its
        sensor (:func:`facing_cosine` below ``rear_view_cos``: the facing, ``left x up`` from hips and
        shoulders, against the horizontal direction from the body to the sensor's calibrated position) is
        therefore a rear view that is not mirrored at that instant, and its left/right is right. A view facing
        its sensor is ambiguous (a front view, or a mirrored rear one); a side view is weak either way and
        stays under the threshold. So: on a cold start the group holding more such views wins (the MEDIUM
        evidence decides only where they tie, e.g. none); a warm anchor that more of them disagree with than
        agree with for ``rear_view_frames`` frames in a row is mirrored, and the body follows the views
        (every decided view's decision inverted, as in recovery); and where more of them agree with the
        anchor than disagree, the majority rules below do not count that frame (a correct anchor is not
        overturned by a majority of mirrored views while one of them vouches for it). A wrong 2-vs-2 start
        (both rear views mirrored at the cold frame: nothing faces away, so nothing to decide by) is thus
        undone ``rear_view_frames`` frames after one rear view stops mirroring, and an instant 180 deg turn
        in place (which no teleport rule sees) within ``rear_view_frames`` of a new rear view that is not
        yet mirrored.
        On the simulator no view below the threshold is mirrored in the base world, and failure families that
        mirror side views or report a neighbour put only a few there, hence the 3-frame streak
        (``python scripts/measure_rear_view_signal.py``; docs/evidence.md, "Rear views that face away"). The
        real takes hold no rear view, so they neither confirm nor refute the rule; it rests on the documented
        tracker behaviour (DESIGN "Known behaviour") and, if a real tracker mirrored every rear frame, it
        would simply never fire.
    Turning
        Nothing special: the anchor turns with the person frame by frame.
    Teleport (``max_jump_mm``, off unless given)
        A body whose centre (the mean of its shoulders and hips, which a flip leaves in place) lies more than
        ``max_jump_mm`` from the anchor's in every view that has all four starts cold: nobody moves that far
        in one frame, so the anchor belongs to another pose (a looped take's
        seam, which also turns the body round in one frame; a track handed to someone else), and deciding
        against it would mirror every view that is right. Without the rule such an anchor stays mirrored
        wherever the views split 2 against 2, since recovery needs a clear majority. One view that jumps
        alone (someone else, a tracker that lost the body, held out by the plausibility stage) is no teleport:
        with two views, a median (their mean) moved with it, and the body started cold in every such frame,
        where a 1-against-1 split is decided by the MEDIUM evidence alone.

    Returns the flip decisions and the new per-body disagreement counters; the caller keeps the counters.

All functions are vectorized over bodies, sensors and pairs, and never modify their inputs.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from skelfuse.fusion import kernels
from skelfuse.fusion.mirror import mirror_views, pair_costs
from skelfuse.schema.skeleton import N_JOINTS, PAPER_REALIGN_PAIRS, Confidence, J

# Confidence value -> tier rank 1 (NONE), 2 (LOW), 3 (MEDIUM+); HIGH and anything above count as MEDIUM.
_TIER_RANK = (np.minimum(np.arange(256), int(Confidence.MEDIUM)) + 1).astype(np.int8)
_ONES3 = np.ones(3)  # x @ ones sums the last axis of 3 faster than x.sum(-1)
_PAIR_LEFT = np.ascontiguousarray(PAPER_REALIGN_PAIRS[:, 0], dtype=np.int64)  # C order: as the kernel reads them
_PAIR_RIGHT = np.ascontiguousarray(PAPER_REALIGN_PAIRS[:, 1], dtype=np.int64)
_PAIR_JOINTS = np.concatenate([_PAIR_LEFT, _PAIR_RIGHT])  # (2P,) left joints, then right joints
_PAIR_SWAPPED = np.concatenate([_PAIR_RIGHT, _PAIR_LEFT])
_N_PAIRS = len(PAPER_REALIGN_PAIRS)
_ONES_J = np.ones(N_JOINTS)
_ONES_2P = np.ones(2 * _N_PAIRS)
# The body centre of the teleport rule: shoulders and hips, both sides, so that a left/right flip leaves it.
_CENTRE_JOINTS = np.array([J["SHOULDER_LEFT"], J["SHOULDER_RIGHT"], J["HIP_LEFT"], J["HIP_RIGHT"]])
_N_COUNTERS = 4  # per-body realignment counters (see realign_temporal's ``streak``)


def reference_positions(positions: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """Per joint, the mean of the valid candidates of the best confidence tier present.

    Parameters
    ----------
    positions : (B, S, J, 3) float, mm
        Candidates; NaN marks a missing one.
    confidence : (B, S, J) int
        Tracker confidence of each candidate (values above MEDIUM count as MEDIUM).

    Returns
    -------
    (B, J, 3) float64, mm. NaN where no sensor has a valid candidate.
    """
    valid = ~np.isnan(positions[..., 0])  # (B, S, J)
    # Rank of each candidate: 0 missing, 1 NONE, 2 LOW, 3 MEDIUM or better; keep the best rank per joint.
    rank = _TIER_RANK[confidence] * valid
    chosen = (rank == rank.max(axis=1, keepdims=True)) & valid
    count = chosen.sum(axis=1)[..., None]  # (B, J, 1)
    sums = np.where(chosen[..., None], positions, 0.0).sum(axis=1)  # (B, J, 3)
    # 0 / NaN is a quiet NaN: no candidate at all gives NaN without a division warning.
    return sums / np.where(count > 0, count, np.nan)


def realign_paper(
    positions: np.ndarray,
    confidence: np.ndarray,
    pairs: np.ndarray = PAPER_REALIGN_PAIRS,
    reference: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Paper's per-pair realignment (eq. 4-6); see the module docstring for the missing-data policy.

    Parameters
    ----------
    positions : (B, S, J, 3) float, mm, NaN = missing
    confidence : (B, S, J) int
    pairs : (P, 2) int
        (left, right) joint indices to check.
    reference : (B, J, 3) float, mm, or None
        :func:`reference_positions` of these same candidates, if the caller already has it.

    Returns
    -------
    positions : (B, S, J, 3) float64, mm, with mirrored pairs swapped back. When nothing is swapped the
        input arrays themselves are returned (do not modify them in place).
    confidence : (B, S, J), swapped along with the positions.
    swapped : (B, S, P) bool, which sensor's pair was swapped.
    """
    pairs = np.asarray(pairs, dtype=np.int64)
    left, right = pairs[:, 0], pairs[:, 1]
    if reference is None:
        ref_right = reference_positions(positions[:, :, right], confidence[:, :, right])  # (B, P, 3)
    else:
        ref_right = reference[:, right]
    sensor_left = positions[:, :, left]
    sensor_right = positions[:, :, right]
    # Squared distances order like distances; NaN compares False, so missing data never swaps.
    to_right = sensor_right - ref_right[:, None]
    to_left = sensor_left - ref_right[:, None]
    d2_correct = (to_right * to_right) @ _ONES3
    d2_wrong = (to_left * to_left) @ _ONES3
    swapped = d2_correct > d2_wrong
    if not swapped.any():  # the usual case: skip the copies
        return positions, confidence, swapped
    return (*_swap_pairs(positions, confidence, swapped, left, right), swapped)


def realign_body(
    positions: np.ndarray, confidence: np.ndarray, passes: int = 2, reference: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whole-body realignment: one mirror decision per sensor from all pairs (beyond the paper).

    Parameters
    ----------
    positions : (B, S, J, 3) float, mm, NaN = missing
    confidence : (B, S, J) int
    passes : int
        Number of decide-then-recompute-the-reference rounds (>= 1).
    reference : (B, J, 3) float, mm, or None
        :func:`reference_positions` of these same candidates, if the caller already has it.

    Returns
    -------
    positions : (B, S, J, 3) float64, mm, mirrored sensors' skeletons mirrored back. When no sensor is
        mirrored the input arrays themselves are returned (do not modify them in place).
    confidence : (B, S, J), permuted along with the positions.
    mirrored : (B, S) bool, which sensors were mirrored.
    """
    left, right = positions[:, :, _PAIR_LEFT], positions[:, :, _PAIR_RIGHT]  # (B, S, P, 3)
    ref_left, ref_right = left, right
    ref_conf = confidence[:, :, _PAIR_JOINTS]
    mirrored = np.zeros(positions.shape[:2], dtype=bool)
    for round_idx in range(passes):  # a fixed, small number of rounds
        if round_idx == 0 and reference is not None:
            ref = reference[:, None, _PAIR_JOINTS]  # (B, 1, 2P, 3): left joints then right joints
        elif round_idx > 0 and not mirrored.any():
            break  # nothing changed: the reference, and so the decision, would be the same again
        else:
            ref = reference_positions(np.concatenate([ref_left, ref_right], axis=2), ref_conf)[:, None]
        keep, swap = pair_costs(left, right, ref[:, :, :_N_PAIRS], ref[:, :, _N_PAIRS:])  # (B, S, P)
        # A pair counts only where both its keep and swap costs exist (both joints and both references).
        mirrored = np.nansum(swap - keep, axis=-1) < 0.0
        flip = mirrored[..., None, None]
        ref_left, ref_right = np.where(flip, right, left), np.where(flip, left, right)
        ref_conf = np.where(mirrored[..., None], confidence[:, :, _PAIR_SWAPPED], confidence[:, :, _PAIR_JOINTS])
    if not mirrored.any():
        return positions, confidence, mirrored
    out_positions, out_confidence = mirror_views(positions, confidence, mirrored)
    return out_positions, out_confidence, mirrored


def realign_temporal(
    positions: np.ndarray,
    confidence: np.ndarray,
    previous: np.ndarray,
    streak: np.ndarray,
    recovery_frames: int = 10,
    recovery_share: float = 0.75,
    reference: np.ndarray | None = None,
    majority_recovery_frames: int | None = None,
    max_jump_mm: float | None = None,
    sensor_positions: np.ndarray | None = None,
    rear_view_cos: float | None = None,
    rear_view_frames: int = 3,
    credit_frames: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Whole-body realignment against the previous merged skeleton; see the module docstring for the policy.

    Parameters
    ----------
    positions : (B, S, J, 3) float, mm, NaN = missing
    confidence : (B, S, J) int
    previous : (B, J, 3) float, mm
        The temporal anchor: last frame's merged skeleton of each body (NaN = none).
    streak : (B, 4) int
        Per body: frames in a row in which the views disagreeing with the anchor held (column 0)
        ``recovery_share`` of the evidence, negative: the anchor's credit (:func:`recovery_count`), and
        (column 1) more than half of it; (column 2) the most views
        that have seen the body's left/right pairs since its last cold start; (column 3) frames in a row in
        which rear views facing away disproved the anchor. All 0 for a new body (three columns are read
        as the first three, the fourth 0).
    recovery_frames : int
        Disagreement frames in a row after which the body follows the majority (>= 1).
    recovery_share : float
        Share of the evidence, in (0.5, 1], that counts as a clear majority against the anchor.
    reference : (B, J, 3) float, mm, or None
        :func:`reference_positions` of these same candidates, if the caller already has it.
    majority_recovery_frames : int or None
        Disagreement frames in a row after which the body follows a simple majority (more than half the
        evidence). This slower rule undoes a wrong start in a 2-against-2 split, which the clear-majority
        rule never sees: an anchor set from the first frames of a body seen only from behind, or a cold
        start that picked the wrong group. None: off.
    max_jump_mm : float or None
        A body whose centre moved further than this since the anchor starts cold (the teleport rule of the
        module docstring). None: off.
    sensor_positions : (S, 3) float, mm, or None
        Each sensor's position in the world frame (the translation of its calibrated pose), in the views'
        order; with ``rear_view_cos`` it enables the rear-view rule of the module docstring.
    rear_view_cos : float or None
        A view whose own skeleton faces away from its sensor (cosine between its facing and the horizontal
        direction from the body to the sensor below this, e.g. -0.7: more than 134 deg away) is a rear view
        that is not mirrored: its left/right is taken as right. None: off.
    rear_view_frames : int
        Frames in a row in which such views disagree with the anchor (more of them disagree than agree)
        before the body follows them (>= 1).
    credit_frames : int
        The most credit the anchor banks, one frame for each frame in which every view agreed with it and
        enough of them decided (:func:`vouched`) (>= 0; 0: none). A run of disagreement spends it before the
        recovery rule counts, and the rear-view rule waits as many frames more as the credit holds, at most
        ``recovery_frames``.

    Returns
    -------
    positions : (B, S, J, 3) float64, mm, mirrored sensors' skeletons mirrored back (the input arrays
        themselves when no sensor is mirrored; do not modify them in place).
    confidence : (B, S, J), permuted along with the positions.
    mirrored : (B, S) bool, which sensors were mirrored.
    streak : (B, 4) int32, the new counters.
    """
    B = positions.shape[0]
    streak = np.asarray(streak, dtype=np.int32)
    if streak.shape[1] < _N_COUNTERS:  # counters from before the rear-view rule: its streak starts at 0
        streak = np.concatenate([streak, np.zeros((B, _N_COUNTERS - streak.shape[1]), np.int32)], axis=1)
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
        if reference is None:
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
        counters = np.zeros((B, _N_COUNTERS), dtype=np.int32)
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


def pair_votes(positions: np.ndarray, anchor: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each view's left/right vote against an anchor, over the pairs of :data:`PAPER_REALIGN_PAIRS`.

    Per view and pair, ``(swap - keep) / max(2 |anchor_L - anchor_R|, 1)`` with ``keep = |L - anchor_L| +
    |R - anchor_R|`` and ``swap = |R - anchor_L| + |L - anchor_R|``: a vote in [-1, 1] (the triangle inequality),
    so a pair held wide apart weighs no more than the hips. A pair decides only where both of the view's joints
    and both anchors exist. Runs in a compiled kernel (:mod:`skelfuse.fusion.kernels.realign`); the numpy form is
    the test reference (:mod:`skelfuse.fusion.reference.realign`).

    Parameters
    ----------
    positions : (B, S, J, 3) float mm, NaN = missing.
    anchor : (B, 2P, 3) float mm, the anchor's left joints of the pairs, then its right joints.

    Returns
    -------
    margin : (B, S) float64, the sum of the deciding pairs' votes (< 0: the view is mirrored against the anchor).
    decided : (B, S) bool, at least one pair decided.
    n_views : (B,) int64, views that hold both joints of at least one pair.
    """
    positions = np.ascontiguousarray(positions, dtype=np.float64)
    anchor = np.ascontiguousarray(anchor, dtype=np.float64)
    if positions.ndim != 4 or positions.shape[2:] != (N_JOINTS, 3) or anchor.shape != (len(positions), 2 * _N_PAIRS, 3):
        raise ValueError(
            f"pair_votes needs positions (B, S, {N_JOINTS}, 3) and anchor (B, {2 * _N_PAIRS}, 3), got "
            f"{positions.shape} and {anchor.shape}"
        )
    return kernels.load().realign.pair_votes(positions, anchor, _PAIR_LEFT, _PAIR_RIGHT)


def facing_cosine(positions: np.ndarray, sensor_positions: np.ndarray) -> np.ndarray:
    """(B, S) cosine between the facing of each view's skeleton, as labelled, and the horizontal direction from
    that body to the view's own sensor: +1 faces its sensor, -1 faces away from it.

    The facing is ``left x up`` (world z up), ``left`` the sum of the hip and shoulder vectors from the right
    joint to the left one; the body's position is the mean of those four joints. NaN where one is missing.
    ``positions`` (B, S, J, 3) world mm; ``sensor_positions`` (S, 3) world mm.
    """
    quad = positions[:, :, _CENTRE_JOINTS]  # (B, S, 4, 3): shoulder L, R, hip L, R
    left = quad[:, :, 0] - quad[:, :, 1] + quad[:, :, 2] - quad[:, :, 3]  # (B, S, 3)
    # np.add.reduce / 4 is what ndarray.mean computes, without its Python-level wrapper (hot path).
    to_sensor = np.asarray(sensor_positions, dtype=np.float64)[None] - np.add.reduce(quad, axis=2) / 4
    # forward = left x z = (left_y, -left_x, 0); its dot with the horizontal direction to the sensor:
    dot = left[..., 1] * to_sensor[..., 0] - left[..., 0] * to_sensor[..., 1]
    norms = np.hypot(left[..., 0], left[..., 1]) * np.hypot(to_sensor[..., 0], to_sensor[..., 1])
    return dot / np.maximum(norms, 1e-9)


def teleported(positions: np.ndarray, previous: np.ndarray, max_jump_mm: float) -> np.ndarray:
    """(B,) bool: the body's centre (mean of shoulders and hips) lies more than ``max_jump_mm`` from the centre of
    ``previous`` (B, J, 3) in every view that has all four: a jump every view makes. One view of someone else (a
    neighbour, a tracker that lost the body) does not make the body jump. False where either centre is unknown."""
    # np.add.reduce / 4 is ndarray.mean over the four joints, without its Python-level wrapper (hot path).
    then = np.add.reduce(previous[:, _CENTRE_JOINTS], axis=1) / 4  # (B, 3), NaN unless all four are known
    now = np.add.reduce(positions[:, :, _CENTRE_JOINTS], axis=2) / 4  # (B, S, 3)
    step = now - then[:, None]
    d2 = (step * step) @ _ONES3  # (B, S), NaN where a centre is unknown
    known = d2 == d2
    far = d2 > max_jump_mm * max_jump_mm  # NaN compares False
    return known.any(axis=1) & (far == known).all(axis=1)


def _swap_pairs(
    positions: np.ndarray, confidence: np.ndarray, swapped: np.ndarray, left: np.ndarray, right: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Swap the (left, right) joints of each (body, sensor, pair) flagged in ``swapped``; returns copies."""
    joints = np.concatenate([left, right])
    twins = np.concatenate([right, left])
    flag = np.concatenate([swapped, swapped], axis=-1)  # (B, S, 2P)
    out_positions = positions.copy()
    out_confidence = confidence.copy()
    out_positions[:, :, joints] = np.where(flag[..., None], positions[:, :, twins], positions[:, :, joints])
    out_confidence[:, :, joints] = np.where(flag, confidence[:, :, twins], confidence[:, :, joints])
    return out_positions, out_confidence
