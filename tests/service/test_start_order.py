"""Kinect start order across worker processes: subordinate camera tokens and the master's wait (zenoh loopback)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
import zenoh

from skelfuse.service.worker import camera_node, wait_for_subordinates
from skelfuse.service.zenoh_io import free_port, loopback_config, wait_for_port
from skelfuse.wire import keys
from waiting import SCHEDULING_ALLOWANCE_S, wait_until

pytestmark = pytest.mark.live

RIG = "order"


@pytest.fixture
def peers() -> Iterator[tuple[Any, Any]]:
    """Two peers on loopback: ``a`` listens on a free port, ``b`` connects to it (multicast scouting off)."""
    port = free_port()
    a = zenoh.open(loopback_config(listen_port=port))
    assert wait_for_port(port, timeout_s=5.0)
    b = zenoh.open(loopback_config(connect_ports=[port]))
    try:
        # wait until the link is up: a token of b is seen by a
        probe = b.liveliness().declare_token(keys.alive(RIG, "probe"))
        wait_until(
            lambda: any(r.ok is not None for r in a.liveliness().get(keys.alive(RIG, "probe"), timeout=0.5)),
            "the two loopback peers to connect",
        )
        probe.undeclare()
        yield a, b
    finally:
        b.close()
        a.close()


class SubscribeWatcher:
    """A session whose liveliness subscriptions set ``subscribed``: the wait has started listening."""

    def __init__(self, session: Any) -> None:
        self.session = session
        self.subscribed = threading.Event()

    def liveliness(self) -> Any:
        liveliness, subscribed = self.session.liveliness(), self.subscribed

        class Watched:
            def declare_subscriber(self, *args: Any, **kwargs: Any) -> Any:
                subscriber = liveliness.declare_subscriber(*args, **kwargs)
                subscribed.set()
                return subscriber

        return Watched()


def test_returns_at_once_when_every_token_exists(peers: tuple[Any, Any]) -> None:
    master, other = peers
    tokens = [other.liveliness().declare_token(keys.alive(RIG, camera_node(s))) for s in ("s1", "s2")]
    try:
        start = time.monotonic()
        assert wait_for_subordinates(master, RIG, ["s1", "s2"], timeout_s=60.0) == []
        assert time.monotonic() - start < SCHEDULING_ALLOWANCE_S  # not the 60 s timeout
    finally:
        for token in tokens:
            token.undeclare()


def test_returns_as_soon_as_the_last_token_appears(peers: tuple[Any, Any]) -> None:
    master, other = peers
    first = other.liveliness().declare_token(keys.alive(RIG, camera_node("s1")))
    watched = SubscribeWatcher(master)
    declaring_at: list[float] = []
    late: list[Any] = []

    def declare_once_listening() -> None:
        if watched.subscribed.wait(60.0):
            declaring_at.append(time.monotonic())
            late.append(other.liveliness().declare_token(keys.alive(RIG, camera_node("s2"))))

    thread = threading.Thread(target=declare_once_listening)
    thread.start()
    try:
        poll_s, timeout_s = 0.1, 60.0
        assert wait_for_subordinates(watched, RIG, ["s1", "s2"], timeout_s=timeout_s, poll_s=poll_s) == []
        returned = time.monotonic()
        assert declaring_at, "the wait returned before the last token was declared"
        assert returned - declaring_at[0] < poll_s + SCHEDULING_ALLOWANCE_S  # on its arrival, not the timeout
    finally:
        thread.join(60.0)
        first.undeclare()
        for token in late:
            token.undeclare()


def test_times_out_naming_the_missing(peers: tuple[Any, Any], caplog: pytest.LogCaptureFixture) -> None:
    master, other = peers
    token = other.liveliness().declare_token(keys.alive(RIG, camera_node("s1")))
    other_node = other.liveliness().declare_token(keys.alive(RIG, "capture-s2"))  # not a camera token
    try:
        timeout_s, poll_s = 0.6, 0.1
        start = time.monotonic()
        with caplog.at_level("INFO", logger="skelfuse.service.worker"):
            missing = wait_for_subordinates(
                master, RIG, ["s1", "s2", "s3"], timeout_s=timeout_s, poll_s=poll_s, log_every_s=0.2
            )
        elapsed = time.monotonic() - start
        assert missing == ["s2", "s3"]
        assert timeout_s <= elapsed < timeout_s + poll_s + SCHEDULING_ALLOWANCE_S
        assert "s2, s3" in caplog.text
    finally:
        token.undeclare()
        other_node.undeclare()


def test_should_exit_stops_the_wait_promptly(peers: tuple[Any, Any]) -> None:
    master, _ = peers
    poll_s, stopped_at = 0.05, []
    stop = threading.Event()

    def stop_now() -> None:
        stopped_at.append(time.monotonic())
        stop.set()

    threading.Timer(0.2, stop_now).start()
    missing = wait_for_subordinates(master, RIG, ["s1"], timeout_s=60.0, should_exit=stop.is_set, poll_s=poll_s)
    assert missing == ["s1"]
    assert time.monotonic() - stopped_at[0] < poll_s + SCHEDULING_ALLOWANCE_S  # within a poll, not at the timeout


def test_no_subordinates_means_no_wait(peers: tuple[Any, Any]) -> None:
    assert wait_for_subordinates(peers[0], RIG, [], timeout_s=30.0) == []
