"""Capture PCs with offset and jittery clocks, host-time grouping: real workers and node on loopback zenoh.

Each worker's wall clock is offset (and one jitters) through ``sensors[i].sim.clock_offset_ms`` /
``clock_jitter_ms``, which the worker adds to the host time it stamps: what a capture PC without NTP/PTP
does. Before the per-sensor clocks of ``rig/grouping.py``, one PC 100 ms ahead made every instant hold only
that sensor. The pure grouper is tested with ±5/±100/±500 ms and 20 ms jitter one by one in
tests/unit/test_grouping.py; here they run together, end to end.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from service_helpers import Processes, start_node, worker_args, write_rig

pytestmark = [pytest.mark.live, pytest.mark.soak]  # five processes: ~30 s on a loaded machine

SENSORS = ("capture_0", "capture_1", "capture_2", "capture_3")


def run_rig(tmp_path: Path, processes: Processes, node_port: int, clocks: dict[int, tuple[float, float]]) -> dict:
    config = write_rig(tmp_path, by="host", deadline_ms=60.0, sim_clocks=clocks)
    node, listener = start_node(processes, config, node_port)
    try:
        workers = {sid: processes.start(sid, *worker_args(config, node_port, sid)) for sid in SENSORS}
        listener.wait_for(lambda: len(listener.fused) >= 30, 60.0, "30 fused frames", lambda: processes.log(node))
        start = len(listener.fused)
        listener.wait_for(lambda: len(listener.fused) >= start + 90, 120.0, "90 more fused frames (3 s of the rig)")
        with listener.lock:
            recent = [f for _, f in listener.fused[start:]]
        status = listener.fusion_status()
        for worker in workers.values():
            assert processes.stop(worker) == 0
        assert processes.stop(node) == 0, processes.log(node)
    finally:
        listener.close()
    return {"recent": recent, "status": status}


def test_every_sensor_is_fused_with_offset_and_jittery_pc_clocks(
    tmp_path: Path, processes: Processes, node_port: int
) -> None:
    # capture_1: +100 ms and 20 ms jitter; capture_2: -500 ms; capture_3: +5 ms; capture_0 on time.
    result = run_rig(tmp_path, processes, node_port, {1: (100.0, 20.0), 2: (-500.0, 0.0), 3: (5.0, 0.0)})
    recent, status = result["recent"], result["status"]
    assert len(recent) >= 60, f"only {len(recent)} fused frames in 3 s"
    measured = [f for f in recent if f.contributors.any()]
    # Every sensor in nearly every instant (a frame the simulator drops, a loaded machine's late frame).
    per_sensor = [sum(bool(f.contributors[:, s].any()) for f in measured) / len(measured) for s in range(4)]
    assert min(per_sensor) >= 0.9, per_sensor
    clocks = {sid: status.info["sensors"][sid]["clock"] for sid in SENSORS}
    # The rig's median offset is ~+2.5 ms (0, +5, +100, -500); a median of 31 stamps with 20 ms jitter is
    # good to ~5 ms (one sigma), and latency differences on a loaded machine add to it.
    assert clocks["capture_1"]["relative_offset_ms"] == pytest.approx(97.5, abs=25.0)
    assert clocks["capture_2"]["relative_offset_ms"] == pytest.approx(-502.5, abs=10.0)
    assert clocks["capture_1"]["jitter_ms"] > 5.0 > clocks["capture_0"]["jitter_ms"]
