"""A fusion node killed (SIGKILL, as a crash) and relaunched on its port fuses the running workers' frames
again: the workers and subscribers reconnect to it without being restarted themselves.

The wait is bounded by the product's own bound on a rig's first fused frame (the demo's STARTUP_TIMEOUT_S),
not by a speed: how fast the relaunched node fuses is measured by ``scripts/startup_time.py`` ("kill -9,
relaunch -> fused frame").
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest
from service_helpers import Processes, node_args, start_node, worker_args, write_rig

from skelfuse.apps.demo.live import STARTUP_TIMEOUT_S

pytestmark = [pytest.mark.service, pytest.mark.live]

SENSORS = ("capture_0", "capture_1")


def test_a_relaunched_node_fuses_every_sensor_again(tmp_path: Path, processes: Processes, node_port: int) -> None:
    config = write_rig(tmp_path, n_sensors=len(SENSORS), deadline_ms=200.0)
    node, listener = start_node(processes, config, node_port)

    def fused_since(moment: float) -> list:
        with listener.lock:
            return [frame for received, frame in listener.fused if received > moment]

    def every_sensor_fused_since(moment: float, at_least: int = 1) -> bool:
        """``at_least`` frames fused since ``moment``, every sensor in one of them (30 after the kill: more
        than a killed node could still have had on its way)."""
        frames = fused_since(moment)
        seen = [frame.contributors.any(axis=0) for frame in frames if frame.contributors.any()]
        return len(frames) >= at_least and bool(seen) and all(any(column) for column in zip(*seen, strict=True))

    try:
        for sensor_id in SENSORS:
            processes.start(sensor_id, *worker_args(config, node_port, sensor_id, listener=listener))
        listener.wait_for(
            lambda: every_sensor_fused_since(0.0), 60.0, "both sensors fused", lambda: processes.log(node)
        )
        processes.stop(node, sig=signal.SIGKILL)
        killed_at = time.monotonic()
        relaunched = processes.start("node-again", *node_args(config, node_port))
        listener.wait_for(
            lambda: every_sensor_fused_since(killed_at, at_least=30),
            STARTUP_TIMEOUT_S,
            "the relaunched node's fused frames with both sensors",
            lambda: processes.log(relaunched),
        )
        assert processes.stop(relaunched) == 0, processes.log(relaunched)
    finally:
        listener.close()


def test_the_check_sees_a_node_that_stays_down(tmp_path: Path, processes: Processes, node_port: int) -> None:
    """The control: without the relaunch no fused frame arrives after the kill (the wait above can fail)."""
    config = write_rig(tmp_path, n_sensors=len(SENSORS), deadline_ms=200.0)
    node, listener = start_node(processes, config, node_port)
    try:
        for sensor_id in SENSORS:
            processes.start(sensor_id, *worker_args(config, node_port, sensor_id, listener=listener))
        listener.wait_for(lambda: bool(listener.fused), 60.0, "fused frames", lambda: processes.log(node))
        processes.stop(node, sig=signal.SIGKILL)
        killed_at = time.monotonic()
        with pytest.raises(AssertionError, match="timed out"):
            listener.wait_for(lambda: any(t > killed_at for t, _ in listener.fused), 3.0, "a fused frame")
    finally:
        listener.close()
