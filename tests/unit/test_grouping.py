"""FrameGrouper: grouping sensor frames of one instant (pure, time passed in)."""

from __future__ import annotations

import dataclasses
from itertools import pairwise

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skelfuse.rig import clocks
from skelfuse.rig.grouping import FrameGroup, FrameGrouper, SensorClock
from skelfuse.schema.frames import SensorFrame

SEED = 20240611
PERIOD_US = 33_333
SENSORS = ("s0", "s1", "s2", "s3")
OFFSETS_US = (0, 160, 320, 480)  # master, then subordinates' depth delays
TOL_US = 10_000
DEADLINE_US = 17_000


def frame(sensor_id: str, sequence: int, device_time_us: int, host_time_ns: int = 0) -> SensorFrame:
    return SensorFrame(
        sensor_id=sensor_id,
        sequence=sequence,
        device_time_us=int(device_time_us),
        host_time_ns=int(host_time_ns),
        body_ids=np.zeros(0, np.uint32),
        positions=np.zeros((0, 32, 3), np.float32),
        orientations=np.zeros((0, 32, 4), np.float32),
        confidence=np.zeros((0, 32), np.uint8),
    )


def grouper(by: str = "device", sensors: tuple[str, ...] = SENSORS, **kwargs: int) -> FrameGrouper:
    return FrameGrouper(
        sensors,
        by=by,
        tolerance_us=kwargs.pop("tolerance_us", TOL_US),  # type: ignore[arg-type]
        deadline_us=kwargs.pop("deadline_us", DEADLINE_US),
        **kwargs,
    )


def synced_stream(
    n_frames: int, rng: np.random.Generator, *, start_us: int = 5_000_000, skip: set[tuple[str, int]] = frozenset()
) -> list[tuple[int, SensorFrame]]:
    """(arrival_ns, frame) of a hardware-synced rig, sorted by arrival.

    Device time: master period with ~12 µs jitter plus each subordinate's delay. Arrival: device time plus
    a latency of 30 ms +- 3 ms per frame (body tracking + network), so sensors interleave.
    """
    events = []
    master_us = start_us
    for k in range(n_frames):
        master_us += PERIOD_US + int(rng.normal(0.0, 12.0))
        for sid, offset in zip(SENSORS, OFFSETS_US, strict=True):
            if (sid, k) in skip:
                continue
            device_us = master_us + offset + int(rng.normal(0.0, 12.0))
            arrival_ns = (device_us + 30_000 + int(rng.normal(0.0, 3_000.0))) * 1000
            events.append((arrival_ns, frame(sid, k, device_us, arrival_ns)))
    # Frames of one sensor keep their order (one pipeline per sensor): sort by arrival, ties by sequence.
    events.sort(key=lambda e: (e[0], e[1].sequence))
    return fix_per_sensor_order(events)


def fix_per_sensor_order(events: list[tuple[int, SensorFrame]]) -> list[tuple[int, SensorFrame]]:
    """Make arrival times monotonic per sensor (a sensor's pipeline never reorders its own frames)."""
    last: dict[str, int] = {}
    fixed = []
    for arrival_ns, f in sorted(events, key=lambda e: (e[1].sensor_id, e[1].sequence)):
        arrival_ns = max(arrival_ns, last.get(f.sensor_id, arrival_ns) + 1)
        last[f.sensor_id] = arrival_ns
        fixed.append((arrival_ns, f))
    fixed.sort(key=lambda e: e[0])
    return fixed


def run(g: FrameGrouper, events: list[tuple[int, SensorFrame]], *, flush: bool = True) -> list[FrameGroup]:
    out: list[FrameGroup] = []
    for arrival_ns, f in events:
        out.extend(g.poll(arrival_ns))
        out.extend(g.push(f, arrival_ns))
    if flush:
        out.extend(g.flush())
    return out


def test_synced_offsets_and_jitter_group_exactly() -> None:
    rng = np.random.default_rng(SEED)
    g = grouper()
    groups = run(g, synced_stream(300, rng), flush=False)
    assert g.n_open <= 1  # the newest instant may wait for its last frame only if it arrived last
    groups += g.flush()
    assert len(groups) == 300
    for k, group in enumerate(groups):
        assert group.complete and group.missing == ()
        assert list(group.frames) == list(SENSORS)
        assert {f.sequence for f in group.frames.values()} == {k}
        assert group.time_us == group.frames["s0"].device_time_us  # the master's timestamp
    times = [grp.time_us for grp in groups]
    assert all(b > a for a, b in pairwise(times))
    stats = g.stats
    assert stats.groups == stats.complete_groups == 300
    assert stats.totals.received == stats.totals.grouped == 1200
    assert stats.totals.late == stats.totals.dropped == stats.totals.duplicate == 0


def test_complete_group_is_emitted_on_its_last_frame_without_waiting() -> None:
    g = grouper()
    t0 = 1_000_000
    for sid, offset in zip(SENSORS[:3], OFFSETS_US[:3], strict=True):
        assert g.push(frame(sid, 0, t0 + offset), now_ns=10) == []
    [group] = g.push(frame("s3", 0, t0 + 480), now_ns=11)
    assert group.complete and group.time_us == t0


def test_silent_sensor_groups_are_emitted_at_the_deadline() -> None:
    g = grouper()
    first_arrival_ns = 7_000_000_000
    for k in range(3):
        t = 2_000_000 + k * PERIOD_US
        arrival = first_arrival_ns + k * PERIOD_US * 1000
        for i, sid in enumerate(SENSORS[:3]):
            emitted = g.push(frame(sid, k, t + OFFSETS_US[i]), arrival + i * 1000)
            assert emitted == [] or k > 0  # earlier groups may come due while pushing later ones
        assert g.poll(arrival + DEADLINE_US * 1000 - 1) == []
        [group] = g.poll(arrival + DEADLINE_US * 1000)
        assert group.missing == ("s3",) and not group.complete
        assert list(group.frames) == ["s0", "s1", "s2"]
        assert group.time_us == t
    assert g.stats.complete_groups == 0 and g.stats.groups == 3


def test_missing_frame_of_a_live_sensor_is_emitted_when_that_sensor_moves_on() -> None:
    rng = np.random.default_rng(SEED + 1)
    g = grouper()
    groups = run(g, synced_stream(20, rng, skip={("s2", 7)}))
    assert len(groups) == 20
    assert [grp.missing for grp in groups if not grp.complete] == [("s2",)]
    assert g.stats.sensors["s2"].dropped == 1  # from the sequence gap 6 -> 8
    assert g.stats.totals.dropped == 1


def test_late_frame_is_counted_and_dropped_and_never_reopens_the_instant() -> None:
    g = grouper()
    t = 3_000_000
    for i, sid in enumerate(SENSORS[:3]):
        g.push(frame(sid, 0, t + OFFSETS_US[i]), now_ns=1000 + i)
    [group] = g.poll(1000 + DEADLINE_US * 1000)
    assert group.missing == ("s3",)
    assert g.push(frame("s3", 0, t + 480), now_ns=1000 + DEADLINE_US * 1000 + 5) == []
    assert g.n_open == 0
    assert g.stats.sensors["s3"].late == 1 and g.stats.sensors["s3"].grouped == 0
    # the next instant is unaffected
    for i, sid in enumerate(SENSORS):
        out = g.push(frame(sid, 1, t + PERIOD_US + OFFSETS_US[i]), now_ns=40_000_000 + i)
    [next_group] = out
    assert next_group.complete and next_group.time_us == t + PERIOD_US


def test_duplicate_and_unknown_frames_are_counted_and_ignored() -> None:
    g = grouper()
    t = 1_000_000
    g.push(frame("s0", 0, t), now_ns=1)
    g.push(frame("s0", 0, t + 3), now_ns=2)  # a second frame of s0 for the same instant
    g.push(frame("intruder", 0, t), now_ns=3)
    for i, sid in enumerate(SENSORS[1:], start=1):
        out = g.push(frame(sid, 0, t + OFFSETS_US[i]), now_ns=4 + i)
    [group] = out
    assert group.complete and group.frames["s0"].device_time_us == t  # the first one kept
    stats = g.stats
    assert stats.sensors["s0"].duplicate == 1 and stats.sensors["s0"].received == 2
    assert stats.unknown == 1 and stats.unknown_ids == ["intruder"]
    assert "intruder" not in stats.sensors


def test_host_time_grouping_with_host_offsets_and_usb_jitter() -> None:
    rng = np.random.default_rng(SEED + 2)
    host_offset_ms = rng.normal(0.0, 1.5, size=len(SENSORS))  # constant per sensor (USB controller, tracker)
    device_epoch_us = rng.integers(0, 10**9, size=len(SENSORS))  # independent device clocks: unrelated epochs
    events = []
    for k in range(400):
        true_ns = 1_700_000_000_000_000_000 + k * PERIOD_US * 1000
        for i, sid in enumerate(SENSORS):
            jitter_ms = float(np.clip(rng.normal(0.0, 1.5), -4.0, 4.0))  # USB + processing jitter
            host_ns = true_ns + int((30.0 + host_offset_ms[i] + jitter_ms) * 1e6)
            events.append((host_ns, frame(sid, k, int(device_epoch_us[i]) + k * PERIOD_US, host_ns)))
    # Host mode needs a wider tolerance than device mode (the config's host default: 0.4 frame = 13.3 ms).
    g = grouper(by="host", tolerance_us=13_000)
    groups = run(g, fix_per_sensor_order(events))
    assert len(groups) == 400
    assert all(grp.complete for grp in groups)
    for k, group in enumerate(groups):
        assert {f.sequence for f in group.frames.values()} == {k}
        # Host mode groups on the rig's clock (each sensor's offset removed, stamp jitter smoothed out), so the
        # instant's time is near the instant's true stamp (+30 ms latency), not one frame's stamp.
        true_us = 1_700_000_000_000_000 + k * PERIOD_US + 30_000
        assert abs(group.time_us - true_us) <= 6_000


def test_device_grouping_would_fail_without_a_shared_epoch_so_host_mode_exists() -> None:
    # Same stream as above, grouped by device time: unrelated epochs never meet within the tolerance.
    g = grouper(by="device")
    events = [
        (k * 1000 + i, frame(sid, k, i * 10**8 + k * PERIOD_US)) for k in range(5) for i, sid in enumerate(SENSORS)
    ]
    groups = run(g, events)
    assert not any(grp.complete for grp in groups)


def test_whole_rig_clock_reset_resyncs_without_losing_frames() -> None:
    rng = np.random.default_rng(SEED + 3)
    first = synced_stream(60, rng, start_us=50_000_000)
    # a looped replay: the same rig starts again 49 s earlier (far outside the 1 s horizon)
    second = synced_stream(60, rng, start_us=1_000_000)
    shift_ns = first[-1][0] + 1_000_000
    second = [(arrival + shift_ns, frame(f.sensor_id, f.sequence, f.device_time_us)) for arrival, f in second]
    g = grouper()
    groups = run(g, first + second)
    stats = g.stats
    assert stats.resyncs == 1
    assert stats.totals.out_of_window == 0  # held-back frames were replayed into the new epoch
    assert stats.totals.received == stats.totals.grouped == 480
    assert len(groups) == 120 and all(grp.complete for grp in groups)
    times = [grp.time_us for grp in groups]
    assert all(b > a for a, b in pairwise(times[:60]))
    assert times[60] < times[59]  # the new epoch starts earlier; within it, time order again
    assert all(b > a for a, b in pairwise(times[60:]))


def test_one_sensor_on_a_foreign_clock_is_ignored_not_followed() -> None:
    # s3 restarts without sync: its device clock starts near 0 while the rig is at ~100 s.
    g = grouper()
    out: list[FrameGroup] = []
    for k in range(40):
        t = 100_000_000 + k * PERIOD_US
        arrival = 10**12 + k * PERIOD_US * 1000
        for i, sid in enumerate(SENSORS):
            device_us = t + OFFSETS_US[i] if (sid != "s3" or k < 10) else 500 + (k - 10) * PERIOD_US
            out += g.poll(arrival + i * 1000)
            out += g.push(frame(sid, k if sid != "s3" or k < 10 else k - 10, device_us), arrival + i * 1000)
    out += g.flush()
    stats = g.stats
    assert stats.resyncs == 0
    assert len(out) == 40
    assert all(grp.complete for grp in out[:10])
    assert all(grp.missing == ("s3",) for grp in out[10:])
    assert stats.sensors["s3"].out_of_window == 30
    assert stats.sensors["s3"].dropped == 0  # the sequence restarting is not counted as drops


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        pytest.param({"tolerance_us": 20_000}, "half a frame period", id="tolerance-too-wide"),
        pytest.param({"tolerance_us": 0}, "tolerance_us", id="tolerance-zero"),
        pytest.param({"deadline_us": 0}, "deadline_us", id="deadline-zero"),
        pytest.param({"resync_after": 0}, "resync_after", id="resync-after-zero"),
        pytest.param({"resync_horizon_us": 5_000}, "resync_horizon_us", id="horizon-below-tolerance"),
    ],
)
def test_invalid_parameters_are_refused(kwargs: dict[str, int], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        grouper(**kwargs)


def test_invalid_sensor_list_and_clock_are_refused() -> None:
    with pytest.raises(ValueError, match="duplicates"):
        FrameGrouper(["a", "a"], tolerance_us=TOL_US, deadline_us=DEADLINE_US)
    with pytest.raises(ValueError, match="at least one"):
        FrameGrouper([], tolerance_us=TOL_US, deadline_us=DEADLINE_US)
    with pytest.raises(ValueError, match="'device' or 'host'"):
        FrameGrouper(["a"], by="gps", tolerance_us=TOL_US, deadline_us=DEADLINE_US)  # type: ignore[arg-type]


def test_stats_is_a_snapshot_and_serializes() -> None:
    g = grouper()
    g.push(frame("s0", 0, 1_000), now_ns=0)
    snapshot = g.stats
    g.push(frame("s0", 2, 1_000 + 2 * PERIOD_US), now_ns=1)
    assert snapshot.sensors["s0"].received == 1 and g.stats.sensors["s0"].received == 2
    doc = g.stats.to_dict()
    assert doc["totals"]["dropped"] == 1 and doc["sensors"]["s0"]["received"] == 2  # type: ignore[index]


# ---------------------------------------------------------------------------------------------------------
# Property: every pushed frame ends in exactly one emitted group or in one counter; groups in time order.
# ---------------------------------------------------------------------------------------------------------

_stream = st.lists(
    st.tuples(
        st.integers(0, 3),  # sensor
        st.integers(0, 40),  # instant
        st.integers(-600, 600),  # device time error, µs (delays + jitter)
        st.integers(0, 60_000),  # arrival delay, µs
        st.booleans(),  # poll before pushing
    ),
    max_size=120,
)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(events=_stream, extra_sensor=st.booleans())
def test_property_accounting_and_time_order(events: list[tuple[int, int, int, int, bool]], extra_sensor: bool) -> None:
    sensors = (*SENSORS, "s4") if extra_sensor else SENSORS  # s4 is expected but never sends
    g = grouper(sensors=sensors)
    pushed = []
    timeline = sorted(
        ((instant * PERIOD_US + delay) * 1000, sid, instant, err, poll) for sid, instant, err, delay, poll in events
    )
    groups: list[FrameGroup] = []
    for arrival_ns, sid, instant, err, poll in timeline:
        f = frame(SENSORS[sid], instant, 1_000_000 + instant * PERIOD_US + err)
        pushed.append(f)
        if poll:
            groups += g.poll(arrival_ns)
        groups += g.push(f, arrival_ns)
    groups += g.flush()
    assert g.n_held == 0

    in_groups = [f for grp in groups for f in grp.frames.values()]
    assert len({id(f) for f in in_groups}) == len(in_groups)  # no frame in two groups
    assert {id(f) for f in in_groups} <= {id(f) for f in pushed}
    stats = g.stats
    for sid in sensors:
        c = stats.sensors[sid]
        assert c.received == sum(f.sensor_id == sid for f in pushed)
        assert c.grouped == sum(f.sensor_id == sid for f in in_groups)
        assert c.received == c.grouped + c.late + c.duplicate + c.out_of_window + c.off_clock
    times = [grp.time_us for grp in groups]
    assert all(b > a for a, b in pairwise(times))
    for grp in groups:
        assert grp.complete == (not grp.missing)
        assert set(grp.frames) | set(grp.missing) == set(sensors)
        frame_times = [f.device_time_us for f in grp.frames.values()]
        assert grp.time_us == min(frame_times)
        assert max(frame_times) - min(frame_times) <= 2 * TOL_US
    assert stats.groups == len(groups)
    assert stats.complete_groups == sum(grp.complete for grp in groups)


def test_for_rig_takes_sensors_and_sync_settings_from_the_config() -> None:
    from pathlib import Path

    from skelfuse.config import load_rig_config

    cfg = load_rig_config(Path(__file__).resolve().parents[2] / "config" / "rig-sim-4.toml")
    g = FrameGrouper.for_rig(cfg)
    assert g.expected_sensor_ids == cfg.sensor_ids
    assert (g.by, g.tolerance_us, g.deadline_us, g.resync_after) == ("device", 10_000, 17_000, 8)


# -- sensor clocks: hostile stamps, offset and jittery PC clocks ---------------------------------------------


def rig_stream(
    n_frames: int,
    rng: np.random.Generator,
    *,
    clock_offset_us: dict[str, int] | None = None,
    clock_jitter_us: dict[str, float] | None = None,
) -> list[tuple[int, SensorFrame]]:
    """(arrival_ns on the node's monotonic clock, frame) of four capture PCs stamping host time.

    Each PC stamps ``host_time_ns`` with its own wall clock: the true publish time plus that PC's offset plus
    (optionally) a per-frame jitter of its clock reading; the node's arrival clock has an unrelated epoch
    and sees 1-3 ms of network latency.
    """
    clock_offset_us = clock_offset_us or {}
    clock_jitter_us = clock_jitter_us or {}
    events = []
    for k in range(n_frames):
        true_us = 1_700_000_000_000_000 + k * PERIOD_US
        for sid in SENSORS:
            stamp_us = true_us + clock_offset_us.get(sid, 0) + int(rng.normal(0.0, clock_jitter_us.get(sid, 0.0)))
            arrival_ns = (true_us - 1_699_999_000_000_000 + int(rng.uniform(1_000, 3_000))) * 1000
            events.append((arrival_ns, frame(sid, 1000 + k, 0, stamp_us * 1000)))
    return fix_per_sensor_order(events)


@pytest.mark.parametrize("offset_ms", [5, -5, 100, -100, 500, -500])
def test_host_grouping_holds_when_one_pc_clock_is_offset(offset_ms: int) -> None:
    # Before per-sensor clocks: +100 ms made every instant hold only that sensor and dropped the others as late.
    g = grouper(by="host", tolerance_us=13_000)
    groups = run(g, rig_stream(300, np.random.default_rng(SEED + 10), clock_offset_us={"s2": offset_ms * 1000}))
    stats = g.stats
    assert len(groups) == 300 and all(grp.complete for grp in groups)
    assert stats.totals.grouped == stats.totals.received == 1200
    estimates = g.clock_estimates()
    assert estimates["s2"].relative_offset_ms == pytest.approx(offset_ms, abs=2.0)
    assert all(abs(estimates[sid].relative_offset_ms) < 2.0 for sid in ("s0", "s1", "s3"))  # type: ignore[arg-type]


def test_clock_estimates_match_numpys_median_and_asdict() -> None:
    # The status reads these every second; their fast forms against numpy and dataclasses.
    g = grouper(by="host", tolerance_us=13_000)
    run(g, rig_stream(120, np.random.default_rng(SEED + 12), clock_jitter_us={"s1": 3_000.0}))
    clock = g._clocks["s1"]
    residuals = np.asarray(clock._residuals, dtype=np.float64)
    estimate = g.clock_estimates()["s1"]
    assert estimate.jitter_ms == round(float(np.median(np.abs(residuals - clock._offset_us))) / 1000, 3)
    assert estimate.jitter_ms > 0.5  # the 3 ms jitter is seen
    assert estimate.to_dict() == dataclasses.asdict(estimate)


def test_host_grouping_holds_with_20ms_jitter_and_offset_on_one_pc_clock() -> None:
    # 20 ms (one sigma) of jitter in one PC's clock readings used to split instants.
    g = grouper(by="host", tolerance_us=13_000)
    events = rig_stream(
        300,
        np.random.default_rng(SEED + 11),
        clock_offset_us={"s1": 100_000},
        clock_jitter_us={"s1": 20_000.0},
    )
    groups = run(g, events)
    stats = g.stats
    # The first frames teach each clock; after that every instant is complete.
    assert len(groups) <= 302
    assert sum(grp.complete for grp in groups) >= 295
    assert stats.sensors["s1"].grouped >= 297
    complete = [grp for grp in groups if grp.complete]
    assert all({f.sequence for f in grp.frames.values()} == {grp.frames["s0"].sequence} for grp in complete)
    times = [grp.time_us for grp in groups]
    assert all(b > a for a, b in pairwise(times))


def test_a_frame_a_second_from_the_future_moves_nothing() -> None:
    # One forged frame per second stamped 0.9 s ahead on s1's key cut the output from 30 to ~4 instants/s.
    rng = np.random.default_rng(SEED + 12)
    events = synced_stream(300, rng)
    forged = []
    for k in range(15, 300, 30):
        arrival_ns, real = next(e for e in events if e[1].sensor_id == "s1" and e[1].sequence == k)
        forged.append((arrival_ns + 500, frame("s1", k + 27, real.device_time_us + 900_000)))
    g = grouper()
    groups = run(g, sorted(events + forged, key=lambda e: e[0]))
    stats = g.stats
    assert len(groups) == 300 and all(grp.complete for grp in groups)
    assert stats.sensors["s1"].off_clock == len(forged) == 10
    assert stats.totals.late == stats.totals.out_of_window == stats.totals.dropped == 0
    assert stats.resyncs == 0


def test_far_future_stamps_do_not_inflate_dropped_or_resync_the_rig() -> None:
    rng = np.random.default_rng(SEED + 13)
    events = synced_stream(180, rng)
    t_burst = events[4 * 120][0]
    # A burst at 1 kHz on s0's key (an attacker's loop): far-future stamps and sequences, amid the real frames.
    burst = [(t_burst + 500 + i * 1_000_000, frame("s0", 10**10 + i, 10**13 + i * PERIOD_US)) for i in range(200)]
    g = grouper()
    groups = run(g, sorted(events + burst, key=lambda e: e[0]))
    stats = g.stats
    assert stats.resyncs == 0
    assert stats.totals.dropped == 0  # not 10**10
    assert stats.sensors["s0"].off_clock == 200
    assert g.clock_estimates()["s0"].relearns == 0
    assert len(groups) == 180 and all(grp.complete for grp in groups)


def test_a_whole_pc_clock_step_is_relearned_without_losing_frames() -> None:
    # s2's PC steps its clock by +3 s (an NTP step): after resync_after frames its clock re-learns, and its
    # host-time frames are grouped again; the others never notice. The held frames come too late for their
    # instants (emitted meanwhile without s2): at most resync_after of them are late.
    events = rig_stream(200, np.random.default_rng(SEED + 14))
    stepped = [
        (a, dataclasses.replace(f, host_time_ns=f.host_time_ns + 3 * 10**9))
        if f.sensor_id == "s2" and f.sequence >= 1100
        else (a, f)
        for a, f in events
    ]
    g = grouper(by="host", tolerance_us=13_000)
    groups = run(g, stepped)
    stats = g.stats
    assert g.clock_estimates()["s2"].relearns == 1
    assert stats.sensors["s2"].off_clock == 0 and stats.sensors["s2"].late <= 8
    assert stats.sensors["s2"].grouped + stats.sensors["s2"].late == 200
    assert stats.resyncs == 0
    assert sum(grp.complete for grp in groups) >= 190


def test_on_time_frames_after_a_backlog_are_not_taken_for_the_future() -> None:
    # s1's frames arrive 250 ms late for 2 s (a stalled tracker, a loaded PC), then on time again: the first
    # on-time frames lie 250 ms "ahead" of the backlog's residuals but not ahead of s1's fastest delivery.
    events = synced_stream(200, np.random.default_rng(SEED + 15))
    delayed = [(a + 250_000_000, f) if f.sensor_id == "s1" and 30 <= f.sequence < 90 else (a, f) for a, f in events]
    g = grouper(deadline_us=400_000)
    groups = run(g, fix_per_sensor_order(delayed))
    stats = g.stats
    assert stats.sensors["s1"].off_clock == 0 and g.clock_estimates()["s1"].relearns == 0
    assert len(groups) == 200 and all(grp.complete for grp in groups)


def test_a_sensor_clocks_offset_is_the_median_of_its_recent_residuals() -> None:
    """The running median (computed without numpy, on every frame) against numpy's, over odd and even windows,
    ties, and residuals of today's epoch-scale device times (~1.7e15 µs)."""
    rng = np.random.default_rng(SEED)
    clock = SensorClock(period_us=1e6 / 30, window=7)
    residuals: list[int] = []
    for k in range(60):
        time_us = 1_764_000_000_000_000 + k * 33_333 + int(rng.integers(-3, 4)) * 500
        arrival_us = 5_000_000 + k * 33_333 + int(rng.integers(0, 3000))
        clock.learn(time_us, arrival_us)
        residuals = [*residuals, time_us - arrival_us][-7:]
        expected = int(np.median(residuals)) if len(residuals) > 2 else residuals[0]
        assert clock.offset_us == expected
    for n in range(1, 12):  # the host-mode phases are floats
        phases = list(rng.normal(0.0, 1e4, n))
        assert clocks.median_of(phases) == float(np.median(phases))


# -- a forged clock that speaks first --------------------------------------------------------------------------


def forged_first(
    events: list[tuple[int, SensorFrame]], sensor_id: str, *, ahead_us: int, hz: float, lead_s: float
) -> list[tuple[int, SensorFrame]]:
    """A forger on ``sensor_id``'s key: frames stamped ``ahead_us`` past the real instant at ``hz``, starting
    ``lead_s`` before the sensor's first genuine frame and going on to the end (forged sequences)."""
    genuine = [(a, f) for a, f in events if f.sensor_id == sensor_id]
    first_ns, last_ns = genuine[0][0], genuine[-1][0]
    slope = (genuine[-1][1].device_time_us - genuine[0][1].device_time_us) / ((last_ns - first_ns) / 1000)
    forged = []
    t_ns = first_ns - int(lead_s * 1e9)
    i = 0
    while t_ns < last_ns:
        now_us = genuine[0][1].device_time_us + slope * (t_ns - first_ns) / 1000
        forged.append((t_ns, frame(sensor_id, 10**9 + i, int(now_us) + ahead_us)))
        t_ns += int(1e9 / hz)
        i += 1
    return forged


@pytest.mark.parametrize(("by", "hz"), [("device", 125.0), ("host", 125.0), ("device", 30.0)])
def test_a_forged_clock_that_speaks_first_loses_the_sensor_to_the_genuine_stream(by: str, hz: float) -> None:
    # s1's key: a forger stamping 0.9 s ahead starts 0.5 s before the genuine frames and never stops. Holding
    # s1's clock for good would leave no complete instant; the genuine stream wins it back: paced like the
    # sensor where the forger is not (125 Hz), or, at 30 Hz in device mode, by agreeing with the rig's other
    # sensors.
    rng = np.random.default_rng(SEED + 16)
    events = synced_stream(300, rng)
    forged = forged_first(events, "s1", ahead_us=900_000, hz=hz, lead_s=0.5)
    start_us = events[0][1].device_time_us
    if by == "host":  # the same streams stamped in host time (one PC: stamp = arrival - 30 ms of latency)
        events = [(a, dataclasses.replace(f, host_time_ns=a - 30_000_000)) for a, f in events]
        forged = [(a, dataclasses.replace(f, host_time_ns=a - 30_000_000 + 900_000_000)) for a, f in forged]
        start_us = events[0][0] // 1000 - 30_000
    g = grouper(by=by, tolerance_us=13_000 if by == "host" else TOL_US)
    groups = run(g, sorted(events + forged, key=lambda e: e[0]))
    s1 = g.stats.sensors["s1"]
    assert g.clock_estimates()["s1"].relearns == 1
    # Every frame is accounted for; the forged ones are off clock except those of the forger's lead and of
    # the takeover (relearn_after genuine frames), which it held the clock for.
    assert s1.received == 300 + len(forged)
    assert s1.grouped + s1.late + s1.duplicate + s1.out_of_window + s1.off_clock == s1.received
    assert len(forged) - s1.off_clock <= hz * (0.5 + 0.35)
    # From 1.5 s on (the forger's 0.9 s lead poisons the windows, then the takeover) every instant is
    # complete, with s1's genuine frame.
    steady = [grp for grp in groups if grp.time_us > start_us + 1_500_000]
    assert len(steady) >= 250
    assert all(grp.complete and grp.frames["s1"].sequence < 10**9 for grp in steady)


def test_the_soak_race_a_forger_on_a_clock_of_its_own_then_two_forged_streams() -> None:
    # The soak's adversary started with the rig: its first frames, stamped on a clock of its
    # own (0 + 0.9 s, 0 + 10^10 µs), can teach s1's clock; then every frame (genuine, 0.9 s ahead, 10^10 ahead,
    # interleaved) is off clock and no resync_after in a row agree: s1 would never be fused again.
    events = synced_stream(300, np.random.default_rng(SEED + 17))
    first_s1 = next(a for a, f in events if f.sensor_id == "s1")
    forged = []
    for i in range(int(10e9 / 4e6)):  # 250 Hz for 10 s, from 20 ms before s1's first frame
        t_ns = first_s1 - 20_000_000 + i * 4_000_000
        genuine_us = 0 if t_ns < first_s1 else events[0][1].device_time_us + (t_ns - first_s1) // 1000
        forged.append((t_ns, frame("s1", 10**9 + i, genuine_us + (900_000 if i % 2 else 10**10))))
    g = grouper()
    groups = run(g, sorted(events + forged, key=lambda e: e[0]))
    s1 = g.stats.sensors["s1"]
    assert s1.grouped >= 290 and s1.off_clock >= len(forged) - 5  # the first speaker's 20 ms (5 frames)
    assert sum(grp.complete for grp in groups) >= 290
    start_us = events[0][1].device_time_us  # the forger's very first frame (its own clock) was fused alone
    on_rig_time = [grp for grp in groups if start_us <= grp.time_us < start_us + 20_000_000]
    assert all(grp.frames["s1"].sequence < 10**9 for grp in on_rig_time if "s1" in grp.frames)


def test_a_forger_does_not_take_a_clock_while_the_rig_pauses() -> None:
    # The soak's publisher stalls 0.8 s (all sensors silent, then a burst); the adversary (same process) goes
    # on more slowly, its stamps frozen at the last instant + 0.9 s. Those forged frames are paced in arrival
    # and s1's stream is quiet: taking s1's clock, the forged instants 0.9 s ahead would make every sensor
    # late. A sensor's own frames are also stamped a frame period apart; frozen stamps are not.
    events = synced_stream(300, np.random.default_rng(SEED + 18))
    stall_from = next(a for a, f in events if f.sequence == 100)
    stall_to = stall_from + 800_000_000
    stalled = [(max(a, stall_to + f.sequence - 100), f) if 100 <= f.sequence < 125 else (a, f) for a, f in events]
    stalled = fix_per_sensor_order(stalled)
    last_us = {f.sequence: f.device_time_us for _, f in events if f.sensor_id == "s0"}
    forged = []
    t_ns, i = events[0][0] + 200_000_000, 0
    while t_ns < events[-1][0]:
        stalling = stall_from <= t_ns < stall_to
        k = 99 if stalling else max(k for k, us in last_us.items() if us * 1000 <= t_ns - 30_000_000)
        forged.append((t_ns, frame("s1", 10**9 + i, last_us[k] + 900_000)))
        t_ns += 25_000_000 if stalling else 8_000_000  # 40 Hz in the stall, 125 Hz otherwise
        i += 1
    g = grouper(deadline_us=400_000)
    groups = run(g, sorted(stalled + forged, key=lambda e: e[0]))
    assert g.clock_estimates()["s1"].relearns == 0
    # At the stall's end a frozen stamp 0.9 s ahead is only ~0.1 s ahead of the arrival clock: one forged frame
    # slips in (a duplicate), and cannot block the genuine frames (the stamps' reference is a median of three).
    assert g.stats.sensors["s1"].off_clock >= len(forged) - 2
    assert g.stats.sensors["s1"].grouped >= 298
    assert len(groups) == 300 and sum(grp.complete for grp in groups) >= 298


@pytest.mark.parametrize("forged_hz", [30.0, 40.0])
def test_a_forger_does_not_take_a_clock_while_the_whole_rig_is_silent(forged_hz: float) -> None:
    # A starved node: the rig's frames (one link) stop arriving for a few hundred ms and then come as a burst,
    # while the adversary's link goes on delivering frames on s1's key stamped 0.9 s ahead on a clock that
    # keeps running (slowed to 30-40 Hz, so paced like a sensor). s1's learned stream is "quiet"; were the
    # forged clock to re-learn s1's clock, its instants 0.9 s ahead would be emitted and every sensor's frames
    # of the next 0.9 s would be late (instants lost). A
    # sensor whose stream goes quiet together with the whole rig has not stepped its clock: nothing arrived.
    events = synced_stream(300, np.random.default_rng(SEED + 19))
    stall_from = next(a for a, f in events if f.sequence == 100)
    stall_to = stall_from + 400_000_000  # 400 ms without any rig frame, then the backlog in one burst
    stalled = [(max(a, stall_to + f.sequence - 100), f) if a >= stall_from else (a, f) for a, f in events]
    stalled = fix_per_sensor_order(stalled)
    start_ns, start_us = events[0][0], events[0][1].device_time_us  # device time = arrival - 30 ms
    forged = []
    t_ns, i = start_ns + 200_000_000, 0
    while t_ns < events[-1][0]:
        now_us = start_us + (t_ns - start_ns) // 1000
        ahead = 900_000 if i % 2 == 0 else 10**10  # the soak's two forged streams, interleaved
        forged.append((t_ns, frame("s1", 10**9 + i, now_us + ahead)))
        t_ns += int(0.5e9 / forged_hz)
        i += 1
    g = grouper()
    groups = run(g, sorted(stalled + forged, key=lambda e: e[0]))
    stats = g.stats
    assert g.clock_estimates()["s1"].relearns == 0
    assert stats.sensors["s1"].off_clock == len(forged)
    assert stats.totals.late == stats.totals.out_of_window == 0
    assert len(groups) == 300 and all(grp.complete for grp in groups)


def test_a_lone_live_sensors_clock_step_is_relearned_though_the_others_are_dead() -> None:
    # The rig check of the "quiet" rule must not read dead sensors as a silent rig: s0, s1 and s3 stop for good
    # at frame 50, then s2's PC steps its clock by +3 s at frame 100. Without the liveness condition s2's 100
    # frames after the step were all off clock (never re-learned).
    events = rig_stream(200, np.random.default_rng(SEED + 14))
    lone = [
        (a, dataclasses.replace(f, host_time_ns=f.host_time_ns + 3 * 10**9) if f.sequence >= 1100 else f)
        for a, f in events
        if f.sensor_id == "s2" or f.sequence < 1050
    ]
    g = grouper(by="host", tolerance_us=13_000)
    run(g, lone)
    s2 = g.stats.sensors["s2"]
    assert g.clock_estimates()["s2"].relearns == 1
    assert s2.off_clock == 0 and s2.grouped + s2.late == 200 and s2.late <= 8
