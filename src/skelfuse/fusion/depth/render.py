"""The virtual depth and IR images (paper Sec. 3.5, Eqs. 9-10): z-buffer back-projection and hole filling.

Every point of the frontalized cloud is projected with the virtual camera's intrinsics ``K_0``; a pixel hit
by several points keeps the nearest (z-buffer). Because the clouds are voxelized, the image has holes
between projected points; Eq. 10 fills each empty pixel with the depth of the nearest projected pixel when
that one lies within ``fill_radius_px`` (the paper's ε), and leaves it "very far" otherwise so that no depth
is invented where the cloud has none. The nearest projected pixel is found for all pixels at once by a
Euclidean distance transform (``scipy.ndimage.distance_transform_edt`` with indices), which is exactly
Eq. 10's arg-min.

Images are float32 mm with ``+inf`` for "no data" (the paper's +∞). :func:`to_k4a_depth` turns one into
what the Azure Kinect SDK delivers (uint16 mm, 0 = invalid), the form a body tracker reads.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt, minimum_filter

from skelfuse.fusion.camera import Intrinsics
from skelfuse.fusion.transform import transform_points

DEFAULT_FILL_RADIUS_PX = 2.0
"""Eq. 10's ε, pixels. A 15 mm voxel at 2.3 m spans about 3.3 px at f = 504 px, so neighbouring voxel
centres project up to ~3-4 px apart and a 2 px radius closes the gaps between them while growing the
silhouette by at most 2 px."""


@dataclass(frozen=True)
class VirtualImage:
    """A rendered virtual view.

    Attributes
    ----------
    depth_mm : (H, W) float32, z in the virtual camera frame, mm; +inf where there is no data.
    ir : (H, W) float32 IR intensity (0 where no data), or None when the cloud has none.
    hit : (H, W) bool, pixels a point projected onto (before hole filling).
    """

    depth_mm: np.ndarray
    ir: np.ndarray | None
    hit: np.ndarray


def render_points(
    points_world: np.ndarray,
    world_from_camera: np.ndarray,
    intrinsics: Intrinsics,
    *,
    ir: np.ndarray | None = None,
    fill_radius_px: float = DEFAULT_FILL_RADIUS_PX,
    splat_mm: float = 0.0,
) -> VirtualImage:
    """Back-project a world cloud into a virtual camera (Eq. 9) and fill its holes (Eq. 10).

    Parameters
    ----------
    points_world : (N, 3) mm.
    world_from_camera : (4, 4) the virtual camera's pose (e.g. ``FrontalView.world_from_camera``).
    intrinsics : the virtual camera's.
    ir : optional (N,) IR intensity per point, rendered with the same z-buffer.
    fill_radius_px : Eq. 10's ε; 0 turns hole filling off.
    splat_mm : before Eq. 9, drop the points hidden behind a surface, found by a visibility pass in which
        every point covers a square of this edge (its voxel's footprint at its depth); 0 keeps every point,
        as the paper. Without it the back of the body shows through the gaps between the front's voxel
        centres (such a pixel lies a body's depth too far), and Eq. 10 cannot repair a pixel that has data.
        The visible points are then rendered one pixel each, so the silhouette grows by no more than ε.
    """
    if not (np.isfinite(fill_radius_px) and fill_radius_px >= 0):
        raise ValueError(f"fill_radius_px must be >= 0, got {fill_radius_px!r}")
    width, height = intrinsics.width, intrinsics.height
    camera_from_world = np.linalg.inv(np.asarray(world_from_camera, dtype=np.float64))
    p = transform_points(camera_from_world, np.asarray(points_world, dtype=np.float64).reshape(-1, 3))
    values = None if ir is None else np.asarray(ir, dtype=np.float32).reshape(-1)
    keep = p[:, 2] > 1.0
    uv = np.zeros((0, 2), np.int64)
    if keep.any():
        uv = np.rint(intrinsics.project(p[keep])).astype(np.int64)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height)
        keep[keep] = inside
        uv = uv[inside]
    p = p[keep]
    values = None if values is None else values[keep]
    depth = np.full((height, width), np.inf, dtype=np.float32)
    image_ir = None if values is None else np.zeros((height, width), dtype=np.float32)
    if p.shape[0] == 0:
        return VirtualImage(depth, image_ir, np.zeros((height, width), dtype=bool))
    # Work in the bounding box of the projected points (plus room for the filling): a person covers a
    # fraction of the image, and the distance transform's cost is the box's area.
    margin = int(np.ceil(fill_radius_px)) + 1
    u0, v0 = np.maximum(uv.min(axis=0) - margin, 0)
    u1, v1 = np.minimum(uv.max(axis=0) + margin + 1, (width, height))
    box_w, box_h = int(u1 - u0), int(v1 - v0)
    flat = (uv[:, 1] - v0) * box_w + (uv[:, 0] - u0)
    z = p[:, 2]
    zbuffer = np.full(box_h * box_w, np.inf)
    np.minimum.at(zbuffer, flat, z)  # Eq. 9: the nearest point per pixel
    if splat_mm > 0:
        visible = _visible(zbuffer.reshape(box_h, box_w), flat, z, splat_mm, intrinsics)
        flat, z = flat[visible], z[visible]
        values = None if values is None else values[visible]
        zbuffer = np.full(box_h * box_w, np.inf)
        np.minimum.at(zbuffer, flat, z)
    box = zbuffer.reshape(box_h, box_w).astype(np.float32)
    box_ir = None
    if values is not None:
        box_ir = np.zeros(box_h * box_w, dtype=np.float32)
        winner = z == zbuffer[flat]
        box_ir[flat[winner]] = values[winner]
        box_ir = box_ir.reshape(box_h, box_w)  # type: ignore[assignment]  # 1-D scratch buffer, then the (H, W) image
    hit = np.zeros((height, width), dtype=bool)
    hit[v0:v1, u0:u1] = np.isfinite(box)
    if fill_radius_px > 0:
        box, box_ir = fill_holes(box, box_ir, fill_radius_px)
    depth[v0:v1, u0:u1] = box
    if image_ir is not None and box_ir is not None:
        image_ir[v0:v1, u0:u1] = box_ir
    return VirtualImage(depth, image_ir, hit)


def _visible(
    zbuffer: np.ndarray, flat: np.ndarray, z: np.ndarray, splat_mm: float, intrinsics: Intrinsics
) -> np.ndarray:
    """(N,) bool: points not hidden behind a nearer surface.

    Every point is taken to cover a square of ``splat_mm`` (its voxel's footprint) at the depth of the
    nearest point: a minimum filter of that width over the one-pixel z-buffer is the z-buffer of the splats.
    A point is hidden when that holds a depth more than ``2 * splat_mm`` in front of it (neighbouring voxels
    of one surface differ by less; a body part behind another by more).
    """
    nearest = float(np.min(z))
    half_px = 0.5 * splat_mm * max(intrinsics.fx, intrinsics.fy) / nearest
    width = 2 * int(np.ceil(min(half_px, 16.0) - 0.5)) + 1
    splatted = minimum_filter(zbuffer, size=width, mode="constant", cval=np.inf).reshape(-1)
    return z <= splatted[flat] + 2.0 * splat_mm


def fill_holes(
    depth_mm: np.ndarray, ir: np.ndarray | None, fill_radius_px: float
) -> tuple[np.ndarray, np.ndarray | None]:
    """Eq. 10: each pixel without data takes the value of the nearest pixel with data within
    ``fill_radius_px`` (Euclidean, in pixels); farther than that it stays +inf (IR 0)."""
    empty = ~np.isfinite(depth_mm)
    distance, (rows, cols) = distance_transform_edt(empty, return_indices=True)
    fill = empty & (distance <= fill_radius_px)
    filled = depth_mm.copy()
    filled[fill] = depth_mm[rows[fill], cols[fill]]
    filled_ir = None
    if ir is not None:
        filled_ir = ir.copy()
        filled_ir[fill] = ir[rows[fill], cols[fill]]
    return filled, filled_ir


def to_k4a_depth(depth_mm: np.ndarray) -> np.ndarray:
    """A float depth image as the Azure Kinect SDK delivers depth: uint16 mm, rounded, 0 = invalid (for +inf,
    NaN and anything outside 1..65535 mm)."""
    d = np.asarray(depth_mm, dtype=np.float64)
    valid = np.isfinite(d) & (d >= 0.5) & (d < 65535.5)
    out = np.zeros(d.shape, dtype=np.uint16)
    out[valid] = np.rint(d[valid]).astype(np.uint16)
    return out


def to_k4a_ir(ir: np.ndarray) -> np.ndarray:
    """A float IR image as the SDK delivers IR: uint16, rounded and clipped to 0..65535."""
    return np.clip(np.rint(np.asarray(ir, dtype=np.float64)), 0, 65535).astype(np.uint16)
