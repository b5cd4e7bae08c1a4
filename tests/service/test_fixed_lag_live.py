"""``[fusion] fixed_lag_frames`` end to end: a real node process with sim workers publishes, N instants late,
what offline fusion of the same frames gives with the fixed-lag smoother (``fuse_recording(...,
smoother_lag=N)``), and says at start the latency this adds."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from service_helpers import RIG, Processes, publish_common_stretch, start_node, write_rig

from skelfuse.config import load_rig_config
from skelfuse.recording import RecordingWriter, fuse_recording

pytestmark = [pytest.mark.live, pytest.mark.service]

LAG = 3
SENSORS = ("capture_0", "capture_1")


def test_the_live_node_publishes_the_offline_fixed_lag_smoother(
    tmp_path: Path, processes: Processes, node_port: int
) -> None:
    config = write_rig(tmp_path, deadline_ms=200.0, n_sensors=len(SENSORS))
    config.write_text(config.read_text(encoding="utf-8") + f"\n[fusion]\nfixed_lag_frames = {LAG}\n", encoding="utf-8")
    node, listener = start_node(processes, config, node_port)

    try:
        publish_common_stretch(processes, listener, config, node_port, SENSORS, 90)
        assert listener.fusion_status().info["fixed_lag_ms"] == 100.0
        assert processes.stop(node) == 0, processes.log(node)  # the stop flushes the instants it still holds
        listener.wait_for(
            lambda: bool(listener.fused) and time.monotonic() - listener.fused[-1][0] > 0.5, 30.0, "the last frames"
        )
        frames = listener.sensor_frames()
        live = [frame for _, frame in listener.fused]
    finally:
        listener.close()
    assert "fixed-lag smoothing over 3 frames adds 100.0 ms of latency" in processes.log(node)

    cfg = load_rig_config(config)
    path = tmp_path / "published.mcap"
    with RecordingWriter(path, rig=RIG, sensor_ids=cfg.sensor_ids) as writer:
        for frame in sorted(frames, key=lambda f: f.host_time_ns):
            writer.write(frame)
    offline = {
        f.time_us: f for f in fuse_recording(path, rig_config=cfg, progress=False, smoother="rts", smoother_lag=LAG)
    }
    causal = {f.time_us: f for f in fuse_recording(path, rig_config=cfg, progress=False, smoother="none")}
    both = [f for f in live if f.time_us in offline]
    assert len(both) >= 0.95 * len(live) and len(both) >= 60, (len(both), len(live), len(offline))
    moved = 0
    for frame in both:
        expected = offline[frame.time_us]
        assert frame.n_persons == expected.n_persons  # the live node's track ids count from its start time
        np.testing.assert_allclose(frame.positions, expected.positions, rtol=0, atol=1e-9, equal_nan=True)
        np.testing.assert_array_equal(frame.n_agree, expected.n_agree)
        moved += not np.allclose(frame.positions, causal[frame.time_us].positions, atol=0.01, equal_nan=True)
    assert moved >= len(both) // 2, "the published frames are the causal ones: nothing was smoothed"
