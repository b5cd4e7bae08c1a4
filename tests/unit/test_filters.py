"""Batched filters against filterpy and a hand-iterated alpha-beta recurrence; coasting and reset."""

from dataclasses import replace

import numpy as np
import pytest
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter

from skelfuse.fusion.filters import filter_step, init_filter_state
from skelfuse.fusion.presets import FusionParams

SEED = 1124
N = 6
T = 80


def _measurements(rng: np.random.Generator, gap_prob: float = 0.15) -> np.ndarray:
    """(T, N, 3) random walk in mm with NaN gaps (no gap longer than a few frames)."""
    z = np.cumsum(rng.normal(0.0, 5.0, (T, N, 3)), axis=0) + rng.normal(0.0, 500.0, (N, 3))
    z[rng.random((T, N)) < gap_prob] = np.nan
    return z


def _run_batched(params, z, n_agree, dt):
    x, P, coast = init_filter_state(N)
    outs, xs, Ps = [], [], []
    for t in range(len(z)):
        out, x, P, coast = filter_step(x, P, coast, z[t], n_agree[t], params, dt[t])
        outs.append(out)
        xs.append(x)
        Ps.append(P)
    return np.array(outs), np.array(xs), np.array(Ps)


def test_paper_kalman_equals_filterpy_with_nan_gaps():
    rng = np.random.default_rng(SEED)
    params = FusionParams(filter="paper_kalman", max_coast_frames=1000)
    z = _measurements(rng)
    z[:3, 0] = np.nan  # a joint that starts late
    outs, xs, Ps = _run_batched(params, z, np.ones((T, N), int), np.full(T, 1 / 30))
    for j in range(N):
        kf = None
        for t in range(T):
            if kf is None:
                if np.isnan(z[t, j, 0]):
                    assert np.isnan(outs[t, j]).all()
                    continue
                kf = KalmanFilter(dim_x=3, dim_z=3)
                kf.F, kf.H = np.eye(3), np.eye(3)
                kf.Q, kf.R, kf.P = 0.01 * np.eye(3), 1.0 * np.eye(3), 1.0 * np.eye(3)
                kf.x = z[t, j].reshape(3, 1).copy()
                np.testing.assert_array_equal(outs[t, j], z[t, j])  # first frame: the measurement itself
            else:
                kf.predict()
                np.testing.assert_allclose(outs[t, j], kf.x[:, 0], rtol=0, atol=1e-12)  # output = prediction
                if not np.isnan(z[t, j, 0]):
                    kf.update(z[t, j].reshape(3, 1))
            np.testing.assert_allclose(xs[t, j, 0], kf.x[:, 0], rtol=0, atol=1e-12)
            np.testing.assert_allclose(Ps[t, j, 0] * np.eye(3), kf.P, rtol=0, atol=1e-12)


def test_paper_kalman_posterior_output_equals_filterpy_after_update():
    rng = np.random.default_rng(SEED + 1)
    params = FusionParams(filter="paper_kalman", max_coast_frames=1000, kalman_output="posterior")
    z = _measurements(rng, gap_prob=0.0)
    outs, _, _ = _run_batched(params, z, np.ones((T, N), int), np.full(T, 1 / 30))
    for j in range(N):
        kf = KalmanFilter(dim_x=3, dim_z=3)
        kf.F, kf.H = np.eye(3), np.eye(3)
        kf.Q, kf.R, kf.P = 0.01 * np.eye(3), 1.0 * np.eye(3), 1.0 * np.eye(3)
        kf.x = z[0, j].reshape(3, 1).copy()
        for t in range(1, T):
            kf.predict()
            kf.update(z[t, j].reshape(3, 1))
            np.testing.assert_allclose(outs[t, j], kf.x[:, 0], rtol=0, atol=1e-12)  # output = posterior


def test_paper_kalman_steady_state_gain_is_about_0095():
    params = FusionParams(filter="paper_kalman")
    x, P, coast = init_filter_state(1)
    for _ in range(300):
        _, x, P, coast = filter_step(x, P, coast, np.zeros((1, 3)), np.ones(1, int), params, 1 / 30)
    p_pred = P[0, 0] + 0.01
    assert p_pred / (p_pred + 1.0) == pytest.approx(0.0951, abs=1e-3)


def test_cv_kalman_equals_filterpy_constant_velocity_model():
    rng = np.random.default_rng(SEED + 1)
    params = FusionParams(filter="cv_kalman", max_coast_frames=1000, cv_scale_r_by_agree=True)
    z = _measurements(rng)
    n_agree = rng.integers(1, 5, (T, N))
    dt = rng.uniform(0.025, 0.045, T)  # jittered frame intervals
    outs, xs, Ps = _run_batched(params, z, n_agree, dt)
    q, r, v0 = params.cv_accel_sigma_mm_s2**2, params.cv_meas_sigma_mm**2, params.cv_velocity0_sigma_mm_s**2
    H = np.zeros((3, 6))
    H[[0, 1, 2], [0, 2, 4]] = 1.0
    for j in range(N):
        kf = None
        for t in range(T):
            measured = not np.isnan(z[t, j, 0])
            if kf is None:
                if not measured:
                    continue
                kf = KalmanFilter(dim_x=6, dim_z=3)  # (x, vx, y, vy, z, vz)
                kf.H = H
                kf.P = np.kron(np.eye(3), np.diag([r, v0]))
                kf.x = np.zeros((6, 1))
                kf.x[[0, 2, 4], 0] = z[t, j]
            else:
                kf.F = np.kron(np.eye(3), np.array([[1.0, dt[t]], [0.0, 1.0]]))
                kf.Q = Q_discrete_white_noise(dim=2, dt=dt[t], var=q, block_size=3)
                kf.predict()
                if measured:
                    kf.update(z[t, j].reshape(3, 1), R=r / n_agree[t, j] * np.eye(3))
            np.testing.assert_allclose(outs[t, j], kf.x[[0, 2, 4], 0], rtol=1e-12, atol=1e-9)
            np.testing.assert_allclose(xs[t, j].T.ravel(), kf.x[:, 0], rtol=1e-12, atol=1e-9)
            P_block = np.array([[Ps[t, j, 0], Ps[t, j, 1]], [Ps[t, j, 1], Ps[t, j, 2]]])
            np.testing.assert_allclose(np.kron(np.eye(3), P_block), kf.P, rtol=1e-9, atol=1e-9)


def test_alpha_beta_equals_hand_iterated_recurrence():
    rng = np.random.default_rng(SEED + 2)
    params = FusionParams(filter="alpha_beta", alpha=0.6, beta=0.2, max_coast_frames=1000)
    z = _measurements(rng)
    dt = rng.uniform(0.025, 0.045, T)
    outs, _, _ = _run_batched(params, z, np.ones((T, N), int), dt)
    for j in range(N):
        X = V = None
        for t in range(T):
            if X is None:
                if np.isnan(z[t, j, 0]):
                    continue
                X, V = z[t, j].copy(), np.zeros(3)
            else:
                X = X + V * dt[t]
                if not np.isnan(z[t, j, 0]):
                    R = z[t, j] - X
                    X = X + 0.6 * R
                    V = V + (0.2 * R) / dt[t]
            np.testing.assert_allclose(outs[t, j], X, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("kind", ["paper_kalman", "cv_kalman", "alpha_beta"])
def test_coasting_predicts_then_gives_nan_and_restarts(kind):
    params = replace(FusionParams(filter=kind), max_coast_frames=3)
    x, P, coast = init_filter_state(1)
    nan = np.full((1, 3), np.nan)
    outputs = []
    zs = [np.array([[0.0, 0, 0]]), np.array([[30.0, 0, 0]])] + [nan] * 4 + [np.array([[500.0, 0, 0]])]
    for z in zs:
        out, x, P, coast = filter_step(x, P, coast, z, np.ones(1, int), params, 1 / 30)
        outputs.append((out[0].copy(), int(coast[0])))
    coasts = [c for _, c in outputs]
    assert coasts == [0, 0, 1, 2, 3, -1, 0]
    assert all(np.isfinite(out).all() for out, _ in outputs[:5])  # 3 coasted frames are predictions
    assert np.isnan(outputs[5][0]).all()  # the 4th frame without data: dropped
    np.testing.assert_array_equal(outputs[6][0], [500.0, 0, 0])  # restarts from the new measurement
    if kind != "paper_kalman":  # velocity models extrapolate while coasting
        assert outputs[2][0][0] > outputs[1][0][0]


def test_no_filter_passes_through():
    params = FusionParams(filter=None)
    x, P, coast = init_filter_state(2)
    z = np.array([[1.0, 2, 3], [np.nan] * 3])
    out, *_ = filter_step(x, P, coast, z, np.ones(2, int), params, 1 / 30)
    np.testing.assert_array_equal(out, z)


def test_filter_step_does_not_mutate_state():
    params = FusionParams(filter="cv_kalman")
    x, P, coast = init_filter_state(3)
    z = np.array([[1.0, 2, 3], [np.nan] * 3, [4.0, 5, 6]])
    _, x, P, coast = filter_step(x, P, coast, z, np.ones(3, int), params, 1 / 30)
    copies = (x.copy(), P.copy(), coast.copy())
    filter_step(x, P, coast, z + 1.0, np.ones(3, int), params, 1 / 30)
    for before, after in zip(copies, (x, P, coast), strict=True):
        np.testing.assert_array_equal(before, after)
