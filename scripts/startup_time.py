#!/usr/bin/env python3
"""Start-up of the command line and the daemons, against another checkout in the same run.

For each tree (this one and ``--baseline SRC``, alternating run by run so both see the same load): the median
wall time of ``skelfuse [CMD] --help`` and the time from launching ``skelfuse fuse`` / ``skelfuse capture``
(the simulated rig of config/rig-sim-4.toml, loopback, no view) to its "zenoh session open" log line; and the
restart gap: a running rig's fusion node killed (SIGKILL, as a crash) and relaunched, from the relaunch to
the first fused frame a subscriber receives (both trees' rigs run side by side, two simulated sensors each,
their restarts alternating). The machine's load average is printed before and after: on a shared machine
report the ratio, not the seconds.

Usage::

    python scripts/startup_time.py --baseline ../other-checkout/src [--runs 10] [--quick] [--no-restart]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from skelfuse.apps.demo import sim_sensor_tables
from skelfuse.service.zenoh_io import free_port, loopback_args, loopback_config
from skelfuse.wire import keys

REPO = Path(__file__).resolve().parents[1]
RIG = REPO / "config" / "rig-sim-4.toml"
HELP_COMMANDS = ([], ["fuse"], ["capture"], ["demo"], ["bench"], ["calibrate"], ["export"], ["eval"])
DAEMONS = {
    "fuse": ["fuse", "--config", str(RIG), "--no-view", "--duration", "30"],
    "capture": ["capture", "--config", str(RIG), "--sensor", "capture_0", "--duration", "30"],
}


def help_time(src: str, command: list[str]) -> float:
    started = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "skelfuse", *command, "--help"],
        env={**os.environ, "PYTHONPATH": src},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        check=True,
    )
    return time.perf_counter() - started


def session_open_time(src: str, command: list[str]) -> float:
    """Seconds from launch to the daemon's "zenoh session open" log line (the daemon is stopped after)."""
    started = time.monotonic()
    process = subprocess.Popen(
        [sys.executable, "-m", "skelfuse", *command],
        env={**os.environ, "PYTHONPATH": src},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stderr is not None
        for line in process.stderr:
            if "zenoh session open" in line:
                return time.monotonic() - started
        raise SystemExit(f"{' '.join(command)} exited without opening its session")
    finally:
        process.terminate()
        process.wait(30)


RESTART_SENSORS = 2
RESTART_TIMEOUT_S = 60.0


class RestartRig:
    """One tree's rig on loopback: simulated capture workers, a fusion node that can be killed and relaunched,
    and a zenoh subscriber that notes when fused frames arrive."""

    def __init__(self, src: str, name: str, workdir: Path) -> None:
        import zenoh

        self.env = {**os.environ, "PYTHONPATH": src}
        self.node_port, listen_port = free_port(), free_port()
        rig = workdir / f"rig-{name}.toml"
        rig.write_text(
            "\n".join(
                [
                    f'[rig]\nname = "{name}"\n',
                    "[zenoh]\nmulticast_scouting = false\n",
                    *sim_sensor_tables(RESTART_SENSORS),
                ]
            ),
            encoding="utf-8",
        )
        self.rig = rig
        self.lock = threading.Lock()
        self.last_fused = 0.0
        self.session = zenoh.open(loopback_config(listen_port=listen_port, connect_ports=[self.node_port]))
        self.session.declare_subscriber(keys.fused_skeletons(name), self._on_fused)
        self.node = self._launch_node()
        self.workers = [
            self._start(
                "capture", "--config", str(rig), "--sensor", sensor_id, "--duration", "600",
                *loopback_args(connect_ports=[self.node_port, listen_port]),
            )
            for sensor_id in (f"capture_{i}" for i in range(RESTART_SENSORS))
        ]  # fmt: skip

    def _on_fused(self, sample: Any) -> None:
        with self.lock:
            self.last_fused = time.monotonic()

    def _start(self, *args: str) -> subprocess.Popen[bytes]:
        return subprocess.Popen(
            [sys.executable, "-m", "skelfuse", *args],
            env=self.env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )

    def _launch_node(self) -> subprocess.Popen[bytes]:
        return self._start(
            "fuse", "--config", str(self.rig), "--no-view", "--duration", "600",
            *loopback_args(listen_port=self.node_port),
        )  # fmt: skip

    def fused_after(self, moment: float, timeout_s: float = RESTART_TIMEOUT_S) -> float:
        """The first moment after ``moment`` a fused frame arrived (waits up to ``timeout_s``)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                if self.last_fused > moment:
                    return self.last_fused
            time.sleep(0.005)
        raise SystemExit(f"no fused frame within {timeout_s:.0f} s of {self.rig.name}'s node launch")

    def restart_gap(self) -> float:
        """Kill the node (SIGKILL), relaunch it; seconds from the relaunch to the next fused frame."""
        os.killpg(self.node.pid, signal.SIGKILL)
        self.node.wait(30)
        launched = time.monotonic()
        self.node = self._launch_node()
        return self.fused_after(launched) - launched

    def close(self) -> None:
        for process in [self.node, *self.workers]:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
            process.wait(30)
        self.session.close()


def restart_gaps(trees: dict[str, str], runs: int) -> dict[str, list[float]]:
    """Each tree's restart gaps, ``runs`` each, alternating between the trees' rigs (both running)."""
    gaps: dict[str, list[float]] = {name: [] for name in trees}
    with tempfile.TemporaryDirectory(prefix="skelfuse-startup-") as workdir:
        rigs = {name: RestartRig(src, f"restart-{name}", Path(workdir)) for name, src in trees.items()}
        try:
            for rig in rigs.values():
                rig.fused_after(0.0)  # the rig fuses before the first kill
            for _ in range(runs):
                for name, rig in rigs.items():
                    gaps[name].append(rig.restart_gap())
        finally:
            for rig in rigs.values():
                rig.close()
    return gaps


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", required=True, metavar="SRC", help="the src/ folder to compare against")
    parser.add_argument("--runs", type=int, default=10, help="runs per command and tree (default: 10)")
    parser.add_argument("--quick", action="store_true", help="only `skelfuse --help`, `fuse --help` and the daemons")
    parser.add_argument("--no-restart", action="store_true", help="leave out the node's restart gap")
    args = parser.parse_args()
    trees = {"baseline": str(Path(args.baseline).resolve()), "this": str(REPO / "src")}
    print(f"load average before: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")
    commands = HELP_COMMANDS[:2] if args.quick else HELP_COMMANDS
    rows = [(f"skelfuse {' '.join(c)} --help".replace("  ", " "), help_time, c) for c in commands]
    rows += [(f"skelfuse {name}: launch -> zenoh session open", session_open_time, c) for name, c in DAEMONS.items()]
    for label, measure, command in rows:
        times: dict[str, list[float]] = {name: [] for name in trees}
        for _ in range(args.runs):
            for name, src in trees.items():
                times[name].append(measure(src, command))
        base, this = (statistics.median(times[name]) for name in ("baseline", "this"))
        print(f"{label:<48} baseline {base:6.3f} s  this {this:6.3f} s  baseline/this {base / this:4.1f}x")
    if not args.no_restart:
        gaps = restart_gaps(trees, args.runs)
        base, this = (statistics.median(gaps[name]) for name in ("baseline", "this"))
        label = "skelfuse fuse: kill -9, relaunch -> fused frame"
        print(f"{label:<48} baseline {base:6.3f} s  this {this:6.3f} s  baseline/this {base / this:4.1f}x")
    print(f"load average after: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
