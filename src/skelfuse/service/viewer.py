"""The fusion node's live Rerun view: where the stream goes (spawn, serve, save) and a logging thread.

Logging happens on its own thread (:class:`RerunView`) fed by a bounded queue, so drawing never delays a
fused frame on the wire: when the viewer cannot keep up, frames are skipped for the view (counted in
``dropped``), never for subscribers.

Modes (``[rerun] mode`` or the command's flags):

- ``spawn``: start a local viewer (the ``rerun`` executable, in its own session); it stays open when the
  node stops. Where no viewer can open (no ``DISPLAY`` / ``WAYLAND_DISPLAY``, or the viewer exits at
  start-up) this is detected before anything is sent: the view falls back to ``file`` when one is given
  (``fuse --spawn --rrd FILE``), else it is dropped with one warning; the node runs on without it.
- ``serve``: start ``rerun --serve-grpc --bind <bind>`` (plus the web viewer with ``--web-viewer-port``)
  as a child process bound to 127.0.0.1 unless told otherwise, and stream to it. Viewers connect with
  ``rerun rerun+http://<bind>:<grpc_port>/proxy`` (or open ``http://<bind>:<web_port>``). The server is
  the node's child: it stops with the node.
- ``save``: write an ``.rrd`` file (open it with ``rerun FILE``).
"""

from __future__ import annotations

import logging
import os
import queue
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.schema.errors import ServiceError
from skelfuse.service.zenoh_io import wait_for_port

log = logging.getLogger("skelfuse.service")

VIEW_MODES = ("off", "spawn", "serve", "save")
FLUSH_TIMEOUT_S = 2.0
"""Longest a view may take to flush at shutdown; a viewer that does not take the data loses it."""
SPAWN_SETTLE_S = 1.5
"""A spawned viewer that is still alive this long after binding its port is taken as started (one that
cannot open a window binds its port first, then exits)."""


class ViewUnavailable(Exception):
    """The live view cannot go where it was asked to (no display, a viewer that exits at start-up)."""


def has_display() -> bool:
    """Whether a viewer window can open here (a desktop session, or macOS / Windows)."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


@dataclass(frozen=True)
class ViewOptions:
    """Where the live view goes; see the module docstring for the modes (``file``: the .rrd of mode "save",
    or with mode "spawn" where the view goes when no viewer can open)."""

    mode: str = "off"
    file: Path | None = None
    bind: str = "127.0.0.1"
    grpc_port: int = 9876
    web_port: int | None = None
    log_sensors: bool = True
    application_id: str = "skelfuse"

    def __post_init__(self) -> None:
        if self.mode not in VIEW_MODES:
            raise ValueError(f"view mode must be one of {VIEW_MODES}, got {self.mode!r}")
        if self.mode == "save" and self.file is None:
            raise ValueError("view mode 'save' needs a file (--rrd FILE)")


def spawn_viewer(port: int, *, settle_s: float = SPAWN_SETTLE_S, timeout_s: float = 15.0) -> str:
    """Start a local Rerun viewer listening on ``port`` (or use the one already there); its gRPC URL.

    The viewer runs in its own session and stays open when the node stops (like ``rr.spawn``), but unlike
    ``rr.spawn`` a viewer that cannot start is detected here, within about ``settle_s`` seconds, instead of
    leaving the recording stream retrying (and its flush blocking) for ever.

    Raises
    ------
    ViewUnavailable
        No display, no ``rerun`` executable, or the viewer exited or never listened.
    """
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    if not has_display():
        raise ViewUnavailable("no display here (DISPLAY and WAYLAND_DISPLAY are unset)")
    if wait_for_port(port, timeout_s=0.2):
        return url  # a viewer is already listening there: stream to it
    exe = shutil.which("rerun")
    if exe is None:
        raise ViewUnavailable("the `rerun` executable of rerun-sdk is not on PATH")
    with tempfile.TemporaryFile() as errors:
        viewer = subprocess.Popen(
            [exe, "--port", str(port)],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=errors,
            start_new_session=True,
        )
        deadline = time.monotonic() + timeout_s
        bound_at: float | None = None
        while viewer.poll() is None and time.monotonic() < deadline:
            if bound_at is None and wait_for_port(port, timeout_s=0.1):
                bound_at = time.monotonic()
            if bound_at is not None and time.monotonic() - bound_at >= settle_s:
                return url
            time.sleep(0.05)
        if viewer.poll() is None:
            stop_server(viewer)
            raise ViewUnavailable(f"the viewer ({exe}) did not listen on port {port} within {timeout_s:.0f} s")
        errors.seek(0)
        lines = [ln for ln in errors.read().decode(errors="replace").splitlines() if "Error" in ln or "error" in ln]
        why = lines[-1].strip() if lines else f"exit status {viewer.returncode}"
        raise ViewUnavailable(f"the viewer exited at start-up: {why[-300:]}")


_UNRELEASED: list[Any] = []
"""Recording streams whose disconnect did not finish in time: kept referenced so that their (blocking)
``__del__`` never runs on the node's thread; the process exit is bounded by the CLI (``EXIT_GRACE_S``)."""


def release_recording(recording: Any, timeout_s: float = FLUSH_TIMEOUT_S) -> bool:
    """Disconnect a recording stream from its sinks within ``timeout_s``; True when it finished.

    Rerun's disconnect (and the ``__del__`` of a stream still connected) waits for a viewer that accepted
    the connection but does not answer; done on a daemon thread, that wait cannot hold a stop.
    """
    done = threading.Event()

    def disconnect() -> None:
        try:
            recording.disconnect()
        except Exception as exc:  # a viewer that went away: nothing left to release
            log.debug("rerun: disconnect failed: %s", exc)
        done.set()

    threading.Thread(target=disconnect, name="skelfuse-rerun-release", daemon=True).start()
    if done.wait(timeout_s):
        return True
    _UNRELEASED.append(recording)
    log.warning("rerun: the viewer did not take the end of the stream within %.1f s; leaving it", timeout_s)
    return False


def _save(recording: Any, file: Path) -> None:
    """Send the view to ``file`` (.rrd); a file that cannot be written is a ServiceError saying what to do."""
    from skelfuse.sinks.rerun_sink import default_blueprint  # Rerun: only where a view is on (start-up)

    try:
        recording.save(file, default_blueprint=default_blueprint())
    except (OSError, RuntimeError) as exc:  # rerun reports a failed write as RuntimeError
        raise ServiceError(
            f"rerun: cannot save the view to {file} ({exc}); free disk space, choose another --rrd FILE, "
            "or run without a view (--no-view)"
        ) from None


def open_recording(options: ViewOptions) -> tuple[Any, subprocess.Popen[bytes] | None]:
    """A ``rr.RecordingStream`` sending where ``options`` says, and the server process it started (serve).

    Returns ``(None, None)`` where mode "spawn" cannot open a viewer and no fallback ``file`` is given
    (logged once, as a warning that says what to do instead).
    """
    import rerun as rr

    from skelfuse.sinks.rerun_sink import default_blueprint

    recording = rr.RecordingStream(options.application_id)
    server: subprocess.Popen[bytes] | None = None
    if options.mode == "spawn":
        try:
            recording.connect_grpc(spawn_viewer(options.grpc_port), default_blueprint=default_blueprint())
        except ViewUnavailable as exc:
            if options.file is not None:
                log.warning("rerun: cannot open a viewer (%s); saving the view to %s instead", exc, options.file)
                _save(recording, options.file)
                return recording, None
            log.warning(
                "rerun: cannot open a viewer (%s); running without a live view. Use --rrd FILE to save it, "
                '--serve to serve it to remote viewers, or --no-view ([rerun] mode = "save" / "serve" / "off")',
                exc,
            )
            return None, None
    elif options.mode == "save":
        assert options.file is not None
        _save(recording, options.file)
    elif options.mode == "serve":
        exe = shutil.which("rerun")
        if exe is None:
            raise ServiceError(
                "--serve needs the `rerun` executable of rerun-sdk on PATH; install rerun-sdk "
                "into this environment or use --rrd FILE"
            )
        command = [exe, "--bind", options.bind, "--port", str(options.grpc_port)]
        command += ["--serve-web", "--web-viewer-port", str(options.web_port)] if options.web_port else ["--serve-grpc"]
        server = subprocess.Popen(command, stdin=subprocess.DEVNULL, start_new_session=True)
        host = "127.0.0.1" if options.bind in ("0.0.0.0", "::") else options.bind
        if not wait_for_port(options.grpc_port, host=host, timeout_s=15.0):
            stop_server(server)
            raise ServiceError(
                f"the rerun server ({' '.join(command)}) did not start listening on "
                f"{host}:{options.grpc_port} within 15 s; is the port taken?"
            )
        url = f"rerun+http://{host}:{options.grpc_port}/proxy"
        recording.connect_grpc(url, default_blueprint=default_blueprint())
        web = f"; in a browser: {web_viewer_url(host, options.web_port, url)}" if options.web_port else ""
        log.info("rerun: serving on %s; open it with:  rerun %s%s", url, url, web)
    return recording, server


def web_viewer_url(host: str, web_port: int, grpc_url: str) -> str:
    """The web viewer's address with the ``?url=`` it needs to connect to the stream (without it the page
    opens on an empty viewer)."""
    return f"http://{host}:{web_port}/?url={urllib.parse.quote(grpc_url, safe='')}"


def stop_server(server: subprocess.Popen[bytes] | None, timeout_s: float = 5.0) -> None:
    """Stop the rerun server process group this node started (and only that one)."""
    if server is None or server.poll() is not None:
        return
    try:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=timeout_s)
    except ProcessLookupError:
        return
    except subprocess.TimeoutExpired:
        os.killpg(server.pid, signal.SIGKILL)
        server.wait(timeout=timeout_s)


class RerunView:
    """Draws the rig, the sensors' raw skeletons and the fused skeletons on a thread of its own.

    Parameters
    ----------
    recording : rr.RecordingStream
        Injected: the caller decides where it goes (:func:`open_recording`).
    sensor_ids : sequence of str
    world_from_sensor : (S, 4, 4) mm, drawn once (static).
    log_sensors : bool
        Also draw each sensor's raw skeleton (in the world frame).
    max_pending : int
        Frames waiting to be drawn before new ones are skipped.
    """

    def __init__(
        self,
        recording: Any,
        sensor_ids: tuple[str, ...],
        world_from_sensor: np.ndarray,
        *,
        log_sensors: bool = True,
        max_pending: int = 64,
    ) -> None:
        from skelfuse.sinks.rerun_sink import RerunSink, default_blueprint

        self.recording = recording
        self.sink = RerunSink(recording, sensor_ids)
        self.log_sensors = log_sensors
        self.dropped = 0
        self.drawn = 0
        self._queue: queue.Queue[tuple[Any, ...] | None] = queue.Queue(maxsize=max_pending)
        self.sink.log_rig(world_from_sensor)
        try:  # the camera on this rig's people (open_recording sent the rig-independent default)
            recording.send_blueprint(default_blueprint(world_from_sensor))
        except Exception as exc:  # a viewer problem never stops the node
            log.warning("rerun: could not send the view's layout: %s", exc)
        self._thread = threading.Thread(target=self._run, name="skelfuse-rerun", daemon=True)
        self._thread.start()

    def submit(
        self,
        time_s: float,
        sensors_world: np.ndarray | None,
        fused: np.ndarray,
        track_ids: np.ndarray,
        fusion_ms: float | None,
        latency_ms: float | None,
        rate_hz: dict[str, float] | None,
        agreement_mm: np.ndarray | None = None,
    ) -> None:
        """Queue one instant: (S, B, 32, 3) raw skeletons (every body) in the world, (P, 32, 3) fused persons
        with their (P,) track ids (one colour per id) and agreement (mm, labelled), metrics."""
        item = (time_s, sensors_world, fused, track_ids, fusion_ms, latency_ms, rate_hz, agreement_mm)
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            self.dropped += 1

    def log_error(self, time_s: float, error_mm: float) -> None:
        """Error against ground truth (simulated rigs)."""
        try:
            self._queue.put_nowait(("error", time_s, error_mm))
        except queue.Full:
            self.dropped += 1

    def log_clouds(self, time_s: float, clouds: tuple[Any, ...]) -> None:
        """Depth / hybrid mode: each person's fused cloud, ((track id, MergedCloud), ...), coloured by sensor."""
        try:
            self._queue.put_nowait(("clouds", time_s, clouds))
        except queue.Full:
            self.dropped += 1

    def _run(self) -> None:
        import rerun as rr

        while True:
            item = self._queue.get()
            if item is None:
                return
            try:
                if item[0] == "error":
                    _, time_s, error_mm = item
                    self.sink.set_time(time_s)
                    self.sink.log_metrics(error_mm=error_mm)
                    continue
                if item[0] == "clouds":
                    _, time_s, clouds = item
                    self.sink.set_time(time_s)
                    self.sink.log_person_clouds([c for _, c in clouds], [t for t, _ in clouds])
                    continue
                time_s, sensors_world, fused, track_ids, fusion_ms, latency_ms, rate_hz, agreement_mm = item
                self.sink.set_time(time_s)
                if self.log_sensors and sensors_world is not None:
                    self.sink.log_sensor_skeletons(sensors_world)
                self.sink.log_fused(fused, track_ids, agreement_mm)
                self.sink.log_metrics(fusion_ms=fusion_ms, rate_hz=rate_hz)
                if latency_ms is not None:
                    self.recording.log("metrics/fusion_ms/node_latency", rr.Scalars(latency_ms))
                self.drawn += 1
            except Exception:  # a viewer problem must never stop the node
                log.exception("rerun: logging a frame failed")

    def close(self, timeout_s: float = 5.0, flush_timeout_s: float = FLUSH_TIMEOUT_S) -> None:
        """Draw what is queued (up to ``timeout_s``), then flush the recording (up to ``flush_timeout_s``).

        Both waits are bounded: a viewer that stopped taking data costs the node at most their sum at shutdown.
        """
        deadline = time.monotonic() + timeout_s
        try:
            self._queue.put(None, timeout=timeout_s)
        except queue.Full:
            log.warning("rerun: view queue still full at shutdown; %d frames not drawn", self._queue.qsize())
        self._thread.join(max(0.0, deadline - time.monotonic()))
        try:
            self.recording.flush(timeout_sec=flush_timeout_s)
        except Exception as exc:  # a viewer that went away: say so in one line, never block the stop
            log.warning(
                "rerun: the view could not be flushed within %.1f s (%s); its last frames are lost",
                flush_timeout_s,
                exc,
            )
        release_recording(self.recording, flush_timeout_s)
