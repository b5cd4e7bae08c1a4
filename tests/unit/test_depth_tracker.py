"""The tracker call of the depth-level fusion against the fake libk4a / libk4abt compiled from C.

The fake tracker, in echo mode, computes its one body from what it was given: the mean of the capture's depth
pixels lifted with the depth intrinsics of the calibration the tracker was created with, read row by row with
the image's stride; the pixel count, mean IR and stride; the calibration's depth mode, resolution, model type,
parameter count and metric radius. The test recomputes all of it with numpy, so a wrong stride, a wrong
calibration layout or value, a lost timestamp or a wrong transform back to the world shows. Both fakes are our
transcription of the SDK's headers (tests/fake_k4a/k4a_abi.h), not the SDK.
"""

from __future__ import annotations

import ctypes

import numpy as np
import pytest
from fake_sdk import build_fake_libs_or_skip, harness

from skelfuse.fusion.camera import Intrinsics, lift_mask
from skelfuse.fusion.depth.cloud import clouds_to_world, person_clouds
from skelfuse.fusion.depth.pipeline import fuse_person_depth
from skelfuse.fusion.depth.render import to_k4a_depth, to_k4a_ir
from skelfuse.schema.errors import ConfigError
from skelfuse.schema.skeleton import J
from skelfuse.sim.depth import render_rig
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.motion import facing_deg
from skelfuse.sim.rig import paper_rig
from skelfuse.sources import k4a_abi, k4abt
from skelfuse.sources.depth_tracker import FRAME_PERIOD_US, VirtualCameraTracker
from skelfuse.sources.k4abt import K4abtLibrary, TrackerSettings, load_k4a, virtual_calibration

K = Intrinsics.azure_kinect_nfov()
RIG = paper_rig()
POSES = np.stack([s.world_from_sensor for s in RIG])


@pytest.fixture(scope="module")
def fakes(tmp_path_factory):
    libs = build_fake_libs_or_skip(tmp_path_factory.mktemp("fake_k4a_depth"), "1.1", "the tracker call runs against")
    fake_k4abt = harness.FakeK4abt(libs.k4abt)
    fake_k4a = harness.FakeK4a(libs.k4a)
    fake_k4a.lib.fake_k4a_images_alive.restype = ctypes.c_int
    return load_k4a(libs.k4a), K4abtLibrary.load(libs.k4abt), fake_k4abt, fake_k4a


@pytest.fixture
def echo(fakes):
    k4a, library, fake_k4abt, fake_k4a = fakes
    fake_k4abt.reset()
    fake_k4abt.lib.fake_k4abt_set_echo(1)
    return k4a, library, fake_k4abt, fake_k4a


_VIEWS: dict[tuple[float, int], tuple] = {}


def _view(facing: float, frame: int):
    """(truth, PersonDepthView) of one person; cached, the rendering is the slow part."""
    if (facing, frame) not in _VIEWS:
        _VIEWS[facing, frame] = _make_view(facing, frame)
    return _VIEWS[facing, frame]


def _make_view(facing: float, frame: int):
    truth = make_gesture("hands_up_down", duration_s=2.0, facing_deg=facing).positions[frame]
    clouds, irs = [], []
    for depth_frame in render_rig(RIG, truth[None], seed=frame):
        (cloud,) = person_clouds(depth_frame.depth, depth_frame.body_index, K, voxel_mm=15.0, ir=depth_frame.ir)
        clouds.append(cloud.points)
        irs.append(cloud.ir)
    assert len(clouds_to_world(clouds, POSES)) == 4
    return truth, fuse_person_depth(clouds, POSES, K, skeleton_facing_deg=float(facing_deg(truth)), ir=irs)


def test_the_calibration_struct_matches_the_c_transcription(fakes) -> None:
    _, _, _, fake_k4a = fakes

    def layout(name: str) -> int:
        fake_k4a.lib.fake_k4a_layout.restype = ctypes.c_size_t
        return int(fake_k4a.lib.fake_k4a_layout(name.encode()))

    assert layout("calibration") == ctypes.sizeof(k4abt.K4aCalibration)
    for field in ("color_camera_calibration", "extrinsics", "depth_mode", "color_resolution"):
        assert layout(f"calibration.{field}") == getattr(k4abt.K4aCalibration, field).offset, field
    assert layout("calibration_camera") == ctypes.sizeof(k4abt.K4aCalibrationCamera)
    for field in ("intrinsics", "resolution_width", "resolution_height", "metric_radius"):
        assert layout(f"calibration_camera.{field}") == getattr(k4abt.K4aCalibrationCamera, field).offset, field
    assert layout("intrinsics") == ctypes.sizeof(k4abt.K4aCalibrationIntrinsics)
    assert layout("intrinsics.parameter_count") == k4abt.K4aCalibrationIntrinsics.parameter_count.offset
    assert layout("intrinsics.parameters") == k4abt.K4aCalibrationIntrinsics.parameters.offset
    assert layout("extrinsics") == ctypes.sizeof(k4abt.K4aCalibrationExtrinsics) == 48
    with pytest.raises(ConfigError, match="no k4a depth mode"):
        virtual_calibration(500.0, 500.0, 300.0, 300.0, 600, 600)


def test_a_virtual_image_goes_through_the_tracker_and_its_skeleton_comes_back_to_the_world(echo) -> None:
    k4a, library, fake_k4abt, fake_k4a = echo
    truth, view = _view(0.0, 20)
    captures_before = fake_k4a.captures_alive()
    with VirtualCameraTracker(k4a, library, K, TrackerSettings(processing_mode="cpu")) as tracker:
        assert tracker.submit(view, timeout_ms=10)
        # the tracker holds its own reference to the capture until its body frame is released (as the SDK's
        # k4abt_frame_get_capture implies): the binding's is given back, the buffers stay pinned till then
        assert fake_k4a.captures_alive() == captures_before + 1
        found = tracker.collect(timeout_ms=50)
        # popped and released: the capture and its images are gone, the buffers unpinned
        assert fake_k4a.captures_alive() == captures_before
        assert fake_k4a.lib.fake_k4a_images_alive() == 0 and not k4a_abi._PINNED  # the pinned-buffer registry
    assert found is not None and found.device_time_us == FRAME_PERIOD_US and found.body_id == 1
    # What the fake computed from the image, recomputed here from the same image.
    depth = to_k4a_depth(view.image.depth_mm)
    valid = depth > 0
    centroid = lift_mask(depth, valid, K).mean(axis=0)
    np.testing.assert_allclose(found.positions_camera[0], centroid, rtol=1e-5)
    assert found.positions_camera[1, 0] == valid.sum()
    assert found.positions_camera[1, 1] == pytest.approx(to_k4a_ir(view.image.ir)[valid].mean(), rel=1e-5)
    assert found.positions_camera[1, 2] == 640 * 2  # DEPTH16 rows, no padding
    np.testing.assert_array_equal(found.positions_camera[2], [2, 640, 576])  # NFOV unbinned
    np.testing.assert_allclose(found.positions_camera[3], [4, 14, k4abt.NFOV_METRIC_RADIUS], rtol=1e-6)
    # ... and back in the world through the view's inverse warp: on the person, in front of the pelvis.
    np.testing.assert_allclose(found.positions_world[0], view.frontal.to_world(centroid), atol=0.05)
    assert np.linalg.norm(found.positions_world[0, :2] - truth[J["PELVIS"], :2]) < 250.0
    stats = fake_k4abt.stats()
    assert stats.created == 1 and stats.destroyed == 1 and stats.bad_captures == 0 and stats.infinite_waits == 0
    assert stats.config_processing_mode == 1


def test_pipelined_results_each_return_through_their_own_view(echo) -> None:
    k4a, library, _, _ = echo
    views = [_view(facing, 20)[1] for facing in (0.0, 120.0)]
    with VirtualCameraTracker(k4a, library, K, TrackerSettings()) as tracker:
        assert all(tracker.submit(view, timeout_ms=10) for view in views)
        assert tracker.pending == 2
        results = [tracker.collect(timeout_ms=50) for _ in views]
    for number, (view, found) in enumerate(zip(views, results, strict=True), start=1):
        assert found.device_time_us == number * FRAME_PERIOD_US
        depth = to_k4a_depth(view.image.depth_mm)
        centroid = lift_mask(depth, depth > 0, K).mean(axis=0)
        np.testing.assert_allclose(found.positions_world[0], view.frontal.to_world(centroid), atol=0.05)
        # every joint through its own view's inverse warp (float32 in, float64 out) ...
        np.testing.assert_allclose(found.positions_world, view.frontal.to_world(found.positions_camera), atol=1e-9)
    # ... and not the other's: the two people face different ways, so a mix-up moves points by metres
    crossed = views[0].frontal.to_world(results[1].positions_camera) - results[1].positions_world
    assert np.linalg.norm(crossed, axis=1).max() > 1000.0


def test_a_capture_the_tracker_cannot_read_is_refused(echo) -> None:
    k4a, library, fake_k4abt, _ = echo
    _, view = _view(0.0, 20)
    binned = Intrinsics.azure_kinect_nfov(binned=True)  # the tracker expects 320 x 288, the image is 640 x 576
    with VirtualCameraTracker(k4a, library, binned, TrackerSettings()) as tracker:
        with pytest.raises(k4abt.TrackerFailedError):
            tracker.submit(view)
    assert fake_k4abt.stats().bad_captures == 1


@pytest.mark.live
def test_the_nodes_depth_stage_runs_the_sdk_adapter_one_tracker_per_person(echo, tmp_path, monkeypatch) -> None:
    """``[depth] tracker = "k4abt"``: the node's depth stage loads the SDK (here the fakes, found the way the
    node finds the SDK: SKELFUSE_K4A_LIBRARY / SKELFUSE_K4ABT_LIBRARY), says so, creates one tracker per track
    id, and outputs what the tracker found mapped back to the world (the echo body's joint 0: the centroid of
    the virtual depth image, on the person); everything is released when the stage closes."""
    from skelfuse.apps.demo import sim_sensor_tables
    from skelfuse.config import load_rig_config
    from skelfuse.service.depth_stage import depth_stage_for
    from skelfuse.service.node import FusionCore
    from skelfuse.service.worker import SimSource
    from skelfuse.sources.k4abt import K4A_LIBRARY_ENV, K4ABT_LIBRARY_ENV
    from skelfuse.wire import keys
    from skelfuse.wire.clouds import encode_person_clouds
    from skelfuse.wire.codec import encode_sensor_frame

    k4a, library, fake_k4abt, fake_k4a = echo
    monkeypatch.setenv(K4A_LIBRARY_ENV, k4a._name)
    monkeypatch.setenv(K4ABT_LIBRARY_ENV, str(library.path))
    config = tmp_path / "rig.toml"
    lines = ["[rig]", 'name = "k"', "[fusion]", 'mode = "depth"', "[depth]", 'tracker = "k4abt"', ""]
    config.write_text("\n".join(lines + sim_sensor_tables(4)), encoding="utf-8")
    cfg = load_rig_config(config)
    sources = [SimSource(cfg, sid, gesture="walking", take_duration_s=0.5, seed=0) for sid in cfg.sensor_ids]
    stage = depth_stage_for(cfg)
    assert stage.tracker.name == "k4abt" and str(library.path) in stage.describe()
    core = FusionCore(cfg, depth=stage)
    captures_before = fake_k4a.captures_alive()
    outputs = []
    for n in range(900, 908):  # 900 = 60 x 15: take frames 0..7
        for source in sources:
            frame = source.frame_at(n)
            stage.clouds.put(keys.sensor_clouds("k", source.sensor_id), encode_person_clouds(source.clouds_at(frame)))
            outputs += core.receive(keys.sensor_skeletons("k", source.sensor_id), encode_sensor_frame(frame), n * 10**6)
    outputs += core.flush()
    fused = [out.frame for out in outputs if out.frame.n_persons]
    assert len(fused) >= 5 and stage.counters.tracker_misses == 0
    truth = sources[0].observations.truth
    for frame in fused:
        pelvis = truth[round(frame.time_us / (1e6 / 30)) % truth.shape[0], J["PELVIS"]]
        assert np.linalg.norm(frame.positions[0, 0, :2] - pelvis[:2]) < 250.0  # the image's centroid, on the person
    stats = fake_k4abt.stats()
    assert stats.created == 1 and stats.infinite_waits == 0  # one person, one tracker, every wait bounded
    stage.close()
    stats = fake_k4abt.stats()
    assert stats.destroyed == 1 and stats.frames_alive == 0 and fake_k4a.captures_alive() == captures_before
