"""Helpers for the live-service tests: real ``python -m skelfuse`` processes and zenoh on loopback.

Every node listens or connects on ``tcp/127.0.0.1`` with a free port, multicast scouting off; every wait has
a timeout; every process is started in its own process group and killed at teardown.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from process_groups import kill_group, stop_group
from skelfuse.apps.demo import sim_sensor_tables
from skelfuse.service.zenoh_io import free_port, loopback_args, loopback_config, wait_for_port
from skelfuse.wire import keys
from skelfuse.wire.codec import DecodeError, decode_fused_frame, decode_sensor_frame, decode_status
from waiting import SCHEDULING_ALLOWANCE_S, wait_until

RIG = "svc"


def write_rig(
    directory: Path,
    *,
    by: str = "device",
    deadline_ms: float = 17.0,
    tolerance_ms: float | None = None,
    status_period_s: float = 0.25,
    n_sensors: int = 4,
    sim_clocks: dict[int, tuple[float, float]] | None = None,
    max_lag_s: float = SCHEDULING_ALLOWANCE_S,
) -> Path:
    """A sim rig; ``sim_clocks``: sensor index -> (clock offset ms, clock jitter ms) of its emulated PC.
    ``max_lag_s``: the node's lag bound; by default as long as a starved machine may hold a thread, so tests
    that count every instant lose none to a stall (the overload test passes the product's default)."""
    tolerance = tolerance_ms if tolerance_ms is not None else (10.0 if by == "device" else 13.0)
    lines = [
        "[rig]",
        f'name = "{RIG}"',
        "",
        "[sync]",
        f'by = "{by}"',
        "fps = 30.0",
        f"tolerance_ms = {tolerance}",
        f"deadline_ms = {deadline_ms}",
        "",
        "[node]",
        f"status_period_s = {status_period_s}",
        f"max_lag_s = {max_lag_s}",
        "",
        "[zenoh]",
        "multicast_scouting = false",
        "",
    ]
    clocks = {
        index: [f"sim = {{ clock_offset_ms = {offset_ms}, clock_jitter_ms = {jitter_ms} }}"]
        for index, (offset_ms, jitter_ms) in (sim_clocks or {}).items()
    }
    lines += sim_sensor_tables(n_sensors, clocks)
    path = directory / f"rig-{by}.toml"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


class Processes:
    """Starts ``python -m skelfuse ...`` in new process groups; kills whatever is left at teardown."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.started: list[subprocess.Popen[bytes]] = []

    def start(self, name: str, *args: str, via: Sequence[str] = ("-m", "skelfuse")) -> subprocess.Popen[bytes]:
        """``python -m skelfuse ARGS`` (``via``: what runs instead of ``-m skelfuse``, e.g. a test's launcher)."""
        log = open(self.log_dir / f"{name}.log", "ab")
        process = subprocess.Popen(
            [sys.executable, *via, *args],
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        process.log_file = log  # type: ignore[attr-defined]
        process.log_path = self.log_dir / f"{name}.log"  # type: ignore[attr-defined]
        self.started.append(process)
        return process

    def log(self, process: subprocess.Popen[bytes]) -> str:
        return Path(process.log_path).read_text(errors="replace")[-3000:]  # type: ignore[attr-defined]

    def stop(self, process: subprocess.Popen[bytes], sig: int = signal.SIGTERM, timeout_s: float = 15.0) -> int:
        if not stop_group(process, sig, timeout_s, dump_stacks=True):
            raise AssertionError(f"process did not stop within {timeout_s} s:\n{self.log(process)}")
        process.log_file.close()  # type: ignore[attr-defined]
        return int(process.returncode)

    def cleanup(self) -> None:
        for process in self.started:
            kill_group(process)
            if not process.log_file.closed:  # type: ignore[attr-defined]
                process.log_file.close()  # type: ignore[attr-defined]


class Listener:
    """An in-test zenoh session connected to the node: collects sensor frames, fused frames, statuses."""

    def __init__(self, port: int) -> None:
        import zenoh

        self.port = free_port()  # workers connect here too, so no frame depends on gossip timing
        self.lock = threading.Lock()
        self.sensor_payloads: list[bytes] = []
        self.fused: list[tuple[float, Any]] = []  # (monotonic receive time, FusedFrame)
        self.statuses: list[Any] = []
        self.session = zenoh.open(loopback_config(listen_port=self.port, connect_ports=[port]))
        self.session.declare_subscriber(keys.all_sensor_skeletons(RIG), self._on_sensor)
        self.session.declare_subscriber(keys.fused_skeletons(RIG), self._on_fused)
        self.session.declare_subscriber(keys.all_status(RIG), self._on_status)

    def _on_sensor(self, sample: Any) -> None:
        with self.lock:
            self.sensor_payloads.append(sample.payload.to_bytes())

    def _on_fused(self, sample: Any) -> None:
        now = time.monotonic()
        frame = decode_fused_frame(sample.payload.to_bytes())
        with self.lock:
            self.fused.append((now, frame))

    def _on_status(self, sample: Any) -> None:
        try:
            status = decode_status(sample.payload.to_bytes())
        except DecodeError:
            return
        with self.lock:
            self.statuses.append(status)

    def fusion_status(self) -> Any:
        with self.lock:
            found = [s for s in self.statuses if s.role == "fusion"]
        return found[-1] if found else None

    def wait_for(
        self, predicate: Callable[[], bool], timeout_s: float, what: str, logs: Callable[[], str] = str
    ) -> None:
        wait_until(predicate, what, timeout_s, logs)

    def sensor_frames(self) -> list[Any]:
        with self.lock:
            return [decode_sensor_frame(p) for p in self.sensor_payloads]

    def close(self) -> None:
        self.session.close()


def node_args(config: Path, port: int, *extra: str) -> list[str]:
    return ["fuse", "--config", str(config), "--no-view", "--duration", "120", *extra, *loopback_args(listen_port=port)]


def worker_args(config: Path, port: int, sensor_id: str, *extra: str, listener: Listener | None = None) -> list[str]:
    ports = [port] if listener is None else [port, listener.port]
    return [
        "capture",
        "--config",
        str(config),
        "--sensor",
        sensor_id,
        "--take-duration",
        "4",
        *extra,
        *loopback_args(connect_ports=ports),
    ]


def start_node(
    processes: Processes, config: Path, port: int, *extra: str, via: Sequence[str] = ("-m", "skelfuse")
) -> tuple[subprocess.Popen[bytes], Listener]:
    """The node as a subprocess (``via``: see :meth:`Processes.start`), and a listener that has seen its first
    status (so it is subscribed)."""
    node = processes.start("node", *node_args(config, port, *extra), via=via)
    assert wait_for_port(port, timeout_s=60.0), f"the node never listened on {port}:\n{processes.log(node)}"
    listener = Listener(port)
    listener.wait_for(
        lambda: listener.fusion_status() is not None,
        60.0,
        "the fusion node's first status",
        lambda: processes.log(node),
    )
    return node, listener


def publish_common_stretch(
    processes: Processes, listener: Listener, config: Path, port: int, sensors: Sequence[str], n_frames: int
) -> None:
    """Sim workers for ``sensors`` run until each published ``n_frames`` since the last of them started (their
    common stretch; on a loaded machine they start seconds apart), then stop; returns once the node's status
    counts every frame the listener saw (a starved node may still be behind)."""

    def overlap_frames() -> int:
        frames = listener.sensor_frames()
        firsts = [min((f.device_time_us for f in frames if f.sensor_id == s), default=None) for s in sensors]
        if None in firsts:
            return 0
        common = max(t for t in firsts if t is not None)
        return min(sum(1 for f in frames if f.sensor_id == s and f.device_time_us >= common) for s in sensors)

    workers = [
        processes.start(f"w{i}", *worker_args(config, port, s, listener=listener)) for i, s in enumerate(sensors)
    ]
    listener.wait_for(lambda: overlap_frames() >= n_frames, 120.0, f"{n_frames} frames from every sensor at once")
    for worker in workers:
        assert processes.stop(worker) == 0, processes.log(worker)

    def node_caught_up() -> bool:
        status = listener.fusion_status()
        seen = Counter(f.sensor_id for f in listener.sensor_frames())
        return status is not None and all(status.info["sensors"][s]["received"] == seen[s] for s in sensors)

    listener.wait_for(node_caught_up, 60.0, "the node to take in every published frame")
