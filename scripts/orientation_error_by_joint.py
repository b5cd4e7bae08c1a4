#!/usr/bin/env python3
"""Fused orientation error per joint against the simulator's truth, split into its swing, beside one view.

    python scripts/orientation_error_by_joint.py [--seed 1] [--duration 4] [--regions arm hand] [--json]

The takes of ``skelfuse eval paper --quick``'s ``paper`` scenario (hands_up_down and squat, facing 0 and 180
deg, 4 capture sensors, no mirroring), fused with the ``skelfuse`` preset. Per joint, median / p90 in degrees:
the fused orientation's angle to the truth; its swing alone (the angle between the fused and the true aim axes:
local X, the foot bone at the ankles; i.e. the fused bone's direction error); and capture view 0's angle to the
truth. ``--regions`` picks the joints (the schema's body regions; default the arms and hands). Where the swing is
nearly all of the error, the fused bone (a position error) and not the views' twist makes it. ``--json`` prints
the figures with the run's stamp (docs/evidence.md, "Orientations", renders them with :func:`format_markdown`).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

import numpy as np

from skelfuse.cli.common import print_json
from skelfuse.cli.stamp import RunStamp
from skelfuse.eval import paper
from skelfuse.fusion.orientation import quat_angle_deg, quat_rotate, to_aim_frames, views_to_world
from skelfuse.schema.skeleton import BODY_REGIONS, JOINT_NAMES
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.orientation import observe_orientations, truth_orientations
from skelfuse.sim.rig import paper_rig

_LOCAL_X = np.array([1.0, 0.0, 0.0])
GESTURES = ("hands_up_down", "squat")
FACINGS_DEG = (0.0, 180.0)


def take_errors(gesture: str, facing: float, seed: int, duration_s: float) -> tuple[np.ndarray, ...]:
    """(T, 32) fused error, fused swing error and view 0's error of one take, degrees."""
    motion = make_gesture(gesture, duration_s=duration_s, fps=30.0, facing_deg=facing, seed=seed)
    profile = paper.scenario_profile(load_profile(None), "paper")
    obs = simulate(motion, list(paper_rig(paper.N_CAPTURE)), profile, seed=seed)
    truth = truth_orientations(obs.truth, 30.0, seed=seed)
    views = views_to_world(observe_orientations(obs, truth, seed=seed), obs.world_from_sensor_calibrated)
    run = paper.FusionRun("skelfuse", "skelfuse", None, tuple(range(paper.N_CAPTURE)))
    sensor_positions = obs.world_from_sensor_calibrated[: paper.N_CAPTURE, :3, 3]
    _, fused = paper.fuse_take_oriented(run, paper._world_skeletons(obs), obs.confidence, views, 30.0, sensor_positions)
    cos = np.sum(quat_rotate(to_aim_frames(fused), _LOCAL_X) * quat_rotate(to_aim_frames(truth), _LOCAL_X), axis=-1)
    swing = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    return quat_angle_deg(fused, truth), swing, quat_angle_deg(views[:, 0], truth)


def measure(seed: int, duration_s: float, regions: list[str]) -> dict[str, Any]:
    """Per joint of ``regions``: median and p90 of the fused error, its swing and view 0's error, degrees."""
    parts = [take_errors(gesture, facing, seed, duration_s) for gesture in GESTURES for facing in FACINGS_DEG]
    fused, swing, view = (np.concatenate([p[k] for p in parts]) for k in range(3))
    joints = {}
    for joint in np.concatenate([BODY_REGIONS[region] for region in regions]):
        joints[JOINT_NAMES[int(joint)]] = {
            name: [float(np.nanmedian(e[:, joint])), float(np.nanpercentile(e[:, joint], 90))]
            for name, e in (("fused", fused), ("swing", swing), ("view 0", view))
        }
    return {"seed": seed, "duration_s": duration_s, "gestures": list(GESTURES), "facings_deg": list(FACINGS_DEG),
            "joints": joints}  # fmt: skip


def format_markdown(result: dict[str, Any]) -> str:
    """One row per joint: fused, its swing, view 0 (median / p90, degrees)."""
    lines = [
        f"Gestures {', '.join(result['gestures'])}, facing {' and '.join(f'{f:g}' for f in result['facings_deg'])} "
        f"deg, {result['duration_s']:g} s each, seed {result['seed']}; median / p90, degrees.",
        "",
        "| joint | fused | its swing | view 0 |",
        "|---|---|---|---|",
    ]
    for name, row in result["joints"].items():
        lines.append(f"| {name} | " + " | ".join(f"{m:.1f} / {p:.1f}" for m, p in row.values()) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--duration", type=float, default=4.0, help="seconds per take")
    parser.add_argument("--regions", nargs="+", default=["arm", "hand"], choices=sorted(BODY_REGIONS))
    parser.add_argument("--json", action="store_true", help="print the per-joint figures as JSON, stamped")
    args = parser.parse_args()
    program = ("python", "scripts/orientation_error_by_joint.py")
    args.stamp = RunStamp.begin(sys.argv[1:], program=program) if args.json else None
    result = measure(args.seed, args.duration, args.regions)
    if args.json:
        print_json(result, args)
    else:
        print(format_markdown(result))


if __name__ == "__main__":
    main()
