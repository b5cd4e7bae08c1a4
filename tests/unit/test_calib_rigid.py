"""Rigid fits: closed-form recovery, the paper's errata (reflection fix, t = mean_M - R mean_p), robustness."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skelfuse.calibration.rigid import fit_rigid, fit_rigid_ransac, rotation_angle_deg
from skelfuse.schema.errors import CalibrationError

SEED = 20240611


def _rotation(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


quaternions = st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1)
translations = st.lists(st.floats(-5000, 5000), min_size=3, max_size=3)
seeds = st.integers(0, 2**32 - 1)


def _spread_points(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform(-1500, 1500, size=(n, 3))


@settings(max_examples=60, deadline=None)
@given(q=quaternions, t=translations, seed=seeds, n=st.integers(3, 60))
def test_exact_recovery_of_random_rigid_transforms(q, t, seed, n):
    rng = np.random.default_rng(seed)
    R, t = _rotation(np.array(q)), np.array(t)
    src = _spread_points(rng, n)
    fit = fit_rigid(src, src @ R.T + t)
    assert np.allclose(fit.R, R, atol=1e-8)
    assert np.allclose(fit.t, t, atol=1e-6)
    assert fit.rms_mm < 1e-6
    assert fit.n == n
    assert np.linalg.det(fit.R) == pytest.approx(1.0)


@settings(max_examples=40, deadline=None)
@given(q=quaternions, t=translations, seed=seeds)
def test_invariant_to_point_order(q, t, seed):
    rng = np.random.default_rng(seed)
    R, t = _rotation(np.array(q)), np.array(t)
    src = _spread_points(rng, 30)
    dst = src @ R.T + t + rng.normal(0, 20, size=src.shape)
    perm = rng.permutation(30)
    a, b = fit_rigid(src, dst), fit_rigid(src[perm], dst[perm])
    assert np.allclose(a.R, b.R, atol=1e-10)
    assert np.allclose(a.t, b.t, atol=1e-7)
    assert a.rms_mm == pytest.approx(b.rms_mm)


@settings(max_examples=40, deadline=None)
@given(q=quaternions, t=translations, seed=seeds)
def test_coplanar_points_give_a_rotation_not_a_reflection(q, t, seed):
    # Coplanar points: the naive U V' is a reflection about half the time (the third singular vector's sign
    # is arbitrary); the fix must return the true proper rotation.
    rng = np.random.default_rng(seed)
    R, t = _rotation(np.array(q)), np.array(t)
    src = np.column_stack([rng.uniform(-1000, 1000, size=(20, 2)), np.zeros(20)])
    fit = fit_rigid(src, src @ R.T + t)
    assert np.linalg.det(fit.R) == pytest.approx(1.0)
    assert np.allclose(fit.R, R, atol=1e-8)
    assert np.allclose(fit.t, t, atol=1e-6)


def test_mirrored_target_yields_the_best_proper_rotation():
    # A mirrored point set (what a flipped skeleton is) cannot be matched by a rotation: the fit stays a
    # rotation and says so through a large residual, instead of silently returning the reflection.
    rng = np.random.default_rng(SEED)
    src = _spread_points(rng, 50)
    mirrored = src * np.array([-1.0, 1.0, 1.0])
    fit = fit_rigid(src, mirrored)
    assert np.linalg.det(fit.R) == pytest.approx(1.0)
    assert fit.rms_mm > 300


def test_translation_follows_the_errata():
    # t = mean_target - R mean_source; the paper's t = mean_target - mean_source is wrong once R != I.
    rng = np.random.default_rng(SEED)
    R = _rotation(np.array([0.8, 0.1, -0.5, 0.3]))
    src = _spread_points(rng, 10) + 3000.0
    dst = src @ R.T + np.array([10.0, 20.0, 30.0])
    fit = fit_rigid(src, dst)
    assert np.allclose(fit.t, dst.mean(0) - R @ src.mean(0))
    assert not np.allclose(fit.t, dst.mean(0) - src.mean(0), atol=100)


def test_weights_select_points():
    rng = np.random.default_rng(SEED)
    R = _rotation(np.array([1.0, 0.2, 0.3, 0.1]))
    src = _spread_points(rng, 20)
    dst = src @ R.T + 5.0
    dst[:5] += 800.0  # garbage, weighted out
    fit = fit_rigid(src, dst, weights=np.r_[np.zeros(5), np.ones(15)])
    assert np.allclose(fit.R, R, atol=1e-9)
    assert fit.n == 15


@pytest.mark.parametrize(
    ("src", "match"),
    [
        pytest.param(np.zeros((2, 3)), "at least 3", id="too-few"),
        pytest.param(np.outer(np.arange(5.0), [1.0, 2.0, 3.0]), "one line", id="collinear"),
    ],
)
def test_degenerate_inputs_raise(src, match):
    with pytest.raises(CalibrationError, match=match):
        fit_rigid(src, src)


def test_bad_shapes_raise_value_error():
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        fit_rigid(np.zeros((4, 3)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match="finite"):
        fit_rigid(np.full((4, 3), np.nan), np.zeros((4, 3)))


@settings(max_examples=15, deadline=None)
@given(q=quaternions, t=translations, seed=seeds)
def test_ransac_is_robust_to_40_percent_outliers(q, t, seed):
    rng = np.random.default_rng(seed)
    R, t = _rotation(np.array(q)), np.array(t)
    n = 200
    src = _spread_points(rng, n)
    dst = src @ R.T + t + rng.normal(0, 10, size=src.shape)
    bad = rng.permutation(n)[: int(0.4 * n)]
    dst[bad] += rng.uniform(-2000, 2000, size=(len(bad), 3))  # gross outliers, mostly far off
    far = np.linalg.norm(dst - (src @ R.T + t), axis=1) > 100
    fit = fit_rigid_ransac(src, dst, threshold_mm=50, iterations=300, min_inliers=50, rng=rng)
    assert rotation_angle_deg(fit.R @ R.T) < 0.5
    assert np.linalg.norm(fit.t - t) < 15
    assert fit.inliers is not None
    assert not (fit.inliers & far).any()
    assert fit.rms_mm < 25
    plain = fit_rigid(src, dst)
    assert rotation_angle_deg(plain.R @ R.T) > rotation_angle_deg(fit.R @ R.T)


def test_ransac_reproducible_with_the_same_seed():
    rng = np.random.default_rng(SEED)
    src = _spread_points(rng, 100)
    dst = src + rng.normal(0, 10, size=src.shape)
    dst[:30] += 1000
    a = fit_rigid_ransac(src, dst, threshold_mm=40, iterations=100, rng=np.random.default_rng(1))
    b = fit_rigid_ransac(src, dst, threshold_mm=40, iterations=100, rng=np.random.default_rng(1))
    assert np.array_equal(a.R, b.R)
    assert np.array_equal(a.inliers, b.inliers)


def test_ransac_raises_when_nothing_matches():
    rng = np.random.default_rng(SEED)
    src = _spread_points(rng, 50)
    dst = _spread_points(rng, 50)
    with pytest.raises(CalibrationError, match="fewer than the 40 required"):
        fit_rigid_ransac(src, dst, threshold_mm=10, iterations=100, min_inliers=40, rng=rng)
