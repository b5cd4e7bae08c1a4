"""Per-frame association of sensor bodies into persons (skelfuse.fusion.association)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skelfuse.fusion.association import (
    associate,
    descriptor_distance,
    gather_candidates,
    nanmedian_axis,
    torso_descriptor,
)
from skelfuse.schema.skeleton import MIRROR, N_JOINTS, Confidence
from skelfuse.sim.gestures import make_gesture

POSE = make_gesture("hands_up_down", duration_s=0.1, seed=0).positions[0]


def body_at(x: float, y: float) -> np.ndarray:
    pose = POSE.copy()
    pose[:, :2] += np.array([x, y]) - pose[0, :2]
    return pose


def scene(rng: np.random.Generator, people_xy: list[tuple[float, float]], n_sensors: int, mirror_prob: float = 0.4):
    """Every sensor sees every person, shuffled slots, some views mirrored; returns inputs and the truth."""
    P = len(people_xy)
    positions = np.full((n_sensors, P + 1, N_JOINTS, 3), np.nan)
    confidence = np.zeros((n_sensors, P + 1, N_JOINTS), dtype=np.uint8)
    valid = np.zeros((n_sensors, P + 1), dtype=bool)
    truth = np.full((n_sensors, P + 1), -1)
    for s in range(n_sensors):
        order = rng.permutation(P)
        for slot, p in enumerate(order):
            body = body_at(*people_xy[p]) + rng.normal(0.0, 15.0, (N_JOINTS, 3))
            if rng.random() < mirror_prob:
                body = body[MIRROR]
            positions[s, slot] = body
            confidence[s, slot] = Confidence.MEDIUM
            valid[s, slot] = True
            truth[s, slot] = p
    return positions, confidence, valid, truth


def test_descriptor_is_mirror_invariant() -> None:
    np.testing.assert_allclose(torso_descriptor(POSE[MIRROR]), torso_descriptor(POSE))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_new_persons_group_each_persons_bodies(seed: int) -> None:
    rng = np.random.default_rng(seed)
    people = [(0.0, 0.0), (900.0, 0.0), (0.0, -1000.0)]
    positions, confidence, valid, truth = scene(rng, people, n_sensors=4)
    result = associate(positions, confidence, valid, np.zeros((0, 7, 3)))
    assert result.n_tracks == 0 and result.n_new == 3
    for p in range(3):  # all bodies of one person in one row, nobody else's
        rows = set(result.person_of_body[truth == p].tolist())
        assert len(rows) == 1
    assert (result.person_of_body[~valid] == -1).all()
    assert (result.n_sensors_seen == 4).all()


def test_tracks_take_their_bodies_under_shuffle_and_mirror() -> None:
    rng = np.random.default_rng(3)
    people = [(0.0, 0.0), (450.0, 0.0), (-450.0, 200.0)]  # close together
    positions, confidence, valid, truth = scene(rng, people, n_sensors=6, mirror_prob=0.5)
    tracks = np.stack([torso_descriptor(body_at(*xy)) for xy in people])
    result = associate(positions, confidence, valid, tracks)
    np.testing.assert_array_equal(result.person_of_body, truth)
    assert result.n_new == 0
    # candidates rows hold each person's own bodies, sensor by sensor
    for s in range(6):
        for b in range(3):
            np.testing.assert_array_equal(result.candidates[truth[s, b], s], positions[s, b])


def test_bystander_seen_by_one_sensor_is_its_own_person() -> None:
    rng = np.random.default_rng(1)
    positions, confidence, valid, _ = scene(rng, [(0.0, 0.0)], n_sensors=4, mirror_prob=0.0)
    positions[2, 1] = body_at(1500.0, 0.0)  # only sensor 2 sees the bystander
    confidence[2, 1] = Confidence.MEDIUM
    valid[2, 1] = True
    subject = torso_descriptor(body_at(0.0, 0.0))[None]
    result = associate(positions, confidence, valid, subject)
    assert result.person_of_body[2, 1] == 1 and result.n_new == 1
    assert (result.person_of_body[valid & (result.person_of_body != 1)] == 0).all()
    assert result.n_sensors_seen.tolist() == [4, 1]


def test_two_bodies_of_one_sensor_near_one_track_keep_the_closer() -> None:
    positions = np.full((1, 2, N_JOINTS, 3), np.nan)
    positions[0, 0] = body_at(120.0, 0.0)  # a duplicate skeleton, 120 mm off
    positions[0, 1] = body_at(10.0, 0.0)
    confidence = np.full((1, 2, N_JOINTS), Confidence.MEDIUM, dtype=np.uint8)
    valid = np.ones((1, 2), dtype=bool)
    track = torso_descriptor(body_at(0.0, 0.0))[None]
    result = associate(positions, confidence, valid, track)
    assert result.person_of_body.tolist() == [[-1, 0]]
    assert result.duplicates.tolist() == [[True, False]]
    kept = associate(positions, confidence, valid, track, duplicate_mm=None)
    assert kept.person_of_body.tolist() == [[1, 0]]  # without the duplicate policy: a new person


def test_confirmed_tracks_win_over_tentative_ones() -> None:
    positions = np.full((1, 1, N_JOINTS, 3), np.nan)
    positions[0, 0] = body_at(0.0, 0.0)
    confidence = np.full((1, 1, N_JOINTS), Confidence.MEDIUM, dtype=np.uint8)
    tracks = np.stack([torso_descriptor(body_at(0.0, 50.0)), torso_descriptor(body_at(0.0, 200.0))])
    result = associate(positions, confidence, np.ones((1, 1), bool), tracks, np.array([False, True]))
    assert result.person_of_body[0, 0] == 1


def test_gate_rejects_far_bodies() -> None:
    positions = np.full((1, 1, N_JOINTS, 3), np.nan)
    positions[0, 0] = body_at(600.0, 0.0)
    confidence = np.full((1, 1, N_JOINTS), Confidence.MEDIUM, dtype=np.uint8)
    track = torso_descriptor(body_at(0.0, 0.0))[None]
    result = associate(positions, confidence, np.ones((1, 1), bool), track, gate_mm=450.0)
    assert result.person_of_body[0, 0] == 1 and result.n_sensors_seen.tolist() == [0, 1]


def test_shape_errors() -> None:
    with pytest.raises(ValueError, match="positions must have shape"):
        associate(np.zeros((2, 3, 3)), np.zeros((2, 3)), np.zeros(2, bool), np.zeros((0, 7, 3)))


def test_nanmedian_matches_numpy_and_is_silent_on_all_nan() -> None:
    rng = np.random.default_rng(0)
    values = rng.normal(size=(5, 6, 4))
    values[rng.random(values.shape) < 0.3] = np.nan
    values[:, :, 0] = 1.0  # every slice has a value
    np.testing.assert_allclose(nanmedian_axis(values, 1), np.nanmedian(values, axis=1))
    assert np.isnan(nanmedian_axis(np.full((2, 3), np.nan), 1)).all()
    # Any axis, negative ones too (the axis is moved last by a transpose); the input is left untouched.
    values = rng.normal(size=(4, 5, 6, 3))
    values[rng.random(values.shape) < 0.3] = np.nan
    values[0, 0, 0] = 1.0
    before = values.copy()
    for axis in (0, 1, 2, 3, -1, -3):
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # numpy warns on its all-NaN slices
            expected = np.nanmedian(values, axis=axis)
        np.testing.assert_array_equal(nanmedian_axis(values, axis), expected)
    np.testing.assert_array_equal(values, before)


def test_descriptor_distance_needs_common_points() -> None:
    a = torso_descriptor(POSE)
    b = a.copy()
    b[2:] = np.nan
    assert descriptor_distance(a, b, min_common_points=3) == np.inf
    assert descriptor_distance(a, b + 10.0, min_common_points=2) == pytest.approx(np.sqrt(300.0))


def test_gather_candidates_scatters_rows() -> None:
    positions = np.arange(2 * 2 * N_JOINTS * 3, dtype=float).reshape(2, 2, N_JOINTS, 3)
    confidence = np.ones((2, 2, N_JOINTS), dtype=np.uint8)
    cand, conf = gather_candidates(positions, confidence, np.array([[1, -1], [0, 1]]), 2)
    np.testing.assert_array_equal(cand[1, 0], positions[0, 0])
    np.testing.assert_array_equal(cand[0, 1], positions[1, 0])
    np.testing.assert_array_equal(cand[1, 1], positions[1, 1])
    assert np.isnan(cand[0, 0]).all() and conf[0, 0].sum() == 0
