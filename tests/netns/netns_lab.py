"""A lab of network namespaces the tests create themselves (``ip netns`` + veth pairs), always torn down.

A module of its own, not conftest.py: a test that imports ``conftest`` gets whichever conftest module Python
imported first when test folders are collected together.

Needs root and iproute2; without them every test here is skipped with the reason. Namespaces are named
``sf<pid><tag>``; every process runs in its own process group and is killed at teardown, then every
namespace is deleted (a finalizer, also after a failing test).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from process_groups import kill_group, stop_group

HERE = Path(__file__).resolve().parent


def netns_unavailable() -> str | None:
    if os.geteuid() != 0:
        return "network-namespace tests need root (ip netns add)"
    if shutil.which("ip") is None:
        return "network-namespace tests need iproute2's `ip`"
    probe = f"sfprobe{os.getpid()}"
    created = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if created.returncode != 0:
        return f"cannot create a network namespace here: {created.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None


class Lab:
    """Namespaces joined by veth pairs to one hub namespace, and the processes started in them."""

    def __init__(self, log_dir: Path) -> None:
        self.prefix = f"sf{os.getpid() % 100000}"
        self.log_dir = log_dir
        self.namespaces: list[str] = []
        self.processes: list[subprocess.Popen[bytes]] = []
        self._links = 0

    def namespace(self, tag: str) -> str:
        name = f"{self.prefix}{tag}"
        subprocess.run(["ip", "netns", "add", name], check=True, capture_output=True)
        self.namespaces.append(name)
        self.ip(name, "link", "set", "lo", "up")
        return name

    def ip(self, ns: str, *args: str) -> None:
        subprocess.run(["ip", "-n", ns, *args], check=True, capture_output=True)

    def link(self, hub: str, ns: str) -> tuple[str, str]:
        """A veth pair between ``hub`` and ``ns`` on its own /30; returns (hub address, ns address)."""
        self._links += 1
        k = self._links
        a, b = f"{self.prefix}h{k}", f"{self.prefix}n{k}"
        subprocess.run(["ip", "link", "add", a, "type", "veth", "peer", "name", b], check=True, capture_output=True)
        subprocess.run(["ip", "link", "set", a, "netns", hub], check=True, capture_output=True)
        subprocess.run(["ip", "link", "set", b, "netns", ns], check=True, capture_output=True)
        hub_ip, ns_ip = f"10.212.{k}.1", f"10.212.{k}.2"
        self.ip(hub, "addr", "add", f"{hub_ip}/30", "dev", a)
        self.ip(ns, "addr", "add", f"{ns_ip}/30", "dev", b)
        self.ip(hub, "link", "set", a, "up")
        self.ip(ns, "link", "set", b, "up")
        return hub_ip, ns_ip

    def run(self, ns: str, name: str, *argv: str, env: dict[str, str] | None = None) -> subprocess.Popen[bytes]:
        log = open(self.log_dir / f"{name}.log", "ab")
        process = subprocess.Popen(
            ["ip", "netns", "exec", ns, *argv],
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            env={**os.environ, "RUST_LOG": "warn", **(env or {})},
        )
        process.log_path = self.log_dir / f"{name}.log"  # type: ignore[attr-defined]
        process.log_file = log  # type: ignore[attr-defined]
        self.processes.append(process)
        return process

    def skelfuse(self, ns: str, name: str, *args: str) -> subprocess.Popen[bytes]:
        return self.run(ns, name, sys.executable, "-m", "skelfuse", *args)

    def probe(self, ns: str, name: str, *args: str) -> subprocess.Popen[bytes]:
        return self.run(ns, name, sys.executable, str(HERE / "probe.py"), *args)

    def log(self, process: subprocess.Popen[bytes]) -> str:
        return Path(process.log_path).read_text(errors="replace")[-3000:]  # type: ignore[attr-defined]

    def stop(self, process: subprocess.Popen[bytes], sig: int = signal.SIGTERM, timeout_s: float = 15.0) -> int | None:
        stop_group(process, sig, timeout_s)
        return process.returncode

    def wait_listening(self, ns: str, port: int, timeout_s: float = 60.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            out = subprocess.run(["ip", "netns", "exec", ns, "ss", "-ltnH"], capture_output=True, text=True).stdout
            if f":{port} " in out:
                return True
            time.sleep(0.2)
        return False

    def cleanup(self) -> None:
        for process in self.processes:
            kill_group(process)
            process.log_file.close()  # type: ignore[attr-defined]
        for ns in reversed(self.namespaces):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)  # deletes its veth ends too
