"""The Rerun sink draws what it is given: read the saved .rrd back and compare with the inputs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import rerun as rr
from rerun.chunk import RrdReader

from skelfuse.sinks.rerun_sink import RerunSink
from skelfuse.skeleton import BONES, N_JOINTS


def _columns(path: Path) -> dict[str, dict[str, list]]:
    """entity path -> component column -> list of rows, over every chunk of the recording."""
    out: dict[str, dict[str, list]] = {}
    for chunk in RrdReader(path).store().stream():
        batch: pa.RecordBatch = chunk.to_record_batch()
        columns = out.setdefault(str(chunk.entity_path), {})
        for name in batch.schema.names:
            if ":" not in name:  # row ids and timelines; only components matter here
                continue
            columns.setdefault(name, []).extend(batch.column(name).to_pylist())
    return out


def test_logged_skeletons_round_trip_in_metres(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    recording = rr.RecordingStream("skelfuse_test")
    path = tmp_path / "sink.rrd"
    recording.save(path)
    sink = RerunSink(recording, ["s0", "s1"])
    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[1, :3, 3] = [1000.0, 2000.0, 500.0]
    sink.log_rig(poses)

    raw = rng.normal(0.0, 500.0, size=(2, 1, N_JOINTS, 3))
    raw[1, 0, 7] = np.nan  # sensor s1 misses the left wrist: its two bones must not be drawn
    fused = rng.normal(0.0, 500.0, size=(1, N_JOINTS, 3))
    sink.set_time(0.5)
    sink.log_sensor_skeletons(raw)
    sink.log_fused(fused, np.array([4]))
    sink.log_metrics(fusion_ms=0.12, error_mm=33.0)
    recording.flush()
    recording.disconnect()

    columns = _columns(path)
    fused_points = np.array(columns["/world/fused/joints"]["Points3D:positions"][0])
    np.testing.assert_allclose(fused_points, fused[0] / 1000.0, rtol=1e-6)
    s1_points = np.array(columns["/world/sensors/s1/skeleton/joints"]["Points3D:positions"][0])
    assert s1_points.shape == (N_JOINTS - 1, 3)
    s1_bones = columns["/world/sensors/s1/skeleton/bones"]["LineStrips3D:strips"][0]
    touching_wrist = int(((BONES[:, 0] == 7) | (BONES[:, 1] == 7)).sum())
    assert len(s1_bones) == len(BONES) - touching_wrist
    translation = np.array(columns["/world/sensors/s1"]["Transform3D:translation"][0])
    np.testing.assert_allclose(translation.reshape(3), [1.0, 2.0, 0.5])
    assert columns["/metrics/fusion_ms"]["Scalars:scalars"][0] == [0.12]
