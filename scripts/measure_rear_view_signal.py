"""Is "the view's skeleton faces away from its own sensor" a sign of an unmirrored rear view?

The temporal realignment's rear-view rule (``skelfuse.fusion.realign.realign_temporal(rear_view_cos=)``) trusts
the left/right of a view whose skeleton faces away from its sensor. This script measures that signal:

- simulator: per (frame, view) of simulated takes (the robustness matrix's gestures and facings, the paper's ring
  of 2/3/4 sensors, seeds 0-19 by default: below the matrix's held-out seeds), the cosine between the view's own
  facing and the direction to its sensor (:func:`skelfuse.fusion.reference.realign.facing_cosine`), against the
  simulator's truth of which views are mirrored; per failure family given on the command line;
- real data (../shared/data/azure-kinect-andyj1, where present): the same cosine for every view whose sensor
  position is known (each camera's own frame: the 2-camera take's two files and the 3-camera take's master), and
  for the 3-camera take's subordinates (already in the master frame, positions unknown) the angle between their
  facing and the master view's.

    python scripts/measure_rear_view_signal.py [family ...] [--seeds 20] [--json]   # default: baseline

``--json`` prints the counts with the run's stamp (docs/evidence.md, "Rear views that face away", renders them
with :func:`format_markdown`).
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.cli.common import print_json
from skelfuse.cli.stamp import RunStamp
from skelfuse.fusion.depth.frontal import body_facing
from skelfuse.fusion.reference.realign import facing_cosine
from skelfuse.sim.failures import family_profile
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.observe import facing_away_deg, load_profile, simulate
from skelfuse.sim.rig import paper_rig

GESTURES = ("squat", "random", "hands_up_down", "walking")
THRESHOLDS = (0.0, -0.3, -0.5, -0.7)
DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "azure-kinect-andyj1"
# k4abt camera frame (x right, y down, z forward) -> a z-up frame: (x, z, -y), a rotation.
CAMERA_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def simulated(family: str, seeds: int) -> dict[str, Any]:
    """Per threshold: samples whose cosine lies below it, and how many of them are mirrored; the unmirrored rear
    views' share below -0.3; the mirrored views' share facing their sensor."""
    cosines, mirrored, angles = [], [], []
    for seed in range(seeds):
        for n_sensors in (2, 3, 4):
            rng = np.random.default_rng([seed, n_sensors])
            motion = make_gesture(
                GESTURES[seed % 4], duration_s=10.0, fps=30.0, facing_deg=float(rng.uniform(0, 360)), seed=seed
            )
            sensors = paper_rig(n_sensors)
            obs = simulate(motion, sensors, family_profile(load_profile(), family), seed=seed)
            world = obs.positions_world(calibrated=True)  # (T, S, J, 3)
            cos = facing_cosine(world, obs.world_from_sensor_calibrated[:, :3, 3])
            for s, sensor in enumerate(sensors):
                seen = obs.tracked[:, s]
                cosines.append(cos[seen, s])
                mirrored.append(obs.mirrored[seen, s])
                angles.append(facing_away_deg(obs.truth, sensor.position_mm)[seen])
    cos, mir, angle = np.concatenate(cosines), np.concatenate(mirrored), np.concatenate(angles)
    rear = (angle > 110.0) & ~mir
    return {
        "family": family,
        "samples": int(cos.size),
        "mirrored": int(mir.sum()),
        "below": {f"{t:+.1f}": [int((cos < t).sum()), int((mir & (cos < t)).sum())] for t in THRESHOLDS},
        "rear_unmirrored": int(rear.sum()),
        "rear_unmirrored_below_-0.3": int((cos[rear] < -0.3).sum()),
        "mirrored_facing_sensor": int((cos[mir] > 0.3).sum()),
    }


def _read_andyj1(path: Path) -> np.ndarray:
    rows = [r for r in list(csv.reader(path.open()))[2:] if len(r) >= 5 and r[1].strip()]
    return np.array([[float(r[2]), float(r[3]), float(r[4])] for r in rows]).reshape(-1, 32, 3) @ CAMERA_TO_Z_UP.T


def real() -> list[dict[str, Any]]:
    """Per real view: the angle between its facing and the direction to its sensor (own-frame views), or to the
    master view's facing (the 3-camera take's subordinates); none where the data is not there."""
    if not DATA.is_dir():
        return []
    rows = []
    own_frame = {
        "2-camera take, master": DATA / "extrinsic_calculation" / "joints_sync_1.csv",
        "2-camera take, subordinate": DATA / "extrinsic_calculation" / "joints_sync_2.csv",
        "3-camera take, master": DATA / "saved_data_2_3dev" / "joints_gen_master.csv",
    }
    master_facing = None
    for name, path in own_frame.items():
        skeletons = _read_andyj1(path)
        if "3-camera" in name:
            skeletons = skeletons[::2]  # the master file holds each frame twice
            master_facing = body_facing(skeletons)
        cos = facing_cosine(skeletons[:, None], np.zeros((1, 3)))[:, 0]  # the camera at its own origin
        angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        rows.append({"view": name, "against": "its own sensor", "frames": len(cos), "angle_deg": _spread(angle)})
    for sub in ("sub1", "sub2"):
        facing = body_facing(_read_andyj1(DATA / "saved_data_2_3dev" / f"joints_gen_{sub}.csv"))
        n = min(len(facing), len(master_facing))
        angle = np.degrees(np.arccos(np.clip(np.sum(facing[:n] * master_facing[:n], axis=-1), -1.0, 1.0)))
        rows.append({"view": f"3-camera take, {sub}", "against": "the master view's facing", "frames": n,
                     "angle_deg": _spread(angle)})  # fmt: skip
    return rows


def _spread(angle: np.ndarray) -> list[float]:
    return [float(angle.min()), float(np.median(angle)), float(angle.max())]


def format_markdown(result: dict[str, Any]) -> str:
    """One row per family (thresholds -0.5 and -0.7, the rear views' share below -0.3), then the real views."""
    lines = [
        f"Seeds 0-{result['seeds'] - 1}, 2/3/4 sensors on the paper's ring, 10 s takes; the cosine between a view's "
        "own facing and the direction to its sensor, against the simulator's truth of which views are mirrored.",
        "",
        "| family | (frame, view) samples | below -0.5: mirrored | below -0.7: mirrored "
        "| unmirrored rear views (>110°) below -0.3 |",
        "|---|---:|---:|---:|---:|",
    ]
    for row in result["families"]:
        cells = [f"{row['below'][t][1]} of {row['below'][t][0]}" for t in ("-0.5", "-0.7")]
        rear = row["rear_unmirrored_below_-0.3"] / max(row["rear_unmirrored"], 1)
        lines.append(f"| {row['family']} | {row['samples']} | " + " | ".join(cells) + f" | {rear:.1%} |")
    if result["real"]:
        lines += [
            "",
            "Real views (../shared/data/azure-kinect-andyj1), facing angle, degrees (min / median / max):",
            "",
        ]
        lines += [f"- {r['view']} ({r['frames']} frames), against {r['against']}: "
                  + " / ".join(f"{a:.0f}" for a in r["angle_deg"]) for r in result["real"]]  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("families", nargs="*", default=["baseline"], help="failure families (default: baseline)")
    parser.add_argument("--seeds", type=int, default=20, help="seeds 0..N-1 per rig size (20)")
    parser.add_argument("--json", action="store_true", help="print the counts as JSON, stamped")
    args = parser.parse_args()
    program = ("python", "scripts/measure_rear_view_signal.py")
    args.stamp = RunStamp.begin(sys.argv[1:], program=program) if args.json else None
    result = {"seeds": args.seeds, "families": [simulated(f, args.seeds) for f in args.families], "real": real()}
    if args.json:
        print_json(result, args)
    else:
        print(format_markdown(result))


if __name__ == "__main__":
    main()
