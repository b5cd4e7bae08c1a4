"""Plausibility before merging: a view whose body cannot be the tracked person is held out of the merge.

Body trackers fail in ways no per-joint vote sees: for a few frames a view turns the person upside down,
loses them and re-acquires them elsewhere (often under a new body id), or fits a body of another size. When
such a view is the only one left for a frame, the merge follows it and, through the previous-position
candidate, can stay with it. This stage checks every view's whole body, before the merge, against what the
track already knows, and holds out the views that fail:

* ``TELEPORT``: the mean offset of the view's torso joints from the track's one-step prediction (the
  filter's ``x + v dt``) is longer than ``plausibility_gate_mm`` (a person's torso does not move
  hundreds of millimetres faster than its own velocity says between two frames);
* ``UPSIDE_DOWN``: the view's pelvis-to-neck direction makes an angle with the track's predicted one whose
  cosine is below ``plausibility_up_cos`` (relative to the track, not to the world's z axis, so it holds in
  an uncalibrated sensor frame and for a person lying down);
* ``BONES``: the median ratio of the view's bone lengths to the person's learned bone lengths (the fused
  body's, learned while the views are plausible) is off by more than ``plausibility_bone_ratio`` (the
  tracker scales every bone together by 2-5 % per frame and by up to 11 % in a deep squat; a body of another
  size is not this person);
* optionally (``plausibility_joint_speed_mm_s``, off by default), a single joint: a candidate farther from its
  own prediction than that speed times dt plus the gate is dropped alone (the view stays in;
  :func:`merge_views`, run after the left/right realignment).

The view checks are mirror-invariant (torso mean, pelvis-to-neck direction, median bone ratio), so they run
*before* the realignment. A view upside down or of another size does not vote on the body's left/right (a
180 deg turned body looks mirrored and, with one other view, could turn the body's labels); a view held for a
teleport still votes (``PlausibilityResult.views``): with two sensors it is often the only view that keeps the
labels right while the other is a mirrored rear view. No held view is merged (:func:`merge_views`).

Hysteresis: a view that fails is held out at once; it is used again in its ``plausibility_release_frames``-th
plausible frame in a row. When every present view of a body fails for ``plausibility_follow_frames``
frames in a row, the track is what is wrong (real fast motion, a track started on a glitch): every view is
released and the caller restarts the body's filter where the views are; at once when two or more views moved
away from the track together (:func:`views_agree_elsewhere`). A body-id change at a sensor needs no rule
here: association matches bodies to tracks by position, so a re-acquired body that fits the
track is simply checked like any other view.

Batched over bodies B, sensors S and joints J: :func:`plausibility_step` (checks, hysteresis, follow rule and the
realignment's views), :func:`merge_views` and :func:`learn_bones` are one compiled call each
(:mod:`skelfuse.fusion.kernels.plausibility`), their numpy forms the test reference
(:mod:`skelfuse.fusion.reference.plausibility`); the caller keeps :class:`PlausibilityState`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skelfuse.fusion import kernels
from skelfuse.schema.skeleton import N_JOINTS, J

PLAUSIBLE = 0
TELEPORT = 1
UPSIDE_DOWN = 2
BONES = 3
HOLD_REASONS: tuple[str, ...] = ("teleport", "upside_down", "bones")
"""Names of the hold-out reasons 1.. (index ``reason - 1``), as counted in results and status documents."""

TORSO_JOINTS = np.array(
    [J[n] for n in ("PELVIS", "SPINE_NAVEL", "SPINE_CHEST", "NECK", "HIP_LEFT", "HIP_RIGHT")], dtype=np.int64
)
"""Joints whose mean offset from the prediction decides a teleport (mirror-invariant: both hips or none)."""

CHECK_BONES = np.array(
    [
        (J[a], J[b])
        for a, b in (
            ("PELVIS", "SPINE_NAVEL"),
            ("SPINE_NAVEL", "SPINE_CHEST"),
            ("SPINE_CHEST", "NECK"),
            ("SHOULDER_LEFT", "ELBOW_LEFT"),
            ("ELBOW_LEFT", "WRIST_LEFT"),
            ("SHOULDER_RIGHT", "ELBOW_RIGHT"),
            ("ELBOW_RIGHT", "WRIST_RIGHT"),
            ("HIP_LEFT", "KNEE_LEFT"),
            ("KNEE_LEFT", "ANKLE_LEFT"),
            ("HIP_RIGHT", "KNEE_RIGHT"),
            ("KNEE_RIGHT", "ANKLE_RIGHT"),
        )
    ],
    dtype=np.int64,
)
"""Bones whose lengths the body model keeps (hands, feet and face are guessed too often to judge a view)."""

BONE_LEARNING_RATE = 0.05
"""Weight of a frame in the learned bone lengths (about 20 frames of memory: follows the squat's shrinking)."""
MIN_BONE_FRAMES = 10
"""Frames of learning before the bone check runs."""
_NO_AGREEMENT = np.zeros(0, dtype=np.bool_)  # the kernel's agreement where none is known (it reads none)


@dataclass(frozen=True)
class PlausibilityParams:
    """The checks' thresholds (see the module docstring); built from FusionParams by the pipeline."""

    gate_mm: float
    up_cos: float
    bone_ratio: float
    joint_speed_mm_s: float
    release_frames: int
    follow_frames: int


@dataclass(frozen=True)
class PlausibilityState:
    """Per body: which views are held out and what the person's body is like.

    Attributes
    ----------
    held : (B, S) uint8, the reason a view is held out (0 = in use).
    release : (B, S) int32, plausible frames in a row of a held view.
    follow : (B,) int32, frames in a row in which every present view failed.
    bones : (B, NB) float64, mm, learned lengths of :data:`CHECK_BONES` (NaN or 0 = not learned).
    bone_frames : (B,) int32, frames the bone lengths were learned from.
    """

    held: np.ndarray
    release: np.ndarray
    follow: np.ndarray
    bones: np.ndarray
    bone_frames: np.ndarray


@dataclass(frozen=True)
class PlausibilityResult:
    """One frame's verdict.

    Attributes
    ----------
    held : (B, S) uint8, reason per view this frame (0 = used, or absent).
    failed : (B, S) uint8, reason the view failed this frame's checks (0 = passed or absent).
    restart : (B,) bool, every view had failed for ``follow_frames``: restart the body's filter at the views.
    views : (B, S, J, 3) float64 mm and views_confidence : (B, S, J) uint8, what the left/right realignment may
        see: the candidates without the views held upside down or for another size (NaN, confidence 0); a view
        held for a teleport still votes.
    """

    held: np.ndarray
    failed: np.ndarray
    restart: np.ndarray
    views: np.ndarray
    views_confidence: np.ndarray


def init_plausibility_state(n_bodies: int, n_sensors: int) -> PlausibilityState:
    """Nothing held, nothing learned."""
    return PlausibilityState(
        held=np.zeros((n_bodies, n_sensors), dtype=np.uint8),
        release=np.zeros((n_bodies, n_sensors), dtype=np.int32),
        follow=np.zeros(n_bodies, dtype=np.int32),
        bones=np.full((n_bodies, len(CHECK_BONES)), np.nan),
        bone_frames=np.zeros(n_bodies, dtype=np.int32),
    )


def bone_lengths(positions: np.ndarray) -> np.ndarray:
    """(..., J, 3) mm -> (..., NB) lengths of :data:`CHECK_BONES`, mm (NaN where an end is missing)."""
    diff = positions[..., CHECK_BONES[:, 1], :] - positions[..., CHECK_BONES[:, 0], :]
    return np.sqrt(np.sum(diff * diff, axis=-1))


def median_of_finite(values: np.ndarray, finite: np.ndarray) -> np.ndarray:
    """Median over the last axis of the entries where ``finite`` (1.0 where none), without numpy's all-NaN
    warning (vectorized: one sort)."""
    count = finite.sum(axis=-1)
    ordered = np.sort(np.where(finite, values, np.inf), axis=-1)
    low = np.take_along_axis(ordered, np.maximum((count - 1) // 2, 0)[..., None], axis=-1)[..., 0]
    high = np.take_along_axis(ordered, np.maximum(count // 2, 0)[..., None], axis=-1)[..., 0]
    return np.where(count > 0, 0.5 * (low + high), 1.0)


def torso_offset(candidates: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """(B, S, 3) mean offset of each view's torso joints from the prediction, mm (NaN: fewer than two in common).

    Mirror-invariant: the torso joints hold both hips or neither."""
    offset = candidates[:, :, TORSO_JOINTS] - predicted[:, None, TORSO_JOINTS]  # (B, S, T, 3)
    common = np.isfinite(offset).all(axis=-1)
    n_common = common.sum(axis=-1)
    mean_offset = np.where(common[..., None], offset, 0.0).sum(axis=-2) / np.maximum(n_common, 1)[..., None]
    return np.where((n_common >= 2)[..., None], mean_offset, np.nan)


def views_agree_elsewhere(
    candidates: np.ndarray, predicted: np.ndarray, present: np.ndarray, failed: np.ndarray, p: PlausibilityParams
) -> np.ndarray:
    """(B,) two or more views, every present one, moved away from the track together (their torso offsets within
    half the gate of their mean): the person is where they say (a track on the wrong place, a take's seam),
    so the track follows them at once instead of after ``follow_frames``."""
    offset = torso_offset(candidates, predicted)  # (B, S, 3)
    moved = present & (failed == TELEPORT) & np.isfinite(offset).all(axis=-1)
    n_moved = moved.sum(axis=-1)
    mean = np.where(moved[..., None], offset, 0.0).sum(axis=1) / np.maximum(n_moved, 1)[:, None]
    spread = np.where(moved, np.linalg.norm(offset - mean[:, None], axis=-1), 0.0).max(axis=-1, initial=0.0)
    return (n_moved >= 2) & (n_moved == present.sum(axis=-1)) & (spread < 0.5 * p.gate_mm)


def check_views(
    candidates: np.ndarray,
    predicted: np.ndarray,
    learned_bones: np.ndarray,
    bones_ready: np.ndarray,
    p: PlausibilityParams,
) -> np.ndarray:
    """The reason each view fails this frame (0 = passes or no evidence), no hysteresis.

    The checks of :func:`plausibility_step`'s compiled kernel (:mod:`skelfuse.fusion.kernels.plausibility`), for
    every view, present or not; the numpy form is the test reference (:mod:`skelfuse.fusion.reference.plausibility`).

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
    candidates = np.ascontiguousarray(candidates, dtype=np.float64)
    B, S = candidates.shape[:2]
    state = init_plausibility_state(B, S)
    no_confidence = np.zeros((B, S, N_JOINTS), np.uint8)
    return _step_kernel(candidates, no_confidence, predicted, state, learned_bones, bones_ready, p)[0]


def plausibility_step(
    candidates: np.ndarray,
    confidence: np.ndarray,
    predicted: np.ndarray,
    state: PlausibilityState,
    p: PlausibilityParams,
) -> tuple[PlausibilityResult, PlausibilityState]:
    """Check every view, apply the hysteresis and the follow rule, and blank what the realignment must not see.

    One compiled call (:mod:`skelfuse.fusion.kernels.plausibility`); the numpy form is the test reference
    (:mod:`skelfuse.fusion.reference.plausibility`).

    Parameters
    ----------
    candidates : (B, S, J, 3) float64 mm, the selected candidates, before the realignment; NaN = missing.
    confidence : (B, S, J) uint8, their confidences.
    predicted : (B, J, 3) mm, the track's one-step prediction; NaN = no track.
    state : PlausibilityState for the same B and S.
    p : PlausibilityParams

    Returns
    -------
    result : PlausibilityResult (its views go to the realignment; :func:`merge_views` applies the rest)
    state : the new PlausibilityState (the caller learns the bones with :func:`learn_bones` after the merge).
    """
    candidates = np.ascontiguousarray(candidates, dtype=np.float64)
    ready = state.bone_frames >= MIN_BONE_FRAMES
    _, failed, held_out, restart, held, release, follow, views, views_confidence = _step_kernel(
        candidates, confidence, predicted, state, state.bones, ready, p
    )
    new_state = PlausibilityState(
        held=held, release=release, follow=follow, bones=state.bones, bone_frames=state.bone_frames
    )
    return PlausibilityResult(
        held=held_out, failed=failed, restart=restart, views=views, views_confidence=views_confidence
    ), new_state


def _step_kernel(
    candidates: np.ndarray,
    confidence: np.ndarray,
    predicted: np.ndarray,
    state: PlausibilityState,
    learned_bones: np.ndarray,
    bones_ready: np.ndarray,
    p: PlausibilityParams,
) -> tuple[np.ndarray, ...]:
    """The plausibility kernel's call, its arguments checked (compiled code does not check its indices)."""
    B, S = candidates.shape[:2]
    if candidates.shape[2:] != (N_JOINTS, 3):
        raise ValueError(f"plausibility needs candidates (B, S, {N_JOINTS}, 3), got {candidates.shape}")
    arguments = (
        candidates,
        kernels.kernel_array(confidence, np.uint8, (B, S, N_JOINTS), "confidence"),
        kernels.kernel_array(predicted, np.float64, (B, N_JOINTS, 3), "predicted"),
        kernels.kernel_array(state.held, np.uint8, (B, S), "held"),
        kernels.kernel_array(state.release, np.int32, (B, S), "release"),
        kernels.kernel_array(state.follow, np.int32, (B,), "follow"),
        kernels.kernel_array(learned_bones, np.float64, (B, len(CHECK_BONES)), "learned_bones"),
        kernels.kernel_array(bones_ready, np.bool_, (B,), "bones_ready"),
        TORSO_JOINTS,
        CHECK_BONES,
        J["NECK"],
        J["PELVIS"],
        float(p.gate_mm),
        float(p.up_cos),
        math.log1p(p.bone_ratio),
        int(p.release_frames),
        int(p.follow_frames),
    )
    kernel = kernels.load().plausibility.plausibility_step
    out = kernel(*arguments, _NO_AGREEMENT, False)
    if out[9].any():  # every view of a body failed (rare): did they move away together? Then the whole call again
        present = np.isfinite(arguments[0][..., TORSO_JOINTS, 0]).any(axis=-1)
        out = kernel(*arguments, views_agree_elsewhere(candidates, arguments[2], present, out[1], p), True)
    return out[:9]


def merge_views(
    candidates: np.ndarray,
    confidence: np.ndarray,
    result: PlausibilityResult,
    predicted: np.ndarray,
    p: PlausibilityParams,
    dt_s: float,
) -> tuple[np.ndarray, np.ndarray]:
    """What the merge gets from the *realigned* candidates: no held view (NaN / confidence 0), and no single joint
    farther from its own prediction than ``joint_speed_mm_s * dt`` plus the gate (a mirrored view's limbs are far
    from their prediction until the realignment swaps them back); nothing is dropped alone in a body whose track
    restarts this frame. One compiled call; the numpy form is the test reference.

    Returns
    -------
    positions : (B, S, J, 3) float64, NaN where held or dropped; confidence : (B, S, J) uint8, 0 there.
    """
    candidates = np.ascontiguousarray(candidates, dtype=np.float64)
    B, S = candidates.shape[:2]
    if candidates.shape[2:] != (N_JOINTS, 3):
        raise ValueError(f"merge_views needs candidates (B, S, {N_JOINTS}, 3), got {candidates.shape}")
    return kernels.load().plausibility.merge_views(
        candidates,
        kernels.kernel_array(confidence, np.uint8, (B, S, N_JOINTS), "confidence"),
        kernels.kernel_array(result.held, np.uint8, (B, S), "held"),
        kernels.kernel_array(predicted, np.float64, (B, N_JOINTS, 3), "predicted"),
        kernels.kernel_array(result.restart, np.bool_, (B,), "restart"),
        p.joint_speed_mm_s * dt_s + p.gate_mm,
    )


def learn_bones(state: PlausibilityState, merged: np.ndarray, n_agree: np.ndarray) -> PlausibilityState:
    """Fold this frame's merged body into the learned bone lengths (bones whose both ends were merged): the first
    length as it is, then at ``max(BONE_LEARNING_RATE, 1 / (frames + 1))``. One compiled call; the numpy form is
    the test reference.

    Parameters
    ----------
    merged : (B, J, 3) mm, the merge of the plausible views; n_agree : (B, J) views behind each joint.
    """
    B = len(state.bones)
    bones, frames = kernels.load().plausibility.learn_bones(
        kernels.kernel_array(merged, np.float64, (B, N_JOINTS, 3), "merged"),
        kernels.kernel_array(n_agree, np.int16, (B, N_JOINTS), "n_agree"),
        kernels.kernel_array(state.bones, np.float64, (B, len(CHECK_BONES)), "bones"),
        kernels.kernel_array(state.bone_frames, np.int32, (B,), "bone_frames"),
        CHECK_BONES,
        BONE_LEARNING_RATE,
    )
    return PlausibilityState(
        held=state.held, release=state.release, follow=state.follow, bones=bones, bone_frames=frames
    )
