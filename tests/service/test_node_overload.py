"""A fusion node that cannot keep up sheds its oldest instants and stays within ``[node] max_lag_s`` of real time.

Real processes: ``skelfuse fuse`` through ``slow_fusion_node.py``, which makes every fused instant take
``COST_MS`` longer (three frame periods: the node can fuse about a third of what arrives, whatever the
machine's speed), and this test publishing four sensors at 30 Hz and listening to the fused stream. Without
shedding, the node's backlog would grow by about two seconds per second of input (its intake queue holds 34 s)
and its output would end about twelve seconds behind. The bound checked on every fused frame (published first
sensor frame of the instant -> fused frame received here) is made of configured values only: the lag bound,
two instants' fusion (the one being fused when the bound is checked, and one fused with it in the same batch),
the grouping deadline and the status period (a status is published on the loop between instants).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import pytest
from service_helpers import Processes, start_node, write_rig

from skelfuse.bench.latency import synthetic_frames
from skelfuse.config import NodeConfig, load_rig_config
from skelfuse.service.node import NodeOptions
from skelfuse.service.zenoh_io import free_port, loopback_config
from skelfuse.wire import keys
from skelfuse.wire.codec import encode_sensor_frame
from waiting import SCHEDULING_ALLOWANCE_S, wait_for_subscriber

pytestmark = [pytest.mark.live, pytest.mark.service]

LAUNCHER = Path(__file__).with_name("slow_fusion_node.py")
COST_MS = 100.0
PUBLISH_S = 6.0
FPS = 30.0


def test_an_overloaded_node_sheds_the_oldest_instants_and_stays_within_its_lag_bound(
    tmp_path: Path, processes: Processes
) -> None:
    import zenoh

    config = write_rig(tmp_path, max_lag_s=NodeConfig().max_lag_s)  # the product's default bound
    cfg = load_rig_config(config)
    bound_s = cfg.node.max_lag_s + 2 * COST_MS / 1000 + cfg.sync.deadline_ms / 1000 + cfg.node.status_period_s
    port = free_port()
    node, listener = start_node(processes, config, port, via=(str(LAUNCHER), str(COST_MS)))
    session = zenoh.open(loopback_config(connect_ports=[port]))
    published: dict[int, float] = {}  # instant's device time (µs) -> monotonic time its first frame was put
    try:
        publishers = {sid: session.declare_publisher(keys.sensor_skeletons(cfg.name, sid)) for sid in cfg.sensor_ids}
        for publisher in publishers.values():
            wait_for_subscriber(publisher, "the node's subscription")
        n_instants = int(PUBLISH_S * FPS)
        frames = synthetic_frames(len(cfg.sensor_ids), n_instants, seed=11)
        base_us, start = time.time_ns() // 1000, time.monotonic()
        for k in range(n_instants):
            delay = start + k / FPS - time.monotonic()
            if delay > 0:
                time.sleep(delay)  # the sensors' pace, not a wait for a result
            device_us = base_us + round(k * 1e6 / FPS)
            published[device_us] = time.monotonic()
            for i, frame in enumerate(frames[k]):
                stamped = dataclasses.replace(frame, sequence=k + 1, device_time_us=device_us + 160 * i)
                publishers[frame.sensor_id].put(encode_sensor_frame(stamped))
        last_us = max(published)
        # The node keeps running: it fuses one of the last second's instants and reports shedding.
        listener.wait_for(
            lambda: any(f.time_us >= last_us - 1_000_000 for _, f in list(listener.fused)),
            60.0,
            "a fused frame of the last second's instants",
            lambda: processes.log(node),
        )
        listener.wait_for(
            lambda: (listener.fusion_status().counters.get("instants_shed") or 0) > 0,
            60.0,
            "a status counting shed instants",
            lambda: processes.log(node),
        )
        assert node.poll() is None, processes.log(node)
        stop_began = time.monotonic()
        assert processes.stop(node, timeout_s=60.0) == 0, processes.log(node)
        stopped_s = time.monotonic() - stop_began
        listener.wait_for(
            lambda: any(s.role == "fusion" and s.state == "stopped" for s in list(listener.statuses)),
            30.0,
            "the node's stopped status",
        )
    finally:
        session.close()
        listener.close()
    drain_timeout_s = NodeOptions().drain_timeout_s
    assert stopped_s <= drain_timeout_s + SCHEDULING_ALLOWANCE_S, f"stopped {stopped_s:.2f} s after SIGTERM"
    with listener.lock:
        fused = [(received, frame) for received, frame in listener.fused if frame.time_us in published]
        final = next(s for s in listener.statuses if s.role == "fusion" and s.state == "stopped")
    ages = [received - published[frame.time_us] for received, frame in fused]
    assert len(fused) >= 0.2 * len(published), f"{len(fused)} of {len(published)} instants fused"
    assert max(ages) <= bound_s, f"a fused frame {max(ages):.3f} s old at output, bound {bound_s:.3f} s"
    counters, sensors = final.counters, final.info["sensors"]
    shed = counters["instants_shed"]
    assert shed > 0.3 * len(published) and counters["shed.behind"] == shed, counters
    # Whole instants: a sensor is missing from a shed instant only where the instant went out incomplete (its
    # grouping deadline passed before that sensor's frame came in, as it may when this machine is loaded).
    incomplete = counters["groups_incomplete"]
    assert all(shed - incomplete <= report["shed"] <= shed for report in sensors.values()), (counters, sensors)
    assert shed + len(fused) <= len(published)
    assert "cannot keep up" in processes.log(node)
