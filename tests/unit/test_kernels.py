"""The compiled kernels against their numpy references (skelfuse.fusion.reference) on random inputs.

Inputs include NaN joints, whole views missing, bodies with no view at all, no bodies, a single sensor, and
positions on a coarse grid, so that clusters tie and pairs lie exactly eps apart. Identical: cluster memberships,
counts, confidences, hold-out reasons, coasting counters; within 1e-9: positions and filter states.
"""

from __future__ import annotations

import logging
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skelfuse.fusion import kernels, plausibility, realign, tracks
from skelfuse.fusion.association import N_DESCRIPTOR
from skelfuse.fusion.filters import filter_step, init_filter_state
from skelfuse.fusion.kernels import plausibility as plausibility_kernel
from skelfuse.fusion.merge import merge_dbscan
from skelfuse.fusion.plausibility import CHECK_BONES, PlausibilityParams, check_views
from skelfuse.fusion.presets import FusionParams
from skelfuse.fusion.reference import filters as filters_reference
from skelfuse.fusion.reference import merge as merge_reference
from skelfuse.fusion.reference import plausibility as plausibility_reference
from skelfuse.fusion.reference import realign as realign_reference
from skelfuse.fusion.reference import tracks as tracks_reference
from skelfuse.fusion.tracks import TrackParams
from skelfuse.schema.skeleton import MIRROR, N_JOINTS
from skelfuse.service.node import prepare_kernels

ATOL = 1e-9


def _points(rng: np.random.Generator, shape: tuple[int, ...], grid: bool, missing: float) -> np.ndarray:
    """Random points, mm: on a 50 mm grid (ties, pairs exactly eps apart) or spread; NaN rows at rate ``missing``."""
    if grid:
        points = rng.integers(-2, 3, (*shape, 3)) * 50.0
    else:
        points = rng.normal(0.0, 80.0, (*shape, 3))
    points[rng.random(shape) < missing] = np.nan
    return points


@settings(max_examples=150, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_bodies=st.integers(0, 3),
    n_sensors=st.integers(1, 7),
    n_joints=st.integers(1, 4),
    grid=st.booleans(),
    missing=st.sampled_from([0.0, 0.3, 1.0]),
    eps_mm=st.sampled_from([50.0, 75.0, 100.0]),
    reference_weight=st.sampled_from([None, 2.0, 0.5]),
    previous_weight=st.sampled_from([None, 1.0, 3.0]),
)
def test_merge_kernel_equals_the_numpy_reference(
    seed, n_bodies, n_sensors, n_joints, grid, missing, eps_mm, reference_weight, previous_weight
):
    rng = np.random.default_rng(seed)
    positions = _points(rng, (n_bodies, n_sensors, n_joints), grid, missing)
    confidence = rng.integers(0, 4, (n_bodies, n_sensors, n_joints)).astype(np.uint8)
    reference = _points(rng, (n_bodies, n_joints), grid, 0.2)
    previous = _points(rng, (n_bodies, n_joints), grid, 0.3)
    options = {"eps_mm": eps_mm, "reference_weight": reference_weight, "previous_weight": previous_weight}
    got = merge_dbscan(positions, confidence, reference, previous, **options)
    want = merge_reference.merge_dbscan(positions, confidence, reference, previous, **options)
    np.testing.assert_array_equal(got.members, want.members)
    np.testing.assert_array_equal(got.n_agree, want.n_agree)
    np.testing.assert_array_equal(got.confidence, want.confidence)
    np.testing.assert_allclose(got.positions, want.positions, rtol=0, atol=ATOL)
    for field in ("positions", "n_agree", "confidence", "members"):
        assert getattr(got, field).dtype == getattr(want, field).dtype, field


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    kind=st.sampled_from(["paper_kalman", "cv_kalman", "alpha_beta", None]),
    output=st.sampled_from(["predicted", "posterior"]),
    scale_r=st.booleans(),
    n_joints=st.integers(0, 40),
    missing=st.sampled_from([0.0, 0.3, 0.8]),
    max_coast_frames=st.integers(0, 4),
)
def test_filter_kernel_equals_the_numpy_reference_over_a_sequence(
    seed, kind, output, scale_r, n_joints, missing, max_coast_frames
):
    rng = np.random.default_rng(seed)
    params = FusionParams(
        filter=kind, kalman_output=output, cv_scale_r_by_agree=scale_r, max_coast_frames=max_coast_frames
    )
    got = want = init_filter_state(n_joints)
    for _ in range(12):
        z = rng.normal(0.0, 500.0, (n_joints, 3))
        z[rng.random(n_joints) < missing] = np.nan
        n_agree = rng.integers(0, 5, n_joints).astype(np.int16)
        dt_s = float(rng.uniform(0.02, 0.05))
        out, *got = filter_step(*got, z, n_agree, params, dt_s)
        out_reference, *want = filters_reference.filter_step(*want, z, n_agree, params, dt_s)
        np.testing.assert_allclose(out, out_reference, rtol=1e-12, atol=ATOL)
        np.testing.assert_allclose(got[0], want[0], rtol=1e-12, atol=ATOL)  # x
        np.testing.assert_allclose(got[1], want[1], rtol=1e-12, atol=ATOL)  # P
        np.testing.assert_array_equal(got[2], want[2])  # coast
        assert got[2].dtype == want[2].dtype == np.int32


def _standing_body(rng: np.random.Generator) -> np.ndarray:
    """(J, 3) a random body around a pelvis at the origin, neck above it, mm."""
    body = rng.normal(0.0, 150.0, (N_JOINTS, 3))
    body[plausibility.J["PELVIS"]] = 0.0
    body[plausibility.J["NECK"]] = (0.0, 0.0, 500.0)
    return body


@settings(max_examples=120, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_bodies=st.integers(0, 3),
    n_sensors=st.integers(1, 5),
    missing_joints=st.sampled_from([0.0, 0.2, 0.7]),
    ready=st.booleans(),
)
def test_plausibility_kernel_equals_the_numpy_reference(seed, n_bodies, n_sensors, missing_joints, ready):
    rng = np.random.default_rng(seed)
    predicted = np.array([_standing_body(rng) for _ in range(n_bodies)]).reshape(n_bodies, N_JOINTS, 3)
    views = predicted[:, None] + rng.normal(0.0, 20.0, (n_bodies, n_sensors, N_JOINTS, 3))
    kind = rng.integers(0, 5, (n_bodies, n_sensors))
    views[kind == 1] += rng.normal(0.0, 300.0, 3)  # teleported
    views[kind == 2] *= (1.0, 1.0, -1.0)  # upside down
    views[kind == 3] *= 1.4  # another body size
    views[kind == 4] = np.nan  # the view does not see the body
    views[rng.random(views.shape[:3]) < missing_joints] = np.nan
    learned = plausibility.bone_lengths(predicted) * rng.uniform(0.9, 1.1, (n_bodies, len(CHECK_BONES)))
    learned[rng.random(learned.shape) < 0.2] = np.nan
    bones_ready = np.full(n_bodies, ready)
    params = PlausibilityParams(
        gate_mm=250.0, up_cos=0.0, bone_ratio=0.25, joint_speed_mm_s=np.inf, release_frames=3, follow_frames=10
    )
    got = check_views(views, predicted, learned, bones_ready, params)
    want = plausibility_reference.check_views(views, predicted, learned, bones_ready, params)
    np.testing.assert_array_equal(got, want)
    assert got.dtype == want.dtype == np.uint8


def _plausibility_frame(rng: np.random.Generator, bodies: np.ndarray, n_sensors: int, missing_joints: float):
    """Views of the bodies: some teleported (by one offset shared by the body's views, or each its own), upside
    down, of another size or absent; NaN joints."""
    predicted = bodies + rng.normal(0.0, 5.0, (len(bodies), 1, 3))
    views = predicted[:, None] + rng.normal(0.0, 20.0, (len(bodies), n_sensors, N_JOINTS, 3))
    kind = rng.integers(0, 6, (len(bodies), n_sensors))
    views[kind == 1] += rng.normal(0.0, 300.0, 3)  # teleported, every such view alike: they agree elsewhere
    views[kind == 5] += rng.normal(0.0, 300.0, ((kind == 5).sum(), 1, 3))  # teleported, each its own way
    views[kind == 2] *= (1.0, 1.0, -1.0)  # upside down
    views[kind == 3] *= 1.4  # another body size
    views[kind == 4] = np.nan  # the view does not see the body
    views[rng.random(views.shape[:3]) < missing_joints] = np.nan
    confidence = rng.integers(0, 4, views.shape[:3]).astype(np.uint8)
    return predicted, views, confidence


@settings(max_examples=80, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_bodies=st.integers(0, 3),
    n_sensors=st.integers(1, 5),
    missing_joints=st.sampled_from([0.0, 0.2, 0.7]),
    joint_speed=st.sampled_from([np.inf, 3000.0]),
)
def test_plausibility_stage_kernels_equal_the_numpy_reference_over_a_sequence(
    seed, n_bodies, n_sensors, missing_joints, joint_speed
):
    rng = np.random.default_rng(seed)
    params = PlausibilityParams(
        gate_mm=250.0, up_cos=0.0, bone_ratio=0.25, joint_speed_mm_s=joint_speed, release_frames=2, follow_frames=3
    )
    bodies = np.array([_standing_body(rng) for _ in range(n_bodies)]).reshape(n_bodies, N_JOINTS, 3)
    got = replace(
        plausibility.init_plausibility_state(n_bodies, n_sensors),
        bones=plausibility.bone_lengths(bodies),
        bone_frames=rng.integers(0, 12, n_bodies).astype(np.int32),  # some ready to judge the size
    )
    want = got
    for _ in range(6):  # the hysteresis, the follow rule and the bone learning carry over
        predicted, views, confidence = _plausibility_frame(rng, bodies, n_sensors, missing_joints)
        result, got = plausibility.plausibility_step(views, confidence, predicted, got, params)
        expected, want = plausibility_reference.plausibility_step(views, confidence, predicted, want, params)
        for field in ("held", "failed", "restart", "views", "views_confidence"):
            np.testing.assert_array_equal(getattr(result, field), getattr(expected, field), err_msg=field)
            assert getattr(result, field).dtype == getattr(expected, field).dtype, field
        for field in ("held", "release", "follow"):
            np.testing.assert_array_equal(getattr(got, field), getattr(want, field), err_msg=field)
            assert getattr(got, field).dtype == getattr(want, field).dtype, field
        merged = plausibility.merge_views(views, confidence, result, predicted, params, 1 / 30)
        merged_reference = plausibility_reference.merge_views(views, confidence, expected, predicted, params, 1 / 30)
        np.testing.assert_array_equal(merged[0], merged_reference[0])
        np.testing.assert_array_equal(merged[1], merged_reference[1])
        fused = predicted + rng.normal(0.0, 5.0, predicted.shape)
        n_agree = rng.integers(0, 3, fused.shape[:2]).astype(np.int16)
        n_agree[rng.random(n_bodies) < 0.3] = 0  # a body nothing was merged for: learns nothing
        got, want = (
            plausibility.learn_bones(got, fused, n_agree),
            plausibility_reference.learn_bones(want, fused, n_agree),
        )
        np.testing.assert_allclose(got.bones, want.bones, rtol=1e-12, atol=ATOL)
        np.testing.assert_array_equal(got.bone_frames, want.bone_frames)
        assert got.bone_frames.dtype == want.bone_frames.dtype == np.int32


def test_the_kernels_reasons_are_the_stages():
    kernel = plausibility_kernel
    assert (kernel.PLAUSIBLE, kernel.TELEPORT, kernel.UPSIDE_DOWN, kernel.BONES) == (
        plausibility.PLAUSIBLE,
        plausibility.TELEPORT,
        plausibility.UPSIDE_DOWN,
        plausibility.BONES,
    )


def test_the_cache_directory_is_the_users(monkeypatch, tmp_path):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert kernels.cache_dir() == tmp_path / "skelfuse" / "numba"
    assert not kernels.is_cached()
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))
    assert kernels.cache_dir() == tmp_path / "mine"


NUMBA_PROBE = """
import sys
import numpy as np
import skelfuse.fusion.pipeline as pipeline
import skelfuse.service.node
before = "numba" in sys.modules
params = pipeline.FusionParams()
candidates = np.zeros((1, 2, pipeline.N_JOINTS, 3))
pipeline.fuse(candidates, np.full((1, 2, pipeline.N_JOINTS), 2), pipeline.init_state(1, params), params)
print(before, "numba" in sys.modules)
"""


@pytest.mark.live  # a fresh interpreter
def test_numba_loads_with_the_first_fusion_not_with_the_modules():
    done = subprocess.run([sys.executable, "-c", NUMBA_PROBE], capture_output=True, text=True, timeout=300, check=True)
    assert done.stdout.split() == ["False", "True"]


def _sided_body(rng: np.random.Generator) -> np.ndarray:
    """(J, 3) a random body whose left joints lie 150 mm to one side and right joints to the other, mm."""
    body = rng.normal(0.0, 40.0, (N_JOINTS, 3))
    body[realign.PAPER_REALIGN_PAIRS[:, 0], 0] -= 150.0
    body[realign.PAPER_REALIGN_PAIRS[:, 1], 0] += 150.0
    return body


@settings(max_examples=150, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_bodies=st.integers(0, 3),
    n_sensors=st.integers(1, 6),
    missing_joints=st.sampled_from([0.0, 0.3, 0.9]),
    anchor=st.sampled_from(["kept", "mirrored", "partial", "none", "jumped"]),
    rules=st.fixed_dictionaries(
        {
            "recovery_frames": st.sampled_from([1, 3, 10]),
            "recovery_share": st.sampled_from([0.6, 0.75]),
            "majority_recovery_frames": st.sampled_from([None, 4]),
            "max_jump_mm": st.sampled_from([None, 200.0]),
            "rear_view_cos": st.sampled_from([None, -0.7, 0.3]),
            "rear_view_frames": st.sampled_from([1, 3]),
            "credit_frames": st.sampled_from([0, 5]),
        }
    ),
)
def test_temporal_realignment_kernel_equals_the_numpy_reference(
    seed, n_bodies, n_sensors, missing_joints, anchor, rules
):
    rng = np.random.default_rng(seed)
    bodies = np.array([_sided_body(rng) for _ in range(n_bodies)]).reshape(n_bodies, N_JOINTS, 3)
    views = bodies[:, None] + rng.normal(0.0, 30.0, (n_bodies, n_sensors, N_JOINTS, 3))
    mirrored = rng.random((n_bodies, n_sensors)) < 0.4
    views[mirrored] = views[mirrored][:, MIRROR]  # left/right labels swapped
    views[rng.random(views.shape[:3]) < missing_joints] = np.nan
    views[rng.random((n_bodies, n_sensors)) < 0.15] = np.nan  # a view without the body
    confidence = rng.integers(0, 4, views.shape[:3]).astype(np.uint8)
    previous = bodies + rng.normal(0.0, 10.0, (n_bodies, 1, 3))
    if anchor == "mirrored":
        previous = previous[:, MIRROR]
    elif anchor == "partial":
        previous[rng.random(previous.shape[:2]) < 0.4] = np.nan
    elif anchor == "none":
        previous[:] = np.nan
    elif anchor == "jumped":
        previous += 500.0
    streak = np.stack(
        [
            rng.integers(-5, 12, n_bodies),
            rng.integers(0, 6, n_bodies),
            rng.integers(0, n_sensors + 2, n_bodies),
            rng.integers(0, 4, n_bodies),
        ],
        axis=1,
    ).astype(np.int32)
    sensors = rng.normal(0.0, 2500.0, (n_sensors, 3))
    got = realign.realign_temporal(views, confidence, previous, streak, sensor_positions=sensors, **rules)
    want = realign_reference.realign_temporal(views, confidence, previous, streak, sensor_positions=sensors, **rules)
    np.testing.assert_array_equal(got[2], want[2])  # mirrored
    np.testing.assert_array_equal(got[3], want[3])  # counters
    np.testing.assert_array_equal(got[0], want[0])  # the views, labels exchanged
    np.testing.assert_array_equal(got[1], want[1])
    assert got[3].dtype == want[3].dtype == np.int32 and got[2].dtype == want[2].dtype


@settings(max_examples=100, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_tracks=st.integers(0, 5),
    missing_points=st.sampled_from([0.0, 0.3, 1.0]),
    still=st.booleans(),
)
def test_tracks_motion_kernel_equals_the_numpy_reference(seed, n_tracks, missing_points, still):
    rng = np.random.default_rng(seed)
    params = TrackParams(max_speed_mm_s=float(rng.choice([500.0, 7000.0])))
    shape = (n_tracks, N_DESCRIPTOR, 3)
    descriptor = rng.normal(0.0, 500.0, shape)
    predicted = descriptor + rng.normal(0.0, 20.0, shape)
    measured = predicted + rng.normal(0.0, 50.0, shape)
    measured[rng.random(shape[:2]) < missing_points] = np.nan
    velocity = rng.normal(0.0, 800.0, (n_tracks, 3))
    last_seen_s = 10.0 - rng.choice([0.0, 1 / 30, 0.2], n_tracks) * (not still)
    n_frames_seen = rng.integers(0, 4, n_tracks)
    hit = rng.random(n_tracks) < 0.7
    arguments = (descriptor, velocity, last_seen_s, n_frames_seen, predicted, measured, hit, 10.0, params)
    got = tracks.seen_motion(*arguments)
    want = tracks_reference.seen_motion(*arguments)
    for got_array, want_array in zip(got, want, strict=True):
        np.testing.assert_allclose(got_array, want_array, rtol=1e-12, atol=ATOL)
    np.testing.assert_array_equal(descriptor, arguments[0])  # the inputs are left as they were


def test_a_first_start_says_it_is_compiling_and_a_later_one_does_not(caplog, monkeypatch, tmp_path):
    kernels.warm_up()  # compiled (or loaded) into the cache directory numba was set up with
    cached = str(kernels.cache_dir())
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))  # an empty cache: what a first start finds
    with caplog.at_level(logging.INFO, logger="skelfuse.service.node"):
        prepare_kernels("first")
    assert f"compiling the fusion kernels (first start; cached in {tmp_path}" in caplog.text
    caplog.clear()
    monkeypatch.setenv("NUMBA_CACHE_DIR", cached)
    assert kernels.is_cached()
    with caplog.at_level(logging.INFO, logger="skelfuse.service.node"):
        prepare_kernels("later")
    assert "compiling" not in caplog.text


def test_the_first_start_compile_groups_cover_every_kernel_module_once():
    grouped = [name for group in kernels.COMPILE_GROUPS for name in group]
    assert sorted(grouped) == sorted(kernels.KERNEL_MODULES)


@pytest.mark.live
def test_kernels_compiled_in_child_processes_fill_the_cache_and_a_failed_child_is_reported(
    caplog, monkeypatch, tmp_path
):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))  # an empty cache: what a first start finds
    kernels.compile_in_processes((("tracks",), ("realign",)))
    cached = {path.name.split(".")[0] for path in tmp_path.rglob("*.nbi")}
    assert cached == {"tracks", "realign"}  # both children compiled into the user's cache, nothing else
    with caplog.at_level(logging.WARNING, logger="skelfuse.fusion.kernels"):
        kernels.compile_in_processes((("no_such_kernel_module",),))
    assert "compiling the kernels ('no_such_kernel_module',) in a child process failed (exit 1)" in caplog.text
    assert "ModuleNotFoundError" in caplog.text
