"""Error metrics on hand-computed cases (skelfuse.eval.metrics)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skelfuse.eval.metrics import (
    ErrorAccumulator,
    best_lag,
    error_stats,
    group_means,
    jitter_rms,
    jitter_sums,
    joint_distances,
    lag_error_curve,
    mean_stats,
    swap_counts,
)


def _offset(distances_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A reference at the origin and an estimate displaced along a fixed direction by the given (T, J)
    distances."""
    distances_mm = np.asarray(distances_mm, dtype=float)
    direction = np.array([2.0, -1.0, 2.0]) / 3.0  # unit length
    reference = np.zeros((*distances_mm.shape, 3))
    return reference + distances_mm[..., None] * direction, reference


def test_joint_distances_is_euclidean_and_nan_where_missing() -> None:
    est = np.array([[[3.0, 4.0, 0.0], [np.nan, 0.0, 0.0]]])
    ref = np.zeros((1, 2, 3))
    d = joint_distances(est, ref)
    assert d.shape == (1, 2)
    assert d[0, 0] == pytest.approx(5.0)
    assert np.isnan(d[0, 1])


def test_ae_rmse_std_of_known_distances() -> None:
    # Joint 0: distances 3, 4, 5, 8 -> mean 5, mean of squares (9+16+25+64)/4 = 28.5, var 28.5-25 = 3.5.
    # Joint 1: constant 10 -> AE = RMSE = 10, STD = 0.
    est, ref = _offset(np.array([[3.0, 10.0], [4.0, 10.0], [5.0, 10.0], [8.0, 10.0]]))
    s = error_stats(est, ref)
    np.testing.assert_allclose(s.ae_mm, [5.0, 10.0])
    np.testing.assert_allclose(s.rmse_mm, [np.sqrt(28.5), 10.0])
    np.testing.assert_allclose(s.std_mm, [np.sqrt(3.5), 0.0], atol=1e-12)
    np.testing.assert_array_equal(s.n_frames, [4, 4])
    # RMSE² = AE² + STD² (population STD), the identity the paper's tables rest on.
    np.testing.assert_allclose(s.rmse_mm**2, s.ae_mm**2 + s.std_mm**2)


def test_nan_frames_are_counted_not_dropped_silently() -> None:
    est, ref = _offset(np.array([[1.0, 2.0], [3.0, 2.0], [5.0, 2.0]]))
    est[1, 0] = np.nan  # output failed on joint 0, frame 1
    ref[2, 1] = np.nan  # reference lacks joint 1 in frame 2: not scored, counted apart
    s = error_stats(est, ref)
    np.testing.assert_array_equal(s.n_frames, [2, 2])
    np.testing.assert_array_equal(s.n_missing, [1, 0])
    np.testing.assert_array_equal(s.n_ref_missing, [0, 1])
    np.testing.assert_allclose(s.ae_mm, [3.0, 2.0])  # (1 + 5) / 2


def test_joint_without_valid_frame_is_nan_not_zero() -> None:
    est, ref = _offset(np.ones((3, 2)))
    est[:, 1] = np.nan
    s = error_stats(est, ref)
    assert np.isnan(s.ae_mm[1]) and np.isnan(s.rmse_mm[1]) and np.isnan(s.std_mm[1])
    assert s.n_missing[1] == 3


def test_accumulators_pool_frames_across_takes() -> None:
    rng = np.random.default_rng(1124)
    d = rng.uniform(0.0, 50.0, size=(40, 3))
    est, ref = _offset(d)
    whole = error_stats(est, ref)
    parts = ErrorAccumulator.zeros(3).add(est[:15], ref[:15]) + ErrorAccumulator.zeros(3).add(est[15:], ref[15:])
    pooled = parts.stats()
    np.testing.assert_allclose(pooled.ae_mm, whole.ae_mm)
    np.testing.assert_allclose(pooled.rmse_mm, whole.rmse_mm)
    np.testing.assert_allclose(pooled.std_mm, whole.std_mm)
    np.testing.assert_allclose(whole.ae_mm, d.mean(axis=0))
    np.testing.assert_allclose(whole.std_mm, d.std(axis=0))


def test_mean_stats_averages_with_equal_weight_and_sums_counts() -> None:
    a = error_stats(*_offset(np.full((10, 2), 2.0)))
    b = error_stats(*_offset(np.full((30, 2), 6.0)))
    m = mean_stats([a, b])
    np.testing.assert_allclose(m.ae_mm, [4.0, 4.0])  # equal weight, not frame-weighted (which would give 5)
    np.testing.assert_array_equal(m.n_frames, [40, 40])


def test_group_mean_is_the_mean_of_its_joints() -> None:
    values = np.array([1.0, 2.0, 3.0, 10.0])
    joints = np.array([7, 3, 5, 9])
    out = group_means(values, joints, {"a": [3, 5], "b": [9, 7]})
    assert out["a"] == pytest.approx(2.5)
    assert out["b"] == pytest.approx(5.5)
    with pytest.raises(ValueError, match="not among"):
        group_means(values, joints, {"c": [0]})


def test_shape_mismatch_is_a_value_error() -> None:
    with pytest.raises(ValueError, match="same shape"):
        joint_distances(np.zeros((2, 3, 3)), np.zeros((2, 4, 3)))


@pytest.mark.parametrize("true_lag", [0, 3, 7, -2])
def test_lag_recovers_a_known_shift(true_lag: int) -> None:
    t = np.arange(200)
    rng = np.random.default_rng(7)
    # A smooth, non-periodic trajectory of two joints (mm); the output is the truth late by true_lag frames.
    truth = np.stack(
        [
            np.stack([300 * np.sin(t / 9.0), 200 * np.cos(t / 13.0), 5 * t], -1),
            np.stack([150 * np.sin(t / 5.0 + 1), 100 * np.sin(t / 17.0), 3 * t], -1),
        ],
        axis=1,
    )
    output = np.roll(truth, true_lag, axis=0) + rng.normal(0.0, 2.0, truth.shape)
    output[: max(true_lag, 0)] = np.nan  # the rolled-in head is not data
    if true_lag < 0:
        output[true_lag:] = np.nan
    shifts = np.arange(-5, 21)
    sums, counts = lag_error_curve(output, truth, shifts)
    lag, err = best_lag(sums, counts, shifts)
    assert lag == pytest.approx(true_lag, abs=0.3)
    assert err < 5.0


def test_best_lag_without_data_is_nan() -> None:
    lag, err = best_lag(np.zeros(3), np.zeros(3, dtype=np.int64), [0, 1, 2])
    assert np.isnan(lag) and np.isnan(err)


def test_swap_counts_detects_exchanged_labels() -> None:
    reference = np.zeros((4, 2, 3))
    reference[:, 0, 0] = -200.0  # left joint at x = -200, right at +200
    reference[:, 1, 0] = 200.0
    estimate = reference.copy()
    estimate[1:3] = estimate[1:3, ::-1]  # frames 1 and 2 swapped
    estimate[3, 0] = np.nan  # frame 3 not scorable
    n_swapped, n_valid = swap_counts(estimate, reference, np.array([[0, 1]]))
    assert n_swapped.tolist() == [2] and n_valid.tolist() == [3]


def test_jitter_is_zero_on_constant_velocity_and_the_acceleration_otherwise() -> None:
    t = np.arange(10.0)
    linear = np.stack([np.stack([3.0 * t, -t, 0.5 * t], axis=-1)] * 2, axis=1)  # (T, 2, 3)
    assert jitter_sums(linear) == pytest.approx((0.0, 2 * 8))
    # x = t² along one axis: second difference 2 mm/frame² everywhere.
    parabola = np.zeros((6, 1, 3))
    parabola[:, 0, 0] = np.arange(6.0) ** 2
    s, n = jitter_sums(parabola)
    assert n == 4 and jitter_rms(s, n) == pytest.approx(2.0)
    # A NaN frame removes the three second differences that touch it.
    parabola[2] = np.nan
    assert jitter_sums(parabola)[1] == 1
    assert np.isnan(jitter_rms(0.0, 0)) and jitter_sums(parabola[:2]) == (0.0, 0)


def test_jitter_of_white_noise_is_sqrt18_sigma() -> None:
    rng = np.random.default_rng(1124)
    noise = rng.normal(0.0, 2.0, (20000, 1, 3))
    assert jitter_rms(*jitter_sums(noise)) == pytest.approx(2.0 * np.sqrt(18.0), rel=0.02)
    with pytest.raises(ValueError, match="T, J, 3"):
        jitter_sums(np.zeros((5, 3)))


def test_none_for_nan_writes_json_and_nan_for_none_reads_it_back() -> None:
    from skelfuse.eval.metrics import nan_for_none, none_for_nan

    value = {"a": [float("nan"), np.float64(1.5)], "b": (np.int64(2), {"c": np.float32("inf")})}
    written = none_for_nan(value)
    assert written == {"a": [None, 1.5], "b": [2, {"c": None}]}
    assert json.loads(json.dumps(written, allow_nan=False)) == written
    back = nan_for_none(written)
    assert np.isnan(back["a"][0]) and back["a"][1] == 1.5 and np.isnan(back["b"][1]["c"])
