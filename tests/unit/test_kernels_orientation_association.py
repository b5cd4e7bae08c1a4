"""The orientation, association and position uncertainty kernels against their references on random inputs.

The orientation stage (skelfuse.fusion.kernels.orientation) against its numpy form (skelfuse.fusion.reference.
orientation): NaN joints, NaN views, no bodies, no views, a single sensor, with and without history; identical view
counts and NaN patterns, quaternions and filter states within 1e-9. The Hungarian solver against
scipy.optimize.linear_sum_assignment: the same pairs on random matrices with ties, rectangular (both ways), empty,
and with infinite costs (and the same refusals: infeasible, NaN). The association's matching (descriptors, costs,
cascade, duplicates) and the persons' descriptors against their numpy form with scipy's solver
(skelfuse.fusion.reference.association). The position uncertainty against its numpy parts composed.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linear_sum_assignment

from skelfuse.fusion import kernels
from skelfuse.fusion import orientation as orient
from skelfuse.fusion.association import (
    N_DESCRIPTOR,
    assign_to_tracks,
    match_tracks,
    person_descriptors,
    torso_descriptor,
)
from skelfuse.fusion.presets import FusionParams
from skelfuse.fusion.reference import association as association_reference
from skelfuse.fusion.reference import orientation as orientation_reference
from skelfuse.fusion.reference import uncertainty as uncertainty_reference
from skelfuse.fusion.uncertainty import position_uncertainty
from skelfuse.schema.skeleton import N_JOINTS

ATOL = 1e-9


def _views(rng: np.random.Generator, positions: np.ndarray, n_sensors: int, spread_rad: float) -> np.ndarray:
    """(B, S, J, 4) world quaternions: the (complete) body's own frames turned by random rotations of
    ``spread_rad``."""
    base = orient.apply_derived(orient.body_hint_frames(positions))
    turn = orient.quat_from_rotvec(rng.normal(0.0, spread_rad, (positions.shape[0], n_sensors, N_JOINTS, 3)))
    return orient.quat_multiply(turn, base[:, None])


@settings(max_examples=150, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_bodies=st.integers(0, 3),
    n_sensors=st.integers(0, 6),
    missing_joints=st.sampled_from([0.0, 0.2, 1.0]),
    missing_views=st.sampled_from([0.0, 0.3, 1.0]),
    spread_rad=st.sampled_from([0.05, 0.5, 3.0]),
    history=st.sampled_from(["none", "some", "all"]),
    agree_deg=st.sampled_from([10.0, 45.0, 180.0]),
    no_views=st.booleans(),
)
def test_orientation_kernel_equals_the_numpy_reference(
    seed, n_bodies, n_sensors, missing_joints, missing_views, spread_rad, history, agree_deg, no_views
):
    rng = np.random.default_rng(seed)
    positions = rng.normal(0.0, 300.0, (n_bodies, 1, 3)) + rng.normal(0.0, 250.0, (n_bodies, N_JOINTS, 3))
    views = _views(rng, positions, n_sensors, spread_rad)
    positions[rng.random((n_bodies, N_JOINTS)) < missing_joints] = np.nan
    views[rng.random(views.shape[:3]) < missing_views] = np.nan
    usable = rng.random(views.shape[:3]) < 0.8
    has_history = rng.random((n_bodies, N_JOINTS, 1)) < {"none": 0.0, "some": 0.5, "all": 1.0}[history]
    quats_prev = np.where(has_history, orient.quat_from_rotvec(rng.normal(0.0, 1.5, (n_bodies, N_JOINTS, 3))), 0.0)
    omega_prev = np.where(has_history, rng.normal(0.0, 2.0, (n_bodies, N_JOINTS, 3)), 0.0)
    params = orient.OrientationParams(agree_deg=agree_deg, alpha=float(rng.uniform(0.1, 1.0)), beta=0.3)
    dt_s = float(rng.choice([1.0 / 30.0, 0.1]))
    args = (None, None) if no_views else (views, usable)
    got = orient.fuse_orientations(positions, *args, quats_prev, omega_prev, params, dt_s)
    want = orientation_reference.fuse_orientations(positions, *args, quats_prev, omega_prev, params, dt_s)
    np.testing.assert_array_equal(got[0].n_views, want[0].n_views)
    assert got[0].n_views.dtype == want[0].n_views.dtype == np.int16
    for name, a, b in (("quats", got[0].quats, want[0].quats), ("state", got[1], want[1]), ("omega", got[2], want[2])):
        assert a.shape == b.shape, name
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=name)
        np.testing.assert_allclose(a, b, rtol=0, atol=ATOL, err_msg=name)


def test_orientation_kernel_checks_shapes():
    with pytest.raises(ValueError, match="view_quats must have shape"):
        orient.fuse_orientations(
            np.zeros((1, N_JOINTS, 3)),
            np.zeros((2, 1, N_JOINTS, 4)),
            np.ones((2, 1, N_JOINTS), bool),
            *orient.init_orientation_state(1),
            orient.OrientationParams(),
            0.1,
        )


def _scipy_pairs(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray] | str:
    try:
        return linear_sum_assignment(matrix)
    except ValueError as error:
        return "infeasible" if "infeasible" in str(error) else "invalid"


@settings(max_examples=400, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_rows=st.integers(0, 7),
    n_cols=st.integers(0, 7),
    kind=st.sampled_from(["ties", "constant", "real", "inf", "nan", "big"]),
)
def test_hungarian_kernel_gives_scipys_assignment(seed, n_rows, n_cols, kind):
    rng = np.random.default_rng(seed)
    matrix = {
        "ties": lambda: rng.integers(0, 3, (n_rows, n_cols)).astype(np.float64),
        "constant": lambda: np.full((n_rows, n_cols), 7.0),
        "real": lambda: rng.normal(0.0, 100.0, (n_rows, n_cols)),
        "inf": lambda: np.where(rng.random((n_rows, n_cols)) < 0.4, np.inf, rng.integers(0, 4, (n_rows, n_cols))),
        "nan": lambda: np.where(rng.random((n_rows, n_cols)) < 0.2, np.nan, rng.random((n_rows, n_cols))),
        "big": lambda: np.where(rng.random((n_rows, n_cols)) < 0.5, 1e12, rng.integers(0, 500, (n_rows, n_cols))),
    }[kind]().astype(np.float64)
    rows, cols, status = kernels.load().association.linear_sum_assignment(np.ascontiguousarray(matrix))
    want = _scipy_pairs(matrix)
    if isinstance(want, str):
        assert status == {"invalid": 1, "infeasible": 2}[want]
    else:
        assert status == 0
        np.testing.assert_array_equal(rows, want[0])
        np.testing.assert_array_equal(cols, want[1])


@settings(max_examples=200, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_sensors=st.integers(0, 5),
    n_bodies=st.integers(0, 5),
    n_tracks=st.integers(0, 5),
    noise=st.sampled_from(["grid", "spread", "shared"]),
    missing=st.sampled_from([0.0, 0.2, 0.6]),
    min_common_points=st.integers(1, 4),
)
def test_assignment_kernel_equals_the_numpy_reference(
    seed, n_sensors, n_bodies, n_tracks, noise, missing, min_common_points
):
    """People on a coarse grid (bodies within the gate of several tracks, exact cost ties), spread, or every view
    of a person identical (a duplicate skeleton: two bodies of one sensor at exactly the same cost)."""
    rng = np.random.default_rng(seed)
    people = rng.integers(-3, 4, (n_tracks + 2, 1, 3)) * 150.0 + rng.integers(-1, 2, (1, N_DESCRIPTOR, 3)) * 50.0
    shape = (n_sensors, n_bodies, N_DESCRIPTOR, 3)
    noise = {
        "grid": lambda: rng.integers(-1, 2, shape) * 50.0,
        "spread": lambda: rng.normal(0.0, 60.0, shape),
        "shared": lambda: rng.normal(0.0, 60.0),
    }[noise]()
    body_desc = people[rng.integers(0, people.shape[0], (n_sensors, n_bodies))] + noise
    body_desc[rng.random(body_desc.shape[:3]) < missing] = np.nan
    tracks = people[rng.integers(0, people.shape[0], n_tracks)]
    tracks[rng.random(tracks.shape[:2]) < missing / 2] = np.nan
    usable = rng.random((n_sensors, n_bodies)) < 0.9
    confirmed = rng.random(n_tracks) < 0.7
    gate = rng.choice([200.0, 450.0, 900.0], n_tracks)
    got = assign_to_tracks(body_desc, usable, tracks, confirmed, gate, min_common_points)
    want = association_reference.assign_to_tracks(body_desc, usable, tracks, confirmed, gate, min_common_points)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_allclose(got[1], want[1], rtol=0, atol=ATOL)
    np.testing.assert_allclose(got[2], want[2], rtol=0, atol=ATOL)
    assert [a.dtype for a in got] == [b.dtype for b in want]


@settings(max_examples=100, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_sensors=st.integers(0, 6),
    n_bodies=st.integers(0, 4),
    n_persons=st.integers(0, 5),
    missing=st.sampled_from([0.0, 0.3, 1.0]),
)
def test_person_descriptors_kernel_equals_the_numpy_reference(seed, n_sensors, n_bodies, n_persons, missing):
    """Rows seen by several sensors, by one, by none; at most one body per sensor and row, as the association
    gives them."""
    rng = np.random.default_rng(seed)
    body_desc = rng.integers(-3, 4, (n_sensors, n_bodies, N_DESCRIPTOR, 3)) * 50.0
    body_desc[rng.random(body_desc.shape[:3]) < missing] = np.nan
    person = np.full((n_sensors, n_bodies), -1, dtype=np.int64)
    for s in range(n_sensors):
        rows = rng.permutation(max(n_persons, n_bodies))[:n_bodies]
        person[s] = np.where((rows < n_persons) & (rng.random(n_bodies) < 0.8), rows, -1)
    got = person_descriptors(body_desc, person, n_persons)
    want = association_reference.person_descriptors(body_desc, person, n_persons)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    assert got[1].dtype == want[1].dtype == np.int64


@settings(max_examples=120, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_bodies=st.integers(0, 3),
    n_sensors=st.integers(1, 6),
    missing=st.sampled_from([0.0, 0.3, 1.0]),
    with_filter=st.booleans(),
)
def test_uncertainty_kernel_equals_the_numpy_reference(seed, n_bodies, n_sensors, missing, with_filter):
    """Joints seen by several views, one, none; tracks new, measured, coasting and absent."""
    rng = np.random.default_rng(seed)
    merged = rng.normal(0.0, 300.0, (n_bodies, N_JOINTS, 3))
    candidates = merged[:, None] + rng.normal(0.0, 40.0, (n_bodies, n_sensors, N_JOINTS, 3))
    candidates[rng.random(candidates.shape[:3]) < missing] = np.nan
    n_agree = rng.integers(0, n_sensors + 1, (n_bodies, N_JOINTS))
    merged[n_agree == 0] = np.nan
    fused = np.where(rng.random((n_bodies, N_JOINTS, 1)) < 0.9, merged + 1.0, np.nan)
    previous_cov = np.abs(rng.normal(0.0, 100.0, (n_bodies, N_JOINTS, 3)))
    coast_before = rng.integers(-1, 3, n_bodies * N_JOINTS)
    coast_after = rng.integers(-1, 3, n_bodies * N_JOINTS)
    params = FusionParams(filter="cv_kalman" if with_filter else None, position_std=True)
    torso = np.array([0, 1, 2, 3, 18, 22])
    args = (candidates, merged, n_agree, fused, previous_cov, coast_before, coast_after, torso, params, 1.0 / 30.0)
    got = position_uncertainty(*args)
    want = uncertainty_reference.position_uncertainty(*args)
    for name, a, b in zip(("std", "cov", "agreement"), got, want, strict=True):
        assert a.shape == b.shape, name
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=name)
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=ATOL, err_msg=name)


@settings(max_examples=120, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_sensors=st.integers(0, 4),
    n_bodies=st.integers(0, 4),
    n_tracks=st.integers(0, 4),
    missing=st.sampled_from([0.0, 0.2, 0.6]),
    duplicate_mm=st.sampled_from([None, 100.0, 250.0, 1000.0]),
)
def test_track_matching_kernel_equals_the_numpy_reference(seed, n_sensors, n_bodies, n_tracks, missing, duplicate_mm):
    """Whole skeletons: descriptors, usable bodies, assignment and duplicates (two skeletons of one person in one
    sensor: the duplicate rule decides)."""
    rng = np.random.default_rng(seed)
    people = rng.integers(-3, 4, (n_tracks + 2, 1, 3)) * 150.0 + rng.normal(0.0, 100.0, (1, N_JOINTS, 3))
    positions = people[rng.integers(0, people.shape[0], (n_sensors, n_bodies))]
    positions = positions + rng.integers(-1, 2, positions.shape) * 40.0
    positions[rng.random(positions.shape[:3]) < missing] = np.nan
    valid = rng.random((n_sensors, n_bodies)) < 0.9
    tracks = torso_descriptor(people[rng.integers(0, people.shape[0], n_tracks)])
    confirmed = rng.random(n_tracks) < 0.7
    gate = rng.choice([200.0, 450.0], n_tracks)
    args = (positions, valid, tracks, confirmed, gate, 3, duplicate_mm)
    got = match_tracks(*args)
    want = association_reference.match_tracks(*args)
    for a, b in zip(got, want, strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype
        np.testing.assert_allclose(a, b, rtol=0, atol=ATOL)
