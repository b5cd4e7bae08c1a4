"""``skelfuse demo`` as a real process, stopped by SIGTERM in the middle of its run: it stops its four capture
workers, prints its summary (what it scored so far, saying the pass was cut short) and exits 0 (docs/service.md,
"Exit codes": a clean stop by signal) within the stop bound its own watchdog enforces, leaving no worker behind.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from skelfuse.service.lifecycle import STOP_TIMEOUT_S

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


def test_demo_stops_on_sigterm_with_its_summary_and_status_0(tmp_path: Path) -> None:
    err_path, out_path = tmp_path / "demo.err", tmp_path / "demo.json"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    with open(err_path, "wb") as err, open(out_path, "wb") as out:
        process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "skelfuse",
                "demo",
                "--duration",
                "300",
                "--take",
                "3",
                "--rrd",
                str(tmp_path / "d.rrd"),
                "--json",
            ],
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=err,
            start_new_session=True,
            env=env,
        )
    workers: list[int] = []
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while RUN_STARTED not in err_path.read_text(errors="replace"):
            assert process.poll() is None, f"the demo exited early:\n{err_path.read_text()[-3000:]}"
            assert time.monotonic() < deadline, f"the run did not start:\n{err_path.read_text()[-3000:]}"
            time.sleep(0.1)
        time.sleep(SCORED_S)
        workers = _children(process.pid)
        sent = time.monotonic()
        os.kill(process.pid, signal.SIGTERM)
        try:
            process.wait(STOP_TIMEOUT_S + 10.0)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGUSR1)  # stacks into the log
            time.sleep(0.5)
            raise AssertionError(f"the demo did not stop on SIGTERM:\n{err_path.read_text()[-3000:]}") from None
        stopped_s = time.monotonic() - sent
    finally:
        if process.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
            process.wait(5.0)
        for pid in workers:
            if _running(pid):
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(pid, signal.SIGKILL)
    log = err_path.read_text(errors="replace")
    assert process.returncode == 0, log[-3000:]
    assert stopped_s < STOP_TIMEOUT_S, (stopped_s, log[-3000:])
    assert "received SIGTERM" in log and "Traceback" not in log, log[-3000:]
    assert len(workers) == 4, workers
    assert not [pid for pid in workers if _running(pid)], "capture workers left running"
    summary = json.loads(out_path.read_text())
    assert summary["frames_fused"] > 0 and 0 < summary["duration_s"] < 300.0, summary
    assert summary["frames_scored"] > 0 and summary["partial_pass"] is True, summary
