"""The person-cloud payload: each tracked body's depth points from one sensor, voxelized, in the sensor frame.

A capture worker in depth mode publishes one of these per depth frame on
``skelfuse/<rig>/sensors/<serial>/clouds`` (:func:`skelfuse.wire.keys.sensor_clouds`), beside its skeletons.
The byte layout is specified in ``docs/wire-format.md`` ("Person clouds"); this module is its reference
implementation. It shares the 10-byte prefix of every skelfuse payload (magic ``SKLF``, major/minor version,
kind, flags, header size) with message kind ``MessageKind.PERSON_CLOUDS`` = 4, and lives in its own module so
that the skeleton payloads of :mod:`skelfuse.wire.codec` are untouched by it.

Compact encoding: every point is three uint16 offsets from its body's origin (the minimum corner of its
points) in units of ``quantum_mm`` (1 mm by default, so the rounding error is at most 0.5 mm per axis, far
below the voxel size and the depth noise): 6 bytes a point, 8 with IR, against 12 for float32 xyz.

Decoding validates everything and raises only :class:`skelfuse.wire.codec.DecodeError` with a reason from
:data:`skelfuse.wire.codec.REJECT_REASONS`, like the other payloads.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from skelfuse.wire.codec import (
    MAGIC,
    MAX_BODIES,
    MAX_ID_BYTES,
    VERSION_MAJOR,
    DecodeError,
    MessageKind,
)

PERSON_CLOUDS_KIND = int(MessageKind.PERSON_CLOUDS)
"""Message kind byte of a person-cloud payload (after SENSOR_FRAME 1, FUSED_FRAME 2, STATUS 3)."""
CLOUDS_VERSION_MINOR = 0
"""Minor version written. A reader accepts any minor of major :data:`VERSION_MAJOR`."""
FLAG_IR = 0x01
"""Prefix flag bit: every point carries a uint16 IR intensity."""
MAX_POINTS_PER_BODY = 640 * 576
"""Most points in one body's cloud (every pixel of an NFOV unbinned depth image)."""

_HEADER = struct.Struct("<4sBBBBHHHQqqff")  # prefix + n_bodies, reserved, sequence, dev us, host ns, voxel, quantum
CLOUDS_HEADER_SIZE = _HEADER.size  # 46 (codec.PERSON_CLOUDS_HEADER_SIZE, checked by the tests)
_BODY = struct.Struct("<IIfff")  # body id, n_points, origin x y z (mm, sensor frame)
BODY_HEADER_SIZE = _BODY.size  # 20
_U16 = struct.Struct("<H")
_WHAT = "person-clouds"


@dataclass(frozen=True)
class PersonCloudsFrame:
    """One sensor's person clouds at one depth frame.

    Attributes
    ----------
    sensor_id : device serial.
    sequence : the capture worker's frame counter.
    device_timestamp_us : the depth frame's device timestamp, µs (the skeletons of the same capture carry it).
    host_timestamp_ns : host clock at capture, ns.
    voxel_mm : voxel edge the clouds were voxelized with (0 = not voxelized).
    body_ids : (B,) uint32 the tracker's body ids, in the order of ``clouds``.
    clouds : B arrays (N_b, 3) float64, sensor frame mm.
    ir : B arrays (N_b,) of IR intensity (uint16 range), or None.
    """

    sensor_id: str
    sequence: int
    device_timestamp_us: int
    host_timestamp_ns: int
    voxel_mm: float
    body_ids: np.ndarray
    clouds: tuple[np.ndarray, ...]
    ir: tuple[np.ndarray, ...] | None = None


def encode_person_clouds(frame: PersonCloudsFrame, *, quantum_mm: float = 1.0) -> bytes:
    """The payload bytes of ``frame``; ValueError for a frame a reader would reject."""
    ids = np.asarray(frame.body_ids, dtype=np.int64).reshape(-1)
    if len(frame.clouds) != ids.shape[0]:
        raise ValueError(f"{ids.shape[0]} body ids for {len(frame.clouds)} clouds")
    if ids.shape[0] > MAX_BODIES:
        raise ValueError(f"{ids.shape[0]} bodies, at most {MAX_BODIES}")
    if ((ids < 0) | (ids > 0xFFFFFFFF)).any() or np.unique(ids).shape[0] != ids.shape[0]:
        raise ValueError(f"body ids must be distinct uint32 values, got {ids.tolist()}")
    if not (np.isfinite(quantum_mm) and quantum_mm > 0 and np.isfinite(frame.voxel_mm) and frame.voxel_mm >= 0):
        raise ValueError(f"quantum_mm must be > 0 and voxel_mm >= 0, got {quantum_mm!r}, {frame.voxel_mm!r}")
    if frame.ir is not None and len(frame.ir) != len(frame.clouds):
        raise ValueError(f"{len(frame.ir)} IR arrays for {len(frame.clouds)} clouds")
    sensor = frame.sensor_id.encode("utf-8")
    if not 0 < len(sensor) <= MAX_ID_BYTES:
        raise ValueError(f"sensor id must be 1..{MAX_ID_BYTES} UTF-8 bytes, got {len(sensor)}")
    flags = FLAG_IR if frame.ir is not None else 0
    parts = [
        _HEADER.pack(
            MAGIC,
            VERSION_MAJOR,
            CLOUDS_VERSION_MINOR,
            PERSON_CLOUDS_KIND,
            flags,
            CLOUDS_HEADER_SIZE,
            ids.shape[0],
            0,
            frame.sequence,
            frame.device_timestamp_us,
            frame.host_timestamp_ns,
            frame.voxel_mm,
            quantum_mm,
        )
    ]
    for index, (body_id, cloud) in enumerate(zip(ids, frame.clouds, strict=True)):
        points = np.asarray(cloud, dtype=np.float64).reshape(-1, 3)
        if points.shape[0] > MAX_POINTS_PER_BODY:
            raise ValueError(f"body {body_id}: {points.shape[0]} points, at most {MAX_POINTS_PER_BODY}")
        if not np.isfinite(points).all():
            raise ValueError(f"body {body_id}: points must be finite")
        origin = points.min(axis=0).astype(np.float32) if points.shape[0] else np.zeros(3, np.float32)
        steps = np.rint((points - origin.astype(np.float64)) / quantum_mm)
        if points.shape[0] and steps.max() > 0xFFFF:
            raise ValueError(
                f"body {body_id}: the cloud spans {np.ptp(points, axis=0).max():.0f} mm, more than "
                f"65535 x quantum_mm = {0xFFFF * quantum_mm:.0f} mm; raise quantum_mm"
            )
        parts.append(_BODY.pack(int(body_id), points.shape[0], *origin.tolist()))
        parts.append(steps.astype("<u2").tobytes())
        if frame.ir is not None:
            values = np.asarray(frame.ir[index], dtype=np.float64).reshape(-1)
            if values.shape[0] != points.shape[0]:
                raise ValueError(f"body {body_id}: {values.shape[0]} IR values for {points.shape[0]} points")
            parts.append(np.clip(np.rint(np.nan_to_num(values)), 0, 0xFFFF).astype("<u2").tobytes())
    parts.append(_U16.pack(len(sensor)) + sensor)
    return b"".join(parts)


def _reject(reason: str, detail: str) -> DecodeError:
    return DecodeError(reason, f"{_WHAT} payload rejected ({reason}): {detail}")


def decode_person_clouds(data: bytes | bytearray | memoryview) -> PersonCloudsFrame:
    """Parse and validate a person-cloud payload; :class:`DecodeError` names what is wrong."""
    view = memoryview(data).cast("B") if not isinstance(data, bytes) else memoryview(data)
    if len(view) < 4 or view[:4] != MAGIC:
        if len(view) < 4 and bytes(view) == MAGIC[: len(view)]:
            raise _reject("truncated", f"{len(view)} bytes, shorter than the prefix")
        raise _reject("bad_magic", f"starts with {bytes(view[:4])!r}, expected {MAGIC!r}")
    if len(view) < 10:
        raise _reject("truncated", f"{len(view)} bytes, shorter than the 10-byte prefix")
    major, minor, kind, flags, header_size = view[4], view[5], view[6], view[7], _U16.unpack_from(view, 8)[0]
    if major != VERSION_MAJOR:
        raise _reject("bad_version", f"schema version {major}.{minor}, this reader supports major {VERSION_MAJOR}")
    if kind != PERSON_CLOUDS_KIND:
        raise _reject("bad_kind", f"message kind {kind}, expected {PERSON_CLOUDS_KIND}; check the key it came from")
    if header_size < CLOUDS_HEADER_SIZE or (minor <= CLOUDS_VERSION_MINOR and header_size != CLOUDS_HEADER_SIZE):
        raise _reject(
            "bad_header", f"header size {header_size} for version {major}.{minor}, expected {CLOUDS_HEADER_SIZE}"
        )
    if len(view) < header_size:
        raise _reject("truncated", f"{len(view)} bytes, shorter than its {header_size}-byte header")
    fields = _HEADER.unpack_from(view)
    n_bodies, _, sequence, device_us, host_ns, voxel_mm, quantum_mm = fields[6:]
    if n_bodies > MAX_BODIES:
        raise _reject("too_large", f"{n_bodies} bodies, at most {MAX_BODIES}")
    if not (np.isfinite(voxel_mm) and voxel_mm >= 0 and np.isfinite(quantum_mm) and quantum_mm > 0):
        raise _reject("bad_value", f"voxel_mm {voxel_mm} must be >= 0 and quantum_mm {quantum_mm} > 0")
    has_ir = bool(flags & FLAG_IR)
    offset = header_size
    ids, clouds, irs = [], [], []
    for _ in range(n_bodies):
        if offset + BODY_HEADER_SIZE > len(view):
            raise _reject("truncated", f"body header at byte {offset} runs past the end ({len(view)} bytes)")
        body_id, n_points, ox, oy, oz = _BODY.unpack_from(view, offset)
        offset += BODY_HEADER_SIZE
        if n_points > MAX_POINTS_PER_BODY:
            raise _reject("too_large", f"body {body_id}: {n_points} points, at most {MAX_POINTS_PER_BODY}")
        if not np.isfinite([ox, oy, oz]).all():
            raise _reject("non_finite", f"body {body_id}: origin is not finite")
        size = n_points * (6 + (2 if has_ir else 0))
        if offset + size > len(view):
            raise _reject("truncated", f"body {body_id}: {n_points} points need {size} bytes from byte {offset}")
        steps = np.frombuffer(view, dtype="<u2", count=n_points * 3, offset=offset).reshape(-1, 3)
        offset += n_points * 6
        clouds.append(
            steps.astype(np.float64) * quantum_mm + np.array([ox, oy, oz], dtype=np.float32).astype(np.float64)
        )
        if has_ir:
            irs.append(np.frombuffer(view, dtype="<u2", count=n_points, offset=offset).astype(np.float32))
            offset += n_points * 2
        ids.append(body_id)
    if len(set(ids)) != len(ids):
        raise _reject("bad_value", f"duplicate body ids {ids}")
    if offset + 2 > len(view):
        raise _reject("truncated", f"sensor id length at byte {offset} is past the end ({len(view)} bytes)")
    (id_size,) = _U16.unpack_from(view, offset)
    offset += 2
    if id_size == 0 or id_size > MAX_ID_BYTES:
        raise _reject("bad_value" if id_size == 0 else "too_large", f"sensor id of {id_size} bytes")
    if offset + id_size > len(view):
        raise _reject("truncated", f"sensor id of {id_size} bytes runs past the end ({len(view)} bytes)")
    try:
        sensor_id = bytes(view[offset : offset + id_size]).decode("utf-8")
    except UnicodeDecodeError:
        raise _reject("bad_utf8", "sensor id is not valid UTF-8") from None
    offset += id_size
    if len(view) != offset and minor <= CLOUDS_VERSION_MINOR:
        raise _reject("bad_length", f"{len(view)} bytes, the header's counts need exactly {offset}")
    return PersonCloudsFrame(
        sensor_id,
        sequence,
        device_us,
        host_ns,
        float(voxel_mm),
        np.array(ids, dtype=np.uint32),
        tuple(clouds),
        tuple(irs) if has_ir else None,
    )


def payload_size(points_per_body: list[int], *, ir: bool, sensor_id_bytes: int) -> int:
    """Bytes of a payload with these cloud sizes (for network budgets): header, per-body header, points, id."""
    per_point = 8 if ir else 6
    return CLOUDS_HEADER_SIZE + sum(BODY_HEADER_SIZE + n * per_point for n in points_per_body) + 2 + sensor_id_bytes
