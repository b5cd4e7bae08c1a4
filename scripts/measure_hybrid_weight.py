"""Hybrid mode: how much should the virtual sensor weigh in the merge? (docs/depth-fusion.md, "Hybrid mode")

Runs the node's own depth stage (``skelfuse.service.depth_stage.DepthStage``, hybrid mode, the simulated
stand-in tracker) offline on simulated multi-person takes: every sensor's skeletons as the crowd simulator
reports them, every sensor's person clouds ray-cast from the true bodies (``sim/depth.py``, NFOV 2x2 binned,
mutual occlusion), the rig's *calibrated* poses (with the profile's calibration error) for fusion. For each
``[depth] virtual_weight`` it prints the mean fused error (evaluation joints, each fused person against the
nearest true person, every instant) next to skeleton-only fusion. Tune on one take, report on another.

    python scripts/measure_hybrid_weight.py                       # crossing (tune), bystander (held out)
    python scripts/measure_hybrid_weight.py --duration 8 --weights 1 2 3

The virtual skeleton comes from the simulated stand-in, not the Body Tracking SDK: the figure says how the
merge treats one more candidate of this quality, not how the SDK's would fare.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from skelfuse.config import parse_rig_config
from skelfuse.eval.depth import SIM_TAKES, Instant, simulated_instants
from skelfuse.rig.instant import GroupFuser
from skelfuse.schema.skeleton import EVAL_JOINTS
from skelfuse.service.depth_stage import CloudBuffer, DepthStage, open_tracker
from skelfuse.sim.crowd import CrowdObservations
from skelfuse.wire import keys
from skelfuse.wire.clouds import encode_person_clouds

RIG = "hw"


def mean_error(obs: CrowdObservations, prepared: list[Instant], mode: str, weight: int) -> float:
    poses = obs.world_from_sensor_calibrated
    eye = [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]
    cfg = parse_rig_config(
        {
            "rig": {"name": RIG},
            # the poses fusion uses are the calibrated ones, passed as arrays below; the config names the sensors
            "sensors": [{"id": sid, "source": "sim", "world_from_sensor": eye} for sid in obs.sensor_ids],
            "fusion": {"mode": mode},
            "depth": {"tracker": "simulated", "virtual_weight": weight},
        }
    )
    stage = None if mode == "skeleton" else DepthStage(cfg, open_tracker(cfg), clouds=CloudBuffer(RIG, cfg.sensor_ids))
    ids, fused_poses = (cfg.sensor_ids, poses) if stage is None else stage.fuser_sensors(poses)
    fuser = GroupFuser(ids, fused_poses, cfg.fusion.fusion_params())
    errors = []
    for instant in prepared:
        if stage is not None:
            for sid, clouds in instant.clouds.items():
                stage.clouds.put(keys.sensor_clouds(RIG, sid), encode_person_clouds(clouds))
        group = instant.group
        frame = (fuser.step(group) if stage is None else stage.step(fuser, group)).frame
        truth = instant.truth
        for fused in frame.positions:
            distance = np.nanmean(np.linalg.norm(truth[:, EVAL_JOINTS] - fused[EVAL_JOINTS], axis=-1), axis=1)
            errors.append(float(distance.min()))
    return float(np.mean(errors))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tune", default="crossing", choices=sorted(SIM_TAKES), help="take the weight is chosen on")
    parser.add_argument("--held-out", default="bystander", choices=sorted(SIM_TAKES), help="take it is reported on")
    parser.add_argument("--duration", type=float, default=4.0, help="seconds of each take")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--weights", type=int, nargs="+", default=[1, 2, 3, 4])
    args = parser.parse_args()
    print("| take | skeleton only | " + " | ".join(f"hybrid, weight {w}" for w in args.weights) + " |")
    print("|---|---:|" + "---:|" * len(args.weights))
    for role, take in (("tune", args.tune), ("held out", args.held_out)):
        tick = time.monotonic()
        prepared, obs = simulated_instants(take, args.duration, args.seed)
        figures = [mean_error(obs, prepared, "skeleton", 1)]
        figures += [mean_error(obs, prepared, "hybrid", w) for w in args.weights]
        cells = " | ".join(f"{e:.1f}" for e in figures)
        print(f"| {take} ({role}, seed {args.seed}, {args.duration:g} s) | {cells} |", flush=True)
        print(f"  ({time.monotonic() - tick:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
