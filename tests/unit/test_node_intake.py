"""The fusion node survives what any peer sends: caps, volume, payload size, bounded records, track ids.

Each test reproduces one fault measured on main (see the issue): 64 bodies on one key for three instants made
more than 64 persons and encode_fused_frame raised out of the node; positions of 1e38 mm were fused; 4 MB
payloads were copied and queued without bound; the report's per-frame lists grew forever; track ids started
again at 1 after a restart.
"""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fake_zenoh import FakeSample
from skelfuse.apps.demo import sim_sensor_tables
from skelfuse.bench.latency import synthetic_frames
from skelfuse.config import IntakeConfig, RigConfig, load_rig_config, parse_rig_config
from skelfuse.fusion.tracks import MAX_TRACKS, TrackParams
from skelfuse.schema.frames import SensorFrame
from skelfuse.service.node import (
    LATENCY_WINDOW,
    FusionCore,
    NodeReport,
    time_based_first_track_id,
)
from skelfuse.service.worker import SimSource
from skelfuse.service.zenoh_io import SampleQueue
from skelfuse.wire.codec import MAX_PERSONS, decode_fused_frame, encode_sensor_frame

RIG_SIM_4 = Path(__file__).resolve().parents[2] / "config" / "rig-sim-4.toml"
PERIOD_NS = 33_333_333


@pytest.fixture(scope="module")
def rig() -> RigConfig:
    return load_rig_config(RIG_SIM_4)


@pytest.fixture(scope="module")
def sources(rig: RigConfig) -> dict[str, SimSource]:
    return {sid: SimSource(rig, sid, take_duration_s=1.0) for sid in rig.sensor_ids}


def key(sid: str) -> str:
    return f"skelfuse/sim4/sensors/{sid}/skeletons"


def crowd(frame: SensorFrame, n: int) -> SensorFrame:
    """``n`` copies of the frame's first body on a 0.6 m grid across the sensor's view (distinct persons)."""
    offsets = np.zeros((n, 1, 3), np.float32)
    offsets[:, 0, 0] = (np.arange(n) % 8 - 3.5) * 600.0
    offsets[:, 0, 2] = (np.arange(n) // 8) * 600.0
    return dataclasses.replace(
        frame,
        body_ids=np.arange(n, dtype=np.uint32),
        positions=(frame.positions[:1] + offsets).astype(np.float32),
        orientations=np.repeat(frame.orientations[:1], n, axis=0),
        confidence=np.repeat(frame.confidence[:1], n, axis=0),
    )


def feed(core: FusionCore, frames: dict[str, SensorFrame], now_ns: int) -> list:
    out = []
    for sid, frame in frames.items():
        out += core.receive(key(sid), encode_sensor_frame(frame), now_ns)
    return out


def test_track_cap_is_the_fused_frames_person_cap() -> None:
    assert MAX_TRACKS == MAX_PERSONS == TrackParams().max_tracks


def test_sixty_four_bodies_per_sensor_are_rejected_as_too_many(rig: RigConfig, sources: dict[str, SimSource]) -> None:
    core = FusionCore(rig)
    for n in range(100, 103):
        frame = dataclasses.replace(sources["capture_0"].frame_at(n), host_time_ns=1)
        core.receive(key("capture_0"), encode_sensor_frame(crowd(frame, 64)), 10**9 + n * PERIOD_NS)
    assert core.rejects["capture_0"]["too_many_bodies"] == 3


def test_coasting_tracks_plus_new_bodies_never_exceed_the_fused_frames_64(
    rig: RigConfig, sources: dict[str, SimSource]
) -> None:
    # With the per-sensor cap raised to the wire's 64, two sensors seeing 64 different people each (their
    # crowds do not coincide in the world) made >64 persons: ValueError out of encode_fused_frame.
    cfg = dataclasses.replace(rig, intake=IntakeConfig(max_bodies_per_sensor=64))
    core = FusionCore(cfg)
    outs = []
    for n in range(100, 104):
        now = 10**9 + n * PERIOD_NS
        frames = {
            sid: crowd(dataclasses.replace(sources[sid].frame_at(n), host_time_ns=1), 64)
            for sid in ("capture_0", "capture_2")
        }
        outs += feed(core, frames, now)
        outs += core.poll(now + 20_000_000)
    assert outs, "no instant was fused"
    persons = [decode_fused_frame(out.payload).track_ids.size for out in outs]
    assert max(persons) == MAX_PERSONS
    assert core.fuser.people.table.births_refused > 0
    assert FUSION_ERROR_FREE(core)


def FUSION_ERROR_FREE(core: FusionCore) -> bool:
    return all("fusion_error" not in counter for counter in core.rejects.values())


def test_positions_outside_the_plausible_volume_are_rejected(rig: RigConfig, sources: dict[str, SimSource]) -> None:
    core = FusionCore(rig)
    frame = dataclasses.replace(sources["capture_1"].frame_at(100), host_time_ns=1)
    far = dataclasses.replace(frame, positions=np.full_like(frame.positions, 1e38))
    assert core.receive(key("capture_1"), encode_sensor_frame(far), 10**9) == []
    assert core.rejects["capture_1"] == {"out_of_volume": 1}
    assert core.grouper.stats.sensors["capture_1"].received == 0  # never reached grouping


def test_oversized_payloads_are_dropped_unread(rig: RigConfig) -> None:
    core = FusionCore(rig)
    core.receive(key("capture_3"), b"\x00" * (4 << 20), 10**9)
    assert core.rejects["capture_3"] == {"oversized": 1}

    class Payload:
        def __init__(self, size: int) -> None:
            self.size = size

        def __len__(self) -> int:
            return self.size

        def to_bytes(self) -> bytes:
            raise AssertionError("an oversized payload must not be copied")

    class Sample:
        key_expr = key("capture_3")

        def __init__(self, size: int) -> None:
            self.payload = Payload(size)

    samples = SampleQueue(max_items=4, max_payload_bytes=rig.intake.max_payload_bytes)
    samples(Sample(4 << 20))
    assert samples.oversized == 1 and samples.qsize() == 0


def test_sample_queue_is_bounded_and_drops_the_oldest(rig: RigConfig) -> None:
    samples = SampleQueue(max_items=16, max_payload_bytes=1024)
    for i in range(100):
        samples(FakeSample(key("capture_0"), b"%d" % i))
    assert samples.qsize() == 16 and samples.dropped == 84
    kept = [samples.get_nowait().payload for _ in range(16)]
    assert kept == [b"%d" % i for i in range(84, 100)] and samples.get_nowait() is None


def test_sample_queue_bounds_bytes_and_each_key() -> None:
    labels = {key(sid): sid for sid in ("capture_0", "capture_1")}
    samples = SampleQueue(max_items=1000, max_items_per_key=5, max_bytes=4096, labels=labels)
    for _ in range(20):
        samples(FakeSample(key("capture_0"), b"a" * 10))
        samples(FakeSample("skelfuse/sim4/sensors/stranger/skeletons", b"b" * 1000))
    samples(FakeSample(key("capture_1"), b"c" * 10))
    counts = samples.counts()
    # capture_0 holds its newest 5 (per-key bound); the stranger's 1000-byte samples are cut to fit 4096 bytes
    # together with capture_0's 50 and capture_1's 10 (the bucket with the most bytes gives way).
    assert counts["capture_0"] == {"queued": 5, "dropped": 15, "oversized": 0}
    assert counts["capture_1"] == {"queued": 1, "dropped": 0, "oversized": 0}
    assert counts["?"]["queued"] == 4 and counts["?"]["dropped"] == 16
    order = [samples.get_nowait().payload[:1] for _ in range(samples.qsize())]
    # a15 a16 b16 a17 b17 a18 b18 a19 b19 c: arrival order kept across the buckets
    assert order == [b"a", b"a", b"b", b"a", b"b", b"a", b"b", b"a", b"b", b"c"]
    with pytest.raises(ValueError, match="max_bytes"):
        SampleQueue(max_payload_bytes=2048, max_bytes=1024)


def flood_rig(node_table: str = "") -> RigConfig:
    """4 synthetic sensors (the soak's), a small intake queue so that a one-second stall overflows it."""
    return parse_rig_config(
        tomllib.loads(
            "\n".join(
                [
                    '[rig]\nname = "flood"\n[sync]\nby = "device"\nfps = 30.0\ntolerance_ms = 10.0',
                    "deadline_ms = 17.0\n[intake]\nmax_queue = 256\nmax_queue_per_key = 64",
                    node_table,
                    *sim_sensor_tables(4),
                ]
            )
        )
    )


@pytest.mark.parametrize(
    ("flood_sensor", "kept_sensors"),
    [
        pytest.param("capture_3", ["capture_0", "capture_1", "capture_2"], id="on-a-sensors-key"),
        pytest.param("intruder", ["capture_0", "capture_1", "capture_2", "capture_3"], id="on-an-unknown-key"),
    ],
)
def test_a_flooding_key_cannot_push_out_other_sensors_frames(flood_sensor: str, kept_sensors: list[str]) -> None:
    # Before: a full queue dropped whatever came next, so a 1 kHz flood that filled it during a one-second stall
    # of the node's loop cost every sensor's frames (the soak lost 317 instants). Now the flood loses its own
    # oldest samples; every instant is fused with every other sensor's frame.
    cfg = flood_rig()
    frames = synthetic_frames(4, 90, seed=5)
    now = [10**9]
    labels = {f"skelfuse/flood/sensors/{sid}/skeletons": sid for sid in cfg.sensor_ids}
    intake = cfg.intake
    samples = SampleQueue(
        max_items=intake.max_queue,
        max_payload_bytes=intake.max_payload_bytes,
        max_items_per_key=intake.max_queue_per_key,
        max_bytes=intake.max_queue_bytes,
        labels=labels,
        clock=lambda: now[0],
    )
    core = FusionCore(cfg)
    flood_key = f"skelfuse/flood/sensors/{flood_sensor}/skeletons"
    outs = []
    for k in range(90):
        now[0] = 10**9 + k * PERIOD_NS
        for i, frame in enumerate(frames[k]):
            stamped = dataclasses.replace(frame, sequence=k, device_time_us=10**6 + k * 33_333 + 160 * i)
            samples(FakeSample(f"skelfuse/flood/sensors/{frame.sensor_id}/skeletons", encode_sensor_frame(stamped)))
        for _ in range(33):  # 1 kHz of garbage on the flood key
            samples(FakeSample(flood_key, b"\x00garbage" * 8))
        if 30 <= k < 60:  # the node's loop stalls for a second: nothing is taken out
            continue
        while (item := samples.get_nowait()) is not None:
            outs += core.receive(item.key, item.payload, item.arrival_ns)
        outs += core.poll(now[0] + 20_000_000)
    columns = [cfg.sensor_ids.index(sid) for sid in kept_sensors]
    seen = [np.isfinite(out.sensors_world[columns]).any(axis=(1, 2, 3)) for out in outs]
    assert len(outs) == 90, f"{90 - len(outs)} instants lost"
    assert all(s.all() for s in seen), "an instant lost a kept sensor's frame"
    counts = samples.counts()
    label = flood_sensor if flood_sensor in cfg.sensor_ids else "?"
    assert counts[label]["dropped"] > 900  # ~1000 flood samples came during the stall, at most 64 stay
    assert all(counts.get(sid, {"dropped": 0})["dropped"] == 0 for sid in kept_sensors)


@pytest.mark.parametrize("rejected_key", ["capture_3", "intruder"])
def test_a_rejected_sample_read_in_a_backlog_does_not_close_its_neighbours_instant(rejected_key: str) -> None:
    # A backlog's frames arrived in time, whatever the time the loop reads them. A rejected payload read between
    # two sensors' frames of one instant made that instant due by the time now (a deadline poll at "now"), so the
    # instant went out with the sensors read so far and the rest came late: a peer's garbage cost good frames.
    cfg = flood_rig("[node]\nmax_lag_s = 30.0")  # nothing shed: the backlog is half a second old when read
    frames = synthetic_frames(4, 10, seed=5)
    core = FusionCore(cfg)
    read_ns = 10**9 + 10 * PERIOD_NS + 500_000_000
    garbage_key = f"skelfuse/flood/sensors/{rejected_key}/skeletons"
    outs = []
    for k in range(10):
        for i, frame in enumerate(frames[k]):
            arrival_ns = 10**9 + k * PERIOD_NS + i * 1_000_000
            stamped = dataclasses.replace(frame, sequence=k, device_time_us=10**6 + k * 33_333 + 160 * i)
            payload = encode_sensor_frame(stamped)
            outs += core.receive(f"skelfuse/flood/sensors/{frame.sensor_id}/skeletons", payload, arrival_ns, read_ns)
            outs += core.receive(garbage_key, b"\x00garbage" * 8, arrival_ns + 500_000, read_ns)
    outs += core.poll(read_ns)
    assert len(outs) == 10
    assert all(np.isfinite(out.sensors_world).any(axis=(1, 2, 3)).all() for out in outs), "an instant lost a sensor"
    assert sum(c.late for c in core.grouper.stats.sensors.values()) == 0
    assert core.deadline_emits == 0


def test_the_node_report_keeps_a_bounded_record() -> None:
    report = NodeReport()
    for i in range(LATENCY_WINDOW + 500):
        report.fusion_ms.append(float(i))
        report.added_ms.append(float(i))
    assert len(report.fusion_ms) == len(report.added_ms) == LATENCY_WINDOW
    assert report.fusion_ms[-1] == LATENCY_WINDOW + 499


def test_track_ids_continue_after_a_restart(rig: RigConfig, sources: dict[str, SimSource]) -> None:
    # Docs say ids are never reused; a restarted node started again at 1.
    first = time_based_first_track_id(1_770_000_000 * 10**9)
    later = time_based_first_track_id(1_770_000_060 * 10**9)  # restarted a minute later
    assert later - first == 60  # room for one new track per second of the previous run
    assert time_based_first_track_id(3_900_000_000 * 10**9) < 2**31  # a 32-bit int holds ids until 2094 (3.9e9 s: 2093)
    core = FusionCore(rig, first_track_id=later)
    outs = []
    for n in range(100, 104):
        frames = {sid: dataclasses.replace(sources[sid].frame_at(n), host_time_ns=1) for sid in rig.sensor_ids}
        outs += feed(core, frames, 10**9 + n * PERIOD_NS)
    assert outs[-1].frame.track_ids.tolist() == [later]


def test_a_forged_frame_from_the_future_is_rejected_and_output_stays_whole(
    rig: RigConfig, sources: dict[str, SimSource]
) -> None:
    core = FusionCore(rig)
    outs = []
    for n in range(100, 190):
        now = 10**9 + n * PERIOD_NS
        frames = {sid: dataclasses.replace(sources[sid].frame_at(n), host_time_ns=1) for sid in rig.sensor_ids}
        outs += feed(core, frames, now)
        if n % 30 == 15:  # once a second, 0.9 s ahead, on capture_1's key
            forged = dataclasses.replace(
                frames["capture_1"], device_time_us=frames["capture_1"].device_time_us + 900_000
            )
            outs += core.receive(key("capture_1"), encode_sensor_frame(forged), now + 1000)
    assert len(outs) == 90 and all(o.complete for o in outs)
    report = core.sensor_report(10**9 + 190 * PERIOD_NS, 1.0)
    assert report["capture_1"]["off_clock"] == 3 and report["capture_1"]["late"] == 0
    assert report["capture_1"]["clock"]["relearns"] == 0


def test_an_exception_inside_the_fusion_step_is_counted_and_the_node_goes_on(
    rig: RigConfig, sources: dict[str, SimSource], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A bug in the core (here an IndexError, as an out-of-range gather of orientations would raise) costs its
    instant, counted as a fusion error; the tracks start afresh and the next instants are fused."""
    core = FusionCore(rig)
    real_step = core.fuser.step
    calls = {"n": 0}

    def flaky_step(group):  # the third instant raises
        calls["n"] += 1
        if calls["n"] == 3:
            raise IndexError("index 2 is out of bounds for axis 0 with size 2")
        return real_step(group)

    monkeypatch.setattr(core.fuser, "step", flaky_step)
    fused = []
    for n in range(10):
        frames = {sid: s.frame_at(n) for sid, s in sources.items()}
        fused += feed(core, frames, 10**9 + n * PERIOD_NS)
    fused += core.flush()
    assert not FUSION_ERROR_FREE(core)
    assert sum(counter.get("fusion_error", 0) for counter in core.rejects.values()) == 1
    assert len(fused) >= 8  # every other instant fused


def test_only_the_rigs_own_sensor_keys_are_taken(rig: RigConfig, sources: dict[str, SimSource]) -> None:
    """The rig's keys are looked up, not parsed, per frame; another rig's key, a malformed key and a key whose
    sensor differs from the payload's are still refused, each under its own reason."""
    core = FusionCore(rig)
    frame = dataclasses.replace(sources["capture_0"].frame_at(100), host_time_ns=1)
    payload = encode_sensor_frame(frame)
    core.receive("skelfuse/other_rig/sensors/capture_0/skeletons", payload, 10**9)
    core.receive("skelfuse/sim4/sensors/*/skeletons", payload, 10**9 + 1)
    core.receive(key("capture_1"), payload, 10**9 + 2)
    assert core.rejects["?"]["bad_key"] == 2
    assert core.rejects["capture_1"]["key_mismatch"] == 1
    core.receive(key("capture_0"), payload, 10**9 + 3)
    assert core.grouper.stats.sensors["capture_0"].received == 1
    assert sum(sum(counter.values()) for counter in core.rejects.values()) == 3
