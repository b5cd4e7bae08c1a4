"""The Rerun sink draws what it is given: read the saved .rrd back and compare with the inputs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import rerun as rr
from rerun.chunk import RrdReader

from skelfuse.fusion.depth.cloud import MergedCloud
from skelfuse.schema.skeleton import BONES, N_JOINTS
from skelfuse.sinks.rerun_sink import SENSOR_COLORS, RerunSink


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
    # The pose sits beside the world-frame skeleton, never above it (a transform applies to the subtree).
    assert not any("Transform3D" in name for name in columns.get("/world/sensors/s1", {}))
    translation = np.array(columns["/world/sensors/s1/pose"]["Transform3D:translation"][0])
    np.testing.assert_allclose(translation.reshape(3), [1.0, 2.0, 0.5])
    assert columns["/metrics/fusion_ms"]["Scalars:scalars"][0] == [0.12]


def test_every_body_and_every_person_is_drawn_one_colour_per_track(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    recording = rr.RecordingStream("skelfuse_test")
    path = tmp_path / "people.rrd"
    recording.save(path)
    sink = RerunSink(recording, ["s0", "s1"])
    sink.log_rig(np.tile(np.eye(4), (2, 1, 1)))
    raw = rng.normal(0.0, 500.0, size=(2, 2, N_JOINTS, 3))
    raw[1, 1] = np.nan  # s1 sees one body, s0 two
    fused = rng.normal(0.0, 500.0, size=(2, N_JOINTS, 3))
    sink.set_time(0.0)
    sink.log_sensor_skeletons(raw)
    sink.log_fused(fused, np.array([3, 4]))
    recording.flush()
    recording.disconnect()

    columns = _columns(path)
    assert len(columns["/world/sensors/s0/skeleton/joints"]["Points3D:positions"][0]) == 2 * N_JOINTS
    assert len(columns["/world/sensors/s1/skeleton/joints"]["Points3D:positions"][0]) == N_JOINTS
    joints = columns["/world/fused/joints"]
    np.testing.assert_allclose(np.array(joints["Points3D:positions"][0]), fused.reshape(-1, 3) / 1000.0, rtol=1e-6)
    colors = np.array(joints["Points3D:colors"][0])
    assert len(set(colors[:N_JOINTS].tolist())) == 1 and len(set(colors[N_JOINTS:].tolist())) == 1
    assert colors[0] != colors[N_JOINTS]  # two track ids, two colours


def test_person_clouds_are_drawn_in_metres_coloured_by_sensor(tmp_path: Path) -> None:
    recording = rr.RecordingStream("skelfuse_test")
    path = tmp_path / "clouds.rrd"
    recording.save(path)
    sink = RerunSink(recording, ["s0", "s1", "s2"])
    cloud = MergedCloud(np.array([[1000.0, 0.0, 500.0], [0.0, 2000.0, 1500.0], [5.0, 5.0, 5.0]]), np.array([0, 2, 1]))
    sink.set_time(0.1)
    sink.log_person_clouds([cloud], [7])
    recording.flush()
    recording.disconnect()
    columns = _columns(path)["/world/fused/clouds/7"]
    np.testing.assert_allclose(np.array(columns["Points3D:positions"][0]), cloud.points / 1000.0, rtol=1e-6)
    expected = [int.from_bytes(bytes([*SENSOR_COLORS[i], 255]), "big") for i in (0, 2, 1)]
    assert columns["Points3D:colors"][0] == expected


def test_fused_people_stand_out_and_everyone_is_labelled(tmp_path: Path) -> None:
    from skelfuse.sinks import rerun_sink as sink_module

    # Every fused colour is far from every sensor colour (RGB distance), and the fused skeleton is the thicker.
    gaps = np.linalg.norm(
        sink_module.TRACK_COLORS[:, None].astype(float) - sink_module.SENSOR_COLORS[None].astype(float), axis=-1
    )
    assert gaps.min() > 60.0, gaps.min()
    assert sink_module.FUSED_BONE_RADIUS_M >= 3 * sink_module.SENSOR_BONE_RADIUS_M

    recording = rr.RecordingStream("skelfuse_test")
    path = tmp_path / "labels.rrd"
    recording.save(path)
    sink = RerunSink(recording, ["left", "right"])
    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[1, :3, 3] = [2000.0, 0.0, 1000.0]
    sink.log_rig(poses)
    fused = np.zeros((2, N_JOINTS, 3))
    fused[1] += 1000.0
    fused[1, sink_module.HEAD] = np.nan  # no head estimate: no label for this person
    sink.set_time(0.0)
    sink.log_sensor_skeletons(np.zeros((2, 1, N_JOINTS, 3)))
    sink.log_fused(fused, np.array([7, 8]))
    recording.flush()
    recording.disconnect()

    columns = _columns(path)
    assert columns["/world/sensors/right/label"]["Points3D:labels"][0] == ["right"]
    np.testing.assert_allclose(columns["/world/sensors/right/label"]["Points3D:positions"][0], [[2.0, 0.0, 1.0]])
    assert columns["/world/fused/labels"]["Points3D:labels"][0] == ["person 7"]
    sensor_colour = np.array(columns["/world/sensors/left/skeleton/bones"]["LineStrips3D:colors"][0])
    assert (sensor_colour & 0xFF < 255).all()  # RGBA packed: the sensors are half transparent


def test_the_camera_looks_at_the_middle_of_the_rig() -> None:
    from skelfuse.sim.rig import paper_rig
    from skelfuse.sinks.rerun_sink import rig_eye

    poses = np.stack([s.world_from_sensor for s in paper_rig(4)])
    poses[:, 0, 3] += 5000.0  # the whole rig 5 m along x
    eye = rig_eye(poses)
    target = np.array(eye.look_target.as_arrow_array().to_pylist()[0])
    position = np.array(eye.position.as_arrow_array().to_pylist()[0])
    np.testing.assert_allclose(target, [5.0, 0.0, 0.9], atol=1e-6)
    assert 2.2 < np.linalg.norm(position[:2] - target[:2]) < 6.0 and position[2] > 1.5  # outside, above the rig
