"""Refusals counted from zenoh's own log: the only place zenoh reports them.

zenoh (1.10, the Python package) has no API for what its router refuses: no callback, no counter, and its admin
space has no statistics in this build (``@/<zid>/router?_stats=true`` answers without ``stats``). It writes its
decisions to its log, which the Rust side prints to the process's standard output (``zenoh.init_log_from_env_or``;
this version has no bridge to Python's ``logging``). Measured on this version with the rig's generated access
control and mutual TLS (``tests/unit/test_router_refusals.py``):

* a client certificate from another CA: ``WARN zenoh_link_tls::unicast: invalid peer certificate: BadSignature``
  on every connection attempt (a bare TCP connection that never speaks TLS, e.g. a port probe: ``tls handshake
  eof``); a client without any certificate (that trusts the rig's CA): ``peer sent no certificates``. All are
  counted under ``refused_tls``, by reason. (A certificate-less client that fails on its own side first, e.g.
  on name verification of the router's certificate, never gets asked for its certificate; then the router logs
  ``received fatal alert: BadCertificate`` instead.)
* a message the access control refuses: at TRACE level of ``zenoh::net::routing::interceptor::access_control``
  only. On a key the sender declared (a publisher), one line per message: ``Using cached result: <zid> is
  unauthorized to Put (ingress) on <key>``. On an undeclared key (``session.put(key, ...)``), one line per ACL
  subject the sender's link matches, ``<zid> on <subject> is unauthorized to Put (ingress) on <key>``; an
  allowed message logs ``is authorized`` for the subject that allowed it (and ``unauthorized`` for the
  subjects tried before it, in an order that varies per link). When a key is declared, zenoh fills its
  permission cache and logs every action for every subject (``caching permissions for `<key>` ...`` and the
  lines after it): hypothetical decisions, no message refused.

:class:`RefusalCounter` turns those lines into counts (pure, fed line by line). Cached decisions count one
message each. Per-subject lines: an action on a key that was authorized even once for that peer is never
counted (its ``unauthorized`` lines are the other subjects tried first); for the others, lines divided by the
subjects the peer matches (2 for a rig identity, which matches the catch-all ``rig`` subject and its own; 1 for
another certificate of the rig's CA) are refused messages. The cache-filling block is skipped.
:class:`ZenohLogTap` routes this process's standard output through a pipe so the counter sees zenoh's lines,
forwards every line it does not consume to where standard output went before, and never blocks zenoh: the
pipe's write end is non-blocking, so a line that does not fit while the reader is behind is lost (counts are
then a lower bound) instead of stalling the routing threads.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import re
import sys
import threading
from collections import Counter
from collections.abc import Collection
from typing import Any

log = logging.getLogger("skelfuse.service.router")

ACL_TARGET = "zenoh::net::routing::interceptor::access_control"
"""zenoh's log target whose TRACE lines carry the access-control decisions."""
TLS_TARGET = "zenoh_link_tls::unicast"
"""zenoh's log target whose WARN lines carry refused TLS connections."""
MAX_KINDS = 256
"""Distinct (peer, action, key) kinds tracked; further kinds share one bucket (keys are chosen by peers)."""
OTHER_KINDS = "(other keys)"

_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_DECISION = re.compile(
    r": (?P<zid>[0-9a-f]+) on (?P<subject>\S+) is (?P<verdict>authorized|unauthorized) to (?P<action>.+?) on "
    r"(?P<key>\S+)\s*$"
)
_CACHED = re.compile(
    r"Using cached result: (?P<zid>[0-9a-f]+) is (?P<verdict>authorized|unauthorized) to (?P<action>.+?) on "
    r"(?P<key>\S+)\s*$"
)
_THREAD = re.compile(r"ThreadId\((\d+)\)")
LAST_CACHED_ACTION = "Declare Liveliness Subscriber"
"""The last action zenoh evaluates when it fills its permission cache for a declared key."""
_COMMON_NAME = re.compile(r"CertCommonName\((?P<cn>[^)]*)\)")
_TLS_REFUSED = re.compile(TLS_TARGET + r": (?P<reason>.+?)(?:\. Hint:.*)?\s*$")


def log_filter(rust_log: str | None) -> str:
    """The zenoh log filter that lets :class:`RefusalCounter` see the access-control decisions.

    ``rust_log`` (the operator's ``RUST_LOG``, default ``warn``) keeps deciding every other target.
    """
    return f"{rust_log or 'warn'},{ACL_TARGET}=trace"


class RefusalCounter:
    """Counts refused TLS connections and refused messages from zenoh's log lines (pure; see the module).

    Parameters
    ----------
    rig_common_names : collection of str
        Certificate common names that have their own ACL subject (the rig's identities): their links match two
        subjects, so each refused message logs two lines.
    """

    def __init__(self, rig_common_names: Collection[str] = ()) -> None:
        self.rig_common_names = frozenset(rig_common_names)
        self.tls_refused: Counter[str] = Counter()
        self._unauthorized: Counter[tuple[str, str, str]] = Counter()  # (zid, action, key) -> per-subject lines
        self._authorized: set[tuple[str, str, str]] = set()  # (zid, action, key) allowed at least once
        self._cached_refused: Counter[tuple[str, str, str]] = Counter()  # (zid, action, key) -> messages
        self._names: dict[str, str] = {}  # zid -> certificate common name
        self._caching: dict[str, str] = {}  # thread -> "in" / "last" while zenoh fills its permission cache
        self._lock = threading.Lock()

    def feed(self, line: str) -> str | None:
        """Read one log line; returns "denied" or "acl" (an access-control line, consumed), "tls" (a TLS
        refusal) or None (not zenoh's refusal business)."""
        if ACL_TARGET in line:
            with self._lock:
                return self._feed_acl(_ANSI.sub("", line))
        if TLS_TARGET in line:
            line = _ANSI.sub("", line)
            tls = _TLS_REFUSED.search(line) if " WARN " in line else None
            if tls is not None:
                with self._lock:
                    self.tls_refused[tls["reason"]] += 1
                return "tls"
        return None

    def _feed_acl(self, line: str) -> str:
        thread_match = _THREAD.search(line)
        thread = thread_match[1] if thread_match else ""
        if "caching permissions for" in line:
            # zenoh evaluates every action for a newly declared key and logs each, allowed or not: no message
            # was refused there. The block ends after its last action (Declare Liveliness Subscriber).
            self._caching[thread] = "in"
            return "acl"
        cached = _CACHED.search(line)
        if cached is not None:  # one line per message on a declared key: the final decision
            if cached["verdict"] == "authorized":
                return "acl"
            self._count(self._cached_refused, (cached["zid"], cached["action"], cached["key"]))
            return "denied"
        decision = _DECISION.search(line)
        if decision is None:
            return "acl"
        zid, action, key = decision["zid"], decision["action"], decision["key"]
        cn = _COMMON_NAME.search(decision["subject"])
        if cn is not None and (zid in self._names or len(self._names) < MAX_KINDS * 16):
            self._names[zid] = cn["cn"]
        state = self._caching.get(thread)
        if state is not None:
            if action.startswith(LAST_CACHED_ACTION):
                self._caching[thread] = "last"
                return "acl"
            if state == "in":
                return "acl"
            del self._caching[thread]  # the block ended: this line is a real decision
        if decision["verdict"] == "authorized":
            if len(self._authorized) < MAX_KINDS * 16:
                self._authorized.add((zid, action, key))
            return "acl"
        self._count(self._unauthorized, (zid, action, key))
        return "denied"

    @staticmethod
    def _count(counter: Counter[tuple[str, str, str]], kind: tuple[str, str, str]) -> None:
        if kind not in counter and len(counter) >= MAX_KINDS:
            kind = ("", "", OTHER_KINDS)  # bounded whatever keys and ids peers send
        counter[kind] += 1

    def refused_messages(self) -> dict[tuple[str, str, str], int]:
        """(who, action, key) -> messages refused (who: the certificate's common name, else the zenoh id)."""
        with self._lock:
            out: Counter[tuple[str, str, str]] = Counter()
            for (zid, action, key), n in self._cached_refused.items():
                out[(self._names.get(zid, zid or OTHER_KINDS), action, key)] += n
            for (zid, action, key), lines in self._unauthorized.items():
                if (zid, action, key) in self._authorized:
                    continue  # allowed messages: these lines are the subjects tried before the one that allowed
                who = self._names.get(zid, zid or OTHER_KINDS)
                subjects = 2 if who in self.rig_common_names else 1
                out[(who, action, key)] += max(lines // subjects, 1)
            return dict(out)

    def counters(self) -> dict[str, int]:
        """``refused_tls`` (connections), ``refused_messages`` (access control), for a status document."""
        with self._lock:
            tls = sum(self.tls_refused.values())
        return {"refused_tls": tls, "refused_messages": sum(self.refused_messages().values())}

    def info(self) -> dict[str, Any]:
        """Who was refused what: the TLS reasons, and the refused messages per peer, action and key (top 20)."""
        refused = sorted(self.refused_messages().items(), key=lambda item: -item[1])[:20]
        with self._lock:
            tls = dict(self.tls_refused)
        return {
            "tls_refused": tls,
            "refused": [{"who": who, "action": action, "key": key, "messages": n} for (who, action, key), n in refused],
        }


class ZenohLogTap:
    """Routes this process's standard output (where zenoh logs) through ``counter``; see the module docstring.

    Use as a context manager around the zenoh session. Lines the counter consumes (access-control decisions) are
    not forwarded: at TRACE level every message of the rig logs one. :meth:`log_refusals` writes the refusals
    through Python's logging instead, so they still reach the journal.
    """

    def __init__(self, counter: RefusalCounter, *, pipe_bytes: int = 1 << 20) -> None:
        self.counter = counter
        self.pipe_bytes = pipe_bytes
        self._saved: int | None = None
        self._reader: threading.Thread | None = None
        self._logged: Counter[tuple[str, str, str]] = Counter()

    def __enter__(self) -> ZenohLogTap:
        with contextlib.suppress(Exception):
            sys.stdout.flush()  # what Python wrote so far goes where it was meant to
        read_end, write_end = os.pipe()
        with contextlib.suppress(OSError):  # Linux: room for bursts while the reader is behind
            fcntl.fcntl(write_end, fcntl.F_SETPIPE_SZ, self.pipe_bytes)
        os.set_blocking(write_end, False)  # never stall zenoh's threads on a full pipe: drop the line instead
        self._saved = os.dup(1)
        os.dup2(write_end, 1)
        os.close(write_end)
        self._reader = threading.Thread(target=self._read, args=(read_end,), name="zenoh-log-tap", daemon=True)
        self._reader.start()
        return self

    def __exit__(self, *exc: object) -> None:
        saved = self._saved
        if saved is None:
            return
        os.dup2(saved, 1)  # closes the pipe's last write end: the reader sees the end and stops
        if self._reader is not None:
            self._reader.join(5.0)
        os.close(saved)
        self._saved = None

    def _read(self, read_end: int) -> None:
        pending = b""
        with os.fdopen(read_end, "rb", buffering=0) as pipe:
            while chunk := pipe.read(65536):
                pending += chunk
                *lines, pending = pending.split(b"\n")
                self._handle(lines)
            if pending:
                self._handle([pending])

    def _handle(self, lines: list[bytes]) -> None:
        forward = []
        for raw in lines:
            text = raw.decode("utf-8", "replace")
            if self.counter.feed(text) in ("denied", "acl"):
                continue
            forward.append(raw + b"\n")
        if forward and self._saved is not None:
            with contextlib.suppress(OSError):
                os.write(self._saved, b"".join(forward))

    def log_refusals(self) -> None:
        """Log each peer's first refused message per action and key, then every 1000th (call it periodically:
        the router does, once per status period, so a flood costs one line a period)."""
        for (who, action, key), n in self.counter.refused_messages().items():
            seen = self._logged[(who, action, key)]
            if n > seen and (seen == 0 or n // 1000 > seen // 1000):
                log.warning(
                    "router: refused %s from %s on %s (%d so far)",
                    action,
                    who,
                    key,
                    n,
                    extra={"who": who, "key": key, "refused": n},
                )
                self._logged[(who, action, key)] = n
