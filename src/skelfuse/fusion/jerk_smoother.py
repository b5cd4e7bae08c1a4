"""The offline default's last pass: a constant-acceleration RTS smoother whose jerk noise follows the motion.

Why: the live filter's constant-velocity model, even with its process noise raised where the motion accelerates
(:func:`skelfuse.fusion.smoother.adaptive_accel_sigma`), rounds off a jump: through a whole flight the body
falls at a constant acceleration, which that model can follow only with a high process noise, and that noise
lets the views' jitter through. A state of position, velocity and acceleration follows a ballistic flight, a
squat's descent or an arm's swing with no process noise at all; only the *changes* of acceleration (take-off,
landing, a foot strike) need it. Those happen to the whole body at once, so each axis's jerk noise is the larger
of the body's median jerk (many joints: robust to one joint's noise) and the joint's own (a waving hand moves
alone), both read from the earlier passes' smoothed positions (:func:`jerk_sigma`).

Per coordinate (each axis of each joint its own filter: a jump jerks up and down, not sideways), over the same
segments as the live filter (``linked``: a track start or a restart begins a new one; coasting frames are
predicted, then smoothed), with the live filter's measurement noise (``cv_meas_sigma_mm``, divided by the views
that agree when ``cv_scale_r_by_agree``). The white-jerk model and the RTS backward pass (Rauch, Tung and
Striebel 1965) are the textbook forms (Bar-Shalom, Li and Kirubarajan 2001, section 6.3.3):

    F = [[1, dt, dt^2/2], [0, 1, dt], [0, 0, 1]],   Q = s^2 g g',   g = (dt^3/6, dt^2/2, dt)
    C_t = P_t F' (P~_{t+1})^-1,   xs_t = x_t + C_t (xs_{t+1} - x~_{t+1})

Linear in the measurements once the jerk noise is set (what ``scripts/smoothing_targets.py`` splits into the
smoothing's distortion and the noise left). Pure numpy, vectorized over coordinates; one Python step per frame.
"""

from __future__ import annotations

import numpy as np

from skelfuse.fusion.presets import FusionParams

JERK_BASE_MM_S3 = 1.0e4
"""The jerk noise of still and steady motion, mm/s^3 (chosen on the training seeds of
``scripts/smoothing_targets.py``, as are the three below)."""
JERK_BODY_GAIN = 3.0
"""Jerk noise per unit of the body's median jerk on that axis."""
JERK_OWN_GAIN = 1.0
"""Jerk noise per unit of the joint's own jerk on that axis."""
JERK_SPREAD = 2
"""Frames on either side over which a jerk sets the noise (a smoothed change spreads over its neighbours)."""
ACCEL0_SIGMA_MM_S2 = 2.0e4
"""A new segment's acceleration starts at 0 with this doubt (2 g), as its velocity starts at 0 with
``cv_velocity0_sigma_mm_s``."""


def jerk_sigma(
    positions: np.ndarray,
    linked: np.ndarray,
    dt_s: np.ndarray,
    base: float = JERK_BASE_MM_S3,
    body_gain: float = JERK_BODY_GAIN,
    own_gain: float = JERK_OWN_GAIN,
    spread: int = JERK_SPREAD,
) -> np.ndarray:
    """(T, N, 3) per-frame, per-axis jerk noise, mm/s^3, from smoothed ``positions`` (T, N, 3) mm (NaN: none).

    The jerk of a frame is the third difference of the positions around it (0 where that crosses a segment start,
    ``linked`` (T, N) False, or a frame without a position); each frame takes the largest within ``spread`` frames,
    of the body's median over joints times ``body_gain`` and of the joint's own times ``own_gain``, and at least
    ``base``.
    """
    own = _jerks(np.asarray(positions, dtype=np.float64), np.asarray(linked, dtype=bool), np.asarray(dt_s, float))
    body = np.median(own, axis=1, keepdims=True)
    return np.maximum(base, np.maximum(body_gain * _nearby_max(body, spread), own_gain * _nearby_max(own, spread)))


def _jerks(positions: np.ndarray, linked: np.ndarray, dt_s: np.ndarray) -> np.ndarray:
    """(T, N, 3) |third difference| / dt^3 of frames t-1 .. t+2 at frame t; 0 where unknown."""
    jerk = np.zeros(positions.shape)
    T = len(positions)
    if T < 4:
        return jerk
    dt = (dt_s[1:-2] + dt_s[2:-1] + dt_s[3:]) / 3.0  # the window's mean step (dt_s[0] is not a step)
    third = np.abs(np.diff(positions, n=3, axis=0)) / dt[:, None, None] ** 3
    whole = linked[1:-2] & linked[2:-1] & linked[3:]  # the window's frames continue one segment
    jerk[1:-2] = np.where(whole[:, :, None], np.nan_to_num(third, nan=0.0), 0.0)
    return jerk


def _nearby_max(values: np.ndarray, spread: int) -> np.ndarray:
    """``values`` (T, ...) with each frame the largest within ``spread`` frames (edges repeated)."""
    padded = np.pad(values, ((spread, spread),) + ((0, 0),) * (values.ndim - 1), mode="edge")
    return np.lib.stride_tricks.sliding_window_view(padded, 2 * spread + 1, axis=0).max(axis=-1)


def jerk_smooth(
    z: np.ndarray,
    n_agree: np.ndarray,
    dt_s: np.ndarray,
    linked: np.ndarray,
    params: FusionParams,
    jerk_noise: np.ndarray,
) -> np.ndarray:
    """(T, N, 3) fixed-interval constant-acceleration smoothing of one track (see the module docstring).

    Parameters
    ----------
    z : (T, N, 3) mm, merged positions (NaN = no measurement); n_agree : (T, N) views behind each.
    dt_s : (T,) seconds since the previous frame (dt_s[0] is not used).
    linked : (T, N) bool, frame t continues frame t - 1's segment (the live filter's, :class:`ForwardPass`).
    params : the live fusion's FusionParams (its measurement noise and initial velocity doubt).
    jerk_noise : (T, N, 3) mm/s^3, the white-jerk noise of the step into frame t (:func:`jerk_sigma`).

    Returns the smoothed positions; frames before a segment's first measurement are NaN (the caller masks the
    frames the live filter had no estimate for).
    """
    z = np.asarray(z, dtype=np.float64)
    T, N, _ = z.shape
    coords = z.reshape(T, 3 * N)
    r = params.cv_meas_sigma_mm**2 / (np.maximum(n_agree, 1) if params.cv_scale_r_by_agree else 1.0)
    meas_var = np.repeat(np.broadcast_to(r, (T, N)), 3, axis=1)
    links = np.repeat(np.asarray(linked, dtype=bool), 3, axis=1)
    initial = np.diag([params.cv_meas_sigma_mm**2, params.cv_velocity0_sigma_mm_s**2, ACCEL0_SIGMA_MM_S2**2])
    forward = _forward(coords, meas_var, links, np.asarray(dt_s, float), np.reshape(jerk_noise, (T, 3 * N)), initial)
    return _backward(*forward, links, np.asarray(dt_s, float))[:, :, 0].reshape(T, N, 3)


def _model(dt: float) -> tuple[np.ndarray, np.ndarray]:
    """F and g g' of the white-jerk model for one step of ``dt`` s."""
    F = np.array([[1.0, dt, dt * dt / 2.0], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    g = np.array([dt**3 / 6.0, dt * dt / 2.0, dt])
    return F, np.outer(g, g)


def _forward(
    z: np.ndarray, meas_var: np.ndarray, linked: np.ndarray, dt_s: np.ndarray, jerk: np.ndarray, initial: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The Kalman filter over (T, M) coordinates: filtered and predicted states (T, M, 3) and covariances
    (T, M, 3, 3), and whether each frame's state is an estimate (a segment measured at or before it)."""
    T, M = z.shape
    x, P = np.zeros((T, M, 3)), np.zeros((T, M, 3, 3))
    x_pred, P_pred = np.zeros((T, M, 3)), np.zeros((T, M, 3, 3))
    state, cov = np.zeros((M, 3)), np.broadcast_to(initial, (M, 3, 3)).copy()
    known = np.zeros((T, M), dtype=bool)
    was_known = np.zeros(M, dtype=bool)
    for t in range(T):
        F, qq = _model(float(dt_s[t]) if t else 1.0 / 30.0)
        has = np.isfinite(z[t])
        going = linked[t] & was_known  # continues a segment that has an estimate
        pred = np.where(going[:, None], state @ F.T, np.where(has[:, None], np.nan_to_num(z[t])[:, None] * _E0, 0.0))
        pred_cov = np.where(going[:, None, None], F @ cov @ F.T + jerk[t][:, None, None] ** 2 * qq, initial)
        update = has & going
        gain = pred_cov[:, :, 0] / (pred_cov[:, 0, 0] + meas_var[t])[:, None]
        innovation = np.where(update, np.nan_to_num(z[t]) - pred[:, 0], 0.0)
        state = pred + gain * innovation[:, None]
        cov = pred_cov - np.where(update[:, None, None], gain[:, :, None] * pred_cov[:, None, 0, :], 0.0)
        x[t], P[t], x_pred[t], P_pred[t] = state, cov, pred, pred_cov
        was_known = going | has
        known[t] = was_known
    return x, P, x_pred, P_pred, known


_E0 = np.array([1.0, 0.0, 0.0])  # the position row of a (position, velocity, acceleration) state


def _backward(
    x: np.ndarray,
    P: np.ndarray,
    x_pred: np.ndarray,
    P_pred: np.ndarray,
    known: np.ndarray,
    linked: np.ndarray,
    dt_s: np.ndarray,
) -> np.ndarray:
    """(T, M, 3) the RTS smoothed states (NaN where no estimate): each frame from the next one of its segment."""
    smoothed = x.copy()
    for t in range(len(x) - 2, -1, -1):
        F, _ = _model(float(dt_s[t + 1]))
        # C = P F' (P~)^-1; both covariances symmetric, so C' = solve(P~, F P).
        gain = np.swapaxes(np.linalg.solve(P_pred[t + 1], F @ P[t]), 1, 2)
        step = x[t] + np.einsum("mij,mj->mi", gain, smoothed[t + 1] - x_pred[t + 1])
        crosses = linked[t + 1] & known[t]
        smoothed[t] = np.where(crosses[:, None], step, x[t])
    return np.where(known[:, :, None], smoothed, np.nan)
