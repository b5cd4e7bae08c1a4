"""The numpy form of the seen tracks' motion update: the test reference of
:func:`skelfuse.fusion.tracks.seen_motion` (the live path runs :mod:`skelfuse.fusion.kernels.tracks` and never
imports this module). The rules are documented there.
"""

from __future__ import annotations

import numpy as np

from skelfuse.fusion.tracks import TrackParams


def seen_motion(
    descriptor: np.ndarray,
    velocity: np.ndarray,
    last_seen_s: np.ndarray,
    n_frames_seen: np.ndarray,
    predicted: np.ndarray,
    measured: np.ndarray,
    hit: np.ndarray,
    time_s: float,
    params: TrackParams,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`skelfuse.fusion.tracks.seen_motion` in numpy, over the seen tracks at once."""
    descriptor = np.array(descriptor, dtype=np.float64)
    velocity = np.array(velocity, dtype=np.float64)
    idx = np.flatnonzero(hit)
    measured = measured[idx]
    dt = time_s - last_seen_s[idx]  # (H,)
    step = measured - descriptor[idx]  # (H, D, 3)
    ok = np.asarray(np.isfinite(step).all(axis=-1))  # (H, D)
    count = ok.sum(axis=-1)
    moved = (dt > 0) & (count > 0)
    if moved.any():
        # Sum over the common points in point order (adding exact zeros elsewhere), then / count / dt,
        # as step[ok].mean(axis=0) / dt does.
        total = np.where(ok[..., None], step, 0.0).sum(axis=-2)  # (H, 3)
        v_meas = total / np.maximum(count, 1)[:, None] / np.where(moved, dt, 1.0)[:, None]
        smoothed = params.velocity_smoothing * v_meas + (1.0 - params.velocity_smoothing) * velocity[idx]
        v = np.where((n_frames_seen[idx] < 2)[:, None], v_meas, smoothed)
        speed = np.sqrt((v * v).sum(axis=-1))
        # A zero velocity stays zero (its scale is 0 then, not 1: the same product).
        scale = np.minimum(1.0, params.max_speed_mm_s / np.where(speed > 0, speed, np.inf))
        velocity[idx[moved]] = (v * scale[:, None])[moved]
    # A point the sensors miss this frame keeps its prediction.
    descriptor[idx] = np.where(np.isfinite(measured), measured, predicted[idx])
    return descriptor, velocity
