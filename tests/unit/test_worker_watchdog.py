"""The capture worker's watchdog restarts a source whose tracker stalled or crashed, and its status says so.

The source is a stand-in for a Kinect whose body tracker stops producing results (it keeps answering its
read timeouts with nothing) or raises; the worker runs for real on a loopback zenoh session and its status
messages are read back over zenoh.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from skelfuse.config import load_rig_config
from skelfuse.service.lifecycle import Lifecycle, RunLimits
from skelfuse.service.worker import WorkerOptions, run_capture_worker
from skelfuse.service.zenoh_io import free_port, loopback_config
from skelfuse.wire import keys
from skelfuse.wire.codec import decode_status
from waiting import wait_until

SIM_RIG = Path(__file__).resolve().parents[2] / "config" / "rig-sim-4.toml"


class StalledTracker:
    """Yields nothing but read timeouts (a tracker that stopped), then, on its second start, raises (a crash)."""

    stamps_host_time = True

    def __init__(self) -> None:
        self.sensor_id = "capture_0"
        self.starts = 0

    def frames(self) -> Iterator[tuple[int, Any]]:
        self.starts += 1
        if self.starts == 2:
            raise RuntimeError("k4abt_tracker_pop_result() failed")
        while True:
            time.sleep(0.02)
            yield time.monotonic_ns(), None


@pytest.mark.live
def test_a_stalled_or_crashed_tracker_is_restarted_and_status_says_so() -> None:
    cfg = load_rig_config(SIM_RIG)
    port = free_port()
    statuses: list[Any] = []
    source = StalledTracker()
    # No run limit: the worker runs until the statuses have said what the test waits for, then it is stopped.
    options = WorkerOptions(stall_timeout_s=0.4, status_period_s=0.2)
    lifecycle = Lifecycle("w")
    report: dict[str, Any] = {}

    def errors() -> set[str]:
        return {s.info.get("last_error") or "" for s in list(statuses)}

    with zenoh.open(loopback_config(listen_port=port)) as session:
        session.declare_subscriber(
            keys.status(cfg.name, "capture-capture_0"), lambda s: statuses.append(decode_status(s.payload.to_bytes()))
        )
        worker = threading.Thread(
            target=lambda: report.update(
                r=run_capture_worker(
                    cfg, "capture_0", loopback_config(connect_ports=[port]), options=options, lifecycle=lifecycle,
                    source=source,
                )
            ),
            daemon=True,
        )  # fmt: skip
        worker.start()
        try:
            wait_until(
                lambda: (
                    source.starts >= 3
                    and any("SourceStalled" in e and "watchdog" in e for e in errors())
                    and any("k4abt_tracker_pop_result() failed" in e for e in errors())
                ),
                "a status naming the stall, then one naming the crash, and the third start",
                details=lambda: str(errors()),
            )
        finally:
            lifecycle.request_exit()
            worker.join(30.0)
    assert not worker.is_alive()
    result = report["r"]
    assert source.starts >= 3  # stalled -> restarted -> crashed -> restarted again
    assert result.stalls >= 1 and result.restarts >= 2
    assert any(s.state == "degraded" for s in statuses)
    assert max(s.counters.get("stalls", 0) for s in statuses) >= 1


class HangsWhileOpening:
    """A source whose start never answers on its first run (an SDK open that hangs), then delivers frames."""

    stamps_host_time = True

    def __init__(self) -> None:
        self.sensor_id = "capture_0"
        self.starts = 0
        self.release = threading.Event()

    def frames(self) -> Iterator[tuple[int, Any]]:
        self.starts += 1
        if self.starts == 1:
            self.release.wait()  # a device open that never returns (released at the end of the test)
            return
        yield time.monotonic_ns(), None  # opened: the stall watchdog takes over from here
        while True:
            time.sleep(0.02)
            yield time.monotonic_ns(), None


@pytest.mark.live
def test_a_source_that_hangs_while_opening_is_restarted_after_the_open_timeout() -> None:
    cfg = load_rig_config(SIM_RIG)
    source = HangsWhileOpening()
    options = WorkerOptions(
        open_timeout_s=0.5, stall_timeout_s=30.0, status_period_s=0.2, limits=RunLimits(duration_s=2.5)
    )
    port = free_port()
    try:
        with zenoh.open(loopback_config(listen_port=port)):
            started = time.monotonic()
            report = run_capture_worker(
                cfg,
                "capture_0",
                loopback_config(connect_ports=[port]),
                options=options,
                lifecycle=Lifecycle("w"),
                source=source,
            )
            took = time.monotonic() - started
    finally:
        source.release.set()
    assert source.starts >= 2, "the hung open was not given up"
    assert report.stalls >= 1 and report.restarts >= 1
    assert took < 10.0  # --duration still ends the run, the abandoned open notwithstanding


def test_the_open_timeout_is_a_config_key_with_a_generous_default(tmp_path: Path) -> None:
    assert load_rig_config(SIM_RIG).capture.open_timeout_s == 120.0
    rig = tmp_path / "rig.toml"
    rig.write_text(SIM_RIG.read_text() + "\n[capture]\nopen_timeout_s = 45\n")
    assert load_rig_config(rig).capture.open_timeout_s == 45.0
