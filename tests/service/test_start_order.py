"""Kinect start order across worker processes: subordinate camera tokens and the master's wait (zenoh loopback)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest

from skelfuse.service.worker import camera_node, wait_for_subordinates
from skelfuse.service.zenoh_io import free_port, loopback_config, wait_for_port
from skelfuse.wire import keys

pytestmark = pytest.mark.live

zenoh = pytest.importorskip("zenoh")

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
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            replies = list(a.liveliness().get(keys.alive(RIG, "probe"), timeout=0.5))
            if any(r.ok is not None for r in replies):
                break
        else:  # pragma: no cover - environment problem
            pytest.fail("the two loopback peers never connected")
        probe.undeclare()
        yield a, b
    finally:
        b.close()
        a.close()


def test_returns_at_once_when_every_token_exists(peers: tuple[Any, Any]) -> None:
    master, other = peers
    tokens = [other.liveliness().declare_token(keys.alive(RIG, camera_node(s))) for s in ("s1", "s2")]
    try:
        start = time.monotonic()
        assert wait_for_subordinates(master, RIG, ["s1", "s2"], timeout_s=2.5) == []
        assert time.monotonic() - start < 1.0
    finally:
        for token in tokens:
            token.undeclare()


def test_returns_as_soon_as_the_last_token_appears(peers: tuple[Any, Any]) -> None:
    master, other = peers
    first = other.liveliness().declare_token(keys.alive(RIG, camera_node("s1")))
    late: list[Any] = []

    def declare_later() -> None:
        time.sleep(0.3)
        late.append(other.liveliness().declare_token(keys.alive(RIG, camera_node("s2"))))

    thread = threading.Thread(target=declare_later)
    start = time.monotonic()
    thread.start()
    try:
        assert wait_for_subordinates(master, RIG, ["s1", "s2"], timeout_s=2.5) == []
        elapsed = time.monotonic() - start
        assert 0.25 <= elapsed < 1.5
    finally:
        thread.join(2.0)
        first.undeclare()
        for token in late:
            token.undeclare()


def test_times_out_naming_the_missing(peers: tuple[Any, Any], caplog: pytest.LogCaptureFixture) -> None:
    master, other = peers
    token = other.liveliness().declare_token(keys.alive(RIG, camera_node("s1")))
    other_node = other.liveliness().declare_token(keys.alive(RIG, "capture-s2"))  # not a camera token
    try:
        start = time.monotonic()
        with caplog.at_level("INFO", logger="skelfuse.service.worker"):
            missing = wait_for_subordinates(master, RIG, ["s1", "s2", "s3"], timeout_s=0.6, log_every_s=0.2)
        elapsed = time.monotonic() - start
        assert missing == ["s2", "s3"]
        assert 0.55 <= elapsed < 1.5
        assert "s2, s3" in caplog.text
    finally:
        token.undeclare()
        other_node.undeclare()


def test_should_exit_stops_the_wait_promptly(peers: tuple[Any, Any]) -> None:
    master, _ = peers
    stop = threading.Event()
    threading.Timer(0.2, stop.set).start()
    start = time.monotonic()
    missing = wait_for_subordinates(master, RIG, ["s1"], timeout_s=30.0, should_exit=stop.is_set, poll_s=0.05)
    assert missing == ["s1"]
    assert time.monotonic() - start < 1.0


def test_no_subordinates_means_no_wait(peers: tuple[Any, Any]) -> None:
    assert wait_for_subordinates(peers[0], RIG, [], timeout_s=30.0) == []
