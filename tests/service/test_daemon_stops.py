"""Every daemon stops, with the right exit status, within a bound after its stop began, whatever a sink or a
peer does: a viewer that cannot open (no display), a viewer that accepts the connection and never answers, an
unreachable zenoh router (every daemon: fuse, capture, record, status, replay, stream), a router whose port is
taken, a recorder or a saved view whose disk is full (/dev/full), a Kinect master on a machine without the SDKs.

Real ``python -m skelfuse`` processes, all started at once (they spend most of their time importing), each
watched for the log line that says its stop began; the bound is measured from that line to the process's
exit, so a slow start on a loaded machine does not count against it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from service_helpers import RIG, write_rig

from skelfuse.config import load_rig_config
from skelfuse.recording import RecordingWriter
from skelfuse.service.worker import SimSource
from skelfuse.service.zenoh_io import free_port, loopback_args

pytestmark = pytest.mark.live

STOP_BOUND_S = 12.0
"""Start of the stop -> process gone: drain 2 s + view flush 2 s + view release 2 s + exit grace 5 s, rounded up."""
RUN_TIMEOUT_S = 90.0
"""Whole test: processes still running then are a hang (killed, reported with their log)."""
DURATION = "3"


@dataclass
class Daemon:
    name: str
    args: list[str]
    expect_rc: int
    trigger: str
    """Log line (substring) that says the stop began."""
    env: dict[str, str] = field(default_factory=dict)
    sigterm_after: str | None = None
    """Send SIGTERM once this log line appears (None: the daemon stops by itself)."""
    expect_log: tuple[str, ...] = ()
    process: subprocess.Popen[bytes] | None = None
    log_path: Path | None = None
    triggered_at: float | None = None
    exited_at: float | None = None
    signalled: bool = False

    def log(self) -> str:
        assert self.log_path is not None
        return self.log_path.read_text(errors="replace")


def _unreachable() -> list[str]:
    """zenoh flags of a client whose router is not there (a closed loopback port)."""
    return ["--zenoh-mode", "client", "--no-multicast-scouting", "--zenoh-connect", f"tcp/127.0.0.1:{free_port()}"]


def _recording(path: Path, rig: Path) -> Path:
    cfg = load_rig_config(rig)
    source = SimSource(cfg, cfg.sensor_ids[0], take_duration_s=2.0, loop=False, clock_ns=lambda: 10**18)
    with RecordingWriter(path, rig=cfg.name, sensor_ids=cfg.sensor_ids[:1]) as writer:
        for n in range(30):
            frame = source.frame_at(n)
            if frame is not None:
                writer.write(dataclasses.replace(frame, host_time_ns=10**18 + n * 33_333_333))
    return path


@pytest.fixture
def black_hole() -> object:
    """A TCP port that accepts connections and never answers (a viewer that hangs)."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(64)
    yield sock.getsockname()[1]
    sock.close()


@pytest.fixture
def busy_port() -> object:
    """A loopback TCP port another program listens on (a router cannot listen there)."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(1)
    yield sock.getsockname()[1]
    sock.close()


def _run_all(daemons: list[Daemon], tmp_path: Path) -> None:
    base_env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    try:
        for d in daemons:
            d.log_path = tmp_path / f"{d.name}.log"
            with open(d.log_path, "wb") as log:
                d.process = subprocess.Popen(
                    [sys.executable, "-m", "skelfuse", *d.args],
                    stdin=subprocess.DEVNULL,
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    start_new_session=True,
                    env=base_env | d.env,
                )
        deadline = time.monotonic() + RUN_TIMEOUT_S
        while time.monotonic() < deadline and any(d.exited_at is None for d in daemons):
            time.sleep(0.05)
            for d in daemons:
                if d.exited_at is not None:
                    continue
                assert d.process is not None
                now = time.monotonic()
                if d.process.poll() is not None:
                    d.exited_at = now
                text = d.log()
                if d.sigterm_after and not d.signalled and d.sigterm_after in text:
                    os.killpg(d.process.pid, signal.SIGTERM)
                    d.signalled = True
                if d.triggered_at is None and d.trigger in text:
                    d.triggered_at = now
    finally:
        for d in daemons:
            if d.process is not None and d.process.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(d.process.pid, signal.SIGUSR1)  # stacks into the log, then kill
                    time.sleep(0.3)
                    os.killpg(d.process.pid, signal.SIGKILL)
                d.process.wait(5.0)


def test_every_daemon_stops_in_bounded_time_whatever_its_sink_or_peer_does(
    tmp_path: Path, black_hole: int, busy_port: int
) -> None:
    rig = write_rig(tmp_path)
    spawn_rig = tmp_path / "spawn-rig.toml"
    spawn_rig.write_text(rig.read_text() + '\n[rerun]\nmode = "spawn"\n', encoding="utf-8")
    kinect_rig = tmp_path / "kinect-rig.toml"
    kinect_rig.write_text(
        '[rig]\nname = "k"\n[sync]\nby = "host"\n[zenoh]\nmulticast_scouting = false\n'
        '[[sensors]]\nid = "m1"\nsource = "kinect"\nsync = { role = "master" }\n'
        '[[sensors]]\nid = "s1"\nsource = "kinect"\nsync = { role = "subordinate", delay_us = 160 }\n',
        encoding="utf-8",
    )
    recording = _recording(tmp_path / "take.mcap", rig)
    no_session = "no zenoh session before the end of --duration"
    fuse_ready = f"publishing on skelfuse/{RIG}/fused"
    daemons = [
        Daemon(
            "fuse-no-display",
            ["fuse", "--config", str(spawn_rig), "--duration", DURATION, *loopback_args()],
            0,
            "--duration 3.0 s reached",
            expect_log=("cannot open a viewer (no display here",),
        ),
        Daemon(
            "fuse-hung-viewer",
            ["fuse", "--config", str(rig), "--spawn", "--grpc-port", str(black_hole), *loopback_args()],
            0,
            "received SIGTERM",
            env={"DISPLAY": ":99"},
            sigterm_after=fuse_ready,
        ),
        Daemon(
            "fuse-no-router", ["fuse", "--config", str(rig), "--duration", DURATION, *_unreachable()], 0, no_session
        ),
        Daemon(
            "capture-no-router",
            ["capture", "--config", str(rig), "--sensor", "capture_0", "--duration", DURATION, *_unreachable()],
            0,
            no_session,
        ),
        Daemon(
            "capture-kinect-no-sdk",
            ["capture", "--config", str(kinect_rig), "--sensor", "m1", "--duration", "60", *loopback_args()],
            1,
            "capture worker capture-m1: publishing sensor m1",
            expect_log=("pyk4a",),
        ),
        Daemon(
            "record-no-router",
            [
                "record",
                "--config",
                str(rig),
                "--output",
                str(tmp_path / "r.mcap"),
                "--duration",
                DURATION,
                *_unreachable(),
            ],
            0,
            no_session,
        ),
        Daemon(
            "fuse-view-disk-full",
            ["fuse", "--config", str(rig), "--rrd", "/dev/full", "--duration", DURATION, *loopback_args()],
            1,
            "cannot save the view to /dev/full",
        ),
        Daemon(
            "record-disk-full",
            ["record", "--config", str(rig), "--output", "/dev/full", "--duration", DURATION, *loopback_args()],
            1,
            "cannot write the recording /dev/full (No space left on device)",
        ),
        Daemon(
            "status-no-router", ["status", "--config", str(rig), "--duration", DURATION, *_unreachable()], 0, no_session
        ),
        Daemon("replay-no-router", ["replay", str(recording), "--duration", DURATION, *_unreachable()], 0, no_session),
        Daemon(
            "stream-no-router",
            ["stream", "osc", "--config", str(rig), "--duration", DURATION, *_unreachable()],
            0,
            no_session,
        ),
        Daemon(
            "router-port-in-use",
            ["router", "--config", str(rig), "--duration", DURATION, "--zenoh-listen", f"tcp/127.0.0.1:{busy_port}"],
            0,
            no_session,
        ),
    ]
    _run_all(daemons, tmp_path)
    problems = []
    for d in daemons:
        assert d.process is not None
        log = d.log()
        if d.exited_at is None:
            problems.append(f"{d.name}: still running after {RUN_TIMEOUT_S:.0f} s (killed)\n{log[-2500:]}")
            continue
        if d.process.returncode != d.expect_rc:
            problems.append(f"{d.name}: exit status {d.process.returncode}, expected {d.expect_rc}\n{log[-2500:]}")
        if d.triggered_at is None:
            problems.append(f"{d.name}: never logged {d.trigger!r}\n{log[-2500:]}")
        elif d.exited_at - d.triggered_at > STOP_BOUND_S:
            problems.append(
                f"{d.name}: stopped {d.exited_at - d.triggered_at:.1f} s after its stop began\n{log[-2500:]}"
            )
        for text in d.expect_log:
            if text not in log:
                problems.append(f"{d.name}: log lacks {text!r}\n{log[-2500:]}")
        if "Traceback" in log:
            problems.append(f"{d.name}: a traceback reached the user\n{log[-2500:]}")
    assert not problems, "\n\n".join(problems)
    viewer_warnings = daemons[0].log().count("cannot open a viewer")
    assert viewer_warnings == 1, f"the missing viewer was reported {viewer_warnings} times"
