"""Show a calibration in Rerun: each sensor's pose and its sphere centres mapped to the world.

A good calibration puts every sensor's centres on top of each other; a sensor whose points drift away
from the others' is miscalibrated, and its label says by how much (RMS residual, mm). Units follow the
Rerun sink (``skelfuse.sinks.rerun_sink``): metres, world z up. Entities::

    world/calibration/{sensor_id}            Transform3D (the sensor's pose) and its axes
    world/calibration/centres/{sensor_id}    Points3D: the centres this sensor saw, in the world
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from skelfuse.config.calibration_file import CalibrationResult

MM_TO_M = 1e-3
_PALETTE = np.array(
    [
        [230, 25, 75],
        [60, 180, 75],
        [0, 130, 200],
        [245, 130, 48],
        [145, 30, 180],
        [70, 240, 240],
        [240, 50, 230],
        [210, 245, 60],
    ],
    dtype=np.uint8,
)


def _label(sensor_id: str, residual_mm: float | None, n_points: int | None, method: str) -> str:
    residual = "master" if residual_mm is None else f"rms {residual_mm:.1f} mm"
    count = "" if n_points is None else f", {n_points} pts"
    return f"{sensor_id}: {residual}{count} ({method})"


def log_calibration(recording: rr.RecordingStream, result: CalibrationResult) -> None:
    """Log ``result`` (static) to ``recording``: sensor poses, and the fit's points in the world frame.

    Parameters
    ----------
    recording : an injected rr.RecordingStream (saved, spawned or served by the caller).
    result : a CalibrationResult; ``points_by_sensor`` (sphere centres, sensor frames) are mapped through
        each sensor's ``world_from_sensor`` and labelled with its residual.
    """
    recording.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    for index, (sensor_id, sensor) in enumerate(result.sensors.items()):
        pose = sensor.world_from_sensor
        label = _label(sensor_id, sensor.residual_mm, sensor.n_points, sensor.method)
        color = _PALETTE[index % len(_PALETTE)]
        recording.log(
            f"world/calibration/{sensor_id}",
            rr.Transform3D(translation=pose[:3, 3] * MM_TO_M, mat3x3=pose[:3, :3]),
            rr.TransformAxes3D(0.2),
            static=True,
        )
        points = result.points_by_sensor.get(sensor_id)
        if points is None or len(points) == 0:
            continue
        world = (np.asarray(points, dtype=np.float64) @ pose[:3, :3].T + pose[:3, 3]) * MM_TO_M
        recording.log(
            f"world/calibration/centres/{sensor_id}",
            rr.Points3D(world, colors=color, radii=0.01, labels=label),
            static=True,
        )
