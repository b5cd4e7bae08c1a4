"""zenoh plumbing shared by the nodes: opening a session with retries, loopback settings, samples into a queue.

Threads: zenoh runs subscriber callbacks on its own threads. :class:`SampleQueue` is the only thing a
callback touches: it stamps the arrival (monotonic ns), copies the payload to ``bytes`` and queues one tuple
(bounded and fair per key). The node's single loop thread takes them out, so decoding, grouping and
fusion state are single-threaded.
"""

from __future__ import annotations

import collections
import contextlib
import json
import logging
import math
import queue
import socket
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

from skelfuse.schema.errors import ConfigError, ServiceError
from skelfuse.service.lifecycle import Lifecycle

if TYPE_CHECKING:  # pragma: no cover - typing only
    import zenoh

log = logging.getLogger("skelfuse.service")

BACKOFF_FIRST_S = 0.5
BACKOFF_MAX_S = 10.0


class Received(NamedTuple):
    """One sample as the node loop sees it."""

    arrival_ns: int  # time.monotonic_ns() in the zenoh callback
    key: str
    payload: bytes


OTHER_KEYS = "?"
"""The bucket label of samples on keys a :class:`SampleQueue` was not told about (they share one bucket)."""


class _Entry:
    """One queued sample; ``item`` None once it was dropped (left in the arrival order until passed over)."""

    __slots__ = ("item", "label", "size")

    def __init__(self, item: Received, label: str, size: int) -> None:
        self.item: Received | None = item
        self.label = label
        self.size = size


class SampleQueue:
    """A zenoh subscriber callback that hands samples to one consumer thread, fair per key.

    Use ``session.declare_subscriber(key, sample_queue)``; the consumer calls :meth:`get` and receives the
    samples in arrival order.

    Bounded, so no peer can raise the node's memory for good, and fair, so no peer can push out another's
    frames: samples are queued per bucket (one per key in ``labels``, whose value names it; samples on any
    other key share the bucket :data:`OTHER_KEYS`). A payload over ``max_payload_bytes`` is dropped before it is
    copied (counted in :attr:`oversized_by`). A bucket holding ``max_items_per_key`` samples drops its own oldest
    to take a new one; while more than ``max_items`` samples or ``max_bytes`` payload bytes wait in all, the
    bucket holding the most drops its oldest. So a key that floods or bursts loses its own oldest samples and
    the other keys keep theirs (drops counted per bucket in :attr:`dropped_by`). None: no bound. Without
    ``labels``, every key is its own bucket (then the counters grow with the keys seen: give ``labels`` where
    peers choose the keys).
    """

    def __init__(
        self,
        *,
        max_items: int | None = None,
        max_payload_bytes: int | None = None,
        max_items_per_key: int | None = None,
        max_bytes: int | None = None,
        labels: Mapping[str, str] | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        if max_bytes is not None and max_payload_bytes is not None and max_bytes < max_payload_bytes:
            raise ValueError(f"max_bytes ({max_bytes}) must hold one payload of max_payload_bytes {max_payload_bytes}")
        # A Condition waits as queue.Queue does (not SimpleQueue: CPython 3.11's SimpleQueue.get(timeout=...) can
        # block forever when a signal interrupts it in the main thread and the deadline passes meanwhile).
        self._ready = threading.Condition(threading.Lock())
        self._order: collections.deque[_Entry] = collections.deque()  # arrival order, dropped entries included
        self._buckets: dict[str, collections.deque[_Entry]] = {}
        self._bucket_bytes: Counter[str] = Counter()
        self._items = 0
        self._bytes = 0
        self.max_items = max_items
        self.max_payload_bytes = max_payload_bytes
        self.max_items_per_key = max_items_per_key
        self.max_bytes = max_bytes
        self.labels = dict(labels) if labels is not None else None
        self.clock = clock  # the arrival stamp (monotonic ns); tests pass their own
        self.dropped_by: Counter[str] = Counter()
        self.oversized_by: Counter[str] = Counter()

    @property
    def dropped(self) -> int:
        """Samples dropped because their bucket or the queue was full, in all."""
        return sum(self.dropped_by.values())

    @property
    def oversized(self) -> int:
        """Payloads dropped unread because they were over ``max_payload_bytes``, in all."""
        return sum(self.oversized_by.values())

    def __call__(self, sample: Any) -> None:
        # Runs on a zenoh thread: stamp first, copy, hand over; nothing that can raise on bad data.
        arrival_ns = self.clock()
        key = str(sample.key_expr)
        label = key if self.labels is None else self.labels.get(key, OTHER_KEYS)
        payload = sample.payload
        size = len(payload)
        if self.max_payload_bytes is not None and size > self.max_payload_bytes:
            with self._ready:
                self.oversized_by[label] += 1
            return
        entry = _Entry(Received(arrival_ns, key, payload.to_bytes()), label, size)
        with self._ready:
            bucket = self._buckets.setdefault(label, collections.deque())
            if self.max_items_per_key is not None and len(bucket) >= self.max_items_per_key:
                self._drop_oldest(label)
            bucket.append(entry)
            self._order.append(entry)
            self._items += 1
            self._bytes += size
            self._bucket_bytes[label] += size
            while self.max_items is not None and self._items > self.max_items:
                self._drop_oldest(max(self._buckets, key=lambda b: len(self._buckets[b])))
            while self.max_bytes is not None and self._bytes > self.max_bytes:
                self._drop_oldest(max(self._buckets, key=lambda b: self._bucket_bytes[b]))
            if len(self._order) > 2 * self._items + 1024:  # forget dropped entries (amortised O(1))
                self._order = collections.deque(e for e in self._order if e.item is not None)
            self._ready.notify()

    def _drop_oldest(self, label: str) -> None:
        bucket = self._buckets[label]
        entry = bucket.popleft()
        entry.item = None  # frees the payload now; the entry leaves the arrival order when passed over
        self._items -= 1
        self._bytes -= entry.size
        self._bucket_bytes[label] -= entry.size
        self.dropped_by[label] += 1
        if not bucket:
            del self._buckets[label]

    def _take(self) -> Received | None:
        while self._order:
            entry = self._order.popleft()
            if entry.item is None:
                continue
            bucket = self._buckets[entry.label]
            bucket.popleft()  # the oldest live entry overall is the oldest of its bucket
            if not bucket:
                del self._buckets[entry.label]
            self._items -= 1
            self._bytes -= entry.size
            self._bucket_bytes[entry.label] -= entry.size
            return entry.item
        return None

    def get(self, timeout: float | None) -> Received | None:
        """The next sample, waiting up to ``timeout`` seconds (None: forever); None when none came."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._ready:
            while True:
                item = self._take()
                if item is not None:
                    return item
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                self._ready.wait(remaining)

    def get_nowait(self) -> Received | None:
        with self._ready:
            return self._take()

    def qsize(self) -> int:
        return self._items

    def counts(self) -> dict[str, dict[str, int]]:
        """Per bucket: samples waiting now, dropped (bucket or queue full) and oversized since the start."""
        with self._ready:
            labels = set(self._buckets) | set(self.dropped_by) | set(self.oversized_by)
            return {
                label: {
                    "queued": len(self._buckets.get(label, ())),
                    "dropped": self.dropped_by[label],
                    "oversized": self.oversized_by[label],
                }
                for label in sorted(labels)
            }


class FusedPublisher:
    """The fusion node's fused-frame publisher: zenoh's congestion control chosen in ``[zenoh]``, puts timed.

    ``"drop"`` (default): a put waits at most ``wait_before_drop_ms`` for room on a full link, then zenoh drops
    the frame for that link; while that link stays full, later frames drop at once (no wait), so a dead or
    stopped subscriber costs the node one bounded wait, and a busy one that reads again within the wait loses
    nothing. ``"block"``: a put waits until there is room, at most ``wait_before_close_ms``; then zenoh closes
    the link to that subscriber (it reconnects when it runs again). Either way the node's loop is held at most
    the bound per put. Express (no batching delay) on priority ``DATA_HIGH``: fused frames have their own
    transmit queue, apart from status and other traffic at the default priority.

    zenoh 1.10's Python ``put`` returns nothing and this build has no transport statistics, so a dropped frame
    cannot be seen here; :meth:`report` gives what can be: how long puts held the node, and how many reached
    the bound (a drop or a closed link most likely followed). Subscribers count the frames they missed.
    """

    def __init__(self, session: zenoh.Session, key: str, *, congestion_control: str, bound_ms: float) -> None:
        import zenoh

        control = {"drop": zenoh.CongestionControl.DROP, "block": zenoh.CongestionControl.BLOCK}[congestion_control]
        self._publisher = session.declare_publisher(
            key, express=True, priority=zenoh.Priority.DATA_HIGH, congestion_control=control
        )
        self.congestion_control = congestion_control
        self.bound_ms = bound_ms
        self.puts = 0
        self.held_max_ms = 0.0
        self.held_over_10ms = 0
        self.reached_bound = 0

    def put(self, payload: bytes) -> None:
        start = time.monotonic_ns()
        self._publisher.put(payload)
        held_ms = (time.monotonic_ns() - start) / 1e6
        self.puts += 1
        self.held_max_ms = max(self.held_max_ms, held_ms)
        self.held_over_10ms += held_ms >= 10.0
        self.reached_bound += held_ms >= 0.95 * self.bound_ms > 0

    def undeclare(self) -> None:
        self._publisher.undeclare()

    def report(self) -> dict[str, Any]:
        """Since the start: puts, the longest a put held the caller, puts held >= 10 ms and to the bound."""
        return {
            "congestion_control": self.congestion_control,
            "bound_ms": self.bound_ms,
            "puts": self.puts,
            "held_max_ms": round(self.held_max_ms, 3),
            "held_over_10ms": self.held_over_10ms,
            "reached_bound": self.reached_bound,
        }


def open_session(
    conf: zenoh.Config,
    *,
    lifecycle: Lifecycle,
    what: str,
    retry: bool = True,
    deadline: float = math.inf,
) -> zenoh.Session | None:
    """Open a zenoh session; on failure log a clear message and retry with exponential backoff.

    Returns None when an exit was asked for, or the monotonic ``deadline`` (the node's ``--duration``)
    passed, before the session opened.

    Raises
    ------
    ServiceError
        ``retry`` is False and the session cannot open.
    """
    import zenoh

    delay = BACKOFF_FIRST_S
    while not lifecycle.should_exit:
        if time.monotonic() >= deadline:
            log.error("%s: no zenoh session before the end of --duration; stopping", what)
            return None
        try:
            session = zenoh.open(conf)
        except Exception as exc:  # zenoh.ZError: endpoint in use, unreachable router, bad TLS files...
            message = (
                f"{what}: cannot open the zenoh session: {exc}; check [zenoh] connect/listen endpoints "
                f"and that the port is free or the router is up"
            )
            if not retry:
                raise ServiceError(message) from None
            log.error("%s (retrying in %.1f s)", message, delay)
            lifecycle.wait(min(delay, max(0.0, deadline - time.monotonic())))
            delay = min(delay * 2, BACKOFF_MAX_S)
            continue
        log.info("%s: zenoh session open (%s)", what, describe_zenoh(conf))
        return session
    return None


SESSION_CLOSE_TIMEOUT_S = 1.0
"""Longest a daemon waits for zenoh to close its session at shutdown before it leaves it behind (see
:func:`close_session`)."""
MIN_CLOSE_TIMEOUT_S = 0.05
"""What a close gets when its stop's budget is already spent (a starved process): one try, then it is left."""


@dataclass(frozen=True)
class StopBudget:
    """A daemon's stop within its drain timeout: drain until :attr:`drain_until`, the close gets the rest.

    The drain (fusing or sending what was queued) is bounded by the drain timeout, and so is everything after
    it: the last flush, the "stopped" status and the session close (itself bounded by
    :data:`SESSION_CLOSE_TIMEOUT_S`) come out of the same budget, not on top of it: a starved node's drain
    can use the whole budget, and a close on top of it would overrun the stop. The close is given up to
    half the budget and at most :data:`SESSION_CLOSE_TIMEOUT_S`; the drain stops that much before the end.
    """

    began: float
    end: float
    drain_until: float

    @classmethod
    def start(cls, drain_timeout_s: float, now: float | None = None) -> StopBudget:
        began = time.monotonic() if now is None else now
        reserve = min(SESSION_CLOSE_TIMEOUT_S, drain_timeout_s / 2)
        return cls(began=began, end=began + drain_timeout_s, drain_until=began + drain_timeout_s - reserve)

    def close_timeout_s(self, now: float | None = None) -> float:
        """What is left of the budget for the session close (at least :data:`MIN_CLOSE_TIMEOUT_S`)."""
        left = self.end - (time.monotonic() if now is None else now)
        return max(MIN_CLOSE_TIMEOUT_S, min(SESSION_CLOSE_TIMEOUT_S, left))


_left_behind: list[str] = []  # daemons whose session close was left running (see close_session)


def sessions_left_behind() -> list[str]:
    """Which sessions :func:`close_session` left closing in a thread (the process must then end with
    ``os._exit``: see there)."""
    return list(_left_behind)


def close_session(session: zenoh.Session, *, what: str, timeout_s: float = SESSION_CLOSE_TIMEOUT_S) -> bool:
    """Close a zenoh session, waiting at most ``timeout_s``; returns whether it closed in time.

    zenoh's ``Session.close()`` has no timeout in its Python API and waits on the session's links: towards a
    peer that stopped reading (a stopped or hung subscriber: its link's buffers are full) it took 2.5 s here and
    can end in ``close operation timed out`` after zenoh's own timeout. A daemon's stop must not depend on its
    peers, so the close runs in a daemon thread; past the bound it is left behind (logged: the process exits
    and the operating system closes the sockets, which the peers see as a closed link) and the caller goes on.
    An error from zenoh's close is logged, never raised: the session is being given up either way.

    A process that left a close behind must end with ``os._exit`` once its own files are closed (the command
    line does: :func:`skelfuse.cli.entrypoint`): when the close returns while the interpreter finalizes, its
    thread is unwound through zenoh's Rust frames and the process aborts (measured: "FATAL: exception not
    rethrown", SIGABRT, once in two stops).
    """
    done = threading.Event()
    errors: list[BaseException] = []

    def close() -> None:
        try:
            session.close()
        except Exception as exc:  # zenoh.ZError: "close operation timed out"
            errors.append(exc)
        finally:
            done.set()

    started = time.monotonic()
    threading.Thread(target=close, name="zenoh-close", daemon=True).start()
    if not done.wait(timeout_s):
        log.warning(
            "%s: zenoh session not closed after %.1f s (a peer not reading: a stopped or hung subscriber?); "
            "left behind, the process exits without waiting for it",
            what,
            timeout_s,
        )
        _left_behind.append(what)
        return False
    if errors:
        log.warning("%s: zenoh session close failed (%s); left behind", what, errors[0])
        return False
    log.debug("%s: zenoh session closed in %.3f s", what, time.monotonic() - started)
    return True


def describe_zenoh(conf: zenoh.Config) -> str:
    """Mode, endpoints and scouting of a zenoh config, in one line for start-up messages."""

    def get(key: str) -> Any:
        try:
            return json.loads(conf.get_json(key))
        except Exception:  # a key this zenoh version does not know: leave it out
            return None

    mode = get("mode") or "peer"
    parts = [f"mode {mode}"]
    for name in ("connect", "listen"):
        endpoints = get(f"{name}/endpoints")
        if isinstance(endpoints, dict):  # zenoh's per-mode defaults
            endpoints = endpoints.get(mode)
        parts.append(f"{name} {', '.join(endpoints) if endpoints else 'none'}")
    multicast = get("scouting/multicast/enabled")
    parts.append(f"multicast scouting {'off' if multicast is False else 'on'}")
    return ", ".join(parts)


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that is free right now on ``host`` (for tests and the demo's loopback rig)."""
    with contextlib.closing(socket.socket(socket.AF_INET, socket.SOCK_STREAM)) as sock:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])


def loopback_args(*, listen_port: int | None = None, connect_ports: Sequence[int] = ()) -> list[str]:
    """Command-line zenoh flags for one node of a loopback rig: peer mode, no multicast, explicit endpoints.

    Nodes that do not listen on a fixed port listen on ``tcp/127.0.0.1:0`` (a free port, loopback only)
    instead of zenoh's default of every interface, so sandboxes without network work. Gossip scouting stays
    on (it runs over the TCP links, not multicast): peers that connect to one hub learn each other's
    loopback endpoints and connect directly, so a subscriber beside the node also hears the workers.
    """
    listen = f"tcp/127.0.0.1:{listen_port if listen_port is not None else 0}"
    args = ["--zenoh-mode", "peer", "--no-multicast-scouting", "--zenoh-listen", listen]
    for port in connect_ports:
        args += ["--zenoh-connect", f"tcp/127.0.0.1:{port}"]
    return args


def loopback_config(*, listen_port: int | None = None, connect_ports: Sequence[int] = ()) -> zenoh.Config:
    """The zenoh.Config of :func:`loopback_args`, for in-process sessions."""
    import zenoh

    conf = zenoh.Config()
    listen = f"tcp/127.0.0.1:{listen_port if listen_port is not None else 0}"
    try:
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("listen/endpoints", json.dumps([listen]))
        if connect_ports:
            conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{p}" for p in connect_ports]))
    except Exception as exc:  # pragma: no cover - fixed keys, only a zenoh API change gets here
        raise ConfigError(f"zenoh rejected the loopback settings: {exc}") from None
    return conf


def wait_for_port(port: int, *, host: str = "127.0.0.1", timeout_s: float = 10.0) -> bool:
    """Wait until something accepts TCP connections on ``host:port``; False on timeout."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with contextlib.closing(socket.socket(socket.AF_INET, socket.SOCK_STREAM)) as sock:
            sock.settimeout(0.2)
            if sock.connect_ex((host, port)) == 0:
                return True
        time.sleep(0.05)
    return False


def put_dropping_oldest(samples: queue.Queue[Any], item: object) -> int:
    """Queue ``item`` in a bounded queue that a reader drains, discarding the oldest entries while it is full.

    A subscriber that falls behind loses its oldest samples, never the newest and never its callback's time.
    Returns how many entries were discarded (the caller counts them).
    """
    dropped = 0
    while True:
        try:
            samples.put_nowait(item)
            return dropped
        except queue.Full:
            try:
                samples.get_nowait()
                dropped += 1
            except queue.Empty:
                pass
