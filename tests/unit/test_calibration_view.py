"""log_calibration: read the saved .rrd back and find each sensor's centres in the world, labelled."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr
from rerun.chunk import RrdReader

from skelfuse.calibration.view import log_calibration
from skelfuse.config.calibration_file import CalibrationResult, SensorCalibration
from skelfuse.fusion.transform import invert_transform
from skelfuse.sim.rig import paper_rig


def _columns(path: Path) -> dict[str, dict[str, list]]:
    out: dict[str, dict[str, list]] = {}
    for chunk in RrdReader(path).store().stream():
        batch = chunk.to_record_batch()
        columns = out.setdefault(str(chunk.entity_path), {})
        for name in batch.schema.names:
            if ":" in name:
                columns.setdefault(name, []).extend(batch.column(name).to_pylist())
    return out


def test_centres_are_logged_in_the_world_with_residual_labels(tmp_path: Path) -> None:
    rng = np.random.default_rng(11)
    rig = paper_rig(2)
    world_points = rng.uniform(-500, 500, size=(20, 3)) + np.array([0.0, 0.0, 1000.0])
    sensors, points = {}, {}
    for sensor, residual in zip(rig, (None, 2.5), strict=True):
        sensors[sensor.sensor_id] = SensorCalibration(sensor.world_from_sensor, "sphere", residual, 20)
        sensor_from_world = invert_transform(sensor.world_from_sensor)
        points[sensor.sensor_id] = world_points @ sensor_from_world[:3, :3].T + sensor_from_world[:3, 3]
    result = CalibrationResult(sensors, "sphere", "capture_0", points_by_sensor=points)

    recording = rr.RecordingStream("skelfuse_calibration_test")
    path = tmp_path / "calibration.rrd"
    recording.save(path)
    log_calibration(recording, result)
    recording.flush()
    recording.disconnect()

    columns = _columns(path)
    for sensor in rig:
        logged = np.array(columns[f"/world/calibration/centres/{sensor.sensor_id}"]["Points3D:positions"][0])
        np.testing.assert_allclose(logged, world_points / 1000.0, atol=1e-6)  # metres, like the Rerun sink
        translation = np.array(columns[f"/world/calibration/{sensor.sensor_id}"]["Transform3D:translation"][0])
        np.testing.assert_allclose(translation.reshape(3), sensor.position_mm / 1000.0, rtol=1e-6)
    assert columns["/world/calibration/centres/capture_1"]["Points3D:labels"][0] == [
        "capture_1: rms 2.5 mm, 20 pts (sphere)"
    ]
    assert columns["/world/calibration/centres/capture_0"]["Points3D:labels"][0][0].startswith("capture_0: master")
