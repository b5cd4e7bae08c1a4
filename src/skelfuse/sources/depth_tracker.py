"""The body tracker on a person's virtual depth image: the one adapter of the depth-level fusion.

The pure stages (``fusion/depth/``) turn a person's merged cloud into a frontal virtual depth and IR image
seen by a virtual camera; this module hands that image to the Azure Kinect Body Tracking SDK and maps the
skeleton it finds back to the world:

1. a ``k4a_capture_t`` is built from the images (``k4a_image_create_from_buffer`` DEPTH16 / IR16,
   ``k4a_capture_create``, ``k4a_capture_set_depth_image`` / ``k4a_capture_set_ir_image``), the images'
   device timestamp numbering the submissions;
2. the tracker was created with a ``k4a_calibration_t`` written for the virtual camera
   (:func:`skelfuse.sources.k4abt.virtual_calibration`);
3. the popped body frame's timestamp finds the frontal view the image came from, and
   :meth:`FrontalView.to_world` maps the skeleton back.

A tracker keeps temporal state per stream, so there is one :class:`VirtualCameraTracker` per person's virtual
camera (per track id), never frames of several people interleaved in one. The SDK allows one tracker per
process on some versions: several people then need several processes (:mod:`skelfuse.sources.tracker_pool`).

Verified against the fake libk4a / libk4abt the suite compiles from C (``tests/fake_k4a``): strides, the
calibration's layout and values, the timestamps, the transform back to world. Those fakes are our own
transcription of the SDK's headers, not the SDK: what the real tracker finds on a virtual image is only
measurable with the SDK on a GPU (``docs/depth-fusion.md``).
"""

from __future__ import annotations

import ctypes
import dataclasses
from dataclasses import dataclass

import numpy as np

from skelfuse.fusion.camera import Intrinsics
from skelfuse.fusion.depth.frontal import FrontalView
from skelfuse.fusion.depth.pipeline import PersonDepthView
from skelfuse.fusion.depth.render import to_k4a_depth, to_k4a_ir
from skelfuse.schema.skeleton import joint_index
from skelfuse.sources.k4abt import (
    K4abtLibrary,
    Tracker,
    TrackerSettings,
    capture_from_images,
    declare_image_api,
    virtual_calibration,
)

FRAME_PERIOD_US = 33_333
"""Step of the device timestamps given to successive virtual images (30 fps)."""
_PELVIS = joint_index("PELVIS")


@dataclass(frozen=True)
class VirtualSkeleton:
    """A skeleton the tracker found on a virtual image, back in the world.

    Attributes
    ----------
    device_time_us : the timestamp the virtual image was submitted with.
    body_id : the tracker's body id.
    positions_world : (32, 3) float64 world mm.
    positions_camera : (32, 3) float32 as the tracker reported them (virtual camera frame, mm).
    confidence : (32,) uint8.
    """

    device_time_us: int
    body_id: int
    positions_world: np.ndarray
    positions_camera: np.ndarray
    confidence: np.ndarray


class VirtualCameraTracker:
    """One body tracker for one person's virtual camera (pipelined: :meth:`submit`, then :meth:`collect`).

    Parameters
    ----------
    k4a : a loaded libk4a (``skelfuse.sources.k4abt.load_k4a``).
    library : a loaded libk4abt.
    intrinsics : the virtual camera's intrinsics (the reference sensor's; its size must be a k4a depth mode).
    settings : the tracker's settings (processing mode, model, smoothing).
    """

    def __init__(
        self, k4a: ctypes.CDLL, library: K4abtLibrary, intrinsics: Intrinsics, settings: TrackerSettings
    ) -> None:
        declare_image_api(k4a)
        self.k4a = k4a
        self.intrinsics = intrinsics
        # Kept alive with the tracker: the SDK may keep the pointer it was created with.
        self.calibration = virtual_calibration(
            intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy, intrinsics.width, intrinsics.height
        )
        self.tracker = Tracker(library, ctypes.addressof(self.calibration), settings)
        self._views: dict[int, FrontalView] = {}
        self._next_time_us = FRAME_PERIOD_US

    def submit(self, view: PersonDepthView, *, timeout_ms: int = 0) -> bool:
        """Enqueue one virtual image; False when the tracker's queue stayed full (the image is dropped)."""
        depth = to_k4a_depth(view.image.depth_mm)
        ir = None if view.image.ir is None else to_k4a_ir(view.image.ir)
        time_us = self.submit_images(depth, ir, timeout_ms=timeout_ms)
        if time_us is not None:
            self._views[time_us] = view.frontal
        return time_us is not None

    def submit_images(self, depth: np.ndarray, ir: np.ndarray | None, *, timeout_ms: int = 0) -> int | None:
        """Enqueue a DEPTH16 (and IR16) image pair (``to_k4a_depth`` / ``to_k4a_ir``); the device timestamp it
        was numbered with, or None when the tracker's queue stayed full."""
        time_us = self._next_time_us
        capture = capture_from_images(self.k4a, depth, ir, device_time_us=time_us)
        try:
            accepted = self.tracker.enqueue(capture, timeout_ms)
        finally:
            self.k4a.k4a_capture_release(capture)  # the SDK holds its own reference while it works
        if not accepted:
            return None
        self._next_time_us += FRAME_PERIOD_US
        return time_us

    def collect(self, *, timeout_ms: int = 0) -> VirtualSkeleton | None:
        """The next result mapped back to the world; None when none is ready, or when the tracker found no
        body. Of several bodies, the one whose pelvis is nearest the image centre (the person the virtual
        camera was placed for) is taken."""
        found = self.collect_camera(timeout_ms=timeout_ms)
        if found is None:
            return None
        frontal = self._views.pop(found.device_time_us, None)
        for stale in [t for t in self._views if t < found.device_time_us]:  # results the tracker dropped
            del self._views[stale]
        if frontal is None:
            return None
        return dataclasses.replace(found, positions_world=frontal.to_world(found.positions_camera.astype(np.float64)))

    def collect_camera(self, *, timeout_ms: int = 0) -> VirtualSkeleton | None:
        """As :meth:`collect`, in the virtual camera's frame only (``positions_world`` left NaN): for a caller
        that keeps the frontal views itself (a tracker process)."""
        frame = self.tracker.pop(timeout_ms)
        if frame is None or frame.n_bodies == 0:
            return None
        pelvis = frame.positions[:, _PELVIS].astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            offset = self.intrinsics.project(pelvis) - [self.intrinsics.cx, self.intrinsics.cy]
        body = int(np.nanargmin(np.where(pelvis[:, 2] > 0, np.hypot(offset[:, 0], offset[:, 1]), np.inf)))
        return VirtualSkeleton(
            device_time_us=frame.device_time_us,
            body_id=int(frame.body_ids[body]),
            positions_world=np.full((frame.positions.shape[1], 3), np.nan),
            positions_camera=frame.positions[body],
            confidence=frame.confidence[body],
        )

    @property
    def pending(self) -> int:
        return self.tracker.pending

    def close(self) -> None:
        self.tracker.close()
        self._views.clear()

    def __enter__(self) -> VirtualCameraTracker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
