"""Record raw sensor frames into MCAP files and read them back, tolerating files cut short by a crash.

Layout of a skelfuse recording (details and the reasons for MCAP in ``docs/recording.md``):

* one *schema* record ``skelfuse.SensorFrame`` (encoding :data:`SCHEMA_ENCODING`) whose text points at
  ``docs/wire-format.md`` section 4, where the payload is specified byte by byte;
* one *channel* per sensor, its topic the sensor's zenoh key expression
  (``skelfuse/<rig>/sensors/<serial>/skeletons``, :func:`skelfuse.wire.keys.sensor_skeletons`), message
  encoding :data:`MESSAGE_ENCODING`;
* one *message* per sensor frame: the payload is exactly :func:`skelfuse.wire.codec.encode_sensor_frame`'s
  bytes (so a replay republishes bit-identical payloads), ``log_time`` = the frame's host time (ns),
  ``publish_time`` = its device time (µs -> ns), ``sequence`` = its sequence number modulo 2**32;
* when the fused stream is recorded too (``[record] fused``), a schema ``skelfuse.FusedFrame`` and one
  channel whose topic is the rig's fused key expression (``skelfuse/<rig>/fused/skeletons``, encoding
  :data:`FUSED_MESSAGE_ENCODING`), one message per fused frame: the fused wire payload as received,
  ``log_time`` = when the recorder received it (host ns), ``publish_time`` = the frame's time (µs -> ns),
  ``sequence`` = its index in the file modulo 2**32;
* *metadata* records ``skelfuse.recording`` (rig, skelfuse version, start time, sensors, caller's keys) and,
  when a calibration is given, ``skelfuse.calibration`` (``world_from_sensor`` per sensor, row-major 4x4,
  mm);
* zstd-compressed chunks with message indexes, and at :meth:`RecordingWriter.close` the summary section
  (chunk indexes, statistics, repeated schemas and channels) and the footer.

Cycle: a recorder opens a :class:`RecordingWriter`, calls :meth:`~RecordingWriter.write` (or
:meth:`~RecordingWriter.write_payload` with the bytes it received) per frame, and closes it. The writer
finishes the open chunk and flushes it to the OS every ``flush_interval_s``, so a recorder killed with
``kill -9`` leaves a file that :class:`RecordingReader` reads up to the last flushed chunk: without a
footer the reader scans the records from the start (the "streaming fallback") instead of using the index.

Reading never crashes on bad content: a message whose payload fails to decode is skipped and counted in
:attr:`RecordingReader.rejects` under its :class:`~skelfuse.wire.codec.DecodeError` reason, a chunk that
cannot be decompressed or fails its CRC is skipped and counted in :attr:`RecordingReader.bad_chunks`.
Only a missing file or one that is not MCAP at all raises :class:`~skelfuse.schema.errors.DataError`.
"""

from __future__ import annotations

import heapq
import io
import json
import os
import struct
from collections import Counter
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk

from skelfuse.recording.mcap_layout import (
    CALIBRATION_METADATA,
    CLOUDS_MESSAGE_ENCODING,
    CLOUDS_SCHEMA_NAME,
    CLOUDS_SCHEMA_TEXT,
    FUSED_MESSAGE_ENCODING,
    FUSED_SCHEMA_NAME,
    FUSED_SCHEMA_TEXT,
    MCAP_MAGIC,
    MESSAGE_ENCODING,
    PROFILE,
    RECORD_PREFIX,
    RECORDING_METADATA,
    RESERVED_METADATA_KEYS,
    SCHEMA_ENCODING,
    SCHEMA_NAME,
    SCHEMA_TEXT,
    as_pose,
)
from skelfuse.recording.mcap_writer import RecordingWriter
from skelfuse.schema.errors import DataError
from skelfuse.schema.frames import FusedFrame, SensorFrame
from skelfuse.wire import keys
from skelfuse.wire.clouds import PersonCloudsFrame, decode_person_clouds
from skelfuse.wire.codec import (
    DecodeError,
    decode_fused_frame,
    decode_sensor_frame,
)

# The layout and the writer live in mcap_layout.py and mcap_writer.py; their names are re-exported here.
__all__ = [
    "CALIBRATION_METADATA",
    "CLOUDS_MESSAGE_ENCODING",
    "CLOUDS_SCHEMA_NAME",
    "CLOUDS_SCHEMA_TEXT",
    "FUSED_MESSAGE_ENCODING",
    "FUSED_SCHEMA_NAME",
    "FUSED_SCHEMA_TEXT",
    "MESSAGE_ENCODING",
    "PROFILE",
    "RECORDING_METADATA",
    "RESERVED_METADATA_KEYS",
    "SCHEMA_ENCODING",
    "SCHEMA_NAME",
    "SCHEMA_TEXT",
    "DecodeError",
    "RecordedFrame",
    "RecordedFused",
    "RecordingReader",
    "RecordingWriter",
]


# --------------------------------------------------------------------------------------------------------
# Reader


@dataclass(frozen=True)
class RecordedFrame:
    """One recorded sensor frame with its MCAP envelope.

    Attributes
    ----------
    topic : str
        The channel topic: the zenoh key the frame was (and is, on replay) published on.
    sensor_id : str
    log_time_ns : int
        Host time of the frame (ns), the recording's time axis.
    publish_time_ns : int
        Device time of the frame (ns).
    payload : bytes
        The wire payload, bit-identical to what was recorded.
    frame : SensorFrame
        The decoded payload.
    """

    topic: str
    sensor_id: str
    log_time_ns: int
    publish_time_ns: int
    payload: bytes = field(repr=False)
    frame: SensorFrame = field(repr=False)


@dataclass(frozen=True)
class RecordedFused:
    """One recorded fused frame with its MCAP envelope.

    Attributes
    ----------
    topic : str
        The fused channel's topic: the rig's fused key expression.
    log_time_ns : int
        Host time the recorder received the frame (ns), the recording's time axis.
    publish_time_ns : int
        The frame's own time (``time_us`` x 1000).
    payload : bytes
        The fused wire payload, bit-identical to what was received.
    frame : FusedFrame
        The decoded payload.
    """

    topic: str
    log_time_ns: int
    publish_time_ns: int
    payload: bytes = field(repr=False)
    frame: FusedFrame = field(repr=False)


@dataclass(frozen=True)
class _ChunkRef:
    start_ns: int
    end_ns: int
    offset: int  # file offset of the chunk record (its opcode byte); -1 for loose (unchunked) messages
    loose: tuple[Message, ...] = ()


class RecordingReader:
    """Read a skelfuse MCAP recording, with or without its summary section.

    Parameters
    ----------
    path : str or Path
    validate_crcs : bool
        Check each chunk's CRC before using it (a mismatch skips the chunk and counts it).

    Attributes
    ----------
    path : Path
    indexed : bool
        True when the summary section (chunk index) was read; False when the file was scanned record by
        record (no footer: a recorder was killed, or the file was cut).
    truncated : bool
        The file ends inside a record or without a footer: it was read up to its last complete record.
    sensors : tuple[str, ...]
        Sensor ids of the sensor-frame channels, in channel order.
    topics : dict[str, str]
        Sensor id -> topic.
    fused_topic : str or None
        Topic of the recorded fused stream (``skelfuse/<rig>/fused/skeletons``), None when the file holds no
        fused channel.
    metadata : dict[str, str]
        The ``skelfuse.recording`` metadata record (empty if absent).
    calibration : dict[str, (4, 4) ndarray] or None
        ``world_from_sensor`` per sensor from the ``skelfuse.calibration`` record, None if absent.
    rejects : Counter[str]
        Messages skipped, per :data:`skelfuse.wire.codec.REJECT_REASONS` reason, accumulated over reads.
    bad_chunks : int
        Chunks skipped because they could not be read, decompressed or failed their CRC.
    problems : list[str]
        Human-readable notes about what was skipped (at most 20 kept).

    Raises
    ------
    DataError
        The file does not exist, cannot be read, or is not an MCAP file.
    """

    def __init__(self, path: str | os.PathLike[str], *, validate_crcs: bool = True) -> None:
        self.path = Path(path)
        self._validate_crcs = validate_crcs
        if not self.path.is_file():
            raise DataError(f"recording {self.path} not found (or not a file); check the path")
        try:
            with open(self.path, "rb") as f:
                magic = f.read(len(MCAP_MAGIC))
        except OSError as exc:
            raise DataError(f"cannot read recording {self.path}: {exc}") from exc
        if magic != MCAP_MAGIC:
            raise DataError(
                f"{self.path} is not an MCAP file: it starts with {magic[:8]!r}, expected the MCAP "
                f"magic {MCAP_MAGIC!r}; skelfuse recordings are written by `skelfuse record`"
            )
        self.rejects: Counter[str] = Counter()
        self.bad_chunks = 0
        self.problems: list[str] = []
        self.truncated = False
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunks: list[_ChunkRef] = []
        self._metadata: dict[str, dict[str, str]] = {}
        self._message_count: int | None = None
        self._channel_counts: dict[int, int] | None = None
        self.indexed = self._load_index()
        if not self.indexed:
            self._scan()
        self._chunks.sort(key=lambda c: (c.start_ns, c.offset))

        sensor_channels = [c for _, c in sorted(self._channels.items()) if c.message_encoding == MESSAGE_ENCODING]
        self.topics = {self._sensor_of(c): c.topic for c in sensor_channels}
        self.sensors = tuple(self.topics)
        fused_channels = [c for _, c in sorted(self._channels.items()) if c.message_encoding == FUSED_MESSAGE_ENCODING]
        self.fused_topic = fused_channels[0].topic if fused_channels else None
        self.metadata = dict(self._metadata.get(RECORDING_METADATA, {}))
        self.calibration = self._read_calibration()

    # -- loading ---------------------------------------------------------------------------------------
    def _note(self, text: str) -> None:
        if len(self.problems) < 20:
            self.problems.append(text)

    @staticmethod
    def _sensor_of(channel: Channel) -> str:
        sensor_id = channel.metadata.get("sensor_id")
        if sensor_id:
            return sensor_id
        try:
            return keys.parse_sensor_key(channel.topic)
        except ValueError:
            return channel.topic

    def _load_index(self) -> bool:
        """Read the summary section; False when there is none or it is unreadable (then scan)."""
        try:
            with open(self.path, "rb") as f:
                f.seek(-len(MCAP_MAGIC), io.SEEK_END)
                if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:  # no closing magic: the writer never finished
                    return False
                f.seek(0)
                reader = SeekingReader(f, validate_crcs=False, record_size_limit=self.path.stat().st_size)
                summary = reader.get_summary()
                if summary is None or not summary.chunk_indexes:
                    return False
                metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        except (McapError, EOFError, OSError, ValueError, KeyError, struct.error, UnicodeDecodeError):
            return False
        self._schemas = dict(summary.schemas)
        self._channels = dict(summary.channels)
        self._metadata = metadata
        self._chunks = [
            _ChunkRef(ci.message_start_time, ci.message_end_time, ci.chunk_start_offset) for ci in summary.chunk_indexes
        ]
        if summary.statistics is not None:
            self._message_count = summary.statistics.message_count
            self._channel_counts = dict(summary.statistics.channel_message_counts)
        return True

    def _scan(self) -> None:
        """Streaming fallback: walk the records from the start, stop at the footer or where the file ends.

        Chunks are decompressed once here to learn the channels they define (the mcap writer puts schema
        and channel records inside chunks) and to count messages; the bodies are read again by
        :meth:`records`.
        """
        size = self.path.stat().st_size
        loose: list[Message] = []
        count = 0
        footer = False
        with open(self.path, "rb") as f:
            pos = len(MCAP_MAGIC)
            while True:
                if pos + RECORD_PREFIX.size > size:
                    break
                f.seek(pos)
                opcode, length = RECORD_PREFIX.unpack(f.read(RECORD_PREFIX.size))
                body_at = pos + RECORD_PREFIX.size
                if body_at + length > size:
                    self._note(f"file ends inside a record (opcode {opcode:#04x}) at byte {pos}: read up to there")
                    break
                if opcode == Opcode.FOOTER:
                    footer = True
                    break
                if opcode not in _KNOWN_OPCODES:
                    self._note(f"unknown or corrupt record (opcode {opcode:#04x}) at byte {pos}: stopped there")
                    break
                if opcode in (Opcode.CHUNK, Opcode.SCHEMA, Opcode.CHANNEL, Opcode.METADATA, Opcode.MESSAGE):
                    body = f.read(length)
                    try:
                        count += self._scan_record(opcode, body, pos, loose)
                    except Exception as exc:  # any damage in one record must not stop the scan
                        if opcode == Opcode.CHUNK:
                            self.bad_chunks += 1
                        self._note(f"unreadable record (opcode {opcode:#04x}) at byte {pos}: {exc!r}")
                pos = body_at + length
        self.truncated = not footer
        if loose:
            times = [m.log_time for m in loose]
            self._chunks.append(_ChunkRef(min(times), max(times), -1, tuple(loose)))
        self._message_count = count

    def require_sensors(self, fix: str) -> tuple[str, ...]:
        """The sensor ids, or a DataError naming the file, saying when it was cut before any complete chunk,
        and ``fix`` (what the user should do)."""
        if not self.sensors:
            ended = " (it ends early: cut before its first complete chunk)" if self.truncated else ""
            raise DataError(f"recording {self.path} holds no sensor-frame channels{ended}; {fix}")
        return self.sensors

    def _scan_record(self, opcode: int, body: bytes, pos: int, loose: list[Message]) -> int:
        stream = ReadDataStream(io.BytesIO(body))
        if opcode == Opcode.CHUNK:
            chunk = Chunk.read(stream)
            n = 0
            for record in breakup_chunk(chunk, validate_crc=self._validate_crcs):
                if isinstance(record, Schema):
                    self._schemas.setdefault(record.id, record)
                elif isinstance(record, Channel):
                    self._channels.setdefault(record.id, record)
                elif isinstance(record, Message):
                    n += 1
            self._chunks.append(_ChunkRef(chunk.message_start_time, chunk.message_end_time, pos))
            return n
        if opcode == Opcode.SCHEMA:
            schema = Schema.read(stream)
            self._schemas.setdefault(schema.id, schema)
        elif opcode == Opcode.CHANNEL:
            channel = Channel.read(stream)
            self._channels.setdefault(channel.id, channel)
        elif opcode == Opcode.METADATA:
            meta = Metadata.read(stream)
            self._metadata[meta.name] = dict(meta.metadata)
        elif opcode == Opcode.MESSAGE:
            loose.append(Message.read(stream, len(body)))
            return 1
        return 0

    def _read_calibration(self) -> dict[str, np.ndarray] | None:
        record = self._metadata.get(CALIBRATION_METADATA)
        if not record:
            return None
        poses: dict[str, np.ndarray] = {}
        for key, value in record.items():
            if not key.startswith("world_from_sensor/"):
                continue
            sensor_id = key.split("/", 1)[1]
            try:
                poses[sensor_id] = as_pose(json.loads(value), sensor_id)
            except (ValueError, TypeError) as exc:
                self._note(f"calibration of sensor {sensor_id!r} unreadable: {exc}")
        return poses or None

    # -- queries ---------------------------------------------------------------------------------------
    @property
    def time_range_ns(self) -> tuple[int, int] | None:
        """(first, last) log time (host ns) of the recorded messages, None when there are none."""
        if not self._chunks:
            return None
        return min(c.start_ns for c in self._chunks), max(c.end_ns for c in self._chunks)

    @property
    def message_count(self) -> int | None:
        """Messages in the file (all channels), from the statistics or the scan; None if unknown."""
        return self._message_count

    @property
    def fused_message_count(self) -> int | None:
        """Messages on the fused channel, from the statistics of an indexed file; None if unknown."""
        if self._channel_counts is None:
            return None
        fused = [cid for cid, c in self._channels.items() if c.message_encoding == FUSED_MESSAGE_ENCODING]
        return sum(self._channel_counts.get(cid, 0) for cid in fused)

    def frames(
        self, start_ns: int | None = None, end_ns: int | None = None, sensors: Iterable[str] | None = None
    ) -> Iterator[SensorFrame]:
        """Decoded sensor frames in log-time (host time) order; see :meth:`records` for the arguments."""
        for record in self.records(start_ns, end_ns, sensors):
            yield record.frame

    def records(
        self, start_ns: int | None = None, end_ns: int | None = None, sensors: Iterable[str] | None = None
    ) -> Iterator[RecordedFrame]:
        """Recorded frames with their envelope, in log-time order (ties: file order).

        Parameters
        ----------
        start_ns, end_ns : int, optional
            Half-open log-time window ``[start_ns, end_ns)``, host ns. Chunks outside it are not read.
        sensors : iterable of str, optional
            Only these sensors (unknown ids yield nothing).

        Yields
        ------
        RecordedFrame
            Corrupt messages are skipped and counted in :attr:`rejects`; unreadable chunks in
            :attr:`bad_chunks`.
        """
        wanted = None if sensors is None else set(sensors)
        channels = {
            cid: c
            for cid, c in self._channels.items()
            if c.message_encoding == MESSAGE_ENCODING and (wanted is None or self._sensor_of(c) in wanted)
        }
        for message in self._merged(channels, start_ns, end_ns):
            yield from self._decode(message, channels)

    def fused_frames(self, start_ns: int | None = None, end_ns: int | None = None) -> Iterator[FusedFrame]:
        """Decoded recorded fused frames in log-time order (see :meth:`fused_records`)."""
        for record in self.fused_records(start_ns, end_ns):
            yield record.frame

    def fused_records(self, start_ns: int | None = None, end_ns: int | None = None) -> Iterator[RecordedFused]:
        """The recorded fused stream with its envelope, in log-time (receive time) order.

        Nothing when the file has no fused channel (:attr:`fused_topic` None). A payload that fails to decode
        is skipped and counted in :attr:`rejects`, as for sensor frames.
        """
        channels = {cid: c for cid, c in self._channels.items() if c.message_encoding == FUSED_MESSAGE_ENCODING}
        for message in self._merged(channels, start_ns, end_ns):
            channel = channels[message.channel_id]
            try:
                frame = decode_fused_frame(message.data)
            except DecodeError as exc:
                self.rejects[exc.reason] += 1
                self._note(f"fused message at log time {message.log_time} on {channel.topic}: {exc.reason}: {exc}")
                continue
            yield RecordedFused(channel.topic, message.log_time, message.publish_time, bytes(message.data), frame)

    def person_clouds(self, start_ns: int | None = None, end_ns: int | None = None) -> Iterator[PersonCloudsFrame]:
        """The recorded person clouds (depth / hybrid mode rigs), every sensor's, in log-time order; payloads
        that fail to decode are skipped and counted in :attr:`rejects`."""
        channels = {cid: c for cid, c in self._channels.items() if c.message_encoding == CLOUDS_MESSAGE_ENCODING}
        for message in self._merged(channels, start_ns, end_ns):
            try:
                yield decode_person_clouds(message.data)
            except DecodeError as exc:
                self.rejects[exc.reason] += 1
                self._note(f"clouds at log time {message.log_time} on {channels[message.channel_id].topic}: {exc}")

    def _merged(self, channels: Mapping[int, Channel], start_ns: int | None, end_ns: int | None) -> Iterator[Message]:
        """Messages of ``channels`` in the half-open log-time window, in log-time order (ties: file order)."""
        chunks = [
            c
            for c in self._chunks
            if (start_ns is None or c.end_ns >= start_ns) and (end_ns is None or c.start_ns < end_ns)
        ]
        if not channels or not chunks:
            return
        # k-way merge: every message of a later chunk is logged at or after that chunk's start, so messages
        # earlier than the next chunk's start can be released before that chunk is read.
        heap: list[tuple[int, int, int, Message]] = []
        with open(self.path, "rb") as f:
            for chunk in chunks:
                while heap and heap[0][0] < chunk.start_ns:
                    yield heapq.heappop(heap)[3]
                for index, message in enumerate(self._messages_of(f, chunk)):
                    if message.channel_id not in channels:
                        continue
                    if start_ns is not None and message.log_time < start_ns:
                        continue
                    if end_ns is not None and message.log_time >= end_ns:
                        continue
                    heapq.heappush(heap, (message.log_time, chunk.offset, index, message))
            while heap:
                yield heapq.heappop(heap)[3]

    def _messages_of(self, f: IO[bytes], chunk: _ChunkRef) -> list[Message]:
        if chunk.offset < 0:
            return list(chunk.loose)
        try:
            f.seek(chunk.offset)
            opcode, length = RECORD_PREFIX.unpack(f.read(RECORD_PREFIX.size))
            if opcode != Opcode.CHUNK:
                raise McapError(f"expected a chunk record, found opcode {opcode:#04x}")
            record = Chunk.read(ReadDataStream(io.BytesIO(f.read(length))))
            return [r for r in breakup_chunk(record, validate_crc=self._validate_crcs) if isinstance(r, Message)]
        except Exception as exc:  # a damaged chunk (bad compression, CRC, lengths) is skipped
            self.bad_chunks += 1
            self._note(f"chunk at byte {chunk.offset} unreadable, its messages skipped: {exc!r}")
            return []

    def _decode(self, message: Message, channels: Mapping[int, Channel]) -> Iterator[RecordedFrame]:
        channel = channels[message.channel_id]
        sensor_id = self._sensor_of(channel)
        try:
            frame = decode_sensor_frame(message.data)
            if frame.sensor_id != sensor_id:
                raise DecodeError(
                    "bad_value", f"payload of sensor {frame.sensor_id!r} on the channel of sensor {sensor_id!r}"
                )
        except DecodeError as exc:
            self.rejects[exc.reason] += 1
            self._note(f"message at log time {message.log_time} on {channel.topic}: {exc.reason}: {exc}")
            return
        yield RecordedFrame(
            topic=channel.topic,
            sensor_id=sensor_id,
            log_time_ns=message.log_time,
            publish_time_ns=message.publish_time,
            payload=bytes(message.data),
            frame=frame,
        )


_KNOWN_OPCODES = frozenset(int(op) for op in Opcode)
