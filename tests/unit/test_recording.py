"""Recording: MCAP write -> read round trips, index and time filters, crash (kill -9) recovery, corrupt and
wrong files, offline fusion of a synthetic recording, and replay pacing (the fused table: test_export_csv.py)."""

from __future__ import annotations

import json
import math
import os
import selectors
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

import skelfuse
from skelfuse.config import FusionConfig, RigConfig, SensorConfig
from skelfuse.fusion.orientation import aim_directions, quat_rotate
from skelfuse.fusion.transform import invert_transform, make_transform
from skelfuse.recording import (
    RecordingReader,
    RecordingWriter,
    fuse_recording,
    mcap_io,
    replay_frames,
)
from skelfuse.schema.errors import DataError
from skelfuse.schema.frames import SensorFrame
from skelfuse.schema.skeleton import N_JOINTS, ORIENTATION_AIMED
from skelfuse.wire import keys
from skelfuse.wire.codec import encode_sensor_frame

ROOT = Path(__file__).resolve().parents[2]
SEED = 20240612
RIG = "lab"
SENSORS = ("000111", "000222", "000333")
BIRTH_FRAMES = 3
"""PeopleFuser's default: instants a person must be seen before it is output."""
T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 33_333_333


def make_frame(
    sensor_idx: int, i: int, *, n_bodies: int = 1, positions: np.ndarray | None = None, seed: int = SEED
) -> SensorFrame:
    """Frame i of sensor ``SENSORS[sensor_idx]``: deterministic, host time ~30 fps, device time in us."""
    rng = np.random.default_rng([seed, sensor_idx, i])
    if positions is None:
        positions = rng.normal(0.0, 800.0, (n_bodies, N_JOINTS, 3))
    n = positions.shape[0]
    return SensorFrame(
        sensor_id=SENSORS[sensor_idx],
        sequence=i,
        device_time_us=5_000_000 + i * 33_333 + sensor_idx * 160,
        host_time_ns=T0_NS + i * PERIOD_NS + sensor_idx * 1_000_000 + int(rng.integers(0, 500_000)),
        body_ids=np.arange(1, n + 1, dtype=np.uint32),
        positions=np.asarray(positions, dtype=np.float32),
        orientations=rng.normal(0.0, 1.0, (n, N_JOINTS, 4)).astype(np.float32),
        confidence=np.full((n, N_JOINTS), 2, dtype=np.uint8),
    )


def frames_of(n_frames: int, n_sensors: int = 3) -> list[SensorFrame]:
    """Frames of several sensors in capture order (each sensor in turn)."""
    return [make_frame(s, i, n_bodies=(i + s) % 3) for i in range(n_frames) for s in range(n_sensors)]


def assert_same_frame(a: SensorFrame, b: SensorFrame) -> None:
    assert encode_sensor_frame(a) == encode_sensor_frame(b)


# ---------------------------------------------------------------------------------------------------------
# Round trip, metadata, index


def test_round_trip_several_sensors_bit_identical(tmp_path: Path) -> None:
    path = tmp_path / "take.mcap"
    frames = frames_of(60)
    poses = {sid: make_transform(np.eye(3), np.array([i * 1000.0, 0.0, 0.0])) for i, sid in enumerate(SENSORS)}
    with RecordingWriter(
        path,
        rig=RIG,
        sensor_ids=SENSORS,
        metadata={"operator": "ana", "take": 3},
        world_from_sensor=poses,
        chunk_size=8 * 1024,
    ) as writer:
        for frame in frames:
            writer.write(frame)
    reader = RecordingReader(path)
    assert reader.indexed and not reader.truncated
    assert reader.sensors == SENSORS
    assert reader.topics == {sid: keys.sensor_skeletons(RIG, sid) for sid in SENSORS}
    assert reader.message_count == len(frames)
    assert reader.metadata["rig"] == RIG
    assert reader.metadata["skelfuse_version"] == skelfuse.__version__
    assert reader.metadata["operator"] == "ana" and json.loads(reader.metadata["take"]) == 3
    assert json.loads(reader.metadata["sensor_ids"]) == list(SENSORS)
    assert int(reader.metadata["start_time_ns"]) > 0
    assert reader.calibration is not None
    for sid in SENSORS:
        np.testing.assert_array_equal(reader.calibration[sid], poses[sid])

    records = list(reader.records())
    expected = sorted(frames, key=lambda f: f.host_time_ns)
    assert [r.log_time_ns for r in records] == [f.host_time_ns for f in expected]
    for record, frame in zip(records, expected, strict=True):
        assert record.payload == encode_sensor_frame(frame)  # bit-identical: a replay republishes these bytes
        assert record.publish_time_ns == frame.device_time_us * 1000
        assert record.topic == keys.sensor_skeletons(RIG, frame.sensor_id)
        assert_same_frame(record.frame, frame)
    assert reader.time_range_ns == (expected[0].host_time_ns, expected[-1].host_time_ns)
    assert reader.rejects == {} and reader.bad_chunks == 0

    # The file is plain MCAP: mcap's own reader sees the channels, encoding, schema and log times.
    with open(path, "rb") as f:
        mcap_reader = make_reader(f)
        summary = mcap_reader.get_summary()
        assert summary is not None and len(summary.chunk_indexes) > 1
        messages = list(mcap_reader.iter_messages())
    assert len(messages) == len(frames)
    schema, channel, _ = messages[0]
    assert channel.message_encoding == mcap_io.MESSAGE_ENCODING
    assert schema is not None and "docs/wire-format.md" in schema.data.decode()


def test_write_payload_records_received_bytes(tmp_path: Path) -> None:
    path = tmp_path / "p.mcap"
    payloads = [encode_sensor_frame(make_frame(s, i)) for i in range(5) for s in range(2)]
    with RecordingWriter(path, rig=RIG) as writer:  # channels appear with the first frame of each sensor
        decoded = [writer.write_payload(p) for p in payloads]
        with pytest.raises(mcap_io.DecodeError):
            writer.write_payload(b"garbage")
    reader = RecordingReader(path)
    assert set(reader.sensors) == {SENSORS[0], SENSORS[1]}
    assert sorted(r.payload for r in reader.records()) == sorted(payloads)
    assert [f.sequence for f in decoded] == [i for i in range(5) for _ in range(2)]


def test_time_and_sensor_filters(tmp_path: Path) -> None:
    path = tmp_path / "f.mcap"
    frames = frames_of(90)
    with RecordingWriter(path, rig=RIG, sensor_ids=SENSORS, chunk_size=4 * 1024) as writer:
        for frame in frames:
            writer.write(frame)
    reader = RecordingReader(path)
    start, end = T0_NS + 30 * PERIOD_NS, T0_NS + 60 * PERIOD_NS
    got = list(reader.frames(start_ns=start, end_ns=end))
    expected = sorted((f for f in frames if start <= f.host_time_ns < end), key=lambda f: f.host_time_ns)
    assert len(got) == len(expected) > 0
    for a, b in zip(got, expected, strict=True):
        assert_same_frame(a, b)
    only = list(reader.frames(sensors=[SENSORS[1]], end_ns=end))
    assert {f.sensor_id for f in only} == {SENSORS[1]} and len(only) == 60
    assert list(reader.frames(sensors=["nope"])) == []
    assert list(reader.frames(start_ns=T0_NS + 10**12)) == []


def test_writer_rejects_bad_arguments(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="reserved"):
        RecordingWriter(tmp_path / "a.mcap", rig=RIG, metadata={"rig": "x"})
    with pytest.raises(ValueError, match="rig name"):
        RecordingWriter(tmp_path / "b.mcap", rig="a/b")
    with pytest.raises(ValueError, match="4x4"):
        RecordingWriter(tmp_path / "c.mcap", rig=RIG, world_from_sensor={"s": np.eye(3)})


# ---------------------------------------------------------------------------------------------------------
# Crash recovery: a recorder killed with SIGKILL leaves a file readable up to its last flushed chunk.

FLUSHED_BATCHES = 5
BATCH = 10


def _child_record(path: str) -> None:
    """Run in a subprocess: write flushed batches, then unflushed frames, then wait to be killed."""
    writer = RecordingWriter(path, rig=RIG, sensor_ids=SENSORS[:2], flush_interval_s=None)
    i = 0
    for _ in range(FLUSHED_BATCHES):
        for _ in range(BATCH):
            writer.write(make_frame(i % 2, i // 2))
            i += 1
        writer.flush()
    for _ in range(7):  # written into the open chunk, never flushed: lost with the process
        writer.write(make_frame(i % 2, i // 2))
        i += 1
    print("ready", flush=True)
    import time

    time.sleep(60)


@pytest.mark.skipif(sys.platform == "win32", reason="SIGKILL")
@pytest.mark.live
def test_kill_9_leaves_a_readable_file_up_to_the_last_flush(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    code = (
        "import importlib.util, sys\n"
        f"spec = importlib.util.spec_from_file_location('rec_test', {str(Path(__file__))!r})\n"
        "module = importlib.util.module_from_spec(spec); spec.loader.exec_module(module)\n"
        f"module._child_record({str(path)!r})\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    try:
        assert proc.stdout is not None
        selector = selectors.DefaultSelector()
        selector.register(proc.stdout, selectors.EVENT_READ)
        ready = selector.select(timeout=30)
        line = proc.stdout.readline() if ready else b""
        detail = proc.stderr.read() if proc.poll() is not None else b""
        assert line.strip() == b"ready", f"child did not get ready: {line!r} {detail!r}"
        os.kill(proc.pid, signal.SIGKILL)
        assert proc.wait(timeout=10) == -signal.SIGKILL
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        proc.stdout.close()
        proc.stderr.close()

    reader = RecordingReader(path)
    assert not reader.indexed and reader.truncated
    assert reader.sensors == SENSORS[:2]
    assert reader.metadata["rig"] == RIG
    got = list(reader.frames())
    n = FLUSHED_BATCHES * BATCH
    assert len(got) == n  # every flushed frame, none of the unflushed ones
    expected = sorted((make_frame(i % 2, i // 2) for i in range(n)), key=lambda f: f.host_time_ns)
    for a, b in zip(got, expected, strict=True):
        assert_same_frame(a, b)
    assert reader.rejects == {} and reader.bad_chunks == 0
    # Time filtering works on the scanned chunk list too.
    window = list(reader.frames(start_ns=expected[10].host_time_ns, end_ns=expected[20].host_time_ns))
    assert len(window) == 10


def test_file_cut_mid_chunk_reads_the_complete_chunks(tmp_path: Path) -> None:
    path = tmp_path / "cut.mcap"
    frames = frames_of(40)
    with RecordingWriter(path, rig=RIG, sensor_ids=SENSORS, chunk_size=6 * 1024) as writer:
        for frame in frames:
            writer.write(frame)
    with open(path, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    last = chunks[-1]
    cut = path.read_bytes()[: last.chunk_start_offset + last.chunk_length // 2]
    (tmp_path / "cut2.mcap").write_bytes(cut)
    reader = RecordingReader(tmp_path / "cut2.mcap")
    assert reader.truncated and not reader.indexed
    assert any("ends inside a record" in p for p in reader.problems)
    got = list(reader.frames())
    before = {(ci.message_start_time, ci.message_end_time) for ci in chunks[:-1]}
    assert 0 < len(got) < len(frames)
    assert all(any(s <= f.host_time_ns <= e for s, e in before) for f in got)


# ---------------------------------------------------------------------------------------------------------
# Corrupt and wrong files


def test_missing_and_non_mcap_files_raise_data_error(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="not found"):
        RecordingReader(tmp_path / "nope.mcap")
    (tmp_path / "text.mcap").write_text("time_us,x\n1,2\n")
    with pytest.raises(DataError, match="not an MCAP file"):
        RecordingReader(tmp_path / "text.mcap")
    (tmp_path / "empty.mcap").write_bytes(b"")
    with pytest.raises(DataError, match="not an MCAP file"):
        RecordingReader(tmp_path / "empty.mcap")
    with pytest.raises(DataError, match="not found"):
        fuse_recording(tmp_path / "nope.mcap")


def test_corrupt_messages_are_skipped_and_counted(tmp_path: Path) -> None:
    """A file written by another tool with the same layout, holding two bad payloads among good ones."""
    path = tmp_path / "bad.mcap"
    good = [make_frame(0, i) for i in range(4)]
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema(mcap_io.SCHEMA_NAME, mcap_io.SCHEMA_ENCODING, b"see docs/wire-format.md")
        channel = writer.register_channel(keys.sensor_skeletons(RIG, SENSORS[0]), mcap_io.MESSAGE_ENCODING, schema)
        payloads = [encode_sensor_frame(fr) for fr in good]
        bad = [b"NOPE" + payloads[0][4:], payloads[1][:50]]
        for t, data in enumerate([payloads[0], bad[0], payloads[1], bad[1], payloads[2], payloads[3]]):
            writer.add_message(channel, log_time=1000 + t, data=data, publish_time=0)
        writer.finish()
    reader = RecordingReader(path)
    got = list(reader.frames())
    assert len(got) == 4
    for a, b in zip(got, good, strict=True):
        assert_same_frame(a, b)
    assert reader.rejects == {"bad_magic": 1, "truncated": 1}
    assert len(reader.problems) == 2


def test_corrupt_chunk_is_skipped_others_read(tmp_path: Path) -> None:
    path = tmp_path / "c.mcap"
    frames = frames_of(60)
    with RecordingWriter(path, rig=RIG, sensor_ids=SENSORS, chunk_size=6 * 1024) as writer:
        for frame in frames:
            writer.write(frame)
    with open(path, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) >= 3
    victim = chunks[1]
    data = bytearray(path.read_bytes())
    middle = victim.chunk_start_offset + victim.chunk_length // 2
    data[middle : middle + 64] = bytes(64)
    path.write_bytes(bytes(data))
    reader = RecordingReader(path)
    got = list(reader.frames())
    assert reader.bad_chunks == 1
    assert 0 < len(got) < len(frames)
    assert not any(victim.message_start_time <= f.host_time_ns <= victim.message_end_time for f in got)


def test_damaged_footer_falls_back_to_scanning(tmp_path: Path) -> None:
    path = tmp_path / "footer.mcap"
    frames = frames_of(20)
    with RecordingWriter(path, rig=RIG, sensor_ids=SENSORS) as writer:
        for frame in frames:
            writer.write(frame)
    data = bytearray(path.read_bytes())
    data[-20:] = bytes(20)  # footer and closing magic gone
    path.write_bytes(bytes(data))
    reader = RecordingReader(path)
    assert not reader.indexed
    assert len(list(reader.frames())) == len(frames)


# ---------------------------------------------------------------------------------------------------------
# Offline fusion

NOISE_MM = 5.0


def truth_skeleton(i: int) -> np.ndarray:
    """(32, 3) world positions, mm, z up: a body standing 2 m in front of the origin, swaying slowly."""
    rng = np.random.default_rng(SEED)
    base = rng.uniform([-250, 1800, 0], [250, 2200, 1800], (N_JOINTS, 3))
    return base + np.array([100.0 * math.sin(i / 30.0), 0.0, 0.0])


def write_synthetic(
    path: Path,
    poses: dict[str, np.ndarray],
    n_frames: int,
    *,
    store_calibration: bool,
    drop: set[tuple[int, int]] = frozenset(),
) -> None:
    rng = np.random.default_rng(SEED + 1)
    with RecordingWriter(
        path, rig=RIG, sensor_ids=SENSORS, world_from_sensor=poses if store_calibration else None
    ) as writer:
        for i in range(n_frames):
            world = truth_skeleton(i)
            for s, sid in enumerate(SENSORS):
                if (s, i) in drop:
                    continue
                noisy = world + rng.normal(0.0, NOISE_MM, world.shape)
                sensor_from_world = invert_transform(poses[sid])
                local = noisy @ sensor_from_world[:3, :3].T + sensor_from_world[:3, 3]
                writer.write(make_frame(s, i, positions=local[None]))


def rig_poses() -> dict[str, np.ndarray]:
    def rot_z(deg: float) -> np.ndarray:
        a = math.radians(deg)
        return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1.0]])

    return {
        sid: make_transform(rot_z(120.0 * s), np.array([100.0 * s, -50.0 * s, 900.0])) for s, sid in enumerate(SENSORS)
    }


def test_fuse_recording_is_within_the_noise_of_the_truth(tmp_path: Path) -> None:
    path = tmp_path / "synthetic.mcap"
    poses = rig_poses()
    n_frames = 90
    write_synthetic(path, poses, n_frames, store_calibration=True)
    fused = list(fuse_recording(path, progress=False))  # poses from the recording's calibration metadata
    assert len(fused) == n_frames
    assert [f.time_us for f in fused] == [5_000_000 + i * 33_333 for i in range(n_frames)]
    errors = []
    born = BIRTH_FRAMES - 1  # a person is output once confirmed: from the third instant on
    for i, frame in enumerate(fused):
        assert frame.sensor_ids == SENSORS and frame.n_persons == (i >= born)
        if i < born:
            continue
        assert frame.track_ids.tolist() == [1]  # the first track id, kept for the whole take
        assert frame.contributors.all()
        assert (frame.n_agree == 3).all()
        errors.append(np.linalg.norm(frame.positions[0] - truth_skeleton(i), axis=-1))
    # The default preset's filter follows the 3 mm/frame sway closely: within a few noise sigmas.
    assert np.median(np.array(errors)[10:]) < 30.0

    # Without the filter (A4) the merge must be within the noise: one view's 3D error is about
    # sqrt(3) * 5 = 8.7 mm, the merge of three views about 5 mm.
    merged = list(fuse_recording(path, preset_name="A4", progress=False))
    errors = np.array(
        [np.linalg.norm(f.positions[0] - truth_skeleton(i), axis=-1) for i, f in enumerate(merged) if i >= born]
    )
    assert np.median(errors) < NOISE_MM * math.sqrt(3) * 0.8, np.median(errors)
    assert errors.max() < 5 * NOISE_MM

    # Identity-free check of the pose precedence: wrong explicit poses move the output away from the truth.
    shifted = {sid: make_transform(np.eye(3), np.array([0.0, 0.0, 1000.0])) @ p for sid, p in poses.items()}
    moved = list(fuse_recording(path, world_from_sensor=shifted, preset_name="A1", progress=False))
    assert abs(np.nanmean(moved[-1].positions[0, :, 2] - truth_skeleton(n_frames - 1)[:, 2]) - 1000.0) < 20.0


def test_fuse_recording_without_calibration_says_where_to_get_one(tmp_path: Path) -> None:
    path = tmp_path / "nocal.mcap"
    write_synthetic(path, {sid: np.eye(4) for sid in SENSORS}, 3, store_calibration=False)
    with pytest.raises(DataError, match="calibrat"):
        fuse_recording(path, progress=False)
    with pytest.raises(DataError, match=SENSORS[2]):
        fuse_recording(path, world_from_sensor={SENSORS[0]: np.eye(4), SENSORS[1]: np.eye(4)}, progress=False)
    identity = {sid: np.eye(4) for sid in SENSORS}
    fused = list(fuse_recording(path, world_from_sensor=identity, progress=False))
    assert len(fused) == 3


def test_fuse_recording_with_rig_config_and_a_dropped_frame(tmp_path: Path) -> None:
    """Poses and preset from a RigConfig; a frame one sensor dropped leaves an incomplete instant."""
    path = tmp_path / "drop.mcap"
    poses = rig_poses()
    write_synthetic(path, poses, 30, store_calibration=False, drop={(2, 10)})
    cfg = RigConfig(
        name=RIG,
        fusion=FusionConfig(preset="A4"),
        sensors=tuple(
            SensorConfig(id=sid, source="sim", world_from_sensor=tuple(map(tuple, poses[sid].tolist())))
            for sid in SENSORS
        ),
    )
    fused = list(fuse_recording(path, rig_config=cfg, progress=False))
    assert len(fused) == 30
    assert fused[10].contributors.tolist() == [[True, True, False]]
    assert (fused[10].n_agree == 2).all() and (fused[11].n_agree == 3).all()
    errors = np.linalg.norm(fused[10].positions[0] - truth_skeleton(10), axis=-1)
    assert np.median(errors) < 3 * NOISE_MM


# ---------------------------------------------------------------------------------------------------------
# Replay pacing


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0
        self.sleeps: list[float] = []

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += seconds


def test_replay_paces_by_log_time(tmp_path: Path) -> None:
    path = tmp_path / "r.mcap"
    frames = [make_frame(0, i) for i in range(10)]
    with RecordingWriter(path, rig=RIG, sensor_ids=SENSORS[:1]) as writer:
        for frame in frames:
            writer.write(frame)
    reader = RecordingReader(path)
    offsets = [(f.host_time_ns - frames[0].host_time_ns) / 1e9 for f in frames]

    clock = FakeClock()
    got = list(replay_frames(reader, speed=2.0, clock=clock, sleep=clock.sleep))
    assert [due for due, _ in got] == pytest.approx([o / 2 for o in offsets])
    assert clock.now - 100.0 == pytest.approx(offsets[-1] / 2)  # slept until each frame was due
    assert [r.payload for _, r in got] == [encode_sensor_frame(f) for f in frames]

    fast = FakeClock()
    got = list(replay_frames(reader.records(), speed=None, clock=fast, sleep=fast.sleep))
    assert fast.sleeps == [] and [due for due, _ in got] == pytest.approx(offsets)
    with pytest.raises(ValueError, match="speed"):
        list(replay_frames(reader, speed=0))


def test_offline_smoothing_lowers_the_jitter_and_the_error(tmp_path: Path) -> None:
    from test_orientation import AIM_AXES  # here: a child process imports this module without the tests' path

    path = tmp_path / "synthetic.mcap"
    write_synthetic(path, rig_poses(), 120, store_calibration=True, drop={(0, 60), (1, 60)})
    live = list(fuse_recording(path, progress=False, smoother="none"))
    smoothed = list(fuse_recording(path, progress=False))  # the default with the skelfuse preset: rts
    assert [f.time_us for f in live] == [f.time_us for f in smoothed]
    frame_of = [round((f.time_us - 5_000_000) / 33_333) for f in live]
    truth = np.stack([truth_skeleton(i) for i in frame_of[BIRTH_FRAMES - 1 :]])
    positions = {
        name: np.stack([f.positions[0] for f in take[BIRTH_FRAMES - 1 :]])
        for name, take in (("live", live), ("rts", smoothed))
    }
    error = {name: float(np.median(np.linalg.norm(x - truth, axis=-1))) for name, x in positions.items()}
    jitter = {name: float(np.median(np.abs(np.diff(x - truth, 2, axis=0)))) for name, x in positions.items()}
    assert error["rts"] < error["live"]
    assert jitter["rts"] < 0.5 * jitter["live"]
    for a_frame, b_frame in zip(live, smoothed, strict=True):  # the same persons, flags and missing joints
        np.testing.assert_array_equal(a_frame.track_ids, b_frame.track_ids)
        np.testing.assert_array_equal(a_frame.n_agree, b_frame.n_agree)
        np.testing.assert_array_equal(np.isnan(a_frame.positions), np.isnan(b_frame.positions))
        if b_frame.n_persons:  # the orientations follow the smoothed bones (X, the ankles' foot axis, on the bone)
            aim_axes = quat_rotate(b_frame.orientations[0], AIM_AXES)
            aims = aim_directions(b_frame.positions[0])
            np.testing.assert_allclose(aim_axes[ORIENTATION_AIMED], aims[ORIENTATION_AIMED], atol=1e-9)


def test_the_rts_smoother_refuses_a_filter_without_velocity(tmp_path: Path) -> None:
    path = tmp_path / "synthetic.mcap"
    write_synthetic(path, rig_poses(), 5, store_calibration=True)
    with pytest.raises(DataError, match="--smoother none"):
        fuse_recording(path, preset_name="A5", smoother="rts", progress=False)
    assert len(list(fuse_recording(path, preset_name="A5", progress=False))) == 5  # default: none for A5
