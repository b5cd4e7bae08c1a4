"""Zero-lag smoothing of a recording: a Rauch-Tung-Striebel smoother over the live filter's motion model.

The live filter (:func:`skelfuse.fusion.filters.filter_step`, "cv_kalman") is causal: every output uses the
frames up to now, so it trades smoothness for lag. A recording has the frames after each instant too. This
module runs the *same* forward filter over the merged measurements of a track (so the forward pass equals
the live output to the last bit) and then the RTS backward pass over it (Rauch, Tung and Striebel 1965; the
form of ``filterpy.kalman.KalmanFilter.rts_smoother``), per joint:

    C_t  = P_t F' (P~_{t+1})^-1
    xs_t = x_t + C_t (xs_{t+1} - x~_{t+1})

where ``x_t, P_t`` are the filtered state and covariance and ``x~_{t+1}, P~_{t+1}`` the prediction of the next
frame. The backward pass never crosses a track start (the first frame of a joint's track, or a restart of the
plausibility stage's follow rule): a segment is smoothed on its own. Frames without a measurement inside a
segment (a gap of at most ``max_coast_frames``) get the smoothed interpolation; the live filter had only a
prediction there.

The white-noise acceleration of the live model suits everyday motion but rounds off a jump's take-off and
landing (smoothed in both directions, the error's second difference grows as the view noise's falls). The
offline default therefore runs a second, adaptive pass: per axis, with the process noise raised where the
first pass saw hard acceleration (:func:`adaptive_accel_sigma`); elsewhere the model is the live one. A third
pass then smooths the measurements again with an acceleration state, its jerk noise set from the second pass's
motion (:mod:`skelfuse.fusion.jerk_smoother`): a flight or a swing at steady acceleration needs no process noise
there, so it keeps the jump's shape while it removes more of the views' jitter.

:func:`fixed_lag_smooth` gives the estimate of every frame from the frames up to ``lag`` later (the live
option: ``lag`` frames of added latency), with a causal form of the adaptive pass: per axis, its process noise
set by the live filter's own velocity changes in the frames up to then (:func:`causal_accel_sigma`), so a jump
is followed within the lag while still motion is smoothed as the live model smooths it. A lag as long as the
segment gives the fixed-interval constant-velocity smoother with that noise (the offline default's third pass,
an acceleration state, needs the frames after the lag). :class:`FixedLagSmoother` gives the same instant by
instant, for the live node.

Pure numpy, vectorized over joints; one Python step per frame (a take is thousands of frames, not millions).
Only the "cv_kalman" filter has a velocity state worth smoothing; other filters are rejected.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from skelfuse.fusion.filters import _cv_model, filter_step, init_filter_state
from skelfuse.fusion.jerk_smoother import jerk_sigma, jerk_smooth
from skelfuse.fusion.presets import FusionParams

ADAPTIVE_GAIN = 1.5
"""Process noise per unit of first-pass acceleration (see :func:`adaptive_accel_sigma`; chosen on the training
seeds of ``scripts/smoothing_targets.py``)."""
ADAPTIVE_SPREAD = 5
"""Frames on either side over which a first-pass acceleration sets the process noise."""

SMOOTHERS: tuple[str, ...] = ("rts", "none")
"""Offline smoother names: the fixed-interval RTS smoother, or the live filter's own output."""


@dataclass(frozen=True)
class ForwardPass:
    """The live filter over a sequence, with what the backward pass needs.

    Attributes
    ----------
    out : (T, N, 3) the live filter's output (NaN = no estimate).
    x : (T, N, 2, 3) filtered state; P : (T, N, 3) filtered covariance triangle (p00, p01, p11).
    x_pred : (T, N, 2, 3) and P_pred : (T, N, 3), the prediction of frame t from frame t - 1.
    linked : (T, N) bool, frame t continues frame t - 1's track (the backward pass may cross into t - 1).
    """

    out: np.ndarray
    x: np.ndarray
    P: np.ndarray
    x_pred: np.ndarray
    P_pred: np.ndarray
    linked: np.ndarray


def forward_pass(
    z: np.ndarray,
    n_agree: np.ndarray,
    dt_s: np.ndarray,
    restart: np.ndarray,
    params: FusionParams,
    *,
    accel_sigma: np.ndarray | None = None,
) -> ForwardPass:
    """Run :func:`filter_step` frame by frame over one track's merged measurements.

    Parameters
    ----------
    z : (T, N, 3) mm, merged positions (NaN = no measurement); n_agree : (T, N) views behind each.
    dt_s : (T,) seconds since the previous frame (dt_s[0] is not used).
    restart : (T,) bool, the live fusion restarted the track's filter at frame t (plausibility follow rule).
    params : FusionParams with ``filter == "cv_kalman"``.
    accel_sigma : None for the live filter exactly; else (T, N) the white-noise acceleration of the step into
        frame t per joint, mm/s^2; below ``params.cv_accel_sigma_mm_s2`` counts as it (see
        :func:`adaptive_accel_sigma`).
    """
    if params.filter != "cv_kalman":
        raise ValueError(f"the RTS smoother needs the cv_kalman filter's motion model, got filter={params.filter!r}")
    z = np.asarray(z, dtype=np.float64)
    T, N, _ = z.shape
    track = _TrackFilter(*init_filter_state(N))
    rows = [
        track.step(
            z[t],
            n_agree[t],
            bool(restart[t]),
            float(dt_s[t]) if t else FIRST_DT_S,
            params,
            None if accel_sigma is None else accel_sigma[t],
        )
        for t in range(T)
    ]
    return _stacked(rows, N)


def _stacked(rows: list[tuple[np.ndarray, ...]], n_joints: int) -> ForwardPass:
    """The :class:`ForwardPass` of ``rows`` ((out, x, P, x_pred, P_pred, linked) per frame)."""
    if not rows:
        vectors, triangles = np.zeros((0, n_joints, 2, 3)), np.zeros((0, n_joints, 3))
        return ForwardPass(triangles, vectors, triangles, vectors, triangles, np.zeros((0, n_joints), bool))
    out, x, P, x_pred, P_pred, linked = (np.stack(column) for column in zip(*rows, strict=True))
    return ForwardPass(out=out, x=x, P=P, x_pred=x_pred, P_pred=P_pred, linked=linked)


FIRST_DT_S = 1.0 / 30.0
"""The time step given to a track's first frame (the filter starts there: it predicts nothing with it)."""


@dataclass
class _TrackFilter:
    """The live filter's state of one track: position/velocity ``x`` (N, 2, 3), covariance ``P`` (N, 3) and
    ``coast`` (N,), as :func:`filter_step` carries them."""

    x: np.ndarray
    P: np.ndarray
    coast: np.ndarray

    def step(
        self,
        z: np.ndarray,
        n_agree: np.ndarray,
        restart: bool,
        dt: float,
        params: FusionParams,
        accel_sigma: np.ndarray | None = None,
    ) -> tuple[np.ndarray, ...]:
        """One frame: the row (out, x, P, x_pred, P_pred, linked) of :class:`ForwardPass` it adds;
        ``accel_sigma`` (N,): the step's process noise per joint where it is not the live model's."""
        coast_in = np.where(restart, -1, self.coast)
        if accel_sigma is not None:
            self.P = self.P + _extra_process_noise(accel_sigma, params.cv_accel_sigma_mm_s2, dt)
        cov_map, q_vec, state_map = _cv_model(dt, params.cv_accel_sigma_mm_s2)
        x_pred, P_pred = state_map @ self.x, self.P @ cov_map + q_vec  # x~ = F x;  P~ = F P F' + Q
        z = np.asarray(z, dtype=np.float64)
        out, self.x, self.P, self.coast = filter_step(
            self.x, self.P, coast_in, z, np.asarray(n_agree).astype(np.int16), params, dt
        )
        linked = (coast_in >= 0) & (self.coast >= 0)
        return out, self.x, self.P, x_pred, P_pred, linked


def _extra_process_noise(accel_sigma: np.ndarray, base: float, dt: float) -> np.ndarray:
    """(N, 3) covariance triangle E with F E F' = Q(sigma) - Q(base): added to P before the live filter's own
    prediction, it turns that prediction's Q into the white-noise acceleration Q of ``accel_sigma`` per joint.

    Q(s) = s^2 [dt^4/4, dt^3/2, dt^2] and F^-1 Q F'^-1 = s^2 [dt^4/4, -dt^3/2, dt^2] (rank one, positive
    semi-definite), so E is that with s^2 the difference of the variances.
    """
    extra = np.maximum(np.asarray(accel_sigma, dtype=np.float64) ** 2 - base**2, 0.0)
    return extra[:, None] * np.array([dt**4 / 4.0, -(dt**3) / 2.0, dt * dt])


def adaptive_accel_sigma(
    states: np.ndarray,
    linked: np.ndarray,
    dt_s: np.ndarray,
    base: float,
    gain: float = ADAPTIVE_GAIN,
    spread: int = ADAPTIVE_SPREAD,
) -> np.ndarray:
    """(T, N, 3) per-frame, per-axis process noise from a first smoothing pass, mm/s^2.

    Where the motion accelerates hard (a jump's take-off, flight and landing), the white-noise acceleration
    rises to ``gain`` times the acceleration the first pass saw on that axis, so the second pass follows the
    motion instead of rounding it off; in still and slow motion it stays ``base`` and smooths as before.

    ``states`` : (T, N, 2, 3) smoothed position and velocity (mm, mm/s); ``linked`` : (T, N) frame t continues
    frame t - 1's track (:class:`ForwardPass`). The acceleration of frame t is the velocity change into it (0 at
    a track's start); each frame takes the largest within ``spread`` frames (the first pass spreads a sharp
    change over its neighbours, and the noise must cover the whole span of the change).
    """
    padded = np.pad(_velocity_changes(states, linked, dt_s), ((spread, spread), (0, 0), (0, 0)), mode="edge")
    nearby = np.lib.stride_tricks.sliding_window_view(padded, 2 * spread + 1, axis=0).max(axis=-1)
    return np.maximum(base, gain * nearby)


def _velocity_changes(states: np.ndarray, linked: np.ndarray, dt_s: np.ndarray) -> np.ndarray:
    """(T, N, 3) |velocity change into frame t| / dt per axis, mm/s^2; 0 at a track's start and where unknown."""
    accel = np.zeros((*states.shape[:2], 3))
    dt = np.asarray(dt_s, dtype=np.float64)[1:, None, None]
    accel[1:] = np.where(linked[1:, :, None], np.abs(np.diff(states[:, :, 1], axis=0)) / dt, 0.0)
    return np.nan_to_num(accel, nan=0.0)


def _gain(P: np.ndarray, P_pred: np.ndarray, dt: float) -> np.ndarray:
    """(N, 2, 2) RTS gain C = P F' (P~)^-1 from the covariance triangles (p00, p01, p11), entry by entry (a
    2 x 2 product: the per-joint arrays are short, so building stacked matrices would cost more than it)."""
    a, b, c = P[:, 0], P[:, 1], P[:, 2]
    p, q, r = P_pred[:, 0], P_pred[:, 1], P_pred[:, 2]
    det = p * r - q * q
    det = np.where(det > 0, det, np.inf)  # a degenerate prediction gives no correction
    i00, i01, i11 = r / det, -q / det, p / det  # (P~)^-1, symmetric
    f00, f10 = a + b * dt, b + c * dt  # P F' = [[f00, b], [f10, c]]
    gain = np.empty((len(P), 2, 2))
    gain[:, 0, 0] = f00 * i00 + b * i01
    gain[:, 0, 1] = f00 * i01 + b * i11
    gain[:, 1, 0] = f10 * i00 + c * i01
    gain[:, 1, 1] = f10 * i01 + c * i11
    return gain


def _backward_step(fwd: ForwardPass, t: int, later: np.ndarray, dt: float) -> np.ndarray:
    """xs_t from xs_{t+1} (``later``, (N, 2, 3)); frames not linked to t + 1 keep their filtered state."""
    gain = _gain(fwd.P[t], fwd.P_pred[t + 1], dt)
    smoothed = fwd.x[t] + gain @ (later - fwd.x_pred[t + 1])
    return np.where(fwd.linked[t + 1][:, None, None], smoothed, fwd.x[t])


def rts_smooth(
    z: np.ndarray,
    n_agree: np.ndarray,
    dt_s: np.ndarray,
    restart: np.ndarray,
    params: FusionParams,
    *,
    adaptive: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-interval smoothing of one track (see the module docstring).

    ``adaptive``: a second pass, per axis, whose process noise follows the first pass's accelerations
    (:func:`adaptive_accel_sigma`), then the constant-acceleration pass whose jerk noise follows the second
    pass's motion (:func:`~skelfuse.fusion.jerk_smoother.jerk_smooth`): a jump or a foot strike is followed, not
    rounded off, while still and slow motion is smoothed harder than the live model can.

    Returns
    -------
    smoothed : (T, N, 3) mm, NaN where the live filter had no estimate.
    causal : (T, N, 3) mm, the live filter's own output (the first forward pass), for comparison.
    """
    fwd = forward_pass(z, n_agree, dt_s, restart, params)
    states = backward_pass(fwd, dt_s)
    positions = states[:, :, 0]
    if adaptive:
        sigma = adaptive_accel_sigma(states, fwd.linked, dt_s, params.cv_accel_sigma_mm_s2)
        positions = smooth_per_axis(z, n_agree, dt_s, restart, params, sigma)
        jerk = jerk_sigma(positions, fwd.linked, dt_s)
        positions = jerk_smooth(z, n_agree, dt_s, fwd.linked, params, jerk)
    return np.where(np.isfinite(fwd.out), positions, np.nan), fwd.out


def smooth_per_axis(
    z: np.ndarray,
    n_agree: np.ndarray,
    dt_s: np.ndarray,
    restart: np.ndarray,
    params: FusionParams,
    accel_sigma: np.ndarray,
    lag: int | None = None,
) -> np.ndarray:
    """(T, N, 3) smoothed positions with the process noise ``accel_sigma`` (T, N, 3, mm/s^2) of each step into
    frame t, per joint and axis (NaN where the filter had no estimate): fixed-interval (``lag`` None) or from
    the frames up to t + ``lag``."""
    fwd = _per_axis_forward(z, n_agree, dt_s, restart, params, accel_sigma)
    smoothed = backward_pass(fwd, dt_s)[:, :, 0] if lag is None else _fixed_lag_positions(fwd, dt_s, int(lag))
    positions = np.where(np.isfinite(fwd.out[:, :, 0]), smoothed[:, :, 0], np.nan)
    return positions.reshape(np.shape(z))


def _per_axis_forward(
    z: np.ndarray,
    n_agree: np.ndarray,
    dt_s: np.ndarray,
    restart: np.ndarray,
    params: FusionParams,
    accel_sigma: np.ndarray,
) -> ForwardPass:
    """The forward pass over (T, 3N) pseudo-joints, one per coordinate, with ``accel_sigma`` (T, N, 3).

    The live filter shares one covariance by the three axes of a joint; a jump accelerates up and down, not
    sideways, so here each coordinate is a joint of its own (its value in all three columns; column 0 read).
    """
    z = np.asarray(z, dtype=np.float64)
    T, N, _ = z.shape
    coords = np.repeat(z.reshape(T, 3 * N, 1), 3, axis=2)
    agree = np.repeat(np.asarray(n_agree), 3, axis=1)
    return forward_pass(coords, agree, dt_s, restart, params, accel_sigma=np.reshape(accel_sigma, (T, 3 * N)))


def backward_pass(fwd: ForwardPass, dt_s: np.ndarray) -> np.ndarray:
    """(T, N, 2, 3) the smoothed states of a whole forward pass."""
    states = fwd.x.copy()
    for t in range(len(states) - 2, -1, -1):
        states[t] = _backward_step(fwd, t, states[t + 1], float(dt_s[t + 1]))
    return states


def fixed_lag_smooth(
    z: np.ndarray,
    n_agree: np.ndarray,
    dt_s: np.ndarray,
    restart: np.ndarray,
    params: FusionParams,
    lag: int,
) -> np.ndarray:
    """(T, N, 3) the estimate of each frame t from the frames up to t + ``lag`` (NaN where no estimate).

    Per axis, with the process noise of :func:`causal_accel_sigma` (from the frames up to t only: it adds no
    latency), smoothed backward from frame t + ``lag``. Frames within ``lag`` of the end use what there is (the
    end of a take is the end of the data).
    """
    if int(lag) < 0:
        raise ValueError(f"lag must be >= 0 frames, got {lag!r}")
    fwd = forward_pass(z, n_agree, dt_s, restart, params)
    sigma = causal_accel_sigma(fwd, dt_s, params.cv_accel_sigma_mm_s2)
    positions = smooth_per_axis(z, n_agree, dt_s, restart, params, sigma, int(lag))
    return np.where(np.isfinite(fwd.out), positions, np.nan)


def _fixed_lag_positions(fwd: ForwardPass, dt_s: np.ndarray, lag: int) -> np.ndarray:
    """(T, N, 3) the position of each frame t smoothed from the frames up to t + ``lag``."""
    T = fwd.out.shape[0]
    result = fwd.x[:, :, 0].copy()
    for t in range(T):
        result[t] = _smoothed_from(fwd, dt_s, t, min(t + lag, T - 1))
    return result


def _smoothed_from(fwd: ForwardPass, dt_s: np.ndarray, t: int, end: int) -> np.ndarray:
    """(N, 3) the position of frame ``t`` smoothed backward from the filtered state of frame ``end``."""
    state = fwd.x[end]
    for k in range(end - 1, t - 1, -1):
        state = _backward_step(fwd, k, state, float(dt_s[k + 1]))
    return state[:, 0]


def causal_accel_sigma(
    fwd: ForwardPass, dt_s: np.ndarray, base: float, gain: float = ADAPTIVE_GAIN, spread: int = ADAPTIVE_SPREAD
) -> np.ndarray:
    """(T, N, 3) the process noise of :func:`adaptive_accel_sigma` from the live filter's own velocities, and
    for each frame from the ``spread`` frames before it only: what a live fixed-lag smoother knows in time."""
    accel = _velocity_changes(fwd.x, fwd.linked, dt_s)
    padded = np.pad(accel, ((spread, 0), (0, 0), (0, 0)), mode="edge")
    before = np.lib.stride_tricks.sliding_window_view(padded, spread + 1, axis=0).max(axis=-1)
    return np.maximum(base, gain * before)


def smooth_tracks(
    times_s: np.ndarray,
    track_ids: list[np.ndarray],
    merged: list[np.ndarray],
    n_agree: list[np.ndarray],
    restarted: list[np.ndarray | None],
    params: FusionParams,
    lag: int | None = None,
) -> list[np.ndarray]:
    """Smooth every track of a fused take, instant by instant as the live fusion gave them.

    Parameters
    ----------
    times_s : (T,) the instants' times, s (increasing).
    track_ids : per instant, (P_t,) the persons' track ids (a track appears in every instant from its
        confirmation to its death).
    merged : per instant, (P_t, J, 3) the merged positions before the filter, mm.
    n_agree : per instant, (P_t, J) the views behind them.
    restarted : per instant, (P_t,) bool or None, the follow rule restarted the person's filter.
    params : the FusionParams of the live fusion ("cv_kalman").
    lag : None for the fixed-interval smoother with its adaptive pass (:func:`rts_smooth`), else the fixed lag
        in frames (:func:`fixed_lag_smooth`, what the live option gives).

    Returns
    -------
    per instant, (P_t, J, 3) the smoothed positions in the instant's person order (NaN where the live filter
    had no estimate).
    """
    times_s = np.asarray(times_s, dtype=np.float64)
    out = [np.full(np.shape(m), np.nan) for m in merged]
    rows: dict[int, list[tuple[int, int]]] = {}
    for t, ids in enumerate(track_ids):
        for row, track_id in enumerate(np.asarray(ids).tolist()):
            rows.setdefault(int(track_id), []).append((t, row))
    for where in rows.values():
        instants = np.array([t for t, _ in where])
        z = np.stack([merged[t][row] for t, row in where])
        agree = np.stack([n_agree[t][row] for t, row in where])
        restart = np.array([_restarted_at(restarted[t], row) for t, row in where])
        dt = np.diff(times_s[instants], prepend=times_s[instants[0]] - 1.0 / 30.0)
        if lag is None:
            smoothed, _ = rts_smooth(z, agree, dt, restart, params, adaptive=True)
        else:
            smoothed = fixed_lag_smooth(z, agree, dt, restart, params, lag)
        for k, (t, row) in enumerate(where):
            out[t][row] = smoothed[k]
    return out


def _restarted_at(restarted: np.ndarray | None, row: int) -> bool:
    """Whether the follow rule restarted row ``row``'s filter at this instant (None: no plausibility stage)."""
    return restarted is not None and bool(restarted[row])


class _AdaptiveTrack:
    """One live track for :class:`FixedLagSmoother`: the steps of :func:`fixed_lag_smooth`, one frame at a time.

    Per frame: the live filter's step (its velocity change into the frame, over the last ``ADAPTIVE_SPREAD``
    frames, sets that frame's per-axis process noise as :func:`causal_accel_sigma` does), then the per-axis
    filter's step with that noise (:func:`_per_axis_forward`'s pseudo-joints). The per-axis rows of the frames
    not yet released are kept for the backward steps.
    """

    def __init__(self, n_joints: int, time_s: float, params: FusionParams) -> None:
        self.params = params
        self.live = _TrackFilter(*init_filter_state(n_joints))
        self.per_axis = _TrackFilter(*init_filter_state(3 * n_joints))
        self.last_time_s = time_s
        self.velocity_changes: deque[np.ndarray] = deque(maxlen=ADAPTIVE_SPREAD + 1)  # (N, 3) mm/s^2 each
        self.instants: list[int] = []  # the instant of each kept row, increasing
        self.rows: list[tuple[np.ndarray, ...]] = []  # the per-axis (out, x, P, x_pred, P_pred, linked) per row
        self.live_out: list[np.ndarray] = []  # (N, 3) the live filter's output per row (NaN: no estimate)
        self.dt_s: list[float] = []

    def step(self, instant: int, time_s: float, z: np.ndarray, agree: np.ndarray, restart: bool) -> None:
        """Add frame ``instant`` of the track (z (N, 3) mm, agree (N,), restart as :func:`forward_pass`)."""
        dt = time_s - self.last_time_s if self.velocity_changes else FIRST_DT_S
        previous = self.live.x
        out, x, _, _, _, linked = self.live.step(z, agree, restart, dt, self.params)  # linked: False at the start
        self.velocity_changes.append(
            _velocity_changes(np.stack([previous, x]), np.stack([linked, linked]), np.full(2, dt))[1]
        )
        base = self.params.cv_accel_sigma_mm_s2
        sigma = np.maximum(base, ADAPTIVE_GAIN * np.max(np.stack(self.velocity_changes), axis=0))
        coords = np.repeat(np.asarray(z, dtype=np.float64).reshape(-1, 1), 3, axis=1)
        self.rows.append(self.per_axis.step(coords, np.repeat(agree, 3), restart, dt, self.params, sigma.reshape(-1)))
        self.live_out.append(out)
        self.instants.append(instant)
        self.dt_s.append(dt)
        self.last_time_s = time_s

    def release(self, instant: int) -> np.ndarray:
        """(N, 3) frame ``instant`` smoothed backward from the newest frame; the frames up to it are dropped."""
        n_joints = len(self.live_out[0])
        fwd = _stacked(self.rows, 3 * n_joints)
        t = self.instants.index(instant)
        smoothed = _smoothed_from(fwd, np.asarray(self.dt_s), t, len(self.rows) - 1)[:, 0]
        alive = np.isfinite(fwd.out[t][:, 0]).reshape(n_joints, 3) & np.isfinite(self.live_out[t])
        positions = np.where(alive, smoothed.reshape(n_joints, 3), np.nan)
        for kept in (self.instants, self.rows, self.live_out, self.dt_s):
            del kept[: t + 1]  # never needed again
        return positions


class FixedLagSmoother:
    """Fixed-lag smoothing of the live tracks, instant by instant: the live fusion's instants in, each one
    back ``lag`` instants later, smoothed by the frames up to then.

    Per track it runs :func:`fixed_lag_smooth`'s steps frame by frame (the live filter, the process noise its
    velocity changes set, the per-axis filter with that noise; :class:`_AdaptiveTrack`) and keeps the frames
    not yet released; an instant is released once ``lag`` more instants arrived, each of its tracks smoothed
    backward from its newest frame. The result is :func:`fixed_lag_smooth` (through :func:`smooth_tracks`)
    over the same stream, frame for frame:

    - a new track starts its own window (the backward pass never crosses a track start or a restart);
    - a track that ends (absent from an instant: ids are never reused) has its last frames smoothed from
      what there is, its last frame included: its tail is flushed, not dropped;
    - frames inside a track without a measurement (coasting, up to ``max_coast_frames``) get the smoothed
      interpolation, as offline; a gap between instants only lengthens the time step;
    - :meth:`flush` releases the instants still held (the end of the stream), smoothed from what there is.
    """

    def __init__(self, params: FusionParams, lag: int) -> None:
        if params.filter != "cv_kalman":
            raise ValueError(f"fixed-lag smoothing needs the cv_kalman filter's motion model, got {params.filter!r}")
        if int(lag) < 1:
            raise ValueError(f"the fixed lag must be at least 1 frame, got {lag!r}")
        self.params = params
        self.lag = int(lag)
        self._tracks: dict[int, _AdaptiveTrack] = {}
        self._held: list[tuple[int, np.ndarray, tuple[int, ...]]] = []  # (instant, track ids, positions' shape)
        self._count = 0

    def push(
        self,
        time_s: float,
        track_ids: np.ndarray,
        merged: np.ndarray,
        n_agree: np.ndarray,
        restarted: np.ndarray | None,
    ) -> np.ndarray | None:
        """Add one instant (as :func:`smooth_tracks` takes it); return the smoothed (P, J, 3) positions of the
        instant ``lag`` instants back, in its track order, or None while fewer have arrived."""
        instant = self._count
        self._count += 1
        for row, track_id in enumerate(np.asarray(track_ids).tolist()):
            track = self._tracks.get(int(track_id))
            if track is None:
                track = self._tracks[int(track_id)] = _AdaptiveTrack(np.shape(merged)[1], float(time_s), self.params)
            track.step(instant, float(time_s), merged[row], n_agree[row], _restarted_at(restarted, row))
        self._held.append((instant, np.asarray(track_ids), np.shape(merged)))
        return self._release() if len(self._held) > self.lag else None

    def flush(self) -> list[np.ndarray]:
        """The instants still held, oldest first, each smoothed from what there is."""
        return [self._release() for _ in range(len(self._held))]

    def _release(self) -> np.ndarray:
        instant, ids, shape = self._held.pop(0)
        out = np.full(shape, np.nan)
        for row, track_id in enumerate(ids.tolist()):
            out[row] = self._tracks[int(track_id)].release(instant)
        # A track without frames left ended at or before this instant (a live one has a frame in every later one).
        for track_id in [k for k, track in self._tracks.items() if not track.instants]:
            del self._tracks[track_id]
        return out
