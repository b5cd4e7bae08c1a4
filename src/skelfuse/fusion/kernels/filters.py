"""The per-joint filters (:func:`skelfuse.fusion.filters.filter_step`) as one compiled loop over joints.

Same models, state layout and coasting rules as :mod:`skelfuse.fusion.filters` (which documents them); the
numpy reference is :mod:`skelfuse.fusion.reference.filters`. A joint has a measurement when the x coordinate of
``z`` is not NaN (as the reference tests it).
"""

from __future__ import annotations

import numba
import numpy as np
from numba.core import types

from skelfuse.fusion.kernels.signatures import BOOL, FLOAT, HELPER, INT, INT32, KERNEL, array

PAPER_KALMAN, CV_KALMAN, ALPHA_BETA = 0, 1, 2
"""Filter kinds, as the kernel's ``kind`` argument."""


@numba.njit(**HELPER)
def _predict(
    x: np.ndarray,
    P: np.ndarray,
    i: int,
    state_map: np.ndarray,
    cov_map: np.ndarray,
    q_vec: np.ndarray,
    pred: np.ndarray,
) -> None:
    """pred[0:2, :] = x~ = F x (position, velocity rows), pred[2, :] = P~ = P cov_map + Q on the triangle (p00,
    p01, p11), of joint i."""
    for row in range(2):
        for axis in range(3):
            pred[row, axis] = state_map[row, 0] * x[i, 0, axis] + state_map[row, 1] * x[i, 1, axis]
    for col in range(3):
        pred[2, col] = P[i, 0] * cov_map[0, col] + P[i, 1] * cov_map[1, col] + P[i, 2] * cov_map[2, col] + q_vec[col]


@numba.njit(**HELPER)
def _update(
    kind: int,
    pred: np.ndarray,
    z: np.ndarray,
    i: int,
    r: float,
    gains: np.ndarray,
    new_x: np.ndarray,
    new_P: np.ndarray,
) -> None:
    """The measured joint i: new_x[i] = x^, new_P[i] = P^. gains = (alpha, beta / dt) for alpha_beta."""
    if kind == ALPHA_BETA:  # X = X + alpha R;  V = V + beta R / dt
        k0, k1 = gains[0], gains[1]
    else:  # K = P~ H' / (H P~ H' + R)
        k0 = pred[2, 0] / (pred[2, 0] + r)
        k1 = pred[2, 1] / (pred[2, 0] + r)
    for axis in range(3):
        y = z[i, axis] - pred[0, axis]  # y = z - H x~
        new_x[i, 0, axis] = pred[0, axis] + k0 * y
        new_x[i, 1, axis] = pred[1, axis] + k1 * y
    if kind == CV_KALMAN:  # P^ = (I - K H) P~
        new_P[i, 0] = pred[2, 0] - k0 * pred[2, 0]
        new_P[i, 1] = pred[2, 1] - k0 * pred[2, 1]
        new_P[i, 2] = pred[2, 2] - k1 * pred[2, 1]
    elif kind == PAPER_KALMAN:  # the off-diagonal and velocity terms stay 0 (set by the caller)
        new_P[i, 0] = (1.0 - k0) * pred[2, 0]
    else:
        new_P[i, 0] = pred[2, 0]
        new_P[i, 1] = pred[2, 1]
        new_P[i, 2] = pred[2, 2]


_SIGNATURE = (
    INT,  # kind
    array(FLOAT, 3),  # x
    array(FLOAT, 2),  # P
    array(INT32, 1),  # coast
    array(FLOAT, 2),  # z
    array(INT, 1),  # n_agree
    types.Tuple((array(FLOAT, 2), array(FLOAT, 2), array(FLOAT, 1), array(FLOAT, 1))),  # model
    FLOAT,  # r
    array(FLOAT, 1),  # gains
    INT,  # max_coast_frames
    BOOL,  # scale_r_by_agree
    BOOL,  # output_posterior
)


@numba.njit(_SIGNATURE, **KERNEL)
def filter_step(
    kind: int,
    x: np.ndarray,
    P: np.ndarray,
    coast: np.ndarray,
    z: np.ndarray,
    n_agree: np.ndarray,
    model: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    r: float,
    gains: np.ndarray,
    max_coast_frames: int,
    scale_r_by_agree: bool,
    output_posterior: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One filter step for N joints.

    Parameters
    ----------
    kind : PAPER_KALMAN, CV_KALMAN or ALPHA_BETA.
    x (N, 2, 3) float64, P (N, 3) float64, coast (N,) int32, z (N, 3) float64, n_agree (N,) int64: as
        :func:`skelfuse.fusion.filters.filter_step`.
    model : the kind's linear model, float64: state_map (2, 2) F acting on the (position, velocity) rows,
        cov_map (3, 3) and q_vec (3,) with ``P~ = P @ cov_map + q_vec`` on the covariance triangle, and
        init_P (3,), a new track's covariance.
    r : measurement variance, mm^2 (divided by max(n_agree, 1) with ``scale_r_by_agree``).
    gains : (2,) float64, alpha and beta / dt (alpha_beta only).
    output_posterior : paper_kalman only: output x^ instead of the prediction x~.

    Returns
    -------
    out (N, 3), x (N, 2, 3), P (N, 3), coast (N,) int32: new arrays.
    """
    N = x.shape[0]
    out = np.empty((N, 3))
    new_x = np.empty((N, 2, 3))
    new_P = np.empty((N, 3))
    new_coast = np.empty(N, dtype=np.int32)
    pred = np.empty((3, 3))
    state_map, cov_map, q_vec, init_P = model
    for i in range(N):
        has_z = z[i, 0] == z[i, 0]  # NaN never equals itself: a missing measurement
        tracked = coast[i] >= 0
        count = 0 if has_z else coast[i] + (1 if tracked else 0)
        alive = 0 <= count <= max_coast_frames
        new_coast[i] = count if alive else -1
        _predict(x, P, i, state_map, cov_map, q_vec, pred)
        if has_z and tracked:
            r_i = r
            if scale_r_by_agree:
                r_i = r / max(n_agree[i], 1)
            _update(kind, pred, z, i, r_i, gains, new_x, new_P)
        elif has_z:  # a new track: (z, 0)
            for axis in range(3):
                new_x[i, 0, axis] = z[i, axis]
                new_x[i, 1, axis] = z[i, axis] * 0.0
            for k in range(3):
                new_P[i, k] = init_P[k]
        else:  # coasting (or nothing): the prediction
            for axis in range(3):
                new_x[i, 0, axis] = pred[0, axis]
                new_x[i, 1, axis] = pred[1, axis]
            for k in range(3):
                new_P[i, k] = pred[2, k]
        if kind == PAPER_KALMAN:  # velocity and the off-diagonal covariance stay 0
            for axis in range(3):
                new_x[i, 1, axis] = new_x[i, 0, axis] * 0.0
            new_P[i, 1] = new_P[i, 2] = new_P[i, 0] * 0.0
        for axis in range(3):
            if not alive:
                out[i, axis] = np.nan
            elif kind == PAPER_KALMAN and not output_posterior:  # eq. 9: x~ = x^_{t-1}; a new track: z
                out[i, axis] = pred[0, axis] if tracked else z[i, axis]
            else:
                out[i, axis] = new_x[i, 0, axis]
    return out, new_x, new_P, new_coast


@numba.njit((array(FLOAT, 4), array(INT32, 2), array(FLOAT, 3), FLOAT), **KERNEL)
def predict(x: np.ndarray, coast: np.ndarray, previous: np.ndarray, dt_s: float) -> np.ndarray:
    """(B, J, 3) each joint's one-step prediction ``x + v dt`` where it has a track (``coast >= 0``), else
    ``previous``. x : (B, J, 2, 3) position and velocity; coast : (B, J); previous : (B, J, 3)."""
    B, J = x.shape[0], x.shape[1]
    out = np.empty((B, J, 3))
    for b in range(B):
        for j in range(J):
            for k in range(3):
                out[b, j, k] = x[b, j, 0, k] + dt_s * x[b, j, 1, k] if coast[b, j] >= 0 else previous[b, j, k]
    return out


def warm_up() -> None:
    """Compile (or load) :func:`filter_step` and :func:`predict` for their signatures."""
    x = np.zeros((1, 2, 3))
    P = np.zeros((1, 3))
    coast = np.zeros(1, dtype=np.int32)
    model = (np.eye(2), np.eye(3), np.zeros(3), np.zeros(3))
    filter_step(CV_KALMAN, x, P, coast, P, np.ones(1, dtype=np.int64), model, 1.0, np.zeros(2), 5, True, False)
    predict(np.zeros((1, 1, 2, 3)), np.zeros((1, 1), dtype=np.int32), np.zeros((1, 1, 3)), 1.0)
