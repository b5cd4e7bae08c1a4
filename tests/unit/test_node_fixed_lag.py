"""``[fusion] fixed_lag_frames``: the node publishes each instant N instants later, smoothed; what it publishes is
the offline fixed-lag smoother (``fixed_lag_smooth`` through ``smooth_tracks``: per axis, with the process noise
the live filter's velocity changes set) over the same causal stream."""

from __future__ import annotations

import dataclasses
import logging
import tomllib

import numpy as np
import pytest

from skelfuse.apps.demo import sim_sensor_tables
from skelfuse.bench.latency import synthetic_frames
from skelfuse.config import parse_rig_config
from skelfuse.fusion.presets import preset
from skelfuse.fusion.smoother import FixedLagSmoother, smooth_tracks
from skelfuse.rig.smoothing import follow_bones
from skelfuse.schema.errors import ConfigError
from skelfuse.service.fusion_core import FusedOutput, FusionCore
from skelfuse.service.node import FusionNode, fixed_lag_line
from skelfuse.sim.rig import paper_rig
from skelfuse.wire.codec import decode_fused_frame, encode_sensor_frame

PERIOD_NS = 33_333_333
LAG = 3
N = 130
LEAVES, RETURNS = 60, 95  # the second walker walks out at instant 60 and a third person in at 95
SILENT = range(40, 43)  # no sensor sends anything: a gap of three instants
SENSOR_DROP = range(20, 31)  # capture_1 sends nothing
JUMPS = 75  # every view puts the first walker 400 mm aside from here on: the follow rule restarts the filter
JUMP_MM = np.array([-400.0, 0.0, 0.0])


def rig_config(fusion: str = "") -> object:
    text = "\n".join(
        [
            '[rig]\nname = "lag"\n[sync]\nby = "host"\nfps = 30.0\ntolerance_ms = 13.0\ndeadline_ms = 30.0',
            f'[fusion]\npreset = "skelfuse"\n{fusion}',
            *sim_sensor_tables(3),
        ]
    )
    return parse_rig_config(tomllib.loads(text))


def take() -> list[list]:
    """Per instant the sensor frames: two walkers, one leaving, a newcomer later, dropouts, a silent gap and a
    jump every view makes."""
    frames = synthetic_frames(3, N, seed=5, n_people=3)
    jump = {s.sensor_id: (s.to_sensor(JUMP_MM) - s.to_sensor(np.zeros(3))).astype(np.float32) for s in paper_rig(3)}
    plan = []
    for k in range(N):
        keep = [0] + ([1] if k < LEAVES else []) + ([2] if k >= RETURNS else [])
        instant = []
        for frame in frames[k]:
            if k in SILENT or (frame.sensor_id == "capture_1" and k in SENSOR_DROP):
                continue
            arrival = 10**9 + k * PERIOD_NS
            positions = frame.positions[keep]
            if k >= JUMPS:
                positions[0] += jump[frame.sensor_id]
            body = dataclasses.replace(
                frame,
                sequence=k,
                host_time_ns=arrival - 2_000_000,
                body_ids=frame.body_ids[keep],
                positions=positions,
                orientations=frame.orientations[keep],
                confidence=frame.confidence[keep],
            )
            instant.append((f"skelfuse/lag/sensors/{frame.sensor_id}/skeletons", encode_sensor_frame(body), arrival))
        plan.append(instant)
    return plan


def run(core: FusionCore, plan: list[list]) -> list[FusedOutput]:
    out: list[FusedOutput] = []
    for instant in plan:
        for key, payload, arrival in instant:
            out += core.receive(key, payload, arrival)
    return out + core.flush()


def test_the_node_publishes_the_offline_fixed_lag_smoother_of_its_causal_stream() -> None:
    plan = take()
    causal = FusionCore(rig_config())
    assert causal.fixed_lag is None  # default off
    instants = []
    step = causal.fuser.step
    causal.fuser.step = lambda group: instants.append(step(group)) or instants[-1]
    live = run(causal, plan)
    lagged_core = FusionCore(rig_config(f"fixed_lag_frames = {LAG}"))
    lagged = run(lagged_core, plan)

    # Default off: the node publishes the instant's own causal frame.
    assert [o.payload for o in live] == [o.payload for o in run(FusionCore(rig_config("fixed_lag_frames = 0")), plan)]
    assert all(
        np.array_equal(o.frame.positions, i.frame.positions, equal_nan=True)
        for o, i in zip(live, instants, strict=True)
    )
    # The offline smoother over the causal stream, independently of the node's windows.
    people = [i.people for i in instants]
    merged = [p.merged if p.merged is not None else np.full_like(p.positions, np.nan) for p in people]
    expected = smooth_tracks(
        np.array([p.time_s for p in people]),
        [p.track_ids for p in people],
        merged,
        [p.n_agree for p in people],
        [p.restarted for p in people],
        causal.params,
        lag=LAG,
    )
    assert len(lagged) == len(live) == len(instants) and lagged_core.frames_out == len(live)
    tracks = {int(t) for p in people for t in p.track_ids}
    assert len(tracks) >= 3  # the leaver's track ended, the newcomer's started
    assert sum(bool(np.any(p.restarted)) for p in people if p.restarted is not None) == 1  # the jump
    for out, instant, smoothed in zip(lagged, instants, expected, strict=True):
        rows = np.searchsorted(instant.people.track_ids, instant.frame.track_ids)
        frame = decode_fused_frame(out.payload)
        assert frame.time_us == instant.frame.time_us
        np.testing.assert_array_equal(frame.track_ids, instant.frame.track_ids)
        np.testing.assert_allclose(frame.positions, smoothed[rows], rtol=0, atol=1e-9)
        np.testing.assert_array_equal(frame.n_agree, instant.frame.n_agree)
        np.testing.assert_array_equal(frame.position_std, instant.frame.position_std)
        np.testing.assert_array_equal(frame.agreement_mm, instant.frame.agreement_mm)
        np.testing.assert_allclose(
            frame.orientations, follow_bones(instant.frame.orientations, smoothed[rows]), rtol=0, atol=1e-12
        )
        np.testing.assert_array_equal(out.sensors_world, instant.sensors_world)  # the view: the same instant's bodies
    # Smoothing did something: the first walker's pelvis moves less from frame to frame than the causal one's.
    first = min(tracks)

    def pelvis(outputs: list[FusedOutput]) -> np.ndarray:
        rows = [
            o.frame.positions[list(o.frame.track_ids).index(first), 0] for o in outputs if first in o.frame.track_ids
        ]
        return np.array(rows)

    jerk = [np.abs(np.diff(pelvis(o), n=2, axis=0)).mean() for o in (live, lagged)]
    assert jerk[1] < 0.8 * jerk[0]


def test_the_newest_instant_waits_lag_instants_and_the_tail_is_flushed() -> None:
    plan = take()[:20]
    core = FusionCore(rig_config(f"fixed_lag_frames = {LAG}"))
    published = []
    for instant in plan:
        for key, payload, arrival in instant:
            published += core.receive(key, payload, arrival)
    fused_so_far = core.groups_complete + core.groups_partial
    assert len(published) == fused_so_far - LAG
    tail = core.flush()
    assert len(published) + len(tail) == core.groups_complete + core.groups_partial
    times = [o.frame.time_us for o in published + tail]
    assert times == sorted(times) and len(set(times)) == len(times)


def test_the_node_says_the_latency_it_adds(caplog: pytest.LogCaptureFixture) -> None:
    assert "adds 100.0 ms of latency (3 frames at 30 fps)" in fixed_lag_line(3, 30.0)
    node = FusionNode(rig_config("fixed_lag_frames = 3"), None)
    with caplog.at_level(logging.INFO, logger="skelfuse.service.node"):
        node._log_start()
    assert any("adds 100.0 ms of latency" in r.getMessage() for r in caplog.records)
    caplog.clear()
    off = FusionNode(rig_config(), None)
    with caplog.at_level(logging.INFO, logger="skelfuse.service.node"):
        off._log_start()
    assert not any("fixed-lag" in r.getMessage() for r in caplog.records)


@pytest.mark.parametrize(
    ("fusion", "message"),
    [
        ("fixed_lag_frames = 31", "fixed_lag_frames"),
        ("fixed_lag_frames = -1", "fixed_lag_frames"),
        ('fixed_lag_frames = 2\n[fusion.params]\nfilter = "ema"', "cv_kalman"),
        ('fixed_lag_frames = 2\nmode = "depth"', "mode 'depth'"),
    ],
)
def test_config_refuses_a_lag_it_cannot_run(fusion: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        rig_config(fusion)


def test_the_smoother_refuses_no_lag_and_other_filters() -> None:
    with pytest.raises(ValueError, match="at least 1"):
        FixedLagSmoother(preset("skelfuse"), 0)
    with pytest.raises(ValueError, match="cv_kalman"):
        FixedLagSmoother(preset("A1"), 3)
