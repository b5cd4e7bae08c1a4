"""The fusion node stops within its drain timeout on SIGTERM while a subscriber's link is full.

Real processes: ``skelfuse fuse``, a subscriber process (``stoppable_subscriber.py``, without zenoh's shared
memory, so every byte goes over its link) that reaches the node only through ``stall_relay.py``, and this test
publishing four sensors at 30 Hz. The relay stops reading; once the node's status says a fused put waited its
whole bound (``info.fused_publish.reached_bound``: the link is full for sure), the node gets SIGTERM. zenoh's
``Session.close()`` waits on such a link for as long as it stays full; the node bounds it
(``service/zenoh_io.py`` ``close_session``, ``SESSION_CLOSE_TIMEOUT_S``) and exits at once after it. The default
run stops one node; the soak run repeats it with other frames.
"""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from service_helpers import RIG, Processes, start_node, write_rig
from stall_relay import StallRelay

from skelfuse.bench.latency import synthetic_frames
from skelfuse.service.node import NodeOptions
from skelfuse.service.zenoh_io import SESSION_CLOSE_TIMEOUT_S, free_port
from skelfuse.wire import keys
from skelfuse.wire.codec import encode_sensor_frame

pytestmark = pytest.mark.live

SUBSCRIBER = Path(__file__).with_name("stoppable_subscriber.py")
DRAIN_TIMEOUT_S = NodeOptions().drain_timeout_s
MARGIN_S = 1.0
"""What a loaded machine may add to the stop (the process's own exit included)."""


def fused_publish(listener) -> dict:
    status = listener.fusion_status()
    return {} if status is None else dict(status.info.get("fused_publish") or {})


@pytest.mark.parametrize("run", [0, *(pytest.param(k, marks=pytest.mark.soak) for k in range(1, 5))])
def test_sigterm_with_a_full_link_to_a_subscriber_stops_the_node_within_its_drain_timeout(
    tmp_path: Path, processes: Processes, run: int
) -> None:
    assert SESSION_CLOSE_TIMEOUT_S < DRAIN_TIMEOUT_S
    port = free_port()
    config = write_rig(tmp_path)
    node, listener = start_node(processes, config, port, "--zenoh-cfg", "transport/link/tcp/so_sndbuf:2048")
    relay = StallRelay(port)
    subscriber = subprocess.Popen(
        [sys.executable, str(SUBSCRIBER), keys.fused_skeletons(RIG), str(relay.port), str(tmp_path / "sub.json")],
        stdout=subprocess.PIPE,
        start_new_session=True,
    )
    stop = threading.Event()
    publisher_thread: threading.Thread | None = None
    try:
        assert subscriber.stdout is not None and subscriber.stdout.readline().strip() == b"subscribed"
        subscriber.stdout.close()
        frames = synthetic_frames(4, 90, seed=run, n_people=8)  # ~17 KB fused frames: the link fills fast
        publishers = {
            f.sensor_id: listener.session.declare_publisher(keys.sensor_skeletons(RIG, f.sensor_id)) for f in frames[0]
        }

        def publish() -> None:
            base_us, start, k = time.time_ns() // 1000, time.monotonic(), 0
            while not stop.is_set():
                time.sleep(max(0.0, start + k / 30.0 - time.monotonic()))
                for i, f in enumerate(frames[k % len(frames)]):
                    stamped = dataclasses.replace(
                        f,
                        sequence=k,
                        device_time_us=base_us + round(k * 1e6 / 30) + 160 * i,
                        host_time_ns=time.time_ns(),
                    )
                    publishers[f.sensor_id].put(encode_sensor_frame(stamped))
                k += 1

        publisher_thread = threading.Thread(target=publish, daemon=True)
        publisher_thread.start()
        listener.wait_for(
            lambda: relay.forwarded > 0, 30.0, "fused frames through the relay", lambda: processes.log(node)
        )
        relay.pause()
        listener.wait_for(
            lambda: fused_publish(listener).get("reached_bound", 0) >= 1,
            30.0,
            "a fused put that waited its whole bound (a full link)",
            lambda: processes.log(node),
        )
        started = time.monotonic()
        os.killpg(node.pid, signal.SIGTERM)
        rc = node.wait(DRAIN_TIMEOUT_S + 20.0)
        took_s = time.monotonic() - started
        log = processes.log(node)
        print(f"run {run}: the node exited {took_s:.2f} s after SIGTERM, status {rc}")
        assert rc == 0, log
        assert took_s <= DRAIN_TIMEOUT_S + MARGIN_S, f"stopped in {took_s:.2f} s:\n{log}"
        assert "fusion node fusion stopped" in log
    finally:
        stop.set()
        if publisher_thread is not None:  # it puts on the listener's session: done before that closes
            publisher_thread.join(10.0)
        relay.close()
        os.killpg(subscriber.pid, signal.SIGKILL)
        subscriber.wait(10)
        if subscriber.stdout is not None:
            subscriber.stdout.close()
        listener.close()
