"""Wire codec: round trips, the documented byte layout, every reject reason, fuzzing, and the example decoder.

The example subscriber (scripts/example_subscriber.py) decodes with the standard library only; checking it
against the codec here keeps docs/wire-format.md, the script and the codec in agreement.
"""

from __future__ import annotations

import ast
import functools
import importlib.util
import json
import math
import pickle
import socket
import struct
import sys
import threading
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skelfuse.schema.errors import DataError
from skelfuse.schema.frames import FusedFrame, SensorFrame
from skelfuse.schema.skeleton import N_JOINTS
from skelfuse.wire import codec, keys
from skelfuse.wire.codec import DecodeError, NodeStatus
from waiting import wait_for_subscriber

ROOT = Path(__file__).resolve().parents[2]
SEED = 20240611

# ---------------------------------------------------------------------------------------------------------
# Frames: hypothesis draws the shape, ids and a seed; numpy fills the arrays (fast), and a few awkward
# float values (-0.0, subnormals, float32 extremes) are planted where hypothesis says.

AWKWARD_F32 = [0.0, -0.0, 1e-45, -1e-45, 3.4028235e38, -3.4028235e38, 1.1754944e-38]
sensor_ids = st.text(min_size=1, max_size=20).filter(lambda s: len(s.encode()) <= codec.MAX_ID_BYTES)


@st.composite
def sensor_frames(draw: st.DrawFn, max_bodies: int = 4) -> SensorFrame:
    n = draw(st.integers(0, max_bodies))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    positions = rng.normal(0.0, 1500.0, (n, N_JOINTS, 3)).astype(np.float32)
    orientations = rng.normal(0.0, 1.0, (n, N_JOINTS, 4)).astype(np.float32)
    if n:
        flat = positions.reshape(-1)
        for value in draw(st.lists(st.sampled_from(AWKWARD_F32), max_size=3)):
            flat[draw(st.integers(0, flat.size - 1))] = value
    return SensorFrame(
        sensor_id=draw(sensor_ids),
        sequence=draw(st.integers(0, 2**64 - 1)),
        device_time_us=draw(st.integers(-(2**63), 2**63 - 1)),
        host_time_ns=draw(st.integers(-(2**63), 2**63 - 1)),
        body_ids=np.array(
            draw(st.lists(st.integers(0, 2**32 - 1), min_size=n, max_size=n, unique=True)), dtype=np.uint32
        ),
        positions=positions,
        orientations=orientations,
        confidence=rng.integers(0, 4, (n, N_JOINTS)).astype(np.uint8),
    )


@st.composite
def fused_frames(draw: st.DrawFn, max_persons: int = 4, max_sensors: int = 5) -> FusedFrame:
    n = draw(st.integers(0, max_persons))
    sensors = tuple(draw(st.lists(sensor_ids, max_size=max_sensors, unique=True)))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    positions = rng.normal(0.0, 1500.0, (n, N_JOINTS, 3))
    positions[rng.random((n, N_JOINTS)) < draw(st.sampled_from([0.0, 0.2, 1.0]))] = np.nan  # whole joints
    return FusedFrame(
        time_us=draw(st.integers(-(2**63), 2**63 - 1)),
        track_ids=np.array(
            draw(st.lists(st.integers(-(2**63), 2**63 - 1), min_size=n, max_size=n, unique=True)), dtype=np.int64
        ),
        positions=positions,
        n_agree=rng.integers(0, codec.MAX_SENSORS + 1, (n, N_JOINTS)).astype(np.int16),
        confidence=rng.integers(0, 4, (n, N_JOINTS)).astype(np.uint8),
        contributors=rng.random((n, len(sensors))) < 0.5,
        sensor_ids=sensors,
    )


statuses = st.builds(
    NodeStatus,
    node=st.text(min_size=1, max_size=20),
    role=st.sampled_from(["capture", "fusion", "recorder"]),
    state=st.sampled_from(codec.STATUS_STATES),
    time_ns=st.integers(0, 2**63 - 1),
    counters=st.dictionaries(st.text(max_size=12), st.integers(0, 2**40), max_size=4),
    info=st.dictionaries(
        st.text(max_size=12),
        st.one_of(
            st.none(),
            st.booleans(),
            st.integers(-100, 100),
            st.floats(allow_nan=False, allow_infinity=False),
            st.text(max_size=10),
        ),
        max_size=4,
    ),
)


def assert_sensor_equal(got: SensorFrame, want: SensorFrame) -> None:
    assert (got.sensor_id, got.sequence, got.device_time_us, got.host_time_ns) == (
        want.sensor_id,
        want.sequence,
        want.device_time_us,
        want.host_time_ns,
    )
    for name, dtype in (
        ("body_ids", np.uint32),
        ("positions", np.float32),
        ("orientations", np.float32),
        ("confidence", np.uint8),
    ):
        array = getattr(got, name)
        assert array.dtype == dtype, name
        assert array.shape == getattr(want, name).shape, name
        # Bitwise equality: -0.0 stays -0.0 and subnormals survive.
        assert array.tobytes() == np.ascontiguousarray(getattr(want, name), dtype=dtype).tobytes(), name


def assert_fused_equal(got: FusedFrame, want: FusedFrame) -> None:
    assert got.time_us == want.time_us
    assert got.sensor_ids == want.sensor_ids
    for name, dtype in (
        ("track_ids", np.int64),
        ("positions", np.float64),
        ("n_agree", np.int16),
        ("confidence", np.uint8),
        ("contributors", np.bool_),
    ):
        array = getattr(got, name)
        assert array.dtype == dtype, name
        assert array.shape == getattr(want, name).shape, name
        np.testing.assert_array_equal(array, getattr(want, name), err_msg=name)  # NaN == NaN here


def make_sensor_frame(n_bodies: int = 2, sensor_id: str = "000123412512") -> SensorFrame:
    rng = np.random.default_rng(SEED)
    return SensorFrame(
        sensor_id=sensor_id,
        sequence=41,
        device_time_us=1_000_000,
        host_time_ns=1_700_000_000_000_000_000,
        body_ids=np.arange(1, n_bodies + 1, dtype=np.uint32),
        positions=rng.normal(0.0, 1000.0, (n_bodies, N_JOINTS, 3)).astype(np.float32),
        orientations=rng.normal(0.0, 1.0, (n_bodies, N_JOINTS, 4)).astype(np.float32),
        confidence=np.full((n_bodies, N_JOINTS), 2, dtype=np.uint8),
    )


def make_fused_frame(n_persons: int = 2, sensors: tuple[str, ...] = ("A1", "B2", "C3")) -> FusedFrame:
    rng = np.random.default_rng(SEED)
    positions = rng.normal(0.0, 1000.0, (n_persons, N_JOINTS, 3))
    if n_persons:
        positions[0, 9] = np.nan
    return FusedFrame(
        time_us=1_000_000,
        track_ids=np.arange(7, 7 + n_persons, dtype=np.int64),
        positions=positions,
        n_agree=np.full((n_persons, N_JOINTS), 2, dtype=np.int16),
        confidence=np.full((n_persons, N_JOINTS), 2, dtype=np.uint8),
        contributors=np.ones((n_persons, len(sensors)), dtype=bool),
        sensor_ids=sensors,
    )


# ---------------------------------------------------------------------------------------------------------
# Round trips


@given(frame=sensor_frames())
def test_sensor_frame_round_trip(frame: SensorFrame) -> None:
    payload = codec.encode_sensor_frame(frame)
    assert len(payload) == (
        codec.SENSOR_HEADER_SIZE + frame.n_bodies * codec.SENSOR_BYTES_PER_BODY + 2 + len(frame.sensor_id.encode())
    )
    assert_sensor_equal(codec.decode_sensor_frame(payload), frame)


@given(frame=fused_frames())
def test_fused_frame_round_trip(frame: FusedFrame) -> None:
    payload = codec.encode_fused_frame(frame)
    table = sum(2 + len(s.encode()) for s in frame.sensor_ids)
    assert len(payload) == (
        codec.FUSED_HEADER_SIZE
        + frame.n_persons * codec.FUSED_BYTES_PER_PERSON
        + frame.n_persons * len(frame.sensor_ids)
        + table
    )
    assert_fused_equal(codec.decode_fused_frame(payload), frame)


@given(status=statuses)
def test_status_round_trip(status: NodeStatus) -> None:
    assert codec.decode_status(codec.encode_status(status)) == status


def test_decode_dispatches_on_kind_and_accepts_any_buffer() -> None:
    sensor, fused = make_sensor_frame(), make_fused_frame()
    status = NodeStatus("fusion", "fusion", "running", 5, {"frames_out": 3}, {"fps": 29.97})
    payload = codec.encode_sensor_frame(sensor)
    for data in (payload, bytearray(payload), memoryview(payload), memoryview(b"xx" + payload)[2:]):
        assert_sensor_equal(codec.decode_sensor_frame(data), sensor)
    assert_sensor_equal(codec.decode(payload), sensor)  # type: ignore[arg-type]
    assert_fused_equal(codec.decode(codec.encode_fused_frame(fused)), fused)  # type: ignore[arg-type]
    assert codec.decode(codec.encode_status(status)) == status
    assert codec.peek_kind(payload) is codec.MessageKind.SENSOR_FRAME


def test_decoded_arrays_are_owned_and_writable() -> None:
    buffer = bytearray(codec.encode_sensor_frame(make_sensor_frame()))
    frame = codec.decode_sensor_frame(memoryview(buffer))
    before = frame.positions.copy()
    buffer[:] = bytes(len(buffer))  # the transport reuses its buffer
    np.testing.assert_array_equal(frame.positions, before)
    frame.positions[0, 0, 0] = 1.0  # writable, as if built in memory
    assert frame.confidence.flags.writeable


def test_frames_with_no_bodies_and_no_sensors() -> None:
    empty = make_sensor_frame(0)
    assert_sensor_equal(codec.decode_sensor_frame(codec.encode_sensor_frame(empty)), empty)
    nobody = make_fused_frame(0, ())
    assert_fused_equal(codec.decode_fused_frame(codec.encode_fused_frame(nobody)), nobody)


def test_encoder_converts_compatible_dtypes() -> None:
    frame = make_sensor_frame()
    loose = SensorFrame(
        frame.sensor_id,
        frame.sequence,
        frame.device_time_us,
        frame.host_time_ns,
        frame.body_ids.astype(np.int64),
        frame.positions.astype(np.float64),
        frame.orientations.astype(np.float64),
        frame.confidence.astype(np.int32),
    )
    assert codec.encode_sensor_frame(loose) == codec.encode_sensor_frame(frame)


# ---------------------------------------------------------------------------------------------------------
# The documented layout (docs/wire-format.md)


def test_sensor_frame_layout_matches_the_doc() -> None:
    frame = make_sensor_frame(2, "AB")
    payload = codec.encode_sensor_frame(frame)
    assert payload[0:4] == b"SKLF"
    assert struct.unpack_from("<BBBBHHHH", payload, 4) == (1, 0, 1, 0, 40, 32, 2, 0)
    assert struct.unpack_from("<Qqq", payload, 16) == (41, 1_000_000, 1_700_000_000_000_000_000)
    assert struct.unpack_from("<2I", payload, 40) == (1, 2)
    assert struct.unpack_from("<3f", payload, 48) == tuple(frame.positions[0, 0].tolist())
    orientations_at = 48 + 2 * 32 * 3 * 4
    assert struct.unpack_from("<4f", payload, orientations_at) == tuple(frame.orientations[0, 0].tolist())
    confidence_at = orientations_at + 2 * 32 * 4 * 4
    assert payload[confidence_at : confidence_at + 64] == bytes([2]) * 64
    assert payload[confidence_at + 64 :] == b"\x02\x00AB"


def test_fused_frame_layout_matches_the_doc() -> None:
    frame = make_fused_frame(2, ("A1", "B22"))
    payload = codec.encode_fused_frame(frame)
    table = b"\x02\x00A1\x03\x00B22"
    assert payload[0:4] == b"SKLF"
    assert struct.unpack_from("<BBBBHHHHqII", payload, 4) == (1, 0, 2, 0, 32, 32, 2, 2, 1_000_000, len(table), 0)
    assert struct.unpack_from("<2q", payload, 32) == (7, 8)
    pelvis = struct.unpack_from("<3d", payload, 48)
    assert pelvis == tuple(frame.positions[0, 0].tolist())
    assert all(math.isnan(v) for v in struct.unpack_from("<3d", payload, 48 + 9 * 24))  # joint 9: missing
    n_agree_at = 48 + 2 * 32 * 24
    assert struct.unpack_from("<64h", payload, n_agree_at) == (2,) * 64
    confidence_at = n_agree_at + 2 * 64
    contributors_at = confidence_at + 64
    assert payload[contributors_at : contributors_at + 4] == b"\x01\x01\x01\x01"
    assert payload[contributors_at + 4 :] == table


def test_doc_lists_every_reject_reason_and_the_worked_example() -> None:
    text = (ROOT / "docs" / "wire-format.md").read_text(encoding="utf-8")
    doc = "\n".join(line.strip() for line in text.splitlines())  # hex blocks sit indented in list items
    for reason in codec.REJECT_REASONS:
        assert f"`{reason}`" in doc, reason
    # The worked example's header dump is the encoding of the frame the doc describes.
    payload = codec.encode_fused_frame(worked_example_frame())
    assert _hex_lines(payload[:32]) in doc  # header
    assert _hex_lines(payload[40:64]) in doc  # pelvis position
    assert _hex_lines(payload[40 + 9 * 24 : 40 + 10 * 24]) in doc  # HANDTIP_LEFT: NaN
    assert _hex_lines(payload[904:]) in doc  # contributors and sensor id table


def worked_example_frame() -> FusedFrame:
    """The frame of docs/wire-format.md's worked example: one person, track 7, two sensors."""
    positions = np.zeros((1, N_JOINTS, 3))
    positions[0, 0] = (250.0, -1200.5, 950.0)  # pelvis
    positions[0, 1:] = positions[0, 0] + np.arange(1, N_JOINTS)[:, None] * (0.0, 0.0, 10.0)
    positions[0, 9] = np.nan  # HANDTIP_LEFT: no estimate
    n_agree = np.full((1, N_JOINTS), 2, dtype=np.int16)
    n_agree[0, 9] = 0
    confidence = np.full((1, N_JOINTS), 2, dtype=np.uint8)
    confidence[0, 9] = 0
    return FusedFrame(
        time_us=1_234_567,
        track_ids=np.array([7]),
        positions=positions,
        n_agree=n_agree,
        confidence=confidence,
        contributors=np.array([[True, True]]),
        sensor_ids=("000123", "000456"),
    )


def _hex_lines(data: bytes) -> str:
    return "\n".join(data[i : i + 16].hex(" ") for i in range(0, len(data), 16))


# ---------------------------------------------------------------------------------------------------------
# Rejects: each reason from a targeted corruption of a valid payload


def _patch(payload: bytes, fmt: str, offset: int, *values: Any) -> bytes:
    out = bytearray(payload)
    struct.pack_into(fmt, out, offset, *values)
    return bytes(out)


SENSOR = codec.encode_sensor_frame(make_sensor_frame(2, "AB"))
FUSED = codec.encode_fused_frame(make_fused_frame(2, ("A1", "B2")))
STATUS = codec.encode_status(NodeStatus("fusion", "fusion", "running", 5))
SENSOR_CONFIDENCE_AT = 40 + 2 * 4 + 2 * 32 * 28
FUSED_N_AGREE_AT = 32 + 2 * 8 + 2 * 32 * 24
FUSED_CONTRIBUTORS_AT = FUSED_N_AGREE_AT + 2 * 32 * 3


def _status(doc: bytes) -> bytes:
    return STATUS[:12] + struct.pack("<I", len(doc)) + doc


REJECT_CASES = [
    # (decoder, payload, reason, fragment of the message)
    ("sensor", b"", "truncated", "0 bytes"),
    ("sensor", b"SKL", "truncated", "prefix"),
    ("sensor", SENSOR[:20], "truncated", "header"),
    ("sensor", SENSOR[:-1], "truncated", "sensor_id"),
    ("sensor", SENSOR[:500], "truncated", "500 bytes"),
    ("fused", FUSED[:-3], "truncated", "need"),
    ("sensor", b"GARBAGE!" * 8, "bad_magic", "b'GARB'"),
    ("sensor", _patch(SENSOR, "<B", 4, 2), "bad_version", "schema version 2.0, this reader supports major version 1"),
    ("fused", _patch(FUSED, "<BB", 4, 0, 9), "bad_version", "schema version 0.9"),
    ("sensor", _patch(SENSOR, "<B", 6, 9), "bad_kind", "unknown message kind 9"),
    ("sensor", FUSED, "bad_kind", "message kind 2 (fused frame), expected 1"),
    ("status", SENSOR, "bad_kind", "expected 3"),
    ("sensor", _patch(SENSOR, "<H", 8, 39), "bad_header", "header size 39"),
    ("fused", _patch(FUSED, "<H", 8, 40), "bad_header", "expected 32"),
    ("sensor", SENSOR + b"\x00", "bad_length", "exactly"),
    ("fused", _patch(FUSED, "<I", 24, 9) + b"\x00", "bad_length", "sensor id table"),
    ("sensor", _patch(SENSOR, "<H", 12, 65), "too_large", "65 bodies, at most 64"),
    ("fused", _patch(FUSED, "<H", 12, 1000), "too_large", "1000 persons"),
    ("fused", _patch(FUSED, "<H", 14, 65), "too_large", "65 sensors"),
    ("sensor", SENSOR[:-4] + b"\xff\x01AB", "too_large", "sensor_id is 511 bytes"),
    ("status", _patch(STATUS, "<I", 12, 10**6), "too_large", "bytes of JSON"),
    ("sensor", _patch(SENSOR, "<H", 10, 31), "bad_joint_count", "31 joints per skeleton, expected 32"),
    ("fused", _patch(FUSED, "<H", 10, 25), "bad_joint_count", "25 joints"),
    ("sensor", _patch(SENSOR, "<f", 48 + 4, math.nan), "non_finite", "NaN or Inf"),
    ("sensor", _patch(SENSOR, "<f", 48 + 2 * 32 * 12 + 8, math.inf), "non_finite", "orientations"),
    ("fused", _patch(FUSED, "<d", 48, math.inf), "non_finite", "Inf"),
    ("fused", _patch(FUSED, "<d", 48, math.nan), "non_finite", "some but not all"),
    ("sensor", _patch(SENSOR, "<B", SENSOR_CONFIDENCE_AT + 5, 4), "bad_confidence", "value 4"),
    ("fused", _patch(FUSED, "<B", FUSED_N_AGREE_AT + 128 + 3, 200), "bad_confidence", "value 200"),
    ("sensor", _patch(SENSOR, "<I", 44, 1), "bad_value", "body_ids hold duplicates"),
    ("sensor", SENSOR[:-4] + b"\x00\x00", "bad_value", "empty"),
    ("fused", _patch(FUSED, "<q", 40, 7), "bad_value", "track_ids hold duplicates"),
    ("fused", _patch(FUSED, "<h", FUSED_N_AGREE_AT, -1), "bad_value", "n_agree spans -1"),
    ("fused", _patch(FUSED, "<B", FUSED_CONTRIBUTORS_AT, 2), "bad_value", "contributors"),
    ("fused", FUSED[:-4] + b"\x02\x00A1", "bad_value", "sensor_ids hold duplicates"),
    ("sensor", SENSOR[:-2] + b"\xc3\x28", "bad_utf8", "sensor_id is not UTF-8"),
    ("fused", FUSED[:-1] + b"\xff", "bad_utf8", "sensor_ids[1]"),
    ("status", _status(b'{"node": "\xff"}'), "bad_utf8", "JSON is not UTF-8"),
    ("status", _status(b"{not json"), "bad_json", "Expecting"),
    ("status", _status(b"[1, 2]"), "bad_json", "expected a JSON object"),
    ("status", _status(b'{"node": "n", "role": "r", "state": "running"}'), "bad_json", "time_ns"),
    (
        "status",
        _status(b'{"node": "n", "role": "r", "state": "x", "time_ns": 1, "counters": {"a": -1}}'),
        "bad_json",
        "non-negative",
    ),
    (
        "status",
        _status(b'{"node": "n", "role": "r", "state": "x", "time_ns": 1, "info": {"v": NaN}}'),
        "bad_json",
        "NaN",
    ),
    ("status", _status(b"[" * 50_000), "bad_json", ""),
]
DECODERS = {"sensor": codec.decode_sensor_frame, "fused": codec.decode_fused_frame, "status": codec.decode_status}


@pytest.mark.parametrize(
    ("decoder", "payload", "reason", "fragment"),
    [pytest.param(*case, id=f"{case[0]}-{case[2]}-{i}") for i, case in enumerate(REJECT_CASES)],
)
def test_reject_reasons(decoder: str, payload: bytes, reason: str, fragment: str) -> None:
    with pytest.raises(DecodeError) as info:
        DECODERS[decoder](payload)
    assert info.value.reason == reason
    assert fragment in str(info.value)
    assert f"({reason})" in str(info.value)


def test_every_reject_reason_is_exercised() -> None:
    assert {case[2] for case in REJECT_CASES} == set(codec.REJECT_REASONS)


def test_decode_error_is_a_data_error_and_pickles() -> None:
    with pytest.raises(DataError) as info:
        codec.decode_sensor_frame(b"nope")
    clone = pickle.loads(pickle.dumps(info.value))
    assert (clone.reason, str(clone)) == (info.value.reason, str(info.value))  # type: ignore[attr-defined]


def test_non_buffer_input_is_a_type_error() -> None:
    with pytest.raises(TypeError, match="payload must be bytes-like, got str"):
        codec.decode_fused_frame("SKLF")  # type: ignore[arg-type]


def test_newer_minor_version_is_read_ignoring_additions() -> None:
    """A 1.1 writer may grow the header and append sections; a 1.0 reader skips both."""
    frame = make_sensor_frame(2, "AB")
    payload = codec.encode_sensor_frame(frame)
    newer = bytearray(payload[:40] + b"\xee" * 8 + payload[40:] + b"\xee" * 5)
    struct.pack_into("<B", newer, 5, 1)  # minor 1
    struct.pack_into("<H", newer, 8, 48)  # header size 48
    assert_sensor_equal(codec.decode_sensor_frame(bytes(newer)), frame)

    fused = make_fused_frame()
    payload = codec.encode_fused_frame(fused)
    newer = bytearray(payload[:32] + b"\xee" * 16 + payload[32:] + b"\xee" * 3)
    struct.pack_into("<B", newer, 5, 7)
    struct.pack_into("<H", newer, 8, 48)
    assert_fused_equal(codec.decode_fused_frame(bytes(newer)), fused)
    example = load_example()
    assert example.decode_fused(bytes(newer))["time_us"] == fused.time_us


# ---------------------------------------------------------------------------------------------------------
# Encoding refuses what decoding would reject


def _with(frame: Any, **changes: Any) -> Any:
    fields = {name: getattr(frame, name) for name in frame.__dataclass_fields__}
    return type(frame)(**{**fields, **changes})


@pytest.mark.parametrize(
    ("frame", "fragment"),
    [
        pytest.param(
            _with(make_sensor_frame(1), positions=np.full((1, 32, 3), np.nan, np.float32)),
            "NaN or Inf",
            id="nan-position",
        ),
        pytest.param(
            _with(make_sensor_frame(1), positions=np.full((1, 32, 3), 1e39)), "NaN or Inf", id="float32-overflow"
        ),
        pytest.param(_with(make_sensor_frame(1), confidence=np.full((1, 32), 5)), "value 5", id="confidence"),
        pytest.param(
            _with(make_sensor_frame(1), positions=np.zeros((1, 31, 3), np.float32)),
            "positions has shape (1, 31, 3), expected (1, 32, 3)",
            id="shape",
        ),
        pytest.param(_with(make_sensor_frame(1), body_ids=np.array([-1])), "body_ids spans -1..-1", id="neg-id"),
        pytest.param(_with(make_sensor_frame(1), sensor_id=""), "sensor_id is empty", id="empty-id"),
        pytest.param(_with(make_sensor_frame(1), sequence=-1), "sequence = -1", id="sequence"),
        pytest.param(make_sensor_frame(65), "65 bodies, at most 64", id="too-many-bodies"),
        pytest.param(
            _with(make_fused_frame(1), contributors=np.ones((1, 2), bool)),
            "contributors (P, S) has shape (1, 2), expected (1, 3)",
            id="contributors-shape",
        ),
        pytest.param(_with(make_fused_frame(1), positions=np.full((1, 32, 3), np.inf)), "Inf", id="inf"),
        pytest.param(_with(make_fused_frame(1), n_agree=np.full((1, 32), 65)), "n_agree spans", id="n-agree"),
        pytest.param(_with(make_fused_frame(2), track_ids=np.array([3, 3])), "duplicates", id="dup-tracks"),
        pytest.param(make_fused_frame(1, ("A", "A")), "sensor_ids hold duplicates", id="dup-sensors"),
        pytest.param(
            _with(make_fused_frame(1), positions=np.zeros((1, 32, 3), np.float32).astype(int)),
            "expected a float array",
            id="int-positions",
        ),
    ],
)
def test_encode_refuses_invalid_frames(frame: Any, fragment: str) -> None:
    encode = codec.encode_sensor_frame if isinstance(frame, SensorFrame) else codec.encode_fused_frame
    with pytest.raises(ValueError) as info:
        encode(frame)
    assert fragment in str(info.value)


def test_encode_status_refuses_unknown_state_and_non_json() -> None:
    with pytest.raises(ValueError, match="state 'busy' is not one of"):
        codec.encode_status(NodeStatus("n", "fusion", "busy", 1))
    with pytest.raises(ValueError, match="info is not JSON"):
        codec.encode_status(NodeStatus("n", "fusion", "running", 1, info={"fps": math.nan}))
    with pytest.raises(ValueError, match="counter 'x' must be a non-negative integer"):
        codec.encode_status(NodeStatus("n", "fusion", "running", 1, counters={"x": 1.5}))  # type: ignore[dict-item]


# ---------------------------------------------------------------------------------------------------------
# Fuzzing: arbitrary bytes never raise anything but DecodeError


def _decode_all(data: bytes) -> None:
    for decode in (codec.decode_sensor_frame, codec.decode_fused_frame, codec.decode_status, codec.decode):
        try:
            decode(data)
        except DecodeError as exc:
            assert exc.reason in codec.REJECT_REASONS


VALID_PREFIXES = [SENSOR[:10], FUSED[:10], STATUS[:10], SENSOR[:40], FUSED[:32]]
FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FUZZ
@given(data=st.binary(max_size=3000))
def test_fuzz_random_bytes(data: bytes) -> None:
    _decode_all(data)


@FUZZ
@given(prefix=st.sampled_from(VALID_PREFIXES), tail=st.binary(max_size=3000))
def test_fuzz_valid_prefix_random_tail(prefix: bytes, tail: bytes) -> None:
    _decode_all(prefix + tail)


@FUZZ
@given(
    payload=st.sampled_from([SENSOR, FUSED, STATUS]),
    flips=st.lists(st.integers(0, 8 * len(FUSED)), min_size=1, max_size=4),
)
def test_fuzz_bit_flips(payload: bytes, flips: list[int]) -> None:
    data = bytearray(payload)
    for bit in flips:
        data[(bit // 8) % len(data)] ^= 1 << (bit % 8)
    _decode_all(bytes(data))


def test_every_truncation_is_rejected() -> None:
    for payload, decode in (
        (SENSOR, codec.decode_sensor_frame),
        (FUSED, codec.decode_fused_frame),
        (STATUS, codec.decode_status),
    ):
        for end in range(len(payload)):
            with pytest.raises(DecodeError) as info:
                decode(payload[:end])
            assert info.value.reason == "truncated", end


# ---------------------------------------------------------------------------------------------------------
# The standard-library example decoder agrees with the codec


@functools.cache
def load_example() -> ModuleType:
    """The example script as a module, loaded from its path (it is not part of the package)."""
    path = ROOT / "scripts" / "example_subscriber.py"
    spec = importlib.util.spec_from_file_location("skelfuse_example_subscriber", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules.pop(spec.name, None)
    spec.loader.exec_module(module)
    return module


def test_example_uses_only_zenoh_and_the_standard_library() -> None:
    tree = ast.parse((ROOT / "scripts" / "example_subscriber.py").read_text(encoding="utf-8"))
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            imported.add(node.module.split(".")[0])
    assert imported - {"zenoh"} <= set(sys.stdlib_module_names), imported
    top_level = {alias.name for node in tree.body if isinstance(node, ast.Import) for alias in node.names}
    assert "zenoh" not in top_level  # imported lazily inside main()


@settings(max_examples=60, deadline=None)
@given(frame=fused_frames())
def test_example_decoder_agrees_with_codec(frame: FusedFrame) -> None:
    example = load_example()
    payload = codec.encode_fused_frame(frame)
    ours = codec.decode_fused_frame(payload)
    theirs = example.decode_fused(payload)
    assert theirs["version"] == (codec.VERSION_MAJOR, codec.VERSION_MINOR)
    assert theirs["time_us"] == ours.time_us
    assert tuple(theirs["sensor_ids"]) == ours.sensor_ids
    assert [p["track_id"] for p in theirs["persons"]] == ours.track_ids.tolist()
    for p, person in enumerate(theirs["persons"]):
        np.testing.assert_array_equal(
            np.array(person["positions"], dtype=np.float64).reshape(N_JOINTS, 3), ours.positions[p]
        )
        assert person["n_agree"] == ours.n_agree[p].tolist()
        assert person["confidence"] == ours.confidence[p].tolist()
        contributed = [s for s, on in zip(ours.sensor_ids, ours.contributors[p], strict=True) if on]
        assert person["contributors"] == contributed


def test_example_decoder_rejects_other_versions_and_kinds() -> None:
    example = load_example()
    with pytest.raises(example.PayloadError, match=r"schema version 2\.0"):
        example.decode_fused(_patch(FUSED, "<B", 4, 2))
    with pytest.raises(example.PayloadError, match="message kind 1"):
        example.decode_fused(SENSOR)
    line = example.describe(example.decode_fused(codec.encode_fused_frame(worked_example_frame())))
    assert line == "t=1.235s persons=1 | track 7: pelvis (250, -1200, 950) mm"


@pytest.mark.live
def test_example_subscriber_receives_over_zenoh(capsys: pytest.CaptureFixture[str]) -> None:
    """Two peers on loopback, multicast scouting off: the example prints what a publisher sends."""
    import zenoh

    with socket.socket() as probe:  # a free port for the subscriber to listen on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    endpoint = f"tcp/127.0.0.1:{port}"
    example = load_example()
    exit_codes: list[int] = []
    argv = ["--rig", "testrig", "--listen", endpoint, "--no-scouting", "--max-messages", "2", "--duration", "60"]
    runner = threading.Thread(target=lambda: exit_codes.append(example.main(argv)))
    runner.start()
    config = zenoh.Config()
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    payload = codec.encode_fused_frame(worked_example_frame())
    with zenoh.open(config) as session:
        publisher = session.declare_publisher(keys.fused_skeletons("testrig"))
        wait_for_subscriber(publisher, "the example's subscription")
        publisher.put(payload)
        publisher.put(payload)
        runner.join(timeout=60)
    assert exit_codes == [0]
    lines = capsys.readouterr().out.splitlines()
    assert lines[:2] == ["t=1.235s persons=1 | track 7: pelvis (250, -1200, 950) mm"] * 2
