"""The web viewer URL the demo prints, opened as printed in headless Chromium (Debian's package), shows the fused
skeleton: the pixels of the fused person's colour that change between two screenshots (the demo's person walks;
the viewer's own UI stands still, and may well use the same colour: white text when the person's colour is
white), against the control of the same viewer page with no stream to connect to."""

from __future__ import annotations

import base64
import contextlib
import importlib.util
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import cv2
import numpy as np
import pytest

from skelfuse.sinks.rerun_sink import TRACK_COLORS
from waiting import wait_for_output

pytestmark = [pytest.mark.live, pytest.mark.service]

REPO = Path(__file__).resolve().parents[2]
BROWSER = shutil.which("chromium") or shutil.which("google-chrome")
START_TIMEOUT_S = 120.0
DRAW_TIMEOUT_S = 300.0
MIN_SKELETON_PX = 300


def _screenshot_tools():
    """The DevTools client of scripts/live_view_screenshot.py (the same code makes the docs' screenshots)."""
    spec = importlib.util.spec_from_file_location("live_view_screenshot", REPO / "scripts" / "live_view_screenshot.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _rgb(png: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1].astype(np.int16)


def _colored(png: bytes, color: np.ndarray) -> np.ndarray:
    """Where the pixels are within 12 of the fused skeleton's colour in every channel."""
    return np.all(np.abs(_rgb(png) - color.astype(np.int16)) <= 12, axis=-1)


def skeleton_pixels(before: bytes, after: bytes, color: np.ndarray) -> int:
    """Pixels of the fused skeleton's colour that appeared or went between two screenshots: what moves in it."""
    return int((_colored(before, color) ^ _colored(after, color)).sum())


def viewer_drawn(png: bytes) -> bool:
    """The viewer's UI is on the page (panels, grid, text: many colours), not a blank page still loading."""
    image = _rgb(png).reshape(-1, 3)
    return len(np.unique(image[:: max(1, len(image) // 20000)], axis=0)) > 100


def _track_color(config: Path) -> np.ndarray:
    """The colour the view draws the demo's person in: the fused stream's track id, read by the example
    subscriber attached as the demo says, picks it from the sink's palette."""
    done = subprocess.run(
        [sys.executable, "scripts/example_subscriber.py", "--config", str(config), "--max-messages", "5",
         "--duration", "60"],
        capture_output=True, text=True, timeout=90, cwd=REPO,
    )  # fmt: skip
    tracks = re.findall(r"track (\d+):", done.stdout)
    assert tracks, done.stderr[-2000:]
    return np.asarray(TRACK_COLORS[int(tracks[-1]) % len(TRACK_COLORS)])


class Browser:
    """Headless Chromium on one URL, screenshots through the DevTools protocol."""

    def __init__(self, url: str, workdir: Path) -> None:
        self.tools = _screenshot_tools()
        self.port = self.tools.free_port()
        self.process = subprocess.Popen(
            [
                str(BROWSER),
                "--headless=new",
                "--no-sandbox",
                "--disable-dev-shm-usage",
                "--use-gl=angle",
                "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader",
                "--ignore-gpu-blocklist",
                "--force-dark-mode",  # the viewer's dark theme, as the native viewer (a white track shows)
                "--window-size=1280,800",
                f"--remote-debugging-port={self.port}",
                f"--user-data-dir={workdir}",
                url,
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
        self.tools.wait_http(f"http://127.0.0.1:{self.port}/json/version", 60.0)
        with urllib.request.urlopen(f"http://127.0.0.1:{self.port}/json/list", timeout=10) as answer:
            page = next(p for p in json.load(answer) if p.get("type") == "page")
        self.devtools = self.tools.DevTools(page["webSocketDebuggerUrl"])

    def screenshot(self) -> bytes:
        """A PNG of the page; a renderer starved of CPU may answer late (the stale answer is skipped later)."""
        for _ in range(4):
            with contextlib.suppress(TimeoutError):
                return base64.b64decode(self.devtools.call("Page.captureScreenshot", format="png")["data"])
        raise TimeoutError("Chromium did not answer four screenshot requests of 60 s each")

    def close(self) -> None:
        self.devtools.sock.close()
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.process.pid, signal.SIGTERM)
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.process.wait(10)


def test_the_printed_web_viewer_url_shows_the_fused_skeleton(tmp_path: Path) -> None:
    tools = _screenshot_tools()
    web, grpc = tools.free_port(), tools.free_port()
    err = tmp_path / "demo.err"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    with open(err, "wb") as log:
        demo = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "skelfuse",
                "demo",
                "--web",
                "--web-port",
                str(web),
                "--grpc-port",
                str(grpc),
                "--duration",
                "600",
            ],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=log,
            start_new_session=True,
            env=env,
        )
    browsers: list[Browser] = []
    try:
        url = wait_for_output(err, r"web viewer: (http\S+)", demo, START_TIMEOUT_S).group(1)
        assert f"?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy" in url
        config = Path(re.search(r"skelfuse status --config (\S+)", err.read_text()).group(1))
        color = _track_color(config)
        viewer = Browser(url, tmp_path / "viewer")  # the URL exactly as printed
        browsers.append(viewer)
        deadline = time.monotonic() + DRAW_TIMEOUT_S
        found = 0
        shot = b""
        while not (shot and viewer_drawn(shot) and found >= MIN_SKELETON_PX):
            assert demo.poll() is None, err.read_text(errors="replace")[-3000:]
            if time.monotonic() > deadline:
                (tmp_path / "viewer.png").write_bytes(viewer.screenshot())
                pytest.fail(f"no skeleton drawn within {DRAW_TIMEOUT_S:.0f} s ({found} px; {tmp_path / 'viewer.png'})")
            previous, shot = shot, viewer.screenshot()
            (tmp_path / "viewer.png").write_bytes(shot)
            found = skeleton_pixels(previous, shot, color) if previous else 0
            time.sleep(2.0)
        viewer.close()  # one browser at a time: each draws on the CPU (SwiftShader)
        # The control: the same viewer page pointed at a port where nothing serves a stream (the bare page may
        # connect to the server that served it, which is the demo's own stream).
        nothing = url.replace(f"%3A{grpc}%2F", f"%3A{tools.free_port()}%2F")
        assert nothing != url
        control = Browser(nothing, tmp_path / "control")
        browsers.append(control)
        background = control.screenshot()
        while not viewer_drawn(background):  # the control page loaded too (its UI drawn)
            assert time.monotonic() < deadline, "the viewer page without a stream never loaded"
            time.sleep(2.0)
            background = control.screenshot()
        (tmp_path / "control.png").write_bytes(background)
        time.sleep(2.0)  # as long as between two viewer screenshots
        unstreamed = skeleton_pixels(background, control.screenshot(), color)
        assert found > 4 * max(unstreamed, 25), f"{found} skeleton pixels; {unstreamed} on the page without a stream"
    finally:
        for browser in browsers:
            browser.close()
        os.killpg(demo.pid, signal.SIGINT)
        demo.wait(60)
