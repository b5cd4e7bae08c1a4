"""``skelfuse router``: zenoh's router, run from the Python package (``zenohd`` is not packaged here).

A rig spread over several PCs runs one router, on the fusion PC or its own; capture PCs, the fusion node and
apps connect to it in client mode (``[zenoh] mode = "client"``, ``connect = ["tls/ROUTER:7447"]``). With
``[zenoh.tls]`` the router requires mutual TLS (a certificate of the rig's CA), and with
``[zenoh] access_control = true`` it enforces the access control generated from the rig
(:mod:`skelfuse.config.access`). Cycle::

    conf = zenoh_config(cfg, mode="router", identity="router", ...)   # listen endpoints: [zenoh] listen
    session = zenoh.open(conf)                                       # retried with backoff
    wait for SIGINT / SIGTERM (or --duration); close

zenoh keeps its decisions to itself: refused TLS handshakes and access-control denials reach no Python API.
They are written to the router's log when ``RUST_LOG`` asks for them (``docs/multi-pc.md``, "Refusals").
"""

from __future__ import annotations

import logging
import os
import time
from typing import TYPE_CHECKING

from skelfuse.service.lifecycle import Lifecycle, RunLimits
from skelfuse.service.zenoh_io import open_session

if TYPE_CHECKING:  # pragma: no cover - typing only
    import zenoh

log = logging.getLogger("skelfuse.service.router")

DEFAULT_RUST_LOG = "warn"
"""zenoh's own log filter when ``RUST_LOG`` is unset: warnings (refused links among them) on stderr."""


def run_router(conf: zenoh.Config, *, lifecycle: Lifecycle, limits: RunLimits | None = None) -> int:
    """Serve as the rig's zenoh router until asked to stop; returns 0."""
    import zenoh

    zenoh.init_log_from_env_or(os.environ.get("RUST_LOG", DEFAULT_RUST_LOG))
    limits = limits or RunLimits()
    with lifecycle.capture_signals():
        session = open_session(
            conf, lifecycle=lifecycle, what="router", deadline=limits.deadline(time.monotonic())
        )  # a listen port in use is retried until --duration at most
        if session is None:
            return 0
        try:
            info = session.info
            log.info("zenoh router %s up: %s", info.zid(), conf.get_json("listen/endpoints"))
            start = time.monotonic()
            deadline = limits.deadline(start)
            while not lifecycle.should_exit and time.monotonic() < deadline:
                lifecycle.wait(min(0.5, max(deadline - time.monotonic(), 0.0)))
        finally:
            lifecycle.request_exit()  # the stop begins (bounded by the stop watchdog)
            session.close()
    log.info("zenoh router stopped")
    return 0
