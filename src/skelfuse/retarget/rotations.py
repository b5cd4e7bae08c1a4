"""Rotation algebra of the retargeting, vectorized over leading axes: axis-angle and minimal rotations,
the weighted best-fit rotation (Kabsch), rotation matrices to and from quaternions (w, x, y, z), and quaternion
tracks kept in one hemisphere over time. Pure numpy; :mod:`skelfuse.retarget.armature` builds on it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def unit(v: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / norm


def skew(v: np.ndarray) -> np.ndarray:
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def axis_angle_matrix(axis: np.ndarray, angle_rad: ArrayLike) -> np.ndarray:
    """Rotation matrices about unit ``axis`` (..., 3) by ``angle_rad`` (...) (Rodrigues)."""
    k = skew(axis)
    angle = np.asarray(angle_rad)[..., None, None]
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


def minimal_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vectors ``a`` to ``b`` (..., 3) → (..., 3, 3).

    Antiparallel pairs turn by 180° about an axis perpendicular to ``a``.
    """
    a, b = np.broadcast_arrays(a, b)
    v = np.cross(a, b)
    c = np.sum(a * b, axis=-1)
    k = skew(v)
    with np.errstate(invalid="ignore", divide="ignore"):
        rot = np.eye(3) + k + (k @ k) / (1.0 + c)[..., None, None]
    flip = c < -1.0 + 1e-9
    if np.any(flip):
        helper = np.where(np.abs(a[..., :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
        axis = unit(np.cross(a, helper))
        rot = np.where(flip[..., None, None], axis_angle_matrix(axis, np.pi), rot)
    return rot


def kabsch(source: np.ndarray, target: np.ndarray, weights: ArrayLike) -> np.ndarray:
    """Best-fit rotation R minimizing ``Σ w_k |R s_k - t_k|²`` (vectors, no translation).

    source, target : (..., K, 3); weights : (..., K) (zero for a missing target). Returns (..., 3, 3).
    """
    cov = np.einsum("...k,...ki,...kj->...ij", np.asarray(weights), np.nan_to_num(target), np.nan_to_num(source))
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(u @ vt))
    d = np.where(d == 0, 1.0, d)
    fix = np.ones((*d.shape, 3))
    fix[..., 2] = d
    return (u * fix[..., None, :]) @ vt


def matrix_to_quaternion(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices → (..., 4) unit quaternions (w, x, y, z), w ≥ 0."""
    m = rot
    trace = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    candidates = np.stack(
        [
            np.stack(
                [1 + trace, m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1
            ),
            np.stack(
                [
                    m[..., 2, 1] - m[..., 1, 2],
                    1 + 2 * m[..., 0, 0] - trace,
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 0, 1] + m[..., 1, 0],
                    1 + 2 * m[..., 1, 1] - trace,
                    m[..., 1, 2] + m[..., 2, 1],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 1, 0] - m[..., 0, 1],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 + 2 * m[..., 2, 2] - trace,
                ],
                -1,
            ),
        ],
        axis=-2,
    )  # (..., 4, 4): row i is 4·q·q_i, best conditioned where q_i is largest
    diag = np.stack(
        [1 + trace, 1 + 2 * m[..., 0, 0] - trace, 1 + 2 * m[..., 1, 1] - trace, 1 + 2 * m[..., 2, 2] - trace], -1
    )
    best = np.argmax(diag, axis=-1)
    q = np.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :]
    q = unit(q)
    return q * np.where(q[..., :1] < 0, -1.0, 1.0)


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions (w, x, y, z; normalized here) → (..., 3, 3) rotation matrices."""
    w, x, y, z = np.moveaxis(unit(np.asarray(q, dtype=np.float64)), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def continuous_quaternions(quaternions: np.ndarray) -> np.ndarray:
    """(F, J, 4) quaternions with signs flipped so each joint's track stays in one hemisphere over time.

    q and -q are the same rotation; interpolating across a sign flip would pass through a near-zero
    quaternion. NaN rows (unknown) are skipped and kept.
    """
    out = np.array(quaternions, dtype=np.float64)
    for joint in range(out.shape[1]):  # a running product along time: one pass per joint
        ok = np.isfinite(out[:, joint]).all(axis=-1)
        track = out[ok, joint]
        if track.shape[0] < 2:
            continue
        flips = np.where(np.sum(track[1:] * track[:-1], axis=-1) < 0, -1.0, 1.0)
        out[ok, joint] = track * np.concatenate([[1.0], np.cumprod(flips)])[:, None]
    return out
