#!/usr/bin/env python3
"""Where the time of one instant goes: CPU time per stage of the per-instant path and of the node's fusion step.

    python scripts/profile_instant.py [--cases 4x1 16x6] [--frames 200]
    PYTHONPATH=/path/to/other/checkout/src python scripts/profile_instant.py   # the same table for another tree

Every stage function is wrapped with a timer (``time.thread_time_ns``: the work itself, not the waits for a core on
a shared machine); nested stages are inside their parents (``fuse`` holds ``realign`` ... ``orientations``). The
inputs are ``skelfuse bench instant``'s simulated crowd (with joint orientations). "node receive" is
FusionCore.receive on the encoded sensor payloads: decode, checks, grouping, and the fusion step when an instant
completes. A stage missing from a tree (renamed) is left out of its table. The wrappers add their own cost (a few
microseconds per call), so the stages do not add up to the total exactly.
"""

from __future__ import annotations

import argparse
import collections
import functools
import importlib
import importlib.util
import sys
import time
from pathlib import Path
from typing import Any

from skelfuse.config import RigConfig, SensorConfig
from skelfuse.service import node as node_module
from skelfuse.wire.codec import encode_fused_frame, encode_sensor_frame

STAGES = [  # (module, attribute, label); a class attribute as "Class.method"
    ("skelfuse.rig.instant", "group_bodies", "stack bodies"),
    ("skelfuse.rig.instant", "group_orientations", "stack orientations"),
    ("skelfuse.rig.instant", "_stack_group", "stack bodies + orientations"),
    ("skelfuse.rig.instant", "bodies_to_world", "bodies to world"),
    ("skelfuse.rig.instant", "views_to_world", "orientations to world"),
    ("skelfuse.rig.instant", "views_to_world_by_matrix", "orientations to world"),
    ("skelfuse.rig.instant", "GroupFuser._stack_to_world", "stack + to world (bodies, orientations)"),
    ("skelfuse.fusion.tracks", "TrackTable.predict", "tracks: predict"),
    ("skelfuse.fusion.people", "associate", "associate"),
    ("skelfuse.fusion.tracks", "TrackTable.update", "tracks: update"),
    ("skelfuse.fusion.people", "stack_states", "state: stack"),
    ("skelfuse.fusion.people", "_row_views", "state: split"),
    ("skelfuse.fusion.people", "take_state", "state: take rows"),
    ("skelfuse.fusion.people", "put_state", "state: put rows"),
    ("skelfuse.fusion.people", "gather_orientations", "gather orientations"),
    ("skelfuse.fusion.people", "fuse", "fuse (all below)"),
    ("skelfuse.fusion.pipeline", "select_candidates", "  select"),
    ("skelfuse.fusion.pipeline", "_predicted", "  prediction"),
    ("skelfuse.fusion.pipeline", "predicted_positions", "  prediction"),
    ("skelfuse.fusion.pipeline", "_plausibility", "  plausibility: view checks (+ hold-outs, views to realign)"),
    ("skelfuse.fusion.pipeline", "realignment_views", "  plausibility: views to realign"),
    ("skelfuse.fusion.pipeline", "_realign", "  realign"),
    ("skelfuse.fusion.pipeline", "remove_held", "  plausibility: remove held views"),
    ("skelfuse.fusion.pipeline", "merge_views", "  plausibility: remove held views (+ far joints)"),
    ("skelfuse.fusion.pipeline", "drop_far_joints", "  plausibility: far joints"),
    ("skelfuse.fusion.pipeline", "learn_bones", "  plausibility: bone lengths"),
    ("skelfuse.fusion.pipeline", "_merge", "  merge"),
    ("skelfuse.fusion.pipeline", "filter_step", "  filter"),
    ("skelfuse.fusion.pipeline", "_orientations", "  orientations"),
    ("skelfuse.fusion.pipeline", "position_uncertainty", "  uncertainty"),
    ("skelfuse.fusion.pipeline", "measurement_variance", "  uncertainty: variance"),
    ("skelfuse.fusion.pipeline", "uncertainty_step", "  uncertainty: recursion"),
    ("skelfuse.rig.instant", "fused_frame", "fused frame"),
    ("skelfuse.service.node", "encode_fused_frame", "encode"),
    ("skelfuse.service.node", "decode_sensor_frame", "node: decode (per payload)"),
    ("skelfuse.service.node", "FrameGrouper.push", "node: grouping"),
    ("skelfuse.service.node", "FusionCore._fuse", "node: fusion step (step + encode)"),
]


def _instrument(totals: dict[str, int]) -> None:
    for module_name, attribute, label in STAGES:
        module = importlib.import_module(module_name)
        owner: Any = module
        name = attribute
        if "." in attribute:
            class_name, name = attribute.split(".")
            owner = getattr(module, class_name, None)
        if owner is None or not hasattr(owner, name):
            continue
        original = getattr(owner, name)

        def timed(*args: Any, _f: Any = original, _label: str = label, **kwargs: Any) -> Any:
            start = time.thread_time_ns()
            try:
                return _f(*args, **kwargs)
            finally:
                totals[_label] += time.thread_time_ns() - start

        setattr(owner, name, functools.wraps(original)(timed))


def _bench_instant() -> Any:
    """This checkout's ``skelfuse/bench/instant.py`` loaded by path, so that its inputs (which use only stable
    interfaces) are built with whichever tree ``PYTHONPATH`` points at."""
    path = Path(__file__).resolve().parents[1] / "src" / "skelfuse" / "bench" / "instant.py"
    spec = importlib.util.spec_from_file_location("_bench_instant_inputs", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["4x1", "16x6"], metavar="SxP")
    parser.add_argument("--frames", type=int, default=200)
    args = parser.parse_args()
    totals: dict[str, int] = collections.defaultdict(int)
    _instrument(totals)
    warmup = 30
    for case in args.cases:
        n_sensors, n_people = (int(v) for v in case.lower().split("x"))
        fuser, groups = _bench_instant().instant_take(n_sensors, n_people, args.frames + warmup)
        sensor_ids, poses = fuser.sensor_ids, fuser.world_from_sensor
        total = 0
        for t, group in enumerate(groups):
            if t == warmup:
                totals.clear()
                total = 0
            start = time.thread_time_ns()
            encode_fused_frame(fuser.step(group).frame)
            total += time.thread_time_ns() - start
        _print(f"{case}: per-instant path (GroupFuser.step + encode)", total, totals, args.frames)
        # The node: every payload through FusionCore.receive.
        cfg = RigConfig(
            name="profile",
            sensors=tuple(
                SensorConfig(id=sid, source="sim", world_from_sensor=tuple(map(tuple, pose.tolist())))
                for sid, pose in zip(sensor_ids, poses, strict=True)
            ),
        )
        core = node_module.FusionCore(cfg)
        payloads = [
            [(f"skelfuse/profile/sensors/{f.sensor_id}/skeletons", encode_sensor_frame(f)) for f in g.frames.values()]
            for g in groups
        ]
        total = 0
        for t, instant in enumerate(payloads):
            if t == warmup:
                totals.clear()
                total = 0
            for k, (key, payload) in enumerate(instant):
                start = time.thread_time_ns()
                core.receive(key, payload, (t * 33_333 + k * 100) * 1000)
                total += time.thread_time_ns() - start
        _print(f"{case}: node, FusionCore.receive of every payload", total, totals, args.frames)
    return 0


def _print(title: str, total_ns: int, totals: dict[str, int], frames: int) -> None:
    print(f"\n{title}: {total_ns / frames / 1e3:.0f} us CPU per instant")
    print("| stage | us per instant | share |")
    print("|---|---:|---:|")
    for label, ns in sorted(totals.items(), key=lambda kv: -kv[1]):
        print(f"| {label} | {ns / frames / 1e3:.0f} | {100 * ns / max(total_ns, 1):.0f}% |")


if __name__ == "__main__":
    raise SystemExit(main())
