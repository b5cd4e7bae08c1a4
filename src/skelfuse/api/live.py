"""Subscribe to a running rig's fused skeletons: the door for apps that consume the live stream.

Cycle::

    with skelfuse.subscribe("lab", connect=["tcp/192.168.1.10:7447"]) as fused:   # opens a zenoh session
        frame = fused.receive(timeout_s=5.0)       # the next FusedFrame, or TimeoutError
        for frame in fused: ...                    # every frame until close() (from any thread)
                                                   # leaving the block closes the session

The session's settings come from the rig config when one is given (its ``[rig] name`` and ``[zenoh]`` section,
with the TLS files of the app's identity), else from the keyword arguments; keyword arguments override the
config, as the command line does (:func:`skelfuse.config.zenoh_config`). Zenoh delivers samples on its own
thread: each payload is decoded there (:func:`skelfuse.wire.codec.decode_fused_frame`) and put on a bounded
queue. A payload that fails to decode is counted in :attr:`FusedSubscriber.rejected` and logged with its
reason, never raised into the app; when the app falls behind, the oldest queued frame is dropped (counted in
:attr:`FusedSubscriber.dropped`) so that the app always reads the newest skeletons.

This module imports numpy and, when a session opens, zenoh: nothing heavier (no SciPy, OpenCV, Rerun or the
simulator), so an app that only subscribes starts fast (``tests/unit/test_public_api.py`` checks it).
"""

from __future__ import annotations

import logging
import os
import queue
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING

from skelfuse.config.access import app_identity
from skelfuse.config.model import RigConfig, ZenohSection, ZenohTls
from skelfuse.config.parse import load_rig_config
from skelfuse.config.zenoh_session import zenoh_config
from skelfuse.schema.errors import ConfigError, ServiceError
from skelfuse.schema.frames import FusedFrame
from skelfuse.service.zenoh_io import close_session, put_dropping_oldest
from skelfuse.wire import keys
from skelfuse.wire.codec import DecodeError, decode_fused_frame

if TYPE_CHECKING:  # pragma: no cover - typing only
    import zenoh

log = logging.getLogger("skelfuse.api")

__all__ = ["FusedSubscriber", "subscribe"]

DEFAULT_QUEUE_FRAMES = 64
"""Frames held for an app that falls behind (about 2 s at 30 fps) before the oldest is dropped."""

_LOGGED_REJECTS = 10
"""Reasons of the first rejected payloads logged one by one; later ones are only counted."""

_CLOSED = object()
"""Queue sentinel that wakes a blocked reader when the subscriber closes."""


class FusedSubscriber:
    """An open subscription to one rig's fused skeletons; made by :func:`subscribe`.

    Iterating yields :class:`~skelfuse.schema.frames.FusedFrame` objects until :meth:`close`; the ``with``
    statement closes it on exit. Thread-safe: :meth:`close` may be called from another thread (a signal
    handler, a UI) to end an iteration that is waiting.

    Attributes
    ----------
    key : str
        The key expression subscribed to (``skelfuse/<rig>/fused/skeletons``).
    received : int
        Fused frames decoded since the subscription opened (including dropped ones).
    rejected : int
        Payloads that failed to decode (each logged with its reason: the first few one by one).
    dropped : int
        Decoded frames discarded because the app had not read the queue (the oldest go first).
    """

    def __init__(self, session: zenoh.Session, key: str, queue_frames: int = DEFAULT_QUEUE_FRAMES) -> None:
        if queue_frames < 1:
            raise ValueError(f"queue_frames must be at least 1, got {queue_frames}")
        self.key = key
        self.received = 0
        self.rejected = 0
        self.dropped = 0
        self._queue: queue.Queue[object] = queue.Queue(maxsize=queue_frames)
        self._lock = threading.Lock()
        self._closed = False
        self._session = session
        self._subscriber = session.declare_subscriber(key, self._on_sample)

    # ---------------------------------------------------------------------------------------------- zenoh side

    def _on_sample(self, sample: zenoh.Sample) -> None:
        """zenoh's callback thread: decode, count, queue (dropping the oldest when full). Never raises."""
        try:
            frame = decode_fused_frame(sample.payload.to_bytes())
        except DecodeError as exc:
            with self._lock:
                self.rejected += 1
                count = self.rejected
            if count <= _LOGGED_REJECTS:
                log.warning("rejected a payload on %s (%s): %s", sample.key_expr, exc.reason, exc)
            return
        with self._lock:
            if self._closed:
                return
            self.received += 1
            self._put_newest(frame)

    def _put_newest(self, item: object) -> None:
        """Queue ``item``, discarding the oldest frame when the queue is full (caller holds the lock)."""
        self.dropped += put_dropping_oldest(self._queue, item)

    # ------------------------------------------------------------------------------------------------ app side

    def receive(self, timeout_s: float | None = None) -> FusedFrame:
        """The next fused frame, waiting at most ``timeout_s`` seconds (None: until one comes).

        Raises
        ------
        TimeoutError
            No frame arrived in time (is the fusion node running, and is this its rig?).
        ServiceError
            The subscriber is closed (before or while waiting).
        """
        try:
            item = self._queue.get(timeout=timeout_s)
        except queue.Empty:
            raise TimeoutError(
                f"no fused frame on {self.key} within {timeout_s} s: is the fusion node running, and is its rig "
                f"the one subscribed to? (`skelfuse status --config RIG.toml` shows what is up)"
            ) from None
        if item is _CLOSED:
            self._queue.put_nowait(_CLOSED)  # wake any other waiting reader too
            raise ServiceError(f"the subscriber to {self.key} is closed")
        assert isinstance(item, FusedFrame)
        return item

    def __iter__(self) -> Iterator[FusedFrame]:
        """Every fused frame, as it arrives, until :meth:`close`."""
        while True:
            try:
                yield self.receive()
            except ServiceError:
                return

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        """Undeclare the subscriber and close the zenoh session; a waiting :meth:`receive` wakes. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._put_newest(_CLOSED)
        self._subscriber.undeclare()
        close_session(self._session, what="the subscriber's zenoh session")  # bounded: a stalled peer cannot hold it

    def __enter__(self) -> FusedSubscriber:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, traceback: TracebackType | None
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"<FusedSubscriber {self.key} {state}: {self.received} received, {self.rejected} rejected>"


def subscribe(
    rig: str | None = None,
    *,
    config: str | os.PathLike[str] | RigConfig | None = None,
    connect: Sequence[str] | None = None,
    listen: Sequence[str] | None = None,
    mode: str | None = None,
    multicast_scouting: bool | None = None,
    tls_ca: str | os.PathLike[str] | None = None,
    tls_certificate: str | os.PathLike[str] | None = None,
    tls_private_key: str | os.PathLike[str] | None = None,
    app: str | None = None,
    queue_frames: int = DEFAULT_QUEUE_FRAMES,
) -> FusedSubscriber:
    """Open a zenoh session and subscribe to the fused skeletons of ``rig``.

    Parameters
    ----------
    rig : str, optional
        The rig's name (``[rig] name`` of its config); taken from ``config`` when not given.
    config : path or RigConfig, optional
        The rig config: its name, and its ``[zenoh]`` section (mode, endpoints, scouting, ``[zenoh.tls]``).
    connect, listen : sequence of str, optional
        zenoh endpoints (``"tcp/192.168.1.10:7447"``, ``"tls/fusion-pc:7447"``); override the config's.
    mode : {"peer", "client"}, optional
        zenoh session mode; default the config's, else peer.
    multicast_scouting : bool, optional
        UDP multicast discovery; default the config's, else on (zenoh's default) when no config is given.
    tls_ca, tls_certificate, tls_private_key : path, optional
        TLS files without a config (the rig's CA, this app's certificate and key from ``skelfuse certs``);
        with a config that has ``[zenoh.tls] directory``, give ``app`` instead.
    app : str, optional
        This app's name: with a TLS directory, its certificate is ``app-<name>.pem`` (``skelfuse certs --app``).
    queue_frames : int
        Frames kept for an app that falls behind before the oldest is dropped.

    Returns
    -------
    FusedSubscriber
        Use it as a context manager, or call :meth:`FusedSubscriber.close`.

    Raises
    ------
    ConfigError
        No rig name, a rig name that differs from the config's, a bad config or endpoint, missing TLS files.
    ServiceError
        zenoh could not open the session (the message names the endpoints).
    """
    cfg = _rig_config(rig, config, multicast_scouting, (tls_ca, tls_certificate, tls_private_key))
    identity = app_identity(app) if app is not None else None
    conf = zenoh_config(
        cfg,
        mode=mode,
        connect=connect,
        listen=listen,
        multicast_scouting=multicast_scouting,
        identity=identity,
    )
    session = _open_session(conf, cfg, connect)
    try:
        return FusedSubscriber(session, keys.fused_skeletons(cfg.name), queue_frames)
    except BaseException:
        close_session(session, what="the subscriber's zenoh session")
        raise


def _rig_config(
    rig: str | None,
    config: str | os.PathLike[str] | RigConfig | None,
    multicast_scouting: bool | None,
    tls_files: tuple[str | os.PathLike[str] | None, ...],
) -> RigConfig:
    """The rig config to subscribe with: the given one (its name checked against ``rig``), or a bare one."""
    if config is not None:
        cfg = config if isinstance(config, RigConfig) else load_rig_config(Path(config))
        if rig is not None and _rig_name(rig) != cfg.name:
            raise ConfigError(f"rig {rig!r} but {cfg.source} is rig {cfg.name!r}; give one of them")
        if any(f is not None for f in tls_files):
            raise ConfigError(f"TLS files come from {cfg.source}'s [zenoh.tls]; give app=NAME for its directory")
        return cfg
    if rig is None:
        raise ConfigError("say which rig to subscribe to: subscribe('NAME') (its [rig] name) or config='RIG.toml'")
    ca, certificate, private_key = (Path(f) if f is not None else None for f in tls_files)
    tls = None
    if ca is not None or certificate is not None:
        if ca is None or (certificate is None) != (private_key is None):
            raise ConfigError("TLS needs tls_ca, and tls_certificate with tls_private_key for mutual TLS")
        tls = ZenohTls(ca=ca, certificate=certificate, private_key=private_key, mutual=certificate is not None)
    zenoh_section = ZenohSection(multicast_scouting=True if multicast_scouting is None else multicast_scouting, tls=tls)
    return RigConfig(name=_rig_name(rig), sensors=(), zenoh=zenoh_section, source="subscribe()")


def _rig_name(rig: str) -> str:
    """``rig`` checked as a zenoh key chunk; a bad one is the caller's configuration error."""
    try:
        return keys.validate_name(rig, "rig")
    except (TypeError, ValueError) as exc:
        raise ConfigError(str(exc)) from None


def _open_session(conf: zenoh.Config, cfg: RigConfig, connect: Sequence[str] | None) -> zenoh.Session:
    """``zenoh.open``, its failure raised as a ServiceError that names where it tried to connect."""
    import zenoh

    try:
        return zenoh.open(conf)
    except Exception as exc:  # zenoh raises its own ZError
        endpoints = ", ".join(connect if connect is not None else cfg.zenoh.connect) or "no connect endpoints"
        raise ServiceError(f"zenoh could not open a session ({endpoints}): {exc}") from None
