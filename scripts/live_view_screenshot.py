#!/usr/bin/env python3
"""Screenshot of the live view as the Rerun web viewer shows it, in headless Chromium: check the layout by eye.

What it does: ``skelfuse demo --offline`` writes a few seconds of the simulated rig to an .rrd (the sink and
blueprint the fusion node uses), ``rerun --serve-web`` serves it, headless Chromium opens the web viewer, waits
for it to load and draw (real time: the viewer is WebAssembly, so Chromium's virtual time does not wait for
it) and saves a PNG through the DevTools protocol (a minimal client on the standard library).

Usage::

    apt-get install -y chromium          # Debian; any Chromium or Chrome on PATH works (--browser)
    python scripts/live_view_screenshot.py --out live-view.png [--wait 25] [--duration 6]

Look at the PNG: the camera should frame the person in the middle of the rig, the fused skeleton (thick,
white for the first person) in front of the thin half-transparent sensor skeletons, "person N" above the
head and each sensor's name at its position, the plots beside the 3D view.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import http.server
import json
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path
from typing import Any


def free_port() -> int:
    with contextlib.closing(socket.socket()) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def wait_http(url: str, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with urllib.request.urlopen(url, timeout=1.0):
                return
        except OSError:
            if time.monotonic() > deadline:
                raise SystemExit(f"nothing answered on {url} within {timeout_s:.0f} s") from None
            time.sleep(0.2)


def serve_file(path: Path, port: int) -> None:
    """Serve ``path``'s folder on 127.0.0.1:port from a daemon thread, with the CORS header the viewer needs."""
    folder = str(path.parent)

    class Handler(http.server.SimpleHTTPRequestHandler):
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, directory=folder, **kwargs)

        def end_headers(self) -> None:
            self.send_header("Access-Control-Allow-Origin", "*")
            super().end_headers()

        def log_message(self, *args: Any) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", port), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()


class DevTools:
    """Just enough of a WebSocket client (RFC 6455) to send DevTools commands and read their answers."""

    def __init__(self, ws_url: str) -> None:
        host_port, path = ws_url.removeprefix("ws://").split("/", 1)
        host, port = host_port.split(":")
        self.sock = socket.create_connection((host, int(port)), timeout=60)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            f"GET /{path} HTTP/1.1\r\nHost: {host_port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode()
        )
        response = b""
        while b"\r\n\r\n" not in response:
            response += self.sock.recv(4096)
        if b" 101 " not in response.split(b"\r\n", 1)[0]:
            raise SystemExit(f"DevTools refused the WebSocket: {response[:200]!r}")
        self.buffer = response.split(b"\r\n\r\n", 1)[1]
        self.next_id = 0

    def _read(self, n: int) -> bytes:
        while len(self.buffer) < n:
            chunk = self.sock.recv(1 << 20)
            if not chunk:
                raise SystemExit("DevTools closed the connection")
            self.buffer += chunk
        data, self.buffer = self.buffer[:n], self.buffer[n:]
        return data

    def _send(self, text: str) -> None:
        payload = text.encode()
        mask = os.urandom(4)
        header = bytes([0x81])
        if len(payload) < 126:
            header += bytes([0x80 | len(payload)])
        elif len(payload) < 1 << 16:
            header += bytes([0x80 | 126]) + struct.pack(">H", len(payload))
        else:
            header += bytes([0x80 | 127]) + struct.pack(">Q", len(payload))
        masked = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        self.sock.sendall(header + mask + masked)

    def _message(self) -> dict:
        parts = b""
        while True:
            first, second = self._read(2)
            length = second & 0x7F
            if length == 126:
                (length,) = struct.unpack(">H", self._read(2))
            elif length == 127:
                (length,) = struct.unpack(">Q", self._read(8))
            parts += self._read(length)
            if first & 0x80:  # FIN
                return json.loads(parts)

    def call(self, method: str, **params: object) -> dict:
        self.next_id += 1
        self._send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            message = self._message()
            if message.get("id") == self.next_id:
                if "error" in message:
                    raise SystemExit(f"DevTools {method}: {message['error']}")
                return message.get("result", {})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("live-view.png"), help="PNG to write")
    parser.add_argument("--rrd", type=Path, default=None, help="an existing .rrd to show instead of a new demo take")
    parser.add_argument("--duration", type=float, default=6.0, help="seconds of demo take to record")
    parser.add_argument("--wait", type=float, default=25.0, help="seconds to let the viewer load and draw")
    parser.add_argument("--browser", default=None, help="Chromium executable (default: chromium or google-chrome)")
    parser.add_argument("--size", default="1600,900", help="window size W,H")
    args = parser.parse_args(argv)
    browser = args.browser or shutil.which("chromium") or shutil.which("google-chrome")
    rerun = shutil.which("rerun")
    if browser is None or rerun is None:
        raise SystemExit("needs Chromium (apt-get install -y chromium) and the rerun executable of rerun-sdk")
    workdir = Path(tempfile.mkdtemp(prefix="skelfuse-view-"))
    rrd = args.rrd or workdir / "view.rrd"
    if args.rrd is None:
        print(f"recording {args.duration:g} s of the demo to {rrd} ...", file=sys.stderr)
        subprocess.run(
            [
                sys.executable,
                "-m",
                "skelfuse",
                "demo",
                "--offline",
                "--duration",
                str(args.duration),
                "--rrd",
                str(rrd),
                "--no-realtime",
                "--json",
            ],
            check=True,
            stdout=subprocess.DEVNULL,
        )
    web, grpc, files, devtools = free_port(), free_port(), free_port(), free_port()
    children = []
    try:
        children.append(  # the web viewer (its gRPC port unused: the recording is fetched as a file)
            subprocess.Popen(
                [rerun, "--serve-web", "--web-viewer-port", str(web), "--port", str(grpc)],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                start_new_session=True,
            )
        )
        serve_file(rrd, files)  # the .rrd over HTTP, whole: the viewer loads all of it
        wait_http(f"http://127.0.0.1:{web}/", 30.0)
        wait_http(f"http://127.0.0.1:{files}/{rrd.name}", 30.0)
        url = f"http://127.0.0.1:{web}/?url=http%3A%2F%2F127.0.0.1%3A{files}%2F{rrd.name}"
        children.append(
            subprocess.Popen(
                [
                    browser,
                    "--headless=new",
                    "--no-sandbox",
                    "--disable-dev-shm-usage",
                    "--use-gl=angle",
                    "--use-angle=swiftshader",
                    "--enable-unsafe-swiftshader",
                    "--ignore-gpu-blocklist",
                    "--force-dark-mode",  # the viewer's dark theme, as the native viewer shows it
                    f"--window-size={args.size}",
                    f"--remote-debugging-port={devtools}",
                    f"--user-data-dir={workdir}/c",
                    url,
                ],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                start_new_session=True,
            )
        )
        wait_http(f"http://127.0.0.1:{devtools}/json/version", 30.0)
        print(f"viewer opened; waiting {args.wait:g} s for it to load and draw ...", file=sys.stderr)
        time.sleep(args.wait)
        with urllib.request.urlopen(f"http://127.0.0.1:{devtools}/json/list", timeout=5) as answer:
            pages = [p for p in json.load(answer) if p.get("type") == "page"]
        shot = DevTools(pages[0]["webSocketDebuggerUrl"]).call("Page.captureScreenshot", format="png")
        args.out.write_bytes(base64.b64decode(shot["data"]))
        print(f"wrote {args.out}", file=sys.stderr)
    finally:
        for child in children:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(child.pid, signal.SIGTERM)
            with contextlib.suppress(subprocess.TimeoutExpired):
                child.wait(10)
        shutil.rmtree(workdir, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
