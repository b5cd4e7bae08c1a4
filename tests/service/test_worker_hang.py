"""A capture worker whose body tracker hangs or stalls, against the fake libk4a / libk4abt compiled from C.

Real ``skelfuse capture`` processes (``tests/fake_k4a/run_skelfuse.py``: the fake ``pyk4a`` module in place of
the real one, the compiled fake libk4abt loaded through ``SKELFUSE_K4ABT_LIBRARY``), all started at once. The
fake's ``FAKE_K4ABT_FAULT`` makes a tracker's ``k4abt_tracker_pop_result`` never return after some results
(``hang``) or time out for ever (``stall``):

- a hung read on the first tracker: the watchdog abandons it and restarts the source, which publishes again;
- a tracker that stops producing results: the Kinect source's own diagnosis, with the config's timeout;
- SIGTERM while a read hangs: the worker still stops at once (exit 0) and within the unit's TimeoutStopSec;
- every tracker hangs: the worker gives up and exits 1, for systemd's ``Restart=on-failure`` (the unit says so).
"""

from __future__ import annotations

import configparser
import contextlib
import importlib.util
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from skelfuse.service.worker import MAX_FAILURES_WHILE_HUNG
from skelfuse.service.zenoh_io import loopback_args

pytestmark = pytest.mark.live

ROOT = Path(__file__).resolve().parents[2]
RUNNER = ROOT / "tests" / "fake_k4a" / "run_skelfuse.py"
UNIT = ROOT / "config" / "systemd" / "skelfuse-capture@.service"
RUN_TIMEOUT_S = 90.0
HANG_LINE = "hangs in k4abt_tracker_pop_result"


def _build_module():
    spec = importlib.util.spec_from_file_location("skelfuse_fake_k4a_build", ROOT / "tests" / "fake_k4a" / "build.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault(spec.name, module)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def fake_libs(tmp_path_factory):
    if shutil.which("gcc") is None:
        pytest.skip("gcc is not on PATH: cannot compile the fake libk4a / libk4abt these tests run against")
    return _build_module().build_fake_libs(tmp_path_factory.mktemp("fake_k4a_hang"), "1.1")


def _rig(path: Path, *, stall_timeout_s: float | None = None) -> Path:
    text = (
        '[rig]\nname = "hang"\n[sync]\nby = "host"\n[zenoh]\nmulticast_scouting = false\n'
        '[[sensors]]\nid = "k1"\nsource = "kinect"\nsync = { role = "standalone" }\n'
        'kinect = { serial = "000111", tracker = { processing_mode = "cpu" } }\n'
    )
    if stall_timeout_s is not None:
        text += f"[capture]\nstall_timeout_s = {stall_timeout_s}\n"
    path.write_text(text, encoding="utf-8")
    return path


@dataclass
class Worker:
    name: str
    fault: str
    args: list[str]
    sigterm_on: str | None = None
    env: dict[str, str] = field(default_factory=dict)
    process: subprocess.Popen[bytes] | None = None
    log_path: Path | None = None
    sigterm_at: float | None = None
    exited_at: float | None = None

    def log(self) -> str:
        assert self.log_path is not None
        return self.log_path.read_text(errors="replace")

    def summary(self) -> dict[str, int]:
        text = self.log()
        return json.loads(text[text.index("{") : text.rindex("}") + 1])


def _run_all(workers: list[Worker], tmp_path: Path, libs) -> None:
    base_env = os.environ | {"FAKE_K4A_LIBRARY": str(libs.k4a), "SKELFUSE_K4ABT_LIBRARY": str(libs.k4abt)}
    try:
        for w in workers:
            w.log_path = tmp_path / f"{w.name}.log"
            with open(w.log_path, "wb") as log:
                w.process = subprocess.Popen(
                    [sys.executable, str(RUNNER), "capture", "--sensor", "k1", "--json", *w.args, *loopback_args()],
                    stdin=subprocess.DEVNULL,
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    start_new_session=True,
                    env=base_env | {"FAKE_K4ABT_FAULT": w.fault},
                )
        deadline = time.monotonic() + RUN_TIMEOUT_S
        while time.monotonic() < deadline and any(w.exited_at is None for w in workers):
            time.sleep(0.05)
            for w in workers:
                assert w.process is not None
                if w.exited_at is not None:
                    continue
                if w.process.poll() is not None:
                    w.exited_at = time.monotonic()
                elif w.sigterm_on and w.sigterm_at is None and w.sigterm_on in w.log():
                    os.killpg(w.process.pid, signal.SIGTERM)
                    w.sigterm_at = time.monotonic()
    finally:
        for w in workers:
            if w.process is not None and w.process.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(w.process.pid, signal.SIGUSR1)  # stacks into the log, then kill
                    time.sleep(0.3)
                    os.killpg(w.process.pid, signal.SIGKILL)
                w.process.wait(5.0)


def _unit_stop_timeout_s() -> float:
    unit = configparser.ConfigParser(strict=False, interpolation=None)
    unit.optionxform = str  # type: ignore[assignment, method-assign]
    unit.read(UNIT)
    assert unit["Service"]["Restart"] == "on-failure", "a worker that exits 1 or crashes must be restarted"
    return float(unit["Service"]["TimeoutStopSec"])


def test_a_hung_or_stalled_tracker_is_restarted_and_a_hung_read_never_blocks_the_stop(tmp_path: Path, fake_libs):
    stop_timeout_s = _unit_stop_timeout_s()
    flag_rig = str(_rig(tmp_path / "rig.toml"))
    workers = [
        # the first tracker hangs after 20 results; the timeout comes from the config's [capture] table
        Worker("hang-once", "hang:20:1", ["--config", str(_rig(tmp_path / "rig1.toml", stall_timeout_s=1.0))]),
        Worker("stall-once", "stall:20:1", ["--config", flag_rig, "--stall-timeout", "1", "--duration", "6"]),
        Worker("hang-sigterm", "hang:20", ["--config", flag_rig, "--stall-timeout", "60"], sigterm_on=HANG_LINE),
        Worker("hang-always", "hang:5", ["--config", flag_rig, "--stall-timeout", "0.5"]),
    ]
    workers[0].args += ["--duration", "6"]
    _run_all(workers, tmp_path, fake_libs)
    by_name = {w.name: w for w in workers}
    for w in workers:
        assert w.exited_at is not None, f"{w.name}: still running after {RUN_TIMEOUT_S:.0f} s\n{w.log()[-3000:]}"
        assert "Traceback" not in w.log(), f"{w.name}: a traceback reached the user\n{w.log()[-3000:]}"

    hang_once = by_name["hang-once"]
    log = hang_once.log()
    assert hang_once.process.returncode == 0, log[-3000:]
    assert log.count(HANG_LINE) == 1 and "its thread is abandoned" in log, log[-3000:]
    summary = hang_once.summary()
    assert summary["stalls"] == 1 and summary["restarts"] == 1, summary
    assert summary["frames_out"] >= 20 + 30, summary  # the restarted source published (a second of frames at least)

    stall_once = by_name["stall-once"]
    log = stall_once.log()
    assert stall_once.process.returncode == 0, log[-3000:]
    assert "TrackerStalled" in log and "returned nothing for 1." in log, log[-3000:]  # the flag's 1 s reached it
    summary = stall_once.summary()
    assert summary["stalls"] == 1 and summary["restarts"] == 1 and summary["frames_out"] >= 20 + 30, summary

    hung = by_name["hang-sigterm"]
    log = hung.log()
    assert hung.sigterm_at is not None, log[-3000:]
    assert hung.process.returncode == 0, log[-3000:]
    assert hung.exited_at - hung.sigterm_at < stop_timeout_s, (hung.exited_at - hung.sigterm_at, log[-3000:])
    assert "read of its source still blocked (left behind)" in log, log[-3000:]
    assert hung.summary()["frames_out"] == 20

    always = by_name["hang-always"]
    log = always.log()
    assert always.process.returncode == 1, log[-3000:]
    assert log.count(HANG_LINE) == MAX_FAILURES_WHILE_HUNG + 1, log[-3000:]
    assert "Restart=on-failure" in log, log[-3000:]
