"""Where an export's fused frames come from: a fused table, a recorded fused stream, or a recording fused now.

:func:`open_fused` looks at the input file and picks the one way to read it:

* ``.csv`` / ``.parquet``: the fused table (:func:`skelfuse.export.csv.read_fused_table`);
* ``.mcap`` with a fused channel (``[record] fused``): the fused frames as the live node published them;
* ``.mcap`` with sensor channels only (or ``refuse=True``): fused on the way through
  :func:`skelfuse.recording.fuse_recording`, with the rig config's poses and fusion settings or the
  recording's calibration metadata, or the poses the caller gives (``world_from_sensor``: the command line's
  levelled world where no calibration defines one, :func:`fuses_sensor_frames` says when it is needed).
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skelfuse.config import RigConfig
from skelfuse.export.csv import FUSED_FORMATS, read_fused_table
from skelfuse.recording.mcap_io import RecordingReader
from skelfuse.recording.offline import fuse_recording
from skelfuse.schema.errors import DataError
from skelfuse.schema.frames import FusedFrame

RECORDING_FORMATS = (".mcap",)
INPUT_FORMATS = FUSED_FORMATS + RECORDING_FORMATS


@dataclass
class FusedSource:
    """Fused frames and where they came from.

    Attributes
    ----------
    frames : iterator of FusedFrame
    kind : str
        ``"table"``, ``"recorded fused stream"`` or ``"fused from the sensor frames"``.
    total : int or None
        Messages to read, for a progress bar (None when unknown).
    """

    frames: Iterator[FusedFrame]
    kind: str
    total: int | None = None


def open_fused(
    path: str | os.PathLike[str],
    *,
    rig_config: RigConfig | None = None,
    preset_name: str | None = None,
    refuse: bool = False,
    progress: bool = True,
    world_from_sensor: Mapping[str, np.ndarray] | None = None,
    smoother: str | None = None,
) -> FusedSource:
    """Open ``path`` as a source of fused frames (see the module docstring).

    Parameters
    ----------
    refuse : bool
        For a recording: fuse its sensor frames even when it holds a recorded fused stream.
    smoother : "rts", "none" or None
        For a recording fused here: :func:`skelfuse.recording.fuse_recording`'s smoother (None: its default).
    progress : bool
        Offline fusion draws its progress bar on stderr (when it is a terminal).
    world_from_sensor : mapping sensor id -> (4, 4), optional
        Poses (mm) to fuse sensor frames with; override the rig config's and the recording's.

    Raises
    ------
    DataError
        The file is missing, has an extension none of the readers knows, or is a recording with neither a
        fused channel nor sensor channels (or no calibration to fuse them with).
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"input {path} not found (or not a file); check the path")
    suffix = path.suffix.lower()
    if suffix in FUSED_FORMATS:
        if refuse:
            raise DataError(f"--fuse needs a recording (.mcap); {path} is already a fused table")
        return FusedSource(read_fused_table(path), "table")
    if suffix not in RECORDING_FORMATS:
        raise DataError(
            f"cannot read {path}: unknown extension {path.suffix!r}; the input is a fused table "
            f"({', '.join(FUSED_FORMATS)}) or a skelfuse recording (.mcap)"
        )
    reader = RecordingReader(path)
    if reader.fused_topic is not None and not refuse:
        return FusedSource(reader.fused_frames(), "recorded fused stream", reader.fused_message_count)
    if not reader.sensors:
        raise DataError(f"recording {path} holds neither a fused stream nor sensor frames: nothing to export")
    frames = fuse_recording(
        path,
        rig_config=rig_config,
        world_from_sensor=world_from_sensor,
        preset_name=preset_name,
        progress=progress,
        smoother=smoother,
    )
    return FusedSource(frames, "fused from the sensor frames", reader.message_count)


def fuses_sensor_frames(path: str | os.PathLike[str], *, refuse: bool = False) -> bool:
    """Whether :func:`open_fused` fuses ``path``'s sensor frames (a recording without a fused stream, or
    ``refuse``) rather than reading fused frames: only then do the poses matter."""
    path = Path(path)
    if path.suffix.lower() not in RECORDING_FORMATS or not path.is_file():
        return False
    reader = RecordingReader(path)
    return bool(reader.sensors) and (refuse or reader.fused_topic is None)
