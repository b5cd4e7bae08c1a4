"""The RTS smoother against filterpy's, its fixed-lag form, and what it does to jitter and lag."""

from dataclasses import replace

import numpy as np
import pytest
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter

from skelfuse.fusion import preset
from skelfuse.fusion.jerk_smoother import ACCEL0_SIGMA_MM_S2, JERK_BASE_MM_S3, jerk_sigma, jerk_smooth
from skelfuse.fusion.smoother import (
    FixedLagSmoother,
    adaptive_accel_sigma,
    backward_pass,
    causal_accel_sigma,
    fixed_lag_smooth,
    forward_pass,
    rts_smooth,
    smooth_per_axis,
    smooth_tracks,
)

SEED = 1965
PARAMS = preset("skelfuse")
DT = 1.0 / 30.0


def _filterpy_rts(z: np.ndarray, r: float, params) -> np.ndarray:
    """One axis through filterpy's KalmanFilter and rts_smoother, started as the live filter starts a track."""
    kf = KalmanFilter(dim_x=2, dim_z=1)
    kf.F = np.array([[1.0, DT], [0.0, 1.0]])
    kf.H = np.array([[1.0, 0.0]])
    kf.R = np.array([[r]])
    kf.Q = Q_discrete_white_noise(2, DT, params.cv_accel_sigma_mm_s2**2)
    kf.x = np.array([[z[0]], [0.0]])
    kf.P = np.diag([params.cv_meas_sigma_mm**2, params.cv_velocity0_sigma_mm_s**2])
    means, covs = [kf.x.copy()], [kf.P.copy()]
    for value in z[1:]:
        kf.predict()
        kf.update(np.array([[value]]))
        means.append(kf.x.copy())
        covs.append(kf.P.copy())
    smoothed, _, _, _ = kf.rts_smoother(np.array(means), np.array(covs))
    return smoothed[:, 0, 0]


def test_rts_equals_filterpy():
    rng = np.random.default_rng(SEED)
    T = 90
    truth = 300.0 * np.sin(np.linspace(0.0, 6.0, T))[:, None, None] + np.zeros((T, 2, 3))
    z = truth + rng.normal(0.0, 10.0, truth.shape)
    n_agree = np.full((T, 2), 2)
    smoothed, causal = rts_smooth(z, n_agree, np.full(T, DT), np.zeros(T, bool), PARAMS)
    r = PARAMS.cv_meas_sigma_mm**2 / 2  # R divided by the two agreeing views
    for joint in range(2):
        for axis in range(3):
            want = _filterpy_rts(z[:, joint, axis], r, PARAMS)
            np.testing.assert_allclose(smoothed[:, joint, axis], want, rtol=0, atol=1e-8)
    assert causal.shape == smoothed.shape


def test_segments_are_smoothed_apart_and_short_gaps_filled():
    rng = np.random.default_rng(SEED + 1)
    T = 60
    z = 100.0 + rng.normal(0.0, 10.0, (T, 1, 3))
    z[20:23] = np.nan  # a 3-frame gap inside a segment: filled
    z[40:] += 1000.0  # a restart at 40: the frames before know nothing of it
    restart = np.zeros(T, bool)
    restart[40] = True
    smoothed, causal = rts_smooth(z, np.ones((T, 1)), np.full(T, DT), restart, PARAMS)
    assert np.isfinite(smoothed[20:23]).all()
    assert np.abs(smoothed[:40] - 100.0).max() < 40.0  # the jump at 40 does not leak backwards
    # The segment before the restart is smoothed as if the take ended at 39.
    alone, _ = rts_smooth(z[:40], np.ones((40, 1)), np.full(40, DT), restart[:40], PARAMS)
    np.testing.assert_allclose(smoothed[:40], alone, rtol=0, atol=1e-9)
    np.testing.assert_allclose(smoothed[-1], causal[-1], rtol=0, atol=1e-12)  # the last frame: nothing later


def test_fixed_lag_spans_causal_to_full():
    # Per axis, with the process noise the live filter's velocity changes set: a lag of 0 is that filter, a lag
    # as long as the take its fixed-interval smoother (filterpy's filter and smoother with the same per-step Q).
    rng = np.random.default_rng(SEED + 2)
    T = 50
    z = np.cumsum(rng.normal(0.0, 5.0, (T, 3, 3)), axis=0)
    z[20:26, 1] += 120.0  # a joint that jumps away and back: the noise rises there
    args = (z, np.ones((T, 3)), np.full(T, DT), np.zeros(T, bool), PARAMS)
    sigma = causal_accel_sigma(forward_pass(*args), np.full(T, DT), PARAMS.cv_accel_sigma_mm_s2)
    assert (sigma > PARAMS.cv_accel_sigma_mm_s2).any() and (sigma == PARAMS.cv_accel_sigma_mm_s2).any()
    causal, full = fixed_lag_smooth(*args, lag=0), fixed_lag_smooth(*args, lag=T)
    for joint in range(3):
        for axis in range(3):
            want_full, want_causal = _filterpy_varying_q(
                z[:, joint, axis], PARAMS.cv_meas_sigma_mm**2, sigma[:, joint, axis], PARAMS
            )
            np.testing.assert_allclose(causal[:, joint, axis], want_causal, rtol=0, atol=1e-7)
            np.testing.assert_allclose(full[:, joint, axis], want_full, rtol=0, atol=1e-7)
    lag3 = fixed_lag_smooth(*args, lag=3)
    np.testing.assert_allclose(lag3[-4:], full[-4:], rtol=0, atol=1e-9)  # the end: as much as there is
    assert not np.allclose(lag3[:-4], full[:-4]) and not np.allclose(lag3[:-4], causal[:-4])


def test_only_the_constant_velocity_model_is_smoothed():
    with pytest.raises(ValueError, match="cv_kalman"):
        forward_pass(np.zeros((3, 1, 3)), np.ones((3, 1)), np.full(3, DT), np.zeros(3, bool), preset("A5"))


def test_smoothing_removes_jitter_without_lag():
    # A 1 Hz sine seen with white jitter: the smoother's error is well below the causal filter's, and its
    # cross-correlation with the truth peaks at zero lag.
    rng = np.random.default_rng(SEED + 3)
    T = 300
    t = np.arange(T) * DT
    truth = 200.0 * np.sin(2 * np.pi * t)[:, None, None] * np.ones((T, 1, 3))
    z = truth + rng.normal(0.0, 8.0, truth.shape)
    params = replace(PARAMS, cv_scale_r_by_agree=False)
    smoothed, causal = rts_smooth(z, np.ones((T, 1)), np.full(T, DT), np.zeros(T, bool), params)
    rms = lambda a: float(np.sqrt(np.mean((a[30:-30] - truth[30:-30]) ** 2)))  # noqa: E731
    assert rms(smoothed) < 0.8 * rms(causal)
    shifts = range(-3, 4)
    errors = [rms(np.roll(smoothed, s, axis=0)) for s in shifts]
    assert shifts[int(np.argmin(errors))] == 0


def test_the_command_line_offers_the_smoothers_there_are():
    from skelfuse.cli.common import OFFLINE_SMOOTHERS
    from skelfuse.fusion.smoother import SMOOTHERS

    assert tuple(OFFLINE_SMOOTHERS) == tuple(SMOOTHERS)


def _filterpy_varying_q(z: np.ndarray, r: float, sigmas: np.ndarray, params) -> tuple[np.ndarray, np.ndarray]:
    """One axis through filterpy with the white-noise acceleration ``sigmas[t]`` for the step into frame t:
    (smoothed, filtered) positions."""
    kf = KalmanFilter(dim_x=2, dim_z=1)
    kf.F = np.array([[1.0, DT], [0.0, 1.0]])
    kf.H = np.array([[1.0, 0.0]])
    kf.R = np.array([[r]])
    kf.x = np.array([[z[0]], [0.0]])
    kf.P = np.diag([params.cv_meas_sigma_mm**2, params.cv_velocity0_sigma_mm_s**2])
    qs = np.stack([Q_discrete_white_noise(2, DT, s**2) for s in sigmas])
    means, covs = [kf.x.copy()], [kf.P.copy()]
    for t in range(1, len(z)):
        kf.predict(Q=qs[t])
        kf.update(np.array([[z[t]]]))
        means.append(kf.x.copy())
        covs.append(kf.P.copy())
    smoothed, _, _, _ = kf.rts_smoother(np.array(means), np.array(covs), Qs=qs)
    return smoothed[:, 0, 0], np.array(means)[:, 0, 0]


def test_per_axis_process_noise_equals_filterpy():
    # Each axis with its own process noise, changing frame by frame: filterpy's filter and smoother with the
    # same per-step Q are the reference.
    rng = np.random.default_rng(SEED + 4)
    T = 80
    z = np.cumsum(rng.normal(0.0, 20.0, (T, 2, 3)), axis=0)
    sigma = rng.uniform(0.5, 8.0, (T, 2, 3)) * PARAMS.cv_accel_sigma_mm_s2
    smoothed = smooth_per_axis(z, np.ones((T, 2)), np.full(T, DT), np.zeros(T, bool), PARAMS, sigma)
    for joint in range(2):
        for axis in range(3):
            # below the live model's noise counts as it
            want_sigma = np.maximum(sigma[:, joint, axis], PARAMS.cv_accel_sigma_mm_s2)
            want, _ = _filterpy_varying_q(z[:, joint, axis], PARAMS.cv_meas_sigma_mm**2, want_sigma, PARAMS)
            np.testing.assert_allclose(smoothed[:, joint, axis], want, rtol=0, atol=1e-7)


def _response(smoother, T: int, at: int) -> np.ndarray:
    """The output over frames of a unit measurement at frame ``at`` (all others 0): one column of the linear map."""
    z = np.zeros((T, 1, 3))
    z[at] = 1.0
    return smoother(z)[:, 0, 0]


def _delay_frames(response: np.ndarray, offsets: np.ndarray, hz: float) -> float:
    """The phase delay of a filter's response at ``hz``, frames (a response delta(d - D) gives D)."""
    omega = 2.0 * np.pi * hz * DT
    return float(-np.angle(np.sum(response * np.exp(-1j * omega * offsets))) / omega)


def test_rts_is_zero_lag_by_construction():
    # Over a linear model the fixed-interval smoother weighs the frames before and after an instant alike: its
    # response to one measurement is symmetric about it, so it delays no frequency; the causal filter's
    # response is one-sided (late at every frequency it passes), the fixed lag's reaches 3 frames back.
    T, at = 301, 150
    args = (np.ones((T, 1)), np.full(T, DT), np.zeros(T, bool), PARAMS)
    rts = _response(lambda z: rts_smooth(z, *args)[0], T, at)
    causal = _response(lambda z: rts_smooth(z, *args)[1], T, at)
    lag3 = _response(lambda z: fixed_lag_smooth(z, *args, lag=3), T, at)
    offsets = np.arange(T) - at
    np.testing.assert_allclose(rts[at + 1 : at + 61], rts[at - 1 : at - 61 : -1], rtol=0, atol=1e-9 * rts[at])
    assert rts.sum() == pytest.approx(1.0, abs=1e-6)  # a constant passes unchanged
    assert np.all(causal[:at] == 0.0) and np.all(lag3[: at - 3] == 0.0) and lag3[at - 3] != 0.0
    for hz in (0.5, 1.0, 2.0, 4.0):
        assert _delay_frames(rts, offsets, hz) == pytest.approx(0.0, abs=1e-6)
        assert 0.0 < _delay_frames(lag3, offsets, hz) < _delay_frames(causal, offsets, hz)
    assert _delay_frames(causal, offsets, 2.0) > 0.5  # a 2 Hz gesture: the live filter half a frame late


def _hops(T: int) -> np.ndarray:
    """(T, 1, 3) a joint hopping in place: 0.45 s ballistic flights (take-off and landing within a frame)."""
    t = np.arange(T) * DT
    flight = 0.45
    phase = (t % 1.6 - 0.55) / flight
    height = np.where((phase > 0) & (phase < 1), 4.0 * 250.0 * phase * (1.0 - phase), 0.0)
    truth = np.zeros((T, 1, 3))
    truth[:, 0, 2] = 900.0 + height
    return truth


def test_the_adaptive_pass_follows_a_hop_and_keeps_still_motion_smooth():
    rng = np.random.default_rng(SEED + 5)
    T = 300
    args = (np.ones((T, 1)), np.full(T, DT), np.zeros(T, bool), PARAMS)
    jitter = lambda e: float(np.median(np.linalg.norm(np.diff(e, 2, axis=0), axis=-1)))  # noqa: E731
    truth = _hops(T)
    z = truth + rng.normal(0.0, 6.0, truth.shape)
    fixed, _ = rts_smooth(z, *args)
    adaptive, _ = rts_smooth(z, *args, adaptive=True)
    error = lambda x: float(np.mean(np.linalg.norm(x - truth, axis=-1)))  # noqa: E731
    assert error(adaptive) < 0.7 * error(fixed)
    peak = lambda x: float(np.abs(x - truth).max())  # noqa: E731  # the landing, rounded off in time
    assert peak(adaptive) < 0.7 * peak(fixed)
    still = 900.0 + rng.normal(0.0, 6.0, (T, 1, 3))
    fixed, _ = rts_smooth(still, *args)
    adaptive, _ = rts_smooth(still, *args, adaptive=True)
    assert jitter(adaptive - 900.0) < 1.3 * jitter(fixed - 900.0)


def test_the_fixed_lag_uses_no_frame_beyond_its_lag_and_follows_a_hop():
    # What a live fixed-lag smoother can give: the estimate of frame t is the same whatever comes after t + lag,
    # its process noise included; over a lag as long as the take it is the fixed-interval smoother with that
    # noise.
    rng = np.random.default_rng(SEED + 6)
    T, lag = 120, 3
    truth = _hops(T)
    z = truth + rng.normal(0.0, 6.0, truth.shape)
    args = (np.ones((T, 1)), np.full(T, DT), np.zeros(T, bool), PARAMS)
    out = fixed_lag_smooth(z, *args, lag)
    for t in (20, 60, 100):
        changed = z.copy()
        changed[t + lag + 1 :] += rng.normal(0.0, 300.0, changed[t + lag + 1 :].shape)
        again = fixed_lag_smooth(changed, *args, lag)
        np.testing.assert_allclose(again[: t + 1], out[: t + 1], rtol=0, atol=1e-9)
        assert not np.allclose(again[t + 1 :], out[t + 1 :])
    sigma = causal_accel_sigma(forward_pass(z, *args), np.full(T, DT), PARAMS.cv_accel_sigma_mm_s2)
    full = smooth_per_axis(z, *args, sigma)
    np.testing.assert_allclose(fixed_lag_smooth(z, *args, T), full, rtol=0, atol=1e-9)
    live_model = np.full((T, 1, 3), PARAMS.cv_accel_sigma_mm_s2)  # the fixed lag over the live model: rounds a hop off
    plain = smooth_per_axis(z, *args, live_model, lag)
    error = lambda x: float(np.mean(np.linalg.norm(x - truth, axis=-1)))  # noqa: E731
    assert error(out) < error(plain)


def test_the_live_fixed_lag_smoother_equals_the_offline_one_instant_by_instant():
    # Two hopping tracks (the process noise rises at every take-off and landing): one restarted by the follow
    # rule, one coasting through a 3-frame hole and ending early, a third starting late; a silent gap between
    # instants lengthens the time step. Pushed instant by instant, released lag instants later and flushed at
    # the end, the live smoother gives the offline fixed lag over the same instants.
    rng = np.random.default_rng(SEED + 7)
    T, lag = 90, 3
    times = np.arange(T) * DT
    times[50:] += 2 * DT  # two instants missing
    hops = _hops(T)[:, 0]
    ids = [np.array([1, 2] if t < 60 else [1]) if t < 70 else np.array([1, 3]) for t in range(T)]
    merged, agree, restarted = [], [], []
    for t in range(T):
        z = np.stack([hops + 300.0 * k for k in range(len(ids[t]))])[:, t] + rng.normal(0.0, 6.0, (len(ids[t]), 3))
        z = np.repeat(z[:, None], 4, axis=1)  # 4 joints per person
        if t in (30, 31, 32) and len(ids[t]) > 1:
            z[1, 2] = np.nan  # the second person's joint 2 coasts
        merged.append(z)
        agree.append(np.full(z.shape[:2], 2))
        restarted.append(np.array([t == 40] + [False] * (len(ids[t]) - 1)))
    smoother = FixedLagSmoother(PARAMS, lag)
    live = [smoother.push(times[t], ids[t], merged[t], agree[t], restarted[t]) for t in range(T)]
    assert all(out is None for out in live[:lag])
    live = [out for out in live if out is not None] + smoother.flush()
    expected = smooth_tracks(times, ids, merged, agree, restarted, PARAMS, lag)
    assert len(live) == T
    for got, want in zip(live, expected, strict=True):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    fwd = forward_pass(np.stack([m[0] for m in merged]), np.full((T, 4), 2), np.diff(times, prepend=-DT),
                       np.arange(T) == 40, PARAMS)  # fmt: skip
    assert (causal_accel_sigma(fwd, np.diff(times, prepend=-DT), PARAMS.cv_accel_sigma_mm_s2) > 1.5e4).any()


def _filterpy_constant_acceleration(z: np.ndarray, r: np.ndarray, jerks: np.ndarray, params) -> np.ndarray:
    """One axis through filterpy with a (position, velocity, acceleration) state, the white-jerk noise
    ``jerks[t]`` for the step into frame t and the measurement variance ``r[t]``: the smoothed positions."""
    kf = KalmanFilter(dim_x=3, dim_z=1)
    kf.F = np.array([[1.0, DT, DT * DT / 2.0], [0.0, 1.0, DT], [0.0, 0.0, 1.0]])
    kf.H = np.array([[1.0, 0.0, 0.0]])
    g = np.array([[DT**3 / 6.0], [DT * DT / 2.0], [DT]])
    qs = np.stack([s**2 * (g @ g.T) for s in jerks])
    kf.x = np.array([[z[0]], [0.0], [0.0]])
    kf.P = np.diag([params.cv_meas_sigma_mm**2, params.cv_velocity0_sigma_mm_s**2, ACCEL0_SIGMA_MM_S2**2])
    means, covs = [kf.x.copy()], [kf.P.copy()]
    for t in range(1, len(z)):
        kf.predict(Q=qs[t])
        kf.update(np.array([[z[t]]]), R=np.array([[r[t]]]))
        means.append(kf.x.copy())
        covs.append(kf.P.copy())
    smoothed, _, _, _ = kf.rts_smoother(np.array(means), np.array(covs), Qs=qs)
    return smoothed[:, 0, 0]


def test_the_constant_acceleration_pass_equals_filterpy():
    # Per axis, its jerk noise changing frame by frame and the measurement noise divided by the views that
    # agree: filterpy's filter and RTS smoother over the same model are the reference.
    rng = np.random.default_rng(SEED + 7)
    T = 80
    z = np.cumsum(np.cumsum(rng.normal(0.0, 5.0, (T, 2, 3)), axis=0), axis=0)
    n_agree = rng.integers(1, 4, (T, 2))
    jerk = rng.uniform(0.5, 20.0, (T, 2, 3)) * JERK_BASE_MM_S3
    smoothed = jerk_smooth(z, n_agree, np.full(T, DT), np.ones((T, 2), bool), PARAMS, jerk)
    for joint in range(2):
        r = PARAMS.cv_meas_sigma_mm**2 / n_agree[:, joint]
        for axis in range(3):
            want = _filterpy_constant_acceleration(z[:, joint, axis], r, jerk[:, joint, axis], PARAMS)
            np.testing.assert_allclose(smoothed[:, joint, axis], want, rtol=0, atol=1e-7)


def test_the_constant_acceleration_pass_smooths_segments_apart_and_is_zero_lag():
    rng = np.random.default_rng(SEED + 8)
    T, start = 120, 50
    z = 900.0 + rng.normal(0.0, 8.0, (T, 1, 3))
    linked = np.ones((T, 1), bool)
    linked[start] = False  # a restart
    jerk = np.full((T, 1, 3), JERK_BASE_MM_S3)
    both = jerk_smooth(z, np.ones((T, 1)), np.full(T, DT), linked, PARAMS, jerk)
    for part in (slice(0, start), slice(start, T)):
        alone = jerk_smooth(z[part], np.ones((len(z[part]), 1)), np.full(T, DT)[part], linked[part], PARAMS, jerk[part])
        np.testing.assert_allclose(both[part], alone, rtol=0, atol=1e-9)
    # One measurement's effect is symmetric about it (a constant noise): the pass delays no frequency.
    T, at = 301, 150
    unit = np.zeros((T, 1, 3))
    unit[at] = 1.0
    jerk = np.full((T, 1, 3), JERK_BASE_MM_S3)
    response = jerk_smooth(unit, np.ones((T, 1)), np.full(T, DT), np.ones((T, 1), bool), PARAMS, jerk)[:, 0, 0]
    np.testing.assert_allclose(response[at + 1 : at + 61], response[at - 1 : at - 61 : -1], atol=1e-9 * response[at])


def test_the_jerk_noise_reads_the_body_and_the_joint():
    # Positions cubic in time have the third difference 6 c dt^3 every frame: jerk 6 c (mm/s^3) exactly.
    T = 40
    t = np.arange(T) * DT
    positions = np.zeros((T, 3, 3))
    positions[:, 0, 2] = 1000.0 * t**3  # one joint jerks upward, 6000 mm/s^3; the other two stand still
    linked = np.ones((T, 3), bool)
    sigma = jerk_sigma(positions, linked, np.full(T, DT), base=10.0, body_gain=3.0, own_gain=1.0, spread=2)
    inner = slice(1, T - 2)  # frames with a whole window
    np.testing.assert_allclose(sigma[inner, 0, 2], 6000.0, rtol=1e-6)  # its own jerk (the body's median is 0)
    np.testing.assert_allclose(sigma[:, 1:, :], 10.0)  # the still joints: the base
    positions[:, :, 2] = 1000.0 * t[:, None] ** 3  # the whole body: 3 x the body's median on every joint
    sigma = jerk_sigma(positions, linked, np.full(T, DT), base=10.0, body_gain=3.0, own_gain=1.0, spread=2)
    np.testing.assert_allclose(sigma[inner, :, 2], 18000.0, rtol=1e-6)
    np.testing.assert_allclose(sigma[:, :, :2], 10.0)  # per axis: nothing sideways
    linked[20] = False  # a segment start at frame 20: no window of frames t - 1 .. t + 2 across it
    sigma = jerk_sigma(positions, linked, np.full(T, DT), base=10.0, body_gain=3.0, own_gain=1.0, spread=0)
    np.testing.assert_allclose(sigma[18:21, :, 2], 10.0)
    np.testing.assert_allclose(sigma[[17, 21], :, 2], 18000.0, rtol=1e-6)


def test_the_offline_default_smooths_a_hop_harder_than_its_constant_velocity_pass():
    # The hops' flights fall at a constant acceleration: the acceleration state follows them with little process
    # noise, so the views' jitter is removed where the constant-velocity pass had to let it through. Against the
    # second pass alone (what the default gave without its third pass): less jitter, no more error.
    rng = np.random.default_rng(SEED + 9)
    T = 300
    args = (np.ones((T, 1)), np.full(T, DT), np.zeros(T, bool), PARAMS)
    truth = _hops(T)
    z = truth + rng.normal(0.0, 6.0, truth.shape)
    fwd = forward_pass(z, *args)
    sigma = adaptive_accel_sigma(backward_pass(fwd, args[1]), fwd.linked, args[1], PARAMS.cv_accel_sigma_mm_s2)
    second = smooth_per_axis(z, *args, sigma)
    default, _ = rts_smooth(z, *args, adaptive=True)
    jitter = lambda x: float(np.median(np.linalg.norm(np.diff(x - truth, 2, axis=0), axis=-1)))  # noqa: E731
    error = lambda x: float(np.mean(np.linalg.norm(x - truth, axis=-1)))  # noqa: E731
    assert jitter(default) < 0.7 * jitter(second)
    assert error(default) <= error(second)
