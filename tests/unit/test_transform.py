"""Rigid transforms: inverse round trip, a hand-computed case, NaN stays NaN."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from skelfuse.fusion.transform import apply_transform, invert_transform, make_transform

angles = st.floats(-np.pi, np.pi, allow_nan=False)
offsets = st.floats(-5000.0, 5000.0, allow_nan=False)


@settings(max_examples=50, deadline=None)
@given(st.tuples(angles, angles, angles), st.tuples(offsets, offsets, offsets))
def test_inverse_composed_with_transform_is_identity(euler, translation):
    T = make_transform(Rotation.from_euler("xyz", euler).as_matrix(), np.array(translation))
    np.testing.assert_allclose(invert_transform(T) @ T, np.eye(4), atol=1e-9)
    np.testing.assert_allclose(T @ invert_transform(T), np.eye(4), atol=1e-9)


def test_hand_computed_rotation_about_z_and_translation():
    # 90 degrees about z maps x to y; then shift by (10, 20, 30) mm.
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    T = make_transform(R, np.array([10.0, 20.0, 30.0]))
    points = np.array([[[[1.0, 0.0, 0.0], [0.0, 2.0, 3.0]]]])  # (B=1, S=1, J=2, 3)
    out = apply_transform(T[None], points)
    np.testing.assert_allclose(out, [[[[10.0, 21.0, 30.0], [8.0, 20.0, 33.0]]]])
    back = apply_transform(invert_transform(T)[None], out)
    np.testing.assert_allclose(back, points, atol=1e-12)


def test_each_sensor_gets_its_own_transform_and_nan_stays_nan():
    T = np.stack([make_transform(np.eye(3), np.array([100.0, 0, 0])), make_transform(np.eye(3), np.zeros(3))])
    points = np.zeros((2, 2, 3, 3))  # (B, S, J, 3)
    points[0, 1, 2] = [np.nan, 1.0, 1.0]
    out = apply_transform(T, points)
    assert np.isnan(out[0, 1, 2]).all()  # any NaN coordinate makes the whole joint missing
    np.testing.assert_allclose(out[:, 0], np.broadcast_to([100.0, 0.0, 0.0], (2, 3, 3)))
    assert np.isfinite(out[1]).all()


@pytest.mark.parametrize(
    ("rotation", "translation", "match"),
    [
        (np.eye(2), np.zeros(3), "rotation must have shape"),
        (np.eye(3), np.zeros(4), "translation_mm must have shape"),
        (np.diag([1.0, 1.0, -1.0]), np.zeros(3), "determinant"),
        (2 * np.eye(3), np.zeros(3), "orthonormal"),
    ],
)
def test_make_transform_rejects_bad_input(rotation, translation, match):
    with pytest.raises(ValueError, match=match):
        make_transform(rotation, translation)


def test_apply_transform_rejects_sensor_count_mismatch():
    with pytest.raises(ValueError, match="S=2"):
        apply_transform(np.stack([np.eye(4)] * 2), np.zeros((1, 3, 32, 3)))
