#!/usr/bin/env python3
"""How close the fused joint orientations sit to the views on the real andyj1 takes, beside what the views allow.

For every aimed joint (``ORIENTATION_AIMED``), the "skelfuse" preset's live output over each pair of views and over
all three views of the 3-sensor take, and over the 2-sensor take: the median angle between the fused frame and
each view's (``skelfuse eval real``'s orientation per joint: mirrored frames left out), and beside it the median
angle between the views' own frames. A frame within x degrees of both views of a pair needs them within 2x of each
other, so half the views' angle is a lower bound on the larger of the fused frame's angles to them (per frame; for
the medians, nearly): where the views disagree by more than 16 degrees, no fusion sits within 8 of both.

Configurations (docs/orientations.md says what the files hold):

- ``3-sensor, as written``: the saved_data_2_3dev files as the product reads them (registered: the subordinates'
  positions are in the master's frame, their orientations in their own camera frames);
- ``3-sensor, frames turned``: the same, each file's orientations turned by the inverse of its one fitted offset
  (``measure_orientation_convention.frame_offset``: the rotation that puts its joint frames on its own bones; a
  correction estimated from the file itself, 3.9 and 12.7 degrees for sub1 and sub2, 0.1 for the master);
- ``2-sensor, own frames``: the extrinsic_calculation take from the files written in each camera's own frame
  (``joints_sync_1`` master, ``joints_sync_2`` subordinate), the subordinate's pose fitted rigidly to the
  master's joints (MEDIUM in both, all 10 frames), so positions and orientations are turned by the same rotation;
  beside it ``2-sensor, mapped``: the authors' ``joints_sync_tf`` (positions mapped, orientations not) as written.

    PYTHONPATH=src python scripts/orientation_to_views.py [--data DIR] [--json]

``--json`` prints every configuration's per-joint figures with the run's stamp (:func:`format_markdown` renders
them).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.calibration.rigid import fit_rigid, rotation_angle_deg
from skelfuse.cli.common import print_json
from skelfuse.cli.stamp import RunStamp
from skelfuse.eval.metrics import nan_for_none, none_for_nan
from skelfuse.eval.rig import run_rig_eval
from skelfuse.fusion.orientation import quat_from_matrix, quat_multiply
from skelfuse.recording.inputs import InputTake, open_inputs
from skelfuse.schema.skeleton import Confidence

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "azure-kinect-andyj1"
TARGET_DEG = 8.0
THREE = {view: f"saved_data_2_3dev/joints_gen_{view}.csv" for view in ("master", "sub1", "sub2")}
OWN_FRAMES = {"master": "extrinsic_calculation/joints_sync_1.csv", "sub": "extrinsic_calculation/joints_sync_2.csv"}
MAPPED = {"master": "extrinsic_calculation/joints_sync_1.csv", "sub": "extrinsic_calculation/joints_sync_tf.csv"}


def fused_to_views(take: InputTake, calibration: dict[str, np.ndarray] | None = None) -> dict[str, dict[str, float]]:
    """Per aimed joint, ``eval real``'s orientation row of the skelfuse preset's live output over ``take``."""
    result = run_rig_eval(take, calibration=calibration, presets=("skelfuse",), progress=False)
    return result.orientation_by_joint["skelfuse"]


def three_sensor_takes(data: Path, turned: bool) -> dict[str, InputTake]:
    """Every pair and the triple of the 3-sensor take, registered; ``turned``: each file's frame offset removed."""
    take = open_inputs([f"{view}={data / file}" for view, file in THREE.items()], registered=True)
    if turned:
        take = dataclasses.replace(take, recordings=tuple(_frames_turned(r) for r in take.recordings))
    subsets = [("master", "sub1"), ("master", "sub2"), ("sub1", "sub2"), ("master", "sub1", "sub2")]
    return {" + ".join(views): _subset(take, views) for views in subsets}


def _frames_turned(recording: Any) -> Any:
    """``recording`` with every orientation turned by the inverse of the file's fitted frame offset."""
    from measure_orientation_convention import frame_offset  # scripts/ is on the path when run as a script

    positions, orientations = recording.positions[:, 0].astype(np.float64), recording.orientations[:, 0]
    undo = quat_from_matrix(frame_offset(positions, orientations.astype(np.float64)).T)
    turned = quat_multiply(undo, recording.orientations.astype(np.float64)).astype(recording.orientations.dtype)
    return dataclasses.replace(recording, orientations=turned)


def _subset(take: InputTake, views: tuple[str, ...]) -> InputTake:
    recordings = tuple(r for r in take.recordings if r.sensor_id in views)
    return dataclasses.replace(take, recordings=recordings, poses={v: take.poses[v] for v in views})


def own_frame_pose(take: InputTake) -> tuple[dict[str, np.ndarray], float]:
    """The 2-sensor take's poses: the master's identity, the subordinate's fitted to the master's MEDIUM joints;
    and the fitted rotation's angle, degrees."""
    master, sub = (r.positions[:, 0].reshape(-1, 3).astype(np.float64) for r in take.recordings)
    medium = np.logical_and(*(r.confidence[:, 0].reshape(-1) >= int(Confidence.MEDIUM) for r in take.recordings))
    fit = fit_rigid(sub[medium], master[medium])
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = fit.R, fit.t
    return {"master": np.eye(4), "sub": pose}, rotation_angle_deg(fit.R)


def measure(data: Path) -> dict[str, Any]:
    """Every configuration's per-joint rows (see the module docstring)."""
    configurations: dict[str, Any] = {}
    for title, turned in (("3-sensor, as written", False), ("3-sensor, frames turned", True)):
        configurations[title] = {name: fused_to_views(t) for name, t in three_sensor_takes(data, turned).items()}
    own = open_inputs([f"{v}={data / f}" for v, f in OWN_FRAMES.items()])
    poses, angle = own_frame_pose(own)
    configurations["2-sensor, own frames"] = {"master + sub": fused_to_views(own, poses)}
    mapped = open_inputs([f"{v}={data / f}" for v, f in MAPPED.items()], registered=True)
    configurations["2-sensor, mapped"] = {"master + sub": fused_to_views(mapped)}
    return {"data": str(data), "target_deg": TARGET_DEG, "own_frame_rotation_deg": angle,
            "configurations": configurations}  # fmt: skip


def verdict(row: dict[str, float], views: list[str], target: float) -> str:
    """Whether the joint meets the target, misses it where the views agree within 2x it (a fusion defect), or
    misses it only where two views disagree by more (a property of the data)."""
    worst = max(row[v] for v in views)
    if not np.isfinite(worst):
        return "no data"
    if worst <= target:
        return "met"
    pairs = [row[k] for k in row if k.startswith("between ") and k != "between views"]
    return "views disagree" if max(pairs) / 2.0 > target else "**views agree**"


def format_markdown(result: dict[str, Any]) -> str:
    """One table per configuration and subset of views."""
    result = nan_for_none(result)
    target = result["target_deg"]
    lines = [
        f"Median angle, degrees, between the fused frame and each view's; the views' own angle per pair, and half "
        f"the largest (the lower bound on the larger fused angle); target {target:g} deg. The 2-sensor own-frame "
        f"take's subordinate pose: a rigid fit to the master's joints, rotation {result['own_frame_rotation_deg']:.2f}"
        " deg.",
    ]
    for title, subsets in result["configurations"].items():
        for name, rows in subsets.items():
            views = name.split(" + ")
            pairs = [f"between {a} and {b}" for i, a in enumerate(views) for b in views[i + 1 :]]
            lines += ["", f"**{title}: {name}**", "",
                      "| joint | " + " | ".join(f"to {v}" for v in views) + " | "
                      + " | ".join(p.removeprefix("between ") for p in pairs) + " | bound | verdict |",
                      "|---|" + "---:|" * (len(views) + len(pairs) + 1) + "---|"]  # fmt: skip
            for joint, row in rows.items():
                bound = max(row[p] for p in pairs) / 2.0
                cells = [f"{row[v]:.1f}" for v in views] + [f"{row[p]:.1f}" for p in pairs] + [f"{bound:.1f}"]
                lines.append(f"| {joint} | " + " | ".join(cells) + f" | {verdict(row, views, target)} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA, help="the andyj1 folder (default: %(default)s)")
    parser.add_argument("--json", action="store_true", help="print the per-joint figures as JSON, stamped")
    args = parser.parse_args()
    args.stamp = (
        RunStamp.begin(sys.argv[1:], program=("python", "scripts/orientation_to_views.py")) if args.json else None
    )
    result = none_for_nan(measure(args.data.resolve()))
    if args.json:
        print_json(result, args)
    else:
        print(format_markdown(result))


if __name__ == "__main__":
    main()
