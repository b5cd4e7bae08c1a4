"""The fusion step's glue kernels (candidate selection, the track's prediction) against their numpy references on
random inputs: NaN and infinite coordinates, every confidence, no bodies, a single sensor, joints without a track."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from skelfuse.fusion.pipeline import FusionState, predicted_positions, select_candidates
from skelfuse.fusion.reference import pipeline as pipeline_reference
from skelfuse.schema.skeleton import N_JOINTS


@settings(max_examples=100, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_bodies=st.integers(0, 3),
    n_sensors=st.integers(1, 5),
    missing=st.sampled_from([0.0, 0.3, 1.0]),
    min_confidence=st.sampled_from([None, 0, 1, 2]),
)
def test_candidate_selection_kernel_equals_the_numpy_reference(seed, n_bodies, n_sensors, missing, min_confidence):
    rng = np.random.default_rng(seed)
    candidates = rng.normal(0.0, 500.0, (n_bodies, n_sensors, N_JOINTS, 3))
    bad = rng.random(candidates.shape) < missing / 3  # single coordinates: NaN, +inf or -inf
    candidates[bad] = rng.choice([np.nan, np.inf, -np.inf], bad.sum())
    confidence = rng.integers(0, 4, candidates.shape[:3]).astype(np.uint8)
    got = select_candidates(candidates, confidence, min_confidence)
    with np.errstate(invalid="ignore"):  # inf - inf in the reference's sum: NaN, as meant
        want = pipeline_reference.select_candidates(candidates, confidence, min_confidence)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    assert got[0].dtype == want[0].dtype and got[1].dtype == want[1].dtype == np.uint8


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_bodies=st.integers(0, 3), dt_s=st.sampled_from([1 / 30, 0.05]))
def test_prediction_kernel_equals_the_numpy_reference(seed, n_bodies, dt_s):
    rng = np.random.default_rng(seed)
    previous = rng.normal(0.0, 500.0, (n_bodies, N_JOINTS, 3))
    previous[rng.random(previous.shape[:2]) < 0.3] = np.nan
    state = FusionState(
        previous=previous,
        x=rng.normal(0.0, 500.0, (n_bodies, N_JOINTS, 2, 3)),
        P=np.zeros((n_bodies, N_JOINTS, 3)),
        coast=rng.integers(-1, 3, (n_bodies, N_JOINTS)).astype(np.int32),  # -1: no track
    )
    got = predicted_positions(state, dt_s)
    want = pipeline_reference.predicted_positions(state, dt_s)
    np.testing.assert_allclose(got, want, rtol=1e-15, atol=0)  # the same sum
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
