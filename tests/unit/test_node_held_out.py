"""The node's status counts the views the fusion held out, per sensor and reason."""

from __future__ import annotations

import dataclasses
import tomllib
from collections import Counter

import numpy as np

from skelfuse.apps.demo import sim_sensor_tables
from skelfuse.bench.latency import synthetic_frames
from skelfuse.config import parse_rig_config
from skelfuse.fusion.plausibility import TELEPORT, UPSIDE_DOWN
from skelfuse.schema.skeleton import J
from skelfuse.service.fusion_core import FusionCore, count_held_out
from skelfuse.wire.codec import encode_sensor_frame

PERIOD_NS = 33_333_333


def test_count_held_out_by_sensor_and_reason() -> None:
    counts: dict[str, Counter[str]] = {}
    held = np.array([[0, TELEPORT, 0], [UPSIDE_DOWN, TELEPORT, 0]], dtype=np.uint8)  # (P=2, S=3)
    count_held_out(counts, held, ("a", "b", "c"))
    count_held_out(counts, held[:1], ("a", "b", "c"))
    assert counts == {"a": Counter(upside_down=1), "b": Counter(teleport=3)}


def test_status_counts_an_upside_down_view() -> None:
    cfg = parse_rig_config(
        tomllib.loads(
            "\n".join(
                [
                    '[rig]\nname = "held"\n[sync]\nby = "host"\nfps = 30.0\ntolerance_ms = 13.0\ndeadline_ms = 30.0',
                    '[fusion]\npreset = "skelfuse"',
                    *sim_sensor_tables(3),
                ]
            )
        )
    )
    core = FusionCore(cfg)
    frames = synthetic_frames(3, 120, seed=3)
    flipped = range(60, 66)  # capture_1's tracker turns the person upside down for 0.2 s
    for k in range(120):
        arrival = 10**9 + k * PERIOD_NS
        for frame in frames[k]:
            frame = dataclasses.replace(frame, sequence=k, host_time_ns=arrival - 2_000_000)
            if frame.sensor_id == "capture_1" and k in flipped:
                pelvis = frame.positions[:, J["PELVIS"] : J["PELVIS"] + 1]
                frame = dataclasses.replace(frame, positions=(2 * pelvis - frame.positions).astype(np.float32))
            core.receive(f"skelfuse/held/sensors/{frame.sensor_id}/skeletons", encode_sensor_frame(frame), arrival)
    report = core.sensor_report(10**9 + 120 * PERIOD_NS, 1.0)
    # Held while flipped and for the first two plausible frames after (the release hysteresis); the flipped body
    # is re-acquired by the person's track (not a ghost person), so the frames stay with one track.
    release = core.fuser.people.params.plausibility_release_frames
    assert report["capture_1"]["held_out"] == {"upside_down": len(flipped) + release - 1}
    assert core.fuser.people.table.next_id == 2
    assert report["capture_0"]["held_out"] == {} and report["capture_2"]["held_out"] == {}
