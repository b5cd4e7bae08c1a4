"""Is "the view's skeleton faces away from its own sensor" a sign of an unmirrored rear view?

The temporal realignment's rear-view rule (``skelfuse.fusion.realign.realign_temporal(rear_view_cos=)``) trusts
the left/right of a view whose skeleton faces away from its sensor. This script measures that signal:

- simulator: per (frame, view) of simulated takes (the robustness matrix's gestures and facings, the paper's ring
  of 2/3/4 sensors, seeds 0-19: below the matrix's held-out seeds), the cosine between the view's own facing and
  the direction to its sensor (:func:`skelfuse.fusion.realign.facing_cosine`), against the simulator's truth of
  which views are mirrored; per failure family given on the command line;
- real data (../shared/data/azure-kinect-andyj1, where present): the same cosine for every view whose sensor
  position is known (each camera's own frame: the 2-camera take's two files and the 3-camera take's master), and
  for the 3-camera take's subordinates (already in the master frame, positions unknown) the angle between their
  facing and the master view's.

    python scripts/measure_rear_view_signal.py [family ...]      # default: baseline
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np

from skelfuse.fusion.depth.frontal import body_facing
from skelfuse.fusion.realign import facing_cosine
from skelfuse.sim.failures import family_profile
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.observe import facing_away_deg, load_profile, simulate
from skelfuse.sim.rig import paper_rig

GESTURES = ("squat", "random", "hands_up_down", "walking")
THRESHOLDS = (0.0, -0.3, -0.5, -0.7)
DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "azure-kinect-andyj1"
# k4abt camera frame (x right, y down, z forward) -> a z-up frame: (x, z, -y), a rotation.
CAMERA_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def simulated(family: str) -> None:
    cosines, mirrored, angles = [], [], []
    for seed in range(20):
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
    print(f"simulator, family {family}: {cos.size} (frame, view) samples, {mir.mean():.1%} mirrored")
    for threshold in THRESHOLDS:
        below = cos < threshold
        print(
            f"  cos < {threshold:+.1f}: {below.mean():.1%} of samples, {below.sum()} samples, "
            f"of which mirrored {mir[below].mean() if below.any() else 0:.2%} ({(mir & below).sum()})"
        )
    rear = (angle > 110.0) & ~mir
    share = (cos[rear] < -0.3).mean()
    print(f"  unmirrored rear views (> 110 deg from the facing): {rear.sum()}, cos < -0.3 in {share:.1%}")
    print(f"  mirrored views facing their sensor (cos > 0.3): {(cos[mir] > 0.3).mean():.1%}")


def _read_andyj1(path: Path) -> np.ndarray:
    rows = [r for r in list(csv.reader(path.open()))[2:] if len(r) >= 5 and r[1].strip()]
    return np.array([[float(r[2]), float(r[3]), float(r[4])] for r in rows]).reshape(-1, 32, 3) @ CAMERA_TO_Z_UP.T


def real() -> None:
    if not DATA.is_dir():
        print(f"real data: {DATA} not found, skipped")
        return
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
        print(
            f"real, {name} ({len(cos)} frames): facing its own sensor within {angle.min():.0f}-{angle.max():.0f} deg "
            f"(median {np.median(angle):.0f}); cos < -0.7 in {(cos < -0.7).sum()} frames"
        )
    for sub in ("sub1", "sub2"):
        facing = body_facing(_read_andyj1(DATA / "saved_data_2_3dev" / f"joints_gen_{sub}.csv"))
        n = min(len(facing), len(master_facing))
        angle = np.degrees(np.arccos(np.clip(np.sum(facing[:n] * master_facing[:n], axis=-1), -1.0, 1.0)))
        print(
            f"real, 3-camera take, {sub} (master frame, position unknown; {n} frames): its facing within "
            f"{angle.min():.0f}-{angle.max():.0f} deg of the master view's"
        )


def main() -> None:
    for family in sys.argv[1:] or ["baseline"]:
        simulated(family)
    real()


if __name__ == "__main__":
    main()
