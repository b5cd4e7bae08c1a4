"""The fusion node survives what any peer sends: caps, volume, payload size, bounded records, track ids.

Each test reproduces one fault measured on main (see the issue): 64 bodies on one key for three instants made
more than 64 persons and encode_fused_frame raised out of the node; positions of 1e38 mm were fused; 4 MB
payloads were copied and queued without bound; the report's per-frame lists grew forever; track ids started
again at 1 after a restart.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from skelfuse.config import IntakeConfig, RigConfig, load_rig_config
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


def test_sample_queue_is_bounded(rig: RigConfig) -> None:
    class Payload:
        def __len__(self) -> int:
            return 1

        def to_bytes(self) -> bytes:
            return b"x"

    class Sample:
        key_expr = key("capture_0")
        payload = Payload()

    samples = SampleQueue(max_items=16, max_payload_bytes=1024)
    for _ in range(100):
        samples(Sample())
    assert samples.qsize() == 16 and samples.dropped == 84


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
