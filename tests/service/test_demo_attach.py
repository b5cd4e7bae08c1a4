"""The demo is a rig like any other: with the flags it prints, `skelfuse status`, `skelfuse stream osc` and the
example subscriber attach to it; its working folder is gone when it ends."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from waiting import wait_for_output

pytestmark = [pytest.mark.live, pytest.mark.service]

REPO = Path(__file__).resolve().parents[2]
START_TIMEOUT_S = 120.0
ATTACH_TIMEOUT_S = 60.0


def _attach(*command: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(list(command), capture_output=True, text=True, timeout=ATTACH_TIMEOUT_S, cwd=REPO)


def test_apps_attach_to_the_demo_with_the_flags_it_prints(tmp_path: Path) -> None:
    err = tmp_path / "demo.err"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    with open(err, "wb") as log:
        demo = subprocess.Popen(
            [sys.executable, "-m", "skelfuse", "demo", "--duration", "300", "--rrd", str(tmp_path / "d.rrd")],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=log,
            start_new_session=True,
            env=env,
        )
    try:
        printed = wait_for_output(err, r'rig "demo", zenoh endpoint (tcp/127\.0\.0\.1:\d+)', demo, START_TIMEOUT_S)
        config = Path(wait_for_output(err, r"skelfuse status --config (\S+)", demo, 5.0).group(1))
        assert config.is_file() and printed.group(1) in config.read_text()
        wait_for_output(err, r"the run starts|frames fused", demo, START_TIMEOUT_S)  # fused frames are flowing

        status = _attach(
            sys.executable, "-m", "skelfuse", "status", "--config", str(config), "--json", "--max-messages", "12",
            "--duration", "30",
        )  # fmt: skip
        assert status.returncode == 0, status.stderr[-2000:]
        nodes = {json.loads(line)["node"] for line in status.stdout.splitlines() if line.strip()}
        assert "fusion" in nodes and any(n.startswith("capture-") for n in nodes), nodes

        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as receiver:
            receiver.bind(("127.0.0.1", 0))
            receiver.settimeout(30.0)
            port = receiver.getsockname()[1]
            osc = _attach(
                sys.executable,
                "-m",
                "skelfuse",
                "stream",
                "osc",
                "--config",
                str(config),
                "--host",
                "127.0.0.1",
                "--port",
                str(port),
                "--max-frames",
                "3",
                "--duration",
                "30",
            )
            assert osc.returncode == 0, osc.stderr[-2000:]
            assert receiver.recv(65536).startswith(b"#bundle")  # an OSC bundle reached the receiver

        subscriber = _attach(
            sys.executable,
            "scripts/example_subscriber.py",
            "--config",
            str(config),
            "--max-messages",
            "3",
            "--duration",
            "30",
        )
        assert subscriber.returncode == 0, subscriber.stderr[-2000:]
        assert subscriber.stdout.strip(), "the example subscriber printed no fused frame"
    finally:
        os.killpg(demo.pid, signal.SIGINT)
        demo.wait(60)
    assert not config.parent.exists(), f"the demo left {config.parent} behind"
