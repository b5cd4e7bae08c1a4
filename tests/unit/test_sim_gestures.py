"""The procedural gestures: finite, rigid bones, feet on the floor, facing and place honoured."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.schema.skeleton import BONES, J
from skelfuse.sim.gestures import GESTURES, make_gesture
from skelfuse.sim.motion import facing_deg

FEET = [J["ANKLE_LEFT"], J["ANKLE_RIGHT"], J["FOOT_LEFT"], J["FOOT_RIGHT"]]


@pytest.fixture(scope="module", params=GESTURES)
def gesture(request):
    name = request.param
    return name, make_gesture(name, duration_s=10.0, fps=30.0, facing_deg=40.0, position_mm=(300.0, -200.0), seed=3)


def test_the_six_gestures() -> None:
    assert GESTURES == ("hands_up_down", "jump", "squat", "lunge", "walking", "random")
    with pytest.raises(ValueError, match="unknown gesture"):
        make_gesture("dance")


def test_shape_and_finite(gesture) -> None:
    name, motion = gesture
    assert motion.name == name
    assert motion.positions.shape == (300, 32, 3)
    assert np.isfinite(motion.positions).all()


def test_bone_lengths_constant(gesture) -> None:
    _, motion = gesture
    p = motion.positions
    lengths = np.linalg.norm(p[:, BONES[:, 1]] - p[:, BONES[:, 0]], axis=-1)
    np.testing.assert_allclose(lengths, np.broadcast_to(lengths[0], lengths.shape), atol=1e-6)


def test_feet_on_the_floor(gesture) -> None:
    name, motion = gesture
    lowest = motion.positions[:, FEET, 2].min(axis=1)
    assert lowest.min() > -1.0  # never below the floor
    if name == "jump":
        airborne = lowest > 100.0
        assert 0.1 < airborne.mean() < 0.6  # flight phases, and standing between them
        assert np.percentile(lowest, 20) < 60.0
    else:
        assert lowest.max() < 60.0  # a foot always touches (ankle joint ~70 mm up, toe joint ~25 mm)


def test_facing_and_position_honoured(gesture) -> None:
    name, motion = gesture
    facing = facing_deg(motion.positions)
    pelvis_xy = motion.positions[:, J["PELVIS"], :2]
    if name == "walking":
        assert abs(facing[0] - 40.0) < 15.0
        centre = 0.5 * (pelvis_xy.min(axis=0) + pelvis_xy.max(axis=0))
        np.testing.assert_allclose(centre, [300.0, -200.0], atol=1.0)
        # walks along the facing direction, about 2 m, then turns back
        direction = np.array([np.cos(np.radians(40.0)), np.sin(np.radians(40.0))])
        along = (pelvis_xy - centre) @ direction
        assert 1500.0 < np.ptp(along) < 2600.0
        assert np.ptp(np.unwrap(np.radians(facing))) > np.radians(150.0)
    else:
        assert abs(np.median(facing) - 40.0) < 10.0
        # the lunge plants the rear foot at the position and steps forward from there
        reach = 500.0 if name == "lunge" else 300.0
        assert np.linalg.norm(np.median(pelvis_xy, axis=0) - [300.0, -200.0]) < reach


def test_realistic_speeds() -> None:
    motion = make_gesture("hands_up_down", seed=0)
    speed = np.linalg.norm(np.diff(motion.positions[:, J["WRIST_LEFT"]], axis=0), axis=1) * motion.fps
    assert 1000.0 < np.percentile(speed, 95) < 2500.0
    # both hands go above the head and back down to the hips
    wrist_z = motion.positions[:, J["WRIST_LEFT"], 2]
    head_z = motion.positions[:, J["HEAD"], 2]
    assert (wrist_z > head_z).any() and (wrist_z < motion.positions[:, J["PELVIS"], 2]).any()


def test_squat_lowers_the_pelvis_and_lunge_steps() -> None:
    squat = make_gesture("squat", seed=0).positions
    assert np.ptp(squat[:, J["PELVIS"], 2]) > 250.0
    lunge = make_gesture("lunge", seed=0).positions
    stride = np.linalg.norm(lunge[:, J["ANKLE_LEFT"], :2] - lunge[:, J["ANKLE_RIGHT"], :2], axis=1)
    assert stride.max() > 700.0


def test_random_crosses_arms_waves_and_leans_over_a_long_take() -> None:
    p = make_gesture("random", duration_s=60.0, seed=5).positions
    # crossing: the left wrist passes to the subject's right of the right wrist (facing +x: left is +y)
    assert (p[:, J["WRIST_LEFT"], 1] < p[:, J["WRIST_RIGHT"], 1]).any()
    assert (p[:, [J["WRIST_LEFT"], J["WRIST_RIGHT"]], 2].max(axis=1) > p[:, J["NECK"], 2]).any()
    lean = p[:, J["NECK"], :2] - p[:, J["PELVIS"], :2]
    assert np.linalg.norm(lean, axis=1).max() > 100.0


def test_seed_and_height() -> None:
    a = make_gesture("random", seed=1).positions
    b = make_gesture("random", seed=1).positions
    c = make_gesture("random", seed=2).positions
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 10.0
    tall = make_gesture("squat", height_mm=1900.0, seed=0).positions
    short = make_gesture("squat", height_mm=1500.0, seed=0).positions
    assert tall[0, J["HEAD"], 2] / short[0, J["HEAD"], 2] == pytest.approx(1900.0 / 1500.0, rel=0.02)
