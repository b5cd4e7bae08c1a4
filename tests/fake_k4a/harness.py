"""Python side of the fake Azure Kinect stack: drives the compiled fake libk4abt (scripted frames, events,
stats, C layouts) and provides a fake ``pyk4a`` module whose captures and calibrations carry real PyCapsules
around handles made by the fake libk4a, exactly as pyk4a's C extension does.

Loaded by the unit tests through tests/unit/fake_sdk.py (the tests folder is not a package).
"""

from __future__ import annotations

import ctypes
import enum
import importlib.util
import sys
import threading
import types
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent


def _load_build() -> types.ModuleType:
    spec = importlib.util.spec_from_file_location("skelfuse_fake_k4a_build", HERE / "build.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


build = _load_build()

EVENTS = {"enqueue_timeout": 1, "enqueue_failed": 2, "pop_failed": 3, "drop": 4}

_PyCapsule_New = ctypes.pythonapi.PyCapsule_New
_PyCapsule_New.restype = ctypes.py_object
_PyCapsule_New.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_void_p]


def make_capsule(address: int, name: bytes) -> Any:
    """A PyCapsule holding ``address`` under ``name`` (the name bytes must outlive it: module constants)."""
    return _PyCapsule_New(address, name, None)


CAPTURE_NAME = b"pyk4a capture handle"
CALIBRATION_NAME = b"pyk4a calibration handle"
DEVICE_NAME = b"pyk4a device handle"


class FakeStats(ctypes.Structure):
    _fields_ = [
        (name, ctypes.c_int32)
        for name in (
            "created",
            "destroyed",
            "shutdowns",
            "frames_alive",
            "infinite_waits",
            "enqueued",
            "popped",
            "bad_captures",
            "config_sensor_orientation",
            "config_processing_mode",
            "config_gpu_device_id",
        )
    ] + [
        ("smoothing", ctypes.c_float),
        ("smoothing_calls", ctypes.c_int32),
        ("abi", ctypes.c_int32),
        ("last_calibration", ctypes.c_void_p),
        ("last_capture", ctypes.c_void_p),
        ("model_path", ctypes.c_char * 512),
    ]


class FakeK4abt:
    """Control of one loaded fake libk4abt."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.lib = ctypes.CDLL(str(path))
        self.lib.fake_k4abt_layout.restype = ctypes.c_size_t
        self.lib.fake_k4abt_layout.argtypes = [ctypes.c_char_p]
        self.lib.fake_k4abt_script_frame.argtypes = [
            ctypes.c_uint64,
            ctypes.c_uint64,
            ctypes.c_uint32,
            ctypes.c_void_p,
            ctypes.c_void_p,
        ]
        self.lib.fake_k4abt_script_event.argtypes = [ctypes.c_int]

    def reset(self) -> None:
        self.lib.fake_k4abt_reset()

    def layout(self, name: str) -> int:
        value = int(self.lib.fake_k4abt_layout(name.encode()))
        assert value != ctypes.c_size_t(-1).value, f"fake knows no layout {name!r}"
        return value

    def script_frame(
        self,
        device_us: int,
        system_ns: int,
        body_ids: np.ndarray,
        positions: np.ndarray,
        orientations: np.ndarray,
        confidence: np.ndarray,
    ) -> None:
        n = len(body_ids)
        raw = np.zeros((n, 32), dtype=[("position", "<f4", (3,)), ("orientation", "<f4", (4,)), ("confidence", "<i4")])
        raw["position"], raw["orientation"], raw["confidence"] = positions, orientations, confidence
        ids = np.ascontiguousarray(body_ids, dtype=np.uint32)
        assert raw.dtype.itemsize == 32
        result = self.lib.fake_k4abt_script_frame(device_us, system_ns, n, ids.ctypes.data, raw.ctypes.data)
        assert result >= 0

    def script_event(self, kind: str) -> None:
        assert self.lib.fake_k4abt_script_event(EVENTS[kind]) >= 0

    def fail_next_creates(self, n: int) -> None:
        self.lib.fake_k4abt_fail_next_creates(n)

    def stats(self) -> FakeStats:
        stats = FakeStats()
        self.lib.fake_k4abt_get_stats(ctypes.byref(stats))
        return stats


class FakeK4a:
    """The loaded fake libk4a: makes real capture handles."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.lib = ctypes.CDLL(str(path))
        self.lib.k4a_capture_create.argtypes = [ctypes.POINTER(ctypes.c_void_p)]
        self.lib.k4a_capture_release.argtypes = [ctypes.c_void_p]
        self.lib.k4a_device_open.argtypes = [ctypes.c_uint32, ctypes.POINTER(ctypes.c_void_p)]
        self.lib.k4a_device_close.argtypes = [ctypes.c_void_p]
        self.lib.fake_k4a_layout.restype = ctypes.c_size_t
        self.lib.fake_k4a_layout.argtypes = [ctypes.c_char_p]

    def new_capture_holder(self) -> ctypes.c_void_p:
        """A heap cell holding a fresh k4a_capture_t, like pyk4a's malloc'd ``k4a_capture_t*``."""
        holder = ctypes.c_void_p()
        assert self.lib.k4a_capture_create(ctypes.byref(holder)) == 0
        return holder

    def captures_alive(self) -> int:
        return int(self.lib.fake_k4a_captures_alive())


# ---------------------------------------------------------------------------------------------- fake pyk4a


class K4AException(Exception):
    pass


class K4ATimeoutException(K4AException):
    pass


class ColorResolution(enum.IntEnum):
    OFF = 0
    RES_720P = 1
    RES_1080P = 2
    RES_1440P = 3
    RES_1536P = 4
    RES_2160P = 5
    RES_3072P = 6


class DepthMode(enum.IntEnum):
    OFF = 0
    NFOV_2X2BINNED = 1
    NFOV_UNBINNED = 2
    WFOV_2X2BINNED = 3
    WFOV_UNBINNED = 4
    PASSIVE_IR = 5


class FPS(enum.IntEnum):
    FPS_5 = 0
    FPS_15 = 1
    FPS_30 = 2


class WiredSyncMode(enum.IntEnum):
    STANDALONE = 0
    MASTER = 1
    SUBORDINATE = 2


class ImageFormat(enum.IntEnum):
    COLOR_MJPG = 0
    COLOR_NV12 = 1
    COLOR_YUY2 = 2
    COLOR_BGRA32 = 3


@dataclass
class Config:
    color_resolution: ColorResolution = ColorResolution.RES_720P
    color_format: ImageFormat = ImageFormat.COLOR_BGRA32
    depth_mode: DepthMode = DepthMode.NFOV_UNBINNED
    camera_fps: FPS = FPS.FPS_30
    synchronized_images_only: bool = True
    depth_delay_off_color_usec: int = 0
    wired_sync_mode: WiredSyncMode = WiredSyncMode.STANDALONE
    subordinate_delay_off_master_usec: int = 0
    disable_streaming_indicator: bool = False


class FakeCapture:
    def __init__(self, k4a: FakeK4a, depth: Any = None) -> None:
        """``depth``: a (H, W) ctypes uint16 array kept alive by the caller (the world), set as the capture's
        DEPTH16 image (rows 2 W bytes apart) through the fake libk4a, like a device capture's."""
        self._k4a = k4a
        self._holder = k4a.new_capture_holder()
        self._capture_handle = make_capsule(ctypes.addressof(self._holder), CAPTURE_NAME)
        if depth is not None:
            from skelfuse.sources.k4abt import K4aMemoryDestroyCallback, declare_image_api

            declare_image_api(k4a.lib)
            height, width = len(depth), len(depth[0])
            image = ctypes.c_void_p()
            assert (
                k4a.lib.k4a_image_create_from_buffer(
                    4,
                    width,
                    height,
                    2 * width,
                    ctypes.addressof(depth),
                    ctypes.sizeof(depth),
                    K4aMemoryDestroyCallback(),  # NULL: the world owns the buffer
                    None,
                    ctypes.byref(image),
                )
                == 0
            )
            k4a.lib.k4a_capture_set_depth_image(self._holder, image)
            k4a.lib.k4a_image_release(image)  # the capture holds its own reference

    def __del__(self) -> None:
        if self._holder.value:
            self._k4a.lib.k4a_capture_release(self._holder)


class FakeCalibration:
    def __init__(self, contents: bytes | None = None) -> None:
        self._buffer = ctypes.create_string_buffer(1024)  # stands in for a k4a_calibration_t
        if contents is not None:  # a real k4a_calibration_t's bytes (skelfuse.sources.k4abt.virtual_calibration)
            ctypes.memmove(self._buffer, contents, len(contents))
        self.address = ctypes.addressof(self._buffer)
        self._calibration_handle = make_capsule(self.address, CALIBRATION_NAME)


@dataclass
class FakeWorld:
    """The state the fake pyk4a module plays from: connected serials, an unplug switch, a capture pacer."""

    k4a: FakeK4a
    serials: list[str] = field(default_factory=list)
    unplugged: threading.Event = field(default_factory=threading.Event)
    busy: set[int] = field(default_factory=set)
    capture_period_s: float = 0.0
    opened: list[PyK4AConfigured] = field(default_factory=list)
    eof_after: int = 0
    depth: Any = None  # a ctypes (H, W) uint16 array: every capture's depth image (None: captures without)
    calibration_bytes: bytes | None = None  # the devices' k4a_calibration_t (None: zeros)


class PyK4AConfigured:
    """Fake ``pyk4a.PyK4A``."""

    world: FakeWorld

    def __init__(self, config: Config | None = None, device_id: int = 0, thread_safe: bool = True) -> None:
        self._config = config or Config()
        self._device_id = device_id
        self.is_running = False
        self.opened = False
        self._calibration: FakeCalibration | None = None
        self._device_holder = ctypes.c_void_p()
        self._device_handle: Any = None

    def open(self) -> None:
        if self._device_id in self.world.busy or self.world.unplugged.is_set():
            raise K4AException("device busy")
        assert self.world.k4a.lib.k4a_device_open(self._device_id, ctypes.byref(self._device_holder)) == 0
        self._device_handle = make_capsule(ctypes.addressof(self._device_holder), DEVICE_NAME)
        self.opened = True
        self.world.opened.append(self)

    def start(self) -> None:
        if not self.opened:
            self.open()
        self.is_running = True

    def stop(self) -> None:
        self.is_running = False
        self.close()

    def close(self) -> None:
        if self.opened:
            self.world.k4a.lib.k4a_device_close(self._device_holder)
        self.opened = False

    @property
    def serial(self) -> str:
        return self.world.serials[self._device_id]

    @property
    def sync_jack_status(self) -> tuple[bool, bool]:
        return (self._device_id > 0, self._device_id < len(self.world.serials) - 1)

    @property
    def calibration(self) -> FakeCalibration:
        if self._calibration is None:
            self._calibration = FakeCalibration(self.world.calibration_bytes)
        return self._calibration

    def get_capture(self, timeout: int = -1) -> FakeCapture:
        assert timeout >= 0, "skelfuse must never wait forever for a capture"
        if self.world.unplugged.is_set():
            raise K4AException("device lost")
        if self.world.capture_period_s:
            threading.Event().wait(self.world.capture_period_s)
        return FakeCapture(self.world.k4a, self.world.depth)


class FakePlayback:
    world: FakeWorld

    def __init__(self, path: Any, thread_safe: bool = True) -> None:
        self.path = Path(path)
        self._left = self.world.eof_after
        self.calibration = FakeCalibration(self.world.calibration_bytes)
        self.closed = False

    def open(self) -> None:
        pass

    def get_next_capture(self) -> FakeCapture:
        if self._left <= 0:
            raise EOFError
        self._left -= 1
        return FakeCapture(self.world.k4a, self.world.depth)

    def close(self) -> None:
        self.closed = True


def make_fake_pyk4a(world: FakeWorld) -> types.ModuleType:
    """A module object with the slice of pyk4a's API skelfuse uses, bound to ``world``."""
    module = types.ModuleType("pyk4a")
    device_cls = type("PyK4A", (PyK4AConfigured,), {"world": world})
    playback_cls = type("PyK4APlayback", (FakePlayback,), {"world": world})
    module.__dict__.update(
        K4AException=K4AException,
        K4ATimeoutException=K4ATimeoutException,
        ColorResolution=ColorResolution,
        DepthMode=DepthMode,
        FPS=FPS,
        WiredSyncMode=WiredSyncMode,
        ImageFormat=ImageFormat,
        Config=Config,
        PyK4A=device_cls,
        PyK4APlayback=playback_cls,
        connected_device_count=lambda: 0 if world.unplugged.is_set() else len(world.serials),
    )
    return module


# --------------------------------------------------------------------------- the lens model, in numpy

NFOV_BINNED_LENS = {
    # A real NFOV depth camera's Brown-Conrady coefficients are of this size (k1..k6 a few units whose ratio
    # stays near 1, p1 / p2 ~1e-4); these are test values of that shape, not a device's calibration.
    "k1": 3.13,
    "k2": 2.32,
    "k3": 0.13,
    "k4": 3.46,
    "k5": 3.35,
    "k6": 0.66,
    "p1": 8.1e-5,
    "p2": -5.1e-5,
}


def distorted_calibration(width: int, height: int, fx: float, fy: float, cx: float, cy: float, metric_radius: float):
    """A ``k4a_calibration_t`` (skelfuse's ctypes struct) of a Brown-Conrady depth camera with
    :data:`NFOV_BINNED_LENS`'s coefficients."""
    from skelfuse.sources.k4abt import virtual_calibration

    calibration = virtual_calibration(fx, fy, cx, cy, width, height)
    camera = calibration.depth_camera_calibration
    for name, value in NFOV_BINNED_LENS.items():
        setattr(camera.intrinsics.parameters, name, value)
    camera.intrinsics.parameters.metric_radius = metric_radius
    camera.metric_radius = metric_radius
    return calibration


def brown_conrady_project(x: np.ndarray, y: np.ndarray, p: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """Pixel (u, v) of normalized rays (x, y) under k4a's Brown-Conrady model (codx = cody = 0), written from
    the SDK documentation's formula, independently of the C fake."""
    r2 = x * x + y * y
    radial = (1 + p["k1"] * r2 + p["k2"] * r2**2 + p["k3"] * r2**3) / (
        1 + p["k4"] * r2 + p["k5"] * r2**2 + p["k6"] * r2**3
    )
    xd = x * radial + (r2 + 2 * x * x) * p["p2"] + 2 * x * y * p["p1"]
    yd = y * radial + (r2 + 2 * y * y) * p["p1"] + 2 * x * y * p["p2"]
    return xd * p["fx"] + p["cx"], yd * p["fy"] + p["cy"]


def brown_conrady_xy_table(width: int, height: int, p: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 2) rays of every pixel by Newton's method on :func:`brown_conrady_project` with a central-difference
    Jacobian (not the fake's analytic one), in float64, and the (H, W) radius of each ray (for validity)."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    x, y = (u - p["cx"]) / p["fx"], (v - p["cy"]) / p["fy"]
    h = 1e-7
    for _ in range(30):
        pu, pv = brown_conrady_project(x, y, p)
        eu, ev = u - pu, v - pv
        ux, vx = brown_conrady_project(x + h, y, p)
        uy, vy = brown_conrady_project(x, y + h, p)
        ux_m, vx_m = brown_conrady_project(x - h, y, p)
        uy_m, vy_m = brown_conrady_project(x, y - h, p)
        a, b = (ux - ux_m) / (2 * h), (uy - uy_m) / (2 * h)
        c, d = (vx - vx_m) / (2 * h), (vy - vy_m) / (2 * h)
        det = a * d - b * c
        x = x + (d * eu - b * ev) / det
        y = y + (-c * eu + a * ev) / det
    return np.stack([x, y], axis=-1), np.hypot(x, y)
