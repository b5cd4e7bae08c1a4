#!/usr/bin/env python3
"""Time per fused frame of the "skelfuse" preset with and without the orientation and position_std stages.

    python scripts/bench_orientation_cost.py [--sensors 4] [--bodies 1 3 6] [--frames 300]

Inputs: a T-pose with 10 mm noise per view and the views' quaternions (the same every frame, noise aside), so
that every stage runs on every joint. Prints ms per frame (median of the frames) for each body count.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from skelfuse.fusion.orientation import apply_derived, body_hint_frames
from skelfuse.fusion.pipeline import Fuser
from skelfuse.fusion.presets import preset
from skelfuse.schema.skeleton import N_JOINTS, J


def t_pose() -> np.ndarray:
    p = np.zeros((N_JOINTS, 3))
    for name, z in {"PELVIS": 1000, "SPINE_NAVEL": 1200, "SPINE_CHEST": 1400, "NECK": 1600, "HEAD": 1700}.items():
        p[J[name]] = (0.0, 0.0, z)
    for side, sx in (("LEFT", 1.0), ("RIGHT", -1.0)):
        for name, x in {
            "CLAVICLE": 50,
            "SHOULDER": 200,
            "ELBOW": 500,
            "WRIST": 750,
            "HAND": 820,
            "HANDTIP": 900,
        }.items():
            p[J[f"{name}_{side}"]] = (sx * x, 0.0, 1500.0)
        p[J[f"THUMB_{side}"]] = (sx * 800, -40.0, 1500.0)
        for name, z in {"HIP": 950, "KNEE": 500, "ANKLE": 80}.items():
            p[J[f"{name}_{side}"]] = (sx * 100, 0.0, z)
        p[J[f"FOOT_{side}"]] = (sx * 100, -150.0, 20.0)
        p[J[f"EYE_{side}"]] = (sx * 30, -80.0, 1750.0)
        p[J[f"EAR_{side}"]] = (sx * 70, 0.0, 1730.0)
    p[J["NOSE"]] = (0.0, -100.0, 1720.0)
    return p


def time_case(params, n_bodies: int, n_sensors: int, frames: int) -> float:
    rng = np.random.default_rng(0)
    pose = t_pose()
    quats = np.broadcast_to(apply_derived(body_hint_frames(pose)), (n_bodies, n_sensors, N_JOINTS, 4)).copy()
    conf = np.full((n_bodies, n_sensors, N_JOINTS), 2, np.uint8)
    fuser = Fuser(params, n_bodies=n_bodies)
    times = []
    for _ in range(frames):
        cand = pose + rng.normal(0.0, 10.0, (n_bodies, n_sensors, N_JOINTS, 3))
        start = time.perf_counter()
        fuser.step(cand, conf, orientations=quats)
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times[10:]))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sensors", type=int, default=4)
    parser.add_argument("--bodies", type=int, nargs="+", default=[1, 3, 6])
    parser.add_argument("--frames", type=int, default=300)
    args = parser.parse_args()
    full = preset("skelfuse")
    plain = dataclasses.replace(full, orientations=False, position_std=False)
    print(f"sensors {args.sensors}, median ms per frame: positions only / + orientations and position_std")
    for n in args.bodies:
        print(
            f"  bodies {n}: {time_case(plain, n, args.sensors, args.frames):.3f} / "
            f"{time_case(full, n, args.sensors, args.frames):.3f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
