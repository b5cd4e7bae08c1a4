"""``skelfuse demo`` as a real process, stopped by SIGTERM in the middle of its run (it prints its summary: what it
scored so far, saying the pass was cut short) or while its workers start (it says there is nothing to summarize):
either way it stops its capture workers and exits 0 (docs/service.md, "Exit codes": a clean stop by signal)
within the stop bound its own watchdog enforces, leaving no worker behind. Both demos run at once.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from skelfuse.service.lifecycle import STOP_TIMEOUT_S

pytestmark = pytest.mark.live

START_TIMEOUT_S = 120.0
"""Import, four workers and the take origin (8 s) on a loaded machine; a hang beyond it fails the test."""
RUN_STARTED = "the run starts:"
SCORED_S = 2.5
"""SIGTERM this long after the run started: past the 1.5 s of a pass that are not scored."""


def _children(pid: int) -> list[int]:
    children = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, ValueError, IndexError):
            fields = stat.read_text().rsplit(")", 1)[1].split()
            if int(fields[1]) == pid:
                children.append(int(stat.parent.name))
    return children


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@dataclass
class Demo:
    """One ``skelfuse demo`` process, sent SIGTERM ``after_s`` seconds after the line ``trigger`` appears."""

    name: str
    trigger: str
    after_s: float
    process: subprocess.Popen[bytes] | None = None
    err_path: Path | None = None
    out_path: Path | None = None
    workers: list[int] = field(default_factory=list)
    trigger_seen: float | None = None
    sent: float | None = None
    exited: float | None = None

    def log(self) -> str:
        assert self.err_path is not None
        return self.err_path.read_text(errors="replace")


def _run(demos: list[Demo], tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    try:
        for d in demos:
            d.err_path, d.out_path = tmp_path / f"{d.name}.err", tmp_path / f"{d.name}.json"
            with open(d.err_path, "wb") as err, open(d.out_path, "wb") as out:
                command = [sys.executable, "-m", "skelfuse", "demo", "--duration", "300", "--take", "3"]
                d.process = subprocess.Popen(
                    [*command, "--rrd", str(tmp_path / f"{d.name}.rrd"), "--json"],
                    stdin=subprocess.DEVNULL,
                    stdout=out,
                    stderr=err,
                    start_new_session=True,
                    env=env,
                )
        deadline = time.monotonic() + START_TIMEOUT_S + STOP_TIMEOUT_S + 10.0
        while any(d.exited is None for d in demos):
            assert time.monotonic() < deadline, "\n\n".join(f"{d.name}:\n{d.log()[-2000:]}" for d in demos)
            time.sleep(0.05)
            for d in demos:
                assert d.process is not None
                now = time.monotonic()
                if d.exited is not None:
                    continue
                if d.process.poll() is not None:
                    d.exited = now
                    assert d.sent is not None, f"{d.name} exited before SIGTERM:\n{d.log()[-3000:]}"
                elif d.trigger_seen is None and d.trigger in d.log():
                    d.trigger_seen = now
                elif d.sent is None and d.trigger_seen is not None and now >= d.trigger_seen + d.after_s:
                    d.workers = _children(d.process.pid)
                    d.sent = time.monotonic()
                    os.kill(d.process.pid, signal.SIGTERM)
    finally:
        for d in demos:
            if d.process is not None and d.process.poll() is None:
                d.workers = d.workers or _children(d.process.pid)  # in their own sessions: killed below
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(d.process.pid, signal.SIGUSR1)  # stacks into the log
                    time.sleep(0.5)
                    os.killpg(d.process.pid, signal.SIGKILL)
                d.process.wait(5.0)
            for pid in d.workers:
                if _running(pid):
                    with contextlib.suppress(ProcessLookupError):
                        os.killpg(pid, signal.SIGKILL)


def test_demo_stops_on_sigterm_with_its_summary_and_status_0(tmp_path: Path) -> None:
    running = Demo("running", RUN_STARTED, SCORED_S)
    starting = Demo("starting", "publishing on skelfuse/demo/fused", 0.0)  # the node is up, workers start
    _run([running, starting], tmp_path)
    for d in (running, starting):
        log = d.log()
        assert d.process is not None and d.process.returncode == 0, (d.name, log[-3000:])
        assert d.exited - d.sent < STOP_TIMEOUT_S, (d.name, d.exited - d.sent, log[-3000:])
        assert "received SIGTERM" in log and "Traceback" not in log, (d.name, log[-3000:])
        assert not [pid for pid in d.workers if _running(pid)], f"{d.name}: capture workers left running"
    assert len(running.workers) == 4, running.workers
    summary = json.loads(running.out_path.read_text())
    assert summary["frames_fused"] > 0 and 0 < summary["duration_s"] < 300.0, summary
    assert summary["frames_scored"] > 0 and summary["partial_pass"] is True, summary
    assert "stopped before the first fused frame; nothing to summarize" in starting.log()
    assert starting.out_path.read_text() == ""
