"""A small ctypes binding to the Azure Kinect Body Tracking SDK (libk4abt) and the bits of libk4a we need.

pyk4a opens devices and recordings but has no body tracking. Its capture and calibration objects hold raw
SDK handles in PyCapsules (``capture._capture_handle`` named "pyk4a capture handle", pointing to a
``k4a_capture_t``; ``calibration._calibration_handle`` named "pyk4a calibration handle", pointing to a
``k4a_calibration_t``), which this module hands to libk4abt.

Cycle::

    lib = K4abtLibrary.load()                        # finds libk4abt, detects the SDK generation (ABI)
    with Tracker(lib, calibration_pointer(calibration), TrackerSettings(...)) as tracker:
        tracker.enqueue(capture_handle(capture), timeout_ms=0)   # False: input queue full, try later
        body_frame = tracker.pop(timeout_ms=0)                   # None: no result ready yet
    # shutdown + destroy on exit

Pipelined: enqueue and pop both take bounded timeouts (never K4A_WAIT_INFINITE), so a stalled tracker can
never hang a capture worker; the caller decides what a run of timeouts means.

SDK generations (``k4abt_tracker_configuration_t`` is passed BY VALUE, so its layout must match):

* 1.0.x: ``{sensor_orientation, cpu_only_mode (bool; 1.0.1 calls it processing_mode GPU/CPU), gpu_device_id}``
  (12 bytes); frames have ``k4abt_frame_get_timestamp_usec`` only.
* 1.1+: ``{sensor_orientation, processing_mode, gpu_device_id, model_path}`` (24 bytes on 64-bit); frames
  have ``k4abt_frame_get_device_timestamp_usec`` and ``k4abt_frame_get_system_timestamp_nsec``.

The SDK exports no version function, so the generation is detected from the exported symbols (1.1 added
``k4abt_frame_get_system_timestamp_nsec``), or forced with ``abi=`` / ``SKELFUSE_K4ABT_ABI``.

Errors: a library that cannot be found or loaded raises :class:`K4ABTLibraryError` (a ServiceError: fatal,
retrying will not help); a tracker that cannot be created raises :class:`TrackerCreateError`; a failed
enqueue or pop raises :class:`TrackerFailedError`. The last two are run-time errors a daemon retries.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import logging
import os
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.schema.errors import ConfigError
from skelfuse.schema.skeleton import N_JOINTS
from skelfuse.sources.k4a_abi import (
    ABIS,
    JOINT_DTYPE,
    K4A_BUFFER_RESULT_SUCCEEDED,
    K4A_BUFFER_RESULT_TOO_SMALL,
    K4A_CALIBRATION_LENS_DISTORTION_MODEL_BROWN_CONRADY,
    K4A_CALIBRATION_TYPE_DEPTH,
    K4A_CALIBRATION_TYPE_NUM,
    K4A_DEPTH_MODES,
    K4A_IMAGE_FORMAT_DEPTH16,
    K4A_IMAGE_FORMAT_IR16,
    K4A_INSTALL_HINT,
    K4A_LIBRARY_ENV,
    K4A_RESULT_FAILED,
    K4A_RESULT_SUCCEEDED,
    K4A_WAIT_RESULT_FAILED,
    K4A_WAIT_RESULT_SUCCEEDED,
    K4A_WAIT_RESULT_TIMEOUT,
    K4ABT_ABI_ENV,
    K4ABT_INSTALL_HINT,
    K4ABT_INVALID_BODY_ID,
    K4ABT_LIBRARY_ENV,
    NFOV_METRIC_RADIUS,
    PROCESSING_MODES,
    PYK4A_CALIBRATION_CAPSULE,
    PYK4A_CAPTURE_CAPSULE,
    PYK4A_DEVICE_CAPSULE,
    SENSOR_ORIENTATIONS,
    WINDOWS_K4A_DIR,
    WINDOWS_K4ABT_DIR,
    K4ABTError,
    K4abtJoint,
    K4ABTLibraryError,
    K4abtSkeleton,
    K4aCalibration,
    K4aCalibrationCamera,
    K4aCalibrationExtrinsics,
    K4aCalibrationIntrinsicParameters,
    K4aCalibrationIntrinsics,
    K4aFloat2,
    K4aFloat3,
    K4aHardwareVersion,
    K4aMemoryDestroyCallback,
    K4aQuaternion,
    K4aVersion,
    TrackerConfiguration10,
    TrackerConfiguration11,
    TrackerCreateError,
    TrackerFailedError,
    capture_from_images,
    declare_calibration_api,
    declare_image_api,
    depth_xy_table,
    image_pixels,
    virtual_calibration,
)

log = logging.getLogger("skelfuse.sources.k4abt")

# The binary interface lives in k4a_abi.py; its names are re-exported here for the binding's users.
__all__ = [
    "ABIS",
    "JOINT_DTYPE",
    "K4ABT_ABI_ENV",
    "K4ABT_INSTALL_HINT",
    "K4ABT_INVALID_BODY_ID",
    "K4ABT_LIBRARY_ENV",
    "K4A_BUFFER_RESULT_SUCCEEDED",
    "K4A_BUFFER_RESULT_TOO_SMALL",
    "K4A_CALIBRATION_LENS_DISTORTION_MODEL_BROWN_CONRADY",
    "K4A_CALIBRATION_TYPE_DEPTH",
    "K4A_CALIBRATION_TYPE_NUM",
    "K4A_DEPTH_MODES",
    "K4A_IMAGE_FORMAT_DEPTH16",
    "K4A_IMAGE_FORMAT_IR16",
    "K4A_INSTALL_HINT",
    "K4A_LIBRARY_ENV",
    "K4A_RESULT_FAILED",
    "K4A_RESULT_SUCCEEDED",
    "K4A_WAIT_RESULT_FAILED",
    "K4A_WAIT_RESULT_SUCCEEDED",
    "K4A_WAIT_RESULT_TIMEOUT",
    "NFOV_METRIC_RADIUS",
    "PROCESSING_MODES",
    "PYK4A_CALIBRATION_CAPSULE",
    "PYK4A_CAPTURE_CAPSULE",
    "PYK4A_DEVICE_CAPSULE",
    "SENSOR_ORIENTATIONS",
    "WINDOWS_K4ABT_DIR",
    "WINDOWS_K4A_DIR",
    "BodyFrameData",
    "K4ABTError",
    "K4ABTLibraryError",
    "K4aCalibration",
    "K4aCalibrationCamera",
    "K4aCalibrationExtrinsics",
    "K4aCalibrationIntrinsicParameters",
    "K4aCalibrationIntrinsics",
    "K4aFloat2",
    "K4aFloat3",
    "K4aHardwareVersion",
    "K4aMemoryDestroyCallback",
    "K4aQuaternion",
    "K4aVersion",
    "K4abtJoint",
    "K4abtLibrary",
    "K4abtSkeleton",
    "Tracker",
    "TrackerConfiguration10",
    "TrackerConfiguration11",
    "TrackerCreateError",
    "TrackerFailedError",
    "TrackerSettings",
    "calibration_pointer",
    "capsule_pointer",
    "capture_from_images",
    "capture_handle",
    "declare_calibration_api",
    "declare_image_api",
    "depth_xy_table",
    "device_handle",
    "image_pixels",
    "load_k4a",
    "virtual_calibration",
]


# ------------------------------------------------------------------------------------------- capsules

_PyCapsule_GetPointer = ctypes.pythonapi.PyCapsule_GetPointer
_PyCapsule_GetPointer.restype = ctypes.c_void_p
_PyCapsule_GetPointer.argtypes = [ctypes.py_object, ctypes.c_char_p]


def capsule_pointer(capsule: Any, name: bytes) -> int:
    """The pointer a PyCapsule holds; K4ABTError if it is not a capsule of that name."""
    try:
        pointer = _PyCapsule_GetPointer(capsule, name)
    except (ValueError, TypeError) as exc:
        raise K4ABTError(
            f"expected a PyCapsule named {name.decode()!r} (a pyk4a handle), got "
            f"{type(capsule).__name__}: {exc}. Is the installed pyk4a >= 1.5?"
        ) from None
    if not pointer:
        raise K4ABTError(f"the PyCapsule {name.decode()!r} holds a NULL pointer")
    return int(pointer)


def capture_handle(capture: Any) -> int:
    """The ``k4a_capture_t`` of a pyk4a capture (its capsule points to the handle, so dereference it)."""
    holder = capsule_pointer(getattr(capture, "_capture_handle", None), PYK4A_CAPTURE_CAPSULE)
    handle = ctypes.c_void_p.from_address(holder).value
    if not handle:
        raise K4ABTError("the pyk4a capture holds a NULL k4a_capture_t")
    return int(handle)


def calibration_pointer(calibration: Any) -> int:
    """The ``k4a_calibration_t*`` of a pyk4a Calibration (passed to k4abt_tracker_create as is)."""
    return capsule_pointer(getattr(calibration, "_calibration_handle", None), PYK4A_CALIBRATION_CAPSULE)


def device_handle(device: Any) -> int:
    """The ``k4a_device_t`` of an opened pyk4a.PyK4A (its capsule points to the handle)."""
    holder = capsule_pointer(getattr(device, "_device_handle", None), PYK4A_DEVICE_CAPSULE)
    handle = ctypes.c_void_p.from_address(holder).value
    if not handle:
        raise K4ABTError("the pyk4a device holds a NULL k4a_device_t")
    return int(handle)


# -------------------------------------------------------------------------------------- library loading


def _candidates(env: str, linux: tuple[str, ...], windows: tuple[str, ...], short: str) -> list[str]:
    names: list[str] = []
    if os.environ.get(env):
        names.append(os.environ[env])
    if sys.platform == "win32":
        names += list(windows)
    else:
        names += list(linux)
    found = ctypes.util.find_library(short)
    if found and found not in names:
        names.append(found)
    return names


def _load(names: list[str], what: str, hint: str) -> tuple[ctypes.CDLL, str]:
    errors = []
    for name in names:
        if sys.platform == "win32" and os.path.isabs(name):
            with contextlib.suppress(OSError):
                os.add_dll_directory(os.path.dirname(name))  # k4abt.dll needs onnxruntime / cudnn beside it
        try:
            return ctypes.CDLL(name), name
        except OSError as exc:
            errors.append(f"{name}: {exc}")
    raise K4ABTLibraryError(f"cannot load {what} (tried {'; '.join(errors) or 'nothing'}); {hint}")


def load_k4a(path: str | os.PathLike[str] | None = None) -> ctypes.CDLL:
    """Load libk4a (Azure Kinect Sensor SDK, or Orbbec's K4A wrapper) and declare what skelfuse calls."""
    names = (
        [os.fspath(path)]
        if path is not None
        else _candidates(
            K4A_LIBRARY_ENV, ("libk4a.so.1.4", "libk4a.so"), ("k4a.dll", str(Path(WINDOWS_K4A_DIR) / "k4a.dll")), "k4a"
        )
    )
    lib, _ = _load(names, "libk4a (Azure Kinect Sensor SDK)", K4A_INSTALL_HINT)
    try:
        lib.k4a_device_get_installed_count.restype = ctypes.c_uint32
        lib.k4a_device_get_installed_count.argtypes = []
        lib.k4a_device_open.restype = ctypes.c_int
        lib.k4a_device_open.argtypes = [ctypes.c_uint32, ctypes.POINTER(ctypes.c_void_p)]
        lib.k4a_device_close.restype = None
        lib.k4a_device_close.argtypes = [ctypes.c_void_p]
        lib.k4a_device_get_serialnum.restype = ctypes.c_int
        lib.k4a_device_get_serialnum.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.POINTER(ctypes.c_size_t)]
        lib.k4a_device_get_version.restype = ctypes.c_int
        lib.k4a_device_get_version.argtypes = [ctypes.c_void_p, ctypes.POINTER(K4aHardwareVersion)]
        lib.k4a_device_get_sync_jack.restype = ctypes.c_int
        lib.k4a_device_get_sync_jack.argtypes = [
            ctypes.c_void_p,
            ctypes.POINTER(ctypes.c_bool),
            ctypes.POINTER(ctypes.c_bool),
        ]
    except AttributeError as exc:
        raise K4ABTLibraryError(
            f"the loaded libk4a lacks a function skelfuse needs ({exc}); {K4A_INSTALL_HINT}"
        ) from None
    return lib


@dataclass(frozen=True)
class TrackerSettings:
    """What ``k4abt_tracker_create`` and ``k4abt_tracker_set_temporal_smoothing`` get.

    Attributes
    ----------
    processing_mode : {"gpu", "cpu", "cuda", "tensorrt", "directml"}
    gpu_device_id : int
    model_path : str or None
        ONNX model; None: the SDK's default (full) model. The lite model (``dnn_model_2_0_lite_op11.onnx``)
        lets several trackers share one GPU. SDK 1.1+ only.
    sensor_orientation : {"default", "clockwise90", "counterclockwise90", "flip180"}
    temporal_smoothing : float in [0, 1]
    """

    processing_mode: str = "gpu"
    gpu_device_id: int = 0
    model_path: str | None = None
    sensor_orientation: str = "default"
    temporal_smoothing: float = 0.0

    def __post_init__(self) -> None:
        if self.processing_mode not in PROCESSING_MODES:
            raise ConfigError(
                f"tracker processing_mode: expected one of {', '.join(PROCESSING_MODES)}, "
                f"found {self.processing_mode!r}"
            )
        if self.sensor_orientation not in SENSOR_ORIENTATIONS:
            raise ConfigError(
                f"tracker sensor_orientation: expected one of {', '.join(SENSOR_ORIENTATIONS)}, "
                f"found {self.sensor_orientation!r}"
            )
        if not 0.0 <= self.temporal_smoothing <= 1.0:
            raise ConfigError(f"tracker temporal_smoothing: expected 0..1, found {self.temporal_smoothing}")

    @classmethod
    def from_config(cls, tracker: Any) -> TrackerSettings:
        """From a :class:`skelfuse.config.TrackerConfig`."""
        return cls(
            processing_mode=tracker.processing_mode,
            gpu_device_id=int(tracker.gpu_device_id),
            model_path=None if tracker.model_path is None else str(tracker.model_path),
            sensor_orientation=tracker.sensor_orientation,
            temporal_smoothing=float(tracker.temporal_smoothing),
        )


class K4abtLibrary:
    """A loaded libk4abt with its functions declared for the detected SDK generation.

    Parameters
    ----------
    path : path of the library; None searches ``SKELFUSE_K4ABT_LIBRARY``, the SDK's usual names and paths.
    abi : {"auto", "1.0", "1.1"}
        The tracker-configuration layout; "auto" (default, or ``SKELFUSE_K4ABT_ABI``) detects it from the
        exported symbols.

    Attributes
    ----------
    lib : ctypes.CDLL
    path : str
    abi : str
    """

    def __init__(self, path: str | os.PathLike[str] | None = None, *, abi: str = "auto") -> None:
        names = (
            [os.fspath(path)]
            if path is not None
            else _candidates(
                K4ABT_LIBRARY_ENV,
                ("libk4abt.so.1.1", "libk4abt.so.1.0", "libk4abt.so"),
                ("k4abt.dll", str(Path(WINDOWS_K4ABT_DIR) / "k4abt.dll")),
                "k4abt",
            )
        )
        self.lib, self.path = _load(names, "libk4abt (Azure Kinect Body Tracking SDK)", K4ABT_INSTALL_HINT)
        abi = os.environ.get(K4ABT_ABI_ENV, abi) if abi == "auto" else abi
        if abi == "auto":
            abi = "1.1" if hasattr(self.lib, "k4abt_frame_get_system_timestamp_nsec") else "1.0"
        if abi not in ABIS:
            raise ConfigError(f"k4abt ABI: expected one of auto, {', '.join(ABIS)}, found {abi!r}")
        self.abi = abi
        self._declare()

    @classmethod
    def load(cls, path: str | os.PathLike[str] | None = None, *, abi: str = "auto") -> K4abtLibrary:
        return cls(path, abi=abi)

    @property
    def config_struct(self) -> type[ctypes.Structure]:
        return TrackerConfiguration11 if self.abi == "1.1" else TrackerConfiguration10

    def _declare(self) -> None:
        lib = self.lib
        handle_p = ctypes.POINTER(ctypes.c_void_p)
        try:
            lib.k4abt_tracker_create.restype = ctypes.c_int
            lib.k4abt_tracker_create.argtypes = [ctypes.c_void_p, self.config_struct, handle_p]
            lib.k4abt_tracker_destroy.restype = None
            lib.k4abt_tracker_destroy.argtypes = [ctypes.c_void_p]
            lib.k4abt_tracker_set_temporal_smoothing.restype = None
            lib.k4abt_tracker_set_temporal_smoothing.argtypes = [ctypes.c_void_p, ctypes.c_float]
            lib.k4abt_tracker_enqueue_capture.restype = ctypes.c_int
            lib.k4abt_tracker_enqueue_capture.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int32]
            lib.k4abt_tracker_pop_result.restype = ctypes.c_int
            lib.k4abt_tracker_pop_result.argtypes = [ctypes.c_void_p, handle_p, ctypes.c_int32]
            lib.k4abt_tracker_shutdown.restype = None
            lib.k4abt_tracker_shutdown.argtypes = [ctypes.c_void_p]
            lib.k4abt_frame_release.restype = None
            lib.k4abt_frame_release.argtypes = [ctypes.c_void_p]
            lib.k4abt_frame_get_num_bodies.restype = ctypes.c_uint32
            lib.k4abt_frame_get_num_bodies.argtypes = [ctypes.c_void_p]
            lib.k4abt_frame_get_body_skeleton.restype = ctypes.c_int
            lib.k4abt_frame_get_body_skeleton.argtypes = [
                ctypes.c_void_p,
                ctypes.c_uint32,
                ctypes.POINTER(K4abtSkeleton),
            ]
            lib.k4abt_frame_get_body_id.restype = ctypes.c_uint32
            lib.k4abt_frame_get_body_id.argtypes = [ctypes.c_void_p, ctypes.c_uint32]
            lib.k4abt_frame_get_body_index_map.restype = ctypes.c_void_p
            lib.k4abt_frame_get_body_index_map.argtypes = [ctypes.c_void_p]
            lib.k4abt_frame_get_capture.restype = ctypes.c_void_p
            lib.k4abt_frame_get_capture.argtypes = [ctypes.c_void_p]
            device_ts = (
                "k4abt_frame_get_device_timestamp_usec" if self.abi == "1.1" else "k4abt_frame_get_timestamp_usec"
            )
            self._device_timestamp = getattr(lib, device_ts)
            self._device_timestamp.restype = ctypes.c_uint64
            self._device_timestamp.argtypes = [ctypes.c_void_p]
        except AttributeError as exc:
            raise K4ABTLibraryError(
                f"{self.path} lacks a function of the Body Tracking SDK {self.abi} ABI ({exc}); "
                f"set {K4ABT_ABI_ENV} to the installed SDK's generation or reinstall it. "
                f"{K4ABT_INSTALL_HINT}"
            ) from None
        self._system_timestamp = getattr(lib, "k4abt_frame_get_system_timestamp_nsec", None)
        if self._system_timestamp is not None:
            self._system_timestamp.restype = ctypes.c_uint64
            self._system_timestamp.argtypes = [ctypes.c_void_p]

    def make_config(self, settings: TrackerSettings) -> tuple[ctypes.Structure, bytes | None]:
        """The by-value configuration struct (and the model-path bytes it points to: keep them alive)."""
        orientation = SENSOR_ORIENTATIONS[settings.sensor_orientation]
        mode = PROCESSING_MODES[settings.processing_mode]
        if self.abi == "1.1":
            path = None if settings.model_path is None else os.fsencode(settings.model_path)
            return TrackerConfiguration11(orientation, mode, settings.gpu_device_id, path), path
        if settings.model_path is not None:
            raise TrackerCreateError(
                f"model_path {settings.model_path!r} needs Body Tracking SDK 1.1 or newer, but "
                f"{self.path} is a 1.0 SDK; upgrade (apt install libk4abt1.1-dev) or leave "
                "model_path out"
            )
        if settings.processing_mode not in ("gpu", "cpu"):
            log.warning(
                "Body Tracking SDK 1.0 knows only GPU or CPU processing: %r runs as GPU", settings.processing_mode
            )
        return TrackerConfiguration10(orientation, settings.processing_mode == "cpu", settings.gpu_device_id), None


@dataclass(frozen=True)
class BodyFrameData:
    """One popped body frame, copied out of the SDK.

    Attributes
    ----------
    device_time_us : int
        Device timestamp of the depth capture, µs.
    system_time_ns : int or None
        Host system timestamp of the capture, ns (CLOCK_MONOTONIC on Linux, QPC on Windows); None on SDK 1.0.
    body_ids : (B,) uint32
    positions : (B, 32, 3) float32, mm, depth camera frame
    orientations : (B, 32, 4) float32, w x y z
    confidence : (B, 32) uint8 (k4abt_joint_confidence_level_t; values outside 0-3 become 0 = NONE)
    depth : (H, W) uint16 mm or None
        The depth image of the capture the frame was computed from (``pop(images=...)`` only).
    body_index : (H, W) uint8 or None
        The tracker's body-index map: the index of the body (in this frame's order) per pixel, 255 background.
    """

    device_time_us: int
    system_time_ns: int | None
    body_ids: np.ndarray
    positions: np.ndarray
    orientations: np.ndarray
    confidence: np.ndarray
    depth: np.ndarray | None = None
    body_index: np.ndarray | None = None

    @property
    def n_bodies(self) -> int:
        return int(self.body_ids.shape[0])


class Tracker:
    """One ``k4abt_tracker_t`` (the SDK allows one per process).

    Parameters
    ----------
    library : K4abtLibrary
    calibration : int
        Address of a ``k4a_calibration_t`` (:func:`calibration_pointer`).
    settings : TrackerSettings

    Attributes
    ----------
    pending : int
        Captures enqueued whose result has not been popped yet.
    """

    def __init__(self, library: K4abtLibrary, calibration: int, settings: TrackerSettings) -> None:
        self.library = library
        self.settings = settings
        self.pending = 0
        self._handle: int | None = None
        config, self._model_path_bytes = library.make_config(settings)
        handle = ctypes.c_void_p()
        result = library.lib.k4abt_tracker_create(ctypes.c_void_p(calibration), config, ctypes.byref(handle))
        if result != K4A_RESULT_SUCCEEDED or not handle.value:
            model = settings.model_path or "the SDK's default model"
            raise TrackerCreateError(
                f"k4abt_tracker_create failed (processing_mode {settings.processing_mode}, "
                f"GPU {settings.gpu_device_id}, "
                f"model {model}, SDK ABI {library.abi}); check that the model file exists, the GPU / CUDA / cuDNN "
                "runtime the mode needs is installed (see the SDK's log: K4ABT_ENABLE_LOG_TO_A_FILE, "
                "K4ABT_LOG_LEVEL=i), and that no other tracker runs in this process"
            )
        self._handle = int(handle.value)
        library.lib.k4abt_tracker_set_temporal_smoothing(self._handle, ctypes.c_float(settings.temporal_smoothing))

    @property
    def closed(self) -> bool:
        return self._handle is None

    def _require(self) -> int:
        if self._handle is None:
            raise K4ABTError("the body tracker is closed")
        return self._handle

    def enqueue(self, capture: int, timeout_ms: int = 0) -> bool:
        """Queue a ``k4a_capture_t`` for tracking. False when the input queue stayed full for ``timeout_ms``.

        Raises TrackerFailedError on K4A_WAIT_RESULT_FAILED (a capture without depth, a dead tracker).
        """
        result = self.library.lib.k4abt_tracker_enqueue_capture(
            self._require(), ctypes.c_void_p(capture), _bounded(timeout_ms)
        )
        if result == K4A_WAIT_RESULT_SUCCEEDED:
            self.pending += 1
            return True
        if result == K4A_WAIT_RESULT_TIMEOUT:
            return False
        raise TrackerFailedError(
            f"k4abt_tracker_enqueue_capture failed (result {result}): the capture has no depth "
            "image, or the tracker stopped working"
        )

    def pop(self, timeout_ms: int = 0, *, images: ctypes.CDLL | None = None) -> BodyFrameData | None:
        """The next result, copied out and released; None if none came within ``timeout_ms``.

        With ``images`` (the loaded libk4a, :func:`declare_image_api` done), the frame's body-index map and its
        capture's depth image are copied out too (``depth``, ``body_index``): what a person cloud is made of.
        """
        frame = ctypes.c_void_p()
        result = self.library.lib.k4abt_tracker_pop_result(self._require(), ctypes.byref(frame), _bounded(timeout_ms))
        if result == K4A_WAIT_RESULT_TIMEOUT:
            return None
        if result != K4A_WAIT_RESULT_SUCCEEDED:
            self.pending = max(0, self.pending - 1)
            raise TrackerFailedError(
                f"k4abt_tracker_pop_result failed (result {result}): the tracker stopped working (GPU lost, shut down)"
            )
        self.pending = max(0, self.pending - 1)
        try:
            data = self._read_frame(int(frame.value or 0))
            if images is not None:
                depth, body_index = self._read_images(images, int(frame.value or 0))
                data = replace(data, depth=depth, body_index=body_index)
            return data
        finally:
            self.library.lib.k4abt_frame_release(frame)

    def _read_images(self, k4a: ctypes.CDLL, frame: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The frame's capture's depth image and its body-index map (None where the SDK gives none)."""
        lib = self.library.lib
        depth = body_index = None
        index_map = lib.k4abt_frame_get_body_index_map(frame)
        if index_map:
            try:
                body_index = image_pixels(k4a, index_map, np.uint8)
            finally:
                k4a.k4a_image_release(index_map)
        capture = lib.k4abt_frame_get_capture(frame)
        if capture:
            try:
                image = k4a.k4a_capture_get_depth_image(capture)
                if image:
                    try:
                        depth = image_pixels(k4a, image, np.uint16)
                    finally:
                        k4a.k4a_image_release(image)
            finally:
                k4a.k4a_capture_release(capture)
        return depth, body_index

    def _read_frame(self, frame: int) -> BodyFrameData:
        lib = self.library.lib
        n = int(lib.k4abt_frame_get_num_bodies(frame))
        raw = np.zeros(n * N_JOINTS, dtype=JOINT_DTYPE)
        ids = np.empty(n, dtype=np.uint32)
        skeleton = K4abtSkeleton()
        for index in range(n):
            if lib.k4abt_frame_get_body_skeleton(frame, index, ctypes.byref(skeleton)) != K4A_RESULT_SUCCEEDED:
                raise TrackerFailedError(f"k4abt_frame_get_body_skeleton failed for body {index} of {n}")
            raw[index * N_JOINTS : (index + 1) * N_JOINTS] = np.frombuffer(bytes(skeleton), dtype=JOINT_DTYPE)
            ids[index] = lib.k4abt_frame_get_body_id(frame, index)
        joints = raw.reshape(n, N_JOINTS)
        confidence = joints["confidence"]
        confidence = np.where((confidence >= 0) & (confidence <= 3), confidence, 0).astype(np.uint8)
        system = self.library._system_timestamp
        return BodyFrameData(
            device_time_us=int(self.library._device_timestamp(frame)),
            system_time_ns=None if system is None else int(system(frame)),
            body_ids=ids,
            positions=np.ascontiguousarray(joints["position"], dtype=np.float32),
            orientations=np.ascontiguousarray(joints["orientation"], dtype=np.float32),
            confidence=confidence,
        )

    def shutdown(self) -> None:
        """Stop accepting captures; results already queued can still be popped."""
        if self._handle is not None:
            self.library.lib.k4abt_tracker_shutdown(self._handle)

    def close(self) -> None:
        """Shut down and destroy the tracker (idempotent)."""
        if self._handle is None:
            return
        handle, self._handle = self._handle, None
        self.library.lib.k4abt_tracker_shutdown(handle)
        self.library.lib.k4abt_tracker_destroy(handle)
        self.pending = 0

    def __enter__(self) -> Tracker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _bounded(timeout_ms: int) -> int:
    """A finite, non-negative wait: skelfuse never passes K4A_WAIT_INFINITE (-1)."""
    if timeout_ms < 0:
        raise ValueError(f"timeout_ms must be >= 0 (skelfuse never waits forever), got {timeout_ms}")
    return min(int(timeout_ms), 2**31 - 1)
