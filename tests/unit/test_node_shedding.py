"""A fusion node that cannot keep up sheds its oldest instants, whole, and never falls more than
``[node] max_lag_s`` behind; one that keeps up, or falls behind for less than the bound, sheds nothing.

The node is simulated on its own clock: four sensors deliver an instant every 1/30 s; the node takes each
sample when it is free (not before it arrived), and every fused instant costs it a fixed time. The truth is an
independent model of that queue: instant k is due when its last frame is taken; it is fused when its age then
(now minus its first frame's arrival) is within the bound, else shed. The core's decisions must match it
instant for instant.
"""

from __future__ import annotations

import dataclasses
import logging
import tomllib

import pytest

from skelfuse.apps.demo import sim_sensor_tables
from skelfuse.bench.latency import synthetic_frames
from skelfuse.config import RigConfig, parse_rig_config
from skelfuse.service.node import FusionCore
from skelfuse.service.shedding import EPISODE_QUIET_S, SHED_BEHIND, LagShedder
from skelfuse.wire.codec import encode_sensor_frame

PERIOD_NS = 33_333_333
SENSOR_GAP_NS = 200_000  # the sensors' frames of one instant arrive 0.2 ms apart
MAX_LAG_S = 0.5
N_INSTANTS = 150


def rig(max_lag_s: float = MAX_LAG_S) -> RigConfig:
    return parse_rig_config(
        tomllib.loads(
            "\n".join(
                [
                    '[rig]\nname = "shed"\n[sync]\nby = "device"\nfps = 30.0\ntolerance_ms = 10.0\ndeadline_ms = 17.0',
                    f"[node]\nmax_lag_s = {max_lag_s}",
                    *sim_sensor_tables(4),
                ]
            )
        )
    )


def instant_costs_ms(cost_ms: float, stall: tuple[int, float] | None = None) -> list[float]:
    """What each fused instant costs the simulated node (``stall``: instant index and its cost)."""
    costs = [cost_ms] * N_INSTANTS
    if stall is not None:
        costs[stall[0]] = stall[1]
    return costs


def run_node(
    cfg: RigConfig, costs_ms: list[float], *, with_clock: bool = True
) -> tuple[list[int], list[int], FusionCore]:
    """The core driven on the simulated clock (``with_clock`` False: the core is not told the time); returns the
    fused instants' indices, each one's age when its fused frame was out (ns), and the core."""
    frames = synthetic_frames(4, N_INSTANTS, seed=3)
    core = FusionCore(cfg)
    free_at = 0
    fused, ages = [], []
    for k in range(N_INSTANTS):
        for i, frame in enumerate(frames[k]):
            arrival = 10**9 + k * PERIOD_NS + i * SENSOR_GAP_NS
            stamped = dataclasses.replace(frame, sequence=k, device_time_us=10**6 + k * 33_333 + 160 * i)
            now = max(free_at, arrival)
            for out in core.receive(
                f"skelfuse/shed/sensors/{frame.sensor_id}/skeletons",
                encode_sensor_frame(stamped),
                arrival,
                now if with_clock else None,
            ):
                index = (out.frame.time_us - 10**6) // 33_333
                now += round(costs_ms[index] * 1e6)
                fused.append(index)
                ages.append(now - (10**9 + index * PERIOD_NS))
            free_at = now
    return fused, ages, core


def model(costs_ms: list[float], max_lag_s: float) -> list[int]:
    """The instants a node fusing in order and shedding those over the bound fuses (the test's truth)."""
    free_at, fused = 0, []
    for k in range(N_INSTANTS):
        first = 10**9 + k * PERIOD_NS
        turn = max(free_at, first + 3 * SENSOR_GAP_NS)  # its last frame taken
        if turn - first > max_lag_s * 1e9:
            free_at = turn
            continue
        fused.append(k)
        free_at = turn + round(costs_ms[k] * 1e6)
    return fused


def test_a_node_that_cannot_keep_up_sheds_the_oldest_instants_and_stays_within_the_bound() -> None:
    costs = instant_costs_ms(50.0)  # 50 ms per instant against 33 ms between instants
    fused, ages, core = run_node(rig(), costs)
    assert fused == model(costs, MAX_LAG_S)
    shed = N_INSTANTS - len(fused)
    assert shed > 30  # about a third of the instants once the bound is reached
    assert core.shedder.by_reason == {SHED_BEHIND: shed}
    assert core.shedder.frames_by_sensor == {sid: shed for sid in core.sensor_ids}  # whole instants
    assert max(ages) <= MAX_LAG_S * 1e9 + 50e6  # the bound plus one instant's fusion
    assert fused == sorted(fused) and fused[-1] == N_INSTANTS - 1  # in order, and the newest kept
    assert core.groups_partial == 0  # no instant was fused from part of its frames


def test_a_node_that_keeps_up_sheds_nothing() -> None:
    fused, _, core = run_node(rig(), instant_costs_ms(20.0))
    assert fused == list(range(N_INSTANTS)) and core.shedder.total == 0


def test_falling_behind_for_less_than_the_bound_loses_nothing_and_longer_sheds_only_the_excess() -> None:
    # One 0.4 s pause: the backlog (12 instants) waits, is caught up at 20 ms an instant, and none is shed.
    short = instant_costs_ms(20.0, stall=(40, 400.0))
    fused, _, core = run_node(rig(), short)
    assert fused == list(range(N_INSTANTS)) and core.shedder.total == 0
    # One 1.5 s pause: what waited longer than 0.5 s is shed, the rest of the backlog is fused.
    long = instant_costs_ms(20.0, stall=(40, 1500.0))
    fused, ages, core = run_node(rig(), long)
    assert fused == model(long, MAX_LAG_S)
    assert 20 <= core.shedder.total <= 35  # 1.5 s is 45 instants; those within the bound's reach are fused
    assert max(age for index, age in zip(fused, ages, strict=True) if index > 40) <= MAX_LAG_S * 1e9 + 20e6


def test_the_bound_is_the_configured_one() -> None:
    costs = instant_costs_ms(50.0)
    for max_lag_s in (0.2, 1.0):
        fused, ages, _ = run_node(rig(max_lag_s), costs)
        assert fused == model(costs, max_lag_s)
        assert max(ages) <= max_lag_s * 1e9 + 50e6


def test_a_caller_without_a_clock_never_sheds() -> None:
    # FusionCore.receive without now_ns (offline tools, tests that feed arrival times only) fuses everything.
    fused, _, core = run_node(rig(), instant_costs_ms(50.0), with_clock=False)
    assert fused == list(range(N_INSTANTS)) and core.shedder.total == 0


def test_each_episode_is_logged_once_and_its_end_with_the_count(caplog: pytest.LogCaptureFixture) -> None:
    shedder = LagShedder(0.5, what="fusion node test")
    second = 1_000_000_000
    with caplog.at_level(logging.INFO, logger="skelfuse.service.node"):
        for n in range(100):  # an episode: a shed instant every 50 ms for 5 s, fused ones between
            now = 10 * second + n * 50_000_000
            shedder.shed(("a", "b"), 600_000_000, now, 40.0)
            shedder.fused(now + 10_000_000)
        shedder.fused(10 * second + 100 * 50_000_000 + round(EPISODE_QUIET_S * second))
        # A second episode 10 s later: counted, not warned about (at most one warning per LOG_EVERY_S).
        shedder.shed(("a",), 700_000_000, 30 * second, 40.0)
        shedder.fused(35 * second)
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "cannot keep up" in warnings[0].getMessage()
    assert "0.60 s" in warnings[0].getMessage() and "max_lag_s = 0.5" in warnings[0].getMessage()
    caught_up = [r.getMessage() for r in caplog.records if "caught up" in r.getMessage()]
    assert caught_up == ["fusion node test caught up: 100 instants shed over 5.0 s (in all 100 since the start)"]
    assert shedder.episodes == 2 and shedder.total == 101
    assert shedder.frames_by_sensor == {"a": 101, "b": 100}
    with pytest.raises(ValueError, match="max_lag_s"):
        LagShedder(0.0)
