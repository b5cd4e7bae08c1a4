"""The RTS smoother against filterpy's, its fixed-lag form, and what it does to jitter and lag."""

from dataclasses import replace

import numpy as np
import pytest
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter

from skelfuse.fusion import preset
from skelfuse.fusion.smoother import fixed_lag_smooth, forward_pass, rts_smooth

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
    rng = np.random.default_rng(SEED + 2)
    T = 50
    z = np.cumsum(rng.normal(0.0, 5.0, (T, 3, 3)), axis=0)
    args = (z, np.ones((T, 3)), np.full(T, DT), np.zeros(T, bool), PARAMS)
    full, causal = rts_smooth(*args)
    np.testing.assert_allclose(fixed_lag_smooth(*args, lag=0), causal, rtol=0, atol=1e-9)
    np.testing.assert_allclose(fixed_lag_smooth(*args, lag=T), full, rtol=0, atol=1e-9)
    lag3 = fixed_lag_smooth(*args, lag=3)
    np.testing.assert_allclose(lag3[-4:], full[-4:], rtol=0, atol=1e-9)  # the end: as much as there is


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
