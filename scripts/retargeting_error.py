#!/usr/bin/env python3
"""Measure the armature's retargeting error (FK of the exported skeleton versus the fused positions).

For each of the simulator's six gestures the paper's 4-sensor rig is simulated (packaged Azure Kinect profile),
fused with our preset, and the fused take is fitted with :func:`skelfuse.retarget.armature.fit_motion`; the real
3-view andyj1 take (if ``--data`` has it) is fused the same way (``eval.real.fuse_views``, preset "skelfuse") and
fitted. Prints median and p90 per joint group (mm), over every joint-frame the fused data held (filled gaps
excluded). docs/evidence.md, "Retargeting", renders the ``--json`` output with :func:`format_markdown`.

Usage::

    python scripts/retargeting_error.py                      # simulator only
    python scripts/retargeting_error.py --data ../shared/data  # plus the real take
    python scripts/retargeting_error.py --blender              # plus Blender's reading of BVH and FBX
    python scripts/retargeting_error.py --json                 # the figures as JSON, stamped
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.cli.common import print_json
from skelfuse.cli.stamp import RunStamp
from skelfuse.eval.metrics import none_for_nan
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
    cells = " | ".join(f"{_mm(err[g]['median'])} / {_mm(err[g]['p90'])}" for g in GROUPS)
    return f"| {name} | {cells} |"


def _mm(value: float | None) -> str:
    """A figure to 0.1 mm; a group without a joint-frame (None in the JSON, NaN before) as a dash."""
    return "—" if value is None or not np.isfinite(value) else f"{value:.1f}"


def _blender_comparison(fit) -> list[dict[str, Any]]:
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
            rows.append({"what": name, "blender": result["blender"], "max_mm": float(gap.max()),
                         "median_mm": float(np.median(gap))})  # fmt: skip
    return rows


def _median_p90(values: np.ndarray) -> list[float]:
    return [float(np.median(values)), float(np.percentile(values, 90))]


def simulated_take(gesture: str, duration_s: float, seed: int) -> tuple[Any, dict[str, Any]]:
    """One gesture fused and fitted: the fit, and its retargeting error and both errors against the truth."""
    run = FusionRun("skelfuse", "skelfuse", None, tuple(range(N_CAPTURE)))
    motion = make_gesture(gesture, duration_s=duration_s, fps=FPS, facing_deg=30.0, seed=seed)
    obs = simulate(motion, list(paper_rig(N_CAPTURE)), load_profile(None), seed=seed + 1)
    fused = fuse_take(run, _world_skeletons(obs), np.asarray(obs.confidence), FPS)
    fit = fit_motion(np.arange(len(fused)) / FPS, fused)
    truth = np.asarray(obs.truth, dtype=np.float64)[: fit.n_frames, EVAL_JOINTS]
    seen = ~fit.filled[:, EVAL_JOINTS]
    to_truth = {
        "fused": _median_p90(np.linalg.norm(fit.targets[:, EVAL_JOINTS] - truth, axis=-1)[seen]),
        "exported": _median_p90(np.linalg.norm(fit.positions[:, EVAL_JOINTS] - truth, axis=-1)[seen]),
    }
    return fit, {"take": gesture, "error": fit.retargeting_error(), "vs_truth": to_truth}


def measure(duration_s: float, seed: int, data: Path | None, blender: bool) -> dict[str, Any]:
    """Every gesture's retargeting error, pooled; Blender's reading of one take; the real take where given."""
    fits, takes = zip(*(simulated_take(g, duration_s, seed) for g in GESTURES), strict=True)
    pooled = retargeting_error(
        *(np.concatenate([getattr(f, k) for f in fits]) for k in ("positions", "targets", "filled"))
    )
    result: dict[str, Any] = {"duration_s": duration_s, "seed": seed, "takes": list(takes), "pooled": pooled,
                              "blender": _blender_comparison(fits[GESTURES.index("random")]) if blender else None,
                              "real": None}  # fmt: skip
    if data is not None:
        try:
            take = load_take(data)
        except DataError as exc:
            result["real"] = {"skipped": str(exc)}
        else:
            fused = fuse_views(take.positions, take.confidence, "skelfuse")
            fit = fit_motion(np.arange(len(fused)) / FPS, fused)
            result["real"] = {"frames": take.n_frames, "error": fit.retargeting_error()}
    return result


def format_markdown(result: dict[str, Any]) -> str:
    """The retargeting error per take (median / p90, mm), the body joints against the truth, Blender's reading."""
    lines = [
        f"Simulated takes of {result['duration_s']:g} s at {FPS:g} Hz (seed {result['seed']}), fused with the "
        "skelfuse preset; FK of the exported skeleton against the fused positions, median / p90 mm, over every "
        "joint-frame the fused data held.",
        "",
        "| take | " + " | ".join(f"{g} median / p90 (mm)" for g in GROUPS) + " |",
        "|---" * (len(GROUPS) + 1) + "|",
    ]
    lines += [_row(f"sim {t['take']}", t["error"]) for t in result["takes"]]
    lines.append(_row(f"sim, all {len(result['takes'])} pooled", result["pooled"]))
    real = result["real"]
    if real is not None and "error" in real:
        lines.append(_row(f"real andyj1 ({real['frames']} frames, 3 views)", real["error"]))
    lines += [
        "",
        "Against the simulator's truth, body joints (median / p90, mm): does the fixed-length skeleton cost accuracy?",
        "",
        "| take | fused vs truth | exported (FK) vs truth |",
        "|---|---|---|",
    ]
    for t in result["takes"]:
        cells = " | ".join(f"{_mm(m)} / {_mm(p)}" for m, p in t["vs_truth"].values())
        lines.append(f"| sim {t['take']} | {cells} |")
    if real is not None and "skipped" in real:
        lines += ["", f"Real take skipped: {real['skipped']}"]
    if result["blender"]:
        lines += ["", "Blender's posed joints against our FK, all 32 joints at 10 sampled frames (sim random):", ""]
        lines += [f"- {r['what']} (Blender {r['blender']}): max {r['max_mm']:.4f} mm, median {r['median_mm']:.4f} mm"
                  for r in result["blender"]]  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, help="shared data folder holding azure-kinect-andyj1/ (optional)")
    parser.add_argument("--duration", type=float, default=20.0, help="seconds per simulated gesture (20)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--blender", action="store_true", help="also compare Blender's import of the BVH and FBX with our FK"
    )
    parser.add_argument("--json", action="store_true", help="print the figures as JSON, stamped")
    args = parser.parse_args()
    args.stamp = RunStamp.begin(sys.argv[1:], program=("python", "scripts/retargeting_error.py")) if args.json else None
    result = none_for_nan(measure(args.duration, args.seed, args.data, args.blender))
    if args.json:
        print_json(result, args)
    else:
        print(format_markdown(result))


if __name__ == "__main__":
    main()
