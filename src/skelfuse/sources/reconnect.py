"""Keeping a live sensor running: :func:`run_with_reconnect` reopens a
:class:`~skelfuse.sources.kinect.SkeletonSource` that fails (an unplugged sensor, a tracker that stops answering)
with exponential backoff, and :class:`WorkerFrameSource` adapts a source to the capture worker's frame loop.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from skelfuse.schema.errors import ConfigError, ServiceError, SkelfuseError
from skelfuse.schema.frames import SensorFrame
from skelfuse.sources.kinect import (
    EndOfStream,
    SkeletonSource,
    TrackerStalled,
)

log = logging.getLogger("skelfuse.sources.kinect")  # one logger for the Kinect source and its reconnects


@dataclass(frozen=True)
class Backoff:
    """Exponential backoff between reconnect attempts: initial_s, initial_s * factor, ..., capped at max_s."""

    initial_s: float = 0.5
    factor: float = 2.0
    max_s: float = 10.0

    def __post_init__(self) -> None:
        if not (self.initial_s >= 0 and self.factor >= 1 and self.max_s >= self.initial_s):
            raise ValueError(f"Backoff needs initial_s >= 0, factor >= 1, max_s >= initial_s; got {self}")

    def delays(self) -> Iterator[float]:
        delay = self.initial_s
        while True:
            yield delay
            delay = min(delay * self.factor, self.max_s)


@dataclass
class ReconnectReport:
    """What :func:`run_with_reconnect` did."""

    frames: int = 0
    opens: int = 0
    failures: int = 0
    last_error: str | None = None
    delays: list[float] = field(default_factory=list)


def run_with_reconnect(
    open_source: Callable[[], SkeletonSource],
    on_frame: Callable[[SensorFrame], Any],
    should_exit: Callable[[], bool],
    *,
    backoff: Backoff | None = None,
    read_timeout_s: float = 0.1,
    wait: Callable[[float], Any] | None = None,
    on_error: Callable[[BaseException, float], Any] | None = None,
) -> ReconnectReport:
    """Read frames from a source forever, reopening it with exponential backoff whenever it fails.

    Parameters
    ----------
    open_source : () -> SkeletonSource
        Builds a fresh (unopened) source; called for every (re)connect.
    on_frame : (SensorFrame) -> Any
        Called for every frame (publish it).
    should_exit : () -> bool
        Checked after every read (at most ``read_timeout_s`` apart) and while backing off.
    backoff : Backoff
        Delays between attempts; reset to the first after a frame arrives.
    wait : (seconds) -> Any, optional
        Interruptible sleep (e.g. ``Lifecycle.wait``); default: sleeps in slices of 50 ms checking should_exit.
    on_error : (exception, next delay s) -> Any, optional
        Told about every failure (status reporting).

    Returns
    -------
    ReconnectReport

    Raises
    ------
    ServiceError, ConfigError
        Problems retrying cannot fix: pyk4a / the SDK missing (KinectUnavailable, K4ABTLibraryError), a bad
        config. Everything else (unplugged sensor, tracker failure, timeouts) is logged and retried.
    """
    backoff = backoff or Backoff()
    report = ReconnectReport()
    delays = backoff.delays()

    while not should_exit():
        source: SkeletonSource | None = None
        try:
            source = open_source()
            source.open()
            report.opens += 1
            while not should_exit():
                frame = source.read(read_timeout_s)
                if frame is not None:
                    on_frame(frame)
                    report.frames += 1
                    delays = backoff.delays()
            return report
        except EndOfStream:
            log.info("source %s: end of stream", getattr(source, "sensor_id", "?"))
            return report
        except (ServiceError, ConfigError):
            raise
        except Exception as exc:
            delay = next(delays)
            _note_failure(exc, source, delay, report)
            if on_error is not None:
                on_error(exc, delay)
        finally:
            if source is not None:
                source.close()
        if should_exit():
            break
        _pause(delay, wait, should_exit)
    return report


def _pause(seconds: float, wait: Callable[[float], Any] | None, should_exit: Callable[[], bool]) -> None:
    """Wait ``seconds`` before the next attempt (with ``wait`` when given), returning early on ``should_exit``."""
    if wait is not None:
        wait(seconds)
        return
    deadline = time.monotonic() + seconds
    while not should_exit():
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return
        time.sleep(min(0.05, remaining))


def _note_failure(exc: Exception, source: SkeletonSource | None, delay: float, report: ReconnectReport) -> None:
    """Count a failure and log it: a warning for a typed error, an error with its traceback for anything else."""
    report.failures += 1
    report.last_error = f"{type(exc).__name__}: {exc}"
    report.delays.append(delay)
    expected = isinstance(exc, SkelfuseError)
    log.log(
        logging.WARNING if expected else logging.ERROR,
        "source %s failed (%s); reconnecting in %.1f s",
        getattr(source, "sensor_id", "?"),
        report.last_error,
        delay,
        exc_info=not expected,
    )


class WorkerFrameSource:
    """Adapts a SkeletonSource to the capture worker's ``FrameSource`` (``frames()`` of ``(due_ns, frame)``).

    Frames are due at once (``time.monotonic_ns()``: a live device paces itself). When no frame comes for
    ``idle_timeout_s`` it raises TrackerStalled, so the worker regains control (and its restart-with-backoff
    loop reopens the device) even when ``should_exit`` is not wired.
    """

    def __init__(
        self,
        source: SkeletonSource,
        *,
        should_exit: Callable[[], bool] = lambda: False,
        read_timeout_s: float = 0.1,
        idle_timeout_s: float = 5.0,
    ) -> None:
        self.source = source
        self.sensor_id = source.sensor_id
        self.should_exit = should_exit
        self.read_timeout_s = read_timeout_s
        self.idle_timeout_s = idle_timeout_s

    def frames(self) -> Iterator[tuple[int, SensorFrame]]:
        self.source.open()
        try:
            last = time.monotonic()
            while not self.should_exit():
                try:
                    frame = self.source.read(self.read_timeout_s)
                except EndOfStream:
                    return
                now = time.monotonic()
                if frame is not None:
                    last = now
                    yield time.monotonic_ns(), frame
                elif now - last > self.idle_timeout_s:
                    raise TrackerStalled(f"sensor {self.sensor_id}: no frame for {now - last:.1f} s")
        finally:
            self.source.close()
