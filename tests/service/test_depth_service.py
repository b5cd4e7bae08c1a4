"""Depth and hybrid modes end to end: real ``python -m skelfuse`` capture workers publishing person clouds and
skeletons over zenoh on loopback, a real fusion node in ``[fusion] mode = "depth"`` / ``"hybrid"``, and the
fused stream checked against the simulator's ground truth.

The tracker is the simulated stand-in (``[depth] tracker = "simulated"``, not the SDK; see
``skelfuse.sim.depth_tracker``): this checks the wiring and the geometry, and that the node says which tracker
runs. The in-process equivalents (and the figures) are in tests/unit/test_depth_live.py.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from service_helpers import RIG, Processes, start_node, worker_args

from skelfuse.config import load_rig_config
from skelfuse.demo import sim_sensor_tables
from skelfuse.schema.skeleton import EVAL_JOINTS
from skelfuse.service.worker import SimSource

pytestmark = pytest.mark.service

TAKE_S = 4.0
"""The workers' take (looped); every worker renders each take frame's depth once."""


def _depth_rig(directory: Path, mode: str) -> Path:
    lines = ["[rig]", f'name = "{RIG}"', "", "[sync]", 'by = "device"', "fps = 15.0", "tolerance_ms = 10.0"]
    lines += ["deadline_ms = 200.0", "", "[node]", "status_period_s = 0.25", "", "[zenoh]"]
    lines += [
        "multicast_scouting = false",
        "",
        "[fusion]",
        f'mode = "{mode}"',
        "",
        "[depth]",
        'tracker = "simulated"',
        "",
    ]
    path = directory / f"rig-{mode}.toml"
    path.write_text("\n".join(lines + sim_sensor_tables(4)), encoding="utf-8")
    return path


# 30-40 s each on this shared machine (five processes render and fuse depth): behind the soak marker
# (`pytest -m soak`). The default suite runs the in-process twins (tests/unit/test_depth_live.py, one with
# the node on a real zenoh session).
@pytest.mark.soak
@pytest.mark.parametrize("mode", ["depth", "hybrid"])
def test_depth_modes_live_against_the_simulators_truth(
    tmp_path: Path, processes: Processes, node_port: int, mode: str
) -> None:
    config = _depth_rig(tmp_path, mode)
    cfg = load_rig_config(config)
    node, listener = start_node(processes, config, node_port)
    try:
        extra = ("--duration", "3.5", "--take-duration", str(TAKE_S))
        workers = [
            processes.start(f"w{i}", *worker_args(config, node_port, sid, *extra, listener=listener))
            for i, sid in enumerate(cfg.sensor_ids)
        ]
        for worker in workers:
            worker.wait(90.0)
            assert worker.returncode == 0, processes.log(worker)
        listener.wait_for(
            lambda: bool(listener.fused) and time.monotonic() - listener.fused[-1][0] > 0.5,
            20.0,
            "the fused stream to settle",
        )
        status = listener.fusion_status()
        assert processes.stop(node) == 0, processes.log(node)
        fused = [frame for _, frame in listener.fused if frame.n_persons]
        published = listener.sensor_frames()
    finally:
        listener.close()
    log = processes.log(node)
    assert f"depth-level fusion, mode {mode}: tracker simulated" in log and "NOT the Body Tracking SDK" in log
    depth = status.info["depth"]
    assert depth["mode"] == mode and depth["tracker"] == "simulated" and not depth["cloud_rejects"]
    with_bodies = sum(1 for f in published if f.n_bodies)
    assert depth["clouds_received"] >= 0.9 * with_bodies and depth["tracked"] >= 25, (depth, with_bodies)

    # The truth of each fused instant: the workers' take (default gesture and seed, take origin 0).
    truth = SimSource(cfg, cfg.sensor_ids[0], take_duration_s=TAKE_S).observations.truth
    errors = []
    for frame in fused:
        n = round(frame.time_us / (1e6 / cfg.sync.fps))
        person = truth[n % truth.shape[0]]
        nearest = np.nanmean(np.linalg.norm(frame.positions[:, EVAL_JOINTS] - person[EVAL_JOINTS], axis=-1), axis=1)
        errors.append(nearest.min())
    assert len(fused) >= 30, f"only {len(fused)} fused frames with a person"
    # The take loops: the person jumps back to its start every 4 s, a new track is born each time (a few
    # instants without output). Measured in process on this take: depth 19 mm, hybrid 12 mm (skeleton 11 mm).
    assert np.median(errors) < 35.0, np.percentile(errors, [50, 90])
    if mode == "hybrid":
        assert fused[-1].sensor_ids[-1] == "virtual"
        # merged into the person except in the first instants of each new track (no previous person to
        # associate the clouds with yet; measured 78%)
        assert np.mean([f.contributors[:, -1].any() for f in fused]) > 0.6
    else:
        assert fused[-1].sensor_ids == cfg.sensor_ids
