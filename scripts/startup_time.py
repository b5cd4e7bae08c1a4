#!/usr/bin/env python3
"""Start-up of the command line and the daemons, against another checkout in the same run.

For each tree (this one and ``--baseline SRC``, alternating run by run so both see the same load): the median
wall time of ``skelfuse [CMD] --help`` and the time from launching ``skelfuse fuse`` / ``skelfuse capture``
(the simulated rig of config/rig-sim-4.toml, loopback, no view) to its "zenoh session open" log line. The
machine's load average is printed before and after: on a shared machine report the ratio, not the seconds.

Usage::

    python scripts/startup_time.py --baseline ../other-checkout/src [--runs 10] [--quick]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

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


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", required=True, metavar="SRC", help="the src/ folder to compare against")
    parser.add_argument("--runs", type=int, default=10, help="runs per command and tree (default: 10)")
    parser.add_argument("--quick", action="store_true", help="only `skelfuse --help`, `fuse --help` and the daemons")
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
    print(f"load average after: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
