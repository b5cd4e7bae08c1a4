"""The plausibility stage (:func:`skelfuse.fusion.plausibility.plausibility_step`) as one compiled call.

Per body and view: the mean offset of the torso joints from the prediction (a teleport), the pelvis-to-neck
direction against the prediction's (upside down), the median ratio of the bone lengths to the learned ones
(another body); then the hold-out hysteresis, the follow rule and the views the realignment may see. The same
sums in the same order as the numpy reference (:mod:`skelfuse.fusion.reference.plausibility`); the rules are
documented in :mod:`skelfuse.fusion.plausibility`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from skelfuse.fusion.kernels.signatures import BOOL, FLOAT, HELPER, INT, INT16, INT32, KERNEL, UINT8, array

PLAUSIBLE, TELEPORT, UPSIDE_DOWN, BONES = 0, 1, 2, 3  # as skelfuse.fusion.plausibility's reasons


@numba.njit(**HELPER)
def _torso_offset(view: np.ndarray, predicted: np.ndarray, torso: np.ndarray) -> tuple[float, float, float]:
    """The mean offset of the torso joints both have, mm (NaN: fewer than two in common)."""
    sx = sy = sz = 0.0
    n_common = 0
    for joint in torso:
        dx = view[joint, 0] - predicted[joint, 0]
        dy = view[joint, 1] - predicted[joint, 1]
        dz = view[joint, 2] - predicted[joint, 2]
        if math.isfinite(dx) and math.isfinite(dy) and math.isfinite(dz):
            sx += dx
            sy += dy
            sz += dz
            n_common += 1
    if n_common < 2:
        return np.nan, np.nan, np.nan
    return sx / n_common, sy / n_common, sz / n_common


@numba.njit(**HELPER)
def _up(body: np.ndarray, neck: int, pelvis: int) -> tuple[float, float, float]:
    """Unit pelvis-to-neck direction (NaN where either joint is missing or they coincide)."""
    ux = body[neck, 0] - body[pelvis, 0]
    uy = body[neck, 1] - body[pelvis, 1]
    uz = body[neck, 2] - body[pelvis, 2]
    norm = math.sqrt(ux * ux + uy * uy + uz * uz)
    return ux / norm, uy / norm, uz / norm


@numba.njit(**HELPER)
def _median_bone_ratio(view: np.ndarray, learned: np.ndarray, bones: np.ndarray, ratios: np.ndarray) -> float:
    """Median of the finite ratios view bone length / learned length; NaN when fewer than three are known."""
    n = 0
    for k in range(bones.shape[0]):
        a, b = bones[k, 0], bones[k, 1]
        dx = view[b, 0] - view[a, 0]
        dy = view[b, 1] - view[a, 1]
        dz = view[b, 2] - view[a, 2]
        ratio = math.sqrt(dx * dx + dy * dy + dz * dz) / learned[k]
        if math.isfinite(ratio):
            i = n  # insertion sort: a dozen bones
            while i > 0 and ratios[i - 1] > ratio:
                ratios[i] = ratios[i - 1]
                i -= 1
            ratios[i] = ratio
            n += 1
    if n < 3:
        return np.nan
    return 0.5 * (ratios[(n - 1) // 2] + ratios[n // 2])


@numba.njit(**HELPER)
def _view_reason(
    view: np.ndarray,
    predicted: np.ndarray,
    learned: np.ndarray,
    bones_ready: bool,
    torso: np.ndarray,
    bones: np.ndarray,
    up: tuple[float, float, float],
    thresholds: tuple[float, float, float],
    neck: int,
    pelvis: int,
    ratios: np.ndarray,
) -> int:
    """One view's reason to fail (UPSIDE_DOWN before BONES before TELEPORT; 0 = passes or no evidence).
    ``up``: the prediction's unit pelvis-to-neck direction; ``thresholds``: gate_mm, up_cos, log1p(bone_ratio)."""
    gate_mm, up_cos, log_bone_ratio = thresholds
    vx, vy, vz = _up(view, neck, pelvis)
    if vx * up[0] + vy * up[1] + vz * up[2] < up_cos:  # NaN compares False
        return UPSIDE_DOWN
    if bones_ready:
        median = _median_bone_ratio(view, learned, bones, ratios)
        if abs(np.log(median)) > log_bone_ratio:  # NaN (too few bones) compares False
            return BONES
    mx, my, mz = _torso_offset(view, predicted, torso)
    if mx * mx + my * my + mz * mz > gate_mm * gate_mm:  # NaN compares False
        return TELEPORT
    return PLAUSIBLE


_SIGNATURE = (
    array(FLOAT, 4),  # candidates
    array(UINT8, 3),  # confidence
    array(FLOAT, 3),  # predicted
    array(UINT8, 2),  # held
    array(INT32, 2),  # release
    array(INT32, 1),  # follow
    array(FLOAT, 2),  # learned_bones
    array(BOOL, 1),  # bones_ready
    array(INT, 1),  # torso
    array(INT, 2),  # bones
    INT,  # neck
    INT,  # pelvis
    FLOAT,  # gate_mm
    FLOAT,  # up_cos
    FLOAT,  # log_bone_ratio
    INT,  # release_frames
    INT,  # follow_frames
    array(BOOL, 1),  # agree_elsewhere
    BOOL,  # agreement_known
)


@numba.njit(_SIGNATURE, **KERNEL)
def plausibility_step(
    candidates: np.ndarray,
    confidence: np.ndarray,
    predicted: np.ndarray,
    held: np.ndarray,
    release: np.ndarray,
    follow: np.ndarray,
    learned_bones: np.ndarray,
    bones_ready: np.ndarray,
    torso: np.ndarray,
    bones: np.ndarray,
    neck: int,
    pelvis: int,
    gate_mm: float,
    up_cos: float,
    log_bone_ratio: float,
    release_frames: int,
    follow_frames: int,
    agree_elsewhere: np.ndarray,
    agreement_known: bool,
) -> tuple[np.ndarray, ...]:
    """Check every view, apply the hysteresis and the follow rule, and blank the views the realignment must not see.

    Parameters
    ----------
    candidates : (B, S, J, 3) float64 mm; confidence : (B, S, J) uint8; predicted : (B, J, 3) float64 mm; held,
    release : (B, S) uint8 / int32 and follow : (B,) int32, the hysteresis state; learned_bones : (B, NB) float64
    mm; bones_ready : (B,) bool; torso : (T,) int64 joint indices; bones : (NB, 2) int64 joint pairs (parent,
    child); neck, pelvis : joint indices; gate_mm, up_cos : thresholds; log_bone_ratio : log1p(bone_ratio);
    release_frames, follow_frames : the hysteresis; agree_elsewhere : (B,) bool, read where ``agreement_known``:
    the body's present views moved away from the track together (every view of a body failed; the caller tests
    that in numpy when this call asks for it, and calls again).

    Returns
    -------
    reasons (B, S) uint8, every view's reason to fail this frame (absent views too); failed (B, S) uint8, the
    present views' reasons; held_out (B, S) uint8, the reason each present view is held out; restart (B,) bool;
    the new held (B, S) uint8, release (B, S) int32 and follow (B,) int32; the realignment's views (B, S, J, 3)
    float64 and their confidence (B, S, J) uint8; needs_agreement (B,) bool, every present view failed and
    ``agreement_known`` is off.
    """
    B, S = candidates.shape[0], candidates.shape[1]
    thresholds = (gate_mm, up_cos, log_bone_ratio)
    reasons = np.empty((B, S), dtype=np.uint8)
    failed_out = np.empty((B, S), dtype=np.uint8)
    held_out = np.empty((B, S), dtype=np.uint8)
    restart = np.empty(B, dtype=np.bool_)
    needs_agreement = np.empty(B, dtype=np.bool_)
    new_held = np.empty((B, S), dtype=np.uint8)
    new_release = np.empty((B, S), dtype=np.int32)
    new_follow = np.empty(B, dtype=np.int32)
    views = candidates.copy()
    views_confidence = confidence.copy()
    ratios = np.empty(bones.shape[0])
    present = np.empty(S, dtype=np.bool_)
    failed = np.empty(S, dtype=np.uint8)
    for b in range(B):
        up = _up(predicted[b], neck, pelvis)
        any_present = any_passed = False
        for s in range(S):
            view = candidates[b, s]
            reasons[b, s] = _view_reason(
                view, predicted[b], learned_bones[b], bones_ready[b], torso, bones, up, thresholds, neck, pelvis, ratios
            )
            present[s] = False
            for joint in torso:
                present[s] |= math.isfinite(view[joint, 0])
            failed[s] = reasons[b, s] if present[s] else PLAUSIBLE
            failed_out[b, s] = failed[s]
            any_present |= present[s]
            any_passed |= present[s] and failed[s] == PLAUSIBLE
        all_failed = any_present and not any_passed
        new_follow[b] = follow[b] + 1 if all_failed else 0
        needs_agreement[b] = all_failed and not agreement_known
        restart[b] = new_follow[b] >= follow_frames or (all_failed and agreement_known and agree_elsewhere[b])
        for s in range(S):
            passing = held[b, s] > 0 and present[s] and failed[s] == PLAUSIBLE
            count = release[b, s] + 1 if passing else 0
            if failed[s] > 0:
                new_held[b, s] = failed[s]
            elif count >= release_frames or restart[b]:
                new_held[b, s] = PLAUSIBLE
            else:
                new_held[b, s] = held[b, s]
            if restart[b]:
                new_held[b, s] = PLAUSIBLE
            new_release[b, s] = count if new_held[b, s] > 0 else 0
            held_out[b, s] = new_held[b, s] if present[s] else PLAUSIBLE
            if held_out[b, s] == UPSIDE_DOWN or held_out[b, s] == BONES:  # does not vote on left/right
                for j in range(candidates.shape[2]):
                    views[b, s, j, 0] = views[b, s, j, 1] = views[b, s, j, 2] = np.nan
                    views_confidence[b, s, j] = 0
        if restart[b]:
            new_follow[b] = 0
    return (
        reasons,
        failed_out,
        held_out,
        restart,
        new_held,
        new_release,
        new_follow,
        views,
        views_confidence,
        needs_agreement,
    )


_MERGE_VIEWS_SIGNATURE = (
    array(FLOAT, 4),  # candidates
    array(UINT8, 3),  # confidence
    array(UINT8, 2),  # held
    array(FLOAT, 3),  # predicted
    array(BOOL, 1),  # restart
    FLOAT,  # max_distance_mm
)


@numba.njit(_MERGE_VIEWS_SIGNATURE, **KERNEL)
def merge_views(
    candidates: np.ndarray,
    confidence: np.ndarray,
    held: np.ndarray,
    predicted: np.ndarray,
    restart: np.ndarray,
    max_distance_mm: float,
) -> tuple[np.ndarray, np.ndarray]:
    """What the merge gets: the held views blanked (NaN, confidence 0), and each joint farther than
    ``max_distance_mm`` from its prediction (inf: none) dropped alone, except in a body whose track restarts."""
    B, S, J = candidates.shape[0], candidates.shape[1], candidates.shape[2]
    positions = candidates.copy()
    out_confidence = confidence.copy()
    check_joints = max_distance_mm < np.inf  # off: no distance to take
    for b in range(B):
        for s in range(S):
            held_out = held[b, s] != PLAUSIBLE
            if not held_out and not (check_joints and not restart[b]):
                continue
            for j in range(J):
                too_far = False
                if not held_out:
                    dx = candidates[b, s, j, 0] - predicted[b, j, 0]
                    dy = candidates[b, s, j, 1] - predicted[b, j, 1]
                    dz = candidates[b, s, j, 2] - predicted[b, j, 2]
                    too_far = math.sqrt(dx * dx + dy * dy + dz * dz) > max_distance_mm  # NaN compares False
                if held_out or too_far:
                    positions[b, s, j, 0] = positions[b, s, j, 1] = positions[b, s, j, 2] = np.nan
                    out_confidence[b, s, j] = 0
    return positions, out_confidence


_LEARN_BONES_SIGNATURE = (
    array(FLOAT, 3),  # merged
    array(INT16, 2),  # n_agree
    array(FLOAT, 2),  # learned_bones
    array(INT32, 1),  # bone_frames
    array(INT, 2),  # bones
    FLOAT,  # learning_rate
)


@numba.njit(_LEARN_BONES_SIGNATURE, **KERNEL)
def learn_bones(
    merged: np.ndarray,
    n_agree: np.ndarray,
    learned_bones: np.ndarray,
    bone_frames: np.ndarray,
    bones: np.ndarray,
    learning_rate: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Fold each body's merged bones (both ends merged this frame) into its learned lengths: the first length as it
    is, later ones at ``max(learning_rate, 1 / (frames + 1))``; returns the lengths (B, NB) and frames (B,)."""
    B, NB = learned_bones.shape[0], learned_bones.shape[1]
    out_bones = learned_bones.copy()
    out_frames = bone_frames.copy()
    for b in range(B):
        seen_any = False
        for k in range(NB):
            parent, child = bones[k, 0], bones[k, 1]
            if n_agree[b, parent] <= 0 or n_agree[b, child] <= 0:
                continue
            dx = merged[b, child, 0] - merged[b, parent, 0]
            dy = merged[b, child, 1] - merged[b, parent, 1]
            dz = merged[b, child, 2] - merged[b, parent, 2]
            length = math.sqrt(dx * dx + dy * dy + dz * dz)
            if not math.isfinite(length):
                continue
            seen_any = True
            old = learned_bones[b, k]
            if not old > 0:  # NaN or 0: not learned yet
                out_bones[b, k] = length
            else:
                out_bones[b, k] = old + max(learning_rate, 1.0 / (bone_frames[b] + 1.0)) * (length - old)
        out_frames[b] += seen_any
    return out_bones, out_frames


def warm_up() -> None:
    """Compile (or load) :func:`plausibility_step`, :func:`merge_views` and :func:`learn_bones` for their signatures."""
    candidates = np.zeros((1, 1, 4, 3))
    bones = np.array([[0, 1], [1, 2], [2, 3]], dtype=np.int64)
    plausibility_step(
        candidates,
        np.zeros((1, 1, 4), dtype=np.uint8),
        candidates[:, 0],
        np.zeros((1, 1), dtype=np.uint8),
        np.zeros((1, 1), dtype=np.int32),
        np.zeros(1, dtype=np.int32),
        np.ones((1, 3)),
        np.ones(1, dtype=np.bool_),
        np.arange(4),
        bones,
        3,
        0,
        250.0,
        0.0,
        0.2,
        3,
        8,
        np.zeros(1, dtype=np.bool_),
        True,
    )
    merge_views(
        candidates,
        np.zeros((1, 1, 4), dtype=np.uint8),
        np.zeros((1, 1), dtype=np.uint8),
        candidates[:, 0],
        np.zeros(1, dtype=np.bool_),
        np.inf,
    )
    learn_bones(
        candidates[:, 0], np.ones((1, 4), dtype=np.int16), np.ones((1, 3)), np.ones(1, dtype=np.int32), bones, 0.05
    )
