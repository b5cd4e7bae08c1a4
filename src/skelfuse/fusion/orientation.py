"""Fused joint orientations: swing from the fused bones, twist from the views that agree, filtered without lag.

Every fused joint gets a quaternion (w, x, y, z) in the world frame, in the k4abt joint-frame convention of
:data:`skelfuse.schema.skeleton.ORIENTATION_AIM` (docs/orientations.md): the joint's local X axis lies along a
bone, the other two axes turn with the body. A bone direction fixes two of the three degrees of freedom of that
frame (the *swing*); the third, the rotation about the bone (the *twist*), is what the views add.

The ankles and the head are the exceptions the convention measured: the tracker's ankle frame is rigid to the
foot, its X off the shin by the ankle's flexion, the foot bone at a fixed angle about its Z, and its head frame
rigid to the face, the nose at a fixed direction in it, its X off the neck as the neck bends
(:data:`~skelfuse.schema.skeleton.ORIENTATION_AIM_OFFSET`). The stage works on *aim frames* (local X on the
aim bone, the foot for the ankles, the nose for the head): the views enter through :func:`to_aim_frames`, the
filter carries aim frames, and the output leaves through :func:`from_aim_frames`, in the tracker's convention.

One step (:func:`fuse_orientations`), for B bodies, S views and the 32 joints at once, no loop over joints:

1. Aim: for every joint with a bone of its own, the unit direction of that bone in the *fused* positions
   (``sign * (p[to] - p[from])``). The fused frame's X axis is this direction exactly (to 1e-12).
2. Candidates: each usable view's quaternion (already in the world frame, :func:`views_to_world`) is swung onto
   the fused bone: the smallest rotation that takes the view's own X axis onto the aim. What is left of the
   view is its twist. A view is usable for a joint when it holds a finite, non-zero quaternion, was not
   mirrored (the caller passes the realignment's flip decision: a mirrored view's frames are those of a body
   facing the other way, about 180 deg off, so they are left out, not remapped) and its candidate position
   for that joint was merged (it agrees on where the joint is).
3. Agreement: the candidate with the most others within ``agree_deg`` of it wins (ties: lowest view index);
   the candidates within ``agree_deg`` of it are averaged (sign-aligned quaternion sum, normalized). All share
   the aim, so the mean does too. A view whose twist disagrees by more is an outlier and ignored.
4. Filter: an alpha-beta filter on the rotation (constant angular velocity model, the quaternion analogue of
   :func:`skelfuse.fusion.filters.filter_step`'s "alpha_beta"): predict ``exp(w dt) q``, swing the prediction
   onto this frame's aim, correct by ``alpha`` of the residual rotation, ``w += beta residual / dt``. A
   constant rate of turn is followed without lag in steady state (measured: tests/unit/test_orientation.py).
   Without a measurement the prediction is output (coasting) for as long as the position filter coasts.
5. Without any view and any history (a track's first frame with no usable view), the twist comes from the
   body: the hint axis of :data:`~skelfuse.schema.skeleton.ORIENTATION_HINT` is turned towards the person's
   left / forward direction. Derived joints (hand tips, feet, face) are their source joint's frame times a
   fixed offset (:data:`~skelfuse.schema.skeleton.ORIENTATION_DERIVED`).

Pure numpy, no I/O; every function returns new arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from skelfuse.schema.skeleton import (
    BODY_FORWARD,
    BODY_LEFT,
    BODY_UP,
    N_JOINTS,
    ORIENTATION_AIM,
    ORIENTATION_AIM_OFFSET,
    ORIENTATION_AIMED,
    ORIENTATION_DERIVED_OFFSET,
    ORIENTATION_DERIVED_SOURCE,
    ORIENTATION_HINT,
    J,
)

_EPS = 1e-12
_AIM_FROM = np.where(ORIENTATION_AIMED, ORIENTATION_AIM[:, 0], 0)
_AIM_TO = np.where(ORIENTATION_AIMED, ORIENTATION_AIM[:, 1], 0)
_AIM_SIGN = ORIENTATION_AIM[:, 2].astype(np.float64)
_LOCAL_X = np.array([1.0, 0.0, 0.0])
_HINT_LOCAL = np.eye(3)[ORIENTATION_HINT[:, 0]] * ORIENTATION_HINT[:, 1:2]  # (J, 3) local hint axis
_HINT_BODY = ORIENTATION_HINT[:, 2]
_DERIVED = np.flatnonzero(~ORIENTATION_AIMED)
_OFFSET = np.flatnonzero(np.abs(ORIENTATION_AIM_OFFSET[:, 0]) < 1.0 - 1e-12)  # joints whose aim is not their X


def _product_table(terms: dict[int, list[tuple[int, int, float]]], n_out: int, n_a: int, n_b: int) -> np.ndarray:
    """(n_a * n_b, n_out) matrix M with ``out = (a outer b).reshape(n_a * n_b) @ M``: a bilinear product as one
    outer product and one matrix product (2 numpy calls instead of a dozen on the hot path)."""
    table = np.zeros((n_a * n_b, n_out))
    for out_index, parts in terms.items():
        for i, k, sign in parts:
            table[i * n_b + k, out_index] = sign
    table.setflags(write=False)
    return table


# Hamilton product a * b: out[i] = sum sign * a[j] * b[k].
_QMUL = _product_table(
    {
        0: [(0, 0, 1.0), (1, 1, -1.0), (2, 2, -1.0), (3, 3, -1.0)],
        1: [(0, 1, 1.0), (1, 0, 1.0), (2, 3, 1.0), (3, 2, -1.0)],
        2: [(0, 2, 1.0), (1, 3, -1.0), (2, 0, 1.0), (3, 1, 1.0)],
        3: [(0, 3, 1.0), (1, 2, 1.0), (2, 1, -1.0), (3, 0, 1.0)],
    },
    4,
    4,
    4,
)
# a * conj(b): the conjugate's signs folded in.
_QMUL_CONJ = _QMUL * np.array([1.0, -1.0, -1.0, -1.0] * 4)[:, None]
_QMUL_CONJ.setflags(write=False)

_DERIVED_SOURCE = ORIENTATION_DERIVED_SOURCE[_DERIVED]


_ONES4 = np.ones(4)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` over the last axis (3), without its axis juggling: the hot path calls it a dozen times."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` (apply b, then a), quaternions on the last axis; the shapes broadcast."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    shape = (*np.broadcast_shapes(a.shape[:-1], b.shape[:-1]), 4)
    a, b = np.moveaxis(np.broadcast_to(a, shape), -1, 0), np.moveaxis(np.broadcast_to(b, shape), -1, 0)
    return np.moveaxis(_rows_bilinear(a, b, _QMUL_ROWS), 0, -1)


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """The inverse rotation of a unit quaternion."""
    return np.asarray(q, dtype=np.float64) * np.array([1.0, -1.0, -1.0, -1.0])


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 3) by unit quaternions ``q`` (..., 4): ``q v q*``."""
    q = np.asarray(q, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * _cross(u, v)
    return v + w * t + _cross(u, t)


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternions; a zero or non-finite one becomes NaN (the squared norm as a matrix product: a sum
    over a trailing axis of 4 costs several times more)."""
    q = np.asarray(q, dtype=np.float64)
    norm = np.sqrt((q * q) @ _ONES4)[..., None]
    out = np.full(q.shape, np.nan)
    np.divide(q, norm, out=out, where=(norm > 1e-9) & (norm < np.inf))  # NaN compares False: stays NaN
    return out


def quat_from_rotvec(r: np.ndarray) -> np.ndarray:
    """Unit quaternion of a rotation vector (axis times angle, rad)."""
    r = np.asarray(r, dtype=np.float64)
    return _rows_rotvec_to_quat(r.reshape(-1, 3).T).T.reshape(*r.shape[:-1], 4)


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vector (rad) of unit quaternions, the short way round (angle <= pi)."""
    q = np.asarray(q, dtype=np.float64)
    return _rows_quat_to_rotvec(q.reshape(-1, 4).T).T.reshape(*q.shape[:-1], 3)


def quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (w >= 0) of rotation matrices (..., 3, 3), by the largest-pivot method."""
    R = np.asarray(R, dtype=np.float64)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    trace = m00 + m11 + m22
    candidates = np.stack(
        [
            np.stack(
                [1.0 + trace, R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1
            ),
            np.stack(
                [
                    R[..., 2, 1] - R[..., 1, 2],
                    1.0 + m00 - m11 - m22,
                    R[..., 0, 1] + R[..., 1, 0],
                    R[..., 0, 2] + R[..., 2, 0],
                ],
                -1,
            ),
            np.stack(
                [
                    R[..., 0, 2] - R[..., 2, 0],
                    R[..., 0, 1] + R[..., 1, 0],
                    1.0 - m00 + m11 - m22,
                    R[..., 1, 2] + R[..., 2, 1],
                ],
                -1,
            ),
            np.stack(
                [
                    R[..., 1, 0] - R[..., 0, 1],
                    R[..., 0, 2] + R[..., 2, 0],
                    R[..., 1, 2] + R[..., 2, 1],
                    1.0 - m00 - m11 + m22,
                ],
                -1,
            ),
        ],
        axis=-2,
    )
    pivots = np.stack([trace, m00, m11, m22], axis=-1)
    best = np.argmax(pivots, axis=-1)
    q = np.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0.0, -q, q)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions; column k is the local axis k in the parent frame."""
    return np.stack([quat_rotate(q, axis) for axis in np.eye(3)], axis=-1)


def quat_angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle of the rotation between two orientations, degrees in [0, 180] (NaN where either is NaN)."""
    dot = np.abs(np.sum(quat_normalize(a) * quat_normalize(b), axis=-1))
    return np.degrees(2.0 * np.arccos(np.clip(dot, 0.0, 1.0)))


def swing_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vectors ``u`` onto unit vectors ``v`` (..., 3) -> (..., 4).

    Opposite vectors (no unique smallest rotation) turn by 180 deg about an axis perpendicular to ``u``.
    """
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    w = 1.0 + np.sum(u * v, axis=-1, keepdims=True)
    axis = _cross(u, v)
    # Opposite: any perpendicular axis; cross with x, or with y where u is along x.
    helper = np.where(np.abs(u[..., :1]) < 0.9, _LOCAL_X, np.array([0.0, 1.0, 0.0]))
    perpendicular = _cross(u, np.broadcast_to(helper, u.shape))
    opposite = w < 1e-9
    q = np.where(opposite, np.concatenate([np.zeros_like(w), perpendicular], axis=-1), np.concatenate([w, axis], -1))
    return quat_normalize(q)


# ----------------------------------------------------------------------------------------------------------------
# Geometry of the fused skeleton.


def aim_directions(positions: np.ndarray) -> np.ndarray:
    """(..., 32, 3) unit world direction of every joint's local X axis (NaN: derived joint or missing bone)."""
    p = np.asarray(positions, dtype=np.float64)
    d = (p[..., _AIM_TO, :] - p[..., _AIM_FROM, :]) * _AIM_SIGN[:, None]
    norm = np.linalg.norm(d, axis=-1, keepdims=True)
    ok = (norm > 1e-6) & ORIENTATION_AIMED[:, None]
    return np.where(ok, d / np.where(ok, norm, 1.0), np.nan)


def body_directions(positions: np.ndarray) -> np.ndarray:
    """(..., 3, 3): rows left, up, forward unit vectors of each body (hips for left, shoulders where hips are
    missing; pelvis to neck for up; forward = left x up). NaN where the body lacks them."""
    p = np.asarray(positions, dtype=np.float64)
    hips = p[..., J["HIP_LEFT"], :] - p[..., J["HIP_RIGHT"], :]
    shoulders = p[..., J["SHOULDER_LEFT"], :] - p[..., J["SHOULDER_RIGHT"], :]
    left = np.where(np.isfinite(hips).all(axis=-1, keepdims=True), hips, shoulders)
    up = p[..., J["NECK"], :] - p[..., J["PELVIS"], :]
    up = up / np.linalg.norm(up, axis=-1, keepdims=True)
    forward = _cross(left, up)
    forward = forward / np.linalg.norm(forward, axis=-1, keepdims=True)
    left = _cross(up, forward)
    out = np.empty((*p.shape[:-2], 3, 3))
    out[..., BODY_LEFT, :] = left
    out[..., BODY_UP, :] = up
    out[..., BODY_FORWARD, :] = forward
    return out


def frames_from_bones(aims: np.ndarray, hints: np.ndarray) -> np.ndarray:
    """Orientations whose X axis is ``aims`` and whose hint axis points as close as it can to ``hints``.

    Parameters
    ----------
    aims : (..., 32, 3) unit world aim of each joint (:func:`aim_directions`).
    hints : (..., 32, 3) world direction the joint's hint axis (ORIENTATION_HINT) should follow.

    Returns
    -------
    (..., 32, 4) quaternions; NaN where the aim is missing or the hint is parallel to it.
    """
    x = np.asarray(aims, dtype=np.float64)
    h = hints - np.sum(hints * x, axis=-1, keepdims=True) * x
    h_norm = np.linalg.norm(h, axis=-1, keepdims=True)
    h = np.where(h_norm > 1e-6, h / np.where(h_norm > 1e-6, h_norm, 1.0), np.nan)
    # The hint is local Y or Z (with a sign): y = sign*h for Y hints, z = sign*h for Z hints; the third by
    # right-handedness (z = x cross y, y = z cross x).
    is_y = (ORIENTATION_HINT[:, 0] == 1)[:, None]
    sign = ORIENTATION_HINT[:, 1:2].astype(np.float64)
    y_from_y = sign * h
    z_from_z = sign * h
    y = np.where(is_y, y_from_y, _cross(z_from_z, x))
    z = np.where(is_y, _cross(x, y_from_y), z_from_z)
    return quat_from_matrix_nan(np.stack([x, y, z], axis=-1))


def quat_from_matrix_nan(R: np.ndarray) -> np.ndarray:
    """:func:`quat_from_matrix` that passes NaN matrices through as NaN quaternions."""
    finite = np.isfinite(R).all(axis=(-1, -2))
    q = quat_from_matrix(np.where(finite[..., None, None], R, np.eye(3)))
    return np.where(finite[..., None], q, np.nan)


def to_aim_frames(quats: np.ndarray) -> np.ndarray:
    """(..., 32, 4) k4abt joint frames -> aim frames (local X on the aim bone): ``q * conj(offset)``
    (:data:`skelfuse.schema.skeleton.ORIENTATION_AIM_OFFSET`; only the ankles and the head differ)."""
    q = np.array(quats, dtype=np.float64, copy=True)
    q[..., _OFFSET, :] = quat_multiply(q[..., _OFFSET, :], quat_conjugate(ORIENTATION_AIM_OFFSET[_OFFSET]))
    return q


def from_aim_frames(quats: np.ndarray) -> np.ndarray:
    """The inverse of :func:`to_aim_frames`: aim frames -> k4abt joint frames, ``q * offset``."""
    q = np.array(quats, dtype=np.float64, copy=True)
    q[..., _OFFSET, :] = quat_multiply(q[..., _OFFSET, :], ORIENTATION_AIM_OFFSET[_OFFSET])
    return q


def _aim_hint_frames(positions: np.ndarray) -> np.ndarray:
    """:func:`body_hint_frames` as aim frames (what the orientation filter carries)."""
    body = body_directions(positions)  # (..., 3, 3)
    return frames_from_bones(aim_directions(positions), body[..., _HINT_BODY, :])


def body_hint_frames(positions: np.ndarray) -> np.ndarray:
    """(..., 32, 4) orientations from the bones alone, the twist from the body's left/forward (ORIENTATION_HINT);
    derived joints NaN (see :func:`apply_derived`)."""
    return from_aim_frames(_aim_hint_frames(positions))


def apply_derived(quats: np.ndarray) -> np.ndarray:
    """Fill the derived joints (hand tips, feet, face) from their source joints and fixed offsets."""
    q = np.array(quats, dtype=np.float64, copy=True)
    q[..., _DERIVED, :] = quat_multiply(
        q[..., ORIENTATION_DERIVED_SOURCE[_DERIVED], :], ORIENTATION_DERIVED_OFFSET[_DERIVED]
    )
    return q


def swing_onto_aims(quats: np.ndarray, aims: np.ndarray) -> np.ndarray:
    """Turn each orientation by the smallest rotation that puts its aim axis (local X; the ankles' foot direction)
    on ``aims`` (keeps its twist).

    NaN where either is NaN. The plain formulation (swing, then product): the fusion's hot path computes the
    same rotation in one bilinear step (``_rows_swing_onto``), and tests/unit/test_orientation.py checks that
    one against this one.
    """
    aimed = to_aim_frames(quats)  # the ankles' X is not on their aim bone: swing their aim frames
    current = quat_rotate(aimed, _LOCAL_X)
    return from_aim_frames(quat_normalize(quat_multiply(swing_between(current, aims), aimed)))


def views_to_world(orientations: np.ndarray, world_from_sensor: np.ndarray) -> np.ndarray:
    """Sensor-frame joint quaternions (..., S, J, 4) to the world frame with the (S, 4, 4) calibrations.

    ``q_world = q_calibration * q_sensor``; an all-zero or non-finite quaternion comes out NaN.
    """
    T = np.asarray(world_from_sensor, dtype=np.float64)
    q_cal = quat_from_matrix(T[:, :3, :3])  # (S, 4)
    return quat_normalize(quat_multiply(q_cal[:, None, :], quat_normalize(orientations)))


def calibration_quat_matrices(world_from_sensor: np.ndarray) -> np.ndarray:
    """(S, 4, 4) matrices ``M`` with ``q_cal[s] * q == q @ M[s]``: :func:`views_to_world`'s rotation as one
    matrix product per sensor, computed once per rig (see :func:`views_to_world_by_matrix`)."""
    T = np.asarray(world_from_sensor, dtype=np.float64)
    q_cal = quat_from_matrix(T[:, :3, :3])  # (S, 4)
    return np.einsum("sj,jki->ski", q_cal, _QMUL.reshape(4, 4, 4))


def views_to_world_by_matrix(orientations: np.ndarray, matrices: np.ndarray) -> np.ndarray:
    """:func:`views_to_world` for sensor-major quaternions (S, ..., 4) with :func:`calibration_quat_matrices`:
    one batched matrix product and one normalization (an all-zero or non-finite quaternion comes out NaN)."""
    q = np.asarray(orientations, dtype=np.float64)
    S = q.shape[0]
    return quat_normalize((q.reshape(S, -1, 4) @ matrices).reshape(q.shape))


# ----------------------------------------------------------------------------------------------------------------
# The hot path, component-major: a quaternion array is laid out (4, ...) and a vector array (3, ...), so that every
# elementwise step runs over one contiguous row per component. numpy's cost for a trailing axis of 3 or 4 is its
# per-element inner-loop setup (a dot product over (N, 4) costs ~15x the same work over four rows of N), and a
# bilinear product is one broadcast outer product of rows plus one (n_out, n_a * n_b) matrix product.


def _table_rows(table: np.ndarray) -> np.ndarray:
    """A bilinear table of :func:`_product_table` for the component-major layout: (n_out, n_a * n_b)."""
    rows = np.ascontiguousarray(table.T)
    rows.setflags(write=False)
    return rows


_QMUL_ROWS = _table_rows(_QMUL)
_QMUL_CONJ_ROWS = _table_rows(_QMUL_CONJ)
# (|q|^2, X axis of q) from q outer q: (w^2 + x^2 + y^2 + z^2, w^2 + x^2 - y^2 - z^2, 2(xy + wz), 2(xz - wy)).
# For a unit q the first row is 1 (to rounding): the four rows are (1, x_axis), ready for :data:`_SWING_ROWS`.
_ONE_XAXIS_ROWS = _table_rows(
    _product_table(
        {
            0: [(0, 0, 1.0), (1, 1, 1.0), (2, 2, 1.0), (3, 3, 1.0)],
            1: [(0, 0, 1.0), (1, 1, 1.0), (2, 2, -1.0), (3, 3, -1.0)],
            2: [(1, 2, 2.0), (0, 3, 2.0)],
            3: [(1, 3, 2.0), (0, 2, -2.0)],
        },
        4,
        4,
        4,
    )
)
# The unnormalized swing (1 + u.v, u x v) from (1, u) outer (1, v).
_SWING_ROWS = _table_rows(
    _product_table(
        {
            0: [(0, 0, 1.0), (1, 1, 1.0), (2, 2, 1.0), (3, 3, 1.0)],
            1: [(2, 3, 1.0), (3, 2, -1.0)],
            2: [(3, 1, 1.0), (1, 3, -1.0)],
            3: [(1, 2, 1.0), (2, 1, -1.0)],
        },
        4,
        4,
        4,
    )
)
_DERIVED_OFFSETS_ROWS = np.ascontiguousarray(ORIENTATION_DERIVED_OFFSET[_DERIVED].T)[:, None, :]  # (4, 1, n_derived)
_AIM_OFFSET_ROWS = np.ascontiguousarray(ORIENTATION_AIM_OFFSET[_OFFSET].T)[:, None, :]  # (4, 1, n_offset)
_AIM_OFFSET_CONJ_ROWS = _AIM_OFFSET_ROWS * np.array([1.0, -1.0, -1.0, -1.0])[:, None, None]
_AIM_SIGN_AIMED = np.where(ORIENTATION_AIMED, _AIM_SIGN, np.nan)  # a derived joint's aim comes out NaN


def _rows_bilinear(a: np.ndarray, b: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``rows @ (a outer b)`` over the leading (component) axes; the trailing axes of a and b broadcast."""
    outer = a[:, None] * b[None, :]
    n = math.prod(outer.shape[2:])  # not -1: that cannot reshape an empty batch
    return (rows @ outer.reshape(rows.shape[1], n)).reshape(rows.shape[0], *outer.shape[2:])


def _rows_normalize(q: np.ndarray) -> np.ndarray:
    """Unit rows of a component-major array whose entries are finite or NaN; NaN where the norm is ~0."""
    norm = np.sqrt((q * q).sum(axis=0))
    out = np.full(q.shape, np.nan)
    np.divide(q, norm, out=out, where=norm > 1e-9)
    return out


def _rows_aims(positions_rows: np.ndarray) -> np.ndarray:
    """:func:`aim_directions` of (3, B, J) positions, (3, B, J); NaN for derived joints and missing bones."""
    d = (positions_rows[:, :, _AIM_TO] - positions_rows[:, :, _AIM_FROM]) * _AIM_SIGN_AIMED
    norm = np.sqrt((d * d).sum(axis=0))
    out = np.full(d.shape, np.nan)
    np.divide(d, norm, out=out, where=norm > 1e-6)
    return out


def _rows_swing_onto(quats: np.ndarray, aims_one: np.ndarray) -> np.ndarray:
    """:func:`swing_onto_aims` component-major: quats (4, ...), ``aims_one`` (4, ...) = (1, aim), broadcast.

    The swing and its product with q as two bilinear products and one normalization, part of the orientation
    stage's component-major layout (fewer numpy calls on small arrays than axis-last; ``skelfuse bench instant``,
    docs/evidence.md "Speed"); checked against :func:`swing_onto_aims`."""
    swing = _rows_bilinear(_rows_bilinear(quats, quats, _ONE_XAXIS_ROWS), aims_one, _SWING_ROWS)
    opposite = swing[0] < 1e-9
    if opposite.any():  # rare: the X axis points exactly away from the aim
        x_axis = np.moveaxis(_rows_bilinear(quats, quats, _ONE_XAXIS_ROWS)[1:], 0, -1)
        aims = np.moveaxis(np.broadcast_to(aims_one[1:], x_axis.shape[-1:] + x_axis.shape[:-1]), 0, -1)
        swing = np.where(opposite, np.moveaxis(swing_between(x_axis, aims), -1, 0), swing)
    # |swing * q| = |swing| |q|: one normalization of the product is the swing's and the product's.
    return _rows_normalize(_rows_bilinear(swing, quats, _QMUL_ROWS))


def _rows_rotvec_to_quat(r: np.ndarray) -> np.ndarray:
    """Unit quaternions (4, ...) of rotation vectors (3, ...), component-major (:func:`quat_from_rotvec`)."""
    angle = np.sqrt((r * r).sum(axis=0))
    half = 0.5 * angle
    k = 0.5 - angle * angle / 48.0  # sin(a/2)/a, with its limit 1/2 - a^2/48 near 0
    np.divide(np.sin(half), angle, out=k, where=angle > 1e-8)
    out = np.empty((4, *r.shape[1:]))
    np.cos(half, out=out[0])
    np.multiply(k, r, out=out[1:])
    return out


def _rows_quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (3, ...) of unit quaternions (4, ...), the short way round (angle <= pi)."""
    sign = np.where(q[0] < 0.0, -1.0, 1.0)
    vec = q[1:] * sign
    s = np.sqrt((vec * vec).sum(axis=0))
    k = np.full(s.shape, 2.0)
    np.divide(2.0 * np.arctan2(s, q[0] * sign), s, out=k, where=s > 1e-12)
    return k * vec


def _rows_consensus(swung: np.ndarray, usable: np.ndarray, agree_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Steps 2-3 on the views already swung onto the aims, (4, S, B, J); ``usable`` (S, B, J) bool.

    Returns the consensus (4, B, J) (NaN where no view) and the views averaged (B, J) int16."""
    _, S, B, J = swung.shape
    valid = usable & (swung[0] == swung[0])  # NaN rows are not valid
    q = np.where(valid, swung, 0.0).reshape(4, S, B * J)
    dots = q.transpose(2, 1, 0) @ q.transpose(2, 0, 1)  # (B*J, S, S) |cos(angle/2)| where both valid
    # An invalid view's row is zero, so its dots are 0 and never reach the threshold (cos(agree/2) > 0 for
    # agree_deg <= 180): only valid pairs agree, the diagonal included.
    agree = np.abs(dots) >= math.cos(math.radians(agree_deg) / 2.0)
    support = agree.astype(np.float64) @ np.ones(S)  # (B*J, S), exact counts (faster than a bool sum)
    best = np.argmax(support, axis=-1)  # lowest index on ties
    lanes = _lanes(B * J)
    members = agree[lanes, best]  # (B*J, S)
    signs = np.sign(dots[lanes, best])  # align to the winner
    weights = np.where(members, np.where(signs == 0, 1.0, signs), 0.0)
    total = np.einsum("ksn,ns->kn", q, weights)
    n_views = members.sum(axis=-1).astype(np.int16)
    # The mean of rotations that share an aim shares it too (up to rounding, ~1e-16): no re-swing needed.
    total[:, n_views == 0] = np.nan
    return _rows_normalize(total).reshape(4, B, J), n_views.reshape(B, J)


@lru_cache(maxsize=64)
def _lanes(n: int) -> np.ndarray:
    out = np.arange(n)
    out.setflags(write=False)
    return out


# ----------------------------------------------------------------------------------------------------------------
# The stage.


@dataclass(frozen=True)
class OrientationParams:
    """Options of :func:`fuse_orientations`.

    Attributes
    ----------
    agree_deg : float
        Two views' swung orientations agree when they are at most this far apart (deg).
    alpha, beta : float
        Gains of the alpha-beta rotation filter. Default beta = alpha^2 / (2 - alpha) (Benedict-Bordner).
    """

    agree_deg: float = 45.0
    alpha: float = 0.5
    beta: float = 0.5**2 / (2.0 - 0.5)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.agree_deg) and 0.0 < self.agree_deg <= 180.0):
            raise ValueError(f"OrientationParams.agree_deg must be in (0, 180], got {self.agree_deg!r}")
        if not (0.0 < self.alpha <= 1.0 and 0.0 <= self.beta < 2.0):
            raise ValueError(
                f"OrientationParams alpha must be in (0, 1] and beta in [0, 2), got {self.alpha}, {self.beta}"
            )


@dataclass(frozen=True)
class OrientationResult:
    """Attributes: quats (B, 32, 4) world, NaN = unknown; n_views (B, 32) int16, views averaged into each
    joint's twist (0: predicted, or from the body hint)."""

    quats: np.ndarray
    n_views: np.ndarray


def init_orientation_state(n_bodies: int) -> tuple[np.ndarray, np.ndarray]:
    """Empty rotation filter state: quats (B, 32, 4) all zero (= none) and angular velocity (B, 32, 3) rad/s."""
    return np.zeros((n_bodies, N_JOINTS, 4)), np.zeros((n_bodies, N_JOINTS, 3))


def view_consensus(
    positions: np.ndarray, view_quats: np.ndarray, usable: np.ndarray, agree_deg: float
) -> tuple[np.ndarray, np.ndarray]:
    """Steps 1-3: the views' orientations swung onto the fused bones and averaged over those that agree.

    Parameters
    ----------
    positions : (B, 32, 3) fused positions, mm, world.
    view_quats : (B, S, 32, 4) the views' quaternions in the world frame (NaN = none).
    usable : (B, S, 32) bool, the view may contribute to the joint (not mirrored, position merged).
    agree_deg : float

    Returns
    -------
    quats : (B, 32, 4) the consensus (NaN where no usable view or no aim).
    n_views : (B, 32) int16, the views averaged.
    """
    aims = _rows_aims(np.asarray(positions, dtype=np.float64).transpose(2, 0, 1))
    aims_one = np.concatenate([np.ones((1, *aims.shape[1:])), aims])[:, None]  # (4, 1, B, J)
    swung = _rows_swing_onto(_rows_view_aim_frames(view_quats), aims_one)
    quats, n_views = _rows_consensus(swung, np.asarray(usable, dtype=bool).transpose(1, 0, 2), agree_deg)
    return _rows_from_aim_frames(quats).transpose(1, 2, 0), n_views


def _rows_view_aim_frames(view_quats: np.ndarray) -> np.ndarray:
    """(B, S, 32, 4) views' k4abt frames -> (4, S, B, J) component-major aim frames (what the filter carries)."""
    views = np.asarray(view_quats, dtype=np.float64).transpose(3, 1, 0, 2)
    if _OFFSET.size:
        views = views.copy()
        views[..., _OFFSET] = _rows_bilinear(views[..., _OFFSET], _AIM_OFFSET_CONJ_ROWS[:, None], _QMUL_ROWS)
    return views


def _rows_from_aim_frames(quats: np.ndarray) -> np.ndarray:
    """(4, ..., J) component-major aim frames -> k4abt frames (a copy; only the ankles and the head change)."""
    out = np.array(quats, dtype=np.float64, copy=True)
    if _OFFSET.size:
        out[..., _OFFSET] = _rows_bilinear(out[..., _OFFSET], _AIM_OFFSET_ROWS, _QMUL_ROWS)
    return out


def _rows_measure(
    view_quats: np.ndarray | None,
    usable: np.ndarray | None,
    predicted: np.ndarray,
    aims_one: np.ndarray,
    agree_deg: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The views' consensus (4, B, J) and its view counts (B, J), and the prediction swung onto this frame's
    bones (4, B, J); component-major rows as in :func:`fuse_orientations`."""
    if view_quats is None or usable is None or np.shape(view_quats)[1] == 0:
        measured = np.full((4, *predicted.shape[1:]), np.nan)
        n_views = np.zeros(predicted.shape[1:], dtype=np.int16)
        swung_prediction = _rows_swing_onto(predicted, aims_one)
    else:
        # The views and the prediction swung onto this frame's bones in one call: (4, S + 1, B, J); the views'
        # axis ahead of the bodies' so that the aims (4, 1, B, J) broadcast over a leading axis.
        views = _rows_view_aim_frames(view_quats)
        swung = _rows_swing_onto(np.concatenate([views, predicted[:, None]], axis=1), aims_one[:, None])
        usable_rows = np.asarray(usable, dtype=bool).transpose(1, 0, 2)  # (S, B, J)
        measured, n_views = _rows_consensus(swung[:, :-1], usable_rows, agree_deg)
        swung_prediction = swung[:, -1]
    return measured, n_views, swung_prediction


def fuse_orientations(
    positions: np.ndarray,
    view_quats: np.ndarray | None,
    usable: np.ndarray | None,
    quats_prev: np.ndarray,
    omega_prev: np.ndarray,
    params: OrientationParams,
    dt_s: float,
) -> tuple[OrientationResult, np.ndarray, np.ndarray]:
    """One step of the orientation stage (module docstring) for B bodies.

    Parameters
    ----------
    positions : (B, 32, 3) fused (filtered) positions, mm, world; NaN = none.
    view_quats : (B, S, 32, 4) the views' world quaternions (finite or NaN rows), or None (no view reports
        orientations).
    usable : (B, S, 32) bool, or None with ``view_quats``.
    quats_prev : (B, 32, 4) last output (zero or NaN rows: no history).
    omega_prev : (B, 32, 3) angular velocity estimate, rad/s, world.
    params : OrientationParams
    dt_s : seconds since the previous step.

    Returns
    -------
    result : OrientationResult
    quats, omega : the new filter state (new arrays; like the result's quats, (B, 32, 4) views of
        component-major arrays).
    """
    positions = np.asarray(positions, dtype=np.float64)
    B = positions.shape[0]
    # Component-major from here on (see _rows_bilinear): quaternions (4, B, J), vectors (3, B, J).
    position_rows = positions.transpose(2, 0, 1)
    aims = _rows_aims(position_rows)
    aims_one = np.concatenate([np.ones((1, B, N_JOINTS)), aims])  # (1, aim): what the swing table takes
    prev = _rows_normalize(np.asarray(quats_prev, dtype=np.float64).transpose(2, 0, 1))
    has_prev = prev[0] == prev[0]  # (B, J)
    omega = np.where(has_prev, np.asarray(omega_prev, dtype=np.float64).transpose(2, 0, 1), 0.0)
    predicted = _rows_bilinear(_rows_rotvec_to_quat(omega * dt_s), prev, _QMUL_ROWS)
    has_aim = aims[0] == aims[0]
    measured, n_views, swung_prediction = _rows_measure(view_quats, usable, predicted, aims_one, params.agree_deg)
    has_meas = measured[0] == measured[0]  # a consensus row is all finite or all NaN
    # The prediction follows this frame's bone; without a bone it coasts on the rotation alone.
    predicted = np.where(has_aim, swung_prediction, predicted)

    # Correct: the residual rotation from the prediction to the measurement (a twist about the aim).
    residual = _rows_quat_to_rotvec(_rows_bilinear(measured, predicted, _QMUL_CONJ_ROWS))  # (3, B, J)
    # Both share this frame's aim, so the residual turns about it and the corrected frame keeps it.
    corrected = _rows_normalize(_rows_bilinear(_rows_rotvec_to_quat(params.alpha * residual), predicted, _QMUL_ROWS))

    # The body's own frame, only where neither a view nor the history gives the twist (a track's start).
    need_hint = ~has_meas & ~has_prev & has_aim
    both = has_meas & has_prev
    if need_hint.any():
        fallback = np.where(has_prev, predicted, _aim_hint_frames(positions).transpose(2, 0, 1))
    else:
        fallback = predicted  # where has_prev is False here, has_aim is too (or has_meas): masked below
    out = np.where(both, corrected, np.where(has_meas, measured, fallback))
    omega_out = np.where(both, omega + (params.beta / dt_s) * residual, np.where(has_prev & ~has_meas, omega, 0.0))
    # Nothing to aim and nothing to coast on, or no fused position: unknown (and the history is dropped).
    out = np.where(has_aim | has_prev, out, np.nan)
    # The sum of the three coordinates is finite exactly when all three are (mm-sized values cannot overflow).
    located = np.isfinite(position_rows.sum(axis=0))
    state_quats = np.where(located & (out == out), out, 0.0)  # the filter carries aim frames
    out = _rows_from_aim_frames(out)
    out[:, :, _DERIVED] = _rows_bilinear(out[:, :, _DERIVED_SOURCE], _DERIVED_OFFSETS_ROWS, _QMUL_ROWS)
    out = np.where(located, out, np.nan)
    omega_out = np.where(np.isfinite(omega_out), omega_out, 0.0)
    n_views = np.where(has_meas, n_views, 0).astype(np.int16)
    return (
        OrientationResult(quats=out.transpose(1, 2, 0), n_views=n_views),
        state_quats.transpose(1, 2, 0),
        omega_out.transpose(1, 2, 0),
    )
