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

All functions are vectorized over bodies, sensors and pairs, and never modify their inputs.
"""

from __future__ import annotations

import numpy as np

from skelfuse.skeleton import MIRROR, PAPER_REALIGN_PAIRS, Confidence

# Confidence value -> one-hot tier (NONE, LOW, MEDIUM+); HIGH and anything above count as MEDIUM.
_TIER_ONEHOT = np.minimum(np.arange(256), int(Confidence.MEDIUM))[:, None] == np.arange(3)
_ONES3 = np.ones(3)  # x @ ones sums the last axis of 3 faster than x.sum(-1)
_PAIR_LEFT = PAPER_REALIGN_PAIRS[:, 0]
_PAIR_RIGHT = PAPER_REALIGN_PAIRS[:, 1]
_PAIR_JOINTS = np.concatenate([_PAIR_LEFT, _PAIR_RIGHT])  # (2P,) left joints, then right joints
_PAIR_SWAPPED = np.concatenate([_PAIR_RIGHT, _PAIR_LEFT])
_N_PAIRS = len(PAPER_REALIGN_PAIRS)


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
    valid = ~np.isnan(positions[..., 0])
    # One matmul sums positions and counts for all three tiers at once: (B,J,T,S) @ (B,J,S,4).
    onehot = _TIER_ONEHOT[confidence] & valid[..., None]
    augmented = np.concatenate([np.where(valid[..., None], positions, 0.0), valid[..., None]], axis=-1)
    sums = np.transpose(onehot, (0, 2, 3, 1)).astype(np.float64) @ np.transpose(augmented, (0, 2, 1, 3))
    has = sums[..., 3:] > 0  # (B, J, T, 1)
    best = np.where(has[..., 2, :], sums[..., 2, :], np.where(has[..., 1, :], sums[..., 1, :], sums[..., 0, :]))
    count = best[..., 3:]
    # 0 / NaN is a quiet NaN: no candidate at all gives NaN without a division warning.
    return best[..., :3] / np.where(count > 0, count, np.nan)


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
    cand = positions[:, :, _PAIR_JOINTS]  # (B, S, 2P, 3): left joints then right joints
    cand_conf = confidence[:, :, _PAIR_JOINTS]
    cand_swapped = positions[:, :, _PAIR_SWAPPED]
    ref_cand, ref_conf = cand, cand_conf
    mirrored = np.zeros(positions.shape[:2], dtype=bool)
    for round_idx in range(passes):  # a fixed, small number of rounds
        if round_idx == 0 and reference is not None:
            ref = reference[:, None, _PAIR_JOINTS]
        elif round_idx > 0 and not mirrored.any():
            break  # nothing changed: the reference, and so the decision, would be the same again
        else:
            ref = reference_positions(ref_cand, ref_conf)[:, None]  # (B, 1, 2P, 3)
        keep = np.sqrt(((cand - ref) ** 2).sum(-1))  # (B, S, 2P)
        swap = np.sqrt(((cand_swapped - ref) ** 2).sum(-1))
        # A pair counts only where both its keep and swap costs exist (both joints and both references).
        decidable = ~np.isnan(keep[..., :_N_PAIRS] + keep[..., _N_PAIRS:] + swap[..., :_N_PAIRS] + swap[..., _N_PAIRS:])
        decidable = np.concatenate([decidable, decidable], axis=-1)
        mirrored = np.where(decidable, swap - keep, 0.0).sum(-1) < 0.0
        ref_cand = np.where(mirrored[..., None, None], cand_swapped, cand)
        ref_conf = np.where(mirrored[..., None], confidence[:, :, _PAIR_SWAPPED], cand_conf)
    if not mirrored.any():
        return positions, confidence, mirrored
    out_positions = np.where(mirrored[..., None, None], positions[:, :, MIRROR], positions)
    out_confidence = np.where(mirrored[..., None], confidence[:, :, MIRROR], confidence)
    return out_positions, out_confidence, mirrored


def realign(
    positions: np.ndarray, confidence: np.ndarray, mode: str | None, passes: int = 2
) -> tuple[np.ndarray, np.ndarray]:
    """Dispatch on ``mode`` ("paper", "body" or None = unchanged); returns (positions, confidence)."""
    if mode is None:
        return positions, confidence
    if mode == "paper":
        out_positions, out_confidence, _ = realign_paper(positions, confidence)
    elif mode == "body":
        out_positions, out_confidence, _ = realign_body(positions, confidence, passes)
    else:
        raise ValueError(f"realign mode must be 'paper', 'body' or None, got {mode!r}")
    return out_positions, out_confidence


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
