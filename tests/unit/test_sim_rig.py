"""Virtual sensors: look_at geometry, the frustum, and the paper's layout."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.schema.skeleton import EVAL_JOINTS, J
from skelfuse.sim.body_model import facing_away_deg
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.motion import facing_deg
from skelfuse.sim.rig import VirtualSensor, best_view_sensor, look_at, paper_rig


@pytest.mark.parametrize(
    ("position", "target"),
    [((2000.0, 0.0, 1000.0), (0.0, 0.0, 900.0)), ((-1500.0, 1200.0, 1800.0), (100.0, -50.0, 500.0))],
)
def test_look_at_puts_the_target_on_the_optical_axis(position, target) -> None:
    sensor = look_at("s", np.array(position), np.array(target))
    local = sensor.to_sensor(np.array(target))
    distance = np.linalg.norm(np.subtract(target, position))
    np.testing.assert_allclose(local, [0.0, 0.0, distance], atol=1e-9)
    rotation = sensor.world_from_sensor[:3, :3]
    np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    assert abs(rotation[2, 0]) < 1e-12  # x (image right) is horizontal: no roll
    assert rotation[2, 1] < 0  # y points down in the world


def test_image_right_is_world_right() -> None:
    # Looking along +x with z up, the image's right is world -y.
    sensor = look_at("s", np.array([0.0, 0.0, 1000.0]), np.array([1000.0, 0.0, 1000.0]))
    np.testing.assert_allclose(sensor.world_from_sensor[:3, 0], [0.0, -1.0, 0.0], atol=1e-12)


def test_frustum_nfov_unbinned() -> None:
    sensor = look_at("s", np.zeros(3), np.array([0.0, 1000.0, 0.0]))
    assert (sensor.fov_h_deg, sensor.fov_v_deg, sensor.range_mm) == (75.0, 65.0, (500.0, 3860.0))
    depth = 2000.0
    points = np.array(
        [
            [0, 0, depth],
            [depth * np.tan(np.radians(36.5)), 0, depth],
            [depth * np.tan(np.radians(38.5)), 0, depth],
            [0, depth * np.tan(np.radians(32.0)), depth],
            [0, -depth * np.tan(np.radians(33.0)), depth],
            [0, 0, 400.0],
            [0, 0, 3900.0],
            [0, 0, -1000.0],
        ]
    )
    np.testing.assert_array_equal(sensor.in_view(points), [True, True, False, True, False, False, False, False])


def test_invalid_pose_rejected() -> None:
    with pytest.raises(ValueError, match="4x4"):
        VirtualSensor("s", np.eye(3))
    mirror = np.eye(4)
    mirror[0, 0] = -1
    with pytest.raises(ValueError, match="not a rotation"):
        VirtualSensor("s", mirror)


def test_paper_rig_sees_a_standing_subject_in_the_centre() -> None:
    rig = paper_rig()
    assert [s.sensor_id for s in rig] == ["capture_0", "capture_1", "capture_2", "capture_3"]
    truth = make_gesture("hands_up_down", seed=0).positions
    for sensor in rig:
        assert 1000.0 <= sensor.position_mm[2] <= 1200.0
        assert -0.2 < sensor.world_from_sensor[2, 2] < 0.0  # optical axis tilted slightly down
        # the paper's 16 evaluation joints stay in view; raised hand tips may leave the top of the image
        assert sensor.in_view(sensor.to_sensor(truth))[:, EVAL_JOINTS].all()
    angles = np.degrees(np.arctan2([s.position_mm[1] for s in rig], [s.position_mm[0] for s in rig]))
    np.testing.assert_allclose(np.sort(angles % 360), [45, 135, 225, 315])


def test_best_view_sensor_is_in_front_of_the_subject() -> None:
    motion = make_gesture("squat", facing_deg=-70.0, position_mm=(400.0, 100.0), seed=0)
    sensor = best_view_sensor(-70.0, subject_mm=(400.0, 100.0))
    assert np.median(facing_away_deg(motion.positions, sensor.position_mm)) < 10.0
    assert np.median(facing_deg(motion.positions)) == pytest.approx(-70.0, abs=10.0)
    assert np.linalg.norm(sensor.position_mm[:2] - [400.0, 100.0]) == pytest.approx(2300.0)
    assert sensor.in_view(sensor.to_sensor(motion.positions))[:, J["PELVIS"]].all()
