"""The wire format's rules, one routine each, shared by the encoder (ValueError) and the decoder (DecodeError).

They run on every frame at 30 Hz per sensor, so each is one numpy call on the fast path. The reading helpers
here turn every short or malformed buffer into a :class:`~skelfuse.wire.layout.DecodeError`.
"""

from __future__ import annotations

import operator
from typing import Any

import numpy as np

from skelfuse.schema.skeleton import N_JOINTS
from skelfuse.wire.layout import (
    _HEADER_SIZES,
    _KIND_NAMES,
    _KNOWN_MINOR,
    _PREFIX,
    _U16,
    _UNIT_TOLERANCE,
    MAGIC,
    MAX_ID_BYTES,
    MAX_SENSORS,
    VERSION_MAJOR,
    VERSION_MINOR,
    DecodeError,
    MessageKind,
    _Invalid,
)

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


_NOT_UNIT = f"orientations hold a quaternion whose norm is not 1 (within {_UNIT_TOLERANCE})"


def _check_orientations(quats: np.ndarray) -> None:
    """``quats``: (P, 32, 4). A joint is all NaN (unknown) or a finite unit quaternion."""
    if np.isfinite(quats).all():  # the fast path: every joint known, only the norms to check
        if (np.abs(np.sqrt(np.add.reduce(quats * quats, axis=-1)) - 1.0) > _UNIT_TOLERANCE).any():
            raise _Invalid("bad_value", _NOT_UNIT)
        return
    nan = np.isnan(quats)
    if np.isinf(quats).any() or (nan.any(axis=-1) != nan.all(axis=-1)).any():
        raise _Invalid(
            "non_finite",
            "orientations hold Inf or a joint with some but not all components NaN; an unknown "
            "orientation is NaN in w, x, y and z",
        )
    norm = np.linalg.norm(np.where(nan, 0.0, quats), axis=-1)
    if (np.abs(norm - 1.0)[~nan[..., 0]] > _UNIT_TOLERANCE).any():
        raise _Invalid("bad_value", _NOT_UNIT)


def _check_position_std(std: np.ndarray) -> None:
    """``std``: (P, 32) mm, NaN (no estimate) or finite and >= 0."""
    if np.isinf(std).any():
        raise _Invalid("non_finite", "position_std holds Inf; only NaN (no estimate) is allowed")
    if (std < 0).any():
        raise _Invalid("bad_value", "position_std holds a negative value")


def _check_agreement(figure: np.ndarray) -> None:
    """``figure``: (P,) mm, NaN (fewer than two views) or finite and >= 0."""
    if np.isinf(figure).any():
        raise _Invalid("non_finite", "agreement_mm holds Inf; only NaN (no figure) is allowed")
    if (figure < 0).any():
        raise _Invalid("bad_value", "agreement_mm holds a negative value")


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
