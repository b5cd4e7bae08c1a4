"""Binary payloads of skelfuse's zenoh traffic: sensor frames, fused frames and node status, versioned.

The format is specified byte by byte in ``docs/wire-format.md``; this module is its reference
implementation. Every message starts with the same 10-byte prefix (magic ``b"SKLF"``, major and minor schema
version, message kind, flags, header size), then a fixed little-endian header of its kind, then packed
arrays whose lengths follow from the header's counts, then length-prefixed UTF-8 sensor ids. No pickle, no
``.npy``: an app in any language can decode the fused stream with a struct reader (see
``scripts/example_subscriber.py``).

Cycle: a capture worker calls :func:`encode_sensor_frame` per tracker result; the fusion node calls
:func:`decode_sensor_frame` per sample, fuses, and publishes :func:`encode_fused_frame`; every node
publishes :func:`encode_status` now and then.

Decoding validates everything (prefix, version, kind, counts against the byte length, caps, joint count,
finiteness, confidence range, UTF-8) and raises only :class:`DecodeError`, whose ``reason`` is one of
:data:`REJECT_REASONS`, so a node can count rejects per reason and carry on. Encoding checks the frame
against the same rules and raises ValueError: a frame that would be rejected is never sent.
"""

from __future__ import annotations

import functools
import json
import operator
import struct
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import numpy as np

from skelfuse.schema.errors import DataError
from skelfuse.schema.frames import FusedFrame, SensorFrame
from skelfuse.schema.skeleton import N_JOINTS

MAGIC = b"SKLF"
"""First 4 bytes of every payload."""
VERSION_MAJOR = 1
"""Schema major version written and read. A reader rejects any other major."""
VERSION_MINOR = 0
"""Schema minor version of sensor frames, status, and fused frames without the 1.1 sections. A reader
accepts any minor of its major (see docs/wire-format.md)."""
FUSED_MINOR_WITH_SECTIONS = 1
"""Minor version of a fused frame that carries orientations and/or position_std (schema 1.1). A fused frame
without them is written as 1.0, byte for byte what a 1.0 writer produced, so 1.0 readers see no change."""
FUSED_SECTION_ORIENTATIONS = 1
"""Bit of the fused header's ``sections`` field (the 1.0 ``reserved`` u32): f64[P][32][4] orientations follow."""
FUSED_SECTION_POSITION_STD = 2
"""Bit of ``sections``: f64[P][32] position_std (mm) follow (after the orientations, when both are present)."""
_KNOWN_MINOR = {1: VERSION_MINOR, 2: FUSED_MINOR_WITH_SECTIONS, 3: VERSION_MINOR, 4: 0}  # by message kind byte
PERSON_CLOUDS_HEADER_SIZE = 46
"""Header size of a person-cloud payload (kind 4; its codec is :mod:`skelfuse.wire.clouds`)."""
_UNIT_TOLERANCE = 1e-3

MAX_BODIES = 64
"""Most bodies in one sensor frame (the k4abt tracker reports a handful)."""
MAX_PERSONS = 64
"""Most persons in one fused frame."""
MAX_SENSORS = 64
"""Most sensors in one rig (columns of ``contributors``, and the cap on ``n_agree``)."""
MAX_ID_BYTES = 255
"""Longest sensor id, UTF-8 bytes."""
MAX_STATUS_BYTES = 65536
"""Longest status JSON document, bytes."""

STATUS_STATES = ("starting", "running", "degraded", "stopping", "stopped")
"""States a node reports. Writers use these; readers accept any non-empty string (newer minors may add)."""

REJECT_REASONS = (
    "truncated",  # fewer bytes than the header or the declared counts need
    "bad_magic",  # not a skelfuse payload
    "bad_version",  # schema major version this reader does not support
    "bad_kind",  # unknown message kind, or another kind than the decoder expects
    "bad_header",  # header size smaller than the version defines (or not as defined for a known minor)
    "bad_length",  # bytes left over after the declared content (for a minor this reader knows)
    "too_large",  # a count or length beyond its cap (bodies, persons, sensors, id bytes, JSON bytes)
    "bad_joint_count",  # joints per skeleton is not 32
    "non_finite",  # NaN/Inf where the format forbids it
    "bad_confidence",  # confidence outside 0..3
    "bad_value",  # any other out-of-range or inconsistent value (duplicate ids, flags 0/1, negative counts)
    "bad_utf8",  # a sensor id or the status document is not valid UTF-8
    "bad_json",  # the status document is not valid JSON or lacks required fields
)
"""Every value :attr:`DecodeError.reason` can take."""


class MessageKind(IntEnum):
    """Message kind, byte 6 of every payload."""

    SENSOR_FRAME = 1
    FUSED_FRAME = 2
    STATUS = 3
    PERSON_CLOUDS = 4  # encoded / decoded by skelfuse.wire.clouds


class DecodeError(DataError):
    """A payload was rejected. ``reason`` is a short machine-readable code from :data:`REJECT_REASONS`.

    Attributes
    ----------
    reason : str
        One of :data:`REJECT_REASONS`, to count rejects per reason.
    """

    def __init__(self, reason: str, message: str) -> None:
        if reason not in REJECT_REASONS:  # a programming error in this module, never data-dependent
            raise ValueError(f"unknown DecodeError reason {reason!r}; expected one of {REJECT_REASONS}")
        super().__init__(message)
        self.reason = reason

    def __reduce__(self) -> tuple[type[DecodeError], tuple[str, str]]:
        return (type(self), (self.reason, str(self)))


@dataclass(frozen=True)
class NodeStatus:
    """What a node says about itself on ``skelfuse/<rig>/status/<node>``.

    Attributes
    ----------
    node : str
        Node name (the ``<node>`` of its keys).
    role : str
        What the node does, e.g. "capture", "fusion", "recorder".
    state : str
        One of :data:`STATUS_STATES` when written by skelfuse.
    time_ns : int
        Host clock when the status was made, nanoseconds since the Unix epoch.
    counters : dict[str, int]
        Monotonic non-negative counts since start, e.g. ``{"frames_out": 901, "rejects.truncated": 2}``.
    info : dict[str, Any]
        Free-form JSON details (fps, last error, software version...).
    """

    node: str
    role: str
    state: str
    time_ns: int
    counters: dict[str, int] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)


# Layouts, all little-endian ("<": no padding). Offsets are in docs/wire-format.md.
_PREFIX = struct.Struct("<4sBBBBH")  # magic, major, minor, kind, flags, header_size
_SENSOR_HEADER = struct.Struct("<4sBBBBHHHHQqq")  # + n_joints, n_bodies, reserved, sequence, dev us, host ns
_FUSED_HEADER = struct.Struct("<4sBBBBHHHHqII")  # + n_joints, n_persons, n_sensors, time_us, table, reserved
_STATUS_HEADER = struct.Struct("<4sBBBBHHI")  # + reserved, json_size
_U16 = struct.Struct("<H")

SENSOR_HEADER_SIZE = _SENSOR_HEADER.size  # 40
FUSED_HEADER_SIZE = _FUSED_HEADER.size  # 32
STATUS_HEADER_SIZE = _STATUS_HEADER.size  # 16

# Bytes per body (sensor frame) and per person (fused frame), excluding the per-person contributors row.
SENSOR_BYTES_PER_BODY = 4 + N_JOINTS * 3 * 4 + N_JOINTS * 4 * 4 + N_JOINTS  # 932
FUSED_BYTES_PER_PERSON = 8 + N_JOINTS * 3 * 8 + N_JOINTS * 2 + N_JOINTS  # 872

_KIND_NAMES = {
    MessageKind.SENSOR_FRAME: "sensor frame",
    MessageKind.FUSED_FRAME: "fused frame",
    MessageKind.STATUS: "status",
    MessageKind.PERSON_CLOUDS: "person-clouds",
}
_HEADER_SIZES = {
    MessageKind.SENSOR_FRAME: SENSOR_HEADER_SIZE,
    MessageKind.FUSED_FRAME: FUSED_HEADER_SIZE,
    MessageKind.STATUS: STATUS_HEADER_SIZE,
    MessageKind.PERSON_CLOUDS: PERSON_CLOUDS_HEADER_SIZE,
}
_I64 = (-(2**63), 2**63 - 1)
_U64 = (0, 2**64 - 1)


class _Invalid(Exception):
    """A rule broken by a frame: becomes DecodeError when decoding and ValueError when encoding."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


# --------------------------------------------------------------------------------------------------------
# Shared validation: one routine per rule, used by both the encoder (ValueError) and the decoder.
# The rules run on every frame at 30 Hz per sensor, so each is one numpy call on the fast path.

_CONFIDENCE_VALUES = bytes(range(4))


def _check_confidence(raw: bytes) -> None:
    """``raw``: the uint8 confidence bytes. ``translate`` deletes 0..3; anything left is out of range."""
    bad = raw.translate(None, _CONFIDENCE_VALUES)
    if bad:
        raise _Invalid("bad_confidence", f"confidence holds value {max(bad)}; expected 0..3 (NONE, LOW, MEDIUM, HIGH)")


def _check_unique(ids: np.ndarray, what: str) -> None:
    values = ids.tolist()
    if len(set(values)) != len(values):
        raise _Invalid("bad_value", f"{what} hold duplicates: {values}")


def _check_sensor_floats(floats: np.ndarray) -> None:
    """``floats``: positions and/or orientations of a sensor frame."""
    # Sensor frames come straight from the tracker, which always reports a (predicted) joint: no NaN.
    if not np.isfinite(floats).all():
        raise _Invalid(
            "non_finite",
            "positions or orientations hold NaN or Inf; the tracker always "
            "reports a joint, so a sensor frame must be finite (drop the body instead)",
        )


def _check_orientations(quats: np.ndarray) -> None:
    """``quats``: (P, 32, 4). A joint is all NaN (unknown) or a finite unit quaternion."""
    nan = np.isnan(quats)
    if np.isinf(quats).any() or (nan.any(axis=-1) != nan.all(axis=-1)).any():
        raise _Invalid(
            "non_finite",
            "orientations hold Inf or a joint with some but not all components NaN; an unknown "
            "orientation is NaN in w, x, y and z",
        )
    norm = np.linalg.norm(np.where(nan, 0.0, quats), axis=-1)
    if (np.abs(norm - 1.0)[~nan[..., 0]] > _UNIT_TOLERANCE).any():
        raise _Invalid("bad_value", f"orientations hold a quaternion whose norm is not 1 (within {_UNIT_TOLERANCE})")


def _check_position_std(std: np.ndarray) -> None:
    """``std``: (P, 32) mm, NaN (no estimate) or finite and >= 0."""
    if np.isinf(std).any():
        raise _Invalid("non_finite", "position_std holds Inf; only NaN (no estimate) is allowed")
    if (std < 0).any():
        raise _Invalid("bad_value", "position_std holds a negative value")


def _check_fused_positions(positions: np.ndarray) -> None:
    """``positions``: (P, 32, 3). NaN means "no estimate" for a whole joint; Inf is never valid."""
    if np.isfinite(positions).all():
        return
    nan = np.isnan(positions)
    if np.isinf(positions).any():
        raise _Invalid("non_finite", "positions hold Inf; only NaN (no estimate) is allowed")
    if (nan.any(axis=-1) != nan.all(axis=-1)).any():
        raise _Invalid(
            "non_finite",
            "positions hold a joint with some but not all coordinates NaN; a missing joint is NaN in x, y and z",
        )


def _check_n_agree(n_agree: np.ndarray) -> None:
    """``n_agree``: int16. Viewed as uint16, negative values are >= 32768, so one max() checks both ends."""
    if n_agree.size and int(n_agree.view(np.uint16).max()) > MAX_SENSORS:
        raise _Invalid(
            "bad_value",
            f"n_agree spans {int(n_agree.min())}..{int(n_agree.max())}; "
            f"expected 0..{MAX_SENSORS} (sensors in the winning cluster)",
        )


def _check_contributors(raw: bytes) -> None:
    if raw.translate(None, b"\x00\x01"):
        raise _Invalid("bad_value", "contributors hold values other than 0 and 1")


def _check_sensor_ids(sensor_ids: tuple[str, ...]) -> None:
    if len(set(sensor_ids)) != len(sensor_ids):
        raise _Invalid("bad_value", f"sensor_ids hold duplicates: {list(sensor_ids)}")


def _check_id(sensor_id: str, what: str) -> bytes:
    if not isinstance(sensor_id, str):
        raise ValueError(f"{what} must be a str, got {type(sensor_id).__name__}: {sensor_id!r}")
    raw = sensor_id.encode("utf-8")
    if not raw:
        raise ValueError(f"{what} is empty; expected the device serial or simulator name")
    if len(raw) > MAX_ID_BYTES:
        raise ValueError(f"{what} {sensor_id[:40]!r}... is {len(raw)} UTF-8 bytes; at most {MAX_ID_BYTES}")
    return raw


def _check_int(value: int, bounds: tuple[int, int], what: str) -> int:
    number = operator.index(value)  # accepts numpy integers, refuses floats (TypeError)
    if not bounds[0] <= number <= bounds[1]:
        raise ValueError(f"{what} = {number} is outside {bounds[0]}..{bounds[1]}")
    return number


def _as_wire(array: object, dtype: np.dtype[Any], shape: tuple[int, ...], what: str, kinds: str) -> np.ndarray:
    """``array`` as a C-contiguous array of wire dtype ``dtype``; ValueError on shape, kind or range."""
    arr = np.asarray(array)
    if arr.shape != shape:
        raise ValueError(f"{what} has shape {arr.shape}, expected {shape}")
    if arr.dtype == dtype:
        return np.ascontiguousarray(arr)
    if arr.dtype.kind not in kinds:
        expected = "a float" if kinds == "f" else "an integer"
        raise ValueError(f"{what} has dtype {arr.dtype}, expected {expected} array (sent as {dtype})")
    if dtype.kind in "iu" and arr.size and arr.dtype.kind in "iu":
        info = np.iinfo(dtype)
        low, high = int(arr.min()), int(arr.max())
        if low < info.min or high > info.max:
            raise ValueError(f"{what} spans {low}..{high}, which {dtype} cannot hold")
    with np.errstate(all="ignore"):  # float64 beyond float32 range becomes Inf, caught by the finiteness rule
        return np.ascontiguousarray(arr, dtype=dtype)


_U1, _U4, _I2, _I8 = np.dtype("u1"), np.dtype("<u4"), np.dtype("<i2"), np.dtype("<i8")
_F4, _F8 = np.dtype("<f4"), np.dtype("<f8")


# --------------------------------------------------------------------------------------------------------
# Reading helpers (every failure is a DecodeError).


def _buffer(data: bytes | bytearray | memoryview) -> memoryview:
    try:
        view = memoryview(data)
    except TypeError:
        hint = " (for a zenoh sample, pass sample.payload.to_bytes())" if hasattr(data, "to_bytes") else ""
        raise TypeError(f"payload must be bytes-like, got {type(data).__name__}{hint}") from None
    if view.ndim != 1 or view.itemsize != 1:
        view = view.cast("B")
    return view


def _read_prefix(view: memoryview, expected: MessageKind | None) -> tuple[MessageKind, int, int]:
    """Check magic, major version and kind; return (kind, minor, header_size)."""
    what = _KIND_NAMES[expected] if expected is not None else "skelfuse"
    if len(view) < len(MAGIC) or view[: len(MAGIC)] != MAGIC:
        if len(view) < len(MAGIC) and bytes(view) == MAGIC[: len(view)]:
            raise DecodeError(
                "truncated",
                f"{what} payload rejected (truncated): {len(view)} bytes, shorter than the {_PREFIX.size}-byte prefix",
            )
        raise DecodeError(
            "bad_magic",
            f"{what} payload rejected (bad_magic): starts with "
            f"{bytes(view[:4])!r}, expected {MAGIC!r}; is this a skelfuse payload?",
        )
    if len(view) < _PREFIX.size:
        raise DecodeError(
            "truncated",
            f"{what} payload rejected (truncated): {len(view)} bytes, shorter than the {_PREFIX.size}-byte prefix",
        )
    _, major, minor, kind_byte, _flags, header_size = _PREFIX.unpack_from(view)
    if major != VERSION_MAJOR:
        raise DecodeError(
            "bad_version",
            f"{what} payload rejected (bad_version): schema version "
            f"{major}.{minor}, this reader supports major version {VERSION_MAJOR} "
            f"(writes {VERSION_MAJOR}.{VERSION_MINOR}); upgrade the reader or the writer",
        )
    if kind_byte not in _KIND_BY_BYTE:
        raise DecodeError(
            "bad_kind",
            f"{what} payload rejected (bad_kind): unknown message kind "
            f"{kind_byte}; known kinds {[int(k) for k in MessageKind]}",
        )
    kind = _KIND_BY_BYTE[kind_byte]
    if expected is not None and kind != expected:
        raise DecodeError(
            "bad_kind",
            f"{what} payload rejected (bad_kind): message kind {int(kind)} "
            f"({_KIND_NAMES[kind]}), expected {int(expected)} ({what}); check the key "
            "the payload came from",
        )
    known_size = _HEADER_SIZES[kind]
    # A newer minor may grow the header; the same or an older minor must match it.
    if header_size < known_size or (minor <= _KNOWN_MINOR[int(kind)] and header_size != known_size):
        raise DecodeError(
            "bad_header",
            f"{_KIND_NAMES[kind]} payload rejected (bad_header): header size "
            f"{header_size} for version {major}.{minor}, expected {known_size}",
        )
    if len(view) < header_size:
        raise DecodeError(
            "truncated",
            f"{_KIND_NAMES[kind]} payload rejected (truncated): {len(view)} "
            f"bytes, shorter than its {header_size}-byte header",
        )
    return kind, minor, header_size


_KIND_BY_BYTE = {int(kind): kind for kind in MessageKind}


def _check_length(view: memoryview, end: int, minor: int, what: str, known_minor: int = VERSION_MINOR) -> None:
    if len(view) < end:
        raise DecodeError(
            "truncated", f"{what} payload rejected (truncated): {len(view)} bytes, the header's counts need {end}"
        )
    if len(view) > end and minor <= known_minor:
        raise DecodeError(
            "bad_length",
            f"{what} payload rejected (bad_length): {len(view)} bytes, the header's counts need exactly {end}",
        )


def _read_id(view: memoryview, offset: int, what: str, kind_name: str) -> tuple[str, int]:
    if offset + 2 > len(view):
        raise DecodeError(
            "truncated",
            f"{kind_name} payload rejected (truncated): {what} length prefix "
            f"at byte {offset} is past the end ({len(view)} bytes)",
        )
    (size,) = _U16.unpack_from(view, offset)
    offset += 2
    if size == 0:
        raise DecodeError("bad_value", f"{kind_name} payload rejected (bad_value): {what} is empty")
    if size > MAX_ID_BYTES:
        raise DecodeError(
            "too_large", f"{kind_name} payload rejected (too_large): {what} is {size} bytes, at most {MAX_ID_BYTES}"
        )
    if offset + size > len(view):
        raise DecodeError(
            "truncated",
            f"{kind_name} payload rejected (truncated): {what} of {size} bytes "
            f"at byte {offset} runs past the end ({len(view)} bytes)",
        )
    try:
        text = str(view[offset : offset + size], "utf-8")
    except UnicodeDecodeError as exc:
        raise DecodeError(
            "bad_utf8",
            f"{kind_name} payload rejected (bad_utf8): {what} is not UTF-8 ({exc.reason} at byte {offset + exc.start})",
        ) from None
    return text, offset + size


def _cap(count: int, cap: int, what: str, kind_name: str) -> None:
    if count > cap:
        raise DecodeError("too_large", f"{kind_name} payload rejected (too_large): {count} {what}, at most {cap}")


def _joints(n_joints: int, kind_name: str) -> None:
    if n_joints != N_JOINTS:
        raise DecodeError(
            "bad_joint_count",
            f"{kind_name} payload rejected (bad_joint_count): "
            f"{n_joints} joints per skeleton, expected {N_JOINTS} (k4abt joint set)",
        )


# --------------------------------------------------------------------------------------------------------
# Sensor frames


def encode_sensor_frame(frame: SensorFrame) -> bytes:
    """Serialize one sensor frame (message kind 1).

    Positions and orientations are sent as float32, body ids as uint32, confidence as uint8.

    Raises
    ------
    ValueError
        The frame breaks a rule of the format (shapes, more than MAX_BODIES bodies, NaN/Inf, confidence
        above 3, duplicate body ids, empty or over-long sensor id, integers out of range).
    """
    ids = np.asarray(frame.body_ids)
    if ids.ndim != 1:
        raise ValueError(f"body_ids of sensor {frame.sensor_id!r} must be 1-D, got shape {ids.shape}")
    n = ids.shape[0]
    if n > MAX_BODIES:
        raise ValueError(f"sensor frame of {frame.sensor_id!r} has {n} bodies, at most {MAX_BODIES}")
    sid = _check_id(frame.sensor_id, "sensor_id")
    body_ids = _as_wire(ids, _U4, (n,), "body_ids", "iu")
    positions = _as_wire(frame.positions, _F4, (n, N_JOINTS, 3), "positions", "f")
    orientations = _as_wire(frame.orientations, _F4, (n, N_JOINTS, 4), "orientations", "f")
    confidence = _as_wire(frame.confidence, _U1, (n, N_JOINTS), "confidence", "iu").tobytes()
    try:
        _check_sensor_floats(positions)
        _check_sensor_floats(orientations)
        _check_confidence(confidence)
        _check_unique(body_ids, "body_ids")
    except _Invalid as exc:
        raise ValueError(f"sensor frame of {frame.sensor_id!r} cannot be sent: {exc}") from None
    header = _SENSOR_HEADER.pack(
        MAGIC,
        VERSION_MAJOR,
        VERSION_MINOR,
        MessageKind.SENSOR_FRAME,
        0,
        SENSOR_HEADER_SIZE,
        N_JOINTS,
        n,
        0,
        _check_int(frame.sequence, _U64, "sequence"),
        _check_int(frame.device_time_us, _I64, "device_time_us"),
        _check_int(frame.host_time_ns, _I64, "host_time_ns"),
    )
    return b"".join(
        (header, body_ids.tobytes(), positions.tobytes(), orientations.tobytes(), confidence, _U16.pack(len(sid)), sid)
    )


def decode_sensor_frame(data: bytes | bytearray | memoryview) -> SensorFrame:
    """Parse and validate a sensor-frame payload (message kind 1).

    Returns a :class:`~skelfuse.schema.frames.SensorFrame` owning fresh writable arrays (never views of
    ``data``): body_ids (B,) uint32, positions (B, 32, 3) float32 mm, orientations (B, 32, 4) float32,
    confidence (B, 32) uint8.

    Raises
    ------
    DecodeError
        For any payload that is not a valid sensor frame; ``reason`` says why.
    TypeError
        ``data`` is not bytes-like.
    """
    name = "sensor frame"
    view = _buffer(data)
    _, minor, offset = _read_prefix(view, MessageKind.SENSOR_FRAME)
    (_, _, _, _, _, _, n_joints, n, _, sequence, device_time_us, host_time_ns) = _SENSOR_HEADER.unpack_from(view)
    _joints(n_joints, name)
    _cap(n, MAX_BODIES, "bodies", name)
    id_at = offset + n * SENSOR_BYTES_PER_BODY
    sensor_id, end = _read_id(view, id_at, "sensor_id", name)
    _check_length(view, end, minor, name)
    # One copy of the payload backs every array: the frame owns them even if zenoh reuses its buffer.
    owned = bytearray(view[:id_at])
    n_joint_rows = n * N_JOINTS
    body_ids = np.frombuffer(owned, _U4, n, offset)
    floats = np.frombuffer(owned, _F4, n_joint_rows * 7, offset + 4 * n)  # positions then orientations
    confidence_at = offset + 4 * n + floats.nbytes
    try:
        _check_sensor_floats(floats)
        _check_confidence(bytes(owned[confidence_at:id_at]))
        _check_unique(body_ids, "body_ids")
    except _Invalid as exc:
        raise DecodeError(exc.reason, f"{name} payload of {sensor_id!r} rejected ({exc.reason}): {exc}") from None
    return SensorFrame(
        sensor_id=sensor_id,
        sequence=sequence,
        device_time_us=device_time_us,
        host_time_ns=host_time_ns,
        body_ids=body_ids.astype(np.uint32, copy=False),
        positions=floats[: n_joint_rows * 3].reshape(n, N_JOINTS, 3).astype(np.float32, copy=False),
        orientations=floats[n_joint_rows * 3 :].reshape(n, N_JOINTS, 4).astype(np.float32, copy=False),
        confidence=np.frombuffer(owned, _U1, n_joint_rows, confidence_at).reshape(n, N_JOINTS),
    )


# --------------------------------------------------------------------------------------------------------
# Fused frames


def encode_fused_frame(frame: FusedFrame) -> bytes:
    """Serialize one fused frame (message kind 2).

    Positions are sent as float64 (NaN = no estimate, whole joints only), track ids as int64, n_agree as
    int16, confidence as uint8, contributors as uint8 0/1, sensor ids as a table of u16-length-prefixed
    UTF-8 strings. A frame with ``orientations`` and/or ``position_std`` is written as version 1.1: the header's
    ``sections`` bits name them and they follow the sensor id table as float64 (NaN = unknown); a frame with
    neither is written as 1.0.

    Raises
    ------
    ValueError
        The frame breaks a rule of the format (shapes, caps, Inf or partial-NaN joints, confidence above 3,
        n_agree outside 0..MAX_SENSORS, duplicate track or sensor ids, bad sensor ids, time out of range).
    """
    ids = np.asarray(frame.track_ids)
    if ids.ndim != 1:
        raise ValueError(f"track_ids must be 1-D, got shape {ids.shape}")
    n = ids.shape[0]
    sensor_ids = tuple(frame.sensor_ids)
    n_sensors = len(sensor_ids)
    if n > MAX_PERSONS:
        raise ValueError(f"fused frame has {n} persons, at most {MAX_PERSONS}")
    if n_sensors > MAX_SENSORS:
        raise ValueError(f"fused frame names {n_sensors} sensors, at most {MAX_SENSORS}")
    table = _sensor_id_table(sensor_ids) if all(type(s) is str for s in sensor_ids) else _id_table(sensor_ids)
    track_ids = _as_wire(ids, _I8, (n,), "track_ids", "iu")
    positions = _as_wire(frame.positions, _F8, (n, N_JOINTS, 3), "positions", "f")
    n_agree = _as_wire(frame.n_agree, _I2, (n, N_JOINTS), "n_agree", "iu")
    confidence = _as_wire(frame.confidence, _U1, (n, N_JOINTS), "confidence", "iu").tobytes()
    contributors = _as_wire(frame.contributors, _U1, (n, n_sensors), "contributors (P, S)", "biu").tobytes()
    try:
        _check_fused_positions(positions)
        _check_n_agree(n_agree)
        _check_confidence(confidence)
        _check_contributors(contributors)
        _check_unique(track_ids, "track_ids")
        _check_sensor_ids(sensor_ids)
    except _Invalid as exc:
        raise ValueError(f"fused frame cannot be sent: {exc}") from None
    sections, extra = _fused_sections(frame, n)
    header = _FUSED_HEADER.pack(
        MAGIC,
        VERSION_MAJOR,
        FUSED_MINOR_WITH_SECTIONS if sections else VERSION_MINOR,
        MessageKind.FUSED_FRAME,
        0,
        FUSED_HEADER_SIZE,
        N_JOINTS,
        n,
        n_sensors,
        _check_int(frame.time_us, _I64, "time_us"),
        len(table),
        sections,
    )
    # The arrays are C-contiguous wire-typed arrays: join reads their buffers directly (one copy, into the payload).
    return b"".join((header, track_ids.data, positions.data, n_agree.data, confidence, contributors, table, *extra))


def _id_table(sensor_ids: tuple[str, ...]) -> bytes:
    """The fused frame's sensor id table (u16-length-prefixed UTF-8), checked (ValueError on a bad id)."""
    raw_ids = [_check_id(sid, f"sensor_ids[{i}]") for i, sid in enumerate(sensor_ids)]
    return b"".join([_U16.pack(len(raw)) + raw for raw in raw_ids])


_sensor_id_table = functools.lru_cache(maxsize=16)(_id_table)
""":func:`_id_table`, cached: a rig's ids repeat frame after frame (an error is never cached)."""


def _fused_sections(frame: FusedFrame, n: int) -> tuple[int, list[memoryview]]:
    """The 1.1 sections of a fused frame: the ``sections`` bits and their bytes, in bit order."""
    sections = 0
    extra: list[memoryview] = []
    orientations = getattr(frame, "orientations", None)
    position_std = getattr(frame, "position_std", None)
    try:
        if orientations is not None:
            quats = _as_wire(orientations, _F8, (n, N_JOINTS, 4), "orientations", "f")
            _check_orientations(quats)
            sections |= FUSED_SECTION_ORIENTATIONS
            extra.append(quats.data)
        if position_std is not None:
            std = _as_wire(position_std, _F8, (n, N_JOINTS), "position_std", "f")
            _check_position_std(std)
            sections |= FUSED_SECTION_POSITION_STD
            extra.append(std.data)
    except _Invalid as exc:
        raise ValueError(f"fused frame cannot be sent: {exc}") from None
    return sections, extra


def decode_fused_frame(data: bytes | bytearray | memoryview) -> FusedFrame:
    """Parse and validate a fused-frame payload (message kind 2).

    Returns a :class:`~skelfuse.schema.frames.FusedFrame` owning fresh writable arrays: track_ids (P,) int64,
    positions (P, 32, 3) float64 mm world (NaN = no estimate), n_agree (P, 32) int16, confidence (P, 32)
    uint8, contributors (P, S) bool, sensor_ids tuple of S str; from a 1.1 payload also orientations (P, 32, 4)
    float64 and/or position_std (P, 32) float64 mm where its ``sections`` bits say so (else None).

    Raises
    ------
    DecodeError
        For any payload that is not a valid fused frame; ``reason`` says why.
    TypeError
        ``data`` is not bytes-like.
    """
    name = "fused frame"
    view = _buffer(data)
    _, minor, offset = _read_prefix(view, MessageKind.FUSED_FRAME)
    (_, _, _, _, _, _, n_joints, n, n_sensors, time_us, table_size, sections) = _FUSED_HEADER.unpack_from(view)
    _joints(n_joints, name)
    _cap(n, MAX_PERSONS, "persons", name)
    _cap(n_sensors, MAX_SENSORS, "sensors", name)
    _cap(table_size, n_sensors * (2 + MAX_ID_BYTES), "bytes of sensor id table", name)
    table_at = offset + n * FUSED_BYTES_PER_PERSON + n * n_sensors
    table_end = table_at + table_size
    # 1.0 readers ignore the reserved field; from 1.1 on its low bits name the sections after the table.
    sections = sections if minor >= FUSED_MINOR_WITH_SECTIONS else 0
    orientations_at = table_end
    std_at = orientations_at + (32 * N_JOINTS * n if sections & FUSED_SECTION_ORIENTATIONS else 0)
    end = std_at + (8 * N_JOINTS * n if sections & FUSED_SECTION_POSITION_STD else 0)
    _check_length(view, end, minor, name, FUSED_MINOR_WITH_SECTIONS)
    table = view[:table_end]  # an id must not run past the declared table
    sensor_ids = []
    at = table_at
    for i in range(n_sensors):
        sid, at = _read_id(table, at, f"sensor_ids[{i}]", name)
        sensor_ids.append(sid)
    if at != table_end:
        raise DecodeError(
            "bad_length",
            f"{name} payload rejected (bad_length): sensor id table holds "
            f"{at - table_at} bytes of ids, header says {table_size}",
        )
    rows = n * N_JOINTS
    owned = bytearray(view[:table_at])  # one copy backs every array (see decode_sensor_frame)
    track_ids = np.frombuffer(owned, _I8, n, offset)
    positions = np.frombuffer(owned, _F8, rows * 3, offset + 8 * n).reshape(n, N_JOINTS, 3)
    n_agree_at = offset + 8 * n + 24 * rows
    n_agree = np.frombuffer(owned, _I2, rows, n_agree_at).reshape(n, N_JOINTS)
    confidence_at = n_agree_at + 2 * rows
    contributors_at = confidence_at + rows
    orientations = position_std = None
    if sections & FUSED_SECTION_ORIENTATIONS:
        orientations = np.frombuffer(bytearray(view[orientations_at:std_at]), _F8).reshape(n, N_JOINTS, 4)
    if sections & FUSED_SECTION_POSITION_STD:
        position_std = np.frombuffer(bytearray(view[std_at:end]), _F8).reshape(n, N_JOINTS)
    try:
        if orientations is not None:
            _check_orientations(orientations)
        if position_std is not None:
            _check_position_std(position_std)
        _check_fused_positions(positions)
        _check_n_agree(n_agree)
        _check_confidence(bytes(owned[confidence_at:contributors_at]))
        _check_contributors(bytes(owned[contributors_at:table_at]))
        _check_unique(track_ids, "track_ids")
        _check_sensor_ids(tuple(sensor_ids))
    except _Invalid as exc:
        raise DecodeError(exc.reason, f"{name} payload rejected ({exc.reason}): {exc}") from None
    return FusedFrame(
        time_us=time_us,
        track_ids=track_ids.astype(np.int64, copy=False),
        positions=positions.astype(np.float64, copy=False),
        n_agree=n_agree.astype(np.int16, copy=False),
        confidence=np.frombuffer(owned, _U1, rows, confidence_at).reshape(n, N_JOINTS),
        contributors=np.frombuffer(owned, np.bool_, n * n_sensors, contributors_at).reshape(n, n_sensors),
        sensor_ids=tuple(sensor_ids),
        orientations=None if orientations is None else orientations.astype(np.float64, copy=False),
        position_std=None if position_std is None else position_std.astype(np.float64, copy=False),
    )


# --------------------------------------------------------------------------------------------------------
# Node status


def _status_problem(doc: object) -> str | None:
    """Why ``doc`` is not a valid status document, or None."""
    if not isinstance(doc, dict):
        return f"document is a {type(doc).__name__}, expected a JSON object"
    for key in ("node", "role", "state"):
        if not isinstance(doc.get(key), str) or not doc[key]:
            return f"field {key!r} must be a non-empty string, got {doc.get(key)!r}"
    time_ns = doc.get("time_ns")
    if not isinstance(time_ns, int) or isinstance(time_ns, bool) or not _I64[0] <= time_ns <= _I64[1]:
        return f"field 'time_ns' must be an integer (int64 ns), got {time_ns!r}"
    counters = doc.get("counters", {})
    if not isinstance(counters, dict):
        return f"field 'counters' must be an object, got {type(counters).__name__}"
    for key, value in counters.items():
        if not isinstance(key, str):
            return f"counter name {key!r} must be a string"
        if not isinstance(value, int) or isinstance(value, bool) or value < 0:
            return f"counter {key!r} must be a non-negative integer, got {value!r}"
    info = doc.get("info", {})
    if not isinstance(info, dict):
        return f"field 'info' must be an object, got {type(info).__name__}"
    if not all(isinstance(key, str) for key in info):
        return "field 'info' must have string keys"
    return None


def _reject_constant(name: str) -> float:
    raise ValueError(f"{name} is not valid JSON")


def encode_status(status: NodeStatus) -> bytes:
    """Serialize a node status (message kind 3): the 16-byte header, then a UTF-8 JSON object.

    Raises
    ------
    ValueError
        Empty node/role, a state outside :data:`STATUS_STATES`, a negative or non-integer counter, info
        that is not JSON-serializable (NaN included), or a document over MAX_STATUS_BYTES.
    """
    if status.state not in STATUS_STATES:
        raise ValueError(f"status state {status.state!r} is not one of {STATUS_STATES}")
    doc = {
        "node": status.node,
        "role": status.role,
        "state": status.state,
        "time_ns": status.time_ns,
        "counters": dict(status.counters),
        "info": dict(status.info),
    }
    problem = _status_problem(doc)
    if problem is not None:
        raise ValueError(f"status of node {status.node!r} cannot be sent: {problem}")
    try:
        text = json.dumps(doc, allow_nan=False, separators=(",", ":"), ensure_ascii=False)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"status of node {status.node!r} cannot be sent: info is not JSON: {exc}") from None
    body = text.encode("utf-8")
    if len(body) > MAX_STATUS_BYTES:
        raise ValueError(
            f"status of node {status.node!r} is {len(body)} bytes of JSON, at most {MAX_STATUS_BYTES}; trim 'info'"
        )
    header = _STATUS_HEADER.pack(
        MAGIC, VERSION_MAJOR, VERSION_MINOR, MessageKind.STATUS, 0, STATUS_HEADER_SIZE, 0, len(body)
    )
    return header + body


def decode_status(data: bytes | bytearray | memoryview) -> NodeStatus:
    """Parse and validate a node-status payload (message kind 3). Unknown JSON fields are ignored.

    Raises
    ------
    DecodeError
        For any payload that is not a valid status; ``reason`` says why.
    TypeError
        ``data`` is not bytes-like.
    """
    name = "status"
    view = _buffer(data)
    _, minor, offset = _read_prefix(view, MessageKind.STATUS)
    (*_, json_size) = _STATUS_HEADER.unpack_from(view)
    _cap(json_size, MAX_STATUS_BYTES, "bytes of JSON", name)
    _check_length(view, offset + json_size, minor, name)
    try:
        text = bytes(view[offset : offset + json_size]).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DecodeError(
            "bad_utf8",
            f"{name} payload rejected (bad_utf8): JSON is not UTF-8 ({exc.reason} at byte {offset + exc.start})",
        ) from None
    try:
        doc = json.loads(text, parse_constant=_reject_constant)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError is a ValueError; deep nesting recurses
        raise DecodeError("bad_json", f"{name} payload rejected (bad_json): {str(exc)[:200]}") from None
    problem = _status_problem(doc)
    if problem is not None:
        raise DecodeError("bad_json", f"{name} payload rejected (bad_json): {problem}")
    return NodeStatus(
        node=doc["node"],
        role=doc["role"],
        state=doc["state"],
        time_ns=doc["time_ns"],
        counters=dict(doc.get("counters", {})),
        info=dict(doc.get("info", {})),
    )


# --------------------------------------------------------------------------------------------------------
# Any message


def peek_kind(data: bytes | bytearray | memoryview) -> MessageKind:
    """Message kind of a payload after checking its prefix (magic, major version, header size).

    Raises
    ------
    DecodeError
        Reasons truncated, bad_magic, bad_version, bad_kind, bad_header.
    """
    kind, _, _ = _read_prefix(_buffer(data), None)
    return kind


def decode(data: bytes | bytearray | memoryview) -> SensorFrame | FusedFrame | NodeStatus:
    """Decode any skelfuse payload, dispatching on its message kind (for recorders and inspectors); person
    clouds (kind 4) have their own decoder, ``skelfuse.wire.clouds.decode_person_clouds``."""
    kind = peek_kind(data)
    if kind == MessageKind.PERSON_CLOUDS:
        raise DecodeError(
            "bad_kind",
            "person-clouds payload: decode it with skelfuse.wire.clouds.decode_person_clouds",
        )
    if kind == MessageKind.SENSOR_FRAME:
        return decode_sensor_frame(data)
    if kind == MessageKind.FUSED_FRAME:
        return decode_fused_frame(data)
    return decode_status(data)


__all__ = [
    "FUSED_BYTES_PER_PERSON",
    "FUSED_HEADER_SIZE",
    "FUSED_MINOR_WITH_SECTIONS",
    "FUSED_SECTION_ORIENTATIONS",
    "FUSED_SECTION_POSITION_STD",
    "MAGIC",
    "MAX_BODIES",
    "MAX_ID_BYTES",
    "MAX_PERSONS",
    "MAX_SENSORS",
    "MAX_STATUS_BYTES",
    "REJECT_REASONS",
    "SENSOR_BYTES_PER_BODY",
    "SENSOR_HEADER_SIZE",
    "STATUS_HEADER_SIZE",
    "STATUS_STATES",
    "VERSION_MAJOR",
    "VERSION_MINOR",
    "DecodeError",
    "MessageKind",
    "NodeStatus",
    "decode",
    "decode_fused_frame",
    "decode_sensor_frame",
    "decode_status",
    "encode_fused_frame",
    "encode_sensor_frame",
    "encode_status",
    "peek_kind",
]
