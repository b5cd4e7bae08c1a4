"""The numpy form of the orientation stage: the test reference of
:func:`skelfuse.fusion.orientation.fuse_orientations` (the live path runs :mod:`skelfuse.fusion.kernels.orientation`
and never imports this module). The rules are documented in :mod:`skelfuse.fusion.orientation`.

Component-major throughout: a quaternion array is laid out (4, ...) and a vector array (3, ...), so that every
elementwise step runs over one contiguous row per component, and a bilinear product is one broadcast outer product
of rows plus one (n_out, n_a * n_b) matrix product (:func:`skelfuse.fusion.orientation._rows_bilinear`).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from skelfuse.fusion.orientation import (
    _AIM_FROM,
    _AIM_SIGN,
    _AIM_TO,
    _DERIVED,
    _DERIVED_SOURCE,
    _OFFSET,
    _QMUL_CONJ_ROWS,
    _QMUL_ROWS,
    OrientationParams,
    OrientationResult,
    _aim_hint_frames,
    _product_table,
    _rows_bilinear,
    _rows_quat_to_rotvec,
    _rows_rotvec_to_quat,
    _table_rows,
    swing_between,
)
from skelfuse.schema.skeleton import N_JOINTS, ORIENTATION_AIM_OFFSET, ORIENTATION_AIMED, ORIENTATION_DERIVED_OFFSET

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
