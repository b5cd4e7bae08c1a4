"""The wire format's constants, message kinds, byte layouts and reject reasons (``docs/wire-format.md``).

:mod:`skelfuse.wire.codec` encodes and decodes with them; :mod:`skelfuse.wire.rules` checks frames against them.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import numpy as np

from skelfuse.schema.errors import DataError
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
FUSED_MINOR_WITH_AGREEMENT = 2
"""Minor version of a fused frame that carries the per-person agreement figure (schema 1.2). A frame without it
is written as 1.1 or 1.0 as before; a 1.1 reader reads a 1.2 frame and skips the section (docs/wire-format.md §7)."""
FUSED_SECTION_AGREEMENT = 4
"""Bit of ``sections`` (1.2): f64[P] agreement_mm follow, after the position_std section."""
FUSED_SECTIONS_BY_MINOR = {
    FUSED_MINOR_WITH_SECTIONS: FUSED_SECTION_ORIENTATIONS | FUSED_SECTION_POSITION_STD,
    FUSED_MINOR_WITH_AGREEMENT: FUSED_SECTION_ORIENTATIONS | FUSED_SECTION_POSITION_STD | FUSED_SECTION_AGREEMENT,
}
"""The ``sections`` bits each fused minor defines; a frame of a minor this reader knows sets no other bit."""
_KNOWN_MINOR = {1: VERSION_MINOR, 2: FUSED_MINOR_WITH_AGREEMENT, 3: VERSION_MINOR, 4: 0}  # by message kind byte
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
_U1, _U4, _I2, _I8 = np.dtype("u1"), np.dtype("<u4"), np.dtype("<i2"), np.dtype("<i8")
_F4, _F8 = np.dtype("<f4"), np.dtype("<f8")


class _Invalid(Exception):
    """A rule broken by a frame: becomes DecodeError when decoding and ValueError when encoding."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason
