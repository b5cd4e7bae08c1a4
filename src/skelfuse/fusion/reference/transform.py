"""The numpy form of an instant's stacking in the world frame: the test reference of
:func:`skelfuse.fusion.transform.stack_views_to_world` (the live path runs :mod:`skelfuse.fusion.kernels.stacking`
and never imports this module): one scatter per array, then :func:`~skelfuse.fusion.transform.apply_transform`
and :func:`~skelfuse.fusion.orientation.views_to_world_by_matrix` over every sensor block.
"""

from __future__ import annotations

import numpy as np

from skelfuse.fusion.orientation import views_to_world_by_matrix
from skelfuse.fusion.transform import StackedViews, apply_transform
from skelfuse.schema.skeleton import N_JOINTS


def stack_views_to_world(
    positions: np.ndarray,
    confidence: np.ndarray,
    orientations: np.ndarray | None,
    frame_rows: np.ndarray,
    frame_counts: np.ndarray,
    n_bodies: int,
    world_from_sensor: np.ndarray,
    quat_matrices: np.ndarray,
) -> StackedViews:
    """:func:`skelfuse.fusion.transform.stack_views_to_world` in numpy."""
    S, B = world_from_sensor.shape[0], int(n_bodies)
    counts = np.asarray(frame_counts, dtype=np.int64)
    rows = np.repeat(np.asarray(frame_rows, dtype=np.int64), counts)
    cols = np.concatenate([np.arange(n) for n in counts]) if counts.size else np.zeros(0, dtype=np.int64)
    local = np.full((S, B, N_JOINTS, 3), np.nan)
    local[rows, cols] = positions
    stacked = np.zeros((S, B, N_JOINTS), dtype=np.uint8)
    stacked[rows, cols] = confidence
    valid = np.zeros((S, B), dtype=bool)
    valid[rows, cols] = True
    # apply_transform wants the sensor axis third from the end: (B, S, 32, 3) in, swapped back out.
    world = np.swapaxes(apply_transform(world_from_sensor, np.swapaxes(local, 0, 1)), 0, 1)
    if orientations is None:
        return StackedViews(world, stacked, valid, None)
    quats = np.full((S, B, N_JOINTS, 4), np.nan)
    quats[rows, cols] = orientations
    return StackedViews(world, stacked, valid, views_to_world_by_matrix(quats, quat_matrices))
