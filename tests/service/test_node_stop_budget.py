"""A starved fusion node stops within its drain timeout: the drain leaves the session close its share.

Before: the drain of a backlog could use the whole drain timeout (2 s) and the session close (bounded to 1 s)
came on top: a starved node took 3.9 s once (session 21's node-stop test). Now the stop is one budget
(``service/zenoh_io.py`` ``StopBudget``): the drain stops when only the close's share is left. Here the node
runs in this process on its own zenoh session (closed by the node); each sample's fusion is slowed to 5 ms (a
starved node) and 1000 samples (5 s of work) wait in its queue when the stop comes.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from fake_zenoh import FakeSample
from skelfuse.config import load_rig_config
from skelfuse.service.node import FusionNode, NodeOptions
from skelfuse.service.worker import SimSource
from skelfuse.service.zenoh_io import StopBudget, free_port, loopback_config
from skelfuse.wire.codec import encode_sensor_frame

pytestmark = pytest.mark.live

RIG_SIM_4 = Path(__file__).resolve().parents[2] / "config" / "rig-sim-4.toml"
DRAIN_TIMEOUT_S = 2.0
SLOW_S = 0.005


def test_the_stop_budget_gives_the_close_its_share_of_the_drain_timeout() -> None:
    budget = StopBudget.start(2.0, now=100.0)
    assert (budget.drain_until, budget.end) == (101.0, 102.0)
    assert budget.close_timeout_s(now=101.2) == pytest.approx(0.8)
    assert budget.close_timeout_s(now=103.0) == 0.05  # spent: one short try, then the close is left behind
    short = StopBudget.start(0.4, now=0.0)
    assert short.drain_until == pytest.approx(0.2) and short.close_timeout_s(now=0.0) == pytest.approx(0.4)


def test_a_starved_node_with_a_backlog_stops_within_its_drain_timeout(caplog: pytest.LogCaptureFixture) -> None:
    rig = load_rig_config(RIG_SIM_4)
    sources = {sid: SimSource(rig, sid, take_duration_s=4.0) for sid in rig.sensor_ids}
    backlog = [
        FakeSample(f"skelfuse/{rig.name}/sensors/{sid}/skeletons", encode_sensor_frame(source.frame_at(n)))
        for n in range(250)
        for sid, source in sources.items()
    ]
    node = FusionNode(
        rig,
        loopback_config(listen_port=free_port()),
        options=NodeOptions(status_period_s=3600.0, drain_timeout_s=DRAIN_TIMEOUT_S),
    )
    receive = node.core.receive

    def starved_receive(key: str, payload: bytes, arrival_ns: int, now_ns: int | None = None):  # type: ignore[no-untyped-def]
        time.sleep(SLOW_S)
        return receive(key, payload, arrival_ns, now_ns)

    node.core.receive = starved_receive  # type: ignore[method-assign]
    thread = threading.Thread(target=node.run, daemon=True)
    thread.start()
    assert node.ready.wait(30.0)
    samples = node._samples
    assert samples is not None
    for sample in backlog:  # a few ms: the loop, at 5 ms a sample, takes one or two meanwhile
        samples(sample)
    node.lifecycle.request_exit()
    stop_began = time.monotonic()
    with caplog.at_level("INFO", logger="skelfuse.service"):
        thread.join(DRAIN_TIMEOUT_S + 20.0)
    took_s = time.monotonic() - stop_began
    assert not thread.is_alive()
    assert len(backlog) * SLOW_S >= 2 * DRAIN_TIMEOUT_S  # more work queued than the budget holds
    assert node.core.frames_in >= 50  # it did fuse part of the backlog before it stopped
    assert took_s <= DRAIN_TIMEOUT_S, f"stopped in {took_s:.2f} s"
    assert "queued samples fused in" in caplog.text
