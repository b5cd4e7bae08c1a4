"""Capture worker: ``skelfuse capture --config RIG.toml --sensor ID``. One source's frames onto zenoh.

Cycle::

    source = make_source(cfg, sensor_id, options)       # sim | replay | kinect (pluggable)
    session = open_session(...)                          # retried with backoff while it fails
    for due_ns, frame in SourceReader(source):           # source.frames() on a thread of its own
        lifecycle.wait(until due)                        # due: monotonic ns when the frame is "captured"
        frame.host_time_ns = time.time_ns()              # stamped at publish
        publisher.put(encode_sensor_frame(frame))        # skelfuse/<rig>/sensors/<id>/skeletons
    + status every status_period_s on skelfuse/<rig>/status/capture-<id>, liveliness on .../alive/capture-<id>

A source that fails at run time (an exception while producing frames) is logged and restarted with
exponential backoff; a source that cannot exist in this config (a sim sensor without a pose, a missing replay
file) raises at once, before anything opens, and a kinect source without pyk4a / the SDKs stops the worker.
A watchdog restarts a started source that delivers no frame for ``stall_timeout_s``, a read that never returns
included (the reader thread is abandoned; SIGTERM still stops the worker at once).

Sources
-------
``sim``
    Simulates the whole rig (the rig's sim sensors in config order, master first) with one seed and keeps
    this sensor's column: per-sensor noise streams are keyed by (seed, sensor id), so every worker of the
    rig simulates the same person and each gets exactly its own view. Wired sync is emulated on the host
    clock: the frame of instant ``n`` (``n = Unix time / frame period``) is published at that time with
    device timestamp ``n * period`` plus the sensor's simulated subordinate delay, and shows take frame
    ``n mod T``. So workers started at different times (or restarted after a crash) agree on the instant
    and the pose, like hardware-synced Kinects. ``sequence`` is ``n`` (a gap is a drop). The take loops, or
    with ``loop = False`` the worker stops at the end of the take.
``replay``
    This sensor's frames of a recording (``sensors[i].replay``): an MCAP paced by its recorded host time,
    any other format (offline_processor JSON, extractor CSV, long CSV, andyj1 CSV) by its device time from
    the earliest first frame of the rig's replay files, at ``speed``. Device times are kept; with ``loop``
    each pass is shifted by the recording's span
    so time keeps increasing.
``kinect``
    An Azure Kinect / Femto Bolt through :class:`skelfuse.sources.kinect.KinectSource` (pyk4a + k4abt, the
    ``kinect`` extra): frames as the tracker delivers them, host time stamped on receipt; a failing device
    is reopened with backoff; without pyk4a or the SDKs the worker stops with a message naming them.
    Subordinates announce their running camera (liveliness ``alive/camera-<id>``) and the master waits for
    them before starting its camera (:func:`wait_for_subordinates`, ``WorkerOptions.subordinate_wait_s``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from skelfuse.config import RigConfig
from skelfuse.schema.errors import ConfigError, ServiceError
from skelfuse.schema.frames import SensorFrame
from skelfuse.service.capture_sources import (
    DEFAULT_GESTURE,
    DEFAULT_OPEN_TIMEOUT_S,
    DEFAULT_STALL_TIMEOUT_S,
    DEFAULT_TAKE_S,
    FrameSource,
    KinectFrameSource,
    ReplaySource,
    SimSource,
    WorkerOptions,
    camera_node,
    check_source,
    make_source,
    replay_anchor_us,
    sim_rig_order,
    simulate_rig,
    wait_for_subordinates,
)
from skelfuse.service.lifecycle import Lifecycle
from skelfuse.service.zenoh_io import BACKOFF_FIRST_S, BACKOFF_MAX_S, close_session, open_session
from skelfuse.sources.kinect import TrackerStalled
from skelfuse.wire import keys
from skelfuse.wire.clouds import PersonCloudsFrame, encode_person_clouds
from skelfuse.wire.codec import NodeStatus, encode_sensor_frame, encode_status

if TYPE_CHECKING:  # pragma: no cover - typing only
    import zenoh

log = logging.getLogger("skelfuse.service.worker")

# The sources live in skelfuse.service.capture_sources; their names are re-exported here for the worker's users.
__all__ = [
    "DEFAULT_GESTURE",
    "DEFAULT_OPEN_TIMEOUT_S",
    "DEFAULT_STALL_TIMEOUT_S",
    "DEFAULT_TAKE_S",
    "MAX_FAILURES_WHILE_HUNG",
    "READER_JOIN_S",
    "READ_POLL_S",
    "FrameSource",
    "KinectFrameSource",
    "ReplaySource",
    "SimSource",
    "SourceReader",
    "SourceStalled",
    "WorkerOptions",
    "WorkerReport",
    "camera_node",
    "check_source",
    "make_source",
    "replay_anchor_us",
    "run_capture_worker",
    "sim_rig_order",
    "simulate_rig",
    "wait_for_subordinates",
]

READ_POLL_S = 0.1
"""How often the publish loop looks at its exit flag, the run limits and the watchdog while it waits for the
source."""
READER_JOIN_S = 1.0
"""How long a stopping worker waits for its source's thread to close the source (a hung read: then abandoned)."""
MAX_FAILURES_WHILE_HUNG = 3
"""While a read the watchdog abandoned is still blocked (the SDK's state is suspect: the call may hold the
device or a lock), the worker gives up after this many further failures of its source and exits with status 1,
so that the service manager (``Restart=on-failure``) starts a fresh process."""


# ----------------------------------------------------------------------------------------------------------
# The worker


class SourceStalled(Exception):
    """The watchdog's verdict: the source delivered no frame for ``stall_timeout_s`` (it kept answering with
    nothing, or its read never returned)."""


_END = object()


class SourceReader:
    """A source's ``frames()`` run on a thread of its own, handed to the publish loop one item at a time.

    A read that never returns (an SDK call that hangs) then blocks this thread only: the publish loop keeps
    watching its exit flag, its run limits and the watchdog, and abandons a hung reader. Python cannot
    interrupt a thread inside a C call, so an abandoned reader is a daemon thread: if its call ever returns it
    sees it was stopped, closes its ``frames()`` (which closes the source) and ends. The source is always
    closed on the thread that opened it.
    """

    def __init__(
        self,
        source: FrameSource,
        name: str,
        clouds_at: Callable[[SensorFrame], PersonCloudsFrame | None] | None = None,
    ) -> None:
        self._items: queue.Queue[tuple[str, Any]] = queue.Queue(maxsize=1)
        self._stop = threading.Event()
        self._ended: bool | None = None
        # a source keeps only its latest frame's clouds: ask on the reading thread, before it reads the next
        self._clouds_at = clouds_at
        self._thread = threading.Thread(target=self._run, args=(source,), name=f"{name}-source", daemon=True)
        self._thread.start()

    def _hand_over(self, item: tuple[str, Any]) -> bool:
        """Put ``item`` for the publish loop; False once the reader is stopped."""
        while not self._stop.is_set():
            try:
                self._items.put(item, timeout=READ_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def _run(self, source: FrameSource) -> None:
        frames = source.frames()
        try:
            for due_ns, frame in frames:
                clouds = None if frame is None or self._clouds_at is None else self._clouds_at(frame)
                if not self._hand_over(("item", (due_ns, frame, clouds))):
                    return
            self._hand_over(("end", None))
        except BaseException as exc:  # handed to the publish loop, which restarts or stops
            self._hand_over(("error", exc))
        finally:
            close = getattr(frames, "close", None)
            if close is not None:
                with contextlib.suppress(Exception):
                    close()

    def next(self, timeout_s: float) -> Any:
        """The next ``(due_ns, frame, clouds)``; None when none came within ``timeout_s``; ``_END`` when the source
        finished. An exception the source raised is raised here."""
        try:
            kind, value = self._items.get(timeout=timeout_s)
        except queue.Empty:
            return None
        if kind == "error":
            raise value
        return _END if kind == "end" else value

    def stop(self, join_s: float = READER_JOIN_S) -> bool:
        """Stop reading; True when the thread ended within ``join_s`` (False: blocked in a read, abandoned).
        Waits only on the first call."""
        if self._ended is None:
            self._stop.set()
            self._thread.join(join_s)
            self._ended = not self._thread.is_alive()
        return self._ended

    @property
    def blocked(self) -> bool:
        """Stopped but its thread still inside a read."""
        return self._ended is not None and self._thread.is_alive()


@dataclass
class WorkerReport:
    frames_out: int = 0
    restarts: int = 0
    late_publishes: int = 0
    stalls: int = 0


def run_capture_worker(
    cfg: RigConfig,
    sensor_id: str,
    zenoh_conf: zenoh.Config,
    *,
    options: WorkerOptions,
    lifecycle: Lifecycle,
    source: FrameSource | None = None,
) -> WorkerReport:
    """Publish one sensor's frames until ``lifecycle.should_exit`` or the run limits.

    ``source`` (injected by tests) defaults to :func:`make_source`, which raises for a source that cannot
    work in this build or config before any session opens.
    """
    name = keys.validate_name(options.node_name or f"capture-{sensor_id}", "node")
    check_source(cfg, sensor_id)
    report = WorkerReport()
    with lifecycle.capture_signals():
        started = time.monotonic()
        session = open_session(
            zenoh_conf, lifecycle=lifecycle, what=f"capture worker {name}", deadline=options.limits.deadline(started)
        )
        if session is None:
            return report
        try:
            # The source is built after the session opened (simulating a take takes a second or two), so the
            # subscribers' declarations have reached this peer before its first frame is published.
            source = source if source is not None else make_source(cfg, sensor_id, options)
            _publish_loop(cfg, sensor_id, name, source, session, options, lifecycle, report)
        finally:
            lifecycle.request_exit()  # the stop begins (bounded by the stop watchdog)
            close_session(session, what=f"capture worker {name}")
    log.info("capture worker %s stopped: %d frames published", name, report.frames_out)
    return report


def _publish_loop(
    cfg: RigConfig,
    sensor_id: str,
    name: str,
    source: FrameSource,
    session: Any,
    options: WorkerOptions,
    lifecycle: Lifecycle,
    report: WorkerReport,
    started: float | None = None,
) -> None:
    _PublishLoop(cfg, sensor_id, name, source, session, options, lifecycle, report, started).run()


DIAGNOSIS_GRACE_S = 0.5
"""How long past ``stall_timeout_s`` the watchdog waits before it restarts a silent source: a source that
diagnoses its own stall with the same timeout (a Kinect source: no capture, or no tracker result) names the
cause first; the watchdog stays the backstop for a read that never returns. Equal timers raced: on a busy
machine the watchdog's generic SourceStalled replaced the source's TrackerStalled."""


class _PublishLoop:
    """The capture worker's loop over one source.

    Cycle: read the source on a thread of its own (:class:`SourceReader`); publish each frame when it is due
    (its person clouds first, in depth / hybrid mode); send a status every ``status_period_s``. When the source
    fails, or the watchdog finds it silent (``stall_timeout_s``, ``open_timeout_s``), restart it after a
    backoff that doubles up to :data:`BACKOFF_MAX_S`; give up (ServiceError) when an abandoned read stays
    blocked through :data:`MAX_FAILURES_WHILE_HUNG` more failures. Stops at ``--duration`` /
    ``--max-frames``, the end of a finite source, or the lifecycle's exit.
    """

    def __init__(
        self,
        cfg: RigConfig,
        sensor_id: str,
        name: str,
        source: FrameSource,
        session: Any,
        options: WorkerOptions,
        lifecycle: Lifecycle,
        report: WorkerReport,
        started: float | None,
    ) -> None:
        self.sensor_id, self.name, self.source = sensor_id, name, source
        self.options, self.lifecycle, self.report = options, lifecycle, report
        rig = cfg.name
        key = keys.sensor_skeletons(rig, sensor_id)
        self.publisher = session.declare_publisher(key, express=True)
        # depth / hybrid mode: a source that can (sim: SimSource.clouds_at) also publishes each body's cloud
        self.clouds_at = getattr(source, "clouds_at", None) if cfg.fusion.mode != "skeleton" else None
        # express like the skeletons: a batched cloud would arrive after the skeleton it belongs to
        self.clouds_pub = (
            None
            if self.clouds_at is None
            else session.declare_publisher(keys.sensor_clouds(rig, sensor_id), express=True)
        )
        self.status_pub = session.declare_publisher(keys.status(rig, name))
        self.token = session.liveliness().declare_token(keys.alive(rig, name))
        self.period_ns = int((options.status_period_s or cfg.node.status_period_s) * 1e9)
        self.limits = options.limits
        self.start = started if started is not None else time.monotonic()
        self.deadline_ns = math.inf if self.limits.duration_s is None else (self.start + self.limits.duration_s) * 1e9
        self.next_status = time.monotonic_ns()
        self.window_frames = 0
        self.last_status = self.next_status
        self.backoff = BACKOFF_FIRST_S
        self.last_error = ""
        self.stamps_host_time = bool(getattr(source, "stamps_host_time", False))
        self.stamp_host_time = getattr(source, "host_time_ns", time.time_ns)  # a sim source may emulate a PC clock
        self.hung: list[SourceReader] = []  # readers the watchdog abandoned inside a read that never returned
        self.failures_while_hung = 0
        if hasattr(source, "attach"):  # a kinect source orders camera starts across workers over this session
            source.attach(session, should_exit=lambda: lifecycle.should_exit or time.monotonic_ns() >= self.deadline_ns)
        log.info("capture worker %s: publishing sensor %s (%s) on %s", name, sensor_id, type(source).__name__, key)

    def run(self) -> None:
        try:
            while not self.lifecycle.should_exit:
                reader = SourceReader(self.source, self.name, self.clouds_at)
                try:
                    self._read_and_publish(reader)
                    return
                except (ConfigError, ServiceError):
                    raise
                except Exception as exc:  # the source failed or stalled: log, back off, start it again
                    if self._recover(exc, reader):
                        return
                finally:
                    if not reader.stop() and reader not in self.hung:
                        log.warning(
                            "capture worker %s: stopping with a read of its source still blocked (left behind)",
                            self.name,
                        )
        finally:
            self._close()

    def _read_and_publish(self, reader: SourceReader) -> None:
        """Publish the reader's frames until the run ends (returns) or the source fails or stalls (raises)."""
        watching = False  # the watchdog starts with the source's first answer (a device open, a frame)
        waiting_since = time.monotonic_ns()
        while True:
            now = time.monotonic_ns()
            if now >= self.next_status:
                self.status("running")
                self.next_status = now + self.period_ns
            if self.lifecycle.should_exit or now >= self.deadline_ns:
                return
            item = reader.next(READ_POLL_S)
            if item is _END:
                log.info("capture worker %s: source finished", self.name)
                return
            now = time.monotonic_ns()
            if item is not None and not watching:
                watching, waiting_since = True, now
            if item is None or item[1] is None:  # nothing yet: a read still running, or a silent device
                self._watchdog(watching, (now - waiting_since) / 1e9)
                continue
            if self._publish(*item):
                return
            waiting_since = time.monotonic_ns()
            if self.limits.max_frames is not None and self.report.frames_out >= self.limits.max_frames:
                return
            if time.monotonic() - self.start > (self.limits.duration_s or math.inf):
                return

    def _watchdog(self, watching: bool, silent_s: float) -> None:
        """Raise SourceStalled when the source has been silent too long (after its first answer, or before)."""
        options = self.options
        if watching and options.stall_timeout_s is not None and silent_s > options.stall_timeout_s + DIAGNOSIS_GRACE_S:
            raise SourceStalled(f"no frame for {silent_s:.1f} s (watchdog: restarting the source)")
        if not watching and options.open_timeout_s is not None and silent_s > options.open_timeout_s:
            raise SourceStalled(
                f"the source has not opened after {silent_s:.1f} s (a device open or tracker create "
                "that hangs?; watchdog: restarting the source)"
            )

    def _publish(self, due_ns: int, frame: SensorFrame, clouds: Any) -> bool:
        """Wait until the frame is due, then publish it; True when the run ended before it could."""
        if due_ns > self.deadline_ns or self.lifecycle.should_exit:
            return True
        wait_ns = due_ns - time.monotonic_ns()
        if wait_ns > 0 and self.lifecycle.wait(wait_ns / 1e9):
            return True
        if wait_ns < -5_000_000:
            self.report.late_publishes += 1
        if not self.stamps_host_time:
            frame = dataclasses.replace(frame, host_time_ns=self.stamp_host_time())
        if self.clouds_pub is not None and clouds is not None:  # before the skeletons: the node has
            # them when the instant is fused
            self.clouds_pub.put(encode_person_clouds(dataclasses.replace(clouds, host_timestamp_ns=frame.host_time_ns)))
        self.publisher.put(encode_sensor_frame(frame))
        self.report.frames_out += 1
        self.window_frames += 1
        self.backoff = BACKOFF_FIRST_S
        return False

    def _recover(self, exc: Exception, reader: SourceReader) -> bool:
        """After a failure: count it, abandon a blocked read, back off; True when the run ends meanwhile.

        Raises
        ------
        ServiceError
            An abandoned read is still blocked after :data:`MAX_FAILURES_WHILE_HUNG` more failures.
        """
        name, report = self.name, self.report
        if isinstance(exc, (SourceStalled, TrackerStalled)):
            report.stalls += 1
        report.restarts += 1
        self.last_error = f"{type(exc).__name__}: {exc}"
        if not reader.stop():
            self.hung.append(reader)
            log.error(
                "capture worker %s: the source's read has not returned (a hung SDK call?); its thread is abandoned",
                name,
            )
        self.hung = [r for r in self.hung if r.blocked]
        self.failures_while_hung = self.failures_while_hung + 1 if self.hung else 0
        if self.hung and self.failures_while_hung > MAX_FAILURES_WHILE_HUNG:
            raise ServiceError(
                f"capture worker {name}: a read of its source is still blocked and the source failed "
                f"{self.failures_while_hung - 1} more times since ({self.last_error}); exiting so that the service "
                "manager starts a fresh process (systemd: Restart=on-failure)"
            ) from None
        log.error(
            "capture worker %s: source failed (%s); restarting it in %.1f s",
            name,
            self.last_error,
            self.backoff,
            exc_info=log.isEnabledFor(logging.DEBUG),
        )
        self.status("degraded")
        if self.lifecycle.wait(min(self.backoff, max(0.0, (self.deadline_ns - time.monotonic_ns()) / 1e9))):
            return True
        if time.monotonic_ns() >= self.deadline_ns:
            log.info("capture worker %s: --duration reached while the source was failing", name)
            return True
        self.backoff = min(self.backoff * 2, BACKOFF_MAX_S)
        return False

    def status(self, state: str) -> None:
        now = time.monotonic_ns()
        window_s = max((now - self.last_status) / 1e9, 1e-9)
        info = {
            "sensor": self.sensor_id,
            "source": type(self.source).__name__,
            "rate_hz": round(self.window_frames / window_s, 3),
            "last_error": self.last_error or None,
        }
        report = self.report
        counters = {
            "frames_out": report.frames_out,
            "restarts": report.restarts,
            "late_publishes": report.late_publishes,
            "stalls": report.stalls,
        }
        status = NodeStatus(
            node=self.name, role="capture", state=state, time_ns=time.time_ns(), counters=counters, info=info
        )
        self.status_pub.put(encode_status(status))
        self.window_frames = 0
        self.last_status = now

    def _close(self) -> None:
        self.lifecycle.request_exit()
        self.status("stopped")
        self.token.undeclare()
        self.publisher.undeclare()
        if self.clouds_pub is not None:
            self.clouds_pub.undeclare()
        self.status_pub.undeclare()
