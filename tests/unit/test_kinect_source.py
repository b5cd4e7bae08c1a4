"""The Kinect device source, rig start order, reconnect loop, recorded sources and device listing.

Hardware is replaced by a fake ``pyk4a`` module (tests/fake_k4a/harness.py) whose captures and calibrations
carry real PyCapsules around handles of a fake libk4a, and a fake libk4abt compiled from C with gcc.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from fake_sdk import build_fake_libs_or_skip, harness

from skelfuse.config import load_rig_config
from skelfuse.schema.errors import ServiceError
from skelfuse.schema.frames import SensorFrame
from skelfuse.sources import devices, kinect
from skelfuse.sources.k4abt import K4abtLibrary, TrackerSettings
from skelfuse.sources.kinect import (
    DeviceSettings,
    EndOfStream,
    KinectSource,
    KinectUnavailable,
    MkvSource,
    RecordedFileSource,
    SensorDisconnected,
    SensorNotFound,
    SkeletonSource,
    kinect_start_order,
    start_rig,
)
from skelfuse.sources.reconnect import Backoff, WorkerFrameSource, run_with_reconnect
from waiting import SCHEDULING_ALLOWANCE_S

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "config" / "rig-example-kinect-4.toml"


@pytest.fixture(scope="module")
def fake_libs(tmp_path_factory):
    return build_fake_libs_or_skip(tmp_path_factory.mktemp("fake_k4a_source"), "1.1", "these tests run against")


@pytest.fixture
def stack(fake_libs, monkeypatch):
    monkeypatch.setenv("FAKE_K4A_DEVICES", "000111:0:1;000222:1:0")  # what the fake libk4a reports
    fake = harness.FakeK4abt(fake_libs.k4abt)
    fake.reset()
    world = harness.FakeWorld(k4a=harness.FakeK4a(fake_libs.k4a), serials=["000111", "000222"])
    return world, harness.make_fake_pyk4a(world), K4abtLibrary.load(fake_libs.k4abt), fake


def _script(fake, n_frames, *, start_us=1_000_000, skip=()):
    rng = np.random.default_rng(7)
    frames = []
    for index in range(n_frames):
        if index in skip:
            continue
        positions = rng.normal(0, 500, (1, 32, 3)).astype(np.float32)
        orientations = rng.normal(0, 1, (1, 32, 4)).astype(np.float32)
        confidence = np.full((1, 32), 2, np.uint8)
        device_us = start_us + index * 33_333
        fake.script_frame(device_us, time.monotonic_ns(), np.array([7], np.uint32), positions, orientations, confidence)
        frames.append((device_us, positions))
    return frames


def test_device_settings_from_the_example_rig():
    cfg = load_rig_config(EXAMPLE)
    master = DeviceSettings.from_sensor(cfg.sensors[0], cfg.sync.fps)
    sub = DeviceSettings.from_sensor(cfg.sensors[2], cfg.sync.fps)
    assert (master.serial, master.sync_role, master.subordinate_delay_us) == ("000123412512", "master", 0)
    assert master.fps == 30
    assert (sub.sync_role, sub.subordinate_delay_us) == ("subordinate", 320)
    assert sub.tracker.model_path.endswith("dnn_model_2_0_lite_op11.onnx") and sub.tracker.processing_mode == "cuda"
    pyk4a_cfg = sub.pyk4a_config(harness.make_fake_pyk4a(harness.FakeWorld(k4a=None)))
    assert pyk4a_cfg.color_resolution == harness.ColorResolution.OFF  # colour off unless asked
    assert pyk4a_cfg.depth_mode == harness.DepthMode.NFOV_UNBINNED and pyk4a_cfg.camera_fps == harness.FPS.FPS_30
    assert pyk4a_cfg.wired_sync_mode == harness.WiredSyncMode.SUBORDINATE
    assert pyk4a_cfg.subordinate_delay_off_master_usec == 320 and pyk4a_cfg.synchronized_images_only is False
    binned = DeviceSettings(serial="x", depth_mode="NFOV_2X2BINNED", color_resolution="720P", sync_role="master")
    cfg_b = binned.pyk4a_config(harness.make_fake_pyk4a(harness.FakeWorld(k4a=None)))
    assert cfg_b.depth_mode == harness.DepthMode.NFOV_2X2BINNED
    assert cfg_b.color_resolution == harness.ColorResolution.RES_720P
    assert cfg_b.wired_sync_mode == harness.WiredSyncMode.MASTER


def test_subordinates_start_before_the_master():
    cfg = load_rig_config(EXAMPLE)
    order = kinect_start_order(cfg.sensors)
    assert [s.sync.role for s in order] == ["subordinate", "subordinate", "subordinate", "master"]
    assert [s.sync.delay_us for s in order[:3]] == [160, 320, 480]
    opened = []

    class Recorder:
        def __init__(self, name, fail=False):
            self.sensor_id, self.fail, self.closed = name, fail, False

        def open(self):
            if self.fail:
                raise SensorNotFound(self.sensor_id)
            opened.append(self.sensor_id)

        def read(self, timeout_s):
            return None

        def close(self):
            self.closed = True

    start_rig(
        [
            ("master", Recorder("m")),
            ("subordinate", Recorder("s1")),
            ("standalone", Recorder("x")),
            ("subordinate", Recorder("s2")),
        ]
    )
    assert opened == ["s1", "s2", "x", "m"]
    s1, bad = Recorder("s1"), Recorder("m", fail=True)
    with pytest.raises(SensorNotFound):
        start_rig([("master", bad), ("subordinate", s1)])
    assert s1.closed  # a failed rig start releases what it opened


def test_device_source_opens_by_serial_and_streams_bit_exact(stack):
    world, pyk4a, library, fake = stack
    expected = _script(fake, 6, skip={3})  # a dropped frame: a sequence gap
    settings = DeviceSettings(
        serial="000222",
        sync_role="subordinate",
        subordinate_delay_us=160,
        tracker=TrackerSettings(processing_mode="cuda", temporal_smoothing=0.1),
    )
    source = KinectSource(settings, sensor_id="left", pyk4a=pyk4a, k4abt=library)
    assert isinstance(source, SkeletonSource)
    source.open()
    try:
        device = world.opened[-1]
        assert device._device_id == 1 and device.is_running  # serial 000222 is device #1
        assert device._config.wired_sync_mode == harness.WiredSyncMode.SUBORDINATE
        assert not world.opened[0].opened  # device #0 was opened to read its serial, then closed
        frames = []
        for _ in range(20):
            frame = source.read(0.01)
            if frame is not None:
                frames.append(frame)
            if len(frames) == len(expected):
                break
    finally:
        source.close()
    assert [f.device_time_us for f in frames] == [us for us, _ in expected]
    assert [f.sequence for f in frames] == [0, 1, 2, 4, 5]
    for frame, (_, positions) in zip(frames, expected, strict=True):
        frame.validate()
        assert frame.sensor_id == "left" and frame.body_ids.tolist() == [7]
        assert np.array_equal(frame.positions.view(np.uint32), positions.view(np.uint32))
        assert abs(frame.host_time_ns - time.time_ns()) < 5e9
    stats = fake.stats()
    assert stats.infinite_waits == 0 and stats.frames_alive == 0 and stats.created == stats.destroyed == 1
    assert stats.config_processing_mode == 2 and stats.smoothing == pytest.approx(0.1)
    assert not device.is_running


def test_unknown_serial_and_unplug_are_typed_errors(stack):
    world, pyk4a, library, fake = stack
    with pytest.raises(SensorNotFound, match=r"000999.*000111, 000222"):
        KinectSource(DeviceSettings(serial="000999"), pyk4a=pyk4a, k4abt=library).open()
    source = KinectSource(DeviceSettings(serial="000111"), pyk4a=pyk4a, k4abt=library)
    source.open()
    source.read(0.01)
    world.unplugged.set()
    with pytest.raises(SensorDisconnected, match="unplugged"):
        source.read(0.01)
    source.close()
    source.close()  # idempotent
    assert fake.stats().created == fake.stats().destroyed


def test_missing_pyk4a_names_the_extra_and_the_sdk(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyk4a", None)
    with pytest.raises(KinectUnavailable, match=r"skelfuse\[kinect\].*Sensor SDK") as info:
        KinectSource(DeviceSettings(serial="1")).open()
    assert isinstance(info.value, ServiceError)  # fatal for the worker: no retry loop


def test_reconnect_loop_recovers_from_an_unplug(stack):
    world, pyk4a, library, fake = stack
    world.capture_period_s = 0.002
    received: list[SensorFrame] = []
    errors: list[str] = []
    stop = threading.Event()
    phase = {"replugged": False}

    def on_frame(frame):
        received.append(frame)
        if len(received) == 5 and not phase["replugged"]:
            world.unplugged.set()  # pull the cable
            threading.Timer(0.15, world.unplugged.clear).start()  # and plug it back
            phase["replugged"] = True
        if phase["replugged"] and len(received) >= 12:
            stop.set()

    def open_source():
        return KinectSource(DeviceSettings(serial="000222"), pyk4a=pyk4a, k4abt=library)

    report = run_with_reconnect(
        open_source,
        on_frame,
        stop.is_set,
        backoff=Backoff(initial_s=0.02, max_s=0.08),
        read_timeout_s=0.01,
        on_error=lambda exc, delay: errors.append(type(exc).__name__),
    )
    assert len(received) >= 12 and report.opens >= 2
    assert errors and set(errors) <= {"SensorDisconnected", "SensorNotFound"}
    assert report.delays[:3] == [0.02, 0.04, 0.08][: len(report.delays[:3])]
    stats = fake.stats()
    assert stats.created == stats.destroyed and stats.frames_alive == 0 and stats.infinite_waits == 0


def test_should_exit_stops_promptly_even_while_backing_off(stack):
    world, pyk4a, library, _ = stack
    world.unplugged.set()
    stop, stopped_at = threading.Event(), []

    def stop_now() -> None:
        stopped_at.append(time.monotonic())
        stop.set()

    threading.Timer(0.2, stop_now).start()
    report = run_with_reconnect(
        lambda: KinectSource(DeviceSettings(serial="000222"), pyk4a=pyk4a, k4abt=library),
        lambda frame: None,
        stop.is_set,
        backoff=Backoff(initial_s=60.0, max_s=60.0),
    )
    assert time.monotonic() - stopped_at[0] < SCHEDULING_ALLOWANCE_S  # the stop cut the 60 s back-off short
    assert report.failures == 1 and report.frames == 0


def test_fatal_errors_are_not_retried(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyk4a", None)
    with pytest.raises(KinectUnavailable):
        run_with_reconnect(lambda: KinectSource(DeviceSettings(serial="1")), lambda f: None, lambda: False)


def _offline_json(path: Path, n_frames: int) -> Path:
    from skelfuse.schema.skeleton import JOINT_NAMES

    frames = [
        {
            "timestamp_usec": 1000 + i * 33_333,
            "frame_id": i,
            "num_bodies": 1,
            "bodies": [
                {
                    "body_id": 3,
                    "joint_positions": [[float(i), 2.0, 3.0]] * 32,
                    "joint_orientations": [[1.0, 0.0, 0.0, 0.0]] * 32,
                }
            ],
        }
        for i in range(n_frames)
    ]
    path.write_text(
        json.dumps(
            {
                "k4abt_sdk_version": "1.1.2",
                "source_file": "x.mkv",
                "joint_names": list(JOINT_NAMES),
                "bone_list": [],
                "frames": frames,
            }
        )
    )
    return path


def test_recorded_file_source_reads_and_ends(tmp_path):
    source = RecordedFileSource(_offline_json(tmp_path / "take.json", 3), sensor_id="rec")
    source.open()
    frames = [source.read(0.0) for _ in range(3)]
    with pytest.raises(EndOfStream):
        source.read(0.0)
    assert [f.device_time_us for f in frames] == [1000, 34_333, 67_666] and frames[2].positions[0, 0, 0] == 2.0
    looped = RecordedFileSource(tmp_path / "take.json", loop=True)
    looped.open()
    times = [looped.read(0.0).device_time_us for _ in range(5)]
    assert times == sorted(times) and len(set(times)) == 5
    got = []
    run_with_reconnect(lambda: RecordedFileSource(tmp_path / "take.json"), got.append, lambda: False)
    assert len(got) == 3  # end of stream ends the loop, no reconnect


def test_mkv_source_tracks_every_capture_then_ends(stack, tmp_path):
    world, pyk4a, library, fake = stack
    world.eof_after = 4
    expected = _script(fake, 4)
    path = tmp_path / "take.mkv"
    path.write_bytes(b"")
    source = MkvSource(path, TrackerSettings(), pyk4a=pyk4a, k4abt=library)
    source.open()
    frames = []
    with pytest.raises(EndOfStream):
        for _ in range(20):
            frame = source.read(0.01)
            if frame is not None:
                frames.append(frame)
    source.close()
    assert [f.device_time_us for f in frames] == [us for us, _ in expected]
    assert frames[0].sensor_id == "take"


def test_worker_adapter_yields_frames_and_stops(stack):
    _, pyk4a, library, fake = stack
    _script(fake, 3)
    stop = threading.Event()
    adapter = WorkerFrameSource(
        KinectSource(DeviceSettings(serial="000111"), pyk4a=pyk4a, k4abt=library),
        should_exit=stop.is_set,
        read_timeout_s=0.01,
    )
    got = []
    for due_ns, frame in adapter.frames():
        assert due_ns <= time.monotonic_ns()
        got.append(frame)
        if len(got) == 3:
            stop.set()
    assert len(got) == 3 and fake.stats().created == fake.stats().destroyed


def test_list_devices_through_pyk4a_and_libk4a(stack, fake_libs, monkeypatch):
    world, pyk4a, _, _ = stack
    monkeypatch.setenv("FAKE_K4A_DEVICES", "000111:0:1;000222:1:0")
    from skelfuse.sources.k4abt import load_k4a

    k4a = load_k4a(fake_libs.k4a)
    via_pyk4a = devices.list_devices(pyk4a=pyk4a, k4a=k4a)
    via_k4a = devices._list_with_k4a(k4a)  # the ctypes-only path used where pyk4a is missing
    for listed in (via_pyk4a, via_k4a):
        assert [d.serial for d in listed] == ["000111", "000222"]
        assert [d.suggested_role for d in listed] == ["master", "subordinate"]
        assert listed[1].firmware.rgb == "1.6.111" and listed[0].firmware.depth_sensor == "6109.7.0"
    world.busy.add(0)
    busy = devices.list_devices(pyk4a=pyk4a, k4a=k4a)
    assert busy[0].serial is None and "another process" in busy[0].note
    assert "000222" in devices.format_devices(busy)


def test_describe_environment_says_what_is_missing(monkeypatch):
    monkeypatch.setenv("SKELFUSE_K4A_LIBRARY", "/nonexistent/libk4a.so")
    monkeypatch.setenv("SKELFUSE_K4ABT_LIBRARY", "/nonexistent/libk4abt.so")
    text = devices.describe_environment(k4a_path="/nonexistent/libk4a.so", k4abt_path="/nonexistent/libk4abt.so")
    assert "libk4a (Sensor SDK): MISSING" in text and "libk4abt (Body Tracking SDK): MISSING" in text
    assert "skelfuse[kinect]" in text and "OrbbecSDK-K4A-Wrapper" in text
    if sys.platform.startswith("linux"):
        assert "libk4abt1.1-dev" in text and "k4a-tools" in text
    assert kinect.PYK4A_INSTALL_HINT


@pytest.mark.parametrize("kind", ["device", "mkv"])
@pytest.mark.live
def test_depth_mode_makes_each_bodys_cloud_from_the_trackers_body_index_map(
    stack, fake_libs, monkeypatch, tmp_path, kind
):
    """clouds_voxel_mm: each popped body frame's body-index map and its capture's depth image (read back with
    their strides through the fake SDKs) become one cloud per body, lifted through the device's xy table: its
    calibration's Brown-Conrady lens, unprojected by the fake libk4a's k4a_calibration_2d_to_3d, recomputed
    here with numpy; pixels beyond the lens's metric radius are dropped. The fake tracker's map gives body b the
    b-th vertical strip of the valid pixels (tests/fake_k4a)."""
    import ctypes

    from skelfuse.fusion.depth.cloud import voxelize
    from skelfuse.sources.k4abt import K4A_LIBRARY_ENV

    world, pyk4a, library, fake = stack
    monkeypatch.setenv(K4A_LIBRARY_ENV, str(fake_libs.k4a))  # the libk4a pyk4a runs on (the same library)
    width, height, fx, fy, cx, cy, metric_radius = 320, 288, 252.0, 251.0, 160.5, 143.0, 0.78
    world.calibration_bytes = bytes(harness.distorted_calibration(width, height, fx, fy, cx, cy, metric_radius))
    depth = np.zeros((height, width), np.uint16)
    depth[10:280, 40:310] = 1800 + (np.arange(310 - 40) % 97)[None, :]  # a slanted block reaching the corners
    rays, radius = harness.brown_conrady_xy_table(
        width, height, {**harness.NFOV_BINNED_LENS, "fx": fx, "fy": fy, "cx": cx, "cy": cy}
    )
    depth[np.abs(radius - metric_radius) < 0.01] = 0  # no pixel on the lens's edge, where rounding decides
    world.depth = (ctypes.c_uint16 * width * height).from_buffer_copy(depth.tobytes())
    captures_before = world.k4a.captures_alive()
    ids = np.array([7, 9], np.uint32)
    for index in range(3):
        zeros = np.zeros((2, 32, 3), np.float32)
        quats = np.tile(np.array([1, 0, 0, 0], np.float32), (2, 32, 1))
        fake.script_frame(
            1_000_000 + index * 33_333, time.monotonic_ns(), ids, zeros, quats, np.full((2, 32), 2, np.uint8)
        )
    if kind == "device":
        settings = DeviceSettings(serial="000111", tracker=TrackerSettings(processing_mode="cpu"))
        source = KinectSource(settings, pyk4a=pyk4a, k4abt=library, clouds_voxel_mm=20.0)
    else:  # a k4arecorder take replayed through the tracker (skelfuse eval depth reads these)
        world.eof_after = 3
        (tmp_path / "take.mkv").write_bytes(b"")
        source = MkvSource(tmp_path / "take.mkv", pyk4a=pyk4a, k4abt=library, clouds_voxel_mm=20.0)
    source.open()
    clouds = []
    try:
        for _ in range(20):
            try:
                frame = source.read(0.01)
            except EndOfStream:
                break
            if frame is not None:
                clouds.append(source.clouds_at(frame))
                assert clouds[-1].device_timestamp_us == frame.device_time_us
            if len(clouds) == 3:
                break
    finally:
        source.close()
    assert len(clouds) == 3
    assert ((depth > 0) & (radius > metric_radius + 0.01)).sum() > 100  # some of the block is beyond the lens
    v, u = np.nonzero((depth > 0) & (radius <= metric_radius))
    z = depth[v, u].astype(np.float64)
    lifted = np.stack([rays[v, u, 0] * z, rays[v, u, 1] * z, z], axis=1)
    strip = (np.nonzero(depth > 0)[1] * 2 // width)[((radius <= metric_radius)[depth > 0])]  # the fake's map
    for cloud in clouds:
        assert cloud.body_ids.tolist() == [7, 9] and cloud.voxel_mm == 20.0
        for b in range(2):
            expected, _, _ = voxelize(lifted[strip == b], 20.0)
            np.testing.assert_allclose(cloud.clouds[b], expected, atol=1e-3)
    stats = fake.stats()
    assert stats.frames_alive == 0 and world.k4a.captures_alive() == captures_before  # nothing held or leaked


@pytest.mark.live
def test_eval_depth_groups_the_mkv_takes_of_several_sensors_into_instants(stack, fake_libs, monkeypatch, tmp_path):
    """skelfuse eval depth's reader: two sensors' takes replayed one after the other through the (fake) SDK,
    frames and clouds grouped by device time within the rig's tolerance (a subordinate 160 µs after its
    master joins the master's instant; a frame of one sensor alone makes an incomplete instant)."""
    import ctypes

    from skelfuse.eval.depth import mkv_instants
    from skelfuse.sources.k4abt import K4A_LIBRARY_ENV, virtual_calibration

    world, pyk4a, library, fake = stack
    monkeypatch.setenv(K4A_LIBRARY_ENV, str(fake_libs.k4a))
    world.calibration_bytes = bytes(virtual_calibration(252.0, 251.0, 160.5, 143.0, 320, 288))
    depth = np.zeros((288, 320), np.uint16)
    depth[60:240, 40:280] = 2000
    world.depth = (ctypes.c_uint16 * 320 * 288).from_buffer_copy(depth.tobytes())
    cfg = load_rig_config(EXAMPLE)
    first, second = cfg.sensor_ids[:2]
    one = np.zeros((1, 32, 3), np.float32)
    quats = np.tile(np.array([1, 0, 0, 0], np.float32), (1, 32, 1))
    conf = np.full((1, 32), 2, np.uint8)
    times = {first: [1_000_000, 1_033_333, 1_066_667], second: [1_000_160, 1_033_493, 1_100_160]}
    for sensor_id in (first, second):  # the takes are read in this order: script each one's frames in turn
        for us in times[sensor_id]:
            fake.script_frame(us, time.monotonic_ns(), np.array([3], np.uint32), one, quats, conf)
    takes = {}
    for sensor_id in (first, second):
        takes[sensor_id] = tmp_path / f"{sensor_id}.mkv"
        takes[sensor_id].write_bytes(b"")
    world.eof_after = 3
    instants = mkv_instants(takes, cfg, voxel_mm=20.0, pyk4a=pyk4a, k4abt=library)
    assert [sorted(i.group.frames) for i in instants] == [
        sorted([first, second]),
        sorted([first, second]),
        [first],
        [second],
    ]
    assert [i.group.time_us for i in instants] == [1_000_000, 1_033_333, 1_066_667, 1_100_160]
    assert all(set(i.clouds) == set(i.group.frames) for i in instants)
    assert instants[0].clouds[second].body_ids.tolist() == [3] and len(instants[0].clouds[second].clouds[0]) > 100
    assert not instants[0].group.complete and set(instants[2].group.missing) >= {second}  # a 4-sensor rig
    assert fake.stats().frames_alive == 0
