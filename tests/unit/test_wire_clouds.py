"""The person-cloud payload: round trip within the quantum, the byte layout docs/wire-format.md states, every
rejection, and the sizes the simulator's people make."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from skelfuse.fusion.camera import Intrinsics
from skelfuse.fusion.depth.cloud import person_clouds
from skelfuse.sim.depth import render_rig
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.rig import paper_rig
from skelfuse.wire import keys
from skelfuse.wire.clouds import (
    BODY_HEADER_SIZE,
    CLOUDS_HEADER_SIZE,
    PersonCloudsFrame,
    decode_person_clouds,
    encode_person_clouds,
    payload_size,
)
from skelfuse.wire.codec import DecodeError


def _frame(ir: bool = True) -> PersonCloudsFrame:
    rng = np.random.default_rng(1)
    near = rng.uniform(-400, 400, (500, 3)) + np.array([0.0, 0.0, 2200.0])
    far = rng.uniform(-300, 300, (20, 3)) + np.array([800.0, 0.0, 3000.0])
    clouds = (near, far)
    return PersonCloudsFrame(
        "000123412512",
        7,
        1_000_033,
        1_700_000_000_000_000_000,
        15.0,
        np.array([3, 9], np.uint32),
        clouds,
        (rng.uniform(0, 4000, 500), rng.uniform(0, 4000, 20)) if ir else None,
    )


@pytest.mark.parametrize("ir", [True, False])
def test_round_trip_within_half_a_quantum(ir: bool) -> None:
    frame = _frame(ir)
    data = encode_person_clouds(frame)
    assert len(data) == payload_size([500, 20], ir=ir, sensor_id_bytes=12)
    back = decode_person_clouds(data)
    assert (back.sensor_id, back.sequence, back.device_timestamp_us, back.host_timestamp_ns) == (
        frame.sensor_id,
        frame.sequence,
        frame.device_timestamp_us,
        frame.host_timestamp_ns,
    )
    assert back.voxel_mm == 15.0 and back.body_ids.tolist() == [3, 9]
    for sent, got in zip(frame.clouds, back.clouds, strict=True):
        assert np.abs(got - sent).max() <= 0.5 + 1e-3  # 1 mm quantum, float32 origin
    if ir:
        for sent, got in zip(frame.ir, back.ir, strict=True):
            np.testing.assert_array_equal(got, np.rint(sent))
    else:
        assert back.ir is None


def test_byte_layout_as_documented() -> None:
    points = np.array([[10.0, -20.0, 1500.0], [13.0, -18.0, 1502.0]])
    data = encode_person_clouds(
        PersonCloudsFrame("s1", 2, 3, 4, 15.0, np.array([5]), (points,), (np.array([100.0, 200.0]),))
    )
    assert data[:10] == b"SKLF" + bytes([1, 0, 4, 1]) + struct.pack("<H", CLOUDS_HEADER_SIZE)
    assert struct.unpack_from("<HHQqqff", data, 10) == (1, 0, 2, 3, 4, 15.0, 1.0)
    assert struct.unpack_from("<IIfff", data, CLOUDS_HEADER_SIZE) == (5, 2, 10.0, -20.0, 1500.0)
    offset = CLOUDS_HEADER_SIZE + BODY_HEADER_SIZE
    assert struct.unpack_from("<6H", data, offset) == (0, 0, 0, 3, 2, 2)
    assert struct.unpack_from("<2H", data, offset + 12) == (100, 200)
    assert data[offset + 16 :] == struct.pack("<H", 2) + b"s1"


def test_every_truncation_and_corruption_is_rejected_with_a_reason() -> None:
    data = encode_person_clouds(_frame())
    for cut in (0, 3, 9, 20, CLOUDS_HEADER_SIZE + 5, len(data) // 2, len(data) - 1):
        with pytest.raises(DecodeError) as error:
            decode_person_clouds(data[:cut])
        assert error.value.reason == "truncated", cut
    cases = {
        "bad_magic": b"XKLF" + data[4:],
        "bad_version": data[:4] + bytes([2]) + data[5:],
        "bad_kind": data[:6] + bytes([1]) + data[7:],
        "bad_header": data[:8] + struct.pack("<H", 40) + data[10:],
        "bad_length": data + b"\0",
        "too_large": data[:10] + struct.pack("<H", 65) + data[12:],
        "bad_value": data[:38] + struct.pack("<f", -1.0) + data[42:],
    }
    for reason, bad in cases.items():
        with pytest.raises(DecodeError) as error:
            decode_person_clouds(bad)
        assert error.value.reason == reason


def test_encoding_refuses_what_a_reader_would_reject() -> None:
    frame = _frame()
    with pytest.raises(ValueError, match="distinct"):
        encode_person_clouds(PersonCloudsFrame("s", 0, 0, 0, 15.0, np.array([1, 1]), frame.clouds))
    with pytest.raises(ValueError, match="finite"):
        encode_person_clouds(PersonCloudsFrame("s", 0, 0, 0, 15.0, np.array([1]), (np.array([[np.nan, 0, 0]]),)))
    with pytest.raises(ValueError, match="raise quantum_mm"):
        encode_person_clouds(
            PersonCloudsFrame("s", 0, 0, 0, 15.0, np.array([1]), (np.array([[0, 0, 0], [70000.0, 0, 0]]),))
        )


def test_the_key_and_the_sizes_of_simulated_people() -> None:
    assert keys.sensor_clouds("lab", "000123") == "skelfuse/lab/sensors/000123/clouds"
    assert keys.all_sensor_clouds("lab") == "skelfuse/lab/sensors/*/clouds"
    # One person 2.2 m from a sensor at 15 mm voxels: a few thousand points, tens of kB per frame.
    truth = make_gesture("hands_up_down", duration_s=1.0).positions[10][None]
    (frame,) = render_rig(paper_rig()[:1], truth)
    intrinsics = Intrinsics.azure_kinect_nfov()
    (cloud,) = person_clouds(frame.depth, frame.body_index, intrinsics, voxel_mm=15.0)
    data = encode_person_clouds(PersonCloudsFrame("capture_0", 0, 0, 0, 15.0, np.array([1]), (cloud.points,)))
    assert 1000 < len(cloud.points) < 6000
    assert len(data) == payload_size([len(cloud.points)], ir=False, sensor_id_bytes=9) < 40_000


def test_the_codec_knows_the_person_clouds_kind() -> None:
    """MessageKind.PERSON_CLOUDS: peek_kind names it, the skeleton decoders refuse it by kind, decode() says
    which decoder reads it."""
    from skelfuse.wire.clouds import CLOUDS_HEADER_SIZE, PERSON_CLOUDS_KIND
    from skelfuse.wire.codec import PERSON_CLOUDS_HEADER_SIZE, MessageKind, decode, decode_sensor_frame, peek_kind

    payload = encode_person_clouds(
        PersonCloudsFrame("s", 1, 2, 3, 15.0, np.array([7], np.uint32), (np.full((3, 3), 500.0),))
    )
    assert peek_kind(payload) == MessageKind.PERSON_CLOUDS == PERSON_CLOUDS_KIND
    assert CLOUDS_HEADER_SIZE == PERSON_CLOUDS_HEADER_SIZE
    with pytest.raises(DecodeError, match="message kind 4 \\(person-clouds\\), expected 1") as refused:
        decode_sensor_frame(payload)
    assert refused.value.reason == "bad_kind"
    with pytest.raises(DecodeError, match="decode_person_clouds"):
        decode(payload)
