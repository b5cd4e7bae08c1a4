"""The numpy form of the per-joint filters: the test reference of :func:`skelfuse.fusion.filters.filter_step`.

The live path runs the compiled kernel (:mod:`skelfuse.fusion.kernels.filters`) and never imports this module;
the models, the state layout and the coasting rules are documented in :mod:`skelfuse.fusion.filters`. Every
step is a handful of numpy calls over all N joints at once.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from skelfuse.fusion.filters import _cv_model
from skelfuse.fusion.presets import FusionParams


def filter_step(
    x: np.ndarray,
    P: np.ndarray,
    coast: np.ndarray,
    z: np.ndarray,
    n_agree: np.ndarray,
    params: FusionParams,
    dt_s: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`skelfuse.fusion.filters.filter_step` in numpy (its parameters and returns are documented there)."""
    kind = params.filter
    if kind is None:
        return z.copy(), x, P, coast
    coast = coast if coast.dtype == np.int32 else coast.astype(np.int32)  # the uint32 view below needs int32
    if kind == "paper_kalman":
        return _paper_kalman_step(x, P, coast, z, params)
    has_z = z[:, 0] == z[:, 0]  # NaN never equals itself: a missing measurement
    if kind == "cv_kalman":
        cov_map, q_vec, state_map = _cv_model(dt_s, params.cv_accel_sigma_mm_s2)
        # x~ = F x;  P~ = F P F' + Q, on the triangle (p00, p01, p11) as one linear map plus Q.
        pred_x = state_map @ x
        pred_P = P @ cov_map + q_vec
        r = params.cv_meas_sigma_mm**2
        if params.cv_scale_r_by_agree:
            # n agreeing views average their independent noise down: R / n (a table lookup for int16 counts;
            # the same divisions, done once).
            r = _r_by_agree(r)[n_agree] if n_agree.dtype == np.int16 else r / np.maximum(n_agree, 1)
            r = r[:, None]
        # y = z - H x~;  S = H P~ H' + R;  K = P~ H' / S;  x^ = x~ + K y;  P^ = (I - K H) P~.
        gain = pred_P[:, :2] / (pred_P[:, :1] + r)
        upd_x = pred_x + gain[:, :, None] * (z - pred_x[:, 0])[:, None, :]
        # (p00, p01, p11) - (K0 p00, K0 p01, K1 p01)
        upd_P = pred_P - gain[:, _GAIN_ROWS] * pred_P[:, _COV_ROWS]
        init_P = (params.cv_meas_sigma_mm**2, 0.0, params.cv_velocity0_sigma_mm_s**2)
    elif kind == "alpha_beta":
        pred_x = x + dt_s * (x[:, 1:2] * _POSITION_ROW)  # X = Xp + V dt
        residual = z - pred_x[:, 0]  # R = Xm - X
        # X = X + alpha R;  V = V + beta R / dt
        upd_x = pred_x + np.array([[params.alpha], [params.beta / dt_s]]) * residual[:, None, :]
        upd_P = pred_P = P
        init_P = (0.0, 0.0, 0.0)
    else:
        raise ValueError(f"filter must be 'paper_kalman', 'cv_kalman', 'alpha_beta' or None, got {kind!r}")

    tracked = coast >= 0
    measured = (has_z & tracked)[:, None]
    # Measured: 0; coasting: one more frame; no track and no measurement: stays -1.
    new_coast = np.where(has_z, 0, coast + tracked)
    # Seen as unsigned, -1 is huge: one comparison tests 0 <= coast <= max_coast_frames.
    alive = new_coast.view(np.uint32) <= params.max_coast_frames
    new_coast = np.where(alive, new_coast, -1)
    # Rows: measured -> update; coasting -> prediction; new track -> (z, 0); dead -> NaN out.
    new_x = np.where(measured[:, :, None], upd_x, np.where(has_z[:, None, None], z[:, None, :] * _POSITION_ROW, pred_x))
    new_P = np.where(measured, upd_P, np.where(has_z[:, None], init_P, pred_P))
    # The output is the new position row: the update when measured (x^), z for a new track, the
    # prediction while coasting.
    out = np.where(alive[:, None], new_x[:, 0], np.nan)
    return out, new_x, new_P, new_coast


_POSITION_ROW = np.array([[1.0], [0.0]])  # (2, 1): selects the position row of a (2, 3) state
_GAIN_ROWS = np.array([0, 0, 1])
_COV_ROWS = np.array([0, 1, 1])


@lru_cache(maxsize=8)
def _r_by_agree(r: float) -> np.ndarray:
    """(32768,) ``r / max(n, 1)`` for every non-negative int16 count n (256 KiB per distinct r)."""
    table = r / np.maximum(np.arange(1 << 15), 1)
    table.setflags(write=False)
    return table


def _paper_kalman_step(
    x: np.ndarray, P: np.ndarray, coast: np.ndarray, z: np.ndarray, params: FusionParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`filter_step` for "paper_kalman", specialised: velocity and off-diagonal P are always 0.

    The hot path of preset A5, so it spends as few numpy calls as it can.
    """
    pos = x[:, 0]
    has_z = z[:, 0] == z[:, 0]  # NaN never equals itself: a missing measurement
    tracked = coast >= 0
    measured = has_z & tracked
    p_pred = P[:, 0] + params.kalman_q_mm2  # P~ = A P A' + Q
    gain = p_pred / (p_pred + params.kalman_r_mm2)  # K = P~ H' (H P~ H' + R)^-1
    new_coast = np.where(has_z, 0, coast + tracked)
    alive = new_coast.view(np.uint32) <= params.max_coast_frames  # -1 seen as unsigned is huge
    new_coast = np.where(alive, new_coast, -1)
    started = has_z > tracked  # a measurement and no track
    # Measured: x^ = x~ + K (z - H x~); new track: z; coasting: x~ = x^ (A = I).
    new_pos = np.where(measured[:, None], pos + gain[:, None] * (z - pos), np.where(started[:, None], z, pos))
    new_p = np.where(measured, (1.0 - gain) * p_pred, np.where(started, params.kalman_p0_mm2, p_pred))
    # Output the prediction x~ = x^_{t-1} (eq. 9); a new track outputs its first measurement. Or, with
    # kalman_output = "posterior", the state after this frame's update.
    if params.kalman_output == "posterior":
        out = np.where(alive[:, None], new_pos, np.nan)
    else:
        out = np.where(alive[:, None], np.where(started[:, None], z, pos), np.nan)
    # Velocity and the off-diagonal covariance stay 0 (new_pos and new_p are finite: z only where present).
    new_x = new_pos[:, None, :] * _POSITION_ROW
    new_P = new_p[:, None] * _P_POSITION
    return out, new_x, new_P, new_coast


_P_POSITION = np.array([1.0, 0.0, 0.0])  # (3,): p_pos alone of the (p_pos, p_pos_vel, p_vel) triangle
