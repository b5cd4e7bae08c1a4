"""Marker calibration (paper 2.1.2): the world frame from a plate of 4 ArUco markers seen by the master."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.calibration.marker import calibrate_world_from_marker, world_from_marker_centres
from skelfuse.calibration.render import Quad, Scene, aruco_plate, render, room
from skelfuse.calibration.rigid import rotation_angle_deg
from skelfuse.config.calibration_file import CalibrationResult, SensorCalibration
from skelfuse.fusion.camera import Intrinsics
from skelfuse.fusion.transform import invert_transform
from skelfuse.schema.errors import CalibrationError
from skelfuse.sim.rig import look_at, paper_rig

SEED = 577
INTRINSICS = Intrinsics.azure_kinect_nfov()
MARKER_MM = 200.0


def _pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    return (
        rotation_angle_deg(estimate[:3, :3] @ truth[:3, :3].T),
        float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3])),
    )


@pytest.fixture(scope="module")
def plate_scene() -> Scene:
    plate, _ = aruco_plate(marker_mm=MARKER_MM, spacing_mm=400.0)  # marker 1 at the world origin, axes = world
    return Scene(quads=[*room(floor_z_mm=-5.0), plate])  # the plate is 5 mm thick


@pytest.mark.parametrize("centre_method", ["plane", "mean"])
@pytest.mark.parametrize(
    "sensor",
    [paper_rig(4)[0], look_at("high", (1300.0, -1000.0, 1700.0), (-200.0, -200.0, 0.0))],
    ids=["paper-rig", "high"],
)
def test_world_from_master_is_recovered(plate_scene: Scene, sensor, centre_method: str) -> None:
    color, depth = render(
        sensor.world_from_sensor, INTRINSICS, plate_scene, rng=np.random.default_rng(SEED), depth_noise_mm=2.5
    )
    result, observations = calibrate_world_from_marker(
        color, depth, INTRINSICS, sensor.sensor_id, marker_mm=MARKER_MM, centre_method=centre_method
    )
    entry = result.sensors[sensor.sensor_id]
    angle_deg, offset_mm = _pose_error(entry.world_from_sensor, sensor.world_from_sensor)
    assert angle_deg < 0.5
    assert offset_mm < 10.0
    assert sorted(observations) == [0, 1, 2, 3]
    assert entry.method == "marker" and entry.n_points == 4
    assert entry.residual_mm is not None and entry.residual_mm < 6.0
    # The PnP cross-check is measured (colour only, much coarser than depth at these grazing angles).
    assert all(obs.center_pnp is not None for obs in observations.values())


def test_marker_calibration_reanchors_a_sphere_calibration(plate_scene: Scene) -> None:
    rig = paper_rig(3)
    master = rig[0]
    # A perfect sensor-to-sensor calibration in the master's frame (as calibrate_from_sphere returns it).
    master_from_world = invert_transform(master.world_from_sensor)
    sphere = CalibrationResult(
        {s.sensor_id: SensorCalibration(master_from_world @ s.world_from_sensor, "sphere", 1.0, 50) for s in rig},
        "sphere",
        master.sensor_id,
    )
    color, depth = render(master.world_from_sensor, INTRINSICS, plate_scene, rng=np.random.default_rng(SEED + 1))
    result, _ = calibrate_world_from_marker(color, depth, INTRINSICS, master.sensor_id, calibration=sphere)
    for sensor in rig:
        angle_deg, offset_mm = _pose_error(result.sensors[sensor.sensor_id].world_from_sensor, sensor.world_from_sensor)
        assert angle_deg < 0.5 and offset_mm < 10.0, sensor.sensor_id
    assert result.sensors["capture_1"].method == "sphere"  # keeps how its relative pose was measured
    assert result.sensors["capture_1"].residual_mm == 1.0


def test_missing_markers_are_named_with_the_ids_seen(plate_scene: Scene) -> None:
    sensor = paper_rig(4)[0]
    # Cover markers 1 and 2 (world x in [-500, 100], y in [-100, 100]) with a grey sheet.
    sheet = Quad((-200.0, 0.0, 2.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), 320.0, 130.0, (120, 120, 120))
    scene = Scene(quads=[*plate_scene.quads, sheet])
    color, depth = render(sensor.world_from_sensor, INTRINSICS, scene, rng=np.random.default_rng(SEED + 2))
    with pytest.raises(CalibrationError) as info:
        calibrate_world_from_marker(color, depth, INTRINSICS, sensor.sensor_id)
    message = str(info.value)
    assert "marker id(s) [1, 2] not found" in message
    assert "expected ArUco ids [0, 1, 2, 3]" in message
    assert "detected [0, 3]" in message
    assert "DICT_4X4_50" in message


def test_wrong_dictionary_says_nothing_was_detected(plate_scene: Scene) -> None:
    sensor = paper_rig(4)[0]
    color, depth = render(sensor.world_from_sensor, INTRINSICS, plate_scene, rng=np.random.default_rng(SEED + 3))
    with pytest.raises(CalibrationError, match=r"detected none .*DICT_6X6_250"):
        calibrate_world_from_marker(color, depth, INTRINSICS, sensor.sensor_id, dictionary="DICT_6X6_250")


def test_axes_follow_the_paper_and_are_orthonormal() -> None:
    """Centres in a sensor frame: x from 2 to 1, y from 0 to 1, z up, origin at 1; a skewed y is split evenly."""
    centres = {
        1: np.array([100.0, 200.0, 2000.0]),
        2: np.array([-300.0, 200.0, 2000.0]),
        0: np.array([100.0, 200.0 + 400.0, 2000.0 + 4.0]),
        3: np.array([-300.0, 600.0, 2004.0]),
    }
    world_from_sensor, residual = world_from_marker_centres(centres)
    R = world_from_sensor[:3, :3]
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    origin = R @ centres[1] + world_from_sensor[:3, 3]
    np.testing.assert_allclose(origin, 0.0, atol=1e-9)
    x_dir = R @ (centres[1] - centres[2])
    np.testing.assert_allclose(x_dir / np.linalg.norm(x_dir), [1.0, 0.0, 0.0], atol=1e-2)
    assert residual < 3.0


def test_unknown_dictionary_is_refused() -> None:
    blank = np.zeros((INTRINSICS.height, INTRINSICS.width, 3), np.uint8)
    with pytest.raises(CalibrationError, match="unknown ArUco dictionary"):
        calibrate_world_from_marker(blank, np.zeros(blank.shape[:2], np.uint16), INTRINSICS, "m", dictionary="DICT_9")
