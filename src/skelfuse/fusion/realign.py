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
        sensor (the cosine of :func:`skelfuse.fusion.reference.realign.facing_cosine` below ``rear_view_cos``:
        the facing, ``left x up`` from hips and shoulders, against the horizontal direction from the body to the
        sensor's calibrated position) is therefore a rear view that is not mirrored at that instant, and its
        left/right is right. A view facing
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

realign_paper and realign_body are numpy, vectorized over bodies, sensors and pairs; realign_temporal runs as one
compiled call (its numpy form is the test reference, :mod:`skelfuse.fusion.reference.realign`). None modifies its
inputs.
"""

from __future__ import annotations

import math

import numpy as np

from skelfuse.fusion import kernels
from skelfuse.fusion.mirror import mirror_views, pair_costs
from skelfuse.schema.skeleton import MIRROR, N_JOINTS, PAPER_REALIGN_PAIRS, Confidence, J

# Confidence value -> tier rank 1 (NONE), 2 (LOW), 3 (MEDIUM+); HIGH and anything above count as MEDIUM.
_TIER_RANK = (np.minimum(np.arange(256), int(Confidence.MEDIUM)) + 1).astype(np.int8)
_ONES3 = np.ones(3)  # x @ ones sums the last axis of 3 faster than x.sum(-1)
_PAIR_LEFT = np.ascontiguousarray(PAPER_REALIGN_PAIRS[:, 0], dtype=np.int64)  # C order: as the kernel reads them
_PAIR_RIGHT = np.ascontiguousarray(PAPER_REALIGN_PAIRS[:, 1], dtype=np.int64)
_PAIR_JOINTS = np.concatenate([_PAIR_LEFT, _PAIR_RIGHT])  # (2P,) left joints, then right joints
_PAIR_SWAPPED = np.concatenate([_PAIR_RIGHT, _PAIR_LEFT])
_N_PAIRS = len(PAPER_REALIGN_PAIRS)
_MIRROR = np.ascontiguousarray(MIRROR, dtype=np.int64)
CENTRE_JOINTS = np.array([J["SHOULDER_LEFT"], J["SHOULDER_RIGHT"], J["HIP_LEFT"], J["HIP_RIGHT"]], dtype=np.int64)
"""The body centre of the teleport and rear-view rules: shoulders and hips, both sides (a flip leaves it in place)."""
N_COUNTERS = 4
"""Per-body realignment counters (see :func:`realign_temporal`'s ``streak``)."""
_NO_ANCHOR = np.zeros((0, 2 * _N_PAIRS, 3))  # the kernel's cold anchor where none is given (it reads none)


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
    majority_recovery_frames : int or None
        Disagreement frames in a row after which the body follows a simple majority (more than half the
        evidence). This slower rule undoes a wrong start in a 2-against-2 split, which the clear-majority
        rule never sees: an anchor set from the first frames of a body seen only from behind, or a cold
        start that picked the wrong group. None: off.
    max_jump_mm : float or None
        A body whose centre moved further than this since the anchor starts cold (the teleport rule of the
        module docstring). None: off.
    sensor_positions : (S, 3) or (B, S, 3) float, mm, or None
        Each sensor's position in the world frame (the translation of its calibrated pose), in the views'
        order, the same for every body or each body's own; with ``rear_view_cos`` it enables the rear-view
        rule of the module docstring.
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
    positions : (B, S, J, 3) float64, mm, mirrored sensors' skeletons mirrored back (new arrays).
    confidence : (B, S, J) uint8, permuted along with the positions.
    mirrored : (B, S) bool, which sensors were mirrored.
    streak : (B, 4) int32, the new counters.

    Runs in one compiled kernel (:mod:`skelfuse.fusion.kernels.realign`); the numpy form is the test reference
    (:mod:`skelfuse.fusion.reference.realign`).
    """
    positions = np.ascontiguousarray(positions, dtype=np.float64)
    B, S = positions.shape[:2]
    streak = np.asarray(streak, dtype=np.int32)
    if streak.ndim == 2 and streak.shape[0] == B and streak.shape[1] < N_COUNTERS:  # counters from before the
        streak = np.concatenate([streak, np.zeros((B, N_COUNTERS - streak.shape[1]), np.int32)], axis=1)  # rear rule
    # The rear-view rule needs both; the kernel reads a NaN cosine as off.
    rear = sensor_positions is not None and rear_view_cos is not None
    sensors = np.asarray(sensor_positions if rear else np.zeros((S, 3)), dtype=np.float64)
    if sensors.shape == (S, 3):  # one rig's sensors for every body
        sensors = np.broadcast_to(sensors, (B, S, 3))
    rear_cos = float(rear_view_cos) if rear_view_cos is not None and rear else math.nan
    arguments = (
        kernels.kernel_array(confidence, np.uint8, (B, S, N_JOINTS), "confidence"),
        kernels.kernel_array(previous, np.float64, (B, N_JOINTS, 3), "previous"),
    )
    options = (
        kernels.kernel_array(streak, np.int32, (B, N_COUNTERS), "streak"),
        kernels.kernel_array(sensors, np.float64, (B, S, 3), "sensor_positions"),
        _PAIR_LEFT,
        _PAIR_RIGHT,
        _MIRROR,
        CENTRE_JOINTS,
        int(recovery_frames),
        -1 if majority_recovery_frames is None else int(majority_recovery_frames),
        int(rear_view_frames),
        int(credit_frames),
        float(recovery_share),
        math.inf if max_jump_mm is None else float(max_jump_mm),
        rear_cos,
        int(Confidence.MEDIUM),
    )
    kernel = kernels.load().realign.realign_temporal
    out = kernel(positions, *arguments, _NO_ANCHOR, False, *options)
    if out[4].any():  # a body starts cold (first frames, a new view, a teleport): its anchor, then the whole call
        out = kernel(positions, *arguments, cold_anchors(positions, arguments[0], out[5]), True, *options)
    return out[:4]


def cold_anchors(positions: np.ndarray, confidence: np.ndarray, has_prev: np.ndarray) -> np.ndarray:
    """(B, 2P, 3) the anchor pairs of a cold start, for the pairs the previous lacks: the seed view's pair where the
    seed holds it and the body's previous holds no pair at all (``has_prev`` (B,) False), else the static reference
    (:func:`reference_positions`). The seed: the view with the most MEDIUM evidence, then the most pair joints, then
    the lowest index. numpy: it runs only when a body starts cold."""
    B = positions.shape[0]
    pairs = positions[:, :, _PAIR_JOINTS]  # (B, S, 2P, 3)
    evidence = (confidence >= int(Confidence.MEDIUM)).sum(axis=2)  # (B, S) MEDIUM-or-better joints
    seed = (evidence * (2 * _N_PAIRS + 1) + (~np.isnan(pairs[..., 0])).sum(axis=2)).argmax(axis=1)  # (B,)
    seed_pairs = pairs[np.arange(B), seed]  # (B, 2P, 3)
    seed_ok = ~np.isnan(seed_pairs[:, :_N_PAIRS, 0] + seed_pairs[:, _N_PAIRS:, 0])
    use_seed = np.tile(seed_ok & ~has_prev[:, None], 2)[..., None]
    return np.ascontiguousarray(
        np.where(use_seed, seed_pairs, reference_positions(positions, confidence)[:, _PAIR_JOINTS])
    )


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
