"""The layout of a skelfuse MCAP recording, shared by its writer and its reader: channel encodings, schema names
and texts, metadata record names, the container's magic and record framing (docs/recording.md).
"""

from __future__ import annotations

import struct
from typing import Any

import numpy as np
from mcap.writer import CompressionType

from skelfuse.wire.codec import (
    VERSION_MAJOR,
    VERSION_MINOR,
)

MESSAGE_ENCODING = "skelfuse-sensor-frame/1"
"""MCAP message encoding of sensor-frame channels: the wire codec's sensor frame, schema major 1."""
SCHEMA_NAME = "skelfuse.SensorFrame"
"""Name of the schema record of sensor-frame channels."""
SCHEMA_ENCODING = "skelfuse-wire"
"""Schema encoding: the schema data is a UTF-8 text that names the specification (docs/wire-format.md)."""
SCHEMA_TEXT = (
    f"skelfuse sensor frame, wire schema {VERSION_MAJOR}.{VERSION_MINOR} (message kind 1).\n"
    "Specified byte by byte in docs/wire-format.md, section 4 'Sensor frame', of the skelfuse project; "
    "reference implementation: skelfuse.wire.codec.decode_sensor_frame.\n"
    "Little-endian; prefix 'SKLF', major, minor, kind, flags, header_size; then sequence, device time (us), "
    "host time (ns), body ids, positions f32[B][32][3] mm, orientations f32[B][32][4] wxyz, confidence "
    "u8[B][32], sensor id.\n"
)
FUSED_MESSAGE_ENCODING = "skelfuse-fused-frame/1"
"""MCAP message encoding of the fused channel: the wire codec's fused frame, schema major 1."""
FUSED_SCHEMA_NAME = "skelfuse.FusedFrame"
"""Name of the schema record of the fused channel."""
FUSED_SCHEMA_TEXT = (
    f"skelfuse fused frame, wire schema {VERSION_MAJOR}.x (message kind 2).\n"
    "Specified byte by byte in docs/wire-format.md, section 'Fused frame', of the skelfuse project; "
    "reference implementation: skelfuse.wire.codec.decode_fused_frame.\n"
    "Little-endian; prefix 'SKLF', major, minor, kind, flags, header_size; then time (us), track ids, "
    "positions f64[P][32][3] mm world, n_agree i16[P][32], confidence u8[P][32], contributors u8[P][S], "
    "sensor id table; then the optional sections the header's 'sections' bits name (1.1: orientations "
    "f64[P][32][4] wxyz, position_std f64[P][32] mm; 1.2: agreement_mm f64[P]).\n"
)
CLOUDS_MESSAGE_ENCODING = "skelfuse-person-clouds/1"
"""MCAP message encoding of person-cloud channels (depth / hybrid mode): the wire payload of kind 4."""
CLOUDS_SCHEMA_NAME = "skelfuse.PersonClouds"
"""Name of the schema record of person-cloud channels."""
CLOUDS_SCHEMA_TEXT = (
    f"skelfuse person clouds, wire schema {VERSION_MAJOR}.x (message kind 4).\n"
    "Specified byte by byte in docs/wire-format.md, section 10 'Person clouds', of the skelfuse project; "
    "reference implementation: skelfuse.wire.clouds.decode_person_clouds.\n"
)
PROFILE = "skelfuse"
"""MCAP header profile of skelfuse recordings."""
RECORDING_METADATA = "skelfuse.recording"
"""Name of the metadata record with rig, version, start time, sensors and the caller's keys."""
CALIBRATION_METADATA = "skelfuse.calibration"
"""Name of the metadata record with ``world_from_sensor/<sensor>`` = JSON row-major 4x4 (mm)."""
RESERVED_METADATA_KEYS = ("rig", "skelfuse_version", "wire_version", "start_time_ns", "start_time_utc", "sensor_ids")
"""Keys of :data:`RECORDING_METADATA` that the writer fills; the caller's metadata cannot use them."""

MCAP_MAGIC = b"\x89MCAP0\r\n"
RECORD_PREFIX = struct.Struct("<BQ")  # opcode, length
CHUNK_TIMES = struct.Struct("<QQ")  # message_start_time, message_end_time: first fields of a chunk record
U64_MAX = 2**64 - 1
COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, None: CompressionType.NONE}


def clamp_u64(value: int) -> int:
    return min(max(int(value), 0), U64_MAX)


def as_pose(value: Any, sensor_id: str) -> np.ndarray:
    pose = np.asarray(value, dtype=np.float64)
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        raise ValueError(
            f"world_from_sensor[{sensor_id!r}] must be a finite 4x4 matrix, got shape {pose.shape}"
            + ("" if pose.shape != (4, 4) else " with NaN/Inf")
        )
    return pose
