"""Skeleton takes for calibration: every sensor's first body per instant, stacked as one array.

From a ``skelfuse record`` MCAP (frames grouped by time, :class:`~skelfuse.rig.grouping.FrameGrouper`) or from
recordings of any format opened by :func:`skelfuse.recording.inputs.open_inputs` (frames matched in time).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from skelfuse.config import SyncConfig
from skelfuse.progress import note
from skelfuse.recording.inputs import InputTake, open_inputs
from skelfuse.recording.mcap_io import RecordingReader
from skelfuse.rig.grouping import FrameGroup, FrameGrouper
from skelfuse.rig.instant import group_bodies
from skelfuse.schema.errors import DataError
from skelfuse.schema.skeleton import N_JOINTS


def load_recording_take(
    path: str | Path,
    *,
    by: str = "device",
    sync: SyncConfig | None = None,
    max_frames: int | None = None,
    progress: bool = True,
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """A skelfuse MCAP recording as a synchronized one-person take for the skeleton calibration.

    Frames are grouped into instants as the fusion node does (:class:`~skelfuse.rig.grouping.FrameGrouper`,
    by device time by default, the recorded host time as the arrival clock); every group is one frame of
    the take, and each sensor contributes its **first body** (NaN / confidence NONE where it has none).

    Parameters
    ----------
    path : the recording.
    by : "device" (wired sync) or "host".
    sync : a :class:`skelfuse.config.SyncConfig` for the tolerances (default: SyncConfig()).
    max_frames : keep only the first this many instants.

    Returns
    -------
    positions (T, S, 32, 3) float64 mm, confidence (T, S, 32) uint8, sensor ids (the recording's order).

    Raises
    ------
    DataError
        Not a recording, no sensor channel, no frame with a body.
    """

    reader = RecordingReader(path)
    ids = reader.require_sensors("record with `skelfuse record`")
    sync = sync if sync is not None else SyncConfig()
    grouper = FrameGrouper.from_sync(ids, sync, by=by)
    positions: list[np.ndarray] = []
    confidence: list[np.ndarray] = []

    def take(groups: Sequence[FrameGroup]) -> None:
        for group in groups:
            pos, conf, _ = group_bodies(group.frames, ids)  # (S, B, 32, 3): every sensor's bodies, padded
            if pos.shape[1] == 0:
                pos, conf = np.full((len(ids), 1, N_JOINTS, 3), np.nan), np.zeros((len(ids), 1, N_JOINTS), np.uint8)
            positions.append(pos[:, 0])  # the first body of each sensor: one person walking
            confidence.append(conf[:, 0])

    n_read = 0
    for frame in reader.frames():
        take(grouper.push(frame, int(frame.host_time_ns)))
        n_read += 1
        if progress and n_read % 5000 == 0:
            note(f"reading {reader.path.name}: {n_read} frames")
        if max_frames is not None and len(positions) >= max_frames:
            break
    take(grouper.flush())
    if max_frames is not None:
        del positions[max_frames:], confidence[max_frames:]
    if not positions:
        raise DataError(f"recording {reader.path} holds no readable sensor frames")
    pos_arr, conf_arr = np.stack(positions), np.stack(confidence)
    seen = np.isfinite(pos_arr).all(axis=-1).any(axis=-1)  # (T, S)
    if not seen.any():
        raise DataError(
            f"recording {reader.path}: no sensor saw a body in {len(positions)} instants; record a "
            "person walking through the shared space"
        )
    if progress:
        per_sensor = ", ".join(f"{s}: {int(seen[:, i].sum())}" for i, s in enumerate(ids))
        rejects = f", {sum(reader.rejects.values())} unreadable messages skipped" if reader.rejects else ""
        note(
            f"read {reader.path.name}: {n_read} frames -> {len(positions)} instants (frames with a body per "
            f"sensor: {per_sensor}){rejects}"
        )
    return pos_arr, conf_arr, ids


def take_arrays(
    take: InputTake,
    *,
    sync: SyncConfig | None = None,
    max_frames: int | None = None,
    progress: bool = True,
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """An opened take (any format, :func:`skelfuse.recording.inputs.open_inputs`) as a one-person take.

    Frames are matched in time as the take says (device clock with offsets, host time, or index: the take's
    notes say which) and grouped into instants by :class:`~skelfuse.rig.grouping.FrameGrouper`; every
    group is one frame of the take, and each sensor contributes its **first body** (NaN / NONE where it
    has none), so files that start at different frames line up by time, not by index.

    Returns positions (T, S, 32, 3) float64 mm, confidence (T, S, 32) uint8, sensor ids (input order).

    Raises DataError when no instant holds a body.
    """
    ids = take.sensor_ids
    positions: list[np.ndarray] = []
    confidence: list[np.ndarray] = []
    for group in take.groups(sync):
        pos, conf, _ = group_bodies(group.frames, ids)
        if pos.shape[1] == 0:
            pos, conf = np.full((len(ids), 1, N_JOINTS, 3), np.nan), np.zeros((len(ids), 1, N_JOINTS), np.uint8)
        positions.append(pos[:, 0])
        confidence.append(conf[:, 0])
        if max_frames is not None and len(positions) >= max_frames:
            break
    if not positions:
        raise DataError(f"the take ({', '.join(ids)}) holds no frames")
    pos_arr, conf_arr = np.stack(positions), np.stack(confidence)
    seen = np.isfinite(pos_arr).all(axis=-1).any(axis=-1)
    if not seen.any():
        raise DataError(
            f"the take ({', '.join(ids)}): no sensor saw a body in {len(positions)} instants; record a person "
            "walking through the shared space"
        )
    if progress:
        both = int(seen.all(axis=1).sum())
        per_sensor = ", ".join(f"{s}: {int(seen[:, i].sum())}" for i, s in enumerate(ids))
        note(
            f"take: {len(positions)} instants matched by {take.clock} time (frames with a body per sensor: "
            f"{per_sensor}; with every sensor: {both})"
        )
    return pos_arr, conf_arr, ids


def load_file_takes(
    takes: Sequence[tuple[str, Path]], *, max_frames: int | None = None, progress: bool = False
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """Per-sensor skeleton files of any format (``(sensor id, path)`` pairs) as one time-matched take.

    Files with device timestamps are matched on them (whatever frame each starts at); files without
    (andyj1 CSV) by index. See :func:`take_arrays`.
    """
    take = open_inputs([f"{sensor_id}={path}" for sensor_id, path in takes])
    return take_arrays(take, max_frames=max_frames, progress=progress)
