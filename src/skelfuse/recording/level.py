"""Level the world of an opened take whose poses do not define one (:mod:`skelfuse.rig.level` on its views)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from skelfuse.recording.inputs import InputTake
from skelfuse.rig.level import Levelling, level_from_skeletons
from skelfuse.schema.errors import DataError


def level_take(
    take: InputTake, poses: Mapping[str, np.ndarray], *, up: np.ndarray | None = None
) -> tuple[dict[str, np.ndarray], Levelling]:
    """``poses`` (world_from_sensor per sensor, one shared frame) re-expressed in the levelled world, and how.

    The skeletons of the view that saw the most joints, in the shared frame, are the evidence; ``up`` (in
    the shared frame) skips the gravity estimate.

    Raises
    ------
    DataError
        Too little evidence to level (the message says what was missing and how to go on).
    """
    views = [r for r in take.recordings if r.sensor_id in poses]
    if not views:
        raise DataError("no view with a pose to level the world from")
    best = max(views, key=lambda r: int(np.isfinite(r.positions).all(axis=-1).sum()))
    pose = np.asarray(poses[best.sensor_id], dtype=np.float64)
    shared = best.positions.astype(np.float64) @ pose[:3, :3].T + pose[:3, 3]
    try:
        levelling = level_from_skeletons(shared, up=up)
    except ValueError as exc:
        raise DataError(f"cannot level the world from {best.sensor_id}'s skeletons: {exc}") from None
    world = levelling.world_from_input
    return {sid: world @ np.asarray(p, dtype=np.float64) for sid, p in poses.items()}, levelling
