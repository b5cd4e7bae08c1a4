"""One fusion step: select candidates -> realign -> merge -> filter (Lee et al. 2022, section 2.2).

Input is one instant of the rig, already in the world frame and already associated: row b of every sensor
is the same person (a sensor that does not see person b has NaN there). :func:`fuse` is pure: it takes the
previous :class:`FusionState` and returns the result and a new state, never mutating its inputs;
:class:`Fuser` is a thin stateful wrapper for callers that just want ``step()``.

Stages (each a pure function of its own module, so it can be tested and timed alone):

1. :func:`select_candidates`: a candidate is missing when any coordinate is NaN/inf or its confidence is
   below ``params.min_confidence`` (default LOW, so NONE joints are dropped).
2. Left/right realignment (:mod:`skelfuse.fusion.realign`): "paper", "body", "temporal" or off. The
   "temporal" anchor is the previous candidate of trick 2 (see ``FusionParams.previous_candidate``), so
   the labels follow the person frame by frame; its disagreement counters live in the state.
3. Merge: :func:`skelfuse.fusion.merge.merge_dbscan` with the reference candidate (trick 1), recomputed
   from the *realigned* candidates so a swapped view no longer drags it, and the previous frame's merged
   position (trick 2: the merge output before filtering, NaN if the joint was not merged last frame; or,
   with ``previous_candidate="predicted"`` and a cv_kalman/alpha_beta filter, the filter's one-step
   prediction ``x + v dt`` for joints whose track is alive); or
   :func:`skelfuse.fusion.merge.merge_average`.
4. :func:`skelfuse.fusion.filters.filter_step`: per-joint filter with coasting, or pass-through.
5. Optional (``params.orientations``): :func:`skelfuse.fusion.orientation.fuse_orientations` on the filtered
   positions and the views' world quaternions (``fuse(..., orientations=)``); views the realignment flipped
   (any pair, for "paper") and views whose candidate was not merged into the joint are left out.
6. Optional (``params.plausibility_gate_mm``, between 1 and 2, and after 2): :mod:`skelfuse.fusion.plausibility`
   holds out the views whose body cannot be the tracked person (a teleport away from the track's prediction,
   upside down, another body size) before they can vote on the left/right labels, and after the realignment
   drops single joints far beyond their prediction; when every view has failed for a while the body's filter
   and realignment restart at the views.
7. Optional (``params.position_std``): :mod:`skelfuse.fusion.uncertainty`, the per-joint one-sigma position
   uncertainty from the merged cluster's spread and a covariance recursion. Neither changes the positions.

Quality fields: ``n_agree`` and ``confidence`` describe this frame's measurement, so a coasted (predicted
only) joint reports 0 for both, as does a joint with no estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from skelfuse.fusion import kernels
from skelfuse.fusion.filters import filter_step, init_filter_state
from skelfuse.fusion.merge import MergeResult, merge_average, merge_dbscan
from skelfuse.fusion.orientation import OrientationParams, fuse_orientations, init_orientation_state
from skelfuse.fusion.plausibility import (
    TORSO_JOINTS,
    PlausibilityParams,
    PlausibilityResult,
    PlausibilityState,
    init_plausibility_state,
    learn_bones,
    merge_views,
    plausibility_step,
)
from skelfuse.fusion.presets import FusionParams
from skelfuse.fusion.realign import realign_body, realign_paper, realign_temporal, reference_positions
from skelfuse.fusion.uncertainty import position_uncertainty
from skelfuse.schema.skeleton import N_JOINTS


@dataclass(frozen=True)
class FusionResult:
    """Fused skeletons of one instant.

    Attributes
    ----------
    positions : (B, J, 3) float64, mm, world frame. NaN = no estimate.
    n_agree : (B, J) int16, sensor candidates in the winning cluster (0 = coasted/predicted or none).
    confidence : (B, J) uint8, highest tracker confidence among the merged candidates (0 if none).
    contributors : (B, S) bool, sensors whose candidates were merged into at least one joint of the body.
    orientations : (B, J, 4) float64 world quaternions w, x, y, z (k4abt joint frames), NaN = unknown; None
        unless ``params.orientations``.
    position_std : (B, J) float64, mm, one-sigma position uncertainty per axis, NaN = no estimate; None unless
        ``params.position_std``.
    flipped : (B, S) bool, views the realignment found left/right mirrored this instant (and swapped); None
        without realignment. What ``skelfuse eval real`` counts per view as the rig's mirroring rate.
    held_out : (B, S) uint8, why each view was held out of the merge
        (:data:`skelfuse.fusion.plausibility.HOLD_REASONS`, ``reason - 1``; 0 = used or absent); None unless
        ``params.plausibility_gate_mm``.
    agreement_mm : (B,) float64, mm, how far the views used lie from the fused torso
        (:func:`skelfuse.fusion.uncertainty.view_agreement`; NaN: fewer than two views); None unless
        ``params.position_std``.
    merged : (B, J, 3) float64, mm, the merge's output before the temporal filter (NaN = no measurement): what
        an offline smoother takes as its measurements.
    restarted : (B,) bool, the plausibility stage's follow rule restarted the body's filter at the views this
        frame (an offline smoother does not smooth across it); None unless ``params.plausibility_gate_mm``.
    """

    positions: np.ndarray
    n_agree: np.ndarray
    confidence: np.ndarray
    contributors: np.ndarray
    orientations: np.ndarray | None = None
    position_std: np.ndarray | None = None
    flipped: np.ndarray | None = None
    held_out: np.ndarray | None = None
    agreement_mm: np.ndarray | None = None
    merged: np.ndarray | None = None
    restarted: np.ndarray | None = None


@dataclass
class FusionState:
    """Everything :func:`fuse` carries from one frame to the next, for B bodies.

    Attributes
    ----------
    previous : (B, J, 3) float64, mm, last frame's merged positions (before filtering); NaN = none.
    x : (B, J, 2, 3) float64, filter state: position (mm) and velocity (mm/s) per axis.
    P : (B, J, 3) float64, filter covariance per axis (p_pos, p_pos_vel, p_vel), shared by the axes.
    coast : (B, J) int32, -1 = no track, else frames since the joint's last measurement.
    flip_counters : (B, 4) int32 or None, "temporal" realignment: (column 0) frames in a row a clear majority
        of the evidence disagreed with the anchor, negative: the anchor's credit
        (:func:`skelfuse.fusion.realign.recovery_count`), (column 1) frames in a row a simple majority did,
        (column 2) the most views that saw the body since its last cold start, and (column 3) frames in a row
        rear views facing away disagreed with it (None reads as all 0).
    orientation : (B, J, 4) float64 or None, last fused orientations (all-zero rows: none).
    angular_velocity : (B, J, 3) float64 or None, rad/s, the rotation filter's rate (None reads as 0).
    position_cov : (B, J, 3) float64 or None, the uncertainty recursion's covariance (None reads as 0).
    view_held, view_release : (B, S) uint8 / int32 or None, the plausibility stage's hold-out reason and release
        streak per view (None reads as nothing held).
    follow_streak : (B,) int32 or None, frames in a row every view failed the plausibility checks.
    bone_lengths : (B, NB) float64 or None, mm, the person's learned bone lengths (0 or NaN: not learned).
    bone_frames : (B,) int32 or None, frames the bone lengths were learned from.
    """

    previous: np.ndarray
    x: np.ndarray
    P: np.ndarray
    coast: np.ndarray
    flip_counters: np.ndarray | None = None
    orientation: np.ndarray | None = None
    angular_velocity: np.ndarray | None = None
    position_cov: np.ndarray | None = None
    view_held: np.ndarray | None = None
    view_release: np.ndarray | None = None
    follow_streak: np.ndarray | None = None
    bone_lengths: np.ndarray | None = None
    bone_frames: np.ndarray | None = None

    @property
    def n_bodies(self) -> int:
        return int(self.previous.shape[0])


def init_state(n_bodies: int, params: FusionParams) -> FusionState:
    """Empty state for ``n_bodies`` bodies: no previous position, no filter track.

    ``params`` is accepted so that future filters can size their state from it; today every filter
    shares one layout.
    """
    if int(n_bodies) < 0:
        raise ValueError(f"n_bodies must be >= 0, got {n_bodies!r}")
    if not isinstance(params, FusionParams):
        raise ValueError(f"params must be a FusionParams, got {type(params).__name__}")
    B = int(n_bodies)
    x, P, coast = init_filter_state(B * N_JOINTS)
    orientation, angular_velocity = init_orientation_state(B) if params.orientations else (None, None)
    return FusionState(
        previous=np.full((B, N_JOINTS, 3), np.nan),
        x=x.reshape(B, N_JOINTS, 2, 3),
        P=P.reshape(B, N_JOINTS, 3),
        coast=coast.reshape(B, N_JOINTS),
        flip_counters=np.zeros((B, 4), dtype=np.int32),
        orientation=orientation,
        angular_velocity=angular_velocity,
        position_cov=np.zeros((B, N_JOINTS, 3)) if params.position_std else None,
    )


def select_candidates(
    candidates: np.ndarray, confidence: np.ndarray, min_confidence: int | None
) -> tuple[np.ndarray, np.ndarray]:
    """Mark unusable candidates missing: non-finite, or confidence below ``min_confidence``.

    A candidate whose coordinates are so large that their sum overflows (beyond about 1e307 mm) counts as
    non-finite too: one sum and one test per candidate. One compiled call (:mod:`skelfuse.fusion.kernels.merge`);
    the numpy form is the test reference (:mod:`skelfuse.fusion.reference.pipeline`).

    Parameters
    ----------
    candidates : (B, S, J, 3) float, mm.
    confidence : (B, S, J) int (0-255).
    min_confidence : int or None (None keeps every finite candidate).

    Returns
    -------
    positions : (B, S, J, 3) float64, mm, all three coordinates NaN where missing.
    confidence : (B, S, J) uint8, 0 where missing.
    """
    positions = np.ascontiguousarray(candidates, dtype=np.float64)
    if positions.ndim != 4 or positions.shape[3] != 3:
        raise ValueError(f"candidates must have shape (B, S, J, 3), got {positions.shape}")
    conf = kernels.kernel_array(confidence, np.uint8, positions.shape[:3], "confidence")
    return kernels.load().merge.select_candidates(positions, conf, 0 if min_confidence is None else int(min_confidence))


def predicted_positions(state: FusionState, dt_s: float) -> np.ndarray:
    """(B, J, 3) the track's one-step prediction ``x + v dt`` (the last merged position without a filter track).

    One compiled call (:mod:`skelfuse.fusion.kernels.filters`); the numpy form is the test reference."""
    B = state.n_bodies
    return kernels.load().filters.predict(
        kernels.kernel_array(state.x, np.float64, (B, N_JOINTS, 2, 3), "x"),
        kernels.kernel_array(state.coast, np.int32, (B, N_JOINTS), "coast"),
        kernels.kernel_array(state.previous, np.float64, (B, N_JOINTS, 3), "previous"),
        float(dt_s),
    )


def fuse(
    candidates: np.ndarray,
    confidence: np.ndarray,
    state: FusionState,
    params: FusionParams,
    dt_s: float = 1.0 / 30.0,
    orientations: np.ndarray | None = None,
    sensor_positions: np.ndarray | None = None,
) -> tuple[FusionResult, FusionState]:
    """Fuse one instant of S sensors' skeletons of B associated bodies.

    Parameters
    ----------
    candidates : (B, S, J, 3) float, mm, world frame; NaN = missing.
    confidence : (B, S, J) uint8, :class:`skelfuse.schema.skeleton.Confidence` values.
    state : FusionState from :func:`init_state` or the previous call, for the same B.
    params : FusionParams
    dt_s : float
        Seconds since the previous frame (used by the cv_kalman and alpha_beta filters).
    orientations : (B, S, J, 4) float or None
        The views' joint quaternions (w, x, y, z) in the world frame (:func:`skelfuse.fusion.orientation.
        views_to_world`), NaN or all-zero = none. Used only with ``params.orientations``; None: the fused
        orientations come from the bones and the history alone.
    sensor_positions : (S, 3) or (B, S, 3) float, or None
        Each sensor's position in the world frame, mm, in the candidates' sensor order (the translations of
        the calibrated poses), the same for every body or each body's own (bodies seen by different sensors
        fused side by side). Used only by the "temporal" realignment's rear-view rule
        (``params.rear_view_cos``); None: that rule is off.

    Returns
    -------
    result : FusionResult
    state : FusionState, new arrays (the input state is left untouched).

    Raises
    ------
    ValueError
        On shapes that do not match each other, the joint set, or the state's body count, or a
        non-positive dt_s.
    """
    candidates = np.asarray(candidates)
    confidence = np.asarray(confidence)
    _validate(candidates, confidence, state, dt_s)
    _check_sensor_positions(candidates, sensor_positions)
    B, _, J, _ = candidates.shape

    positions, conf = select_candidates(candidates, confidence, params.min_confidence)
    held_out = plausibility = restarted = predicted = verdict = None
    if params.plausibility_gate_mm is not None or _anchored_on_prediction(params):
        predicted = predicted_positions(state, dt_s)
    previous = predicted if predicted is not None and _anchored_on_prediction(params) else state.previous
    state_coast, flip_counters = state.coast, state.flip_counters
    if predicted is not None and params.plausibility_gate_mm is not None:
        verdict, plausibility = _plausibility(positions, conf, predicted, state, params)
        held_out, restarted = verdict.held, verdict.restart
        positions, conf = verdict.views, verdict.views_confidence
        if restarted.any():  # the track follows the views: filter, trick 2 and the realignment start over there
            state_coast = np.where(restarted[:, None], -1, state.coast)
            previous = np.where(restarted[:, None, None], np.nan, previous)
            if flip_counters is not None:
                flip_counters = np.where(restarted[:, None], 0, flip_counters).astype(flip_counters.dtype)
    positions, conf, reference, streak, flipped = _realign(
        positions, conf, params, previous, flip_counters, dt_s, sensor_positions
    )
    if predicted is not None and verdict is not None:
        positions, conf = merge_views(positions, conf, verdict, predicted, _plausibility_params(params), dt_s)
        reference = None  # recomputed from what is left where the merge needs one
    merged = _merge(positions, conf, reference, previous, params)
    if plausibility is not None:
        plausibility = learn_bones(plausibility, merged.positions, merged.n_agree)
    out, x, P, coast = filter_step(
        state.x.reshape(B * J, 2, 3),
        state.P.reshape(B * J, 3),
        state_coast.reshape(B * J),
        merged.positions.reshape(B * J, 3),
        merged.n_agree.reshape(B * J),
        params,
        dt_s,
    )
    fused = out.reshape(B, J, 3)
    orientation_out = orientation_state = angular_velocity = None
    if params.orientations:
        orientation_out, orientation_state, angular_velocity = _orientations(
            fused, orientations, flipped, merged, state, params, dt_s
        )
    std = position_cov = agreement = None
    if params.position_std:
        std, position_cov, agreement = _position_uncertainty(
            positions, merged, fused, state.position_cov, state_coast, coast, params, dt_s
        )
    result = FusionResult(
        positions=fused,
        n_agree=merged.n_agree,
        confidence=merged.confidence,
        contributors=np.asarray(merged.members.any(axis=1)),
        orientations=orientation_out,
        position_std=std,
        flipped=flipped,
        held_out=held_out,
        agreement_mm=agreement,
        merged=merged.positions,
        restarted=restarted,
    )
    new_state = FusionState(
        previous=merged.positions,
        x=x.reshape(B, J, 2, 3),
        P=P.reshape(B, J, 3),
        coast=coast.reshape(B, J),
        flip_counters=streak,
        orientation=orientation_state,
        angular_velocity=angular_velocity,
        position_cov=position_cov,
        **_plausibility_fields(plausibility),
    )
    return result, new_state


def _check_sensor_positions(candidates: np.ndarray, sensor_positions: np.ndarray | None) -> None:
    """Refuse sensor positions that are not one world position per sensor of the candidates (the same for every
    body, or each body's own)."""
    B, S = candidates.shape[:2]
    if sensor_positions is not None and np.shape(sensor_positions) not in ((S, 3), (B, S, 3)):
        raise ValueError(
            f"sensor_positions must have shape ({S}, 3) or ({B}, {S}, 3), one world position per sensor of the "
            f"candidates, got {np.shape(sensor_positions)}"
        )


def _position_uncertainty(
    positions: np.ndarray,
    merged: MergeResult,
    fused: np.ndarray,
    previous_position_cov: np.ndarray | None,
    state_coast: np.ndarray,
    coast: np.ndarray,
    params: FusionParams,
    dt_s: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each fused joint's position std (B, J) and covariance state (B, J, 3), and the views' torso agreement."""
    B, J = fused.shape[:2]
    previous_cov = previous_position_cov if previous_position_cov is not None else np.zeros((B, J, 3))
    return position_uncertainty(
        positions,
        merged.positions,
        merged.n_agree,
        fused,
        previous_cov,
        state_coast.reshape(B * J),
        coast,
        TORSO_JOINTS,
        params,
        dt_s,
    )


def _plausibility(
    positions: np.ndarray, conf: np.ndarray, predicted: np.ndarray, state: FusionState, params: FusionParams
) -> tuple[PlausibilityResult, PlausibilityState]:
    """The plausibility stage's view checks, before the realignment, against the track's prediction."""
    B, S = positions.shape[:2]
    held, release, follow = state.view_held, state.view_release, state.follow_streak
    bones, bone_frames = state.bone_lengths, state.bone_frames
    if (
        held is None
        or release is None
        or follow is None
        or bones is None
        or bone_frames is None
        or held.shape != (B, S)
    ):
        previous = init_plausibility_state(B, S)
    else:
        previous = PlausibilityState(held=held, release=release, follow=follow, bones=bones, bone_frames=bone_frames)
    return plausibility_step(positions, conf, predicted, previous, _plausibility_params(params))


@lru_cache(maxsize=16)
def _plausibility_params(params: FusionParams) -> PlausibilityParams:
    """The plausibility stage's options from FusionParams' (made once per parameter set, not per frame)."""
    return PlausibilityParams(
        gate_mm=float(params.plausibility_gate_mm or 0.0),
        up_cos=params.plausibility_up_cos,
        bone_ratio=params.plausibility_bone_ratio,
        joint_speed_mm_s=float(params.plausibility_joint_speed_mm_s or math.inf),
        release_frames=params.plausibility_release_frames,
        follow_frames=params.plausibility_follow_frames,
    )


def _plausibility_fields(state: PlausibilityState | None) -> dict[str, np.ndarray | None]:
    """The FusionState fields of the plausibility stage (all None when it is off)."""
    if state is None:
        return {}
    return {
        "view_held": state.held,
        "view_release": state.release,
        "follow_streak": state.follow,
        "bone_lengths": state.bones,
        "bone_frames": state.bone_frames,
    }


def _orientations(
    fused: np.ndarray,
    orientations: np.ndarray | None,
    flipped: np.ndarray | None,
    merged: MergeResult,
    state: FusionState,
    params: FusionParams,
    dt_s: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 5: which views may give the twist, then :func:`fuse_orientations`."""
    B = fused.shape[0]
    usable = None
    if orientations is not None:
        orientations = np.asarray(orientations, dtype=np.float64)
        if orientations.shape != (*merged.members.shape[:1], merged.members.shape[2], N_JOINTS, 4):
            raise ValueError(
                f"orientations must have shape (B, S, {N_JOINTS}, 4) = "
                f"{(B, merged.members.shape[2], N_JOINTS, 4)}, got {orientations.shape}"
            )
        usable = np.transpose(merged.members, (0, 2, 1)).copy()  # (B, S, J): the view's position was merged
        if flipped is not None:
            usable &= ~flipped[:, :, None]
    quats_prev, omega_init = init_orientation_state(B) if state.orientation is None else (state.orientation, None)
    omega_prev = state.angular_velocity if state.angular_velocity is not None else omega_init
    if omega_prev is None:  # FusionState reads a missing angular velocity as 0
        omega_prev = np.zeros((*quats_prev.shape[:2], 3))
    orientation_params = _orientation_params(
        params.orientation_agree_deg, params.orientation_alpha, params.orientation_beta
    )
    result, quats, omega = fuse_orientations(
        fused, orientations, usable, quats_prev, omega_prev, orientation_params, dt_s
    )
    return result.quats, quats, omega


@lru_cache(maxsize=16)
def _orientation_params(agree_deg: float, alpha: float, beta: float) -> OrientationParams:
    """The orientation stage's options from FusionParams' (made once per set of values, not per frame)."""
    return OrientationParams(agree_deg=agree_deg, alpha=alpha, beta=beta)


def _anchored_on_prediction(params: FusionParams) -> bool:
    """Trick 2's candidate and the temporal anchor are the filter's prediction (else the last merged positions)."""
    return params.previous_candidate == "predicted" and params.filter in ("cv_kalman", "alpha_beta")


def _realign(
    positions: np.ndarray,
    conf: np.ndarray,
    params: FusionParams,
    previous: np.ndarray,
    streak: np.ndarray | None,
    dt_s: float,
    sensor_positions: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray, np.ndarray | None]:
    """Realign; also return the reference positions of the result when they come for free (else None),
    the new flip counters and which views were flipped ((B, S) bool; None without realignment)."""
    B = positions.shape[0]
    if streak is None:
        streak = np.zeros((B, 4), dtype=np.int32)
    if params.realign is None:
        return positions, conf, None, streak, None
    if params.realign == "temporal":
        # The static reference is needed only where the anchor lacks a pair: computed there, on demand.
        out_positions, out_conf, flipped, streak = realign_temporal(
            positions,
            conf,
            previous,
            streak,
            params.recovery_frames,
            params.recovery_share,
            majority_recovery_frames=params.majority_recovery_frames,
            max_jump_mm=None if params.max_body_speed_mm_s is None else params.max_body_speed_mm_s * dt_s,
            sensor_positions=sensor_positions,
            rear_view_cos=params.rear_view_cos,
            rear_view_frames=params.rear_view_frames,
            credit_frames=params.recovery_credit_frames,
        )
        return out_positions, out_conf, None, streak, flipped
    reference = reference_positions(positions, conf)
    if params.realign == "paper":
        out_positions, out_conf, swapped = realign_paper(positions, conf, reference=reference)
        flipped = np.asarray(swapped.any(axis=-1))  # any pair swapped: the view's frames are not trusted
    else:
        out_positions, out_conf, flipped = realign_body(positions, conf, params.realign_passes, reference=reference)
    # Nothing swapped (the usual case): the reference of the realigned candidates is the one just computed.
    return out_positions, out_conf, reference if out_positions is positions else None, streak, flipped


def _merge(
    positions: np.ndarray,
    conf: np.ndarray,
    reference: np.ndarray | None,
    previous: np.ndarray,
    params: FusionParams,
) -> MergeResult:
    if params.merge == "average":
        return merge_average(positions, conf)
    if params.reference_weight is not None and reference is None:
        reference = reference_positions(positions, conf)
    return merge_dbscan(
        positions,
        conf,
        reference=reference,
        previous=previous if params.previous_weight is not None else None,
        eps_mm=params.eps_mm,
        reference_weight=params.reference_weight,
        previous_weight=params.previous_weight,
    )


def _validate(candidates: np.ndarray, confidence: np.ndarray, state: FusionState, dt_s: float) -> None:
    if candidates.ndim != 4 or candidates.shape[2:] != (N_JOINTS, 3):
        raise ValueError(f"candidates must have shape (B, S, {N_JOINTS}, 3), got {candidates.shape}")
    if confidence.shape != candidates.shape[:3]:
        raise ValueError(f"confidence must have shape {candidates.shape[:3]} (B, S, J), got {confidence.shape}")
    if candidates.shape[0] != state.n_bodies:
        raise ValueError(
            f"candidates hold {candidates.shape[0]} bodies but the state was made for {state.n_bodies}; "
            "call init_state with the new body count"
        )
    if not (isinstance(dt_s, int | float) and math.isfinite(dt_s) and dt_s > 0):
        raise ValueError(f"dt_s must be a finite number of seconds > 0, got {dt_s!r}")


class Fuser:
    """Stateful wrapper over :func:`fuse` for a fixed number of bodies.

    Attributes
    ----------
    params : FusionParams
    n_bodies : int
    sensor_positions : (S, 3) or (B, S, 3) float or None, the sensors' world positions passed to :func:`fuse`.
    state : FusionState, the state after the last :meth:`step`.
    """

    def __init__(self, params: FusionParams, n_bodies: int = 1, sensor_positions: np.ndarray | None = None) -> None:
        self.params = params
        self.n_bodies = int(n_bodies)
        self.sensor_positions = None if sensor_positions is None else np.asarray(sensor_positions, dtype=np.float64)
        self.state = init_state(self.n_bodies, params)

    def step(
        self,
        candidates: np.ndarray,
        confidence: np.ndarray,
        dt_s: float = 1.0 / 30.0,
        orientations: np.ndarray | None = None,
    ) -> FusionResult:
        """Fuse one frame (see :func:`fuse`) and keep the new state."""
        result, self.state = fuse(
            candidates, confidence, self.state, self.params, dt_s, orientations, self.sensor_positions
        )
        return result

    def reset(self) -> None:
        """Forget every track and previous position, as after construction."""
        self.state = init_state(self.n_bodies, self.params)
