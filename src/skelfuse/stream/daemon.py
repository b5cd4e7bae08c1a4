"""The stream daemon: subscribe to the rig's fused stream and re-send every frame in another protocol.

Cycle (``skelfuse stream osc|lsl``)::

    zenoh subscriber (skelfuse/<rig>/fused/skeletons)
      -> BoundedSampleQueue      a zenoh callback never waits: when the queue is full the OLDEST frame is
                                 dropped and counted (a live stream wants the newest pose)
      -> one loop thread         decode (a bad payload is counted by reason, never sent, never fatal)
      -> sender.send(frame)      OSC: a non-blocking UDP socket; LSL: the outlet's buffer
    SIGINT/SIGTERM: stop taking frames, send what is queued within [stream] drain_timeout_s, close.

The daemon is one more subscriber: fusion never waits for it, and a receiver that is gone only costs that
receiver its frames (counted as send errors for UDP).
"""

from __future__ import annotations

import logging
import queue
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

from skelfuse.config import RigConfig
from skelfuse.schema.frames import FusedFrame
from skelfuse.service.lifecycle import Lifecycle, RunLimits
from skelfuse.service.zenoh_io import (
    SESSION_CLOSE_TIMEOUT_S,
    Received,
    StopBudget,
    close_session,
    open_session,
    put_dropping_oldest,
)
from skelfuse.wire import keys
from skelfuse.wire.codec import DecodeError, decode_fused_frame

if TYPE_CHECKING:  # pragma: no cover - typing only
    import zenoh

log = logging.getLogger("skelfuse.stream")


class FrameSender(Protocol):
    """What the daemon drives: OSC, LSL (and VMC once its builder is in the tree)."""

    stats: Any

    def send(self, frame: FusedFrame) -> None: ...

    def close(self) -> None: ...

    def describe(self) -> str: ...


class BoundedSampleQueue:
    """A zenoh subscriber callback with a bounded queue that drops the oldest sample when full.

    The callback runs on a zenoh thread and must never block: a stuck consumer costs old frames, not
    memory and not a stalled zenoh session.
    """

    def __init__(self, maxsize: int) -> None:
        if maxsize < 1:
            raise ValueError(f"queue size must be at least 1, got {maxsize}")
        self._queue: queue.Queue[Received] = queue.Queue(maxsize)
        self.dropped = 0

    def __call__(self, sample: Any) -> None:
        self.put(Received(time.monotonic_ns(), str(sample.key_expr), sample.payload.to_bytes()))

    def put(self, item: Received) -> None:
        self.dropped += put_dropping_oldest(self._queue, item)

    def get(self, timeout: float) -> Received | None:
        try:
            return self._queue.get(timeout=timeout)
        except queue.Empty:
            return None

    def qsize(self) -> int:
        return self._queue.qsize()


@dataclass
class StreamReport:
    frames_in: int = 0
    frames_out: int = 0
    dropped: int = 0
    rejects: Counter[str] = field(default_factory=Counter)
    send_failures: int = 0


def run_stream(
    cfg: RigConfig,
    zenoh_conf: zenoh.Config,
    sender: FrameSender,
    *,
    node: str,
    limits: RunLimits,
    lifecycle: Lifecycle,
) -> StreamReport:
    """Re-send the rig's fused frames through ``sender`` until a signal or the run limits (see the module)."""
    report = StreamReport()
    samples = BoundedSampleQueue(cfg.stream.queue_size)
    with lifecycle.capture_signals():
        session = open_session(
            zenoh_conf, lifecycle=lifecycle, what=node, deadline=limits.deadline(time.monotonic())
        )  # an unreachable router is retried until --duration at most
        if session is None:
            sender.close()
            return report
        budget: StopBudget | None = None  # from the stop's start
        try:
            subscriber = session.declare_subscriber(keys.fused_skeletons(cfg.name), samples)
            token = session.liveliness().declare_token(keys.alive(cfg.name, node))
            log.info("%s: streaming rig %s's fused skeletons as %s", node, cfg.name, sender.describe())
            start = time.monotonic()
            while not lifecycle.should_exit and not limits.reached(report.frames_out, start):
                item = samples.get(timeout=0.05)
                if item is not None:
                    _forward(item, sender, report, node)
            subscriber.undeclare()
            # Drain: what was received before the stop is still sent, within the drain timeout, which the
            # session close comes out of too (service.zenoh_io.StopBudget).
            budget = StopBudget.start(cfg.stream.drain_timeout_s)
            while not lifecycle.force_exit and time.monotonic() < budget.drain_until:
                if limits.max_frames is not None and report.frames_out >= limits.max_frames:
                    break
                item = samples.get(timeout=0)
                if item is None:
                    break
                _forward(item, sender, report, node)
            token.undeclare()
        finally:
            lifecycle.request_exit()  # the stop begins (bounded by the stop watchdog)
            sender.close()
            close_timeout_s = SESSION_CLOSE_TIMEOUT_S if budget is None else budget.close_timeout_s()
            close_session(session, what="stream", timeout_s=close_timeout_s)
    report.dropped = samples.dropped
    log.info(
        "%s: %d fused frames in, %d sent, %d dropped (queue full), %d rejected",
        node,
        report.frames_in,
        report.frames_out,
        report.dropped,
        sum(report.rejects.values()),
    )
    return report


def _forward(item: Received, sender: FrameSender, report: StreamReport, node: str) -> None:
    report.frames_in += 1
    try:
        frame = decode_fused_frame(item.payload)
    except DecodeError as exc:
        report.rejects[exc.reason] += 1
        if report.rejects[exc.reason] == 1:
            log.warning("%s: rejected a fused payload (%s): %s", node, exc.reason, exc)
        return
    try:
        sender.send(frame)
    except Exception as exc:  # a sender must not kill the daemon: count, log once in a while, go on
        report.send_failures += 1
        if report.send_failures in (1, 10, 100) or report.send_failures % 1000 == 0:
            log.warning("%s: sending a frame failed (%d so far): %r", node, report.send_failures, exc)
        return
    report.frames_out += 1
