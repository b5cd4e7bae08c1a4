"""The fused publisher's congestion control, with real zenoh processes: a subscriber whose link fills.

The publisher is the fusion node's own (:class:`~skelfuse.service.zenoh_io.FusedPublisher`) on a session that
the rig config builds (:func:`skelfuse.config.zenoh_config`, so ``[zenoh]``'s keys and defaults are what is
tested); the subscriber, ``stoppable_subscriber.py``, runs in its own process and reaches the publisher only
through ``stall_relay.py``, a TCP relay that stops reading the publisher's side on command. The publisher puts
fused-frame-sized payloads (17.4 KB: eight people) at 30 Hz; the relay stops reading for 2 s (less than
zenoh's 10 s lease, which would close the link), or 200 ms of every 600 ms (an app starved of CPU). With small
socket buffers (zenoh ``so_sndbuf``, the relay's ``SO_RCVBUF``) and without zenoh's shared memory (which would
carry the payloads between two processes of one host beside the link) every stop fills the link within a few
frames.

zenoh's drop path (io/zenoh-transport/src/common/pipeline.rs): a droppable message waits up to
``wait_before_drop`` for a free batch; when none came, the link's queue at that priority is marked congested
and later messages drop at once until the link takes a batch again. So a stop of 2 s holds one put for the
bound and drops most frames of the stop; a starved subscriber (stops shorter than the bound) loses nothing with
the default bound and loses frames with zenoh's own 1 ms (the soak-marked contrast that gives the default's
test its meaning).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path
from typing import Any

import pytest
from stall_relay import StallRelay
from stoppable_subscriber import END

from skelfuse.apps.demo import sim_sensor_tables
from skelfuse.config import parse_rig_config, zenoh_config
from skelfuse.service.zenoh_io import FusedPublisher, free_port
from skelfuse.wire import keys
from waiting import wait_for_subscriber, wait_until

pytestmark = pytest.mark.live

SUBSCRIBER = Path(__file__).with_name("stoppable_subscriber.py")
SMALL_BUFFER = 2048  # bytes; Linux doubles it and keeps a floor of a few KB
FRAME_BYTES = 17_400  # a fused frame of eight people (four: 8.7 KB, measured)
NO_SHARED_MEMORY = ("transport/shared_memory/enabled:false",)
"""Between processes on one host zenoh carries payloads over a few KB in shared memory once both sides have
mapped it, and the TCP link then carries only references of a few dozen bytes, which no stop fills; a
subscriber on another PC gets every byte over the link, as here."""
STOPPED_PUTS = 60  # 2 s at 30 Hz, less than zenoh's 10 s lease
STARVED_PUTS = 90  # 3 s


def run_subscriber(
    tmp_path: Path, zenoh_lines: list[str], puts: int, stops: list[tuple[float, float]], raw: tuple[str, ...] = ()
) -> tuple[list[int], dict[str, Any]]:
    """Put ``puts`` payloads at 30 Hz; the relay stops reading for each (from s, for s) of ``stops``, by a
    thread of its own (a put held by the full link must not delay the resume); then it reads.

    Returns the put numbers it received and the publisher's report.
    """
    import zenoh

    cfg = parse_rig_config(
        tomllib.loads("\n".join(['[rig]\nname = "cc"\n[zenoh]', *zenoh_lines, *sim_sensor_tables(1)]))
    )
    port = free_port()
    conf = zenoh_config(
        cfg,
        [f"transport/link/tcp/so_sndbuf:{SMALL_BUFFER}", *NO_SHARED_MEMORY, *raw],
        mode="peer",
        listen=[f"tcp/127.0.0.1:{port}"],
        multicast_scouting=False,
    )
    key = keys.fused_skeletons("cc")
    out = tmp_path / "received.json"
    session = zenoh.open(conf)
    subscriber = None
    relay: StallRelay | None = None
    try:
        z = cfg.zenoh
        publisher = FusedPublisher(
            session,
            key,
            congestion_control=z.fused_congestion_control,
            bound_ms=z.wait_before_drop_ms if z.fused_congestion_control == "drop" else z.wait_before_close_ms,
        )
        relay = StallRelay(port)
        subscriber = subprocess.Popen(
            [sys.executable, str(SUBSCRIBER), key, str(relay.port), str(out), str(SMALL_BUFFER)],
            stdout=subprocess.PIPE,
            start_new_session=True,
        )
        assert subscriber.stdout is not None and subscriber.stdout.readline().strip() == b"subscribed"
        subscriber.stdout.close()
        wait_for_subscriber(publisher._publisher, "the stoppable subscriber")
        start = time.monotonic()

        def stop_and_continue() -> None:
            for at_s, for_s in stops:
                time.sleep(max(0.0, start + at_s - time.monotonic()))
                relay.pause()
                time.sleep(max(0.0, start + at_s + for_s - time.monotonic()))
                relay.resume()

        stopper = threading.Thread(target=stop_and_continue, daemon=True)
        stopper.start()
        for k in range(puts):
            delay = start + k / 30.0 - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            publisher.put(k.to_bytes(8, "little") + bytes(FRAME_BYTES - 8))
        stopper.join(30)
        relay.resume()

        def read_to_the_end() -> bool:  # the end marker, after every frame: put again until one gets through
            publisher._publisher.put(END)  # not through FusedPublisher: its report counts the frames only
            return subscriber.poll() is not None

        wait_until(read_to_the_end, "the subscriber to read everything up to the end marker and exit")
        subscriber = None
        return json.loads(out.read_text()), publisher.report()
    finally:
        if subscriber is not None:
            os.killpg(subscriber.pid, signal.SIGKILL)
            subscriber.wait(5)
        if relay is not None:
            relay.close()
        session.close()


STARVED = [(0.6 * i, 0.2) for i in range(5)]
"""Stopped 200 ms of every 600 ms (a subscriber starved of CPU), less than the default 250 ms bound."""


def test_a_stopped_subscriber_holds_the_publisher_once_for_at_most_the_bound(tmp_path: Path) -> None:
    """Not read for 2 s: one put waits the bound, later ones drop at once; once it is read again, frames flow."""
    received, report = run_subscriber(tmp_path, [], STOPPED_PUTS + 45, [(0.0, STOPPED_PUTS / 30.0)])
    assert report["congestion_control"] == "drop" and report["bound_ms"] == 250
    assert report["reached_bound"] >= 1, f"the stop never congested the link: {report}"
    # The caller (the node's loop) is held about the bound once, not for the stop: a put that blocked until
    # the link drained would be held the whole stop, so the line between the two lies halfway between the
    # bound and the stop's length (scheduling on a loaded machine only lengthens one wait, by far less).
    # And not again and again: while the link stays full, frames drop without waiting.
    stop_ms = 1000.0 * STOPPED_PUTS / 30.0
    assert report["held_max_ms"] < report["bound_ms"] + (stop_ms - report["bound_ms"]) / 2, report
    assert report["reached_bound"] <= 3, report
    lost_while_stopped = STOPPED_PUTS - len([k for k in received if k < STOPPED_PUTS])
    assert lost_while_stopped > 0
    after = [k for k in received if k >= STOPPED_PUTS + 15]  # half a second after it reads again
    assert after == list(range(STOPPED_PUTS + 15, STOPPED_PUTS + 45)), f"the link did not recover: {after}"
    print(f"stopped 2 s: lost {lost_while_stopped} of {STOPPED_PUTS} while stopped; {report}")


def test_with_the_default_wait_a_starved_subscriber_loses_no_fused_frame(tmp_path: Path) -> None:
    """Stopped 200 ms of every 600 ms (starved of CPU): with the 250 ms bound it loses nothing."""
    received, report = run_subscriber(tmp_path, [], STARVED_PUTS, STARVED)
    assert report["bound_ms"] == 250 and report["reached_bound"] == 0, report
    assert report["held_over_10ms"] > 0, f"the starvation never filled the link: {report}"
    assert sorted(received) == list(range(STARVED_PUTS)), f"lost {STARVED_PUTS - len(set(received))}: {report}"
    print(f"starved, default wait: received {len(received)} of {STARVED_PUTS}; {report}")


@pytest.mark.soak
def test_with_zenohs_own_1ms_wait_the_same_starvation_loses_frames(tmp_path: Path) -> None:
    """What the bound is for: zenoh's default wait drops frames of a subscriber that is only starved."""
    received, report = run_subscriber(tmp_path, ["wait_before_drop_ms = 1"], STARVED_PUTS, STARVED)
    assert report["bound_ms"] == 1
    lost = STARVED_PUTS - len(set(received))
    assert lost > 0, f"nothing lost with a 1 ms wait: this setup did not congest the link ({report})"
    print(f"1 ms wait: the starved subscriber lost {lost} of {STARVED_PUTS}; {report}")
