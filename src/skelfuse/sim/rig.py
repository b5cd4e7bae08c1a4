"""Virtual Azure Kinect sensors: where they stand, where they look, and what their depth camera sees.

Sensor frame = the k4abt depth camera frame: x right, y down, z forward (mm). ``world_from_sensor`` maps
sensor coordinates to the world (z up): ``p_world = R @ p_sensor + t``.

Default field of view and range are those of the NFOV unbinned depth mode (75° x 65°, 0.5-3.86 m), the
mode the paper used with the lite body-tracking model (Azure Kinect DK hardware specification).
The paper's layout: four capture sensors at fixed places around a ~2 m capture area at a low height
(~1-1.2 m, tilted slightly down), plus a movable "best view" sensor 2-2.5 m in front of the subject
whose skeleton serves as the reference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skelfuse.fusion.camera import look_at_pose
from skelfuse.fusion.transform import invert_transform, transform_points

NFOV_UNBINNED_FOV_DEG = (75.0, 65.0)
NFOV_UNBINNED_RANGE_MM = (500.0, 3860.0)


@dataclass(frozen=True)
class VirtualSensor:
    """A depth camera with a body tracker, placed in the world.

    Attributes
    ----------
    sensor_id : str
        Name standing in for the device serial.
    world_from_sensor : (4, 4) float64
        True pose: maps the sensor frame (x right, y down, z forward, mm) to the world frame (z up, mm).
    fov_h_deg, fov_v_deg : float
        Full horizontal and vertical field of view, degrees (NFOV unbinned: 75 x 65).
    range_mm : (float, float)
        Depth range, mm (NFOV unbinned: 500 to 3860).
    """

    sensor_id: str
    world_from_sensor: np.ndarray
    fov_h_deg: float = NFOV_UNBINNED_FOV_DEG[0]
    fov_v_deg: float = NFOV_UNBINNED_FOV_DEG[1]
    range_mm: tuple[float, float] = NFOV_UNBINNED_RANGE_MM

    def __post_init__(self) -> None:
        pose = np.asarray(self.world_from_sensor, dtype=np.float64)
        if pose.shape != (4, 4):
            raise ValueError(f"VirtualSensor {self.sensor_id!r}: world_from_sensor must be 4x4, got {pose.shape}")
        rotation = pose[:3, :3]
        if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0:
            raise ValueError(f"VirtualSensor {self.sensor_id!r}: world_from_sensor's rotation is not a rotation")
        object.__setattr__(self, "world_from_sensor", pose)

    @property
    def sensor_from_world(self) -> np.ndarray:
        """(4, 4) the inverse pose: world points into this sensor's frame."""
        return invert_transform(self.world_from_sensor)

    @property
    def position_mm(self) -> np.ndarray:
        """(3,) sensor origin in the world, mm."""
        return self.world_from_sensor[:3, 3]

    def to_sensor(self, points_world: np.ndarray) -> np.ndarray:
        """(..., 3) world points → sensor frame, mm."""
        return transform_points(self.sensor_from_world, points_world)

    def in_view(self, points_sensor: np.ndarray) -> np.ndarray:
        """(...) bool: inside the field of view and the depth range (points in the sensor frame).

        The depth range applies to the z coordinate (depth), as the depth camera measures it.
        """
        x, y, z = points_sensor[..., 0], points_sensor[..., 1], points_sensor[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            inside_h = np.abs(x) <= z * np.tan(np.radians(self.fov_h_deg / 2))
            inside_v = np.abs(y) <= z * np.tan(np.radians(self.fov_v_deg / 2))
        return inside_h & inside_v & (z >= self.range_mm[0]) & (z <= self.range_mm[1])


def look_at(
    sensor_id: str,
    position_mm: np.ndarray,
    target_mm: np.ndarray,
    *,
    up: ArrayLike = (0.0, 0.0, 1.0),
    **fov: object,
) -> VirtualSensor:
    """A sensor at ``position_mm`` whose optical axis (+z) points at ``target_mm``, with no roll.

    The sensor's x axis is horizontal (right in the image), y points down in the image. Extra keyword
    arguments (``fov_h_deg``, ``fov_v_deg``, ``range_mm``) go to :class:`VirtualSensor`.
    """
    try:
        pose = look_at_pose(position_mm, target_mm, up)
    except ValueError as error:
        raise ValueError(f"look_at {sensor_id!r}: {error}") from None
    return VirtualSensor(sensor_id, pose, **fov)  # type: ignore[arg-type]  # the field-of-view keywords, passed through


def paper_rig(
    n_capture: int = 4,
    *,
    radius_mm: float = 2200.0,
    height_mm: float = 1100.0,
    target_height_mm: float = 900.0,
    first_angle_deg: float = 45.0,
    centre_mm: tuple[float, float] = (0.0, 0.0),
) -> list[VirtualSensor]:
    """Fixed capture sensors evenly spaced on a circle around the capture area, looking at its centre.

    Defaults: 4 sensors at 45°, 135°, 225°, 315° (counter-clockwise from world +x), 2.2 m from the centre,
    1.1 m high, aimed at 0.9 m above the centre (about 5° down), so a subject anywhere within ~1 m of the
    centre stays inside the NFOV range and a 1.75 m body fits the vertical field of view. Named
    ``capture_0`` ... ``capture_{n-1}``; the first is the master.
    """
    if n_capture < 1:
        raise ValueError(f"paper_rig needs at least one capture sensor, got n_capture={n_capture}")
    sensors = []
    for idx in range(n_capture):
        angle = np.radians(first_angle_deg + 360.0 * idx / n_capture)
        position = np.array(
            [centre_mm[0] + radius_mm * np.cos(angle), centre_mm[1] + radius_mm * np.sin(angle), height_mm]
        )
        target = np.array([centre_mm[0], centre_mm[1], target_height_mm])
        sensors.append(look_at(f"capture_{idx}", position, target))
    return sensors


def best_view_sensor(
    facing_deg: float,
    *,
    distance_mm: float = 2300.0,
    height_mm: float = 1000.0,
    sensor_id: str = "best_view",
    subject_mm: tuple[float, float] = (0.0, 0.0),
    target_height_mm: float = 900.0,
) -> VirtualSensor:
    """The paper's reference sensor: straight in front of a subject who faces ``facing_deg``.

    Placed ``distance_mm`` from ``subject_mm`` along the facing direction, at ``height_mm``, looking back
    at the subject (``target_height_mm`` above the floor).
    """
    angle = np.radians(facing_deg)
    position = np.array(
        [subject_mm[0] + distance_mm * np.cos(angle), subject_mm[1] + distance_mm * np.sin(angle), height_mm]
    )
    return look_at(sensor_id, position, np.array([subject_mm[0], subject_mm[1], target_height_mm]))


def arc_rig(
    n_sensors: int = 2,
    *,
    spread_deg: float = 45.0,
    distance_mm: float = 2250.0,
    height_mm: float = 1000.0,
    target_height_mm: float = 900.0,
    facing_deg: float = 0.0,
    subject_mm: tuple[float, float] = (0.0, 0.0),
    prefix: str = "view",
) -> list[VirtualSensor]:
    """Sensors on an arc in front of a subject, ``spread_deg`` apart, all looking at the subject.

    The layout of the real recordings the simulator is checked against (DESIGN.md "Real noise": two sensors
    about 45° apart, subject 2-2.5 m away), as opposed to :func:`paper_rig`'s ring at 90°. The arc is centred
    on the direction the subject faces (``facing_deg``, counter-clockwise from world +x), so with two
    sensors each sees the subject 22.5° off its front. Named ``{prefix}_0`` ...; the first is the master.
    """
    if n_sensors < 1:
        raise ValueError(f"arc_rig needs at least one sensor, got n_sensors={n_sensors}")
    offsets = (np.arange(n_sensors) - (n_sensors - 1) / 2.0) * spread_deg
    return [
        best_view_sensor(
            facing_deg + offset,
            distance_mm=distance_mm,
            height_mm=height_mm,
            sensor_id=f"{prefix}_{idx}",
            subject_mm=subject_mm,
            target_height_mm=target_height_mm,
        )
        for idx, offset in enumerate(offsets)
    ]
