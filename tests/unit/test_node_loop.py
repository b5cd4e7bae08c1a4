"""The fusion node's loop with a backlog: it publishes as it fuses and sees a stop at once.

Measured before the fix: a node that fell behind on a starved machine emptied its whole intake queue before
publishing anything or looking at the stop flag, so under load it published in bursts and overran the stop
watchdog on SIGTERM (exit status 4 after 15 s while still fusing the backlog).
"""

from __future__ import annotations

import dataclasses
import itertools
import time
from pathlib import Path
from typing import Any

import pytest
from numba.core import event

from fake_zenoh import FakeSample
from skelfuse.config import RigConfig, load_rig_config
from skelfuse.service.node import FusionNode, NodeOptions
from skelfuse.service.worker import SimSource
from skelfuse.service.zenoh_io import SampleQueue
from skelfuse.wire.codec import decode_fused_frame, encode_sensor_frame
from waiting import DEFAULT_TIMEOUT_S

RIG_SIM_4 = Path(__file__).resolve().parents[2] / "config" / "rig-sim-4.toml"
INSTANTS = 60


class _Publisher:
    """Records what the node puts; ``on_put`` runs after each put (the test's hook)."""

    def __init__(self, on_put: Any = None) -> None:
        self.payloads: list[bytes] = []
        self.on_put = on_put

    def put(self, payload: bytes) -> None:
        self.payloads.append(payload)
        if self.on_put is not None:
            self.on_put(self)


@pytest.fixture(scope="module")
def rig() -> RigConfig:
    return load_rig_config(RIG_SIM_4)


@pytest.fixture(scope="module")
def payloads(rig: RigConfig) -> list[tuple[str, bytes]]:
    """INSTANTS instants of four simulated sensors, as (key, payload) in arrival order."""
    sources = {sid: SimSource(rig, sid, take_duration_s=4.0) for sid in rig.sensor_ids}
    return [
        (f"skelfuse/{rig.name}/sensors/{sid}/skeletons", encode_sensor_frame(source.frame_at(n)))
        for n in range(INSTANTS)
        for sid, source in sources.items()
    ]


def _backlog(rig: RigConfig, payloads: list[tuple[str, bytes]]) -> tuple[FusionNode, SampleQueue]:
    """A node whose intake queue already holds every payload (a node that fell behind). Its lag bound is above any
    backlog: these tests are about the loop's order and stop; shedding is tests/unit/test_node_shedding.py's."""
    rig = dataclasses.replace(rig, node=dataclasses.replace(rig.node, max_lag_s=3600.0))
    node = FusionNode(rig, None, options=NodeOptions(status_period_s=3600.0))
    samples = SampleQueue()
    for key, payload in payloads:
        samples(FakeSample(key, payload))
    return node, samples


def test_a_backlog_is_published_instant_by_instant_not_after_the_queue_is_empty(
    rig: RigConfig, payloads: list[tuple[str, bytes]]
) -> None:
    node, samples = _backlog(rig, payloads)
    queued_at_first_put: list[int] = []

    def first_put(publisher: _Publisher) -> None:
        if len(publisher.payloads) == 1:
            queued_at_first_put.append(samples.qsize())
            node.lifecycle.request_exit()

    fused = _Publisher(first_put)
    node._loop(samples, fused, _Publisher(), None)
    # The first fused frame went out while almost the whole backlog still waited, and the stop it asked for
    # ended the loop before the node fused more than the instant in hand.
    assert len(fused.payloads) == 1
    decode_fused_frame(fused.payloads[0])
    assert queued_at_first_put[0] >= 4 * (INSTANTS - 3), queued_at_first_put
    assert samples.qsize() >= 4 * (INSTANTS - 3)


def test_without_a_stop_the_whole_backlog_is_fused(rig: RigConfig, payloads: list[tuple[str, bytes]]) -> None:
    node, samples = _backlog(rig, payloads)
    fused = _Publisher()

    def stop_when_drained(publisher: _Publisher) -> None:
        if samples.qsize() == 0:
            node.lifecycle.request_exit()

    fused.on_put = stop_when_drained
    node._loop(samples, fused, _Publisher(), None)
    # Every instant but the newest (still open, waiting for its deadline) is fused, in time order.
    times = [decode_fused_frame(p).time_us for p in fused.payloads]
    assert len(times) >= INSTANTS - 2 and times == sorted(times)


class _Compiles(event.Listener):
    """Records the functions numba compiles while installed."""

    def __init__(self) -> None:
        self.names: list[str] = []

    def on_start(self, ev: event.Event) -> None:
        self.names.append(ev.data["dispatcher"].py_func.__qualname__)

    def on_end(self, ev: event.Event) -> None:
        pass


def test_a_node_compiles_nothing_once_it_started(rig: RigConfig, payloads: list[tuple[str, bytes]]) -> None:
    # The node prepares its kernels before its first instant; a live call with argument types the preparation
    # did not cover (another array layout, a read-only table) would compile in the loop, for seconds on a first
    # start, with no status meanwhile.
    node, samples = _backlog(rig, payloads)
    fused = _Publisher(lambda publisher: samples.qsize() == 0 and node.lifecycle.request_exit())
    compiles = _Compiles()
    with event.install_listener("numba:compile", compiles):
        node._loop(samples, fused, _Publisher(), None)
    frames = [decode_fused_frame(p) for p in fused.payloads]
    assert len(frames) >= INSTANTS - 2
    assert all(frame.orientations is not None for frame in frames)  # every stage ran, the orientations too
    assert compiles.names == []


def test_a_backlog_that_never_empties_does_not_hold_the_status_back(
    rig: RigConfig, payloads: list[tuple[str, bytes]]
) -> None:
    # With a restarted worker on a loaded machine the node can stay a little behind for seconds, its intake
    # queue never quite empty; the loop must still publish its status on time while it fuses on (the live
    # kill -9 test waits for a status after the restarted sensor's return).
    node = FusionNode(rig, None, options=NodeOptions(status_period_s=0.01))
    samples = SampleQueue()
    feed = itertools.cycle(payloads)
    for key, payload in (next(feed) for _ in range(8)):
        samples(FakeSample(key, payload))
    take, take_now = samples.get, samples.get_nowait
    fused, status = _Publisher(), _Publisher()
    # The loop runs until five statuses are out (the event this test waits for), its deadline far above five
    # periods: how many instants fit in five periods is the node's speed, not the rule under test.
    deadline = time.monotonic() + DEFAULT_TIMEOUT_S

    def arrive() -> None:  # a sample arrives for each one taken: the queue never empties
        key, payload = next(feed)
        samples(FakeSample(key, payload))
        if (len(status.payloads) >= 5 and len(fused.payloads) >= INSTANTS) or time.monotonic() > deadline:
            node.lifecycle.request_exit()

    samples.get = lambda timeout: arrive() or take(timeout)  # type: ignore[method-assign]
    samples.get_nowait = lambda: arrive() or take_now()  # type: ignore[method-assign]
    node._loop(samples, fused, status, None)
    assert samples.qsize() == 8  # it never emptied
    assert len(fused.payloads) >= INSTANTS
    assert len(status.payloads) >= 5, "no status while the queue never emptied"
