"""The ctypes k4abt binding against a fake libk4abt compiled from C with the SDK's real ABI.

The fake (tests/fake_k4a/) is built with gcc for both Body Tracking SDK generations (1.1+: 24-byte tracker
configuration with model_path; 1.0: 12 bytes with cpu_only_mode). The binding must pass skeletons through
bit-exactly, hand the tracker configuration over by value, never wait forever, and release every frame.
"""

from __future__ import annotations

import ctypes

import numpy as np
import pytest
from fake_sdk import build_fake_libs_or_skip, harness

from skelfuse.schema.errors import ServiceError
from skelfuse.sources import k4abt
from skelfuse.sources.k4abt import (
    K4abtLibrary,
    K4ABTLibraryError,
    Tracker,
    TrackerCreateError,
    TrackerFailedError,
    TrackerSettings,
)


@pytest.fixture(scope="module")
def fake_libs(tmp_path_factory):
    root = tmp_path_factory.mktemp("fake_k4a")
    return {
        abi: build_fake_libs_or_skip(root / abi.replace(".", "_"), abi, "the binding tests run against")
        for abi in ("1.1", "1.0")
    }


@pytest.fixture(scope="module")
def loaded(fake_libs):
    out = {}
    for abi, libs in fake_libs.items():
        out[abi] = (K4abtLibrary.load(libs.k4abt), harness.FakeK4abt(libs.k4abt), harness.FakeK4a(libs.k4a))
    return out


@pytest.fixture
def lib11(loaded):
    library, fake, k4a = loaded["1.1"]
    fake.reset()
    return library, fake, k4a


@pytest.fixture
def lib10(loaded):
    library, fake, k4a = loaded["1.0"]
    fake.reset()
    return library, fake, k4a


_KEEP: list = []


def _capture(k4a):
    """A pyk4a-like capture: a capsule around a heap cell holding a fake k4a_capture_t.

    Kept alive for the module: the real SDK references an enqueued capture, the fake does not.
    """
    capture = harness.FakeCapture(k4a)
    _KEEP.append(capture)
    return capture


def _random_bodies(rng, n):
    positions = rng.normal(0, 1000, (n, 32, 3)).astype(np.float32)
    if n:
        positions[0, 0] = [-0.0, np.float32(1e-42), np.finfo(np.float32).max]  # -0, a denormal, the max: bit-exact
    orientations = rng.normal(0, 1, (n, 32, 4)).astype(np.float32)
    confidence = rng.integers(0, 4, (n, 32)).astype(np.uint8)
    ids = rng.integers(1, 2**32 - 2, n).astype(np.uint32)
    return ids, positions, orientations, confidence


def test_ctypes_structs_match_the_c_layouts(lib11, lib10):
    _, fake11, k4a = lib11
    _, fake10, _ = lib10
    assert fake11.layout("float3") == ctypes.sizeof(k4abt.K4aFloat3) == 12
    assert fake11.layout("quaternion") == ctypes.sizeof(k4abt.K4aQuaternion) == 16
    assert fake11.layout("joint") == ctypes.sizeof(k4abt.K4abtJoint) == k4abt.JOINT_DTYPE.itemsize == 32
    for name in ("position", "orientation", "confidence_level"):
        assert fake11.layout(f"joint.{name}") == getattr(k4abt.K4abtJoint, name).offset
    assert fake11.layout("skeleton") == ctypes.sizeof(k4abt.K4abtSkeleton) == 32 * 32
    cfg11 = k4abt.TrackerConfiguration11
    assert fake11.layout("config") == ctypes.sizeof(cfg11)
    for name in ("sensor_orientation", "processing_mode", "gpu_device_id", "model_path"):
        assert fake11.layout(f"config.{name}") == getattr(cfg11, name).offset
    cfg10 = k4abt.TrackerConfiguration10
    assert fake10.layout("config") == ctypes.sizeof(cfg10) == 12
    for name in ("sensor_orientation", "cpu_only_mode", "gpu_device_id"):
        assert fake10.layout(f"config.{name}") == getattr(cfg10, name).offset
    hw = k4abt.K4aHardwareVersion
    assert int(k4a.lib.fake_k4a_layout(b"hardware_version")) == ctypes.sizeof(hw)
    for name in ("depth", "depth_sensor", "firmware_build", "firmware_signature"):
        assert int(k4a.lib.fake_k4a_layout(f"hardware_version.{name}".encode())) == getattr(hw, name).offset


def test_abi_is_detected_from_exported_symbols(lib11, lib10, fake_libs, monkeypatch):
    assert lib11[0].abi == "1.1" and lib10[0].abi == "1.0"
    assert K4abtLibrary.load(fake_libs["1.1"].k4abt, abi="1.1").abi == "1.1"
    monkeypatch.setenv(k4abt.K4ABT_ABI_ENV, "1.0")
    assert K4abtLibrary.load(fake_libs["1.0"].k4abt).abi == "1.0"
    with pytest.raises(K4ABTLibraryError, match=r"1\.0 ABI"):  # forced to a generation the library is not
        K4abtLibrary.load(fake_libs["1.1"].k4abt)
    monkeypatch.delenv(k4abt.K4ABT_ABI_ENV)
    with pytest.raises(K4ABTLibraryError, match=r"1\.1 ABI"):
        K4abtLibrary.load(fake_libs["1.0"].k4abt, abi="1.1")


def test_missing_library_is_a_fatal_typed_error(tmp_path):
    with pytest.raises(K4ABTLibraryError, match=r"libk4abt1\.1-dev") as info:
        K4abtLibrary.load(tmp_path / "libk4abt.so")
    assert isinstance(info.value, ServiceError)
    with pytest.raises(K4ABTLibraryError, match=r"libk4a1\.4"):
        k4abt.load_k4a(tmp_path / "libk4a.so")


def test_skeletons_pass_through_bit_exact(lib11):
    library, fake, k4a = lib11
    rng = np.random.default_rng(20240607)
    calibration = harness.FakeCalibration()
    script = []
    for index, n in enumerate([2, 0, 3, 1]):
        bodies = _random_bodies(rng, n)
        device_us, system_ns = 2**40 + index * 33_333, 2**62 + index * 33_333_333
        fake.script_frame(device_us, system_ns, *bodies)
        script.append((device_us, system_ns, bodies))
    with Tracker(library, k4abt.calibration_pointer(calibration), TrackerSettings()) as tracker:
        assert fake.stats().last_calibration == calibration.address
        got = []
        for _ in script:
            capture = _capture(k4a)
            assert tracker.enqueue(k4abt.capture_handle(capture), timeout_ms=0)
            assert fake.stats().last_capture == capture._holder.value  # the handle, not the capsule's cell
            frame = tracker.pop(timeout_ms=0)
            assert frame is not None
            got.append(frame)
        assert tracker.pending == 0
    for frame, (device_us, system_ns, (ids, positions, orientations, confidence)) in zip(got, script, strict=True):
        assert frame.device_time_us == device_us and frame.system_time_ns == system_ns
        assert frame.body_ids.dtype == np.uint32 and np.array_equal(frame.body_ids, ids)
        assert frame.positions.dtype == np.float32 and frame.positions.shape == positions.shape
        assert np.array_equal(frame.positions.view(np.uint32), positions.view(np.uint32))
        assert np.array_equal(frame.orientations.view(np.uint32), orientations.view(np.uint32))
        assert frame.confidence.dtype == np.uint8 and np.array_equal(frame.confidence, confidence)
    stats = fake.stats()
    assert stats.frames_alive == 0 and stats.infinite_waits == 0 and stats.bad_captures == 0
    assert stats.created == stats.destroyed == 1 and stats.shutdowns == 1


def test_configuration_is_passed_by_value_on_sdk_11(lib11):
    library, fake, _ = lib11
    settings = TrackerSettings(
        processing_mode="tensorrt",
        gpu_device_id=3,
        model_path="/usr/bin/dnn_model_2_0_lite_op11.onnx",
        sensor_orientation="flip180",
        temporal_smoothing=0.25,
    )
    with Tracker(library, harness.FakeCalibration().address, settings):
        stats = fake.stats()
    assert (stats.config_sensor_orientation, stats.config_processing_mode, stats.config_gpu_device_id) == (3, 3, 3)
    assert stats.model_path == b"/usr/bin/dnn_model_2_0_lite_op11.onnx"
    assert stats.smoothing == pytest.approx(0.25) and stats.smoothing_calls == 1
    with Tracker(library, harness.FakeCalibration().address, TrackerSettings(processing_mode="cuda")):
        stats = fake.stats()
    assert stats.config_processing_mode == 2 and stats.model_path == b""


def test_sdk_10_gets_its_own_configuration_and_timestamps(lib10):
    library, fake, k4a = lib10
    with Tracker(
        library,
        harness.FakeCalibration().address,
        TrackerSettings(processing_mode="cpu", gpu_device_id=1, sensor_orientation="clockwise90"),
    ) as tracker:
        stats = fake.stats()
        assert (stats.config_sensor_orientation, stats.config_processing_mode, stats.config_gpu_device_id) == (1, 1, 1)
        ids, positions, orientations, confidence = _random_bodies(np.random.default_rng(5), 1)
        fake.script_frame(123_456, 999, ids, positions, orientations, confidence)
        assert tracker.enqueue(k4abt.capture_handle(_capture(k4a)))
        frame = tracker.pop()
        assert frame.device_time_us == 123_456 and frame.system_time_ns is None
        assert np.array_equal(frame.positions, positions)
    with pytest.raises(TrackerCreateError, match=r"1\.1 or newer"):
        Tracker(library, harness.FakeCalibration().address, TrackerSettings(model_path="lite.onnx"))


def test_failures_and_timeouts_become_typed_results(lib11):
    library, fake, k4a = lib11
    calibration = harness.FakeCalibration().address
    fake.fail_next_creates(1)
    with pytest.raises(TrackerCreateError, match="k4abt_tracker_create failed"):
        Tracker(library, calibration, TrackerSettings())
    with Tracker(library, calibration, TrackerSettings()) as tracker:
        fake.script_event("enqueue_timeout")
        assert tracker.enqueue(k4abt.capture_handle(_capture(k4a)), timeout_ms=1) is False
        assert tracker.pop(timeout_ms=1) is None  # nothing queued: a bounded timeout, not a hang
        fake.script_event("enqueue_failed")
        with pytest.raises(TrackerFailedError, match="enqueue"):
            tracker.enqueue(k4abt.capture_handle(_capture(k4a)))
        fake.script_event("pop_failed")
        assert tracker.enqueue(k4abt.capture_handle(_capture(k4a)))
        with pytest.raises(TrackerFailedError, match="pop_result"):
            tracker.pop()
        fake.script_event("drop")
        assert tracker.enqueue(k4abt.capture_handle(_capture(k4a)))
        assert tracker.pop(timeout_ms=2) is None and tracker.pending == 1
        for _ in range(3):  # the input queue fills up: enqueue reports it instead of blocking
            assert tracker.enqueue(k4abt.capture_handle(_capture(k4a)))
        assert tracker.enqueue(k4abt.capture_handle(_capture(k4a)), timeout_ms=1) is False
        with pytest.raises(ValueError, match="never waits forever"):
            tracker.pop(timeout_ms=-1)
    with pytest.raises(k4abt.K4ABTError, match="closed"):
        tracker.pop()
    stats = fake.stats()
    assert stats.infinite_waits == 0 and stats.frames_alive == 0 and stats.created == stats.destroyed


def test_capsules_are_checked_by_name(lib11):
    _, _, k4a = lib11
    capture = _capture(k4a)
    assert k4abt.capture_handle(capture) == capture._holder.value
    wrong = type(
        "C", (), {"_capture_handle": harness.make_capsule(ctypes.addressof(capture._holder), harness.CALIBRATION_NAME)}
    )()
    with pytest.raises(k4abt.K4ABTError, match="pyk4a capture handle"):
        k4abt.capture_handle(wrong)
    with pytest.raises(k4abt.K4ABTError, match="PyCapsule"):
        k4abt.calibration_pointer(object())


def test_settings_are_validated():
    with pytest.raises(Exception, match="processing_mode"):
        TrackerSettings(processing_mode="quantum")
    with pytest.raises(Exception, match="temporal_smoothing"):
        TrackerSettings(temporal_smoothing=2.0)
