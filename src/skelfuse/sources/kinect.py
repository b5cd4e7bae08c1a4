"""Skeleton sources for real hardware and its recordings: an Azure Kinect / Femto Bolt device, a ``.mkv``
recording replayed through the body tracker, and the recorded skeleton files of :mod:`.recorded`.

Every source implements :class:`SkeletonSource`::

    source.open()                       # device: open by serial, configure, start cameras, create tracker
    frame = source.read(timeout_s)      # a SensorFrame, or None if none came within timeout_s
    source.close()                      # idempotent; never raises
    # end of a finite source: read() raises EndOfStream

A live device runs under :func:`skelfuse.sources.reconnect.run_with_reconnect`: an unplugged sensor, a tracker
that stops answering or cannot be created is logged, the source is closed and reopened after an exponential
backoff, until ``should_exit()``. Only errors retrying cannot fix (pyk4a or the SDK missing, a bad config) propagate.

Rigs with wired sync must start the subordinates before the master: :func:`kinect_start_order` gives that
order and :func:`start_rig` opens the local sources in it.

pyk4a (the ``kinect`` extra) is imported lazily, only by the code paths that need it; without it they raise
:class:`KinectUnavailable` naming the extra and the SDKs.
"""

from __future__ import annotations

import importlib
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any, Protocol, runtime_checkable

import numpy as np

from skelfuse.config import RigConfig, SensorConfig
from skelfuse.fusion.depth.cloud import person_clouds
from skelfuse.schema.errors import ConfigError, DataError, ServiceError, SkelfuseError
from skelfuse.schema.frames import SensorFrame
from skelfuse.sources import recorded
from skelfuse.sources.k4abt import (
    K4A_INSTALL_HINT,
    K4ABT_INSTALL_HINT,
    BodyFrameData,
    K4abtLibrary,
    Tracker,
    TrackerFailedError,
    TrackerSettings,
    calibration_pointer,
    capture_handle,
    declare_image_api,
    depth_xy_table,
    load_k4a,
)
from skelfuse.wire.clouds import PersonCloudsFrame

log = logging.getLogger("skelfuse.sources.kinect")

PYK4A_INSTALL_HINT = (
    "pip install 'skelfuse[kinect]' (pyk4a; it builds only where the Azure Kinect Sensor SDK is installed: "
    f"{K4A_INSTALL_HINT}). Body tracking also needs the Body Tracking SDK: {K4ABT_INSTALL_HINT}"
)


# ------------------------------------------------------------------------------------------------ errors


class EndOfStream(SkelfuseError):
    """A finite source (a recording) has no more frames."""


class KinectError(SkelfuseError):
    """A run-time problem with a device: a daemon logs it and reconnects."""


class KinectUnavailable(KinectError, ServiceError):
    """pyk4a (the ``kinect`` extra) or the Azure Kinect SDK is not installed: fatal, retrying will not help."""


class SensorNotFound(KinectError):
    """No connected device has the configured serial (unplugged, powered off, or opened by another process)."""


class SensorDisconnected(KinectError):
    """The device stopped delivering captures (unplugged, USB reset, power loss)."""


class TrackerStalled(KinectError):
    """Captures flow but the body tracker gave no result for too long."""


# ----------------------------------------------------------------------------------------- interface


@runtime_checkable
class SkeletonSource(Protocol):
    """Where one sensor's skeletons come from."""

    sensor_id: str

    def open(self) -> None:
        """Acquire the device / file. Raises a typed SkelfuseError."""
        ...

    def read(self, timeout_s: float) -> SensorFrame | None:
        """The next frame, or None if none came within ``timeout_s``; EndOfStream when a finite source ends."""
        ...

    def close(self) -> None:
        """Release everything (idempotent, never raises)."""
        ...


def import_pyk4a() -> ModuleType:
    """``import pyk4a``, or KinectUnavailable saying what to install."""
    try:
        return importlib.import_module("pyk4a")
    except ImportError as exc:  # not installed, or installed but libk4a.so is missing
        raise KinectUnavailable(f"cannot import pyk4a ({exc}); {PYK4A_INSTALL_HINT}") from None


# ----------------------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class DeviceSettings:
    """How one device is opened and started (from its ``[[sensors]]`` entry and the rig's ``[sync] fps``).

    Attributes
    ----------
    serial : str
    depth_mode : str
        One of skelfuse.config.DEPTH_MODES (pyk4a.DepthMode member name).
    color_resolution : str or None
        None: colour camera off (body tracking needs depth only).
    fps : int
        5, 15 or 30.
    sync_role : {"standalone", "master", "subordinate"}
    subordinate_delay_us : int
        Subordinates: depth capture delay after the master's sync pulse (distinct, >= 160 µs apart). 0 otherwise.
    tracker : TrackerSettings
    """

    serial: str
    depth_mode: str = "NFOV_UNBINNED"
    color_resolution: str | None = None
    fps: int = 30
    sync_role: str = "standalone"
    subordinate_delay_us: int = 0
    tracker: TrackerSettings = field(default_factory=TrackerSettings)

    @classmethod
    def from_sensor(cls, sensor: SensorConfig, fps: float) -> DeviceSettings:
        if sensor.kinect is None:
            raise ConfigError(f'sensor {sensor.id!r} has source = {sensor.source!r}, not "kinect"')
        return cls(
            serial=sensor.kinect.serial,
            depth_mode=sensor.kinect.depth_mode,
            color_resolution=sensor.kinect.color_resolution,
            fps=round(fps),
            sync_role=sensor.sync.role,
            subordinate_delay_us=sensor.sync.delay_us if sensor.sync.role == "subordinate" else 0,
            tracker=TrackerSettings.from_config(sensor.kinect.tracker),
        )

    def pyk4a_config(self, pyk4a: Any) -> Any:
        """The ``pyk4a.Config`` these settings describe."""
        color = (
            pyk4a.ColorResolution.OFF
            if self.color_resolution is None
            else getattr(pyk4a.ColorResolution, f"RES_{self.color_resolution}")
        )
        return pyk4a.Config(
            color_resolution=color,
            color_format=pyk4a.ImageFormat.COLOR_BGRA32,
            depth_mode=getattr(pyk4a.DepthMode, self.depth_mode),
            camera_fps=getattr(pyk4a.FPS, f"FPS_{self.fps}"),
            # with colour on, only depth+colour pairs (the calibration tools need both); off: depth alone
            synchronized_images_only=self.color_resolution is not None,
            depth_delay_off_color_usec=0,
            wired_sync_mode=getattr(pyk4a.WiredSyncMode, self.sync_role.upper()),
            subordinate_delay_off_master_usec=self.subordinate_delay_us,
            disable_streaming_indicator=False,
        )


def kinect_start_order(sensors: Sequence[SensorConfig]) -> list[SensorConfig]:
    """Kinect sensors in the order they must start: subordinates (by delay), standalone ones, the master last.

    A master starts emitting sync pulses as soon as its cameras start; a subordinate started later misses
    them and its first frames are not synchronized, so every subordinate starts first.
    """
    kinects = [s for s in sensors if s.source == "kinect"]
    rank = {"subordinate": 0, "standalone": 1, "master": 2}
    return sorted(kinects, key=lambda s: (rank[s.sync.role], s.sync.delay_us))


def start_rig(
    sources: Sequence[tuple[str, SkeletonSource]], *, settle_s: float = 0.0, sleep: Callable[[float], None] = time.sleep
) -> None:
    """Open ``(role, source)`` pairs in start order (subordinates, standalone, master); close all on failure.

    ``settle_s`` is waited between the last subordinate and the master (the SDK needs none: starting a
    subordinate returns once it waits for the sync signal).
    """
    rank = {"subordinate": 0, "standalone": 1, "master": 2}
    ordered = sorted(sources, key=lambda pair: rank[pair[0]])
    opened: list[SkeletonSource] = []
    try:
        for role, source in ordered:
            if role == "master" and opened and settle_s > 0:
                sleep(settle_s)
            source.open()
            opened.append(source)
    except BaseException:
        for source in reversed(opened):
            source.close()
        raise


# ------------------------------------------------------------------------------------- frame assembly


class _FrameAssembler:
    """BodyFrameData -> SensorFrame: sequence from the device clock, host time from the capture's system stamp."""

    def __init__(self, sensor_id: str, fps: float) -> None:
        self.sensor_id = sensor_id
        self.period_us = 1e6 / fps
        self.first_us: int | None = None

    def __call__(self, body: BodyFrameData) -> SensorFrame:
        if self.first_us is None:
            self.first_us = body.device_time_us
        sequence = round((body.device_time_us - self.first_us) / self.period_us)  # a gap is a drop
        return SensorFrame(
            sensor_id=self.sensor_id,
            sequence=int(sequence),
            device_time_us=int(body.device_time_us),
            host_time_ns=_host_time_ns(body.system_time_ns),
            body_ids=body.body_ids,
            positions=body.positions,
            orientations=body.orientations,
            confidence=body.confidence,
        )


def _host_time_ns(system_ns: int | None) -> int:
    """Wall-clock ns of the capture: the SDK's system stamp is the monotonic clock; map it when plausible."""
    now_wall, now_mono = time.time_ns(), time.monotonic_ns()
    if system_ns is None or not 0 <= now_mono - system_ns < 10_000_000_000:
        return now_wall
    return now_wall - (now_mono - system_ns)


def body_clouds(
    body: BodyFrameData, frame: SensorFrame, xy_table: np.ndarray, voxel_mm: float
) -> PersonCloudsFrame | None:
    """Each tracked body's person cloud of one body frame (its depth image masked by the body-index map, the
    map's index b being the frame's b-th body, lifted through the device's xy table, lens distortion included:
    :func:`skelfuse.sources.k4abt.depth_xy_table`; voxelized); None when the frame came without its images."""
    if body.depth is None or body.body_index is None:
        return None
    clouds = [
        c
        for c in person_clouds(body.depth, body.body_index, xy_table, voxel_mm=voxel_mm)
        if c.body_index < body.n_bodies
    ]
    return PersonCloudsFrame(
        sensor_id=frame.sensor_id,
        sequence=frame.sequence,
        device_timestamp_us=frame.device_time_us,
        host_timestamp_ns=frame.host_time_ns,
        voxel_mm=voxel_mm,
        body_ids=np.array([body.body_ids[c.body_index] for c in clouds], dtype=np.uint32),
        clouds=tuple(c.points for c in clouds),
    )


# ----------------------------------------------------------------------------------------- device source


class KinectSource:
    """A live Azure Kinect DK (or Femto Bolt through Orbbec's K4A wrapper) with body tracking.

    Parameters
    ----------
    settings : DeviceSettings
    sensor_id : str, optional
        Default: the serial.
    pyk4a : module, optional
        The pyk4a module (tests inject a fake); default ``import pyk4a``.
    k4abt : K4abtLibrary or path, optional
        Default: :class:`K4abtLibrary` found on the system.
    stall_timeout_s : float
        Captures without any tracker result (or no capture at all) for this long raise TrackerStalled /
        SensorDisconnected.
    enqueue_timeout_ms : int
        How long one capture may wait for room in the tracker's input queue before it is dropped.
    clouds_voxel_mm : float, optional
        Depth / hybrid mode (``[fusion] mode``): also make each body's person cloud (the capture's depth image
        masked by the tracker's body-index map, lifted through the device's xy table, lens distortion included,
        built once at :meth:`open` with ``k4a_calibration_2d_to_3d``; voxelized), for :meth:`clouds_at`. None:
        skeletons only.

    Attributes
    ----------
    captures, dropped_captures, results : int
        Counters since open().
    """

    def __init__(
        self,
        settings: DeviceSettings,
        *,
        sensor_id: str | None = None,
        pyk4a: Any = None,
        k4abt: K4abtLibrary | str | Path | None = None,
        stall_timeout_s: float = 3.0,
        enqueue_timeout_ms: int = 5,
        clouds_voxel_mm: float | None = None,
    ) -> None:
        self.settings = settings
        self.clouds_voxel_mm = clouds_voxel_mm
        self._k4a: Any = None  # libk4a through ctypes: the images of a body frame (clouds only)
        self._xy_table: np.ndarray | None = None
        self._clouds: dict[int, PersonCloudsFrame] = {}
        self.sensor_id = sensor_id or settings.serial
        self._pyk4a = pyk4a
        self._k4abt = k4abt
        self.stall_timeout_s = stall_timeout_s
        self.enqueue_timeout_ms = enqueue_timeout_ms
        self._device: Any = None
        self._tracker: Tracker | None = None
        self._assemble = _FrameAssembler(self.sensor_id, settings.fps)
        self.captures = self.dropped_captures = self.results = 0
        self._last_capture = self._last_result = 0.0

    @classmethod
    def from_config(cls, cfg: RigConfig, sensor_id: str, **kwargs: Any) -> KinectSource:
        return cls(DeviceSettings.from_sensor(cfg.sensor(sensor_id), cfg.sync.fps), sensor_id=sensor_id, **kwargs)

    def _library(self) -> K4abtLibrary:
        if isinstance(self._k4abt, K4abtLibrary):
            return self._k4abt
        self._k4abt = K4abtLibrary.load(self._k4abt)
        return self._k4abt

    def ensure_available(self) -> None:
        """Raise KinectUnavailable now when pyk4a or the Body Tracking SDK is missing (no device touched).

        Workers call it before anything that waits (the master's wait for its subordinates), so a machine
        without the SDKs is told so at once.
        """
        if self._pyk4a is None:
            import_pyk4a()
        self._library()

    def open(self) -> None:
        pyk4a = self._pyk4a if self._pyk4a is not None else import_pyk4a()
        library = self._library()  # before the device: a missing SDK is fatal, no need to touch USB
        self._device = _open_by_serial(pyk4a, self.settings)
        try:
            self._device.start()
            calibration = self._device.calibration
            self._tracker = Tracker(library, calibration_pointer(calibration), self.settings.tracker)
            if self.clouds_voxel_mm is not None:
                self._k4a = load_k4a()
                declare_image_api(self._k4a)
                self._xy_table = depth_xy_table(self._k4a, calibration_pointer(calibration))
        except pyk4a.K4AException as exc:
            self.close()
            raise SensorDisconnected(
                f"sensor {self.sensor_id} (serial {self.settings.serial}) opened but cannot "
                f"start its cameras ({exc or type(exc).__name__}); check its power supply and "
                "USB 3 port, and that k4aviewer can stream from it"
            ) from None
        except BaseException:
            self.close()
            raise
        self._assemble = _FrameAssembler(self.sensor_id, self.settings.fps)
        self.captures = self.dropped_captures = self.results = 0
        self._last_capture = self._last_result = time.monotonic()
        log.info(
            "sensor %s: opened serial %s (%s, %d fps, colour %s, sync %s%s, tracker %s ABI %s)",
            self.sensor_id,
            self.settings.serial,
            self.settings.depth_mode,
            self.settings.fps,
            self.settings.color_resolution or "off",
            self.settings.sync_role,
            f" +{self.settings.subordinate_delay_us} us" if self.settings.sync_role == "subordinate" else "",
            self.settings.tracker.processing_mode,
            library.abi,
        )

    def read(self, timeout_s: float) -> SensorFrame | None:
        if self._device is None or self._tracker is None:
            raise KinectError(f"sensor {self.sensor_id}: read() before open()")
        pyk4a = self._pyk4a if self._pyk4a is not None else import_pyk4a()
        tracker = self._tracker
        now = time.monotonic()
        try:
            capture = self._device.get_capture(timeout=max(0, int(timeout_s * 1000)))
        except pyk4a.K4ATimeoutException:
            capture = None
        except pyk4a.K4AException as exc:
            raise SensorDisconnected(
                f"sensor {self.sensor_id} (serial {self.settings.serial}) stopped delivering "
                f"captures ({exc or type(exc).__name__}): unplugged or USB reset?"
            ) from None
        now = time.monotonic()
        if capture is None:
            if now - self._last_capture > self.stall_timeout_s:
                raise SensorDisconnected(
                    f"sensor {self.sensor_id} (serial {self.settings.serial}): no capture for "
                    f"{now - self._last_capture:.1f} s; unplugged, or a subordinate whose master is not running "
                    "(start the master, check the sync cable)"
                )
        else:
            self._last_capture = now
            self.captures += 1
            handle = capture_handle(capture)
            if not tracker.enqueue(handle, timeout_ms=0):
                # queue full: free a slot by taking a result, then try once more within a bounded wait
                body = tracker.pop(timeout_ms=self.enqueue_timeout_ms, images=self._k4a)
                if not tracker.enqueue(handle, timeout_ms=self.enqueue_timeout_ms):
                    self.dropped_captures += 1
                if body is not None:
                    return self._emit(body, now)
        body = tracker.pop(timeout_ms=0, images=self._k4a)
        if body is not None:
            return self._emit(body, now)
        if self.captures and now - self._last_result > self.stall_timeout_s:
            raise TrackerStalled(
                f"sensor {self.sensor_id}: the body tracker returned nothing for "
                f"{now - self._last_result:.1f} s while captures arrived ({tracker.pending} pending); "
                "GPU overloaded or lost?"
            )
        return None

    def _emit(self, body: BodyFrameData, now: float) -> SensorFrame:
        self._last_result = now
        self.results += 1
        frame = self._assemble(body)
        if self.clouds_voxel_mm is not None and self._xy_table is not None:
            clouds = body_clouds(body, frame, self._xy_table, self.clouds_voxel_mm)
            self._clouds = {} if clouds is None else {frame.device_time_us: clouds}  # the latest frame's only
        return frame

    def clouds_at(self, frame: SensorFrame) -> PersonCloudsFrame | None:
        """The person clouds of ``frame`` (the latest one read), None where none were made."""
        return self._clouds.get(frame.device_time_us)

    def close(self) -> None:
        tracker, self._tracker = self._tracker, None
        device, self._device = self._device, None
        if tracker is not None:
            _quietly(tracker.close, f"sensor {self.sensor_id}: closing the tracker")
        if device is not None:
            if getattr(device, "is_running", False):
                _quietly(device.stop, f"sensor {self.sensor_id}: stopping the device")
            elif getattr(device, "opened", False):
                _quietly(device.close, f"sensor {self.sensor_id}: closing the device")


def _quietly(action: Callable[[], Any], what: str) -> None:
    try:
        action()
    except Exception as exc:  # close() must never raise: the device may already be gone
        log.debug("%s failed: %s", what, exc)


def _open_by_serial(pyk4a: Any, settings: DeviceSettings) -> Any:
    """Open the connected device whose serial is ``settings.serial`` (configured, not started)."""
    count = int(pyk4a.connected_device_count())
    seen: list[str] = []
    for device_id in range(count):
        device = pyk4a.PyK4A(config=settings.pyk4a_config(pyk4a), device_id=device_id)
        try:
            device.open()
        except pyk4a.K4AException:
            seen.append(f"#{device_id} (busy: opened by another process?)")
            continue
        try:
            serial = str(device.serial)
        except pyk4a.K4AException:
            serial = "?"
        if serial == settings.serial:
            return device
        seen.append(serial)
        _quietly(device.close, f"closing device #{device_id}")
    raise SensorNotFound(
        f"no connected Azure Kinect has serial {settings.serial!r} (found {count} device(s): "
        f"{', '.join(seen) or 'none'}); check the cable and power, the serial in the rig config, "
        "and `skelfuse devices`"
    )


# ------------------------------------------------------------------------------------------- mkv source


class MkvSource:
    """A Kinect ``.mkv`` recording (k4arecorder) replayed through the body tracker.

    Frames come as fast as the tracker produces them (no pacing). Needs pyk4a and the Body Tracking SDK.
    """

    def __init__(
        self,
        path: str | Path,
        tracker: TrackerSettings | None = None,
        *,
        sensor_id: str | None = None,
        pyk4a: Any = None,
        k4abt: K4abtLibrary | str | Path | None = None,
        fps: float = 30.0,
        result_timeout_ms: int = 5000,
        clouds_voxel_mm: float | None = None,
    ) -> None:
        self.path = Path(path)
        self.clouds_voxel_mm = clouds_voxel_mm  # as KinectSource's: person clouds for clouds_at()
        self._k4a: Any = None
        self._xy_table: np.ndarray | None = None
        self._clouds: dict[int, PersonCloudsFrame] = {}
        self.sensor_id = sensor_id or self.path.stem
        self.tracker_settings = tracker or TrackerSettings()
        self._pyk4a = pyk4a
        self._k4abt = k4abt
        self.fps = fps
        self.result_timeout_ms = result_timeout_ms
        self._playback: Any = None
        self._tracker: Tracker | None = None
        self._eof = False
        self.skipped_captures = 0
        self._assemble = _FrameAssembler(self.sensor_id, fps)

    def open(self) -> None:
        if not self.path.exists():
            raise DataError(f"recording {self.path} does not exist")
        pyk4a = self._pyk4a if self._pyk4a is not None else import_pyk4a()
        library = self._k4abt if isinstance(self._k4abt, K4abtLibrary) else K4abtLibrary.load(self._k4abt)
        self._playback = pyk4a.PyK4APlayback(self.path)
        try:
            self._playback.open()
            self._tracker = Tracker(library, calibration_pointer(self._playback.calibration), self.tracker_settings)
            if self.clouds_voxel_mm is not None:
                self._k4a = load_k4a()
                declare_image_api(self._k4a)
                self._xy_table = depth_xy_table(self._k4a, calibration_pointer(self._playback.calibration))
        except pyk4a.K4AException as exc:
            self.close()
            raise DataError(
                f"cannot open Kinect recording {self.path} ({exc or type(exc).__name__}); is it a "
                "k4arecorder .mkv with a depth track?"
            ) from None
        except BaseException:
            self.close()
            raise
        self._eof = False
        self._assemble = _FrameAssembler(self.sensor_id, self.fps)

    def read(self, timeout_s: float) -> SensorFrame | None:
        if self._tracker is None or self._playback is None:
            raise DataError(f"{self.path}: read() before open()")
        pyk4a = self._pyk4a if self._pyk4a is not None else import_pyk4a()
        tracker = self._tracker
        timeout_ms = max(0, int(timeout_s * 1000))
        while not self._eof:
            body = tracker.pop(timeout_ms=0, images=self._k4a)
            if body is not None:
                return self._emit(body)
            try:
                capture = self._playback.get_next_capture()
            except EOFError:
                self._eof = True
                tracker.shutdown()
                break
            try:
                if not tracker.enqueue(capture_handle(capture), timeout_ms=self.result_timeout_ms):
                    self.skipped_captures += 1
            except TrackerFailedError:
                self.skipped_captures += 1  # a capture without depth (recordings start with a few)
            except pyk4a.K4AException as exc:
                raise DataError(f"{self.path}: cannot read the next capture ({exc})") from None
            body = tracker.pop(timeout_ms=timeout_ms, images=self._k4a)
            if body is not None:
                return self._emit(body)
            return None
        if tracker.pending == 0:
            raise EndOfStream(f"{self.path}: end of recording")
        try:
            body = tracker.pop(timeout_ms=self.result_timeout_ms, images=self._k4a)
        except TrackerFailedError:
            body = None
            tracker.pending = 0
        if body is None:
            tracker.pending = 0
            raise EndOfStream(f"{self.path}: end of recording")
        return self._emit(body)

    def _emit(self, body: BodyFrameData) -> SensorFrame:
        frame = self._assemble(body)
        if self.clouds_voxel_mm is not None and self._xy_table is not None:
            clouds = body_clouds(body, frame, self._xy_table, self.clouds_voxel_mm)
            self._clouds = {} if clouds is None else {frame.device_time_us: clouds}
        return frame

    def clouds_at(self, frame: SensorFrame) -> PersonCloudsFrame | None:
        """The person clouds of ``frame`` (the latest one read), None where none were made."""
        return self._clouds.get(frame.device_time_us)

    def close(self) -> None:
        tracker, self._tracker = self._tracker, None
        playback, self._playback = self._playback, None
        if tracker is not None:
            _quietly(tracker.close, f"{self.path}: closing the tracker")
        if playback is not None:
            _quietly(playback.close, f"{self.path}: closing the playback")


# -------------------------------------------------------------------------------------- recorded files


class RecordedFileSource:
    """Skeletons recorded to a file, no SDK needed: andyj1 ``.csv`` or offline_processor ``.json``.

    ``loop`` replays forever, shifting device times by the take's span each pass so time keeps increasing.
    Frames are returned as fast as they are read (no pacing).
    """

    def __init__(
        self, path: str | Path, *, sensor_id: str | None = None, kind: str = "auto", loop: bool = False
    ) -> None:
        self.path = Path(path)
        self.kind = kind
        self.loop = loop
        self.sensor_id = sensor_id or self.path.stem
        self._frames: list[SensorFrame] = []
        self._index = 0
        self._shift_us = 0
        self._pass = 0

    def open(self) -> None:

        kind = self.kind
        if kind == "auto":
            kind = {".csv": "andyj1", ".json": "offline_processor"}.get(self.path.suffix.lower(), "")
        if kind == "andyj1":
            recording = recorded.load_andyj1_csv(self.path, sensor_id=self.sensor_id)
        elif kind == "offline_processor":
            recording = recorded.load_offline_processor_json(self.path, sensor_id=self.sensor_id)
        else:
            raise DataError(
                f"{self.path}: cannot tell the recording format from the suffix; expected .csv (andyj1) "
                'or .json (offline_processor), or pass kind="andyj1" / "offline_processor"'
            )
        self._frames = list(recording.frames())
        if not self._frames:
            raise DataError(f"{self.path}: the recording holds no frames")
        self._index = 0
        self._shift_us = 0
        self._pass = 0

    def read(self, timeout_s: float) -> SensorFrame | None:
        if self._index >= len(self._frames):
            if not self.loop or not self._frames:
                raise EndOfStream(f"{self.path}: end of recording")
            first, last = self._frames[0], self._frames[-1]
            self._shift_us += last.device_time_us - first.device_time_us + 33_333
            self._pass += 1
            self._index = 0
        frame = self._frames[self._index]
        self._index += 1
        if not self._pass:
            return frame
        shift = self._shift_us
        return SensorFrame(
            sensor_id=frame.sensor_id,
            sequence=frame.sequence + self._pass * len(self._frames),
            device_time_us=frame.device_time_us + shift,
            host_time_ns=frame.host_time_ns + shift * 1000,
            body_ids=frame.body_ids,
            positions=frame.positions,
            orientations=frame.orientations,
            confidence=frame.confidence,
        )

    def close(self) -> None:
        self._frames = []


def make_skeleton_source(cfg: RigConfig, sensor_id: str, **kwargs: Any) -> SkeletonSource:
    """The SkeletonSource of a ``source = "kinect"`` sensor (kwargs go to :class:`KinectSource`)."""
    sensor = cfg.sensor(sensor_id)
    if sensor.source != "kinect":
        raise ConfigError(
            f"{cfg.source}: sensor {sensor_id!r} has source = {sensor.source!r}; make_skeleton_source "
            "handles kinect sensors"
        )
    return KinectSource.from_config(cfg, sensor_id, **kwargs)
