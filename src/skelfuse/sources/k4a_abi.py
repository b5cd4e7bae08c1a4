"""The Azure Kinect SDKs' binary interface as :mod:`skelfuse.sources.k4abt` uses it: constants, the typed errors,
the ctypes structs (joints, skeletons, tracker configurations of both SDK generations, calibration), and the
libk4a image and calibration calls (declared on a loaded library). No library is loaded here.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging

import numpy as np

from skelfuse.schema.errors import ConfigError, ServiceError, SkelfuseError
from skelfuse.schema.skeleton import N_JOINTS

log = logging.getLogger("skelfuse.sources.k4abt")

# k4a_wait_result_t / k4a_result_t / k4a_buffer_result_t (k4atypes.h)
K4A_RESULT_SUCCEEDED = 0
K4A_RESULT_FAILED = 1
K4A_WAIT_RESULT_SUCCEEDED = 0
K4A_WAIT_RESULT_FAILED = 1
K4A_WAIT_RESULT_TIMEOUT = 2
K4A_BUFFER_RESULT_SUCCEEDED = 0
K4A_BUFFER_RESULT_TOO_SMALL = 2
K4ABT_INVALID_BODY_ID = 0xFFFFFFFF

PROCESSING_MODES: dict[str, int] = {"gpu": 0, "cpu": 1, "cuda": 2, "tensorrt": 3, "directml": 4}
"""k4abt_tracker_processing_mode_t (1.1+)."""
SENSOR_ORIENTATIONS: dict[str, int] = {"default": 0, "clockwise90": 1, "counterclockwise90": 2, "flip180": 3}
"""k4abt_sensor_orientation_t."""
ABIS: tuple[str, ...] = ("1.0", "1.1")

PYK4A_CAPTURE_CAPSULE = b"pyk4a capture handle"
PYK4A_CALIBRATION_CAPSULE = b"pyk4a calibration handle"
PYK4A_DEVICE_CAPSULE = b"pyk4a device handle"

K4ABT_LIBRARY_ENV = "SKELFUSE_K4ABT_LIBRARY"
K4A_LIBRARY_ENV = "SKELFUSE_K4A_LIBRARY"
K4ABT_ABI_ENV = "SKELFUSE_K4ABT_ABI"

WINDOWS_K4ABT_DIR = r"C:\Program Files\Azure Kinect Body Tracking SDK\sdk\windows-desktop\amd64\release\bin"
WINDOWS_K4A_DIR = r"C:\Program Files\Azure Kinect SDK v1.4.1\sdk\windows-desktop\amd64\release\bin"

K4ABT_INSTALL_HINT = (
    "install the Azure Kinect Body Tracking SDK: on Ubuntu add Microsoft's package repository and "
    "`sudo apt install libk4abt1.1-dev` (it brings libk4a1.4); on Windows run the Body Tracking SDK installer "
    f"(the DLLs land in {WINDOWS_K4ABT_DIR}). Or point {K4ABT_LIBRARY_ENV} at libk4abt.so / k4abt.dll. "
    "See docs/kinect.md"
)
K4A_INSTALL_HINT = (
    "install the Azure Kinect Sensor SDK: on Ubuntu `sudo apt install libk4a1.4 libk4a1.4-dev k4a-tools` from "
    "Microsoft's package repository; on Windows the Azure Kinect SDK 1.4.1 installer; for an Orbbec Femto Bolt, "
    f"Orbbec's OrbbecSDK-K4A-Wrapper. Or point {K4A_LIBRARY_ENV} at libk4a.so / k4a.dll. See docs/kinect.md"
)


class K4ABTError(SkelfuseError):
    """Something went wrong in the body-tracking binding."""


class K4ABTLibraryError(K4ABTError, ServiceError):
    """libk4abt (or libk4a) cannot be found or loaded, or lacks a function: fatal, retrying will not help."""


class TrackerCreateError(K4ABTError):
    """``k4abt_tracker_create`` failed (no GPU / CUDA / model file, a bad calibration)."""


class TrackerFailedError(K4ABTError):
    """``k4abt_tracker_enqueue_capture`` or ``k4abt_tracker_pop_result`` returned K4A_WAIT_RESULT_FAILED."""


# ------------------------------------------------------------------------------------------------ structs


class K4aFloat3(ctypes.Structure):
    """``k4a_float3_t`` (a union of {x, y, z} and float v[3]: same bytes)."""

    _fields_ = [("x", ctypes.c_float), ("y", ctypes.c_float), ("z", ctypes.c_float)]


class K4aQuaternion(ctypes.Structure):
    """``k4a_quaternion_t`` (a union of {w, x, y, z} and float v[4])."""

    _fields_ = [("w", ctypes.c_float), ("x", ctypes.c_float), ("y", ctypes.c_float), ("z", ctypes.c_float)]


class K4abtJoint(ctypes.Structure):
    """``k4abt_joint_t``: position (mm), orientation (w, x, y, z), confidence_level (enum, int): 32 bytes."""

    _fields_ = [("position", K4aFloat3), ("orientation", K4aQuaternion), ("confidence_level", ctypes.c_int)]


class K4abtSkeleton(ctypes.Structure):
    """``k4abt_skeleton_t``: 32 joints."""

    _fields_ = [("joints", K4abtJoint * N_JOINTS)]


class TrackerConfiguration11(ctypes.Structure):
    """``k4abt_tracker_configuration_t`` of Body Tracking SDK 1.1+."""

    _fields_ = [
        ("sensor_orientation", ctypes.c_int),
        ("processing_mode", ctypes.c_int),
        ("gpu_device_id", ctypes.c_int32),
        ("model_path", ctypes.c_char_p),
    ]


class TrackerConfiguration10(ctypes.Structure):
    """``k4abt_tracker_configuration_t`` of Body Tracking SDK 1.0.x (``cpu_only_mode``; 1.0.1 made it an enum
    ``processing_mode`` GPU=0 / CPU=1 of the same size after padding)."""

    _fields_ = [
        ("sensor_orientation", ctypes.c_int),
        ("cpu_only_mode", ctypes.c_bool),
        ("gpu_device_id", ctypes.c_int32),
    ]


class K4aVersion(ctypes.Structure):
    _fields_ = [("major", ctypes.c_uint32), ("minor", ctypes.c_uint32), ("iteration", ctypes.c_uint32)]


class K4aHardwareVersion(ctypes.Structure):
    """``k4a_hardware_version_t``."""

    _fields_ = [
        ("rgb", K4aVersion),
        ("depth", K4aVersion),
        ("audio", K4aVersion),
        ("depth_sensor", K4aVersion),
        ("firmware_build", ctypes.c_int),
        ("firmware_signature", ctypes.c_int),
    ]


# ------------------------------------------------------------------- calibration (k4atypes.h, SDK 1.4)
# Transcribed from the Sensor SDK's k4atypes.h; tests/fake_k4a/k4a_abi.h holds the same transcription in C and
# the suite checks that both agree (sizes and offsets). Neither is checked against the real SDK here.

K4A_DEPTH_MODES: dict[tuple[int, int], int] = {(320, 288): 1, (640, 576): 2, (512, 512): 3, (1024, 1024): 4}
"""k4a_depth_mode_t of each depth image size: NFOV 2x2 binned, NFOV unbinned, WFOV 2x2 binned, WFOV unbinned."""
K4A_CALIBRATION_TYPE_NUM = 4
K4A_CALIBRATION_LENS_DISTORTION_MODEL_BROWN_CONRADY = 4
K4A_IMAGE_FORMAT_DEPTH16 = 4
K4A_IMAGE_FORMAT_IR16 = 5
NFOV_METRIC_RADIUS = 1.7
"""Largest normalized image radius the distortion model is valid for (a real NFOV unbinned calibration holds
about 1.7); a pinhole virtual camera has no distortion, so any value covering the image will do."""


class K4aCalibrationExtrinsics(ctypes.Structure):
    """``k4a_calibration_extrinsics_t``: row-major rotation[9], translation[3] (mm)."""

    _fields_ = [("rotation", ctypes.c_float * 9), ("translation", ctypes.c_float * 3)]


class K4aCalibrationIntrinsicParameters(ctypes.Structure):
    """``k4a_calibration_intrinsic_parameters_t`` (a union of these 15 named floats and float v[15])."""

    _fields_ = [
        (name, ctypes.c_float)
        for name in (
            "cx",
            "cy",
            "fx",
            "fy",
            "k1",
            "k2",
            "k3",
            "k4",
            "k5",
            "k6",
            "codx",
            "cody",
            "p2",
            "p1",
            "metric_radius",
        )
    ]


class K4aCalibrationIntrinsics(ctypes.Structure):
    """``k4a_calibration_intrinsics_t``."""

    _fields_ = [
        ("type", ctypes.c_int),
        ("parameter_count", ctypes.c_uint),
        ("parameters", K4aCalibrationIntrinsicParameters),
    ]


class K4aCalibrationCamera(ctypes.Structure):
    """``k4a_calibration_camera_t``."""

    _fields_ = [
        ("extrinsics", K4aCalibrationExtrinsics),
        ("intrinsics", K4aCalibrationIntrinsics),
        ("resolution_width", ctypes.c_int),
        ("resolution_height", ctypes.c_int),
        ("metric_radius", ctypes.c_float),
    ]


class K4aCalibration(ctypes.Structure):
    """``k4a_calibration_t``."""

    _fields_ = [
        ("depth_camera_calibration", K4aCalibrationCamera),
        ("color_camera_calibration", K4aCalibrationCamera),
        ("extrinsics", (K4aCalibrationExtrinsics * K4A_CALIBRATION_TYPE_NUM) * K4A_CALIBRATION_TYPE_NUM),
        ("depth_mode", ctypes.c_int),
        ("color_resolution", ctypes.c_int),
    ]


def virtual_calibration(fx: float, fy: float, cx: float, cy: float, width: int, height: int) -> K4aCalibration:
    """A ``k4a_calibration_t`` for a virtual depth camera: pinhole intrinsics as a Brown-Conrady model with every
    distortion coefficient 0, colour camera off, identity extrinsics between all sensors.

    The principal point is in the same pixel convention as :class:`skelfuse.fusion.camera.Intrinsics` (the
    centre of the top-left pixel at (0, 0)), which is k4a's for 2D pixel coordinates. The body tracker only
    accepts the depth modes' image sizes (:data:`K4A_DEPTH_MODES`): a virtual camera takes the reference
    sensor's size, so it is one of them.
    """
    if (width, height) not in K4A_DEPTH_MODES:
        raise ConfigError(
            f"a virtual depth camera of {width}x{height} has no k4a depth mode; use one of "
            f"{', '.join(f'{w}x{h}' for w, h in K4A_DEPTH_MODES)} (the reference sensor's depth mode)"
        )
    calibration = K4aCalibration()
    identity = K4aCalibrationExtrinsics((ctypes.c_float * 9)(1, 0, 0, 0, 1, 0, 0, 0, 1), (ctypes.c_float * 3)(0, 0, 0))
    depth = calibration.depth_camera_calibration
    depth.extrinsics = identity
    depth.intrinsics.type = K4A_CALIBRATION_LENS_DISTORTION_MODEL_BROWN_CONRADY
    depth.intrinsics.parameter_count = 14
    parameters = depth.intrinsics.parameters
    parameters.cx, parameters.cy, parameters.fx, parameters.fy = cx, cy, fx, fy
    parameters.metric_radius = NFOV_METRIC_RADIUS
    depth.resolution_width, depth.resolution_height = width, height
    depth.metric_radius = NFOV_METRIC_RADIUS
    calibration.color_camera_calibration.extrinsics = identity
    for row in calibration.extrinsics:
        for index in range(K4A_CALIBRATION_TYPE_NUM):
            row[index] = identity
    calibration.depth_mode = K4A_DEPTH_MODES[(width, height)]
    calibration.color_resolution = 0  # K4A_COLOR_RESOLUTION_OFF
    return calibration


K4aMemoryDestroyCallback = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p)
"""``k4a_memory_destroy_cb_t``: called by libk4a when the last reference to an image made from our buffer goes."""

_PINNED: dict[int, np.ndarray] = {}
_PIN_COUNTER = iter(range(1, 2**62))


@K4aMemoryDestroyCallback
def _unpin_buffer(_buffer: int | None, context: int | None) -> None:
    _PINNED.pop(int(context or 0), None)


def declare_image_api(lib: ctypes.CDLL) -> None:
    """Declare the libk4a functions that build a capture from our own images (idempotent)."""
    handle_p = ctypes.POINTER(ctypes.c_void_p)
    try:
        lib.k4a_image_create_from_buffer.restype = ctypes.c_int
        lib.k4a_image_create_from_buffer.argtypes = [
            ctypes.c_int,
            ctypes.c_int,
            ctypes.c_int,
            ctypes.c_int,
            ctypes.c_void_p,
            ctypes.c_size_t,
            K4aMemoryDestroyCallback,
            ctypes.c_void_p,
            handle_p,
        ]
        lib.k4a_image_release.restype = None
        lib.k4a_image_release.argtypes = [ctypes.c_void_p]
        lib.k4a_image_set_device_timestamp_usec.restype = None
        lib.k4a_image_set_device_timestamp_usec.argtypes = [ctypes.c_void_p, ctypes.c_uint64]
        lib.k4a_capture_create.restype = ctypes.c_int
        lib.k4a_capture_create.argtypes = [handle_p]
        lib.k4a_capture_release.restype = None
        lib.k4a_capture_release.argtypes = [ctypes.c_void_p]
        lib.k4a_capture_set_depth_image.restype = None
        lib.k4a_capture_set_depth_image.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
        lib.k4a_capture_set_ir_image.restype = None
        lib.k4a_capture_set_ir_image.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
        lib.k4a_capture_get_depth_image.restype = ctypes.c_void_p
        lib.k4a_capture_get_depth_image.argtypes = [ctypes.c_void_p]
        lib.k4a_image_get_buffer.restype = ctypes.c_void_p
        lib.k4a_image_get_buffer.argtypes = [ctypes.c_void_p]
        for getter in ("k4a_image_get_width_pixels", "k4a_image_get_height_pixels", "k4a_image_get_stride_bytes"):
            getattr(lib, getter).restype = ctypes.c_int
            getattr(lib, getter).argtypes = [ctypes.c_void_p]
        lib.k4a_image_get_format.restype = ctypes.c_int
        lib.k4a_image_get_format.argtypes = [ctypes.c_void_p]
    except AttributeError as exc:
        raise K4ABTLibraryError(f"the loaded libk4a lacks an image function ({exc}); {K4A_INSTALL_HINT}") from None


def image_pixels(lib: ctypes.CDLL, image: int, dtype: type[np.generic]) -> np.ndarray:
    """A copy of a ``k4a_image_t``'s pixels, (height, width) of ``dtype``, read row by row with the image's
    stride (rows may be padded). The image is not released here."""
    width = int(lib.k4a_image_get_width_pixels(image))
    height = int(lib.k4a_image_get_height_pixels(image))
    stride = int(lib.k4a_image_get_stride_bytes(image))
    item = np.dtype(dtype).itemsize
    buffer = lib.k4a_image_get_buffer(image)
    if not buffer or width <= 0 or height <= 0 or stride < width * item:
        raise K4ABTError(f"a k4a image of {width} x {height} pixels, stride {stride} bytes, cannot be read")
    raw = np.frombuffer(ctypes.string_at(buffer, stride * height), dtype=np.uint8).reshape(height, stride)
    return np.ascontiguousarray(raw[:, : width * item]).view(dtype).reshape(height, width)


class K4aFloat2(ctypes.Structure):
    """``k4a_float2_t`` (a union of {x, y} and float v[2]: same bytes)."""

    _fields_ = [("x", ctypes.c_float), ("y", ctypes.c_float)]


K4A_CALIBRATION_TYPE_DEPTH = 0
"""``k4a_calibration_type_t`` of the depth camera."""
_XY_TABLES: dict[tuple[str, bytes], np.ndarray] = {}
"""xy tables already built, by (library path, calibration bytes)."""


def declare_calibration_api(lib: ctypes.CDLL) -> None:
    """Declare ``k4a_calibration_2d_to_3d`` (k4a.h, Sensor SDK 1.4; idempotent)::

    k4a_result_t k4a_calibration_2d_to_3d(const k4a_calibration_t *calibration,
                                          const k4a_float2_t *source_point2d, const float source_depth_mm,
                                          const k4a_calibration_type_t source_camera,
                                          const k4a_calibration_type_t target_camera,
                                          k4a_float3_t *target_point3d_mm, int *valid);
    """
    try:
        function = lib.k4a_calibration_2d_to_3d
    except AttributeError:
        raise K4ABTLibraryError(f"the loaded libk4a lacks k4a_calibration_2d_to_3d; {K4A_INSTALL_HINT}") from None
    function.restype = ctypes.c_int
    function.argtypes = [
        ctypes.c_void_p,
        ctypes.POINTER(K4aFloat2),
        ctypes.c_float,
        ctypes.c_int,
        ctypes.c_int,
        ctypes.POINTER(K4aFloat3),
        ctypes.POINTER(ctypes.c_int),
    ]


def depth_xy_table(lib: ctypes.CDLL, calibration: int) -> np.ndarray:
    """The depth camera's xy table (the SDK's fastpointcloud sample): for every depth pixel (u, v), the ray
    (X/Z, Y/Z) the SDK's lens model gives it, from ``k4a_calibration_2d_to_3d`` at a depth of 1 mm, depth
    camera to depth camera. A point of depth d at that pixel is then (x d, y d, d): the lens distortion applied
    to a whole image as one multiplication (:func:`skelfuse.fusion.depth.cloud.lift_xy_table`).

    Built once per sensor and depth mode (the calibration is the depth mode's; kept per calibration, read-only):
    one SDK call per pixel, about 1.2 s of CPU for 640 x 576 from Python (against the fake library). Pixels the
    model calls invalid (``valid`` = 0: beyond the lens's metric radius, or no convergence) are NaN, so their
    points are dropped.

    Parameters
    ----------
    lib : libk4a (:func:`load_k4a`); the function is declared here.
    calibration : address of the device's ``k4a_calibration_t`` (:func:`calibration_pointer`).

    Returns
    -------
    (H, W, 2) float32, H x W the calibration's depth resolution.
    """
    declare_calibration_api(lib)
    key = (str(getattr(lib, "_name", id(lib))), ctypes.string_at(calibration, ctypes.sizeof(K4aCalibration)))
    cached = _XY_TABLES.get(key)
    if cached is not None:  # the same calibration again (a reopened device, several takes of one sensor)
        return cached
    camera = K4aCalibration.from_address(calibration).depth_camera_calibration
    width, height = int(camera.resolution_width), int(camera.resolution_height)
    if not (0 < width <= 4096 and 0 < height <= 4096):
        raise K4ABTError(f"the depth camera calibration has a resolution of {width} x {height} pixels")
    function = lib.k4a_calibration_2d_to_3d
    depth = K4A_CALIBRATION_TYPE_DEPTH
    pixel, ray, valid = K4aFloat2(), K4aFloat3(), ctypes.c_int()
    pixel_p, ray_p, valid_p, unit = ctypes.byref(pixel), ctypes.byref(ray), ctypes.byref(valid), ctypes.c_float(1.0)
    table = np.full((height, width, 2), np.nan, dtype=np.float32)
    for v in range(height):
        pixel.y = v
        for u in range(width):
            pixel.x = u
            if function(calibration, pixel_p, unit, depth, depth, ray_p, valid_p) != K4A_RESULT_SUCCEEDED:
                raise K4ABTError(
                    f"k4a_calibration_2d_to_3d failed at depth pixel ({u}, {v}): the device's calibration has "
                    "an unknown lens model or bad focal lengths"
                )
            if valid.value:
                table[v, u] = ray.x, ray.y
    table.flags.writeable = False
    _XY_TABLES[key] = table
    while len(_XY_TABLES) > 16:  # a few sensors' depth modes; never grows without bound
        _XY_TABLES.pop(next(iter(_XY_TABLES)))
    return table


def _image_from_array(lib: ctypes.CDLL, pixels: np.ndarray, image_format: int, device_time_us: int) -> int:
    """A ``k4a_image_t`` around a copy of ``pixels`` (uint16, H x W, rows ``2 W`` bytes apart), kept alive
    until libk4a releases the image (its release callback unpins it)."""
    buffer = np.ascontiguousarray(pixels, dtype="<u2")
    if buffer.ndim != 2:
        raise ValueError(f"an image must be 2-D (H, W), got shape {buffer.shape}")
    height, width = buffer.shape
    key = next(_PIN_COUNTER)
    _PINNED[key] = buffer
    image = ctypes.c_void_p()
    result = lib.k4a_image_create_from_buffer(
        image_format,
        width,
        height,
        width * 2,
        buffer.ctypes.data,
        buffer.nbytes,
        _unpin_buffer,
        key,
        ctypes.byref(image),
    )
    if result != K4A_RESULT_SUCCEEDED or not image.value:
        _PINNED.pop(key, None)
        raise K4ABTError(f"k4a_image_create_from_buffer failed for a {width}x{height} image (format {image_format})")
    lib.k4a_image_set_device_timestamp_usec(image, device_time_us)
    return int(image.value)


def capture_from_images(
    lib: ctypes.CDLL, depth_mm: np.ndarray, ir: np.ndarray | None = None, *, device_time_us: int = 0
) -> int:
    """A new ``k4a_capture_t`` holding a DEPTH16 image (and an IR16 image) made from our arrays; the caller
    releases it with ``k4a_capture_release`` (the capture holds the only references to its images).

    Parameters
    ----------
    lib : libk4a with :func:`declare_image_api` done.
    depth_mm : (H, W) uint16 mm, 0 = invalid (``fusion.depth.render.to_k4a_depth``).
    ir : optional (H, W) uint16 of the same size.
    device_time_us : the images' device timestamp (the body frame carries it back).
    """
    if ir is not None and np.shape(ir) != np.shape(depth_mm):
        raise ValueError(f"IR image {np.shape(ir)} and depth image {np.shape(depth_mm)} differ in size")
    capture = ctypes.c_void_p()
    if lib.k4a_capture_create(ctypes.byref(capture)) != K4A_RESULT_SUCCEEDED or not capture.value:
        raise K4ABTError("k4a_capture_create failed")
    try:
        for pixels, image_format, setter in (
            (depth_mm, K4A_IMAGE_FORMAT_DEPTH16, lib.k4a_capture_set_depth_image),
            (ir, K4A_IMAGE_FORMAT_IR16, lib.k4a_capture_set_ir_image),
        ):
            if pixels is None:
                continue
            image = _image_from_array(lib, pixels, image_format, device_time_us)
            setter(capture, image)  # the capture takes its own reference
            lib.k4a_image_release(image)
    except BaseException:
        lib.k4a_capture_release(capture)
        raise
    return int(capture.value)


JOINT_DTYPE = np.dtype(
    {
        "names": ["position", "orientation", "confidence"],
        "formats": [("<f4", (3,)), ("<f4", (4,)), "<i4"],
        "offsets": [0, 12, 28],
        "itemsize": 32,
    }
)
"""numpy view of one ``k4abt_joint_t`` (little-endian, as every platform the SDK runs on)."""
