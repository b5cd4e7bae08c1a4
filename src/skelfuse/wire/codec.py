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
import math
from collections.abc import Callable

import numpy as np

from skelfuse.schema.frames import FusedFrame, SensorFrame
from skelfuse.schema.skeleton import N_JOINTS
from skelfuse.wire.layout import (
    _F4,
    _F8,
    _FUSED_HEADER,
    _I2,
    _I8,
    _I64,
    _SENSOR_HEADER,
    _STATUS_HEADER,
    _U1,
    _U4,
    _U16,
    _U64,
    FUSED_BYTES_PER_PERSON,
    FUSED_HEADER_SIZE,
    FUSED_MINOR_WITH_AGREEMENT,
    FUSED_MINOR_WITH_SECTIONS,
    FUSED_SECTION_AGREEMENT,
    FUSED_SECTION_ORIENTATIONS,
    FUSED_SECTION_POSITION_STD,
    FUSED_SECTIONS_BY_MINOR,
    MAGIC,
    MAX_BODIES,
    MAX_ID_BYTES,
    MAX_PERSONS,
    MAX_SENSORS,
    MAX_STATUS_BYTES,
    PERSON_CLOUDS_HEADER_SIZE,
    REJECT_REASONS,
    SENSOR_BYTES_PER_BODY,
    SENSOR_HEADER_SIZE,
    STATUS_HEADER_SIZE,
    STATUS_STATES,
    VERSION_MAJOR,
    VERSION_MINOR,
    DecodeError,
    MessageKind,
    NodeStatus,
    _Invalid,
)
from skelfuse.wire.rules import (
    _as_wire,
    _buffer,
    _cap,
    _check_agreement,
    _check_confidence,
    _check_contributors,
    _check_fused_positions,
    _check_id,
    _check_int,
    _check_length,
    _check_n_agree,
    _check_orientations,
    _check_position_std,
    _check_sensor_floats,
    _check_sensor_ids,
    _check_unique,
    _joints,
    _read_id,
    _read_prefix,
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
    ``sections`` bits name them and they follow the sensor id table as float64 (NaN = unknown); one with
    ``agreement_mm`` too is written as 1.2 (the per-person figure after them); a frame with none is written as 1.0.

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
        _fused_minor(sections),
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


def _fused_minor(sections: int) -> int:
    """The oldest fused minor that defines every bit of ``sections`` (older readers see no change)."""
    if not sections:
        return VERSION_MINOR
    return min(minor for minor, bits in FUSED_SECTIONS_BY_MINOR.items() if sections & ~bits == 0)


_FUSED_SECTIONS: tuple[tuple[int, str, tuple[int, ...], Callable[[np.ndarray], None]], ...] = (
    (FUSED_SECTION_ORIENTATIONS, "orientations", (N_JOINTS, 4), _check_orientations),
    (FUSED_SECTION_POSITION_STD, "position_std", (N_JOINTS,), _check_position_std),
    (FUSED_SECTION_AGREEMENT, "agreement_mm", (), _check_agreement),
)
"""The optional float64 sections of a fused frame, in bit order: bit, FusedFrame field, shape per person, rule."""


def _fused_sections(frame: FusedFrame, n: int) -> tuple[int, list[memoryview]]:
    """The optional sections of a fused frame (1.1, 1.2): the ``sections`` bits and their bytes, in bit order."""
    sections = 0
    extra: list[memoryview] = []
    try:
        for bit, field, shape, check in _FUSED_SECTIONS:
            if (value := getattr(frame, field, None)) is not None:
                array = _as_wire(value, _F8, (n, *shape), field, "f")
                check(array)
                sections |= bit
                extra.append(array.data)
    except _Invalid as exc:
        raise ValueError(f"fused frame cannot be sent: {exc}") from None
    return sections, extra


def _section_spans(sections: int, n: int, start: int) -> tuple[list[tuple[str, int, int, tuple[int, ...]]], int]:
    """Where the sections ``sections`` names lie from byte ``start``: (field, begin, end, shape) each, and the end."""
    spans = []
    for bit, field, shape, _ in _FUSED_SECTIONS:
        if sections & bit:
            size = 8 * n * math.prod(shape)
            spans.append((field, start, start + size, (n, *shape)))
            start += size
    return spans, start


def decode_fused_frame(data: bytes | bytearray | memoryview) -> FusedFrame:
    """Parse and validate a fused-frame payload (message kind 2).

    Returns a :class:`~skelfuse.schema.frames.FusedFrame` owning fresh writable arrays: track_ids (P,) int64,
    positions (P, 32, 3) float64 mm world (NaN = no estimate), n_agree (P, 32) int16, confidence (P, 32)
    uint8, contributors (P, S) bool, sensor_ids tuple of S str; from a 1.1 payload also orientations (P, 32, 4)
    float64 and/or position_std (P, 32) float64 mm where its ``sections`` bits say so (else None), from a 1.2
    payload also agreement_mm (P,) float64 mm. Sections of a newer minor are skipped.

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
    spans, end = _section_spans(_known_sections(sections, minor, name), n, table_end)
    _check_length(view, end, minor, name, FUSED_MINOR_WITH_AGREEMENT)
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
    extra = {f: np.frombuffer(bytearray(view[a:b]), _F8).reshape(shape) for f, a, b, shape in spans}
    try:
        for _, field, _, check in _FUSED_SECTIONS:
            if field in extra:
                check(extra[field])
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
        **{field: array.astype(np.float64, copy=False) for field, array in extra.items()},
    )


def _known_sections(sections: int, minor: int, name: str) -> int:
    """The ``sections`` bits this reader reads: none before 1.1 (the field was ``reserved``), the bits of the
    frame's minor, or, from a newer minor, the bits this reader knows (the newer sections follow them)."""
    if minor < FUSED_MINOR_WITH_SECTIONS:
        return 0
    known = FUSED_SECTIONS_BY_MINOR[min(minor, FUSED_MINOR_WITH_AGREEMENT)]
    if minor <= FUSED_MINOR_WITH_AGREEMENT and sections & ~known:
        raise DecodeError(
            "bad_header",
            f"{name} payload rejected (bad_header): sections bits {sections:#x} for version 1.{minor}, "
            f"which defines only {known:#x}",
        )
    return sections & known


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
    "FUSED_MINOR_WITH_AGREEMENT",
    "FUSED_MINOR_WITH_SECTIONS",
    "FUSED_SECTION_AGREEMENT",
    "FUSED_SECTION_ORIENTATIONS",
    "FUSED_SECTION_POSITION_STD",
    "MAGIC",
    "MAX_BODIES",
    "MAX_ID_BYTES",
    "MAX_PERSONS",
    "MAX_SENSORS",
    "MAX_STATUS_BYTES",
    "PERSON_CLOUDS_HEADER_SIZE",
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
