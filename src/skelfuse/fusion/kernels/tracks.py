"""The seen tracks' motion update (:func:`skelfuse.fusion.tracks.seen_motion`) as a compiled loop over tracks.

Per track seen this frame: the velocity from the mean step of the descriptor points it shares with its
measurement (smoothed, capped), and the new descriptor (a point the sensors miss keeps its prediction). The same
sums in the same order as the numpy reference (:mod:`skelfuse.fusion.reference.tracks`); the rules are
documented in :mod:`skelfuse.fusion.tracks`.
"""

from __future__ import annotations

import numba
import numpy as np

from skelfuse.fusion.kernels.signatures import BOOL, FLOAT, INT, KERNEL, array

_SIGNATURE = (
    array(FLOAT, 3),  # descriptor
    array(FLOAT, 2),  # velocity
    array(FLOAT, 1),  # last_seen_s
    array(INT, 1),  # n_frames_seen
    array(FLOAT, 3),  # predicted
    array(FLOAT, 3),  # measured
    array(BOOL, 1),  # hit
    FLOAT,  # time_s
    FLOAT,  # smoothing
    FLOAT,  # max_speed_mm_s
)


@numba.njit(_SIGNATURE, **KERNEL)
def seen_motion(
    descriptor: np.ndarray,
    velocity: np.ndarray,
    last_seen_s: np.ndarray,
    n_frames_seen: np.ndarray,
    predicted: np.ndarray,
    measured: np.ndarray,
    hit: np.ndarray,
    time_s: float,
    smoothing: float,
    max_speed_mm_s: float,
) -> tuple[np.ndarray, np.ndarray]:
    """New descriptors (K, D, 3) and velocities (K, 3) of the K tracks, the rows not ``hit`` unchanged (copies).

    Parameters
    ----------
    descriptor, predicted, measured : (K, D, 3) float64 mm; velocity : (K, 3) float64 mm/s; last_seen_s : (K,)
    float64 s; n_frames_seen : (K,) int64; hit : (K,) bool; smoothing : weight of the new velocity; max_speed_mm_s.
    """
    K, D = descriptor.shape[0], descriptor.shape[1]
    new_descriptor = descriptor.copy()
    new_velocity = velocity.copy()
    total = np.empty(3)
    v = np.empty(3)
    for k in range(K):
        if not hit[k]:
            continue
        dt = time_s - last_seen_s[k]
        count = 0
        for axis in range(3):
            total[axis] = 0.0
        for d in range(D):
            sx = measured[k, d, 0] - descriptor[k, d, 0]
            sy = measured[k, d, 1] - descriptor[k, d, 1]
            sz = measured[k, d, 2] - descriptor[k, d, 2]
            if np.isfinite(sx) and np.isfinite(sy) and np.isfinite(sz):
                total[0] += sx
                total[1] += sy
                total[2] += sz
                count += 1
        if dt > 0 and count > 0:
            for axis in range(3):
                v_meas = total[axis] / count / dt
                if n_frames_seen[k] < 2:
                    v[axis] = v_meas
                else:
                    v[axis] = smoothing * v_meas + (1.0 - smoothing) * velocity[k, axis]
            speed = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
            # A zero velocity stays zero (its scale is 0 then, not 1: the same product).
            scale = np.minimum(1.0, max_speed_mm_s / (speed if speed > 0 else np.inf))
            for axis in range(3):
                new_velocity[k, axis] = v[axis] * scale
        for d in range(D):
            for axis in range(3):
                m = measured[k, d, axis]
                new_descriptor[k, d, axis] = m if np.isfinite(m) else predicted[k, d, axis]
    return new_descriptor, new_velocity


def warm_up() -> None:
    """Compile (or load) :func:`seen_motion` for its one signature."""
    points = np.zeros((1, 2, 3))
    seen_motion(
        points,
        np.zeros((1, 3)),
        np.zeros(1),
        np.zeros(1, dtype=np.int64),
        points,
        points,
        np.ones(1, np.bool_),
        1.0,
        0.5,
        7000.0,
    )
