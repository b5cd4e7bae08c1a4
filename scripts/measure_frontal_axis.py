#!/usr/bin/env python3
"""Frontalization axis error with the whole cloud (the paper) and with height bands (docs/depth-fusion.md).

Simulates each of the paper's six gestures (4 s, facing 37°) in front of the paper rig's 4 sensors, takes every
20th frame, merges the person clouds (15 mm voxels) and compares the principal axis of the floor projection,
turned into a facing, with the true facing from the hips and shoulders. Prints p50 / p90 / max error per band
and the worst frame per gesture. Simulator figures: capsule bodies, assumed depth noise.

Usage::

    python scripts/measure_frontal_axis.py            # about a minute
    python scripts/measure_frontal_axis.py --step 40  # faster, fewer frames
"""

from __future__ import annotations

import argparse

import numpy as np

from skelfuse.fusion.camera import Intrinsics
from skelfuse.fusion.depth.cloud import clouds_to_world, merge_clouds, person_clouds
from skelfuse.fusion.depth.frontal import CHEST_BAND, principal_axis_deg
from skelfuse.sim.depth import render_rig
from skelfuse.sim.gestures import GESTURES, make_gesture
from skelfuse.sim.motion import facing_deg
from skelfuse.sim.rig import paper_rig

BANDS: tuple[tuple[float, float] | None, ...] = (None, (0.45, 0.75), (0.6, 0.8), CHEST_BAND)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--step", type=int, default=20, help="take every STEP-th frame (default: %(default)s)")
    parser.add_argument("--voxel", type=float, default=15.0, help="voxel edge, mm (default: %(default)s)")
    args = parser.parse_args()
    rig = paper_rig()
    poses = np.stack([s.world_from_sensor for s in rig])
    intrinsics = Intrinsics.azure_kinect_nfov()
    errors: dict[tuple[float, float] | None, list[tuple[str, float]]] = {band: [] for band in BANDS}
    for gesture in GESTURES:
        motion = make_gesture(gesture, duration_s=4.0, facing_deg=37.0, seed=3)
        for frame in range(0, motion.n_frames, args.step):
            truth = motion.positions[frame]
            true_facing = float(facing_deg(truth))
            clouds = []
            for depth_frame in render_rig(rig, truth[None], seed=frame):
                found = person_clouds(depth_frame.depth, depth_frame.body_index, intrinsics, voxel_mm=args.voxel)
                clouds.append(found[0].points if found else np.zeros((0, 3)))
            merged = merge_clouds(clouds_to_world(clouds, poses), voxel_mm=args.voxel)
            for band in BANDS:
                axis, _ = principal_axis_deg(merged.points, band=band)
                errors[band].append((gesture, abs((axis + 90.0 - true_facing + 90.0) % 180.0 - 90.0)))
        print(f"{gesture} done", flush=True)
    for band, values in errors.items():
        e = np.array([v for _, v in values])
        worst = {g: round(max(v for name, v in values if name == g), 1) for g in GESTURES}
        label = "whole cloud" if band is None else f"band {band[0]:.2f}-{band[1]:.2f}"
        print(
            f"{label:>18}: p50 {np.median(e):5.1f}°  p90 {np.percentile(e, 90):5.1f}°  max {e.max():5.1f}°  "
            f"worst per gesture {worst}"
        )


if __name__ == "__main__":
    main()
