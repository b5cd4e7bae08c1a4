"""The live service end to end: real ``python -m skelfuse`` processes talking zenoh on loopback.

Every test is bounded (timeouts on every wait, processes killed at teardown) and uses free ports with
multicast scouting off.
"""

from __future__ import annotations

import dataclasses
import random
import signal
import struct
import time
from pathlib import Path

import numpy as np
import pytest
from service_helpers import RIG, Processes, publish_common_stretch, start_node, worker_args, write_rig

from skelfuse.bench.latency import synthetic_frames
from skelfuse.config import load_rig_config
from skelfuse.recording import RecordingWriter, fuse_recording
from skelfuse.schema.frames import FusedFrame
from skelfuse.wire import keys
from skelfuse.wire.codec import encode_sensor_frame
from waiting import SCHEDULING_ALLOWANCE_S, wait_for_subscriber

pytestmark = pytest.mark.live

SENSORS = ("capture_0", "capture_1", "capture_2", "capture_3")
BIRTH_FRAMES = 3
"""PeopleFuser's default: instants a person must be seen before it is output."""


def test_live_rig_equals_offline_fusion_of_the_same_frames(
    tmp_path: Path, processes: Processes, node_port: int
) -> None:
    """4 sim workers -> node; the fused stream equals fuse_recording() of the frames the workers published."""
    # A long deadline: a frame delayed by a loaded CI machine is still grouped live as offline would group it.
    config = write_rig(tmp_path, deadline_ms=200.0)
    node, listener = start_node(processes, config, node_port)

    try:
        publish_common_stretch(processes, listener, config, node_port, SENSORS, 100)
        listener.wait_for(
            lambda: bool(listener.fused) and time.monotonic() - listener.fused[-1][0] > 0.5,
            30.0,
            "the fused stream to settle",
        )
        assert processes.stop(node) == 0, processes.log(node)
        frames = listener.sensor_frames()
        node_received = {sid: s["received"] for sid, s in listener.fusion_status().info["sensors"].items()}
        live = [frame for _, frame in listener.fused]
    finally:
        listener.close()
    assert len(frames) >= 4 * 60, f"only {len(frames)} sensor frames arrived"
    seen = {sid: sum(1 for f in frames if f.sensor_id == sid) for sid in SENSORS}
    assert seen == node_received, "the node and the test did not receive the same frames"

    # Offline: the same frames, recorded with their publish host time, fused as the live node would.
    cfg = load_rig_config(config)
    path = tmp_path / "published.mcap"
    with RecordingWriter(path, rig=RIG, sensor_ids=cfg.sensor_ids) as writer:
        for frame in sorted(frames, key=lambda f: f.host_time_ns):
            writer.write(frame)
    offline = {f.time_us: f for f in fuse_recording(path, rig_config=cfg, progress=False, smoother="none")}

    both = [f for f in live if f.time_us in offline]
    assert len(both) >= 0.95 * len(live) and len(both) >= 60, (len(both), len(live), len(offline))
    complete = 0
    for frame in both:
        expected = offline[frame.time_us]
        assert frame.n_persons == expected.n_persons
        np.testing.assert_allclose(frame.positions, expected.positions, rtol=0, atol=1e-9, equal_nan=True)
        np.testing.assert_array_equal(frame.contributors, expected.contributors)
        np.testing.assert_array_equal(frame.n_agree, expected.n_agree)
        complete += bool(frame.n_persons and frame.contributors[0].all())
    assert complete >= 30, f"only {complete} instants fused all four sensors"


def test_kill_9_one_worker_fusion_goes_on_and_takes_it_back(
    tmp_path: Path, processes: Processes, node_port: int
) -> None:
    """kill -9 a capture worker: 3-sensor fusion of every instant goes on; a restart is taken back."""
    # A long deadline, so that a loaded machine's late frames are grouped, not dropped: the test asks whether
    # the node fuses every instant without the dead sensor, which holds whatever the load.
    config = write_rig(tmp_path, deadline_ms=200.0)
    node, listener = start_node(processes, config, node_port)

    # The sim take loops every 4 s and the person jumps back to the start of the path: the tracker takes
    # that for a new person (a new track id; the old track coasts out). So a sensor's contribution is
    # checked over every person of a frame, in the frames where some sensor measured someone.
    def measured(frame: FusedFrame) -> bool:
        return bool(frame.contributors.any())

    def with_all_four() -> bool:
        # Some frame measured, or the check is vacuous (frames where no sensor saw anyone): on a loaded
        # machine this wait can pass before the restarted sensor is back (its status last_seen_s over 2 s).
        with listener.lock:
            recent = [f for _, f in listener.fused[-10:]]
        seen = [f for f in recent if measured(f)]
        return len(recent) == 10 and bool(seen) and all(f.contributors.any(axis=0).all() for f in seen)

    def fused_since(at: float) -> list[FusedFrame]:
        with listener.lock:
            return [f for t, f in listener.fused if t > at]

    try:
        workers = {sid: processes.start(sid, *worker_args(config, node_port, sid)) for sid in SENSORS}
        listener.wait_for(with_all_four, 60.0, "four sensors fused", lambda: processes.log(workers["capture_3"]))
        killed_at = time.monotonic()
        processes.stop(workers["capture_3"], sig=signal.SIGKILL)
        listener.wait_for(lambda: len(fused_since(killed_at)) >= 90, 60.0, "90 fused frames after the kill")
        after = fused_since(killed_at)
        # Every instant fused, none skipped while the node waited for the dead sensor: consecutive fused
        # times one frame period apart (30 Hz; subordinate delays move an instant by well under a period).
        steps_ms = np.diff([f.time_us for f in after]) / 1e3
        assert steps_ms.max() < 1.5 * 1e3 / 30.0, (
            f"instants skipped after the kill: steps up to {steps_ms.max():.0f} ms"
        )
        column = SENSORS.index("capture_3")
        settled = [f for f in after[15:] if measured(f)]  # the first half second may still hold its last frames
        assert settled and not any(f.contributors[:, column].any() for f in settled)
        assert all(f.contributors[:, :column].any(axis=0).all() for f in settled[-30:])

        restarted_at = time.monotonic()
        workers["capture_3"] = processes.start("capture_3-again", *worker_args(config, node_port, "capture_3"))
        listener.wait_for(
            lambda: with_all_four() and any(f.contributors[:, column].any() for f in fused_since(restarted_at)),
            60.0,
            "the restarted sensor fused again",
            lambda: processes.log(workers["capture_3"]),
        )
        # The node's status once it fused the restarted sensor (the status before may predate its return).
        back_ns = time.time_ns()
        listener.wait_for(
            lambda: listener.fusion_status().time_ns >= back_ns, 10.0, "a status after the restarted sensor's return"
        )
        status = listener.fusion_status()
        assert status.info["sensors"]["capture_3"]["last_seen_s"] < 1.0, status.info["sensors"]["capture_3"]
        for worker in workers.values():
            assert processes.stop(worker) == 0
        assert processes.stop(node) == 0, processes.log(node)
    finally:
        listener.close()


def _corrupt(good: bytes) -> list[tuple[str, bytes]]:
    """(expected reject reason, payload) for every kind of corruption; ``good`` is a one-body sensor frame."""

    def patched(offset: int, fmt: str, value: object) -> bytes:
        data = bytearray(good)
        struct.pack_into(fmt, data, offset, value)
        return bytes(data)

    positions = 40 + 4  # header, then one u32 body id
    return [
        ("truncated", good[: len(good) // 2]),
        ("truncated", good[:7]),
        ("bad_version", patched(4, "<B", 2)),
        ("bad_magic", b"XXXX" + good[4:]),
        ("non_finite", patched(positions + 4 * 5, "<f", float("nan"))),
        ("non_finite", patched(positions, "<f", float("inf"))),
        ("too_large", patched(12, "<H", 65535)),  # 65535 bodies claimed
        ("bad_joint_count", patched(10, "<H", 31)),
        ("bad_length", good + b"\0" * 16),
    ]


def test_corrupt_payloads_are_rejected_counted_and_good_frames_keep_fusing(
    tmp_path: Path, processes: Processes, node_port: int
) -> None:
    # capture_3 never delivers a valid frame, so every instant waits for its deadline; 100 ms keeps a good
    # frame delayed by a loaded CI machine from counting as late.
    config = write_rig(tmp_path, deadline_ms=100.0)
    node, listener = start_node(processes, config, node_port)
    n_instants = 90
    frames = synthetic_frames(4, n_instants, seed=3)
    sent_reasons: dict[str, int] = {}
    try:
        publishers = {sid: listener.session.declare_publisher(keys.sensor_skeletons(RIG, sid)) for sid in SENSORS}
        for publisher in publishers.values():
            wait_for_subscriber(publisher, "the node's subscription")
        base_us = time.time_ns() // 1000
        start = time.monotonic()
        for k in range(n_instants):
            delay = start + k / 30.0 - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            stamped = [
                dataclasses.replace(
                    f, sequence=k, device_time_us=base_us + round(k * 1e6 / 30) + 160 * i, host_time_ns=time.time_ns()
                )
                for i, f in enumerate(frames[k])
            ]
            for frame in stamped[:3]:
                publishers[frame.sensor_id].put(encode_sensor_frame(frame))
            reason, payload = _corrupt(encode_sensor_frame(stamped[3]))[k % 9]
            publishers["capture_3"].put(payload)
            sent_reasons[reason] = sent_reasons.get(reason, 0) + 1
        total = sum(sent_reasons.values())
        listener.wait_for(
            lambda: (
                (s := listener.fusion_status()) is not None
                and s.counters.get("invalid") == total
                and s.counters["frames_out"] >= n_instants
            ),
            10.0,
            "the rejects counted",
            lambda: str(listener.fusion_status()),
        )
        status = listener.fusion_status()
        assert node.poll() is None, "the node died"
        for reason, count in sent_reasons.items():
            assert status.counters[f"rejects.{reason}"] == count, reason
        assert status.info["sensors"]["capture_3"]["invalid"] == total
        assert status.info["sensors"]["capture_3"]["rejects"] == sent_reasons
        for sid in SENSORS[:3]:  # none of the good frames lost
            sensor = status.info["sensors"][sid]
            assert sensor["received"] == sensor["grouped"] == n_instants, (sid, sensor)
            assert sensor["invalid"] == sensor["late"] == 0
        fused = [f for _, f in listener.fused]
        assert len(fused) == n_instants
        # The person is output once its track is confirmed (BIRTH_FRAMES instants), then in every instant.
        assert [f.n_persons for f in fused[: BIRTH_FRAMES - 1]] == [0] * (BIRTH_FRAMES - 1)
        # One stable id; the live node's ids start at its start time in seconds since 2026 (never reused across
        # restarts, and within a 32-bit integer).
        first_id = int(fused[BIRTH_FRAMES - 1].track_ids[0])
        assert 25_000_000 < first_id < 2**31
        assert all(f.n_persons == 1 and f.track_ids.tolist() == [first_id] for f in fused[BIRTH_FRAMES - 1 :])
        assert all(f.contributors[0].tolist() == [True, True, True, False] for f in fused[BIRTH_FRAMES - 1 :])
        assert processes.stop(node) == 0, processes.log(node)
    finally:
        listener.close()


@pytest.mark.parametrize("by", ["device", "host"])
def test_grouping_with_constant_offsets_and_jitter(
    tmp_path: Path, processes: Processes, node_port: int, by: str
) -> None:
    """Per-sensor clock offsets, jitter and shuffled arrival: every instant fused once, all four sensors in it.

    device: subordinate delays 0/160/320/480 us plus +-60 us jitter. host: per-sensor host latency offsets
    of -3..+4 ms plus +-1 ms jitter, and device clocks on unrelated epochs (host grouping must ignore them).
    """
    # Every sensor's frame of an instant is sent, so a complete group is emitted at once and the deadline only
    # matters to a sender the machine starved mid-instant: one scheduling allowance keeps that from splitting
    # an instant (the deadline itself is checked in tests/unit/test_grouping.py on injected arrival times).
    config = write_rig(tmp_path, by=by, deadline_ms=1000.0 * SCHEDULING_ALLOWANCE_S)
    node, listener = start_node(processes, config, node_port)
    rng = random.Random(7)
    n_instants = 60
    frames = synthetic_frames(4, n_instants, seed=5)
    expected_times = []
    try:
        publishers = {sid: listener.session.declare_publisher(keys.sensor_skeletons(RIG, sid)) for sid in SENSORS}
        for publisher in publishers.values():
            wait_for_subscriber(publisher, "the node's subscription")
        base_us = time.time_ns() // 1000
        start = time.monotonic()
        for k in range(n_instants):
            delay = start + k / 30.0 - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            instant_us = base_us + round(k * 1e6 / 30)
            stamped = []
            for i, frame in enumerate(frames[k]):
                if by == "device":
                    device = instant_us + 160 * i + rng.randint(-60, 60)
                    host = time.time_ns()
                else:
                    device = 10**12 * (i + 1) + k * 33_333  # unrelated device clocks
                    host = instant_us * 1000 + [0, 4_000_000, -3_000_000, 2_000_000][i] + rng.randint(-(10**6), 10**6)
                stamped.append(dataclasses.replace(frame, sequence=k, device_time_us=device, host_time_ns=host))
            expected_times.append(min(f.device_time_us if by == "device" else f.host_time_ns // 1000 for f in stamped))
            rng.shuffle(stamped)
            for frame in stamped:
                publishers[frame.sensor_id].put(encode_sensor_frame(frame))
                time.sleep(rng.uniform(0, 0.002))
        # The node's status and its fused frames leave one session on one link, in order: a status that counts
        # n_instants frames out comes after all of them, so an extra frame would be here by then.
        listener.wait_for(
            lambda: (s := listener.fusion_status()) is not None and s.counters["frames_out"] >= n_instants,
            60.0,
            f"a status counting {n_instants} fused frames",
            lambda: str(listener.fusion_status()),
        )
        assert listener.fusion_status().counters["frames_out"] == n_instants
        fused = [f for _, f in listener.fused]
        if by == "device":
            assert [f.time_us for f in fused] == expected_times
        else:  # on the rig's clock: each sensor's offset removed, the stamps' jitter smoothed (module docs)
            # The reference is the sensors' median offset when the epoch began, this machine's latency then
            # included (23 ms measured beside two CPU burners): so not the stamps' absolute value, but one
            # offset from them for every instant (within half a frame), and one frame period apart. The offsets
            # themselves are checked on injected arrival times in tests/unit/test_grouping.py.
            assert len(fused) == n_instants
            offsets = [f.time_us - t for f, t in zip(fused, expected_times, strict=True)]
            assert max(offsets) - min(offsets) < 16_000, offsets
            steps = np.diff([f.time_us for f in fused])
            assert np.abs(steps[3:] - 33_333).max() <= 3_000
        assert all(f.n_persons == (i >= BIRTH_FRAMES - 1) for i, f in enumerate(fused))
        assert all(f.contributors[0].all() for f in fused if f.n_persons)
        status = listener.fusion_status()
        assert status.counters["late"] == status.counters["duplicate"] == status.counters["out_of_window"] == 0
        assert processes.stop(node) == 0, processes.log(node)
    finally:
        listener.close()
