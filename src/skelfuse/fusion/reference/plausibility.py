"""The numpy form of the plausibility stage: the test reference of :func:`skelfuse.fusion.plausibility.check_views`,
:func:`~skelfuse.fusion.plausibility.plausibility_step`, :func:`~skelfuse.fusion.plausibility.merge_views` and
:func:`~skelfuse.fusion.plausibility.learn_bones` (the live path runs :mod:`skelfuse.fusion.kernels.plausibility`
and never imports this module). The rules are documented in :mod:`skelfuse.fusion.plausibility`.
"""

from __future__ import annotations

import math

import numpy as np

from skelfuse.fusion.plausibility import (
    BONE_LEARNING_RATE,
    BONES,
    MIN_BONE_FRAMES,
    PLAUSIBLE,
    TELEPORT,
    TORSO_JOINTS,
    UPSIDE_DOWN,
    PlausibilityParams,
    PlausibilityResult,
    PlausibilityState,
    bone_lengths,
    median_of_finite,
    torso_offset,
    views_agree_elsewhere,
)
from skelfuse.schema.skeleton import J


def _up(positions: np.ndarray) -> np.ndarray:
    """(..., J, 3) -> (..., 3) unit pelvis-to-neck direction (NaN where either joint is missing)."""
    up = positions[..., J["NECK"], :] - positions[..., J["PELVIS"], :]
    norm = np.sqrt(np.sum(up * up, axis=-1, keepdims=True))
    with np.errstate(invalid="ignore", divide="ignore"):
        return up / norm


def check_views(
    candidates: np.ndarray,
    predicted: np.ndarray,
    learned_bones: np.ndarray,
    bones_ready: np.ndarray,
    p: PlausibilityParams,
) -> np.ndarray:
    """The reason each view fails this frame (0 = passes or no evidence), no hysteresis: numpy over all views.

    Parameters
    ----------
    candidates : (B, S, J, 3) mm, NaN = missing.
    predicted : (B, J, 3) mm, the track's prediction (NaN = no track for that joint).
    learned_bones : (B, NB) mm; bones_ready : (B,) bool, the lengths are learned enough to judge.
    p : PlausibilityParams

    Returns
    -------
    (B, S) uint8 reason (UPSIDE_DOWN before BONES before TELEPORT where several hold).
    """
    mean_offset = torso_offset(candidates, predicted)
    teleport = np.sum(mean_offset * mean_offset, axis=-1) > p.gate_mm**2  # NaN compares False

    cos_up = np.sum(_up(candidates) * _up(predicted)[:, None], axis=-1)  # NaN where unknown: compares False
    upside_down = cos_up < p.up_cos

    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = bone_lengths(candidates) / learned_bones[:, None]  # (B, S, NB)
    known = np.isfinite(ratio)
    enough = known.sum(axis=-1) >= 3
    median = median_of_finite(ratio, known)
    wrong_size = (
        enough & bones_ready[:, None] & (np.abs(np.log(np.where(enough, median, 1.0))) > math.log1p(p.bone_ratio))
    )

    reason = np.where(teleport, TELEPORT, PLAUSIBLE)
    reason = np.where(wrong_size, BONES, reason)
    return np.where(upside_down, UPSIDE_DOWN, reason).astype(np.uint8)


def plausibility_step(
    candidates: np.ndarray,
    confidence: np.ndarray,
    predicted: np.ndarray,
    state: PlausibilityState,
    p: PlausibilityParams,
) -> tuple[PlausibilityResult, PlausibilityState]:
    """:func:`skelfuse.fusion.plausibility.plausibility_step` in numpy: every body and view at once."""
    present = np.isfinite(candidates[..., TORSO_JOINTS, 0]).any(axis=-1)  # (B, S)
    failed = np.where(
        present, check_views(candidates, predicted, state.bones, state.bone_frames >= MIN_BONE_FRAMES, p), 0
    )
    failed = failed.astype(np.uint8)
    # Every present view failed: count; after follow_frames the track follows the views.
    all_failed = present.any(axis=-1) & ~((present & (failed == PLAUSIBLE)).any(axis=-1))
    follow = np.where(all_failed, state.follow + 1, 0).astype(np.int32)
    restart = follow >= p.follow_frames
    if all_failed.any():  # the views' agreement matters only for a body every view failed
        restart |= all_failed & views_agree_elsewhere(candidates, predicted, present, failed, p)
    # Hysteresis: a failing view is held (reason of this frame); a held view passing counts towards release.
    release = np.where((state.held > 0) & present & (failed == PLAUSIBLE), state.release + 1, 0).astype(np.int32)
    released = (release >= p.release_frames) | restart[:, None]
    held = np.where(failed > 0, failed, np.where(released, PLAUSIBLE, state.held)).astype(np.uint8)
    held = np.where(restart[:, None], PLAUSIBLE, held).astype(np.uint8)
    release = np.where(held > 0, release, 0).astype(np.int32)
    follow = np.where(restart, 0, follow).astype(np.int32)

    new_state = PlausibilityState(
        held=held, release=release, follow=follow, bones=state.bones, bone_frames=state.bone_frames
    )
    held_out = np.where(present, held, 0).astype(np.uint8)
    views, views_confidence = realignment_views(candidates, confidence, held_out)
    result = PlausibilityResult(
        held=held_out, failed=failed, restart=restart, views=views, views_confidence=views_confidence
    )
    return result, new_state


def realignment_views(
    candidates: np.ndarray, confidence: np.ndarray, held: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """What the left/right realignment may see: every view but those upside down or of another size (a body
    turned 180 deg looks mirrored: it would vote the labels wrong, and its jump would restart the realignment).
    A view held for a teleport still votes where it is: its labels still tell left from right, and a jump that
    every view makes (a looped take's seam) must still restart the realignment."""
    garbage = (held == UPSIDE_DOWN) | (held == BONES)
    positions = np.where(garbage[..., None, None], np.nan, candidates)
    return positions, np.where(garbage[..., None], 0, confidence).astype(np.uint8)


def merge_views(
    candidates: np.ndarray,
    confidence: np.ndarray,
    result: PlausibilityResult,
    predicted: np.ndarray,
    p: PlausibilityParams,
    dt_s: float,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`skelfuse.fusion.plausibility.merge_views` in numpy: the held views out, then the far joints."""
    positions, conf = remove_held(candidates, confidence, result.held)
    return drop_far_joints(positions, conf, predicted, result.restart, p, dt_s)


def remove_held(candidates: np.ndarray, confidence: np.ndarray, held: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The candidates without the held-out views (NaN / confidence 0): what the merge gets."""
    use = held == PLAUSIBLE
    return np.where(use[..., None, None], candidates, np.nan), np.where(use[..., None], confidence, 0).astype(np.uint8)


def drop_far_joints(
    candidates: np.ndarray,
    confidence: np.ndarray,
    predicted: np.ndarray,
    restart: np.ndarray,
    p: PlausibilityParams,
    dt_s: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Drop single candidates farther from their own prediction than ``joint_speed_mm_s * dt`` plus the gate.

    Run on the *realigned* candidates (a mirrored view's limbs are far from their prediction until the
    realignment swaps them back); nothing is dropped for a body whose track restarts this frame.

    Returns
    -------
    positions : (B, S, J, 3) NaN where dropped; confidence : (B, S, J) 0 where dropped.
    """
    distance = np.sqrt(np.sum((candidates - predicted[:, None]) ** 2, axis=-1))  # (B, S, J), NaN: unknown
    too_far = (distance > p.joint_speed_mm_s * dt_s + p.gate_mm) & ~restart[:, None, None]
    return np.where(too_far[..., None], np.nan, candidates), np.where(too_far, 0, confidence).astype(np.uint8)


def learn_bones(state: PlausibilityState, merged: np.ndarray, n_agree: np.ndarray) -> PlausibilityState:
    """:func:`skelfuse.fusion.plausibility.learn_bones` in numpy: every body and bone at once."""
    lengths = bone_lengths(np.where((n_agree > 0)[..., None], merged, np.nan))  # (B, NB)
    seen = np.isfinite(lengths)
    first = ~(state.bones > 0)  # NaN or 0: not learned yet
    rate = np.where(first, 1.0, np.maximum(BONE_LEARNING_RATE, 1.0 / (state.bone_frames[:, None] + 1.0)))
    bones = np.where(seen, np.where(first, lengths, state.bones + rate * (lengths - state.bones)), state.bones)
    frames = state.bone_frames + seen.any(axis=-1)
    return PlausibilityState(
        held=state.held, release=state.release, follow=state.follow, bones=bones, bone_frames=frames.astype(np.int32)
    )
