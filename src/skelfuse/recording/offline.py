"""Fuse a recording offline and pace a replay.

The fused frames are written by :mod:`skelfuse.export.csv` (the one fused table, CSV or Parquet) or the other
exporters of :mod:`skelfuse.export`.

Cycle of :func:`fuse_recording`: read the recording's sensor frames in host-time order
(:class:`~skelfuse.recording.mcap_io.RecordingReader`), group them into instants as the live fusion node
does (:class:`skelfuse.rig.grouping.FrameGrouper`, fed the recorded host time as its arrival clock),
and fuse each instant with the node's own per-instant adapter
(:class:`skelfuse.rig.instant.GroupFuser`: every body of every sensor mapped to the world frame with
the rig's calibration, associated across sensors and time by :class:`skelfuse.fusion.people.PeopleFuser`,
one fused skeleton per person with a stable track id). Live and offline share that adapter, so the live
stream of a set of frames equals the offline fusion of the same frames.

:func:`replay_frames` paces recorded frames by their log time (host clock) and knows nothing of zenoh: the
CLI's ``skelfuse replay FILE`` publishes each yielded ``record.payload`` on ``record.topic``.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from skelfuse.config import DEFAULT_PRESET, RigConfig, SyncConfig
from skelfuse.fusion.presets import FusionParams, preset
from skelfuse.fusion.smoother import SMOOTHERS, smooth_tracks
from skelfuse.progress import Progress
from skelfuse.recording.inputs import InputTake
from skelfuse.recording.mcap_io import RecordedFrame, RecordingReader
from skelfuse.rig.grouping import FrameGrouper
from skelfuse.rig.instant import RESET_GAP_S, FusedInstant, GroupFuser
from skelfuse.rig.smoothing import merged_or_nan, smoothed_frame
from skelfuse.schema.errors import DataError
from skelfuse.schema.frames import FusedFrame, SensorFrame

log = logging.getLogger("skelfuse.recording")

__all__ = ["RESET_GAP_S", "fuse_recording", "replay_frames", "resolve_poses"]


# --------------------------------------------------------------------------------------------------------
# Parameters and calibration


def _params(rig_config: RigConfig | None, preset_name: str | None, eps_mm: float | None) -> FusionParams:
    """Explicit preset / eps first, then the rig config's ``[fusion]`` (with its overrides), then the default
    preset (:data:`skelfuse.config.DEFAULT_PRESET`) at its own DBSCAN radius."""
    if preset_name is None and rig_config is not None:
        params = rig_config.fusion.fusion_params()
        return params if eps_mm is None else replace(params, eps_mm=float(eps_mm))
    return preset(preset_name or DEFAULT_PRESET, eps_mm=eps_mm)


def resolve_poses(
    sensor_ids: Iterable[str],
    *,
    world_from_sensor: Mapping[str, Any] | None = None,
    rig_config: RigConfig | None = None,
    recording: RecordingReader | None = None,
    take: InputTake | None = None,
) -> np.ndarray:
    """(S, 4, 4) ``world_from_sensor`` of ``sensor_ids``, from the first source that has them.

    Order: the explicit ``world_from_sensor`` mapping, the rig config, the recording's calibration metadata
    (or the opened take's: an MCAP's metadata, identity poses for ``--registered`` inputs).

    Raises
    ------
    DataError
        No source holds a pose for every sensor: the message names the sensors and where to get one.
    """
    sensor_ids = tuple(sensor_ids)
    sources: list[tuple[str, Mapping[str, Any]]] = []
    if world_from_sensor is not None:
        sources.append(("world_from_sensor argument", world_from_sensor))
    if rig_config is not None:
        _check_rig_matches(rig_config, sensor_ids, recording)
        if rig_config.calibration.file is not None and not rig_config.calibration.file.exists():
            rig_config.poses()  # raises the ConfigError that names the missing file and the fix
        sources.append((f"rig config {rig_config.source}", rig_config.poses(required=False)))
    if recording is not None and recording.calibration:
        sources.append((f"calibration metadata of {recording.path}", recording.calibration))
    if take is not None and take.poses:
        what = "--registered identity poses" if take.registered else "calibration metadata of the recording"
        sources.append((what, take.poses))
    tried: list[str] = []
    for name, poses in sources:
        missing = [s for s in sensor_ids if s not in poses]
        if not missing:
            out = np.stack([np.asarray(poses[s], dtype=np.float64) for s in sensor_ids])
            if out.shape[1:] != (4, 4) or not np.isfinite(out).all():
                raise DataError(f"the {name} holds a pose that is not a finite 4x4 matrix")
            log.info(
                "poses of %s: from the %s%s", ", ".join(sensor_ids), name, f" ({'; '.join(tried)})" if tried else ""
            )
            return out
        tried.append(f"the {name} lacks {', '.join(missing)}")
    where = (
        "; ".join(tried)
        if tried
        else "no rig config or world_from_sensor was given and the recording holds no calibration metadata"
    )
    raise DataError(
        f"no calibration (world_from_sensor) for every sensor of the recording ({', '.join(sensor_ids)}): "
        f"{where}. Pass the rig config that holds the poses "
        f"([calibration] file or sensors[i].world_from_sensor), or pass world_from_sensor; recordings made "
        f"with a calibrated rig carry it in their metadata; files already in one frame take --registered; "
        f"`skelfuse calibrate skeleton` makes a calibration from a walk"
    )


def _check_rig_matches(rig_config: RigConfig, sensor_ids: tuple[str, ...], recording: RecordingReader | None) -> None:
    """A rig config given for a recording must be that recording's rig: its sensors, and (warned) its name."""
    foreign = [s for s in sensor_ids if s not in rig_config.sensor_ids]
    recorded_rig = recording.metadata.get("rig") if recording is not None else None
    where = f"recording {recording.path}" if recording is not None else "the recording"
    if foreign:
        raise DataError(
            f"the rig config {rig_config.source} (rig {rig_config.name!r}, sensors "
            f"{', '.join(rig_config.sensor_ids) or 'none'}) is not the rig of {where} (rig {recorded_rig!r}, sensors "
            f"{', '.join(sensor_ids)}): it has no sensor {', '.join(foreign)}. Pass the config of the rig that "
            "recorded it, or leave the config out to fuse with the recording's own calibration"
        )
    if recorded_rig is not None and recorded_rig != rig_config.name:
        log.warning(
            "the rig config %s is rig %r but %s was recorded by rig %r; its sensor ids match, so its poses, "
            "[sync] and [fusion] are used",
            rig_config.source,
            rig_config.name,
            where,
            recorded_rig,
        )


# --------------------------------------------------------------------------------------------------------
# Offline fusion


def fuse_recording(
    recording_path: str | os.PathLike[str] | InputTake,
    *,
    rig_config: RigConfig | None = None,
    world_from_sensor: Mapping[str, Any] | None = None,
    preset_name: str | None = None,
    eps_mm: float | None = None,
    by: str | None = None,
    tolerance_us: int | None = None,
    deadline_us: int | None = None,
    start_ns: int | None = None,
    end_ns: int | None = None,
    progress: bool = True,
    smoother: str | None = None,
    smoother_lag: int | None = None,
) -> Iterator[FusedFrame]:
    """Fuse every instant of a recording, as the live node would have, then smooth it with zero lag.

    Parameters
    ----------
    recording_path : str, Path or InputTake
        A skelfuse MCAP recording (a truncated one is read up to its last complete chunk), or a take opened
        by :func:`skelfuse.recording.inputs.open_inputs` (any format, frames matched in time).
    rig_config : skelfuse.config.RigConfig, optional
        Poses of the sensors (``rig_config.poses()``), the fusion section and the grouping (``[sync]``).
    world_from_sensor : mapping sensor id -> (4, 4), optional
        Poses (mm); override the rig config's and the recording's.
    preset_name : str, optional
        Fusion preset ("skelfuse", or the paper's "A1".."A5"). Default: the rig config's ``[fusion]`` (preset
        and overrides), else "skelfuse".
    eps_mm : float, optional
        DBSCAN radius; default the rig config's, else the preset's own (75 mm for "skelfuse", 100 mm for
        the paper's presets).
    by : {"device", "host"}, optional
        Group by device timestamps (hardware-synced rigs) or host timestamps. Default: the rig config's
        ``[sync] by``, else "device". For an MCAP path only (an opened take has its matching clock).
    tolerance_us, deadline_us : int, optional
        Grouping window and how long an incomplete instant waits, on the recorded host clock. Default: the
        rig config's ``[sync]``, else :class:`skelfuse.config.SyncConfig`'s defaults (10 ms, 17 ms).
    start_ns, end_ns : int, optional
        Log-time (host ns) window of an MCAP recording to fuse (ignored for an opened take).
    progress : bool
        Draw a progress bar on stderr (only when it is a terminal).
    smoother : {"rts", "none"} or None
        "rts": the zero-lag RTS smoother over the whole take (:mod:`skelfuse.fusion.smoother`); "none": the
        live output, frame by frame. None: "rts" with the "cv_kalman" filter, else "none" (logged).
    smoother_lag : int, optional
        With "rts": the fixed-lag form, each instant from the instants up to this many later.

    Returns
    -------
    iterator of FusedFrame
        One per instant, in time order, with the recording's sensors as ``sensor_ids``; one person per
        confirmed track with an estimate (stable track ids, ascending; none before a track is confirmed,
        ``birth_frames`` = 3 instants after a person first appears). Setup errors are raised by this call,
        before iterating.

    Raises
    ------
    DataError
        Missing / not-MCAP recording, no sensor channel, or no calibration for every sensor (see
        :func:`resolve_poses`).
    """
    params = _params(rig_config, preset_name, eps_mm)
    smooth = _smoother(smoother, params)
    sync = rig_config.sync if rig_config is not None else SyncConfig()
    if isinstance(recording_path, InputTake):
        take = recording_path
        poses = resolve_poses(take.sensor_ids, world_from_sensor=world_from_sensor, rig_config=rig_config, take=take)
        grouper = take.grouper(sync, tolerance_us=tolerance_us, deadline_us=deadline_us)
        return _smoothed(_fuse_take(take, poses, params, grouper, progress), params, smooth, smoother_lag)
    reader = _open_recording(recording_path)
    sensor_ids = reader.require_sensors("nothing to fuse")
    poses = resolve_poses(sensor_ids, world_from_sensor=world_from_sensor, rig_config=rig_config, recording=reader)
    grouper = FrameGrouper.from_sync(sensor_ids, sync, by=by, tolerance_us=tolerance_us, deadline_us=deadline_us)
    instants = _fuse(reader, sensor_ids, poses, params, grouper, start_ns, end_ns, progress)
    return _smoothed(instants, params, smooth, smoother_lag)


def _open_recording(path: str | os.PathLike[str]) -> RecordingReader:
    """The MCAP recording, with a warning where it ends early or has unreadable chunks."""
    reader = RecordingReader(path)
    if reader.truncated or reader.bad_chunks:
        log.warning(
            "recording %s %s; fusing what it holds up to there%s",
            reader.path,
            "ends early (no footer: a recorder that was killed, or a file that was cut)"
            if reader.truncated
            else f"has {reader.bad_chunks} unreadable chunk(s)",
            f" ({'; '.join(reader.problems[:3])})" if reader.problems else "",
        )
    return reader


def _smoother(name: str | None, params: FusionParams) -> bool:
    """Whether to smooth: the named smoother, or the default for the fusion's filter (logged)."""
    if name is None:
        smooth = params.filter == "cv_kalman"
        log.info(
            "offline smoothing: %s",
            "rts (zero lag; --smoother none for the live filter's output)"
            if smooth
            else f"none (the {params.filter} filter has no velocity model to smooth over)",
        )
        return smooth
    if name not in SMOOTHERS:
        raise DataError(f"unknown smoother {name!r}; expected one of {', '.join(SMOOTHERS)}")
    if name == "rts" and params.filter != "cv_kalman":
        raise DataError(
            f"the rts smoother needs the cv_kalman filter (the skelfuse preset); this fusion uses {params.filter!r}: "
            "choose --smoother none"
        )
    return name == "rts"


def _smoothed(
    instants: Iterator[FusedInstant], params: FusionParams, smooth: bool, lag: int | None
) -> Iterator[FusedFrame]:
    """The instants' frames, live (streamed) or, when ``smooth``, after the RTS smoother over the whole take."""
    if not smooth:
        return (instant.frame for instant in instants)
    return _smooth_take(instants, params, lag)


def _smooth_take(instants: Iterator[FusedInstant], params: FusionParams, lag: int | None) -> Iterator[FusedFrame]:
    frames: list[FusedFrame] = []
    times: list[float] = []
    ids: list[np.ndarray] = []
    merged: list[np.ndarray] = []
    agree: list[np.ndarray] = []
    restarted: list[np.ndarray | None] = []
    for instant in instants:
        people = instant.people
        frames.append(instant.frame)
        times.append(people.time_s)
        ids.append(people.track_ids)
        merged.append(merged_or_nan(people))
        agree.append(people.n_agree)
        restarted.append(people.restarted)
    smoothed = smooth_tracks(np.asarray(times), ids, merged, agree, restarted, params, lag)
    for frame, people_ids, positions in zip(frames, ids, smoothed, strict=True):
        yield smoothed_frame(frame, people_ids, positions)


def _fuse_take(
    take: InputTake, poses: np.ndarray, params: FusionParams, grouper: FrameGrouper, progress: bool
) -> Iterator[FusedInstant]:
    """A take of any format, clocked by its matched time (host time where the take has it)."""
    host = take.clock == "host"
    frames = ((f, int(f.host_time_ns) if host else int(f.device_time_us) * 1000) for f in take.frames())
    total = sum(r.n_frames for r in take.recordings)
    return _fuse_clocked(frames, take.sensor_ids, poses, params, grouper, total, progress)


def _fuse(
    reader: RecordingReader,
    sensor_ids: tuple[str, ...],
    poses: np.ndarray,
    params: FusionParams,
    grouper: FrameGrouper,
    start_ns: int | None,
    end_ns: int | None,
    progress: bool,
) -> Iterator[FusedInstant]:
    """A skelfuse recording: the recorded host time stands in for the arrival clock, so deadlines behave as
    they did live."""
    frames = ((f, int(f.host_time_ns)) for f in reader.frames(start_ns, end_ns))
    sensor_messages = (reader.message_count or 0) - (reader.fused_message_count or 0)  # a recorded fused stream
    return _fuse_clocked(frames, sensor_ids, poses, params, grouper, max(sensor_messages, 0), progress)


def _fuse_clocked(
    frames: Iterator[tuple[SensorFrame, int]],
    sensor_ids: tuple[str, ...],
    poses: np.ndarray,
    params: FusionParams,
    grouper: FrameGrouper,
    total: int,
    progress: bool,
) -> Iterator[FusedInstant]:
    """Group (frame, arrival clock in ns) pairs as the node would and fuse every group."""
    fuser = GroupFuser(sensor_ids, poses, params)
    bar = Progress(total, "fuse", enabled=None if progress else False)
    try:
        for frame, now_ns in frames:
            for group in grouper.push(frame, now_ns):
                yield fuser.step(group)
            bar.update()
        for group in grouper.flush():
            yield fuser.step(group)
    finally:
        bar.close()


# --------------------------------------------------------------------------------------------------------
# Replay pacing


def replay_frames(
    source: RecordingReader | Iterable[RecordedFrame],
    *,
    speed: float | None = 1.0,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], object] = time.sleep,
) -> Iterator[tuple[float, RecordedFrame]]:
    """Yield recorded frames when they are due, paced by their log time (host clock).

    Parameters
    ----------
    source : RecordingReader or iterable of RecordedFrame
        A reader (all its frames, in log-time order) or records from ``reader.records(start, end, sensors)``.
    speed : float or None
        Playback rate: 1.0 real time, 2.0 twice as fast. None: as fast as possible (no sleeping).
    clock, sleep : callables
        Monotonic seconds and a sleep function (injected by tests).

    Yields
    ------
    due_offset_s : float
        When the frame is due, seconds after the first frame (log-time offset divided by ``speed``; the plain
        log-time offset when ``speed`` is None).
    record : RecordedFrame
        ``record.frame`` is the decoded SensorFrame; publish ``record.payload`` on ``record.topic`` to replay
        bit-identical traffic. A consumer slower than real time is not caught up by skipping: frames come
        late instead.
    """
    if speed is not None and not (isinstance(speed, int | float) and math.isfinite(speed) and speed > 0):
        raise ValueError(f"speed must be a number > 0 or None (as fast as possible), got {speed!r}")
    records = source.records() if isinstance(source, RecordingReader) else source
    first_ns: int | None = None
    start_s = 0.0
    for record in records:
        if first_ns is None:
            first_ns = record.log_time_ns
            start_s = clock()
        offset_s = (record.log_time_ns - first_ns) / 1e9
        if speed is None:
            yield offset_s, record
            continue
        due_s = offset_s / speed
        delay = start_s + due_s - clock()
        if delay > 0:
            sleep(delay)
        yield due_s, record
