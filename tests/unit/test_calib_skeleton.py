"""Calibration from skeletons on simulated walks (flips and occlusion on), against the simulator's true poses.

Errors are relative to the master. Translation is measured *at the subject* (where the poses map the person,
the capture-area centre 0.9 m above the floor): an error at the camera origin also holds the rotation error
times the 2-3 m lever arm and says nothing more about fusion quality.
"""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.calibration.rigid import rotation_angle_deg
from skelfuse.calibration.skeleton import (
    SIDE_PAIRS,
    calibrate_from_skeletons,
    check_calibration,
    stack_sensor_takes,
)
from skelfuse.fusion.transform import invert_transform
from skelfuse.schema.errors import CalibrationError
from skelfuse.schema.skeleton import MIRROR
from skelfuse.sim import load_profile, look_at, make_gesture, paper_rig, simulate


def _relative_errors(estimate: dict, world_from_sensor: np.ndarray, ids, subject_world: np.ndarray):
    """Per sensor (rotation deg, translation at the subject mm) of master_from_sensor vs the truth."""
    truth_master = invert_transform(world_from_sensor[0])
    out = {}
    for s, sensor_id in enumerate(ids):
        true_rel = truth_master @ world_from_sensor[s]
        est = estimate[sensor_id]
        subject = invert_transform(world_from_sensor[s]) @ np.r_[subject_world, 1.0]
        out[sensor_id] = (
            rotation_angle_deg(est[:3, :3] @ true_rel[:3, :3].T),
            float(np.linalg.norm((est @ subject)[:3] - (true_rel @ subject)[:3])),
        )
    return out


def _paper_take(seed: int, facing_deg: float):
    motion = make_gesture("walking", duration_s=30, seed=seed, facing_deg=facing_deg)
    obs = simulate(motion, paper_rig(4), load_profile(), seed=seed)
    return obs, calibrate_from_skeletons(obs.positions, obs.confidence, obs.sensor_ids, progress=False)


@pytest.fixture(scope="module")
def paper_take():
    return _paper_take(0, 30.0)


@pytest.fixture(scope="module", params=[(0, 30.0), (4, 120.0)], ids=["seed0-facing30", "seed4-facing120"])
def any_paper_take(request, paper_take):
    return paper_take if request.param == (0, 30.0) else _paper_take(*request.param)


def test_the_take_has_flips_and_occlusion(paper_take):
    obs, cal = paper_take
    assert obs.mirrored.any(axis=0).all()  # every view is mirrored at some point
    assert (obs.confidence == 1).any()  # LOW (occluded) joints exist
    assert sum(p.mirrored_frames for p in cal.pairs) > 0  # and the labeling test noticed the flips


def test_relative_poses_within_1_deg_and_20_mm(any_paper_take):
    obs, cal = any_paper_take
    errors = _relative_errors(cal.master_from_sensor, obs.world_from_sensor, obs.sensor_ids, np.array([0, 0, 900.0]))
    for sensor_id, (rot, trans) in errors.items():
        assert rot < 1.0, f"{sensor_id}: {rot:.2f} deg"
        assert trans < 20.0, f"{sensor_id}: {trans:.1f} mm at the subject"


def test_world_z_from_the_floor(any_paper_take):
    obs, cal = any_paper_take
    for s, sensor_id in enumerate(obs.sensor_ids):
        true_up = obs.world_from_sensor[s][2, :3]  # world z in the sensor's frame
        est_up = cal.world_from_sensor[sensor_id][2, :3]
        assert np.degrees(np.arccos(np.clip(true_up @ est_up, -1, 1))) < 1.5
    # The floor is at z = 0 in the simulator: the origin lies on it within a few cm.
    master_origin_height = cal.world_from_sensor[obs.sensor_ids[0]][2, 3]
    assert master_origin_height == pytest.approx(obs.world_from_sensor[0][2, 3], abs=40.0)
    assert cal.world_source == "floor"


def test_quality_is_good_and_half_takes_agree(any_paper_take):
    _, cal = any_paper_take
    for q in cal.quality.values():
        assert q.verdict == "good", q
        assert 5.0 < q.residual_mm < 50.0
        assert q.n_points > 1000
    for sensor_id, q in cal.quality.items():
        if sensor_id != cal.master:
            assert q.half_rotation_deg < 2.0
            assert q.half_translation_mm < 75.0
    text = cal.report()
    for sensor_id in cal.sensor_ids:
        assert sensor_id in text
    assert "good" in text and "floor:" in text


def test_plate_pose_defines_the_world_when_given(paper_take):
    obs, _ = paper_take
    cal = calibrate_from_skeletons(
        obs.positions,
        obs.confidence,
        obs.sensor_ids,
        master_world_from_sensor=obs.world_from_sensor[0],
        progress=False,
    )
    assert cal.world_source == "plate"
    assert np.array_equal(cal.world_from_sensor[obs.sensor_ids[0]], obs.world_from_sensor[0])
    for s, sensor_id in enumerate(obs.sensor_ids):
        est = cal.world_from_sensor[sensor_id]
        assert rotation_angle_deg(est[:3, :3] @ obs.world_from_sensor[s][:3, :3].T) < 1.0
    assert cal.floor.plate_tilt_deg is not None and cal.floor.plate_tilt_deg < 1.5


def test_master_choice_and_sensor_order_give_the_same_rig(paper_take):
    obs, cal = paper_take
    order = [2, 0, 3, 1]
    other = calibrate_from_skeletons(
        obs.positions[:, order],
        obs.confidence[:, order],
        [obs.sensor_ids[i] for i in order],
        "capture_0",
        progress=False,
    )
    for sensor_id in obs.sensor_ids:
        a, b = cal.master_from_sensor[sensor_id], other.master_from_sensor[sensor_id]
        assert rotation_angle_deg(a[:3, :3] @ b[:3, :3].T) < 0.05
        assert np.linalg.norm(a[:3, 3] - b[:3, 3]) < 2.0


@pytest.fixture(scope="module")
def row_rig_take():
    """Three sensors in a row; the person walks between 0 and 1, then between 1 and 2: 0 and 2 never overlap.
    Shared by the tests below, so its arrays are read-only: a test that changes them copies them first."""
    rig = [look_at(f"row_{i}", np.array([2500.0 * i, 0, 1100]), np.array([2500.0 * i, 2800, 900])) for i in range(3)]
    profile = load_profile()
    first = simulate(
        make_gesture("walking", duration_s=15, seed=1, position_mm=(1250, 2700), facing_deg=90), rig, profile, seed=1
    )
    second = simulate(
        make_gesture("walking", duration_s=15, seed=2, position_mm=(3750, 2700), facing_deg=90), rig, profile, seed=2
    )
    positions = np.concatenate([first.positions, second.positions])
    confidence = np.concatenate([first.confidence, second.confidence])
    positions.flags.writeable = confidence.flags.writeable = False
    return first, positions, confidence


def test_sensor_that_never_overlaps_the_master_is_chained_consistently(row_rig_take):
    obs, positions, confidence = row_rig_take
    seen = np.isfinite(positions).all(axis=-1).any(axis=-1)
    assert not (seen[:, 0] & seen[:, 2]).any()  # row_0 (master) and row_2 never see the person together
    cal = calibrate_from_skeletons(positions, confidence, obs.sensor_ids, progress=False)
    assert {(p.sensor_a, p.sensor_b) for p in cal.pairs} == {("row_0", "row_1"), ("row_1", "row_2")}
    # Measured where each sensor sees the person (its walking zone).
    for s, zone in ((1, (1250, 2700, 900.0)), (2, (3750, 2700, 900.0))):
        sensor_id = obs.sensor_ids[s]
        rot, trans = _relative_errors(cal.master_from_sensor, obs.world_from_sensor, obs.sensor_ids, np.array(zone))[
            sensor_id
        ]
        assert rot < 1.0, f"{sensor_id}: {rot:.2f} deg"
        # row_2 inherits row_1's rotation error over the 2.5 m between the zones (0.5 deg ~ 22 mm).
        assert trans < (20.0 if s == 1 else 40.0), f"{sensor_id}: {trans:.1f} mm"
    assert all(q.verdict == "good" for q in cal.quality.values())


def test_unlinked_sensor_raises_a_calibration_error(row_rig_take):
    obs, positions, confidence = row_rig_take
    positions = positions.copy()
    positions[:, 1] = np.nan  # without the middle sensor nothing links row_2 to row_0
    with pytest.raises(CalibrationError, match=r"could not link sensors row_1, row_2 to master row_0"):
        calibrate_from_skeletons(positions, confidence, obs.sensor_ids, progress=False)


def test_fully_mirrored_view_still_calibrates_from_the_midline():
    # A view that is mirrored all the time (labels swapped in every frame): side joints never agree, the
    # mid-line joints alone still give the pose.
    motion = make_gesture("walking", duration_s=20, seed=3, facing_deg=60)
    obs = simulate(motion, paper_rig(3), load_profile(), seed=3)
    positions, confidence = obs.positions.copy(), obs.confidence.copy()
    positions[:, 2] = positions[:, 2][:, MIRROR]
    confidence[:, 2] = confidence[:, 2][:, MIRROR]
    cal = calibrate_from_skeletons(positions, confidence, obs.sensor_ids, progress=False)
    errors = _relative_errors(cal.master_from_sensor, obs.world_from_sensor, obs.sensor_ids, np.array([0, 0, 900.0]))
    assert errors["capture_2"][0] < 1.5
    assert errors["capture_2"][1] < 30.0
    assert SIDE_PAIRS.shape == (3, 2)


def test_check_calibration_flags_a_moved_sensor_only(paper_take):
    obs, cal = paper_take
    stored = dict(cal.world_from_sensor)
    take = (obs.positions[:600], obs.confidence[:600], obs.sensor_ids)  # a new 20 s walk
    clean = check_calibration(stored, *take, reference_residual_mm=cal.residuals_mm())
    assert clean.moved == ()
    assert not clean.warnings
    # Knock capture_2 by 4 deg about its vertical axis.
    angle = np.radians(4.0)
    bump = np.eye(4)
    bump[:3, :3] = [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
    stored["capture_2"] = stored["capture_2"] @ bump
    moved = check_calibration(stored, *take, reference_residual_mm=cal.residuals_mm())
    assert moved.moved == ("capture_2",)
    check = moved.sensors["capture_2"]
    assert check.correction_rotation_deg == pytest.approx(4.0, abs=0.5)
    assert check.residual_mm > check.reference_residual_mm + 15.0
    assert check.refit_residual_mm < check.reference_residual_mm + 5.0
    assert "capture_2 looks moved" in moved.report()
    assert "residual" in " ".join(moved.warnings)


def test_check_calibration_needs_every_sensor_in_the_stored_calibration(paper_take):
    obs, cal = paper_take
    stored = {k: v for k, v in cal.world_from_sensor.items() if k != "capture_3"}
    with pytest.raises(CalibrationError, match="no pose for sensor"):
        check_calibration(stored, obs.positions, obs.confidence, obs.sensor_ids)


def test_stack_sensor_takes_cuts_to_the_shortest():
    rng = np.random.default_rng(7)
    takes = {
        "a": (rng.normal(size=(10, 32, 3)), np.full((10, 32), 2, np.uint8)),
        "b": (rng.normal(size=(8, 32, 3)), np.full((8, 32), 2, np.uint8)),
    }
    positions, confidence, ids = stack_sensor_takes(takes)
    assert positions.shape == (8, 2, 32, 3)
    assert confidence.shape == (8, 2, 32)
    assert ids == ("a", "b")
    assert np.array_equal(positions[:, 1], takes["b"][0])


@pytest.mark.parametrize(
    ("positions", "confidence", "ids", "master", "error", "match"),
    [
        pytest.param(
            np.zeros((5, 2, 32, 2)),
            np.zeros((5, 2, 32)),
            ["a", "b"],
            None,
            ValueError,
            r"\(T, S, 32, 3\)",
            id="bad-shape",
        ),
        pytest.param(
            np.zeros((5, 2, 32, 3)), np.zeros((5, 2, 32)), ["a"], None, ValueError, "1 sensor ids", id="ids-count"
        ),
        pytest.param(
            np.zeros((5, 2, 32, 3)),
            np.zeros((5, 2, 32)),
            ["a", "b"],
            "c",
            ValueError,
            "master 'c'",
            id="unknown-master",
        ),
        pytest.param(
            np.zeros((5, 1, 32, 3)), np.zeros((5, 1, 32)), ["a"], None, CalibrationError, "at least 2", id="one-sensor"
        ),
    ],
)
def test_invalid_input(positions, confidence, ids, master, error, match):
    with pytest.raises(error, match=match):
        calibrate_from_skeletons(positions, confidence, ids, master, progress=False)
