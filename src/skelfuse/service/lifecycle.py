"""Service lifecycle: signals, run limits and logs of skelfuse's long-running nodes.

Modelled on uvicorn's ``Server.capture_signals`` / ``handle_exit`` / ``shutdown``. Cycle of every node::

    lifecycle = Lifecycle("fusion")
    with lifecycle.capture_signals():          # SIGINT / SIGTERM -> handle_exit (main thread only)
        while not lifecycle.should_exit and not limits.reached(frames):
            ...                                 # one iteration of the node's loop
            lifecycle.wait(seconds)             # sleeps, wakes early on exit
        drain(timeout=...)                      # bounded: a second Ctrl-C sets force_exit and cuts it short
    # the original handlers are restored here

The first SIGINT or SIGTERM asks for a clean shutdown (``should_exit``): the node stops taking new input,
drains what it holds within a timeout, flushes its files and closes its zenoh session. A second Ctrl-C
sets ``force_exit``: the drain is cut short (files are still closed). The process exits 0 after a clean
shutdown by signal (systemd counts that as success; uvicorn re-raises the signal instead).

A node running in a thread (the demo's fusion node) gets its own :class:`Lifecycle` and is stopped with
:meth:`Lifecycle.request_exit`; only the main thread installs signal handlers.

The stop is bounded whatever a sink or a peer does: once a stop began (a signal, a run limit, an error
leaving the block), a watchdog thread gives the node ``stop_timeout_s`` (:data:`STOP_TIMEOUT_S`) to leave
:meth:`Lifecycle.capture_signals`; past it, it logs which node hung, dumps every thread's stack to stderr
and ends the process with :data:`FORCED_EXIT_CODE`. The drains and flushes inside have their own shorter
timeouts, so the watchdog only fires on a bug or a library call that ignores its timeout.
"""

from __future__ import annotations

import contextlib
import faulthandler
import json
import logging
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from types import FrameType

log = logging.getLogger("skelfuse.service")

HANDLED_SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""Signals that shut a node down cleanly."""
STOP_TIMEOUT_S = 15.0
"""Longest a node may take from the start of its stop to its end before the watchdog ends the process."""
FORCED_EXIT_CODE = 4
"""Exit status of a process the stop watchdog had to end (docs/service.md, "Exit codes")."""


class Lifecycle:
    """Exit flags of one node, set by signals or by :meth:`request_exit`.

    Parameters
    ----------
    name : str
        The node's name, used in log messages.

    Attributes
    ----------
    should_exit : bool
        A clean shutdown was asked for: leave the loop, drain, flush, close.
    force_exit : bool
        A second Ctrl-C: cut the drain short.
    """

    def __init__(self, name: str = "skelfuse") -> None:
        self.name = name
        self.should_exit = False
        self.force_exit = False
        self._wake = threading.Event()

    def handle_exit(self, sig: int, frame: FrameType | None) -> None:
        """Signal handler: the first SIGINT/SIGTERM asks for a clean shutdown, a second SIGINT forces it.

        Only sets flags and logs (safe in a signal handler); :meth:`wait` notices within 50 ms.
        """
        try:
            name = signal.Signals(sig).name
        except ValueError:
            name = str(sig)
        if self.should_exit and sig == signal.SIGINT:
            self.force_exit = True
            log.warning("%s: second %s, forcing exit (the drain is cut short)", self.name, name)
        else:
            self.should_exit = True
            log.info("%s: received %s, shutting down (press Ctrl-C again to force)", self.name, name)

    def request_exit(self, *, force: bool = False) -> None:
        """Ask for a clean shutdown from code (another thread, a test, a run limit)."""
        self.should_exit = True
        if force:
            self.force_exit = True
        self._wake.set()

    def wait(self, seconds: float) -> bool:
        """Sleep up to ``seconds``, waking early when an exit is asked for; returns ``should_exit``."""
        deadline = time.monotonic() + max(0.0, seconds)
        while not self.should_exit:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            # Short slices: a signal handler only sets a flag (setting an Event from a handler can deadlock).
            self._wake.wait(min(remaining, 0.05))
        return self.should_exit

    @contextlib.contextmanager
    def capture_signals(self, *, stop_timeout_s: float | None = STOP_TIMEOUT_S) -> Iterator[None]:
        """Route SIGINT/SIGTERM to :meth:`handle_exit` inside the block; restore the original handlers after.

        With ``stop_timeout_s``, a watchdog ends the process (:data:`FORCED_EXIT_CODE`) when the block has
        not been left ``stop_timeout_s`` seconds after ``should_exit`` was set (nodes set it with
        :meth:`request_exit` when a run limit is reached or their loop fails, before they clean up). Outside
        the main thread (where Python cannot install handlers) this does
        nothing: the owner of the thread stops it with :meth:`request_exit`.
        """
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        original = {sig: signal.signal(sig, self.handle_exit) for sig in HANDLED_SIGNALS}
        left = threading.Event()
        if stop_timeout_s is not None:
            threading.Thread(
                target=self._stop_watchdog, args=(left, stop_timeout_s), name=f"{self.name}-stop-watchdog", daemon=True
            ).start()
        try:
            yield
        finally:
            left.set()
            for sig, handler in original.items():
                signal.signal(sig, handler)

    def _stop_watchdog(self, left: threading.Event, stop_timeout_s: float) -> None:
        while not self.should_exit:
            if left.wait(0.1):
                return
        if left.wait(stop_timeout_s):
            return
        log.error(
            "%s: still stopping %.0f s after the stop began (a sink or a peer is blocking); ending the process "
            "with status %d (stacks below)",
            self.name,
            stop_timeout_s,
            FORCED_EXIT_CODE,
        )
        with contextlib.suppress(Exception):
            faulthandler.dump_traceback(all_threads=True)
        os._exit(FORCED_EXIT_CODE)


@dataclass(frozen=True)
class RunLimits:
    """When a node stops by itself: after ``duration_s`` seconds or ``max_frames`` frames (None: never).

    Every long-running command takes ``--duration`` and ``--max-frames`` so tests and CI terminate.
    """

    duration_s: float | None = None
    max_frames: int | None = None

    def __post_init__(self) -> None:
        if self.duration_s is not None and not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise ValueError(f"--duration must be a positive number of seconds, got {self.duration_s!r}")
        if self.max_frames is not None and self.max_frames < 1:
            raise ValueError(f"--max-frames must be at least 1, got {self.max_frames!r}")

    def deadline(self, start_monotonic: float) -> float:
        """Monotonic time at which the duration ends (inf without a duration)."""
        return math.inf if self.duration_s is None else start_monotonic + self.duration_s

    def reached(self, frames: int, start_monotonic: float, now: float | None = None) -> bool:
        """Whether the node should stop: enough frames, or the duration has passed."""
        if self.max_frames is not None and frames >= self.max_frames:
            return True
        now = time.monotonic() if now is None else now
        return now >= self.deadline(start_monotonic)


class JsonLogFormatter(logging.Formatter):
    """One JSON object per line: ``ts`` (UTC ISO 8601), ``level``, ``logger``, ``msg``, and any ``extra`` keys.

    Structured logs for journald / log shippers (``skelfuse --log-format json ...``).
    """

    _STANDARD = frozenset(vars(logging.LogRecord("", 0, "", 0, "", None, None))) | {"message", "asctime"}

    def format(self, record: logging.LogRecord) -> str:
        doc = {
            "ts": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created)) + f".{int(record.msecs):03d}Z",
            "level": record.levelname,
            "logger": record.name,
            "msg": record.getMessage(),
        }
        for key, value in vars(record).items():
            if key not in self._STANDARD and not key.startswith("_"):
                doc[key] = value
        if record.exc_info:
            doc["exc"] = self.formatException(record.exc_info)
        return json.dumps(doc, default=str, allow_nan=False)


def configure_logging(*, verbose: bool = False, fmt: str = "text") -> None:
    """Logs on stderr: ``text`` (time level logger: message) or ``json`` (one object per line)."""
    handler = logging.StreamHandler(sys.stderr)
    if fmt == "json":
        handler.setFormatter(JsonLogFormatter())
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    for old in [h for h in root.handlers if getattr(h, "_skelfuse", False)]:
        root.removeHandler(old)
    handler._skelfuse = True  # type: ignore[attr-defined]  # a mark on our own handler, so a second setup replaces it
    if not root.handlers:
        root.addHandler(handler)
    root.setLevel(logging.DEBUG if verbose else logging.INFO)
