"""The compiled stacking of an instant's bodies in the world frame against its numpy reference
(skelfuse.fusion.reference.transform) on random frames: several sensors or one, sensors without bodies, NaN
joints, zero and non-finite quaternions, no bodies at all. Identical: slots, confidences; within 1e-9: positions
and quaternions (the reference's matrix products sum in another order)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skelfuse.fusion.orientation import calibration_quat_matrices, quat_from_rotvec, quat_to_matrix
from skelfuse.fusion.reference import transform as transform_reference
from skelfuse.fusion.transform import make_transform, stack_views_to_world
from skelfuse.schema.skeleton import N_JOINTS

ATOL = 1e-9


def _poses(rng: np.random.Generator, n_sensors: int) -> np.ndarray:
    rotations = quat_to_matrix(quat_from_rotvec(rng.normal(0.0, 1.5, (n_sensors, 3))))
    return np.array([make_transform(r, rng.normal(0.0, 2000.0, 3)) for r in rotations])


def _frames(rng: np.random.Generator, n_sensors: int, max_bodies: int, missing: float):
    """Frames of a random subset of the sensors, in random order, each with 1..max_bodies bodies."""
    rows = rng.permutation(n_sensors)[: rng.integers(0, n_sensors + 1)]
    counts = rng.integers(1, max_bodies + 1, rows.size) if max_bodies else np.zeros(0, dtype=np.int64)
    rows = rows[: counts.size]
    N = int(counts.sum())
    positions = rng.normal(0.0, 1000.0, (N, N_JOINTS, 3)).astype(np.float32).astype(np.float64)
    positions[rng.random((N, N_JOINTS)) < missing] = np.nan
    confidence = rng.integers(0, 4, (N, N_JOINTS)).astype(np.uint8)
    quats = rng.normal(0.0, 1.0, (N, N_JOINTS, 4))
    odd = rng.random((N, N_JOINTS))
    quats[odd < missing / 2] = 0.0  # a zero quaternion: NaN out
    quats[(odd >= missing / 2) & (odd < missing)] = np.nan
    return positions, confidence, quats, rows.astype(np.int64), counts.astype(np.int64)


@settings(max_examples=150, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_sensors=st.integers(1, 6),
    max_bodies=st.integers(0, 4),
    missing=st.sampled_from([0.0, 0.3, 1.0]),
    with_orientations=st.booleans(),
    spare_slots=st.integers(0, 2),
)
def test_stacking_kernel_equals_the_numpy_reference(
    seed, n_sensors, max_bodies, missing, with_orientations, spare_slots
):
    rng = np.random.default_rng(seed)
    poses = _poses(rng, n_sensors)
    positions, confidence, quats, rows, counts = _frames(rng, n_sensors, max_bodies, missing)
    args = (
        positions,
        confidence,
        quats if with_orientations else None,
        rows,
        counts,
        int(counts.max(initial=0)) + spare_slots,
        poses,
        calibration_quat_matrices(poses),
    )
    got, want = stack_views_to_world(*args), transform_reference.stack_views_to_world(*args)
    np.testing.assert_array_equal(got.valid, want.valid)
    np.testing.assert_array_equal(got.confidence, want.confidence)
    np.testing.assert_allclose(got.world, want.world, rtol=0, atol=ATOL)
    if with_orientations:
        np.testing.assert_allclose(got.orientations, want.orientations, rtol=0, atol=ATOL)
    else:
        assert got.orientations is None and want.orientations is None


def test_stacking_puts_each_body_in_its_sensors_row_and_moves_it_by_that_sensors_pose():
    """A hand-computed case: sensor 1 sits 1 m along x, turned a quarter turn about z (x -> y)."""
    quarter = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    poses = np.array([np.eye(4), make_transform(quarter, np.array([1000.0, 0.0, 0.0]))])
    positions = np.zeros((1, N_JOINTS, 3))
    positions[0, :, 0] = 100.0  # every joint 100 mm along the sensor's x
    identity = np.tile([1.0, 0.0, 0.0, 0.0], (1, N_JOINTS, 1))
    out = stack_views_to_world(
        positions,
        np.full((1, N_JOINTS), 2, dtype=np.uint8),
        identity,
        np.array([1]),
        np.array([1]),
        2,
        poses,
        calibration_quat_matrices(poses),
    )
    assert out.valid.tolist() == [[False, False], [True, False]]
    np.testing.assert_allclose(out.world[1, 0], np.tile([1000.0, 100.0, 0.0], (N_JOINTS, 1)), atol=1e-12)
    assert np.isnan(out.world[0]).all() and np.isnan(out.world[1, 1]).all() and not out.confidence[0].any()
    half = np.sqrt(0.5)  # the quarter turn about z as a quaternion (w, x, y, z)
    np.testing.assert_allclose(out.orientations[1, 0], np.tile([half, 0.0, 0.0, half], (N_JOINTS, 1)), atol=1e-12)


def test_stacking_refuses_frames_that_do_not_fit_the_slots():
    poses = np.eye(4)[None]
    one = (np.zeros((2, N_JOINTS, 3)), np.zeros((2, N_JOINTS), dtype=np.uint8), None)
    with pytest.raises(ValueError, match="do not fit"):
        stack_views_to_world(*one, np.array([0]), np.array([2]), 1, poses, poses)  # 2 bodies, 1 slot
    with pytest.raises(ValueError, match="do not fit"):
        stack_views_to_world(*one, np.array([1]), np.array([2]), 2, poses, poses)  # no sensor row 1
    with pytest.raises(ValueError, match="do not fit"):
        stack_views_to_world(*one, np.array([0]), np.array([1]), 2, poses, poses)  # 1 body counted, 2 given
