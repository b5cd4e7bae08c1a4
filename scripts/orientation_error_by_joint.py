#!/usr/bin/env python3
"""Fused orientation error per joint against the simulator's truth, split into its swing, beside one view.

    python scripts/orientation_error_by_joint.py [--seed 1] [--duration 4] [--regions arm hand]

The takes of ``skelfuse eval paper --quick``'s ``paper`` scenario (hands_up_down and squat, facing 0 and 180
deg, 4 capture sensors, no mirroring), fused with the ``skelfuse`` preset. Per joint, median / p90 in degrees:
the fused orientation's angle to the truth; its swing alone (the angle between the fused and the true aim axes:
local X, the foot bone at the ankles; i.e. the fused bone's direction error); and capture view 0's angle to the
truth. ``--regions`` picks the joints (the schema's body regions; default the arms and hands). Where the swing is
nearly all of the error, the fused bone (a position error) and not the views' twist makes it.
"""

from __future__ import annotations

import argparse

import numpy as np

from skelfuse.eval import paper
from skelfuse.fusion.orientation import quat_angle_deg, quat_rotate, to_aim_frames, views_to_world
from skelfuse.schema.skeleton import BODY_REGIONS, J
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.orientation import observe_orientations, truth_orientations
from skelfuse.sim.rig import paper_rig

_LOCAL_X = np.array([1.0, 0.0, 0.0])


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--duration", type=float, default=4.0, help="seconds per take")
    parser.add_argument("--regions", nargs="+", default=["arm", "hand"], choices=sorted(BODY_REGIONS))
    args = parser.parse_args()
    parts = [
        take_errors(gesture, facing, args.seed, args.duration)
        for gesture in ("hands_up_down", "squat")
        for facing in (0.0, 180.0)
    ]
    fused, swing, view = (np.concatenate([p[k] for p in parts]) for k in range(3))
    names = {index: name for name, index in J.items()}
    print("| joint | fused | its swing | view 0 |\n|---|---|---|---|")
    for joint in np.concatenate([BODY_REGIONS[region] for region in args.regions]):
        cells = [
            f"{np.nanmedian(e[:, joint]):.1f} / {np.nanpercentile(e[:, joint], 90):.1f}" for e in (fused, swing, view)
        ]
        print(f"| {names[int(joint)]} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
