"""The orientation stage (:func:`skelfuse.fusion.orientation.fuse_orientations`) as one compiled loop over joints.

Per body and joint: the aim from the fused bone, every usable view swung onto it, the consensus of the views that
agree, the alpha-beta rotation filter, the body-hint fallback, then the aim offsets and the derived joints. The
same rules and the same arithmetic as the numpy reference (:mod:`skelfuse.fusion.reference.orientation`) up to the
order of its sums of three and four terms (last bits); the rules are documented in
:mod:`skelfuse.fusion.orientation`.

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


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _multiply(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """Hamilton product ``out = a * b`` of (4,) quaternions (w, x, y, z); ``out`` may not alias a or b."""
    out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3]
    out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2]
    out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1]
    out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _multiply_conjugate(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out = a * conj(b)``."""
    out[0] = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
    out[1] = -a[0] * b[1] + a[1] * b[0] - a[2] * b[3] + a[3] * b[2]
    out[2] = -a[0] * b[2] + a[1] * b[3] + a[2] * b[0] - a[3] * b[1]
    out[3] = -a[0] * b[3] - a[1] * b[2] + a[2] * b[1] + a[3] * b[0]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _normalize(q: np.ndarray, min_norm: float) -> None:
    """Scale ``q`` to unit length in place; NaN where its norm is not above ``min_norm`` (NaN: stays NaN)."""
    norm = 0.0
    for c in range(q.shape[0]):
        norm += q[c] * q[c]
    norm = np.sqrt(norm)
    if norm > min_norm:
        for c in range(q.shape[0]):
            q[c] = q[c] / norm
    else:
        q[:] = np.nan


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _rotvec_to_quat(r0: float, r1: float, r2: float, out: np.ndarray) -> None:
    """Unit quaternion of a rotation vector (rad); sin(a/2)/a by its series 1/2 - a^2/48 near 0."""
    angle = np.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    half = 0.5 * angle
    k = np.sin(half) / angle if angle > 1e-8 else 0.5 - angle * angle / 48.0
    out[0] = np.cos(half)
    out[1] = k * r0
    out[2] = k * r1
    out[3] = k * r2


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _quat_to_rotvec(q: np.ndarray, out: np.ndarray) -> None:
    """Rotation vector (rad) of a unit quaternion, the short way round (angle <= pi)."""
    sign = -1.0 if q[0] < 0.0 else 1.0
    v0, v1, v2 = q[1] * sign, q[2] * sign, q[3] * sign
    s = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    k = 2.0 * math.atan2(s, q[0] * sign) / s if s > 1e-12 else 2.0
    out[0] = k * v0
    out[1] = k * v1
    out[2] = k * v2


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _swing_onto(q: np.ndarray, aim: np.ndarray, swing: np.ndarray, out: np.ndarray) -> None:
    """``out`` = q turned by the smallest rotation that takes its local X axis onto the unit ``aim`` (normalized).

    The swing (|q|^2 + x.aim, x cross aim) with x the X axis of q scaled by |q|^2; where X points away from the aim
    (no unique smallest rotation) 180 deg about an axis perpendicular to X. ``swing`` (4,): scratch."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    n = w * w + x * x + y * y + z * z
    ax = w * w + x * x - y * y - z * z
    ay = 2.0 * (x * y + w * z)
    az = 2.0 * (x * z - w * y)
    swing[0] = n + ax * aim[0] + ay * aim[1] + az * aim[2]
    swing[1] = ay * aim[2] - az * aim[1]
    swing[2] = az * aim[0] - ax * aim[2]
    swing[3] = ax * aim[1] - ay * aim[0]
    if swing[0] < 1e-9:
        # swing_between(x, aim): the same, unscaled, or 180 deg about x cross (1, 0, 0) (or (0, 1, 0)).
        sw = 1.0 + ax * aim[0] + ay * aim[1] + az * aim[2]
        if sw < 1e-9:
            swing[0] = 0.0
            if abs(ax) < 0.9:  # x cross (1, 0, 0)
                swing[1], swing[2], swing[3] = 0.0, az, -ay
            else:  # x cross (0, 1, 0)
                swing[1], swing[2], swing[3] = -az, 0.0, ax
        else:
            swing[0] = sw
        norm = np.sqrt(swing[0] ** 2 + swing[1] ** 2 + swing[2] ** 2 + swing[3] ** 2)
        if norm > 1e-9 and norm < np.inf:
            for c in range(4):
                swing[c] = swing[c] / norm
        else:
            swing[:] = np.nan
    _multiply(swing, q, out)
    _normalize(out, 1e-9)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _quat_from_frame(x: np.ndarray, y: np.ndarray, z: np.ndarray, out: np.ndarray) -> None:
    """Unit quaternion (w >= 0) of the rotation whose columns are x, y, z (largest pivot); NaN if any is not finite."""
    for axis in (x, y, z):
        for c in range(3):
            if not np.isfinite(axis[c]):
                out[:] = np.nan
                return
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
        out[0], out[1], out[2], out[3] = 1.0 + trace, y[2] - z[1], z[0] - x[2], x[1] - y[0]
    elif best == 1:
        out[0], out[1], out[2], out[3] = y[2] - z[1], 1.0 + m00 - m11 - m22, y[0] + x[1], z[0] + x[2]
    elif best == 2:
        out[0], out[1], out[2], out[3] = z[0] - x[2], y[0] + x[1], 1.0 - m00 + m11 - m22, z[1] + y[2]
    else:
        out[0], out[1], out[2], out[3] = x[1] - y[0], z[0] + x[2], z[1] + y[2], 1.0 - m00 - m11 + m22
    norm = np.sqrt(out[0] ** 2 + out[1] ** 2 + out[2] ** 2 + out[3] ** 2)
    sign = -1.0 if out[0] / norm < 0.0 else 1.0
    for c in range(4):
        out[c] = sign * out[c] / norm


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _cross(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _body_directions(p: np.ndarray, body_joints: np.ndarray, out: np.ndarray) -> None:
    """Rows left, up, forward (3, 3) of one body's fused positions (J, 3): hips (shoulders where a hip is missing)
    for left, pelvis to neck for up, forward = left x up, left = up x forward. NaN where the body lacks them."""
    hip_l, hip_r, sh_l, sh_r, neck, pelvis = (
        body_joints[0],
        body_joints[1],
        body_joints[2],
        body_joints[3],
        body_joints[4],
        body_joints[5],
    )
    left = np.empty(3)
    up = np.empty(3)
    forward = np.empty(3)
    hips_finite = True
    for c in range(3):
        left[c] = p[hip_l, c] - p[hip_r, c]
        hips_finite = hips_finite and np.isfinite(left[c])
    if not hips_finite:
        for c in range(3):
            left[c] = p[sh_l, c] - p[sh_r, c]
    for c in range(3):
        up[c] = p[neck, c] - p[pelvis, c]
    norm = np.sqrt(up[0] * up[0] + up[1] * up[1] + up[2] * up[2])
    for c in range(3):
        up[c] = up[c] / norm
    _cross(left, up, forward)
    norm = np.sqrt(forward[0] * forward[0] + forward[1] * forward[1] + forward[2] * forward[2])
    for c in range(3):
        forward[c] = forward[c] / norm
    _cross(up, forward, left)
    out[0] = left
    out[1] = up
    out[2] = forward


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _hint_frame(aim: np.ndarray, hint: np.ndarray, axis: int, sign: float, out: np.ndarray) -> None:
    """The aim frame whose X is ``aim`` and whose hint axis (1 = Y, 2 = Z, times ``sign``) is as close as it can be
    to ``hint``; NaN where the hint is parallel to the aim."""
    along = hint[0] * aim[0] + hint[1] * aim[1] + hint[2] * aim[2]
    h = np.empty(3)
    for c in range(3):
        h[c] = hint[c] - along * aim[c]
    norm = np.sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2])
    for c in range(3):
        h[c] = sign * (h[c] / norm if norm > 1e-6 else np.nan)
    other = np.empty(3)
    if axis == 1:  # y = sign h, z = x cross y
        _cross(aim, h, other)
        _quat_from_frame(aim, h, other, out)
    else:  # z = sign h, y = z cross x
        _cross(h, aim, other)
        _quat_from_frame(aim, other, h, out)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _consensus(
    swung: np.ndarray, valid: np.ndarray, min_cos: float, dots: np.ndarray, support: np.ndarray, out: np.ndarray
) -> int:
    """Steps 2-3 on the views swung onto the aim, (S, 4) with ``valid`` (S,): the view with the most others within
    the agreement angle (ties: lowest index) and those views, sign-aligned, summed and normalized into ``out``.
    Returns the views averaged (0: ``out`` NaN). ``dots`` (S, S), ``support`` (S,): scratch."""
    n = swung.shape[0]
    support[:] = 0
    for s in range(n):
        if not valid[s]:
            continue
        for t in range(s + 1):
            if not valid[t]:
                continue
            dot = swung[s, 0] * swung[t, 0] + swung[s, 1] * swung[t, 1]
            dot += swung[s, 2] * swung[t, 2] + swung[s, 3] * swung[t, 3]
            dots[s, t] = dots[t, s] = dot
            if abs(dot) >= min_cos:
                support[s] += 1
                if t != s:
                    support[t] += 1
    best = 0
    best_support = 0
    for s in range(n):
        if support[s] > best_support:
            best, best_support = s, support[s]
    if best_support == 0:
        out[:] = np.nan
        return 0
    out[:] = 0.0
    for t in range(n):
        if valid[t] and abs(dots[best, t]) >= min_cos:
            weight = -1.0 if dots[best, t] < 0.0 else 1.0
            for c in range(4):
                out[c] += weight * swung[t, c]
    _normalize(out, 1e-9)
    return best_support


@numba.njit(cache=True, nogil=True, error_model="numpy")
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
    docstring).

    Returns
    -------
    quats (B, J, 4) k4abt frames (NaN = unknown), n_views (B, J) int64, state quats (B, J, 4) aim frames (zero:
    none), omega (B, J, 3) rad/s.
    """
    B, J = positions.shape[0], positions.shape[1]
    S = view_quats.shape[1]
    min_cos = math.cos(math.radians(agree_deg) / 2.0)
    out = np.empty((B, J, 4))
    n_out = np.zeros((B, J), dtype=np.int64)
    state = np.zeros((B, J, 4))
    omega_out = np.zeros((B, J, 3))
    swung = np.empty((S, 4))
    dots = np.empty((S, S))
    support = np.zeros(S, dtype=np.int64)
    scratch = np.empty(4)
    valid = np.zeros(S, dtype=np.bool_)
    aim = np.empty(3)
    prev = np.empty(4)
    turn = np.empty(4)
    predicted = np.empty(4)
    swung_prediction = np.empty(4)
    measured = np.empty(4)
    view = np.empty(4)
    residual = np.empty(3)
    omega = np.empty(3)
    corrected = np.empty(4)
    body = np.empty((3, 3))
    for b in range(B):
        p = positions[b]
        has_body = False
        for j in range(J):
            # Step 1: the aim, the unit direction of the joint's bone (NaN: derived joint or no bone).
            sign = joint_value[j, 0]
            norm = 0.0
            for c in range(3):
                aim[c] = (p[joint_index[j, 1], c] - p[joint_index[j, 0], c]) * sign
                norm += aim[c] * aim[c]
            norm = np.sqrt(norm)
            for c in range(3):
                aim[c] = aim[c] / norm if norm > 1e-6 else np.nan
            has_aim = aim[0] == aim[0]
            # The filter's prediction: exp(omega dt) * previous.
            prev[:] = quats_prev[b, j]
            _normalize(prev, 1e-9)
            has_prev = prev[0] == prev[0]
            for c in range(3):
                omega[c] = omega_prev[b, j, c] if has_prev else 0.0
            _rotvec_to_quat(omega[0] * dt_s, omega[1] * dt_s, omega[2] * dt_s, turn)
            _multiply(turn, prev, predicted)
            # Steps 2-3: the usable views swung onto the aim, their consensus.
            for s in range(S):
                # Without an aim every swing is NaN, and a view that may not contribute is never read: skip both.
                valid[s] = has_aim and usable[b, s, j]
                if not valid[s]:
                    continue
                for c in range(4):
                    view[c] = view_quats[b, s, j, c]
                if joint_index[j, 5]:
                    _multiply_conjugate(view, joint_value[j, 2:6], turn)
                    view[:] = turn
                _swing_onto(view, aim, scratch, swung[s])
                valid[s] = swung[s, 0] == swung[s, 0]
            n_views = _consensus(swung, valid, min_cos, dots, support, measured)
            has_meas = measured[0] == measured[0]
            _swing_onto(predicted, aim, scratch, swung_prediction)
            if has_aim:  # the prediction follows this frame's bone; without one it coasts on the rotation
                predicted[:] = swung_prediction
            # Step 4: correct by alpha of the residual rotation (a twist about the shared aim).
            _multiply_conjugate(measured, predicted, turn)
            _quat_to_rotvec(turn, residual)
            _rotvec_to_quat(alpha * residual[0], alpha * residual[1], alpha * residual[2], turn)
            _multiply(turn, predicted, corrected)
            _normalize(corrected, 1e-9)
            q = out[b, j]
            if has_meas and has_prev:
                q[:] = corrected
                for c in range(3):
                    omega_out[b, j, c] = omega[c] + (beta / dt_s) * residual[c]
            elif has_meas:
                q[:] = measured
            elif has_prev:
                q[:] = predicted
                omega_out[b, j] = omega
            elif has_aim:  # step 5: no view, no history: the twist from the body's own frame
                if not has_body:
                    _body_directions(p, body_joints, body)
                    has_body = True
                _hint_frame(aim, body[joint_index[j, 4]], joint_index[j, 3], joint_value[j, 1], q)
            if not (has_aim or has_prev):
                q[:] = np.nan
            n_out[b, j] = n_views if has_meas else 0
            located = np.isfinite(p[j, 0] + p[j, 1] + p[j, 2])
            for c in range(4):
                state[b, j, c] = q[c] if located and q[c] == q[c] else 0.0
            for c in range(3):
                if not np.isfinite(omega_out[b, j, c]):
                    omega_out[b, j, c] = 0.0
            # The aim frame to the tracker's joint frame (the ankles: times their offset).
            if joint_index[j, 5]:
                _multiply(q, joint_value[j, 2:6], turn)
                q[:] = turn
        # Derived joints (hand tips, feet, face): their source joint's frame times a fixed offset.
        for j in range(J):
            if joint_index[j, 6]:
                _multiply(out[b, joint_index[j, 2]], joint_value[j, 6:10], out[b, j])
        for j in range(J):
            if not np.isfinite(p[j, 0] + p[j, 1] + p[j, 2]):
                out[b, j] = np.nan
    return out, n_out, state, omega_out


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
