"""DBSCAN merge: clusters equal scikit-learn's, documented weights / ties / empty cases, invariances."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from sklearn.cluster import DBSCAN

from skelfuse.fusion.merge import merge_average, merge_dbscan
from skelfuse.fusion.reference.merge import cluster_matrix

EPS = 100.0
RNG_SEED = 1124


def _partition_matches_sklearn(points: np.ndarray, same: np.ndarray) -> None:
    valid = ~np.isnan(points).any(axis=1)
    idx = np.flatnonzero(valid)
    assert not same[~valid].any() and not same[:, ~valid].any()
    if len(idx) == 0:
        return
    labels = DBSCAN(eps=EPS, min_samples=1).fit(points[idx]).labels_
    np.testing.assert_array_equal(same[np.ix_(idx, idx)] > 0, labels[:, None] == labels[None, :])


def test_clusters_equal_sklearn_dbscan_on_random_sets():
    rng = np.random.default_rng(RNG_SEED)
    for n in (1, 2, 5, 7, 12):
        pts = rng.normal(0.0, 120.0, (300, n, 3))
        pts[rng.random((300, n)) < 0.15] = np.nan
        same = cluster_matrix(pts, EPS)
        for k in range(len(pts)):
            _partition_matches_sklearn(pts[k], same[k])


def test_clusters_equal_sklearn_with_duplicates_and_chains_near_eps():
    rng = np.random.default_rng(RNG_SEED + 1)
    sets = []
    for _ in range(200):
        n = 7
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        # Chain links just inside/outside eps. Exactly eps is left out: there float rounding (~1e-13 mm), not
        # the algorithm, decides, and scikit-learn rounds differently.
        gaps = EPS + rng.choice([-1e-9, 1e-9, -1e-6, 1e-6, -1e-3, 1e-3, -20.0], size=n)
        steps = np.concatenate([[0.0], np.cumsum(gaps[:-1])])
        pts = rng.normal(0.0, 500.0, 3) + steps[:, None] * direction
        dup = rng.integers(0, n, 2)
        pts[dup[0]] = pts[dup[1]]  # an exact duplicate
        sets.append(rng.permutation(pts))
    pts = np.array(sets)
    same = cluster_matrix(pts, EPS)
    for k in range(len(pts)):
        _partition_matches_sklearn(pts[k], same[k])


def _one_joint(sensor_xyz, conf=None, reference=None, previous=None, **kw):
    """Merge one joint of one body: sensor_xyz (S, 3); returns (position, n_agree, confidence, members)."""
    S = len(sensor_xyz)
    pos = np.full((1, S, 1, 3), np.nan)
    pos[0, :, 0] = sensor_xyz
    c = np.full((1, S, 1), 2, dtype=np.uint8) if conf is None else np.asarray(conf, np.uint8).reshape(1, S, 1)
    ref = None if reference is None else np.asarray(reference, float).reshape(1, 1, 3)
    prev = None if previous is None else np.asarray(previous, float).reshape(1, 1, 3)
    r = merge_dbscan(pos, c, ref, prev, eps_mm=EPS, **kw)
    return r.positions[0, 0], int(r.n_agree[0, 0]), int(r.confidence[0, 0]), r.members[0, 0]


def test_reference_weight_decides_between_clusters():
    sensors = [[0.0, 0, 0], [10.0, 0, 0], [1000.0, 0, 0]]
    # Without the reference the pair {0, 1} (score 2) beats the lone sensor 2 (score 1).
    pos, n, _, members = _one_joint(sensors, reference_weight=None, previous_weight=None)
    np.testing.assert_allclose(pos, [5.0, 0, 0])
    assert n == 2 and members.tolist() == [True, True, False]
    # The reference (weight 2) next to sensor 2 makes that cluster score 3; it votes but is not averaged.
    pos, n, _, _ = _one_joint(sensors, reference=[1050.0, 0, 0], reference_weight=2.0, previous_weight=None)
    np.testing.assert_allclose(pos, [1000.0, 0, 0])
    assert n == 1


def test_tie_prefers_cluster_with_previous_position():
    # {s0, s1, prev} scores 1 + 1 + 1 = 3, {s2, s3, s4} scores 3: the previous position breaks the tie.
    sensors = [[0.0, 0, 0], [20.0, 0, 0], [800.0, 0, 0], [810.0, 0, 0], [820.0, 0, 0]]
    pos, n, _, _ = _one_joint(sensors, previous=[10.0, 0, 0], reference_weight=None, previous_weight=1.0)
    np.testing.assert_allclose(pos, [10.0, 0, 0])
    assert n == 2


def test_tie_prefers_more_sensors_then_confidence_then_smaller_centroid():
    # {s0, s1, s2} = 3 vs {s3} + reference (weight 2) = 3: more sensors win.
    sensors = [[0.0, 0, 0], [10.0, 0, 0], [20.0, 0, 0], [900.0, 0, 0]]
    pos, n, _, _ = _one_joint(sensors, reference=[900.0, 0, 0], reference_weight=2.0, previous_weight=None)
    np.testing.assert_allclose(pos, [10.0, 0, 0])
    assert n == 3
    # Two pairs: the one with the higher summed confidence wins...
    sensors = [[0.0, 0, 0], [10.0, 0, 0], [900.0, 0, 0], [910.0, 0, 0]]
    pos, *_ = _one_joint(sensors, conf=[1, 2, 2, 2], reference_weight=None, previous_weight=None)
    np.testing.assert_allclose(pos, [905.0, 0, 0])
    # ...and with equal confidence the smaller centroid x, whatever the sensor order.
    for order in ([0, 1, 2, 3], [2, 3, 0, 1], [3, 0, 2, 1]):
        pos, *_ = _one_joint(np.array(sensors)[order], reference_weight=None, previous_weight=None)
        np.testing.assert_allclose(pos, [5.0, 0, 0])


def test_cluster_without_sensor_cannot_win():
    # Reference (2) + previous (1) far from the only sensor: their cluster scores 3 but holds no sensor.
    pos, n, conf, _ = _one_joint([[0.0, 0, 0]], reference=[500.0, 0, 0], previous=[510.0, 0, 0])
    np.testing.assert_allclose(pos, [0.0, 0, 0])
    assert (n, conf) == (1, 2)


def test_reference_bridges_two_groups_like_dbscan():
    # Sensors 160 mm apart are not neighbours, but the reference between them (80 mm from each) joins them.
    pos, n, _, _ = _one_joint([[0.0, 0, 0], [160.0, 0, 0]], reference=[80.0, 0, 0], previous_weight=None)
    np.testing.assert_allclose(pos, [80.0, 0, 0])
    assert n == 2


def test_all_nan_joint_stays_nan_even_with_reference_and_previous():
    pos, n, conf, members = _one_joint(np.full((3, 3), np.nan), reference=[0.0, 0, 0], previous=[0.0, 0, 0])
    assert np.isnan(pos).all() and n == 0 and conf == 0 and not members.any()


finite = st.floats(-3000.0, 3000.0, allow_nan=False, allow_infinity=False)


@settings(max_examples=60, deadline=None)
@given(
    arrays(np.float64, (2, 5, 4, 3), elements=finite),
    arrays(np.uint8, (2, 5, 4), elements=st.integers(0, 3)),
    arrays(np.bool_, (2, 5, 4)),
    st.permutations(range(5)),
)
def test_merge_is_invariant_to_sensor_order(pos, conf, missing, order):
    pos = pos.copy()
    pos[missing] = np.nan
    ref = np.nanmean(np.where(missing[..., None], np.nan, pos), axis=1) if (~missing).any(axis=1).all() else None
    prev = pos[:, 0] + 30.0
    a = merge_dbscan(pos, conf, ref, prev, eps_mm=EPS)
    b = merge_dbscan(pos[:, order], conf[:, order], ref, prev, eps_mm=EPS)
    np.testing.assert_allclose(a.positions, b.positions, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(a.n_agree, b.n_agree)
    np.testing.assert_array_equal(a.confidence, b.confidence)
    np.testing.assert_array_equal(a.members[..., order], b.members)


@settings(max_examples=40, deadline=None)
@given(arrays(np.float64, (1, 1, 32, 3), elements=finite), st.integers(1, 6))
def test_identical_sensors_fuse_to_the_input(skeleton, n_sensors):
    pos = np.repeat(skeleton, n_sensors, axis=1)
    conf = np.full(pos.shape[:3], 2, dtype=np.uint8)
    for result in (merge_dbscan(pos, conf, skeleton[:, 0], skeleton[:, 0] + 1000.0), merge_average(pos, conf)):
        np.testing.assert_allclose(result.positions, skeleton[:, 0], rtol=0, atol=1e-9)
        assert (result.n_agree == n_sensors).all()


def test_average_is_mean_of_valid_candidates():
    pos = np.array([[[[0.0, 0, 0]], [[10.0, 20, 30]], [[np.nan] * 3]]])  # (1, 3, 1, 3)
    conf = np.array([[[1], [2], [2]]], dtype=np.uint8)
    r = merge_average(pos, conf)
    np.testing.assert_allclose(r.positions[0, 0], [5.0, 10.0, 15.0])
    assert r.n_agree[0, 0] == 2 and r.confidence[0, 0] == 2
    assert r.members[0, 0].tolist() == [True, True, False]
    empty = merge_average(np.full((1, 2, 1, 3), np.nan), np.zeros((1, 2, 1), np.uint8))
    assert np.isnan(empty.positions).all() and empty.n_agree[0, 0] == 0
