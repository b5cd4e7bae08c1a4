"""The position uncertainty stage (:func:`skelfuse.fusion.uncertainty.position_uncertainty`) as one compiled loop.

Per body: the views' torso agreement (median over the torso joints of the views' RMS distance from the merged
joint); per joint: the measurement variance from the spread of the views around the merged position, then one
step of the constant-velocity covariance recursion. The same arithmetic as the numpy reference
(:mod:`skelfuse.fusion.reference.uncertainty`) up to the order of its sums (last bits); the rules are documented in
:mod:`skelfuse.fusion.uncertainty`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from skelfuse.fusion.kernels.signatures import BOOL, FLOAT, HELPER, INT, KERNEL, array


@numba.njit(**HELPER)
def _squared_distance(candidates: np.ndarray, b: int, s: int, j: int, merged: np.ndarray) -> float:
    """|candidate - merged|^2, mm^2 (NaN where either is missing)."""
    dx = candidates[b, s, j, 0] - merged[b, j, 0]
    dy = candidates[b, s, j, 1] - merged[b, j, 1]
    dz = candidates[b, s, j, 2] - merged[b, j, 2]
    return dx * dx + dy * dy + dz * dz


@numba.njit(**HELPER)
def _torso_agreement(candidates: np.ndarray, merged: np.ndarray, b: int, torso: np.ndarray, rms: np.ndarray) -> float:
    """Median over the torso joints seen by two views or more of the views' RMS distance from the merged joint
    (NaN: no such joint). ``rms`` (K,): scratch."""
    S = candidates.shape[1]
    count = 0
    for k in range(torso.shape[0]):
        total = 0.0
        n = 0
        for s in range(S):
            sq = _squared_distance(candidates, b, s, torso[k], merged)
            if math.isfinite(sq):
                total += sq
                n += 1
        if n >= 2:
            value = math.sqrt(total / n)
            at = count  # insertion sort: a handful of joints
            while at > 0 and rms[at - 1] > value:
                rms[at] = rms[at - 1]
                at -= 1
            rms[at] = value
            count += 1
    if count == 0:
        return math.nan
    return 0.5 * (rms[(count - 1) // 2] + rms[count // 2])


_SIGNATURE = (
    array(FLOAT, 4),  # candidates
    array(FLOAT, 3),  # merged
    array(INT, 2),  # n_agree
    array(FLOAT, 3),  # fused
    array(FLOAT, 3),  # previous_cov
    array(INT, 1),  # coast_before
    array(INT, 1),  # coast_after
    array(INT, 1),  # torso
    FLOAT,  # sigma0_mm
    FLOAT,  # prior_samples
    BOOL,  # use_filter
    FLOAT,  # dt_s
    FLOAT,  # accel_sigma
    FLOAT,  # velocity0_sigma
)


@numba.njit(_SIGNATURE, **KERNEL)
def position_uncertainty(
    candidates: np.ndarray,
    merged: np.ndarray,
    n_agree: np.ndarray,
    fused: np.ndarray,
    previous_cov: np.ndarray,
    coast_before: np.ndarray,
    coast_after: np.ndarray,
    torso: np.ndarray,
    sigma0_mm: float,
    prior_samples: float,
    use_filter: bool,
    dt_s: float,
    accel_sigma: float,
    velocity0_sigma: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each joint's one-sigma position uncertainty and covariance state, and each body's torso agreement.

    Parameters
    ----------
    candidates : (B, S, J, 3) float64 mm, NaN = missing; merged, fused : (B, J, 3) float64 mm; n_agree : (B, J)
    int64; previous_cov : (B, J, 3) float64 (p_pos, p_pos_vel, p_vel); coast_before, coast_after : (B * J,) int64,
    the position filter's coast counters; torso : (K,) int64 joints; sigma0_mm, prior_samples : the measurement
    variance's prior; use_filter : False: the frame's own variance, no recursion; dt_s, accel_sigma,
    velocity0_sigma : the constant-velocity model.

    Returns
    -------
    std (B, J) float64 mm (NaN: no position), cov (B, J, 3) float64, agreement (B,) float64 mm.
    """
    B, S, J = candidates.shape[0], candidates.shape[1], candidates.shape[2]
    std = np.empty((B, J))
    cov = np.empty((B, J, 3))
    agreement = np.empty(B)
    rms = np.empty(torso.shape[0])
    q = accel_sigma**2
    q0, q1, q2 = q * dt_s**4 / 4.0, q * dt_s**3 / 2.0, q * dt_s * dt_s
    prior = prior_samples * sigma0_mm**2
    for b in range(B):
        agreement[b] = _torso_agreement(candidates, merged, b, torso, rms)
        for j in range(J):
            cov[b, j, 0] = cov[b, j, 1] = cov[b, j, 2] = 0.0  # none unless the filter below sets it
            ss = 0.0  # the measurement variance R = v / n from the views' spread around the merged joint
            n_views = 0
            for s in range(S):
                sq = _squared_distance(candidates, b, s, j, merged)
                if math.isfinite(sq):
                    ss += sq
                    n_views += 1
            n = float(n_agree[b, j])
            v = (ss / 3.0 + prior) / (max(n_views - 1.0, 0.0) + prior_samples)
            r = v / max(n, 1.0) if n > 0.0 else np.nan
            i = b * J + j
            if not use_filter:
                std[b, j] = math.sqrt(r)
            else:
                # P~ = F P F' + Q on the triangle (p00, p01, p11).
                p0, p1, p2 = previous_cov[b, j, 0], previous_cov[b, j, 1], previous_cov[b, j, 2]
                pred0 = p0 + p1 * (2.0 * dt_s) + p2 * (dt_s * dt_s) + q0
                pred1 = p1 + p2 * dt_s + q1
                pred2 = p2 + q2
                r_safe = r if math.isfinite(r) else 1.0
                if coast_after[i] == 0 and coast_before[i] >= 0:  # K = P~ H' / (H P~ H' + R); P = (I - KH) P~
                    g0 = pred0 / (pred0 + r_safe)
                    g1 = pred1 / (pred0 + r_safe)
                    cov[b, j, 0], cov[b, j, 1], cov[b, j, 2] = (
                        pred0 - g0 * pred0,
                        pred1 - g0 * pred1,
                        pred2 - g1 * pred1,
                    )
                elif coast_after[i] == 0:  # a new track
                    cov[b, j, 0], cov[b, j, 1], cov[b, j, 2] = r_safe, 0.0, velocity0_sigma**2
                elif coast_after[i] > 0:
                    cov[b, j, 0], cov[b, j, 1], cov[b, j, 2] = pred0, pred1, pred2
                # Never below this frame's own measurement variance (the slow part of the error stays).
                value = math.sqrt(max(cov[b, j, 0], r) if math.isfinite(r) else cov[b, j, 0])
                std[b, j] = value if coast_after[i] >= 0 else np.nan
            if not math.isfinite(fused[b, j, 0] + fused[b, j, 1] + fused[b, j, 2]):
                std[b, j] = np.nan
    return std, cov, agreement


def warm_up() -> None:
    """Compile (or load) :func:`position_uncertainty` for its one signature."""
    points = np.zeros((1, 2, 3))
    coast = np.zeros(2, dtype=np.int64)
    position_uncertainty(
        np.zeros((1, 2, 2, 3)),
        points,
        np.ones((1, 2), dtype=np.int64),
        points,
        points,
        coast,
        coast,
        np.arange(2, dtype=np.int64),
        10.0,
        2.0,
        True,
        1.0 / 30.0,
        1000.0,
        500.0,
    )
