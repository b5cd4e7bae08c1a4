"""The demo's live score: the live node's path must fuse the demo's take as well as the offline one.

Regression: `skelfuse demo --duration 10 --seed 0` scored 104.7 mm fused against 94.5 mm
for the best single sensor, while `--offline` on the same take scored 16.9 mm. The capture workers come up
before the take's origin and play the end of the 20 s loop first; at the loop's seam the walking body jumps
267 mm and turns round in one frame, the temporal realignment's anchor (last frame's skeleton) was left
mirrored, and with two rear views mirrored against two front views the recovery rule never fired. The fast
test replays exactly that path without zenoh (the workers' frames, complete frame groups, the node's
GroupFuser, the demo scorer's rule); the soak test runs the real demo.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skelfuse.apps import demo
from skelfuse.config import load_rig_config
from skelfuse.fusion.pipeline import Fuser
from skelfuse.fusion.transform import apply_transform
from skelfuse.rig.grouping import FrameGroup
from skelfuse.rig.instant import GroupFuser
from skelfuse.service.worker import SimSource

LIVE_FACTOR = 1.25
"""The live path may score at most this factor (+ LIVE_SLACK_MM) of the offline path on the same frames."""
LIVE_SLACK_MM = 3.0
SEAM_TAKE_S = 20.0
"""The take length whose loop seam regressed: the walk's end and start lie 267 mm apart and turned round, close
enough for the track to carry on across the seam with its (now stale) realignment anchor. The demo's own take
is shorter now (``demo.DEMO_TAKE_S``); its seam is a jump back that starts a new track, a cold start by design."""


def _live_and_offline(tmp_path: Path, seed: int, preroll_s: float, scored_s: float) -> tuple[dict, dict, dict]:
    rig = demo.write_demo_rig(tmp_path, preset_name="skelfuse")
    cfg = load_rig_config(rig)
    first = SimSource(cfg, cfg.sensor_ids[0], gesture="walking", take_duration_s=SEAM_TAKE_S, seed=seed)
    obs = first.observations
    demo.write_calibration(tmp_path / "calibration.toml", obs.sensor_ids, obs.world_from_sensor_calibrated)
    cfg = load_rig_config(rig)  # now with the simulated calibration, as the demo's node loads it
    poses = cfg.poses()
    sources = [first] + [
        SimSource(cfg, sid, gesture="walking", take_duration_s=SEAM_TAKE_S, seed=seed) for sid in cfg.sensor_ids[1:]
    ]
    fuser = GroupFuser(
        cfg.sensor_ids, np.stack([poses[s] for s in cfg.sensor_ids]), cfg.fusion.fusion_params(), max_persons=8
    )
    n_scored = round(scored_s * cfg.sync.fps)
    births: dict[int, int] = {}
    estimate, truth, instants = [], [], []
    for n in range(-round(preroll_s * cfg.sync.fps), n_scored):  # take origin at instant 0, as in the demo
        frames = {s.sensor_id: f for s in sources if (f := s.frame_at(n)) is not None}
        time_us = min(f.device_time_us for f in frames.values())
        missing = tuple(sid for sid in cfg.sensor_ids if sid not in frames)
        fused = fuser.step(FrameGroup(time_us, frames, missing, not missing)).frame
        seen_by = fused.contributors.sum(axis=1)
        if not seen_by.any():
            continue
        person = int(np.argmax(seen_by))  # the demo scorer's rule: the person most sensors measured
        birth = births.setdefault(int(fused.track_ids[person]), fused.time_us)
        if n >= 0 and fused.time_us - birth >= demo.CONVERGE_S * 1e6:
            estimate.append(fused.positions[person])
            truth.append(obs.truth[n % obs.n_frames])
            instants.append(n % obs.n_frames)
    # a pass of the take starts at instant 0: the person jumps back and gets a new track, scored CONVERGE_S on
    settled = n_scored - round(demo.CONVERGE_S * cfg.sync.fps)
    assert len(estimate) > 0.9 * settled, "the live path output too few frames to score"
    live = demo.group_errors(np.stack(estimate), np.stack(truth))

    world = apply_transform(obs.world_from_sensor_calibrated, obs.positions.astype(np.float64))
    offline_fuser = Fuser(
        cfg.fusion.fusion_params(), n_bodies=1, sensor_positions=obs.world_from_sensor_calibrated[:, :3, 3]
    )
    offline_out = np.stack(
        [offline_fuser.step(world[f][None], obs.confidence[f][None]).positions[0] for f in range(n_scored)]
    )
    offline = demo.group_errors(offline_out[instants], obs.truth[instants])
    singles = [demo.group_errors(world[instants, s], obs.truth[instants]) for s in range(len(obs.sensor_ids))]
    best_single = min(singles, key=lambda errors: errors["all16"])
    return live, offline, best_single


def test_live_path_scores_like_offline_through_the_takes_loop_seam(tmp_path: Path) -> None:
    live, offline, best_single = _live_and_offline(tmp_path, seed=0, preroll_s=3.0, scored_s=6.0)
    assert live["all16"] < best_single["all16"], (live, best_single)
    for group in ("torso", "upper_limb", "lower_limb", "all16"):
        assert live[group] <= LIVE_FACTOR * offline[group] + LIVE_SLACK_MM, (group, live, offline)


@pytest.mark.soak
def test_real_demo_beats_every_sensor_and_stays_near_the_offline_score(tmp_path: Path) -> None:
    # The real thing: 4 capture worker processes, zenoh on loopback, the fusion node; about 25 s wall time.
    live = demo.run_demo(duration_s=10.0, seed=0, rrd_path=tmp_path / "live.rrd", progress=False)
    offline = demo.run_demo_offline(duration_s=10.0, seed=0, rrd_path=tmp_path / "offline.rrd", progress=False)
    fused, single = live.error_fused_mm["all16"], live.error_best_single_sensor_mm["all16"]
    assert fused < 0.5 * single, (live.error_fused_mm, live.error_best_single_sensor_mm)
    assert fused <= 2.0 * offline.error_fused_mm["all16"] + 5.0, (live.error_fused_mm, offline.error_fused_mm)
