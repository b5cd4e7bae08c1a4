"""Rigid transforms between sensor frames and the world frame, as 4x4 homogeneous matrices in millimetres.

``world_from_sensor`` maps a point in a sensor's depth-camera frame to the world frame:
``p_world = R @ p_sensor + t``. The calibration produces one per sensor, stacked as (S, 4, 4).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from skelfuse.fusion import kernels
from skelfuse.schema.skeleton import N_JOINTS

_ORTHO_TOL = 1e-6


def make_transform(rotation: np.ndarray, translation_mm: np.ndarray) -> np.ndarray:
    """Build a rigid transform from a rotation and a translation.

    Parameters
    ----------
    rotation : (3, 3) array
        Proper rotation matrix (orthonormal, determinant +1).
    translation_mm : (3,) array
        Translation, mm.

    Returns
    -------
    (4, 4) float64 homogeneous matrix.

    Raises
    ------
    ValueError
        On a wrong shape, a non-finite value, or a rotation that is not orthonormal with determinant +1
        (a reflection would mirror every skeleton, swapping left and right).
    """
    R = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(translation_mm, dtype=np.float64)
    if R.shape != (3, 3):
        raise ValueError(f"rotation must have shape (3, 3), got {R.shape}")
    if t.shape != (3,):
        raise ValueError(f"translation_mm must have shape (3,), got {t.shape}")
    if not (np.isfinite(R).all() and np.isfinite(t).all()):
        raise ValueError("rotation and translation_mm must be finite; check the calibration")
    ortho_err = np.abs(R.T @ R - np.eye(3)).max()
    if ortho_err > _ORTHO_TOL or np.linalg.det(R) < 0:
        raise ValueError(
            f"rotation must be orthonormal with determinant +1, got |R'R - I| = {ortho_err:.2e}, "
            f"det = {np.linalg.det(R):.6f}; re-orthonormalize it (SVD) before building the transform"
        )
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def invert_transform(T: np.ndarray) -> np.ndarray:
    """Rigid inverse ``[R' | -R't]``: exact for rotations, cheaper and better conditioned than ``np.linalg.inv``.

    Parameters
    ----------
    T : (..., 4, 4) array of rigid transforms.

    Returns
    -------
    (..., 4, 4) float64, the inverse transforms (``sensor_from_world`` for a ``world_from_sensor``).
    """
    T = np.asarray(T, dtype=np.float64)
    if T.shape[-2:] != (4, 4):
        raise ValueError(f"T must have shape (..., 4, 4), got {T.shape}")
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -(Rt @ T[..., :3, 3:4])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def transform_points(frame_b_from_a: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map points by one rigid transform: (4, 4) and (..., 3) mm -> (..., 3) float64 mm (``p @ R' + t``).

    The inverse direction is ``transform_points(invert_transform(T), points)``; NaN stays NaN.
    """
    T = np.asarray(frame_b_from_a, dtype=np.float64)
    return np.asarray(points, dtype=np.float64) @ T[:3, :3].T + T[:3, 3]


def apply_transform(world_from_sensor: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Map every sensor's joints into the world frame.

    Parameters
    ----------
    world_from_sensor : (S, 4, 4) array
        One rigid transform per sensor.
    positions : (..., S, J, 3) array, mm, sensor frames
        Joint positions; NaN marks a missing joint.

    Returns
    -------
    (..., S, J, 3) float64, mm, world frame. A joint with any NaN coordinate comes out all NaN
    (``NaN * 0`` is NaN, so the matrix product spreads it to the three axes).
    """
    T = np.asarray(world_from_sensor, dtype=np.float64)
    p = np.asarray(positions, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ValueError(f"world_from_sensor must have shape (S, 4, 4), got {T.shape}")
    if p.ndim < 3 or p.shape[-1] != 3 or p.shape[-3] != T.shape[0]:
        raise ValueError(
            f"positions must have shape (..., S={T.shape[0]}, J, 3) to match world_from_sensor, got {p.shape}"
        )
    # p @ R' + t, batched over sensors: (..., S, J, 3) @ (S, 3, 3) broadcasts the leading axes.
    return p @ np.swapaxes(T[:, :3, :3], -1, -2) + T[:, None, :3, 3]


class StackedViews(NamedTuple):
    """One instant's bodies, sensor by sensor, in the world frame (:func:`stack_views_to_world`)."""

    world: np.ndarray  # (S, B, 32, 3) float64 mm; NaN in empty slots
    confidence: np.ndarray  # (S, B, 32) uint8; 0 in empty slots
    valid: np.ndarray  # (S, B) bool: the slot holds a body
    orientations: np.ndarray | None  # (S, B, 32, 4) float64 world quaternions; NaN in empty slots; None: not asked


def stack_views_to_world(
    positions: np.ndarray,
    confidence: np.ndarray,
    orientations: np.ndarray | None,
    frame_rows: np.ndarray,
    frame_counts: np.ndarray,
    n_bodies: int,
    world_from_sensor: np.ndarray,
    quat_matrices: np.ndarray,
) -> StackedViews:
    """Scatter the frames' bodies into sensor-by-body slots and move them to the world frame, in one pass.

    Parameters
    ----------
    positions : (N, 32, 3) float64, mm, sensor frames; confidence : (N, 32) uint8
        Every frame's bodies, frame after frame.
    orientations : (N, 32, 4) float64 sensor-frame quaternions, or None (the output has none)
    frame_rows, frame_counts : (F,) int64
        Each frame's sensor row and its number of bodies (they sum to N); a body's slot is its index in its frame.
    n_bodies : int
        B, at least the largest count.
    world_from_sensor : (S, 4, 4) float64; quat_matrices : (S, 4, 4) float64
        The poses and their rotations as quaternion products
        (:func:`skelfuse.fusion.orientation.calibration_quat_matrices`).

    Runs in a compiled kernel (:mod:`skelfuse.fusion.kernels.stacking`; numpy's per-call overhead dominates this
    small work); the numpy form (:func:`apply_transform` over the scattered blocks) is its test reference.
    """
    S, N, F = world_from_sensor.shape[0], positions.shape[0], frame_rows.shape[0]
    world = np.empty((S, n_bodies, N_JOINTS, 3))
    stacked = np.empty((S, n_bodies, N_JOINTS), dtype=np.uint8)
    valid = np.empty((S, n_bodies), dtype=bool)
    quats = np.empty((S, n_bodies, N_JOINTS, 4) if orientations is not None else (0, 0, N_JOINTS, 4))
    fits = kernels.load().stacking.stack_to_world(
        kernels.kernel_array(positions, np.float64, (N, N_JOINTS, 3), "positions"),
        kernels.kernel_array(confidence, np.uint8, (N, N_JOINTS), "confidence"),
        _NO_ORIENTATIONS
        if orientations is None
        else kernels.kernel_array(orientations, np.float64, (N, N_JOINTS, 4), "orientations"),
        kernels.kernel_array(frame_rows, np.int64, (F,), "frame_rows"),
        kernels.kernel_array(frame_counts, np.int64, (F,), "frame_counts"),
        kernels.kernel_array(world_from_sensor, np.float64, (S, 4, 4), "world_from_sensor"),
        kernels.kernel_array(quat_matrices, np.float64, (S, 4, 4), "quat_matrices"),
        world,
        stacked,
        valid,
        quats,
    )
    if not fits:
        raise ValueError(f"frame_rows / frame_counts do not fit {N} bodies in ({S}, {n_bodies}) slots")
    return StackedViews(world, stacked, valid, None if orientations is None else quats)


_NO_ORIENTATIONS = np.empty((0, N_JOINTS, 4))
_NO_ORIENTATIONS.setflags(write=False)
