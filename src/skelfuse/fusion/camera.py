"""Pinhole intrinsics of a depth camera, and lifting depth pixels to 3D points in the sensor frame.

Sensor frame = the k4abt depth camera frame: x right, y down, z forward, mm. A depth image holds z (the
distance along the optical axis, not along the ray) in mm as uint16, 0 = invalid, as the Azure Kinect SDK
delivers it. Pixel (u, v) = (column, row), the centre of the top-left pixel at (0, 0) (OpenCV convention).

Colour registered to depth: the sphere and marker calibrations read colour and depth at the same pixel,
which assumes a colour image already warped into the depth camera (on an Azure Kinect:
``k4a_transformation_color_image_to_depth_camera``, pyk4a ``capture.transformed_color``). The depth
camera's intrinsics then hold for both images, and every 3D point is in the depth camera frame, the frame
k4abt skeletons are in. Lens distortion is ignored here (undistort first for wide-angle modes).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

NFOV_UNBINNED_SIZE = (640, 576)
"""(width, height) of the Azure Kinect NFOV unbinned depth image, pixels."""


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics (no distortion), pixels.

    Attributes
    ----------
    fx, fy : float
        Focal lengths, pixels.
    cx, cy : float
        Principal point, pixels.
    width, height : int
        Image size, pixels.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        if not (self.fx > 0 and self.fy > 0 and self.width > 0 and self.height > 0):
            raise ValueError(f"Intrinsics: focal lengths and image size must be positive, got {self}")

    @classmethod
    def azure_kinect_nfov(cls, *, binned: bool = False) -> Intrinsics:
        """Typical Azure Kinect NFOV depth intrinsics: unbinned 640 x 576, f ≈ 504 px; 2x2 binned 320 x 288,
        f ≈ 252 px; principal point centred.

        Real devices differ by a few pixels: read them from the device calibration
        (``k4a_calibration_t.depth_camera_calibration``) for real data.
        """
        width, height = NFOV_UNBINNED_SIZE
        scale = 2 if binned else 1
        width, height = width // scale, height // scale
        return cls(504.0 / scale, 504.0 / scale, (width - 1) / 2, (height - 1) / 2, width, height)

    def matrix(self) -> np.ndarray:
        """(3, 3) camera matrix K, as OpenCV wants it."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def lift(self, u: np.ndarray, v: np.ndarray, depth_mm: np.ndarray) -> np.ndarray:
        """Pixels and their depth → (N, 3) float64 points in the sensor frame, mm.

        Parameters
        ----------
        u, v : (N,) arrays
            Column and row of each pixel.
        depth_mm : (N,) array
            z of each pixel, mm (callers drop the 0 = invalid pixels first).
        """
        z = np.asarray(depth_mm, dtype=np.float64)
        x = (np.asarray(u, dtype=np.float64) - self.cx) * z / self.fx
        y = (np.asarray(v, dtype=np.float64) - self.cy) * z / self.fy
        return np.stack([x, y, z], axis=-1)

    def project(self, points_mm: np.ndarray) -> np.ndarray:
        """(..., 3) sensor-frame points → (..., 2) pixel coordinates (u, v)."""
        p = np.asarray(points_mm, dtype=np.float64)
        return np.stack([self.fx * p[..., 0] / p[..., 2] + self.cx, self.fy * p[..., 1] / p[..., 2] + self.cy], axis=-1)


def lift_mask(depth_mm: np.ndarray, mask: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """The valid depth pixels of ``mask`` as (N, 3) float64 points in the sensor frame, mm.

    Parameters
    ----------
    depth_mm : (H, W) uint16 (or any numeric) depth image, mm, 0 = invalid.
    mask : (H, W) bool (or nonzero) selection.
    intrinsics : Intrinsics of the depth camera.
    """
    depth = np.asarray(depth_mm)
    if depth.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(
            f"depth image is {depth.shape[1]}x{depth.shape[0]} (W x H), intrinsics are for "
            f"{intrinsics.width}x{intrinsics.height}; pass the depth camera's intrinsics"
        )
    rows, cols = np.nonzero((np.asarray(mask) != 0) & (depth > 0))
    return intrinsics.lift(cols, rows, depth[rows, cols])


def look_at_pose(position_mm: np.ndarray, target_mm: np.ndarray, up: ArrayLike = (0.0, 0.0, 1.0)) -> np.ndarray:
    """(4, 4) ``world_from_camera`` of a camera at ``position_mm`` whose optical axis (+z) points at
    ``target_mm``, with no roll: its x axis is horizontal (right in the image), y points down in the image.

    Raises ValueError when the target equals the position or the camera looks straight along ``up``.
    """
    position = np.asarray(position_mm, dtype=np.float64)
    forward = np.asarray(target_mm, dtype=np.float64) - position
    norm = np.linalg.norm(forward)
    if norm < 1e-9:
        raise ValueError(f"look_at: target equals position {position}")
    z_axis = forward / norm
    x_axis = np.cross(z_axis, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(x_axis) < 1e-9:
        raise ValueError("look_at: looking straight along 'up' leaves the roll undefined")
    x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(z_axis, x_axis)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x_axis, y_axis, z_axis], axis=1)
    pose[:3, 3] = position
    return pose
