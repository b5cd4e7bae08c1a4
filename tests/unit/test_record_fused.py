"""``[record] fused``: the fused stream recorded beside the sensor channels, and read back as FusedFrame.

The file is checked with the ``mcap`` library's own reader (an independent implementation of the container),
not only with ours: the fused channel's topic is the fused key expression and its messages are the payload
bytes as given.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest
import zenoh
from mcap.reader import make_reader

from skelfuse.config import parse_rig_config
from skelfuse.recording import RecordingReader, RecordingWriter, mcap_io
from skelfuse.schema.frames import FusedFrame, SensorFrame
from skelfuse.schema.skeleton import N_JOINTS
from skelfuse.service.lifecycle import Lifecycle, RunLimits
from skelfuse.service.recorder import RecordReport, run_recorder
from skelfuse.service.zenoh_io import free_port, loopback_config
from skelfuse.wire import keys
from skelfuse.wire.codec import DecodeError, encode_fused_frame, encode_sensor_frame
from waiting import wait_for_subscriber, wait_until

RIG = "lab"
SENSORS = ("000111", "000222")
T0_NS = 1_700_000_000_000_000_000


def sensor_frame(sensor: int, i: int) -> SensorFrame:
    rng = np.random.default_rng([sensor, i])
    return SensorFrame(
        sensor_id=SENSORS[sensor],
        sequence=i,
        device_time_us=1_000_000 + 33_333 * i,
        host_time_ns=T0_NS + 33_333_333 * i + sensor * 1000,
        body_ids=np.array([1], np.uint32),
        positions=rng.normal(0, 800, (1, N_JOINTS, 3)).astype(np.float32),
        orientations=rng.normal(0, 1, (1, N_JOINTS, 4)).astype(np.float32),
        confidence=np.full((1, N_JOINTS), 2, np.uint8),
    )


def fused_frame(i: int, persons: int = 2) -> FusedFrame:
    rng = np.random.default_rng([99, i])
    positions = rng.normal(0, 1000, (persons, N_JOINTS, 3))
    if persons:
        positions[0, 9] = np.nan  # a joint without an estimate
    return FusedFrame(
        time_us=1_000_000 + 33_333 * i,
        track_ids=np.arange(1, persons + 1, dtype=np.int64) + i % 2,
        positions=positions,
        n_agree=rng.integers(0, 3, (persons, N_JOINTS)).astype(np.int16),
        confidence=rng.integers(0, 3, (persons, N_JOINTS)).astype(np.uint8),
        contributors=rng.integers(0, 2, (persons, len(SENSORS))).astype(bool),
        sensor_ids=SENSORS,
    )


def write_take(path: Path, n: int, *, close: bool = True) -> tuple[list[bytes], RecordingWriter]:
    """Sensor frames of both sensors and one fused frame per instant, as a recorder interleaves them."""
    payloads = []
    writer = RecordingWriter(path, rig=RIG, sensor_ids=SENSORS, flush_interval_s=None)
    for i in range(n):
        for s in range(len(SENSORS)):
            writer.write_payload(encode_sensor_frame(sensor_frame(s, i)))
        payload = encode_fused_frame(fused_frame(i, persons=i % 3))
        payloads.append(payload)
        writer.write_fused_payload(payload, log_time_ns=T0_NS + 33_333_333 * i + 5_000_000)
        if i == n // 2:
            writer.flush()
    if close:
        writer.close()
    return payloads, writer


def test_fused_channel_beside_the_sensor_channels_read_by_the_mcap_library(tmp_path: Path) -> None:
    path = tmp_path / "take.mcap"
    payloads, writer = write_take(path, 12)
    assert writer.fused_frames_written == 12 and writer.frames_written == 24

    with open(path, "rb") as f:
        reader = make_reader(f)
        topics: dict[str, list[bytes]] = {}
        encodings = {}
        schemas = {}
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            topics.setdefault(channel.topic, []).append(bytes(message.data))
            encodings[channel.topic] = channel.message_encoding
            schemas[channel.topic] = schema.name
    fused_topic = keys.fused_skeletons(RIG)
    assert set(topics) == {keys.sensor_skeletons(RIG, s) for s in SENSORS} | {fused_topic}
    assert topics[fused_topic] == payloads  # byte for byte, in order
    assert encodings[fused_topic] == mcap_io.FUSED_MESSAGE_ENCODING
    assert schemas[fused_topic] == mcap_io.FUSED_SCHEMA_NAME


def test_reader_yields_the_fused_frames_and_keeps_sensor_reads_unchanged(tmp_path: Path) -> None:
    path = tmp_path / "take.mcap"
    payloads, _ = write_take(path, 9)
    rec = RecordingReader(path)
    assert rec.fused_topic == keys.fused_skeletons(RIG)
    assert rec.sensors == SENSORS  # the fused channel is not a sensor
    assert rec.fused_message_count == 9 and rec.message_count == 27
    records = list(rec.fused_records())
    assert [r.payload for r in records] == payloads
    for i, r in enumerate(records):
        expected = fused_frame(i, persons=i % 3)
        assert r.log_time_ns == T0_NS + 33_333_333 * i + 5_000_000
        assert r.publish_time_ns == expected.time_us * 1000
        assert r.frame.time_us == expected.time_us
        np.testing.assert_array_equal(r.frame.track_ids, expected.track_ids)
        np.testing.assert_array_equal(r.frame.positions, expected.positions)  # NaN where NaN
        np.testing.assert_array_equal(r.frame.n_agree, expected.n_agree)
        np.testing.assert_array_equal(r.frame.contributors, expected.contributors)
    assert len(list(rec.frames())) == 18
    # time window: half-open on log time
    window = list(rec.fused_frames(T0_NS + 33_333_333 * 3, T0_NS + 33_333_333 * 6))
    assert [f.time_us for f in window] == [fused_frame(i).time_us for i in (3, 4, 5)]


def test_fused_frames_survive_a_killed_recorder(tmp_path: Path) -> None:
    """No footer (the process died after a flush): the streaming fallback still yields the flushed fused frames."""
    path = tmp_path / "cut.mcap"
    payloads, writer = write_take(path, 10, close=False)
    writer._stream.flush()  # what the OS holds when the process dies: chunks up to the last flush
    size_at_flush = path.stat().st_size
    rec = RecordingReader(path)
    assert not rec.indexed and rec.truncated and size_at_flush > 0
    got = [r.payload for r in rec.fused_records()]
    assert got == payloads[: len(got)] and len(got) == 6  # instants 0..5 were flushed at i == 5
    writer.close()


def test_a_bad_fused_payload_is_refused_and_a_file_without_fused_channel_yields_none(tmp_path: Path) -> None:
    path = tmp_path / "plain.mcap"
    with RecordingWriter(path, rig=RIG, sensor_ids=SENSORS) as writer:
        writer.write(sensor_frame(0, 0))
        with pytest.raises(DecodeError):
            writer.write_fused_payload(b"SKLF\x01\x00\x02garbage", log_time_ns=T0_NS)
        with pytest.raises(DecodeError):  # a sensor frame is not a fused frame
            writer.write_fused_payload(encode_sensor_frame(sensor_frame(0, 1)), log_time_ns=T0_NS)
        assert writer.fused_frames_written == 0
    rec = RecordingReader(path)
    assert rec.fused_topic is None
    assert list(rec.fused_frames()) == []


@pytest.mark.parametrize("record_fused", [True, False], ids=["fused on", "fused off"])
@pytest.mark.live
def test_recorder_records_the_fused_key_as_configured_and_rejects_bad_payloads(
    tmp_path: Path, record_fused: bool
) -> None:
    """run_recorder in-process on a real zenoh loopback session: `[record] fused` decides whether the fused key is
    recorded; a bad payload on it is counted by reason and the recorder goes on."""
    port = free_port()
    cfg = parse_rig_config(
        {
            "rig": {"name": RIG},
            "sensors": [{"id": s, "source": "sim", "world_from_sensor": np.eye(4).tolist()} for s in SENSORS],
            "record": {"fused": record_fused, "flush_period_s": 0.2},
        }
    )
    lifecycle = Lifecycle("recorder-test")
    output = tmp_path / "rec.mcap"
    result: dict[str, RecordReport] = {}

    def run() -> None:
        result["report"] = run_recorder(
            cfg, loopback_config(listen_port=port), output=output, limits=RunLimits(duration_s=60), lifecycle=lifecycle
        )

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    session = zenoh.open(loopback_config(connect_ports=[port]))
    try:
        wait_until(
            lambda: any(
                getattr(r, "ok", None) is not None
                for r in session.liveliness().get(keys.alive(RIG, "recorder"), timeout=0.5)
            ),
            "the recorder's liveliness token",
        )
        fused_pub = session.declare_publisher(keys.fused_skeletons(RIG))
        sensor_pub = session.declare_publisher(keys.sensor_skeletons(RIG, SENSORS[0]))
        wait_for_subscriber(sensor_pub, "the recorder's subscription")
        if record_fused:
            wait_for_subscriber(fused_pub, "the recorder's fused subscription")
        good = [encode_fused_frame(fused_frame(i)) for i in range(3)]
        fused_pub.put(good[0])
        fused_pub.put(b"SKLF garbage")
        fused_pub.put(good[1])
        sensor_pub.put(encode_sensor_frame(sensor_frame(0, 0)))
        fused_pub.put(good[2])

        def recorded() -> bool:  # flushed every 0.2 s: read back what the file holds so far
            if not output.exists():
                return False
            rec = RecordingReader(output)
            return len(list(rec.frames())) == 1 and (not record_fused or len(list(rec.fused_frames())) == 3)

        wait_until(recorded, "the sensor frame (and the 3 good fused frames) in the recording")
    finally:
        lifecycle.request_exit()
        thread.join(15)
        session.close()
    assert not thread.is_alive()
    report = result["report"]
    rec = RecordingReader(output)
    assert report.frames_written == 1 and len(list(rec.frames())) == 1
    if record_fused:
        assert report.fused_frames_written == 3 and sum(report.rejects.values()) == 1
        assert [r.payload for r in rec.fused_records()] == good
    else:
        assert report.fused_frames_written == 0 and not report.rejects
        assert rec.fused_topic is None
