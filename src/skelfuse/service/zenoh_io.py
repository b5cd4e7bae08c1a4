"""zenoh plumbing shared by the nodes: opening a session with retries, loopback settings, samples into a queue.

Threads: zenoh runs subscriber callbacks on its own threads. :class:`SampleQueue` is the only thing a
callback touches: it stamps the arrival (monotonic ns), copies the payload to ``bytes`` and puts one tuple
into a ``queue.Queue``. The node's single loop thread takes them out, so decoding, grouping and
fusion state are single-threaded.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import queue
import socket
import time
from collections.abc import Sequence
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


class SampleQueue:
    """A zenoh subscriber callback that hands samples to one consumer thread.

    Use ``session.declare_subscriber(key, sample_queue)``; the consumer calls :meth:`get`.

    Bounded, so no peer can raise the node's memory for good: a payload over ``max_payload_bytes`` is
    dropped before it is copied (counted in :attr:`oversized`), and while ``max_items`` samples wait, new
    ones are dropped (counted in :attr:`dropped`). None: no bound.
    """

    def __init__(self, *, max_items: int | None = None, max_payload_bytes: int | None = None) -> None:
        # queue.Queue, not SimpleQueue: CPython 3.11's SimpleQueue.get(timeout=...) can block forever when a
        # signal (SIGTERM) interrupts it in the main thread and the deadline passes meanwhile.
        self._queue: queue.Queue[Received] = queue.Queue()
        self.max_items = max_items
        self.max_payload_bytes = max_payload_bytes
        self.dropped = 0
        self.oversized = 0

    def __call__(self, sample: Any) -> None:
        # Runs on a zenoh thread: stamp first, copy, hand over; nothing that can raise on bad data.
        arrival_ns = time.monotonic_ns()
        payload = sample.payload
        if self.max_payload_bytes is not None and len(payload) > self.max_payload_bytes:
            self.oversized += 1
            return
        if self.max_items is not None and self._queue.qsize() >= self.max_items:
            self.dropped += 1
            return
        self._queue.put(Received(arrival_ns, str(sample.key_expr), payload.to_bytes()))

    def get(self, timeout: float | None) -> Received | None:
        """The next sample, waiting up to ``timeout`` seconds (None: forever); None when none came."""
        try:
            return self._queue.get(timeout=timeout) if timeout is None or timeout > 0 else self._queue.get_nowait()
        except queue.Empty:
            return None

    def get_nowait(self) -> Received | None:
        try:
            return self._queue.get_nowait()
        except queue.Empty:
            return None

    def qsize(self) -> int:
        return self._queue.qsize()


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
