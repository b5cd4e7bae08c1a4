"""Which recorded skeleton format a path holds, and ``ID=PATH`` input specs.

Formats, by what the file holds (not only its suffix):

============== ============================================================ ===================
name           what                                                         needs
============== ============================================================ ===================
mcap           a ``skelfuse record`` MCAP (read by ``skelfuse.recording``)   -
mkv            an Azure Kinect ``.mkv``, run through the body tracker        pyk4a + k4abt SDK
offline        the Body Tracking SDK offline_processor JSON                  -
extractor      HPI-CH/azure-kinect-mkv-extractor positions_3d.csv (+ orient.) -
andyj1         the andyj1 joints CSV (two header rows, 32 rows per body)     -
long           the plain long CSV (``timestamp_us,sensor,body_id,joint,...``) -
============== ============================================================ ===================

:func:`detect_format` looks at the first bytes / line; :func:`load_sensor_file` reads every non-MCAP format
into :class:`~skelfuse.sources.recorded.Recording` objects (one per sensor).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skelfuse.schema.errors import DataError
from skelfuse.sources import extractor_csv, long_csv
from skelfuse.sources.kinect import EndOfStream, MkvSource
from skelfuse.sources.recorded import Recording, _pad_bodies, load_andyj1_csv, load_offline_processor_json

FORMATS = ("mcap", "mkv", "offline", "extractor", "andyj1", "long")
"""Every recorded format the reader layer knows (``--format`` choices besides ``auto``)."""

_MCAP_MAGIC = b"\x89MCAP0\r\n"
_MKV_MAGIC = b"\x1a\x45\xdf\xa3"


@dataclass(frozen=True)
class InputSpec:
    """One ``[ID=]PATH`` given on the command line: the path and, optionally, the sensor id to use."""

    path: Path
    sensor_id: str | None = None

    @classmethod
    def parse(cls, text: str) -> InputSpec:
        """``PATH`` or ``ID=PATH`` (an ``=`` inside an existing path is taken as part of the path)."""
        if "=" in text and not Path(text).exists():
            sensor_id, _, path = text.partition("=")
            if not sensor_id or not path:
                raise DataError(f"input {text!r}: expected PATH or ID=PATH")
            return cls(Path(path), sensor_id)
        return cls(Path(text))

    def __str__(self) -> str:
        return f"{self.sensor_id}={self.path}" if self.sensor_id else str(self.path)


def detect_format(path: str | Path) -> str:
    """The format of ``path`` (one of :data:`FORMATS`), from its content.

    Raises
    ------
    DataError
        The path does not exist, or holds none of the known formats (the message lists them).
    """
    path = Path(path)
    if path.is_dir():
        extractor_csv.extractor_files(path)  # raises naming the missing positions_3d.csv
        return "extractor"
    if not path.is_file():
        raise DataError(f"{path}: no such file or folder; check the path")
    with path.open("rb") as handle:
        head = handle.read(4096)
    if head.startswith(_MCAP_MAGIC):
        return "mcap"
    if head.startswith(_MKV_MAGIC):
        return "mkv"
    text = head.decode("utf-8", errors="replace").lstrip("\ufeff")
    stripped = text.lstrip()
    if stripped.startswith("{"):
        return "offline"
    lines = [line.strip() for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    first = lines[0] if lines else ""
    if first.startswith("timestamp;body_idx;"):
        return "extractor"
    if first.split(",")[0].strip().lower() == "timestamp_us":
        return "long"
    if len(lines) > 1 and lines[1].startswith("Body ID"):
        return "andyj1"
    raise DataError(
        f"{path}:1: cannot tell the recording format from its first line {first[:60]!r}. Known: a skelfuse "
        "MCAP, an Azure Kinect .mkv, an offline_processor .json, an azure-kinect-mkv-extractor camera folder "
        "(positions_3d.csv, header 'timestamp;body_idx;...'), an andyj1 CSV (second line 'Body ID,...') or the "
        "long CSV (header 'timestamp_us,sensor,body_id,joint,x,y,z', docs/recordings.md); convert yours to "
        "the long CSV"
    )


def load_sensor_file(spec: InputSpec, *, fmt: str | None = None, assume_confidence: str = "medium") -> list[Recording]:
    """Read a non-MCAP recording into one :class:`Recording` per sensor it holds.

    ``fmt`` None detects the format. ``assume_confidence`` applies to formats without confidence (the
    offline_processor JSON without a confidence field, a long CSV without a confidence column).

    Raises
    ------
    DataError
        Unknown or malformed file (naming file, line or frame and the fix); ``mcap`` (read it with
        ``skelfuse.recording.inputs``).
    ServiceError
        ``mkv`` where pyk4a or the Body Tracking SDK is not installed.
    """
    fmt = fmt or detect_format(spec.path)
    if fmt == "offline":
        return [load_offline_processor_json(spec.path, sensor_id=spec.sensor_id, assume_confidence=assume_confidence)]
    if fmt == "extractor":
        return [extractor_csv.load_extractor_csv(spec.path, sensor_id=spec.sensor_id)]
    if fmt == "andyj1":
        return [load_andyj1_csv(spec.path, sensor_id=spec.sensor_id)]
    if fmt == "long":
        return long_csv.load_long_csv(spec.path, assume_confidence=assume_confidence, sensor_id=spec.sensor_id)
    if fmt == "mkv":
        return [load_mkv(spec.path, sensor_id=spec.sensor_id)]
    raise DataError(f"{spec.path}: format {fmt!r} is not a per-sensor skeleton file; known: {', '.join(FORMATS)}")


def load_mkv(path: Path, *, sensor_id: str | None = None) -> Recording:
    """Run an Azure Kinect ``.mkv`` through the body tracker (pyk4a + the Body Tracking SDK) into a Recording."""
    source = MkvSource(path, sensor_id=sensor_id)
    source.open()
    frames, times = [], []
    try:
        while True:
            try:
                frame = source.read(5.0)
            except EndOfStream:
                break
            if frame is None:
                continue
            frames.append(
                [
                    (int(b), frame.positions[i], frame.orientations[i], frame.confidence[i])
                    for i, b in enumerate(frame.body_ids)
                ]
            )
            times.append(frame.device_time_us)
    finally:
        source.close()
    positions, orientations, confidence, body_ids = _pad_bodies(frames)
    return Recording(
        sensor_id=source.sensor_id,
        positions=positions,
        orientations=orientations,
        confidence=confidence,
        body_ids=body_ids,
        device_time_us=np.asarray(times, dtype=np.int64),
        source=str(path),
        file_format="mkv",
    )
