"""Waiting in tests: until something happens, or fail after a deadline.

A test never sleeps a fixed time and then counts what arrived: under load the count depends on the machine's
speed. It waits for the event it needs (a message, a subscriber, a process's exit) with a deadline long enough
for a starved machine, and the failure says what it waited for. Where a test must show that something did
*not* arrive, it sends a marker after it on the same path and waits for the marker (zenoh keeps the order of
one session's messages on one link), then checks.
"""

from __future__ import annotations

import re
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")

POLL_S = 0.02
# Deadlines are generous: they bound a hang, not the speed of the code (speed lives in `skelfuse bench`).
DEFAULT_TIMEOUT_S = 30.0


def wait_until(
    predicate: Callable[[], T],
    what: str,
    timeout_s: float = DEFAULT_TIMEOUT_S,
    details: Callable[[], str] = str,
) -> T:
    """Polls ``predicate`` until it returns a truthy value, which is returned.

    Raises AssertionError naming ``what`` (and ``details()``, e.g. a process's log) after ``timeout_s``.
    """
    deadline = time.monotonic() + timeout_s
    while True:
        result = predicate()
        if result:
            return result
        if time.monotonic() >= deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}\n{details()}")
        time.sleep(POLL_S)


def wait_for_output(
    log: Path, pattern: str, process: subprocess.Popen[bytes], timeout_s: float = DEFAULT_TIMEOUT_S
) -> re.Match[str]:
    """Waits until ``process``'s output file ``log`` matches ``pattern``; fails at once if the process exits first."""

    def found() -> re.Match[str] | None:
        match = re.search(pattern, log.read_text(errors="replace"))
        assert match or process.poll() is None, (
            f"the process exited ({process.returncode}) before printing {pattern!r}:\n"
            f"{log.read_text(errors='replace')[-3000:]}"
        )
        return match

    return wait_until(found, repr(pattern), timeout_s, lambda: log.read_text(errors="replace")[-3000:])


def wait_for_subscriber(publisher: Any, what: str = "a subscriber", timeout_s: float = DEFAULT_TIMEOUT_S) -> None:
    """Waits until a zenoh ``publisher`` has a matching subscriber, so what it puts next is delivered."""
    wait_until(lambda: publisher.matching_status.matching, f"{what} to match {publisher.key_expr}", timeout_s)


SCHEDULING_ALLOWANCE_S = 5.0
"""How late a starved machine may wake a thread. A bound on a timing the product promises is the configured
value plus this, never more: the promise is checked, the machine's speed is not."""
