"""Per-joint position uncertainty from the data: the spread of the merged cluster, carried through time.

The position filter's own covariance (:mod:`skelfuse.fusion.filters`) is fed with a fixed measurement noise,
so it converges to the same number for every joint that is seen: it says nothing about this joint, now.
This stage runs the same constant-velocity covariance recursion (``cv_accel_sigma_mm_s2``) beside it, fed
with a measurement variance taken from the data:

* the sensors' candidates that were merged into the joint scatter around the merged position; their sum of
  squared distances ``ss`` (mm^2, over the n members and three axes) gives a per-axis sample variance
  ``ss / (3 (n - 1))``;
* two or three views say little about a variance, so it is shrunk towards the nominal per-view noise
  ``sigma0 = cv_meas_sigma_mm`` with the weight of ``nu0 = 2`` extra samples:
  ``v = (ss / 3 + nu0 sigma0^2) / (n - 1 + nu0)`` (one view: ``v = sigma0^2``);
* the merged position is the mean of n candidates: its variance is ``R = v / n``;
* views the merge left out of the cluster (further than eps from it) still disagree about where the joint is:
  their squared distances from the merged position join ``ss`` and their number the sample count, so two
  views 300 mm apart give about 100 mm where two views 10 mm apart give about 9 mm (views the plausibility
  stage held out are not candidates any more and do not count).

The recursion starts a track at ``P = (R, 0, sigma_v0^2)``, predicts while the joint coasts (the uncertainty
grows with the coasting) and is dropped with the position filter's track. Its output never falls below this
frame's ``sqrt(R)``: most of a view's error is slow (an AR(1) with rho 0.8-0.94 per frame on real recordings),
so averaging over time cannot lower it the way the recursion's white-noise model assumes; a joint one view
carries alone stays at about ``sigma0`` however long it is seen. With no position filter the output is
``sqrt(R)`` of the frame. Output: the one-sigma uncertainty per axis, mm (a 3D error is about sqrt(3)
times larger), NaN where the joint has no position. The fusion step runs the stage as one compiled kernel
(:func:`position_uncertainty`, :mod:`skelfuse.fusion.kernels.uncertainty`); the numpy functions here are its parts
and, composed, its test reference (:mod:`skelfuse.fusion.reference.uncertainty`).
"""

from __future__ import annotations

import numpy as np

from skelfuse.fusion import kernels
from skelfuse.fusion.filters import _cv_model
from skelfuse.fusion.plausibility import median_of_finite
from skelfuse.fusion.presets import FusionParams

PRIOR_SAMPLES = 2.0
"""``nu0``: weight, in samples, of the nominal per-view noise in the measurement variance."""

_GAIN_ROWS = np.array([0, 0, 1])
_COV_ROWS = np.array([0, 1, 1])


def measurement_variance(
    candidates: np.ndarray, members: np.ndarray, merged: np.ndarray, n_agree: np.ndarray, sigma0_mm: float
) -> np.ndarray:
    """Per-axis variance (mm^2) of each merged position, from the spread of its cluster.

    Parameters
    ----------
    candidates : (B, S, J, 3) the (realigned) sensor candidates, mm; NaN = missing.
    members : (B, J, S) bool, the candidates merged into each joint.
    merged : (B, J, 3) the merged positions, mm.
    n_agree : (B, J) number of members.
    sigma0_mm : nominal per-view noise, mm.

    Returns
    -------
    (B, J) float64, ``R = v / n`` (NaN where nothing was merged).
    """
    sq = _squared_distances(candidates, merged)  # (B, S, J), NaN where the candidate is missing
    present = np.isfinite(sq)
    ss = np.sum(np.where(present, sq, 0.0), axis=1)  # (B, J): members and the views outside the cluster
    n_views = present.sum(axis=1).astype(np.float64)
    n = np.asarray(n_agree, dtype=np.float64)
    v = (ss / 3.0 + PRIOR_SAMPLES * sigma0_mm**2) / (np.maximum(n_views - 1.0, 0.0) + PRIOR_SAMPLES)
    return np.where(n > 0, v / np.maximum(n, 1.0), np.nan)


def _squared_distances(candidates: np.ndarray, merged: np.ndarray) -> np.ndarray:
    """(B, S, J) squared distance of every candidate from the merged joint, mm^2 (NaN: either missing)."""
    diff = np.asarray(candidates, dtype=np.float64) - np.asarray(merged, dtype=np.float64)[:, None]
    return np.sum(diff * diff, axis=-1)


def view_agreement(candidates: np.ndarray, merged: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """Per body: how far the views used lie from the fused body, mm.

    The median over ``joints`` (seen by two views or more) of the root-mean-square distance of the views'
    candidates from the merged joint: about 10 mm where two real views agree on the torso, hundreds where they
    see the person in different places. NaN where no joint has two views (one view cannot disagree).

    Parameters
    ----------
    candidates : (B, S, J, 3) mm, the candidates the merge was given; merged : (B, J, 3) mm.
    joints : (K,) joint indices (the torso: the joints every view of a body has).

    Returns
    -------
    (B,) float64, mm.
    """
    sq = _squared_distances(candidates[:, :, joints], merged[:, joints])  # (B, S, K)
    present = np.isfinite(sq)
    n = present.sum(axis=1)
    rms = np.sqrt(np.sum(np.where(present, sq, 0.0), axis=1) / np.maximum(n, 1))  # (B, K)
    shared = n >= 2
    return np.where(shared.any(axis=-1), median_of_finite(rms, shared), np.nan)


def uncertainty_step(
    P: np.ndarray,
    coast_before: np.ndarray,
    coast_after: np.ndarray,
    r_mm2: np.ndarray,
    params: FusionParams,
    dt_s: float,
) -> tuple[np.ndarray, np.ndarray]:
    """One step of the covariance recursion for N joints.

    Parameters
    ----------
    P : (N, 3) (p_pos, p_pos_vel, p_vel) of the last step.
    coast_before, coast_after : (N,) the position filter's coast counters before and after this frame
        (-1 no track, 0 measured, k > 0 coasting).
    r_mm2 : (N,) this frame's measurement variance (NaN = no measurement).
    params : FusionParams (``filter``, ``cv_accel_sigma_mm_s2``, ``cv_velocity0_sigma_mm_s``).
    dt_s : float

    Returns
    -------
    std_mm : (N,) one-sigma per axis, mm (NaN: no track and no measurement).
    P : (N, 3) the new covariance (zeros where no track).
    """
    r = np.asarray(r_mm2, dtype=np.float64)
    if params.filter is None:
        return np.sqrt(r), np.zeros_like(P)
    cov_map, q_vec, _ = _cv_model(dt_s, params.cv_accel_sigma_mm_s2)
    pred = P @ cov_map + q_vec
    r_safe = np.where(np.isfinite(r), r, 1.0)[:, None]
    gain = pred[:, :2] / (pred[:, :1] + r_safe)
    upd = pred - gain[:, _GAIN_ROWS] * pred[:, _COV_ROWS]
    start = np.stack(
        [r_safe[:, 0], np.zeros_like(r_safe[:, 0]), np.full_like(r_safe[:, 0], params.cv_velocity0_sigma_mm_s**2)],
        axis=-1,
    )
    measured = (coast_after == 0)[:, None]
    tracked = (coast_before >= 0)[:, None]
    coasting = (coast_after > 0)[:, None]
    new_P = np.where(measured & tracked, upd, np.where(measured, start, np.where(coasting, pred, 0.0)))
    alive = coast_after >= 0
    # Never below this frame's own measurement variance (the slow part of the error does not average out).
    std = np.sqrt(np.where(np.isfinite(r), np.maximum(new_P[:, 0], r), new_P[:, 0]))
    return np.where(alive, std, np.nan), new_P


def position_uncertainty(
    candidates: np.ndarray,
    merged: np.ndarray,
    n_agree: np.ndarray,
    fused: np.ndarray,
    previous_cov: np.ndarray,
    coast_before: np.ndarray,
    coast_after: np.ndarray,
    torso: np.ndarray,
    params: FusionParams,
    dt_s: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The whole stage for B bodies in one kernel call: :func:`view_agreement`, :func:`measurement_variance` and
    :func:`uncertainty_step`, the std masked where the fused joint has no position.

    Parameters
    ----------
    candidates : (B, S, J, 3) mm, the candidates the merge was given; merged : (B, J, 3) mm, the merge's output;
    n_agree : (B, J) members merged; fused : (B, J, 3) mm, the filtered positions; previous_cov : (B, J, 3);
    coast_before, coast_after : (B * J,) the position filter's coast counters; torso : (K,) joint indices;
    params : FusionParams; dt_s : float.

    Returns
    -------
    std (B, J) mm, cov (B, J, 3), agreement (B,) mm.
    """
    candidates = np.ascontiguousarray(candidates, dtype=np.float64)
    if candidates.ndim != 4 or candidates.shape[3] != 3:
        raise ValueError(f"candidates must have shape (B, S, J, 3), got {candidates.shape}")
    B, J = candidates.shape[0], candidates.shape[2]
    return kernels.load().uncertainty.position_uncertainty(
        candidates,
        kernels.kernel_array(merged, np.float64, (B, J, 3), "merged"),
        kernels.kernel_array(n_agree, np.int64, (B, J), "n_agree"),
        kernels.kernel_array(fused, np.float64, (B, J, 3), "fused"),
        kernels.kernel_array(previous_cov, np.float64, (B, J, 3), "previous_cov"),
        kernels.kernel_array(coast_before, np.int64, (B * J,), "coast_before"),
        kernels.kernel_array(coast_after, np.int64, (B * J,), "coast_after"),
        kernels.kernel_array(torso, np.int64, np.shape(torso), "torso"),
        float(params.cv_meas_sigma_mm),
        PRIOR_SAMPLES,
        params.filter is not None,
        float(dt_s),
        float(params.cv_accel_sigma_mm_s2),
        float(params.cv_velocity0_sigma_mm_s),
    )
