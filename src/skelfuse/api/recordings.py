"""Recordings for apps: read any supported format, read recorded fused frames, fuse recordings offline.

Cycle::

    for frame in skelfuse.read_sensor_frames("take.mcap"): ...          # SensorFrame, every sensor, in time
    for frame in skelfuse.read_fused_frames("take.mcap"): ...           # FusedFrame, as the recorder got them
    for frame in skelfuse.fuse_recording("take.mcap", config="rig.toml"): ...   # FusedFrame, fused here

The formats are those of ``skelfuse fuse --input`` (docs/recordings.md): a skelfuse MCAP, an Azure Kinect
``.mkv`` (needs the SDK), offline_processor JSON, azure-kinect-mkv-extractor folders, andyj1 CSV, the long
CSV; several files are matched in time (:func:`skelfuse.recording.inputs.open_inputs`). Offline fusion runs
the live node's own per-instant code (:func:`skelfuse.recording.offline.fuse_recording`), so it yields the
same :class:`~skelfuse.schema.frames.FusedFrame` objects a live subscriber receives.

Setup errors (a missing file, an unknown format, no calibration for a sensor) are raised by the call, before
iterating; they are :class:`~skelfuse.schema.errors.DataError` or :class:`~skelfuse.schema.errors.ConfigError`.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from skelfuse.config.model import RigConfig
from skelfuse.config.parse import load_rig_config
from skelfuse.recording.inputs import InputTake, open_inputs, single_recorded_mcap
from skelfuse.recording.mcap_io import RecordingReader
from skelfuse.recording.offline import fuse_recording as _fuse_offline
from skelfuse.schema.errors import DataError
from skelfuse.schema.frames import FusedFrame, SensorFrame

__all__ = ["fuse_recording", "read_fused_frames", "read_sensor_frames"]

PathLike = str | os.PathLike[str]


def read_sensor_frames(
    *inputs: PathLike, assume_confidence: str = "medium", clock: str = "auto", fps: float = 30.0
) -> Iterator[SensorFrame]:
    """Every sensor frame of a recording, all sensors in one stream, in the order their times match.

    Parameters
    ----------
    *inputs : ``PATH`` or ``"ID=PATH"``
        One recording holding several sensors (MCAP, long CSV), or one file per sensor.
    assume_confidence : {"medium", "low", "unknown"}
        The confidence given to joints of formats that store none (offline_processor JSON).
    clock : {"auto", "shared", "independent"}
        How the files' device clocks relate (docs/recordings.md); "auto" decides from their time ranges.
    fps : float
        Nominal frame rate, for files without timestamps.

    Returns
    -------
    iterator of SensorFrame
        Positions in each sensor's own frame (mm); times on the matched clock.
    """
    return _open(inputs, assume_confidence=assume_confidence, clock=clock, fps=fps).frames()


def read_fused_frames(path: PathLike) -> Iterator[FusedFrame]:
    """The fused frames a recorder wrote (``skelfuse record`` with ``[record] fused``), in receive order.

    A payload that fails to decode is skipped and counted, as the recorder's reader does; a file without a
    fused channel is an error (record the fused stream, or fuse the sensor frames: :func:`fuse_recording`).
    """
    reader = RecordingReader(path)
    if reader.fused_topic is None:
        raise DataError(
            f"{reader.path} holds no fused frames; record them with [record] fused = true, or fuse its sensor "
            f"frames offline with skelfuse.fuse_recording({str(path)!r}, config=...)"
        )
    return (record.frame for record in reader.fused_records())


def fuse_recording(
    *inputs: PathLike,
    config: PathLike | RigConfig | None = None,
    world_from_sensor: Mapping[str, Any] | None = None,
    preset: str | None = None,
    assume_confidence: str = "medium",
    clock: str = "auto",
) -> Iterator[FusedFrame]:
    """Fuse a recording offline, as the live fusion node would have: one FusedFrame per instant.

    Parameters
    ----------
    *inputs : ``PATH`` or ``"ID=PATH"``
        As for :func:`read_sensor_frames`. A single skelfuse MCAP is grouped on its recorded host arrival
        times, exactly as live (as ``skelfuse fuse --input take.mcap`` does).
    config : path or RigConfig, optional
        The rig config: the sensors' poses, ``[fusion]`` and ``[sync]``.
    world_from_sensor : mapping sensor id -> (4, 4) array, optional
        Poses (mm), overriding the config's and the recording's calibration metadata.
    preset : str, optional
        Fusion preset ("skelfuse", or the paper's "A1".."A5"); default the config's ``[fusion]``.
    assume_confidence, clock : as for :func:`read_sensor_frames`.

    Returns
    -------
    iterator of FusedFrame
        Positions in the world frame (mm), one person per confirmed track, stable track ids.

    Raises
    ------
    DataError
        A missing or malformed file, or no calibration for every sensor (the message says where to get one).
    """
    cfg = config if config is None or isinstance(config, RigConfig) else load_rig_config(Path(config))
    fps = cfg.sync.fps if cfg is not None else 30.0
    by = cfg.sync.by if cfg is not None else "device"
    source: Path | InputTake
    if single_recorded_mcap([os.fspath(i) for i in inputs]):
        source = Path(inputs[0])
    else:
        source = _open(inputs, assume_confidence=assume_confidence, clock=clock, fps=fps, by=by)
    return _fuse_offline(
        source, rig_config=cfg, world_from_sensor=world_from_sensor, preset_name=preset, progress=False
    )


def _open(inputs: tuple[PathLike, ...], **options: Any) -> InputTake:
    return open_inputs([os.fspath(i) for i in inputs], **options)
