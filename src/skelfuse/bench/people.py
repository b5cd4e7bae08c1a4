"""Time per frame of multi-person fusion (:meth:`skelfuse.fusion.people.PeopleFuser.step`).

Input: the crowd simulator (:func:`skelfuse.sim.crowd.crowd_scenario`: people walking on two
counter-rotating rings, occluding each other) seen by ``n_sensors`` sensors, so association, track
bookkeeping and the batched fusion all do their real work. Warm-up frames first, then one
``perf_counter_ns`` sample per frame; the distribution (p50 / p99 / max) and the margin against the
30 Hz frame budget (budget / p99).
"""

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np

from skelfuse.fusion.people import PeopleFuser
from skelfuse.fusion.presets import preset
from skelfuse.sim.crowd import crowd_scenario, simulate_scenario
from skelfuse.sim.observe import load_profile

FRAME_BUDGET_MS = 1000.0 / 30.0


def bench_people(
    n_sensors: int = 8,
    n_people: int = 6,
    n_frames: int = 300,
    *,
    warmup: int = 30,
    seed: int = 0,
    preset_name: str = "skelfuse",
) -> dict[str, Any]:
    """Time :meth:`PeopleFuser.step` on a simulated crowd.

    Returns
    -------
    dict with n_sensors, n_people, n_frames (timed), preset, p50_ms, p99_ms, max_ms, budget_ms (30 Hz),
    margin_p99 (budget / p99: how many times the step fits in a frame), rate_hz (frames per second the step
    sustains back to back: timed frames / their total time; at or above 30 a node keeps up), mean_persons_out (confirmed
    tracks output per frame), track_ids (distinct ids seen; n_people means no fragmentation), and the
    machine's load (``os.getloadavg``) before and after the timed frames, with its CPU count.
    """

    total = int(n_frames) + int(warmup)
    scenario = crowd_scenario(n_people=n_people, n_sensors=n_sensors, duration_s=total / 30.0, seed=seed)
    observations = simulate_scenario(scenario, load_profile(), seed=seed)
    world = observations.positions_world(calibrated=True)
    fuser = PeopleFuser(preset(preset_name))
    load_before = os.getloadavg()
    samples = []
    persons = []
    ids: set[int] = set()
    for t in range(observations.n_frames):
        start = time.perf_counter_ns()
        result = fuser.step(world[t], observations.confidence[t], observations.valid[t], observations.times_s[t])
        elapsed = time.perf_counter_ns() - start
        if t >= warmup:
            samples.append(elapsed / 1e6)
            persons.append(result.n_persons)
        ids.update(int(i) for i in result.track_ids)
    ms = np.asarray(samples)
    p99 = float(np.percentile(ms, 99))
    return {
        "n_sensors": int(n_sensors),
        "n_people": int(n_people),
        "n_frames": int(ms.size),
        "preset": preset_name,
        "p50_ms": float(np.percentile(ms, 50)),
        "p99_ms": p99,
        "max_ms": float(ms.max()),
        "budget_ms": FRAME_BUDGET_MS,
        "margin_p99": FRAME_BUDGET_MS / p99 if p99 > 0 else float("inf"),
        "rate_hz": 1000.0 * ms.size / float(ms.sum()) if ms.sum() > 0 else float("inf"),
        "mean_persons_out": float(np.mean(persons)),
        "track_ids": len(ids),
        "load_before": [round(v, 2) for v in load_before],
        "load_after": [round(v, 2) for v in os.getloadavg()],
        "cpus": os.cpu_count(),
    }


def format_people_bench(result: dict[str, Any]) -> str:
    """One paragraph: the distribution per frame and how many times it fits in the 30 Hz budget."""
    return (
        f"Multi-person fusion (association + tracks + fusion), preset {result['preset']}, "
        f"{result['n_people']} people x {result['n_sensors']} sensors, {result['n_frames']} frames:\n"
        f"  p50 {result['p50_ms']:.3f} ms, p99 {result['p99_ms']:.3f} ms, max {result['max_ms']:.3f} ms per frame; "
        f"the {result['budget_ms']:.1f} ms frame budget holds the p99 {result['margin_p99']:.1f} times; "
        f"{result['rate_hz']:.1f} frames/s sustained back to back.\n"
        f"  {result['mean_persons_out']:.2f} persons out per frame on average, {result['track_ids']} distinct "
        "track ids (equal to the number of people means no fragmentation).\n"
        f"  Machine load (1 min) {result['load_before'][0]:.2f} before, {result['load_after'][0]:.2f} after, on "
        f"{result['cpus']} CPUs."
    )
