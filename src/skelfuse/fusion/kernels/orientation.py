"""The orientation stage (:func:`skelfuse.fusion.orientation.fuse_orientations`) as one compiled loop over joints.

Per body and joint: the aim from the fused bone, every usable view swung onto it, the consensus of the views that
agree, the alpha-beta rotation filter, the body-hint fallback, then the aim offsets and the derived joints. The
same rules and the same arithmetic as the numpy reference (:mod:`skelfuse.fusion.reference.orientation`) up to the
order of its sums of three and four terms (last bits); the rules are documented in
:mod:`skelfuse.fusion.orientation`.

Quaternions (w, x, y, z) and vectors travel between the helpers as tuples of floats, not small arrays: a helper
over scalars compiles once and fast, where one over array arguments compiles per caller's array layout.

The joint tables come from the wrapper (one row per joint), so that the compiled code holds no schema constant:
``joint_index`` (J, 7) int64 = aim from, aim to, derived source, hint axis (1 = Y, 2 = Z), hint body direction
(0 left, 1 up, 2 forward), has an aim offset, is derived; ``joint_value`` (J, 10) float64 = aim sign (NaN:
derived), hint sign, aim offset (w, x, y, z), derived offset (w, x, y, z); ``body_joints`` (6,) int64 = hip left,
hip right, shoulder left, shoulder right, neck, pelvis.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from skelfuse.fusion.kernels.signatures import BOOL, FLOAT, HELPER, INT, KERNEL, array

Quat = tuple[float, float, float, float]
Vec = tuple[float, float, float]

_NAN4 = (np.nan, np.nan, np.nan, np.nan)


@numba.njit(**HELPER)
def _multiply(a: Quat, b: Quat) -> Quat:
    """Hamilton product ``a * b``."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@numba.njit(**HELPER)
def _multiply_conjugate(a: Quat, b: Quat) -> Quat:
    """``a * conj(b)``."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw + ax * bx + ay * by + az * bz,
        -aw * bx + ax * bw - ay * bz + az * by,
        -aw * by + ax * bz + ay * bw - az * bx,
        -aw * bz - ax * by + ay * bx + az * bw,
    )


@numba.njit(**HELPER)
def _normalize(q: Quat, min_norm: float) -> Quat:
    """``q`` scaled to unit length; NaN where its norm is not above ``min_norm`` (NaN: stays NaN)."""
    w, x, y, z = q
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if norm > min_norm:
        return (w / norm, x / norm, y / norm, z / norm)
    return _NAN4


@numba.njit(**HELPER)
def _rotvec_to_quat(r0: float, r1: float, r2: float) -> Quat:
    """Unit quaternion of a rotation vector (rad); sin(a/2)/a by its series 1/2 - a^2/48 near 0."""
    angle = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    half = 0.5 * angle
    k = math.sin(half) / angle if angle > 1e-8 else 0.5 - angle * angle / 48.0
    return (math.cos(half), k * r0, k * r1, k * r2)


@numba.njit(**HELPER)
def _quat_to_rotvec(q: Quat) -> Vec:
    """Rotation vector (rad) of a unit quaternion, the short way round (angle <= pi)."""
    sign = -1.0 if q[0] < 0.0 else 1.0
    v0, v1, v2 = q[1] * sign, q[2] * sign, q[3] * sign
    s = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    k = 2.0 * math.atan2(s, q[0] * sign) / s if s > 1e-12 else 2.0
    return (k * v0, k * v1, k * v2)


@numba.njit(**HELPER)
def _swing_onto(q: Quat, aim: Vec) -> Quat:
    """``q`` turned by the smallest rotation that takes its local X axis onto the unit ``aim`` (normalized).

    The swing (|q|^2 + x.aim, x cross aim) with x the X axis of q scaled by |q|^2; where X points away from the aim
    (no unique smallest rotation) 180 deg about an axis perpendicular to X."""
    w, x, y, z = q
    a0, a1, a2 = aim
    ax = w * w + x * x - y * y - z * z
    ay = 2.0 * (x * y + w * z)
    az = 2.0 * (x * z - w * y)
    s0 = w * w + x * x + y * y + z * z + ax * a0 + ay * a1 + az * a2
    s1, s2, s3 = ay * a2 - az * a1, az * a0 - ax * a2, ax * a1 - ay * a0
    if s0 < 1e-9:
        # swing_between(x, aim): the same, unscaled, or 180 deg about x cross (1, 0, 0) (or (0, 1, 0)).
        s0 = 1.0 + ax * a0 + ay * a1 + az * a2
        if s0 < 1e-9:
            s0 = 0.0
            if abs(ax) < 0.9:  # x cross (1, 0, 0)
                s1, s2, s3 = 0.0, az, -ay
            else:  # x cross (0, 1, 0)
                s1, s2, s3 = -az, 0.0, ax
        norm = math.sqrt(s0**2 + s1**2 + s2**2 + s3**2)
        if not (norm > 1e-9 and norm < math.inf):
            return _NAN4
        s0, s1, s2, s3 = s0 / norm, s1 / norm, s2 / norm, s3 / norm
    return _normalize(_multiply((s0, s1, s2, s3), q), 1e-9)


@numba.njit(**HELPER)
def _quat_from_frame(x: Vec, y: Vec, z: Vec) -> Quat:
    """Unit quaternion (w >= 0) of the rotation whose columns are x, y, z (largest pivot); NaN if any is not finite."""
    for value in x + y + z:
        if not math.isfinite(value):
            return _NAN4
    m00, m11, m22 = x[0], y[1], z[2]
    trace = m00 + m11 + m22
    best = 0
    pivot = trace
    if m00 > pivot:
        best, pivot = 1, m00
    if m11 > pivot:
        best, pivot = 2, m11
    if m22 > pivot:
        best = 3
    # R[r, c] = column c's row r: R[2, 1] = y[2], R[1, 2] = z[1], ...
    if best == 0:
        q = (1.0 + trace, y[2] - z[1], z[0] - x[2], x[1] - y[0])
    elif best == 1:
        q = (y[2] - z[1], 1.0 + m00 - m11 - m22, y[0] + x[1], z[0] + x[2])
    elif best == 2:
        q = (z[0] - x[2], y[0] + x[1], 1.0 - m00 + m11 - m22, z[1] + y[2])
    else:
        q = (x[1] - y[0], z[0] + x[2], z[1] + y[2], 1.0 - m00 - m11 + m22)
    norm = math.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    sign = -1.0 if q[0] / norm < 0.0 else 1.0
    return (sign * q[0] / norm, sign * q[1] / norm, sign * q[2] / norm, sign * q[3] / norm)


@numba.njit(**HELPER)
def _cross(a: Vec, b: Vec) -> Vec:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@numba.njit(**HELPER)
def _unit(v: Vec) -> Vec:
    """``v`` divided by its length (NaN or inf where it has none)."""
    norm = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return (v[0] / norm, v[1] / norm, v[2] / norm)


@numba.njit(**HELPER)
def _difference(p: np.ndarray, a: int, b: int) -> Vec:
    """``p[a] - p[b]`` of a body's (J, 3) positions."""
    return (p[a, 0] - p[b, 0], p[a, 1] - p[b, 1], p[a, 2] - p[b, 2])


@numba.njit(**HELPER)
def _body_hint(p: np.ndarray, body_joints: np.ndarray, direction: int) -> Vec:
    """The body's left (0), up (1) or forward (2) of its fused positions (J, 3): hips (shoulders where a hip is
    missing) for left, pelvis to neck for up, forward = left x up, left = up x forward. NaN where the body lacks
    them."""
    left = _difference(p, body_joints[0], body_joints[1])
    if not (math.isfinite(left[0]) and math.isfinite(left[1]) and math.isfinite(left[2])):
        left = _difference(p, body_joints[2], body_joints[3])
    up = _unit(_difference(p, body_joints[4], body_joints[5]))
    forward = _unit(_cross(left, up))
    if direction == 0:
        return _cross(up, forward)
    return up if direction == 1 else forward


@numba.njit(**HELPER)
def _hint_frame(aim: Vec, hint: Vec, axis: int, sign: float) -> Quat:
    """The aim frame whose X is ``aim`` and whose hint axis (1 = Y, 2 = Z, times ``sign``) is as close as it can be
    to ``hint``; NaN where the hint is parallel to the aim."""
    along = hint[0] * aim[0] + hint[1] * aim[1] + hint[2] * aim[2]
    h0, h1, h2 = hint[0] - along * aim[0], hint[1] - along * aim[1], hint[2] - along * aim[2]
    norm = math.sqrt(h0 * h0 + h1 * h1 + h2 * h2)
    if not norm > 1e-6:
        h0 = h1 = h2 = np.nan
        norm = 1.0
    h = (sign * (h0 / norm), sign * (h1 / norm), sign * (h2 / norm))
    if axis == 1:  # y = sign h, z = x cross y
        return _quat_from_frame(aim, h, _cross(aim, h))
    return _quat_from_frame(aim, _cross(h, aim), h)  # z = sign h, y = z cross x


@numba.njit(**HELPER)
def _consensus(swung: np.ndarray, valid: np.ndarray, min_cos: float, dots: np.ndarray) -> tuple[int, Quat]:
    """Steps 2-3 on the views swung onto the aim, (S, 4) with ``valid`` (S,): the view with the most others within
    the agreement angle (ties: lowest index) and those views, sign-aligned, summed and normalized. Returns the
    views averaged (0: the quaternion is NaN) and their mean. ``dots`` (S, S): scratch."""
    n = swung.shape[0]
    best = 0
    best_support = 0
    for s in range(n):
        if not valid[s]:
            continue
        support = 0
        for t in range(n):
            if not valid[t]:
                continue
            dot = swung[s, 0] * swung[t, 0] + swung[s, 1] * swung[t, 1]
            dot += swung[s, 2] * swung[t, 2] + swung[s, 3] * swung[t, 3]
            dots[s, t] = dot
            support += abs(dot) >= min_cos
        if support > best_support:
            best, best_support = s, support
    if best_support == 0:
        return 0, _NAN4
    w = x = y = z = 0.0
    for t in range(n):
        if valid[t] and abs(dots[best, t]) >= min_cos:
            weight = -1.0 if dots[best, t] < 0.0 else 1.0
            w += weight * swung[t, 0]
            x += weight * swung[t, 1]
            y += weight * swung[t, 2]
            z += weight * swung[t, 3]
    return best_support, _normalize((w, x, y, z), 1e-9)


@numba.njit(**HELPER)
def _quat(a: np.ndarray, b: int, j: int) -> Quat:
    """Row (b, j) of a (B, J, 4) quaternion array."""
    return (a[b, j, 0], a[b, j, 1], a[b, j, 2], a[b, j, 3])


@numba.njit(**HELPER)
def _aim(p: np.ndarray, joint_index: np.ndarray, joint_value: np.ndarray, j: int) -> Vec:
    """Step 1: the unit direction of joint j's bone (NaN: a derived joint, or no bone)."""
    d = _difference(p, joint_index[j, 1], joint_index[j, 0])
    sign = joint_value[j, 0]
    d0, d1, d2 = d[0] * sign, d[1] * sign, d[2] * sign
    norm = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    if not norm > 1e-6:
        return (np.nan, np.nan, np.nan)
    return (d0 / norm, d1 / norm, d2 / norm)


@numba.njit(**HELPER, inline="always")
def _measure(
    view_quats: np.ndarray,
    usable: np.ndarray,
    b: int,
    j: int,
    aim: Vec,
    offset: Quat,
    has_offset: bool,
    min_cos: float,
    swung: np.ndarray,
    valid: np.ndarray,
    dots: np.ndarray,
) -> tuple[int, Quat]:
    """Steps 2-3: joint j's usable views (an ankle's or the head's times the inverse of its aim offset) swung onto
    the aim, and their consensus (:func:`_consensus`). ``swung`` (S, 4), ``valid`` (S,), ``dots`` (S, S): scratch."""
    has_aim = aim[0] == aim[0]
    for s in range(view_quats.shape[1]):
        # Without an aim every swing is NaN, and a view that may not contribute is never read: skip both.
        valid[s] = has_aim and usable[b, s, j]
        if not valid[s]:
            continue
        view = (view_quats[b, s, j, 0], view_quats[b, s, j, 1], view_quats[b, s, j, 2], view_quats[b, s, j, 3])
        if has_offset:
            view = _multiply_conjugate(view, offset)
        swung[s, 0], swung[s, 1], swung[s, 2], swung[s, 3] = _swing_onto(view, aim)
        valid[s] = swung[s, 0] == swung[s, 0]
    return _consensus(swung, valid, min_cos, dots)


@numba.njit(**HELPER, inline="always")
def _filter(
    measured: Quat, previous: Quat, omega_prev: Vec, aim: Vec, alpha: float, beta: float, dt_s: float
) -> tuple[Quat, Vec, bool]:
    """Step 4, the alpha-beta rotation filter: the prediction exp(omega dt) * previous swung onto the aim (without
    an aim it coasts on the rotation), corrected by alpha of the residual rotation to the measurement (a twist
    about the shared aim). Returns the aim frame (NaN: neither a measurement nor a history), the new angular
    velocity (rad/s) and whether a measurement or a history gave the frame."""
    prev = _normalize(previous, 1e-9)
    has_prev = prev[0] == prev[0]
    omega = omega_prev if has_prev else (0.0, 0.0, 0.0)
    predicted = _multiply(_rotvec_to_quat(omega[0] * dt_s, omega[1] * dt_s, omega[2] * dt_s), prev)
    if aim[0] == aim[0]:
        predicted = _swing_onto(predicted, aim)
    if measured[0] != measured[0]:
        return (predicted, omega, True) if has_prev else (_NAN4, (0.0, 0.0, 0.0), False)
    if not has_prev:
        return measured, (0.0, 0.0, 0.0), True
    residual = _quat_to_rotvec(_multiply_conjugate(measured, predicted))
    turn = _rotvec_to_quat(alpha * residual[0], alpha * residual[1], alpha * residual[2])
    gain = beta / dt_s
    omega_new = (omega[0] + gain * residual[0], omega[1] + gain * residual[1], omega[2] + gain * residual[2])
    return _normalize(_multiply(turn, predicted), 1e-9), omega_new, True


@numba.njit(**HELPER, inline="always")
def _fuse_body(
    p: np.ndarray,
    views: np.ndarray,
    usable: np.ndarray,
    quats_prev: np.ndarray,
    omega_prev: np.ndarray,
    b: int,
    settings: tuple[float, float, float, float],
    tables: tuple[np.ndarray, np.ndarray, np.ndarray],
    scratch: tuple[np.ndarray, np.ndarray, np.ndarray],
    out: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
) -> None:
    """Body b's joints into row b of the four outputs of :func:`fuse_orientations`. ``settings``: min_cos, alpha,
    beta, dt_s; ``scratch``: swung (S, 4), valid (S,), dots (S, S)."""
    min_cos, alpha, beta, dt_s = settings
    joint_index, joint_value, body_joints = tables
    quats, n_out, state, omega_out = out
    for j in range(p.shape[0]):
        aim = _aim(p, joint_index, joint_value, j)
        offset = (joint_value[j, 2], joint_value[j, 3], joint_value[j, 4], joint_value[j, 5])
        has_offset = joint_index[j, 5] != 0
        swung, valid, dots = scratch
        n_views, measured = _measure(views, usable, b, j, aim, offset, has_offset, min_cos, swung, valid, dots)
        omega_before = (omega_prev[b, j, 0], omega_prev[b, j, 1], omega_prev[b, j, 2])
        q, omega, known = _filter(measured, _quat(quats_prev, b, j), omega_before, aim, alpha, beta, dt_s)
        if not known and aim[0] == aim[0]:  # step 5: no view, no history: the twist from the body's own frame
            hint = _body_hint(p, body_joints, joint_index[j, 4])
            q = _hint_frame(aim, hint, joint_index[j, 3], joint_value[j, 1])
        n_out[b, j] = n_views if measured[0] == measured[0] else 0
        located = math.isfinite(p[j, 0] + p[j, 1] + p[j, 2])
        for c in range(4):
            state[b, j, c] = q[c] if located and q[c] == q[c] else 0.0
        for c in range(3):
            omega_out[b, j, c] = omega[c] if math.isfinite(omega[c]) else 0.0
        if has_offset:  # the aim frame to the tracker's joint frame (the ankles and the head: times their offset)
            q = _multiply(q, offset)
        quats[b, j, 0], quats[b, j, 1], quats[b, j, 2], quats[b, j, 3] = q
    # Derived joints (hand tips, feet, face): their source joint's frame times a fixed offset.
    for j in range(p.shape[0]):
        if joint_index[j, 6]:
            derived = (joint_value[j, 6], joint_value[j, 7], joint_value[j, 8], joint_value[j, 9])
            q = _multiply(_quat(quats, b, joint_index[j, 2]), derived)
            quats[b, j, 0], quats[b, j, 1], quats[b, j, 2], quats[b, j, 3] = q
    for j in range(p.shape[0]):
        if not math.isfinite(p[j, 0] + p[j, 1] + p[j, 2]):
            quats[b, j, 0] = quats[b, j, 1] = quats[b, j, 2] = quats[b, j, 3] = np.nan


_SIGNATURE = (
    array(FLOAT, 3),  # positions
    array(FLOAT, 4),  # view_quats
    array(BOOL, 3),  # usable
    array(FLOAT, 3),  # quats_prev
    array(FLOAT, 3),  # omega_prev
    FLOAT,  # agree_deg
    FLOAT,  # alpha
    FLOAT,  # beta
    FLOAT,  # dt_s
    array(INT, 2),  # joint_index
    array(FLOAT, 2),  # joint_value
    array(INT, 1),  # body_joints
)


@numba.njit(_SIGNATURE, **KERNEL)
def fuse_orientations(
    positions: np.ndarray,
    view_quats: np.ndarray,
    usable: np.ndarray,
    quats_prev: np.ndarray,
    omega_prev: np.ndarray,
    agree_deg: float,
    alpha: float,
    beta: float,
    dt_s: float,
    joint_index: np.ndarray,
    joint_value: np.ndarray,
    body_joints: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One step of the orientation stage for B bodies, S views, J joints.

    Parameters
    ----------
    positions : (B, J, 3) float64 mm, NaN = none; view_quats : (B, S, J, 4) float64 world quaternions (NaN rows:
    none; S may be 0); usable : (B, S, J) bool; quats_prev : (B, J, 4) float64 aim frames (zero rows: no history);
    omega_prev : (B, J, 3) float64 rad/s; joint_index, joint_value, body_joints: the joint tables (module
    docstring), read-only or not.

    Returns
    -------
    quats (B, J, 4) k4abt frames (NaN = unknown), n_views (B, J) int64, state quats (B, J, 4) aim frames (zero:
    none), omega (B, J, 3) rad/s.
    """
    B, J = positions.shape[0], positions.shape[1]
    S = view_quats.shape[1]
    settings = (math.cos(math.radians(agree_deg) / 2.0), alpha, beta, dt_s)
    out = (np.empty((B, J, 4)), np.empty((B, J), dtype=np.int64), np.empty((B, J, 4)), np.empty((B, J, 3)))
    scratch = (np.empty((S, 4)), np.empty(S, dtype=np.bool_), np.empty((S, S)))
    tables = (joint_index, joint_value, body_joints)
    for b in range(B):
        _fuse_body(positions[b], view_quats, usable, quats_prev, omega_prev, b, settings, tables, scratch, out)
    return out


def warm_up() -> None:
    """Compile (or load) :func:`fuse_orientations` for its one signature."""
    fuse_orientations(
        np.zeros((1, 2, 3)),
        np.zeros((1, 1, 2, 4)),
        np.ones((1, 1, 2), dtype=np.bool_),
        np.zeros((1, 2, 4)),
        np.zeros((1, 2, 3)),
        45.0,
        0.5,
        0.25,
        1.0 / 30.0,
        np.array([[0, 1, 0, 1, 0, 0, 0], [0, 1, 1, 1, 0, 0, 0]], dtype=np.int64),
        np.zeros((2, 10)),
        np.zeros(6, dtype=np.int64),
    )
