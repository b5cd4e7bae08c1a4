"""The wire: zenoh key expressions (:mod:`.keys`) and versioned binary payloads (:mod:`.codec`).

Frames cross the process boundary here and nowhere else: a capture worker encodes a
:class:`~skelfuse.schema.frames.SensorFrame`, the fusion node decodes it, fuses, and encodes a
:class:`~skelfuse.schema.frames.FusedFrame` for any app. Nothing in this package imports zenoh; the byte layout
is specified in ``docs/wire-format.md``.
"""

from __future__ import annotations

from skelfuse.wire import keys
from skelfuse.wire.codec import (
    REJECT_REASONS,
    DecodeError,
    MessageKind,
    NodeStatus,
    decode,
    decode_fused_frame,
    decode_sensor_frame,
    decode_status,
    encode_fused_frame,
    encode_sensor_frame,
    encode_status,
    peek_kind,
)

__all__ = [
    "REJECT_REASONS",
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
    "keys",
    "peek_kind",
]
