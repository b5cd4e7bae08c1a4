"""The calibration file: round trip, compatibility with config.load_calibration, version and metadata checks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skelfuse.config import load_calibration
from skelfuse.config.calibration_file import (
    CalibrationResult,
    SensorCalibration,
    read_calibration,
    reanchor,
    write_calibration,
)
from skelfuse.fusion.transform import make_transform
from skelfuse.schema.errors import CalibrationError
from skelfuse.sim.rig import paper_rig


def _result() -> CalibrationResult:
    rig = paper_rig(3)
    sensors = {
        rig[0].sensor_id: SensorCalibration(
            rig[0].world_from_sensor, "marker", 2.25, 4, "2025-01-31T10:22:03+00:00", "plate markers [0, 1, 2, 3]"
        ),
        rig[1].sensor_id: SensorCalibration(
            rig[1].world_from_sensor,
            "sphere",
            1.8123456789,
            412,
            "2025-01-31T10:20:00+00:00",
            'fitted to "capture_0"\nline two',
        ),
        "000123412512": SensorCalibration(rig[2].world_from_sensor, "manual"),
    }
    return CalibrationResult(sensors, "marker", master="capture_0", date="2025-01-31T10:22:03+00:00", notes="take 3")


def test_round_trip_is_exact(tmp_path: Path) -> None:
    result = _result()
    path = write_calibration(tmp_path / "calib" / "rig.toml", result)
    back = read_calibration(path)
    assert back.master == "capture_0" and back.method == "marker" and back.notes == "take 3"
    for sensor_id, sensor in result.sensors.items():
        got = back.sensors[sensor_id]
        np.testing.assert_array_equal(got.world_from_sensor, sensor.world_from_sensor)  # bit for bit
        assert (got.method, got.residual_mm, got.n_points, got.notes) == (
            sensor.method,
            sensor.residual_mm,
            sensor.n_points,
            sensor.notes,
        )
    assert back.sensors["capture_1"].date == "2025-01-31T10:20:00+00:00"
    assert "version = 1" in path.read_text()


def test_config_loader_reads_the_file(tmp_path: Path) -> None:
    result = _result()
    path = write_calibration(tmp_path / "rig.toml", result)
    poses = load_calibration(path)
    assert set(poses) == set(result.sensors)
    for sensor_id, pose in poses.items():
        np.testing.assert_array_equal(pose, result.sensors[sensor_id].world_from_sensor)


def test_hand_written_file_without_metadata_reads_as_manual(tmp_path: Path) -> None:
    path = tmp_path / "hand.toml"
    path.write_text("[sensors.a]\nworld_from_sensor = [[1, 0, 0, 10], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n")
    back = read_calibration(path)
    assert back.sensors["a"].method == "manual" and back.sensors["a"].residual_mm is None
    assert back.master is None


def test_newer_version_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "future.toml"
    path.write_text(
        "version = 2\n[sensors.a]\nworld_from_sensor = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n"
    )
    with pytest.raises(CalibrationError, match="key version"):
        read_calibration(path)


def test_unknown_method_and_bad_pose_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(
        '[sensors.a]\nmethod = "guess"\nworld_from_sensor = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n'
    )
    with pytest.raises(CalibrationError, match=r"sensors\.a\.method"):
        read_calibration(path)
    path.write_text("[sensors.a]\nworld_from_sensor = [[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n")
    with pytest.raises(CalibrationError, match="det"):
        read_calibration(path)


def test_reanchor_keeps_relative_poses() -> None:
    result = _result()
    new_master = make_transform(np.eye(3), np.array([0.0, 0.0, 1500.0]))
    moved = reanchor(result, new_master)
    np.testing.assert_allclose(moved.sensors["capture_0"].world_from_sensor, new_master, atol=1e-9)

    def relative(r: CalibrationResult) -> np.ndarray:
        return np.linalg.inv(r.sensors["capture_0"].world_from_sensor) @ r.sensors["capture_1"].world_from_sensor

    before, after = relative(result), relative(moved)
    np.testing.assert_allclose(after, before, atol=1e-9)
