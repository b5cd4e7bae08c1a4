"""A simulated sensor's person clouds, made the way a capture worker makes them from a real one.

The simulator renders what the sensor and its body tracker give (:func:`skelfuse.sim.depth.render_sensor`:
the depth image and the body-index map of capsule bodies); turning those into each person's voxelized cloud is
the product's own step (:func:`skelfuse.fusion.depth.cloud.person_clouds`, as the capture worker runs it on
the SDK's images). It lives here, outside ``skelfuse.sim``, so that the simulator never runs the product's
depth code (a contract in pyproject.toml).
"""

from __future__ import annotations

import numpy as np

from skelfuse.fusion.camera import Intrinsics
from skelfuse.fusion.depth.cloud import person_clouds
from skelfuse.sim.depth import DepthNoise, render_sensor
from skelfuse.sim.rig import VirtualSensor


def sensor_person_clouds(
    sensor: VirtualSensor,
    people_world: np.ndarray,
    *,
    voxel_mm: float,
    intrinsics: Intrinsics | None = None,
    noise: DepthNoise | None = None,
    rng: np.random.Generator | None = None,
) -> dict[int, np.ndarray]:
    """What a capture worker sends in depth mode: each person's voxelized cloud in the sensor frame, by the
    person's index in ``people_world`` (people without a visible pixel are absent). ``noise``: the
    simulator's default :class:`~skelfuse.sim.depth.DepthNoise` when None."""
    frame = render_sensor(
        sensor, people_world, intrinsics=intrinsics, noise=DepthNoise() if noise is None else noise, rng=rng
    )
    clouds = person_clouds(frame.depth, frame.body_index, frame.intrinsics, voxel_mm=voxel_mm)
    return {cloud.body_index: cloud.points for cloud in clouds}
