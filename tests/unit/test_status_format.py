"""``skelfuse status`` prints each sensor's clock as the node estimates it (one PC's clock set 100 ms ahead)."""

from __future__ import annotations

import dataclasses
import re
import tomllib

import numpy as np

from skelfuse.apps.demo import sim_sensor_tables
from skelfuse.bench.latency import synthetic_frames
from skelfuse.config import parse_rig_config
from skelfuse.service.node import FusionCore
from skelfuse.service.status import format_status
from skelfuse.wire.codec import NodeStatus, encode_sensor_frame

PERIOD_NS = 33_333_333
AHEAD_NS = 100_000_000  # capture_2's PC clock runs 100 ms ahead of the others', with 5 ms (1 sigma) of jitter
JITTER_NS = 5_000_000


def test_status_line_prints_each_sensors_clock_offset_and_jitter() -> None:
    cfg = parse_rig_config(
        tomllib.loads(
            "\n".join(
                [
                    '[rig]\nname = "clocks"\n[sync]\nby = "host"\nfps = 30.0\ntolerance_ms = 13.0\ndeadline_ms = 30.0',
                    *sim_sensor_tables(4),
                ]
            )
        )
    )
    core = FusionCore(cfg)
    frames = synthetic_frames(4, 150, seed=2)
    jitter = np.random.default_rng(4).normal(0.0, JITTER_NS, 150).astype(np.int64)
    for k in range(150):
        arrival = 10**9 + k * PERIOD_NS
        for i, frame in enumerate(frames[k]):
            stamped = dataclasses.replace(
                frame, sequence=k, host_time_ns=arrival - 2_000_000 + (AHEAD_NS + int(jitter[k]) if i == 2 else 0)
            )
            core.receive(f"skelfuse/clocks/sensors/{frame.sensor_id}/skeletons", encode_sensor_frame(stamped), arrival)
    sensors = core.sensor_report(10**9 + 150 * PERIOD_NS, 1.0)
    status = NodeStatus(
        node="fusion",
        role="fusion",
        state="running",
        time_ns=0,
        counters={"frames_in": core.frames_in, "frames_out": core.frames_out},
        info={"fused_rate_hz": 30.0, "sensors": sensors},
    )
    line = format_status(status)
    printed = re.findall(r"(capture_\d) ([+-]\d+\.\d) ms / (\d+\.\d) ms", line.split("clocks")[1])
    offsets = {sid: float(ms) for sid, ms, _ in printed}
    jitters = {sid: float(ms) for sid, _, ms in printed}
    assert set(offsets) == set(cfg.sensor_ids), line
    assert abs(offsets["capture_2"] - 100.0) < 2.0, line  # the injected offset, read back from the status line
    assert all(abs(offsets[sid]) < 2.0 for sid in ("capture_0", "capture_1", "capture_3")), line
    # jitter is a median absolute deviation: 0.674 sigma of a normal distribution = 3.4 ms here
    assert 2.0 < jitters["capture_2"] < 5.0 and jitters["capture_0"] < 0.5, line
