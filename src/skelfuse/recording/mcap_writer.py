"""Writing a skelfuse MCAP recording: :class:`RecordingWriter` (the layout in :mod:`skelfuse.recording.mcap_layout`,
the file described in docs/recording.md); :mod:`skelfuse.recording.mcap_io` reads it back.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Iterable, Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any

from mcap.writer import IndexType, Writer

from skelfuse.recording.mcap_layout import (
    CALIBRATION_METADATA,
    CLOUDS_MESSAGE_ENCODING,
    CLOUDS_SCHEMA_NAME,
    CLOUDS_SCHEMA_TEXT,
    COMPRESSIONS,
    FUSED_MESSAGE_ENCODING,
    FUSED_SCHEMA_NAME,
    FUSED_SCHEMA_TEXT,
    MESSAGE_ENCODING,
    PROFILE,
    RECORDING_METADATA,
    RESERVED_METADATA_KEYS,
    SCHEMA_ENCODING,
    SCHEMA_NAME,
    SCHEMA_TEXT,
    as_pose,
    clamp_u64,
)
from skelfuse.schema.frames import FusedFrame, SensorFrame
from skelfuse.version import __version__
from skelfuse.wire import keys
from skelfuse.wire.clouds import PersonCloudsFrame, decode_person_clouds
from skelfuse.wire.codec import (
    VERSION_MAJOR,
    VERSION_MINOR,
    decode_fused_frame,
    decode_sensor_frame,
    encode_fused_frame,
    encode_sensor_frame,
)

# --------------------------------------------------------------------------------------------------------
# Writer


class RecordingWriter:
    """Write raw sensor frames of one rig into an MCAP file.

    Parameters
    ----------
    path : str or Path
        File to create (overwritten if it exists). ``.mcap`` is the usual extension.
    rig : str
        Rig name; the topics are the rig's zenoh sensor keys.
    sensor_ids : iterable of str
        Sensors whose channels are created up front (in this order). Frames of other sensors get a
        channel when their first frame arrives.
    metadata : dict, optional
        Extra keys for the ``skelfuse.recording`` metadata record (e.g. operator, take, notes). Values that
        are not str are stored as JSON text. Keys must not be one of :data:`RESERVED_METADATA_KEYS`.
    world_from_sensor : mapping of sensor id -> (4, 4) array, optional
        The rig's calibration (mm), stored in a ``skelfuse.calibration`` metadata record so that offline
        fusion needs no separate file.
    chunk_size : int
        Bytes of uncompressed messages after which a chunk is closed (the mcap writer's ``chunk_size``).
    flush_interval_s : float or None
        Seconds after which the open chunk is finished and flushed to the OS on the next write: the most
        data a killed recorder can lose. None: flush only when a chunk is full (and on :meth:`flush`).
    fsync : bool
        Also ``os.fsync`` on every flush (survives power loss, not only a killed process; slower).
    compression : {"zstd", "lz4", None}
        Chunk compression. Foxglove and the ``mcap`` CLI read both.
    clock : callable
        Monotonic time source in seconds (injected by tests).

    Attributes
    ----------
    path : Path
    rig : str
    frames_written : int
        Sensor frames written.
    fused_frames_written : int
        Fused frames written (:meth:`write_fused_payload`).
    flushes : int
        How many times buffered data was pushed to the OS.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        rig: str,
        sensor_ids: Iterable[str] = (),
        metadata: Mapping[str, Any] | None = None,
        world_from_sensor: Mapping[str, Any] | None = None,
        chunk_size: int = 1024 * 1024,
        flush_interval_s: float | None = 1.0,
        fsync: bool = False,
        compression: str | None = "zstd",
        clock=time.monotonic,
    ) -> None:
        self.path = Path(path)
        self.rig = keys.validate_name(rig, "rig")
        if compression not in COMPRESSIONS:
            raise ValueError(f"compression must be one of 'zstd', 'lz4' or None, got {compression!r}")
        if flush_interval_s is not None and not (math.isfinite(flush_interval_s) and flush_interval_s > 0):
            raise ValueError(f"flush_interval_s must be a number of seconds > 0 or None, got {flush_interval_s!r}")
        if int(chunk_size) <= 0:
            raise ValueError(f"chunk_size must be > 0 bytes, got {chunk_size!r}")
        user = dict(metadata or {})
        clash = sorted(set(user) & set(RESERVED_METADATA_KEYS))
        if clash:
            raise ValueError(
                f"metadata keys {clash} are reserved for the writer; rename them "
                f"(reserved: {', '.join(RESERVED_METADATA_KEYS)})"
            )
        sensors = [keys.validate_name(s, "sensor") for s in sensor_ids]
        poses = {sid: as_pose(pose, sid) for sid, pose in (world_from_sensor or {}).items()}

        self._clock = clock
        self._flush_interval_s = flush_interval_s
        self._fsync = bool(fsync)
        self._stream: IO[bytes] = open(self.path, "wb")  # closed in close()
        self._writer = Writer(
            self._stream, chunk_size=int(chunk_size), compression=COMPRESSIONS[compression], index_types=IndexType.ALL
        )
        self._channels: dict[str, int] = {}
        self._fused_channel: int | None = None
        self._cloud_channels: dict[str, int] = {}
        self._closed = False
        self.frames_written = 0
        self.clouds_written = 0
        self.fused_frames_written = 0
        self.flushes = 0

        start_ns = time.time_ns()
        self._writer.start(profile=PROFILE, library=f"skelfuse/{__version__}")
        record = {str(k): v if isinstance(v, str) else json.dumps(v) for k, v in user.items()}
        record.update(
            {
                "rig": self.rig,
                "skelfuse_version": __version__,
                "wire_version": f"{VERSION_MAJOR}.{VERSION_MINOR}",
                "start_time_ns": str(start_ns),
                "start_time_utc": datetime.fromtimestamp(start_ns / 1e9, UTC).isoformat(),
                "sensor_ids": json.dumps(sensors),
            }
        )
        self._writer.add_metadata(RECORDING_METADATA, record)
        if poses:
            calib = {"units": "mm", "convention": "world_from_sensor, row-major 4x4, p_world = T @ p_sensor"}
            calib.update({f"world_from_sensor/{sid}": json.dumps(pose.tolist()) for sid, pose in poses.items()})
            self._writer.add_metadata(CALIBRATION_METADATA, calib)
        self._schema_id = self._writer.register_schema(SCHEMA_NAME, SCHEMA_ENCODING, SCHEMA_TEXT.encode())
        for sid in sensors:
            self._channel(sid)
        self._stream.flush()
        self._last_flush = self._clock()

    # -- context manager -------------------------------------------------------------------------------
    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _channel(self, sensor_id: str) -> int:
        channel_id = self._channels.get(sensor_id)
        if channel_id is None:
            channel_id = self._writer.register_channel(
                topic=keys.sensor_skeletons(self.rig, sensor_id),
                message_encoding=MESSAGE_ENCODING,
                schema_id=self._schema_id,
                metadata={"sensor_id": sensor_id},
            )
            self._channels[sensor_id] = channel_id
        return channel_id

    def write(self, frame: SensorFrame) -> None:
        """Encode ``frame`` with the wire codec and record it (ValueError if the codec refuses it)."""
        self._write(frame, encode_sensor_frame(frame))

    def write_payload(self, payload: bytes | bytearray | memoryview) -> SensorFrame:
        """Record a received wire payload as it is (bit-identical); returns the decoded frame.

        Raises
        ------
        DecodeError
            The payload is not a valid sensor frame: nothing is written (count it and carry on).
        """
        data = bytes(payload)
        frame = decode_sensor_frame(data)
        self._write(frame, data)
        return frame

    def _write(self, frame: SensorFrame, data: bytes) -> None:
        if self._closed:
            raise ValueError(f"recording {self.path} is closed")
        channel_id = self._channel(frame.sensor_id)
        self._add(channel_id, frame.host_time_ns, frame.device_time_us * 1000, data, int(frame.sequence))
        self.frames_written += 1

    def _add(self, channel_id: int, log_time_ns: int, publish_time_ns: int, data: bytes, sequence: int) -> None:
        """One message on ``channel_id`` (times clamped to MCAP's u64, sequence to u32), flushed when one is due."""
        self._writer.add_message(
            channel_id=channel_id,
            log_time=clamp_u64(log_time_ns),
            publish_time=clamp_u64(publish_time_ns),
            data=data,
            sequence=sequence & 0xFFFFFFFF,
        )
        if self._flush_interval_s is not None and self._clock() - self._last_flush >= self._flush_interval_s:
            self.flush()

    def write_fused(self, frame: FusedFrame, *, log_time_ns: int) -> None:
        """Encode a fused frame with the wire codec and record it on the fused channel.

        ``log_time_ns`` is the host time (ns since the Unix epoch) the frame belongs to on the recording's
        time axis; a recorder passes the time it received the frame. ValueError if the codec refuses it.
        """
        self._write_fused(encode_fused_frame(frame), int(frame.time_us), log_time_ns)

    def write_fused_payload(self, payload: bytes | bytearray | memoryview, *, log_time_ns: int) -> FusedFrame:
        """Record a received fused wire payload as it is (bit-identical); returns the decoded frame.

        Raises
        ------
        DecodeError
            The payload is not a valid fused frame: nothing is written (count it and carry on).
        """
        data = bytes(payload)
        frame = decode_fused_frame(data)
        self._write_fused(data, int(frame.time_us), log_time_ns)
        return frame

    def _write_fused(self, data: bytes, time_us: int, log_time_ns: int) -> None:
        if self._closed:
            raise ValueError(f"recording {self.path} is closed")
        if self._fused_channel is None:
            schema_id = self._writer.register_schema(FUSED_SCHEMA_NAME, SCHEMA_ENCODING, FUSED_SCHEMA_TEXT.encode())
            self._fused_channel = self._writer.register_channel(
                topic=keys.fused_skeletons(self.rig),
                message_encoding=FUSED_MESSAGE_ENCODING,
                schema_id=schema_id,
                metadata={"stream": "fused"},
            )
        self._add(self._fused_channel, log_time_ns, time_us * 1000, data, self.fused_frames_written)
        self.fused_frames_written += 1

    def write_clouds_payload(self, payload: bytes | bytearray | memoryview) -> PersonCloudsFrame:
        """Record a received person-cloud payload as it is, on its sensor's ``.../clouds`` channel.

        Raises
        ------
        DecodeError
            The payload is not a valid person-cloud payload: nothing is written.
        """
        if self._closed:
            raise ValueError(f"recording {self.path} is closed")
        data = bytes(payload)
        frame = decode_person_clouds(data)
        channel_id = self._cloud_channels.get(frame.sensor_id)
        if channel_id is None:
            schema_id = self._writer.register_schema(CLOUDS_SCHEMA_NAME, SCHEMA_ENCODING, CLOUDS_SCHEMA_TEXT.encode())
            channel_id = self._cloud_channels[frame.sensor_id] = self._writer.register_channel(
                topic=keys.sensor_clouds(self.rig, frame.sensor_id),
                message_encoding=CLOUDS_MESSAGE_ENCODING,
                schema_id=schema_id,
                metadata={"sensor_id": frame.sensor_id},
            )
        self._add(channel_id, frame.host_timestamp_ns, frame.device_timestamp_us * 1000, data, int(frame.sequence))
        self.clouds_written += 1
        return frame

    def flush(self) -> None:
        """Finish the open chunk and push everything written so far to the OS (and disk, with ``fsync``).

        A recorder that can sit idle should call this on a timer: the periodic flush runs on writes only.
        """
        if self._closed:
            return
        self._writer.flush()
        if self._fsync:
            os.fsync(self._stream.fileno())
        self.flushes += 1
        self._last_flush = self._clock()

    def close(self) -> None:
        """Write the last chunk, the summary (indexes, statistics) and the footer; close the file."""
        if self._closed:
            return
        try:
            self._writer.finish()
            self._stream.flush()
            if self._fsync:
                os.fsync(self._stream.fileno())
        finally:
            self._closed = True
            self._stream.close()
