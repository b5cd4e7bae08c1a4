"""``[record] fused`` live: a fusion node, a recorder and simulated workers as real processes on loopback.

The fused frames the recorder wrote equal, payload for payload, what an independent subscriber received.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from service_helpers import RIG, Processes, start_node, worker_args, write_rig

from skelfuse.recording import RecordingReader
from skelfuse.service.zenoh_io import loopback_args
from skelfuse.wire import keys
from skelfuse.wire.codec import encode_fused_frame

pytestmark = pytest.mark.service

SENSORS = ("capture_0", "capture_1")


def _alive(session, node: str) -> bool:
    replies = session.liveliness().get(keys.alive(RIG, node), timeout=1.0)
    return any(getattr(reply, "ok", None) is not None for reply in replies)


def test_recorder_writes_the_fused_stream_a_subscriber_receives(
    tmp_path: Path, processes: Processes, node_port: int
) -> None:
    config = write_rig(tmp_path, n_sensors=2, deadline_ms=100.0)
    output = tmp_path / "take.mcap"
    node, listener = start_node(processes, config, node_port)
    try:
        recorder = processes.start(
            "recorder",
            "record",
            "--config",
            str(config),
            "--output",
            str(output),
            "--duration",
            "60",
            *loopback_args(connect_ports=[node_port]),
        )
        listener.wait_for(
            lambda: _alive(listener.session, "recorder"),
            30.0,
            "the recorder's liveliness token",
            lambda: processes.log(recorder),
        )
        time.sleep(0.5)  # let the recorder's subscriptions reach the node
        workers = [
            processes.start(f"w{i}", *worker_args(config, node_port, sid, "--duration", "3", listener=listener))
            for i, sid in enumerate(SENSORS)
        ]
        for worker in workers:
            worker.wait(60.0)
            assert worker.returncode == 0, processes.log(worker)
        listener.wait_for(
            lambda: bool(listener.fused) and time.monotonic() - listener.fused[-1][0] > 0.5,
            10.0,
            "the fused stream to settle",
        )
        assert processes.stop(recorder) == 0, processes.log(recorder)
        assert processes.stop(node) == 0, processes.log(node)
        received = [frame for _, frame in listener.fused]
        sensor_frames = listener.sensor_frames()
    finally:
        listener.close()

    rec = RecordingReader(output)
    assert rec.indexed, rec.problems  # closed cleanly on SIGTERM
    assert rec.fused_topic == keys.fused_skeletons(RIG)
    recorded = list(rec.fused_records())
    assert len(received) >= 60, f"only {len(received)} fused frames reached the subscriber"
    # The same frames, in the same order, with identical payloads (the wire codec is deterministic, so
    # re-encoding what the subscriber decoded gives the bytes it received).
    assert [r.frame.time_us for r in recorded] == [f.time_us for f in received]
    assert [r.payload for r in recorded] == [encode_fused_frame(f) for f in received]
    assert sum(f.n_persons for f in received) > 0
    for r, f in zip(recorded, received, strict=True):
        np.testing.assert_array_equal(r.frame.positions, f.positions)
    # Receive times are on the host clock, in order, and the sensor channels are still there beside.
    log_times = np.array([r.log_time_ns for r in recorded])
    assert (np.diff(log_times) >= 0).all()
    assert abs(log_times[0] / 1e9 - time.time()) < 300
    assert set(rec.sensors) == set(SENSORS)
    assert len(list(rec.frames())) == len(sensor_frames)
