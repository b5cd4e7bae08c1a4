#!/usr/bin/env python3
"""Measure the armature's retargeting error (FK of the exported skeleton versus the fused positions).

The figures in docs/export.md come from this script. For each of the simulator's six gestures the paper's
4-sensor rig is simulated (packaged Azure Kinect profile), fused with our preset, and the fused take is fitted
with :func:`skelfuse.retarget.armature.fit_motion`; the real 3-view andyj1 take (if ``--data`` has it) is fused
the same way (``eval.real.fuse_views``, preset "skelfuse") and fitted. Prints median and p90 per joint group
(mm), over every joint-frame the fused data held (filled gaps excluded).

Usage::

    python scripts/retargeting_error.py                      # simulator only
    python scripts/retargeting_error.py --data ../shared/data  # plus the real take
    python scripts/retargeting_error.py --blender              # plus Blender's reading of BVH and FBX
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from skelfuse.eval.paper import N_CAPTURE, FusionRun, _world_skeletons, fuse_take
from skelfuse.eval.real import fuse_views, load_take
from skelfuse.export.blender import run_blender
from skelfuse.export.bvh import UNIT_MM, write_bvh_motion
from skelfuse.export.fbx import write_fbx_motion
from skelfuse.retarget.armature import fit_motion, retargeting_error
from skelfuse.schema.errors import DataError
from skelfuse.schema.skeleton import EVAL_JOINTS, JOINT_NAMES
from skelfuse.sim.gestures import GESTURES, make_gesture
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.rig import paper_rig

GROUPS = ("torso", "upper_limb", "lower_limb", "body", "all")
FPS = 30.0


def _row(name: str, err: dict) -> str:
    cells = " | ".join(f"{err[g]['median']:.1f} / {err[g]['p90']:.1f}" for g in GROUPS)
    return f"| {name} | {cells} |"


def _blender_comparison(fit) -> list[str]:
    """Max and median |Blender - FK| (mm) of the BVH import and of the FBX round trip."""
    frames = np.linspace(0, fit.n_frames - 1, 10).astype(int).tolist()
    rows = []
    with tempfile.TemporaryDirectory() as work:
        bvh = write_bvh_motion(Path(work) / "take.bvh", fit, unit="cm")
        fbx = write_fbx_motion(Path(work) / "take.fbx", fit)
        requests = {
            "BVH import": {"command": "sample", "bvh": str(bvh.path), "scale": UNIT_MM["cm"] / 1000.0},
            "FBX (Blender export, re-import)": {"command": "sample", "fbx": str(fbx.path), "fps": 1 / fit.frame_time_s},
        }
        for name, request in requests.items():
            result = run_blender({**request, "frames": frames})
            heads = np.array([result["heads"][n] for n in JOINT_NAMES]).transpose(1, 0, 2) * 1000.0
            gap = np.linalg.norm(heads - fit.positions[frames], axis=-1)
            rows.append(f"{name} (Blender {result['blender']}): max {gap.max():.4f} mm, median {np.median(gap):.4f} mm")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, help="shared data folder holding azure-kinect-andyj1/ (optional)")
    parser.add_argument("--duration", type=float, default=20.0, help="seconds per simulated gesture (20)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--blender", action="store_true", help="also compare Blender's import of the BVH and FBX with our FK"
    )
    args = parser.parse_args()

    print("| take | " + " | ".join(f"{g} median / p90 (mm)" for g in GROUPS) + " |")
    print("|---" * (len(GROUPS) + 1) + "|")
    pooled = []
    truth_rows = []
    run = FusionRun("skelfuse", "skelfuse", None, tuple(range(N_CAPTURE)))
    for gesture in GESTURES:
        motion = make_gesture(gesture, duration_s=args.duration, fps=FPS, facing_deg=30.0, seed=args.seed)
        obs = simulate(motion, list(paper_rig(N_CAPTURE)), load_profile(None), seed=args.seed + 1)
        fused = fuse_take(run, _world_skeletons(obs), np.asarray(obs.confidence), FPS)
        fit = fit_motion(np.arange(len(fused)) / FPS, fused)
        pooled.append(fit)
        if args.blender and gesture == "random":
            blender_rows = _blender_comparison(fit)
        print(_row(f"sim {gesture}", fit.retargeting_error()), flush=True)
        truth = np.asarray(obs.truth, dtype=np.float64)[: fit.n_frames, EVAL_JOINTS]
        seen = ~fit.filled[:, EVAL_JOINTS]
        to_truth = {
            "fused": np.linalg.norm(fit.targets[:, EVAL_JOINTS] - truth, axis=-1)[seen],
            "exported": np.linalg.norm(fit.positions[:, EVAL_JOINTS] - truth, axis=-1)[seen],
        }
        truth_rows.append(
            f"| sim {gesture} | "
            + " | ".join(f"{np.median(d):.1f} / {np.percentile(d, 90):.1f}" for d in to_truth.values())
            + " |"
        )
    print(
        _row(
            "sim, all six",
            retargeting_error(
                np.concatenate([f.positions for f in pooled]),
                np.concatenate([f.targets for f in pooled]),
                np.concatenate([f.filled for f in pooled]),
            ),
        )
    )
    print(
        "\nAgainst the simulator's truth, body joints (median / p90, mm): does the fixed-length skeleton cost accuracy?"
    )
    print("| take | fused vs truth | exported (FK) vs truth |\n|---|---|---|")
    print("\n".join(truth_rows))
    if args.blender:
        print("\nBlender's posed joints versus our FK, all 32 joints at 10 sampled frames (sim random):")
        print("\n".join(blender_rows))
    if args.data is not None:
        try:
            take = load_take(args.data)
        except DataError as exc:
            print(f"(real take skipped: {exc})")
            return
        fused = fuse_views(take.positions, take.confidence, "skelfuse")
        fit = fit_motion(np.arange(len(fused)) / FPS, fused)
        print(_row(f"real andyj1 ({take.n_frames} frames, 3 views)", fit.retargeting_error()))


if __name__ == "__main__":
    main()
