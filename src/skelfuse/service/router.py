"""``skelfuse router``: zenoh's router, run from the Python package (``zenohd`` is not packaged here).

A rig spread over several PCs runs one router, on the fusion PC or its own; capture PCs, the fusion node and
apps connect to it in client mode (``[zenoh] mode = "client"``, ``connect = ["tls/ROUTER:7447"]``). With
``[zenoh.tls]`` the router requires mutual TLS (a certificate of the rig's CA), and with
``[zenoh] access_control = true`` it enforces the access control generated from the rig
(:mod:`skelfuse.config.access`). Cycle::

    conf = zenoh_config(cfg, mode="router", identity="router", ...)   # listen endpoints: [zenoh] listen
    session = zenoh.open(conf)                                       # retried with backoff
    wait for SIGINT / SIGTERM (or --duration); close

zenoh keeps its decisions to itself: refused TLS handshakes and access-control denials reach no Python API, only
its log. With ``rig`` given, the router reads its own zenoh log (:mod:`skelfuse.service.zenoh_log`), counts the
refusals and publishes them in its status on ``skelfuse/<rig>/status/router`` every ``status_period_s``
(``docs/multi-pc.md``, "Refusals").
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Collection
from typing import TYPE_CHECKING, Any

from skelfuse.service.lifecycle import Lifecycle, RunLimits
from skelfuse.service.zenoh_io import close_session, open_session
from skelfuse.service.zenoh_log import RefusalCounter, ZenohLogTap, log_filter
from skelfuse.wire import keys
from skelfuse.wire.codec import NodeStatus, encode_status

if TYPE_CHECKING:  # pragma: no cover - typing only
    import zenoh

log = logging.getLogger("skelfuse.service.router")

ROUTER_NODE = "router"
"""The router's node name in its status key, ``skelfuse/<rig>/status/router``."""
DEFAULT_RUST_LOG = "warn"
"""zenoh's own log filter when ``RUST_LOG`` is unset: warnings (refused links among them) on stderr."""


def run_router(
    conf: zenoh.Config,
    *,
    lifecycle: Lifecycle,
    limits: RunLimits | None = None,
    rig: str | None = None,
    rig_common_names: Collection[str] = (),
    status_period_s: float = 1.0,
) -> int:
    """Serve as the rig's zenoh router until asked to stop; returns 0.

    With ``rig``, count the refusals zenoh logs and publish them in the router's status (see the module).
    ``rig_common_names``: the certificate names that have their own ACL subject (:class:`RefusalCounter`).
    """
    import zenoh

    rust_log = os.environ.get("RUST_LOG", DEFAULT_RUST_LOG)
    limits = limits or RunLimits()
    counter = RefusalCounter(rig_common_names) if rig is not None else None
    tap = ZenohLogTap(counter) if counter is not None else contextlib.nullcontext()
    with lifecycle.capture_signals(), tap:
        if counter is not None:  # zenoh takes RUST_LOG before the level given here
            os.environ["RUST_LOG"] = log_filter(rust_log)
        zenoh.init_log_from_env_or(os.environ.get("RUST_LOG", rust_log))
        session = open_session(
            conf, lifecycle=lifecycle, what="router", deadline=limits.deadline(time.monotonic())
        )  # a listen port in use is retried until --duration at most
        if session is None:
            return 0
        try:
            info = session.info
            log.info("zenoh router %s up: %s", info.zid(), conf.get_json("listen/endpoints"))
            publisher = session.declare_publisher(keys.status(rig, ROUTER_NODE)) if rig is not None else None
            start = time.monotonic()
            deadline = limits.deadline(start)
            next_status = start
            while not lifecycle.should_exit and time.monotonic() < deadline:
                if publisher is not None and counter is not None and time.monotonic() >= next_status:
                    _publish_status(publisher, counter, "running")
                    if isinstance(tap, ZenohLogTap):
                        tap.log_refusals()
                    next_status += status_period_s
                lifecycle.wait(min(0.2, max(deadline - time.monotonic(), 0.0)))
            if publisher is not None and counter is not None:
                _publish_status(publisher, counter, "stopped")
        finally:
            lifecycle.request_exit()  # the stop begins (bounded by the stop watchdog)
            close_session(session, what="router")
    log.info("zenoh router stopped")
    return 0


def _publish_status(publisher: Any, counter: RefusalCounter, state: str) -> None:
    status = NodeStatus(
        node=ROUTER_NODE,
        role="router",
        state=state,
        time_ns=time.time_ns(),
        counters=counter.counters(),
        info=counter.info(),
    )
    try:
        publisher.put(encode_status(status))
    except ValueError:
        log.exception("router: status could not be encoded")
