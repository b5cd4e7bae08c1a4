"""One tracker per process: each person's virtual-camera tracker in a worker process of its own.

Against the fake libk4a / libk4abt compiled from C: ``FAKE_K4ABT_ONE_TRACKER=1`` makes the fake refuse a second
live tracker in one process (as Body Tracking SDK versions that allow one tracker per process do), so the test
first shows that in-process trackers then track one person only, then that the worker processes track every
person. ``FAKE_K4ABT_ECHO=1`` puts each process's fake tracker in echo mode: its one body's joint 0 is the
centroid of the virtual depth image it was given, lifted with the calibration it was created with, recomputed
here with numpy and mapped to the world through the person's own frontal view. Worker processes are real
(spawned) processes; a dead one is made by SIGKILL, a hung one by the fake's ``FAKE_K4ABT_FAULT=hang``.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from fake_sdk import build_fake_libs_or_skip

from skelfuse.fusion.camera import lift_mask
from skelfuse.fusion.depth.cloud import person_clouds
from skelfuse.fusion.depth.pipeline import fuse_person_depth
from skelfuse.fusion.depth.render import to_k4a_depth
from skelfuse.service.depth_stage import VIRTUAL_INTRINSICS, K4abtDepthTracker
from skelfuse.sim.depth import render_rig
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.motion import facing_deg
from skelfuse.sim.rig import paper_rig
from skelfuse.sources.k4abt import K4A_LIBRARY_ENV, K4ABT_LIBRARY_ENV, TrackerCreateError, TrackerSettings
from waiting import SCHEDULING_ALLOWANCE_S, wait_until

K = VIRTUAL_INTRINSICS
RIG = paper_rig()
POSES = np.stack([s.world_from_sensor for s in RIG])
SETTINGS = TrackerSettings(processing_mode="cpu")
WAIT_MS = 40


@pytest.fixture(scope="module")
def fake_libs(tmp_path_factory):
    return build_fake_libs_or_skip(tmp_path_factory.mktemp("fake_k4a_processes"), "1.1", "the trackers run on")


@pytest.fixture
def one_tracker_sdk(fake_libs, monkeypatch):
    """The node's environment: the fake SDK found by its variables, one tracker per process, echo mode."""
    monkeypatch.setenv(K4A_LIBRARY_ENV, str(fake_libs.k4a))
    monkeypatch.setenv(K4ABT_LIBRARY_ENV, str(fake_libs.k4abt))
    monkeypatch.setenv("FAKE_K4ABT_ONE_TRACKER", "1")
    monkeypatch.setenv("FAKE_K4ABT_ECHO", "1")
    monkeypatch.delenv("FAKE_K4ABT_FAULT", raising=False)
    return fake_libs


@pytest.fixture(scope="module")
def views():
    """Two people's virtual views (two frames of a gesture, facing different ways)."""
    out = []
    for facing, frame in ((0.0, 10), (90.0, 30)):
        truth = make_gesture("hands_up_down", duration_s=2.0, facing_deg=facing).positions[frame]
        clouds = [
            person_clouds(f.depth, f.body_index, K, voxel_mm=15.0)[0].points
            for f in render_rig(RIG, truth[None], seed=frame)
        ]
        out.append(fuse_person_depth(clouds, POSES, K, skeleton_facing_deg=float(facing_deg(truth))))
    return out


def _echo_joint0(view) -> np.ndarray:
    """What the fake tracker's echo body puts at joint 0, back in the world: the virtual image's centroid."""
    depth = to_k4a_depth(view.image.depth_mm)
    return view.frontal.to_world(lift_mask(depth, depth > 0, K).mean(axis=0))


def _until_tracked(tracker, requests, *, timeout_s: float = 90.0) -> list:
    """track_many until every person has a result (the workers start in the background)."""

    def tracked() -> list | None:
        results = tracker.track_many(requests)
        return results if all(isinstance(r, tuple) for r in results) else None

    return wait_until(tracked, "a result for every person", timeout_s)


@pytest.mark.live
def test_an_sdk_with_one_tracker_per_process_needs_and_gets_a_process_per_person(one_tracker_sdk, views) -> None:
    requests = [(11, views[0], None), (12, views[1], None)]
    here = K4abtDepthTracker(SETTINGS, wait_ms=WAIT_MS, processes="in_process")
    try:
        first, second = here.track_many(requests)
        assert isinstance(first, tuple) and isinstance(second, TrackerCreateError)  # one person only
    finally:
        here.close()
    auto = K4abtDepthTracker(SETTINGS, wait_ms=WAIT_MS, processes="auto")
    try:
        results = _until_tracked(auto, requests)
        assert all(isinstance(r, tuple) for r in results), results
        for (positions, confidence), view in zip(results, views, strict=True):
            np.testing.assert_allclose(positions[0], _echo_joint0(view), atol=0.05)
            assert confidence.shape == (32,)
        pids = auto.pool().pids()
        assert set(pids) == {12} and pids[12] != os.getpid()  # person 11 in this process, 12 in a worker
        report = auto.report()
        assert report["workers"] == 1 and report["started"] == 1 and report["restarts"] == {}
    finally:
        auto.close()
    assert not Path(f"/proc/{pids[12]}").exists()  # the worker is gone (and reaped) after close


@pytest.mark.live
def test_a_dead_or_hung_tracker_process_is_counted_restarted_and_never_stalls_the_node(
    one_tracker_sdk, views, monkeypatch
) -> None:
    tracker = K4abtDepthTracker(SETTINGS, wait_ms=WAIT_MS, processes="per_person", hung_after_s=1.0)
    pool = tracker.pool()
    request = [(21, views[0], None)]
    try:
        monkeypatch.setenv("FAKE_K4ABT_FAULT", "hang:2")  # this worker's tracker: 2 results, then its pop hangs
        tracker.track_many(request)  # starts the worker with that environment
        monkeypatch.delenv("FAKE_K4ABT_FAULT")  # the workers started after it are healthy
        (result,) = _until_tracked(tracker, request)
        np.testing.assert_allclose(result[0][0], _echo_joint0(views[0]), atol=0.05)
        first_pid = pool.pids()[21]
        longest, misses, deadline = 0.0, 0, time.monotonic() + 60.0
        while pool.counters.restarts["hung"] == 0 and time.monotonic() < deadline:
            tick = time.monotonic()
            (result,) = tracker.track_many(request)
            longest = max(longest, time.monotonic() - tick)
            misses += result is None
        assert pool.counters.restarts["hung"] == 1 and misses >= 1
        assert longest < pool.budget_s + SCHEDULING_ALLOWANCE_S  # bounded by the budget (and a kill), not the hang
        (result,) = _until_tracked(tracker, request)  # a fresh worker tracks the person again
        second_pid = pool.pids()[21]
        assert isinstance(result, tuple) and second_pid != first_pid and not Path(f"/proc/{first_pid}").exists()

        os.kill(second_pid, signal.SIGKILL)  # a worker that dies

        def death_counted() -> bool:  # the pool notices on the next call that uses the worker
            tracker.track_many(request)
            return pool.counters.restarts["died"] > 0

        wait_until(death_counted, "the dead worker to be counted")
        assert pool.counters.restarts["died"] == 1
        (result,) = _until_tracked(tracker, request)
        np.testing.assert_allclose(result[0][0], _echo_joint0(views[0]), atol=0.05)
        report = tracker.report()
        assert report["started"] == 3 and report["restarts"] == {"hung": 1, "died": 1}
        last_pid = pool.pids()[21]
    finally:
        tick = time.monotonic()
        tracker.close()
        closing_s = time.monotonic() - tick
    assert closing_s < pool.close_timeout_s + SCHEDULING_ALLOWANCE_S and not Path(f"/proc/{last_pid}").exists()
