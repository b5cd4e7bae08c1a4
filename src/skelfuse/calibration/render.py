"""A small synthetic RGB-D renderer for calibration tests: ray casting, vectorized over all pixels.

A virtual Azure Kinect (pinhole :class:`~skelfuse.fusion.camera.Intrinsics`, pose ``world_from_sensor``
as built by :func:`skelfuse.sim.rig.look_at`) looks at a scene of spheres and flat textured rectangles
(:class:`Sphere`, :class:`Quad`) inside a room (floor and walls). It renders what the calibrations read:

- colour: BGR uint8, registered to depth (same pixels, same intrinsics; see ``camera``), Lambert shading
  under one light from above plus ambient, Gaussian pixel noise;
- depth: uint16 mm, the z of the first hit in the sensor frame plus Gaussian noise, 0 where nothing is hit
  or the hit lies outside the depth range (as the Azure Kinect reports it).

Cycle: build a :class:`Scene` (``room()``, ``aruco_plate()``, spheres), then ``render(sensor, intrinsics,
scene, rng=...)`` per view. Each primitive is intersected with every ray at once (numpy), the nearest hit
wins; no per-pixel Python loops. Optional supersampling (odd factor) anti-aliases colour (marker edges).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from skelfuse.fusion.camera import Intrinsics

_LIGHT_DIR = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])  # towards the light (world, z up)
_AMBIENT = 0.45


@dataclass(frozen=True)
class Sphere:
    """A uniformly coloured sphere: centre (3,) mm (world), radius mm, colour BGR."""

    center_mm: Sequence[float]
    radius_mm: float
    color_bgr: Sequence[int] = (30, 30, 200)


@dataclass(frozen=True)
class Quad:
    """A flat rectangle, seen from both sides.

    Attributes
    ----------
    center_mm : (3,) world position of its centre, mm.
    u_axis, v_axis : (3,) orthonormal in-plane directions (world); texture columns grow along u, rows along -v
        (so a texture reads unmirrored when seen from the side u × v points to).
    half_u_mm, half_v_mm : half sizes along u and v, mm.
    color_bgr : colour where there is no texture.
    texture : (H, W) or (H, W, 3) uint8, stretched over the whole rectangle (bilinear), optional.
    checker_mm : a grey checkerboard of this square size (plus a fine noise), optional (floors, walls).
    """

    center_mm: Sequence[float] | np.ndarray
    u_axis: Sequence[float] | np.ndarray
    v_axis: Sequence[float] | np.ndarray
    half_u_mm: float
    half_v_mm: float
    color_bgr: Sequence[int] = (128, 128, 128)
    texture: np.ndarray | None = None
    checker_mm: float | None = None


@dataclass
class Scene:
    """What the cameras see: spheres and quads (order does not matter: the nearest hit wins)."""

    spheres: list[Sphere] = field(default_factory=list)
    quads: list[Quad] = field(default_factory=list)


def room(half_size_mm: float = 4000.0, height_mm: float = 3000.0, floor_z_mm: float = 0.0) -> list[Quad]:
    """A floor (grey checker) and four walls (lighter checker) around the origin."""
    h = half_size_mm
    mid = floor_z_mm + height_mm / 2
    x, y, z = np.eye(3)
    quads = [Quad((0.0, 0.0, floor_z_mm), x, y, h, h, (110, 110, 110), checker_mm=500.0)]
    for axis, sign in ((x, 1.0), (x, -1.0), (y, 1.0), (y, -1.0)):
        centre = sign * h * axis + np.array([0.0, 0.0, mid])
        along = np.cross(z, axis)
        quads.append(Quad(centre, along, z, h, height_mm / 2, (165, 170, 175), checker_mm=700.0))
    return quads


def aruco_plate(
    dictionary: int = cv2.aruco.DICT_4X4_50,
    *,
    marker_mm: float = 200.0,
    spacing_mm: float = 400.0,
    margin_mm: float = 60.0,
    px_per_mm: float = 1.0,
    z_mm: float = 0.0,
) -> tuple[Quad, dict[int, np.ndarray]]:
    """The paper's plate: 4 ArUco markers (ids 0-3) lying flat, marker 1 at the world origin.

    Layout seen from above (x right, y up): marker 1 at (0, 0), marker 2 at (-spacing, 0) (so the x axis
    runs from marker 2 to marker 1), marker 0 at (0, -spacing) (y axis from marker 0 to marker 1), marker 3
    at (-spacing, -spacing). The plate's world frame is therefore the true world frame of the paper's
    sensor-to-marker calibration.

    Returns
    -------
    quad : the plate (white, with the markers in its texture), lying in the plane z = ``z_mm``.
    centres : marker id -> (3,) true centre in the world, mm.
    """
    aruco_dict = cv2.aruco.getPredefinedDictionary(dictionary)
    centres_xy = {1: (0.0, 0.0), 2: (-spacing_mm, 0.0), 0: (0.0, -spacing_mm), 3: (-spacing_mm, -spacing_mm)}
    lo = -spacing_mm - marker_mm / 2 - margin_mm
    hi = marker_mm / 2 + margin_mm
    size_mm = hi - lo
    size_px = round(size_mm * px_per_mm)
    texture = np.full((size_px, size_px), 255, np.uint8)
    side_px = round(marker_mm * px_per_mm)
    for marker_id, (mx, my) in centres_xy.items():
        image = cv2.aruco.generateImageMarker(aruco_dict, marker_id, side_px)
        col0 = round((mx - marker_mm / 2 - lo) * px_per_mm)
        row0 = round((hi - (my + marker_mm / 2)) * px_per_mm)  # rows grow along -y
        texture[row0 : row0 + side_px, col0 : col0 + side_px] = image
    centre = ((lo + hi) / 2, (lo + hi) / 2, z_mm)
    quad = Quad(centre, (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), size_mm / 2, size_mm / 2, (255, 255, 255), texture=texture)
    return quad, {k: np.array([x, y, z_mm]) for k, (x, y) in centres_xy.items()}


def _sample_texture(texture: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """Bilinear lookup of (N,) continuous pixel coordinates (centres at integers) → (N, 3) float BGR."""
    tex = texture if texture.ndim == 3 else texture[..., None].repeat(3, axis=-1)
    tex = tex.astype(np.float64)
    h, w = tex.shape[:2]
    col = np.clip(col, 0, w - 1)
    row = np.clip(row, 0, h - 1)
    c0 = np.minimum(np.floor(col).astype(np.int64), w - 2)
    r0 = np.minimum(np.floor(row).astype(np.int64), h - 2)
    fc = (col - c0)[:, None]
    fr = (row - r0)[:, None]
    top = tex[r0, c0] * (1 - fc) + tex[r0, c0 + 1] * fc
    bottom = tex[r0 + 1, c0] * (1 - fc) + tex[r0 + 1, c0 + 1] * fc
    return top * (1 - fr) + bottom * fr


def render(
    world_from_sensor: np.ndarray,
    intrinsics: Intrinsics,
    scene: Scene,
    *,
    rng: np.random.Generator,
    depth_noise_mm: float = 2.5,
    color_noise: float = 3.0,
    range_mm: tuple[float, float] = (250.0, 5460.0),
    supersample: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Render one RGB-D view of ``scene``.

    Parameters
    ----------
    world_from_sensor : (4, 4) pose of the camera (sensor frame x right, y down, z forward), mm.
    intrinsics : Intrinsics (image size included).
    scene : Scene.
    rng : seeded generator for the noise.
    depth_noise_mm : standard deviation of the Gaussian depth noise per pixel, mm.
    color_noise : standard deviation of the Gaussian colour noise per channel, 0-255 units.
    range_mm : (near, far) depth range; hits outside read 0 (invalid).
    supersample : odd factor k: colour is averaged over k x k rays per pixel, depth is the centre ray.

    Returns
    -------
    color : (H, W, 3) uint8 BGR.
    depth : (H, W) uint16, mm, 0 = invalid.
    """
    if supersample < 1 or supersample % 2 == 0:
        raise ValueError(f"supersample must be an odd factor >= 1, got {supersample}")
    k = supersample
    width, height = intrinsics.width, intrinsics.height
    offsets = (np.arange(k) - (k - 1) / 2) / k
    us = (np.arange(width)[:, None] + offsets[None, :]).reshape(-1)
    vs = (np.arange(height)[:, None] + offsets[None, :]).reshape(-1)
    # Ray directions in the sensor frame with z = 1, so the ray parameter of a hit is its depth. Kept as
    # three (N,) component arrays: (N, 3) @ (3, 3) products are several times slower in numpy.
    ray_x = np.broadcast_to(((us - intrinsics.cx) / intrinsics.fx)[None, :], (vs.size, us.size)).reshape(-1)
    ray_y = np.broadcast_to(((vs - intrinsics.cy) / intrinsics.fy)[:, None], (vs.size, us.size)).reshape(-1)
    pose = np.asarray(world_from_sensor, dtype=np.float64)
    rotation, origin = pose[:3, :3], pose[:3, 3]
    dirs_w = [rotation[i, 0] * ray_x + rotation[i, 1] * ray_y + rotation[i, 2] for i in range(3)]
    n_rays = ray_x.size
    best = np.full(n_rays, np.inf)
    color = np.zeros((n_rays, 3))
    normal = np.zeros((n_rays, 3))

    def dot(vec: np.ndarray) -> np.ndarray:
        return dirs_w[0] * vec[0] + dirs_w[1] * vec[1] + dirs_w[2] * vec[2]

    for sphere in scene.spheres:
        centre = np.asarray(sphere.center_mm, dtype=np.float64)
        oc = origin - centre
        a = dirs_w[0] ** 2 + dirs_w[1] ** 2 + dirs_w[2] ** 2
        b = dot(oc)
        c = oc @ oc - sphere.radius_mm**2
        disc = b * b - a * c
        idx = np.nonzero(disc >= 0)[0]
        s = (-b[idx] - np.sqrt(disc[idx])) / a[idx]
        keep = (s > 0) & (s < best[idx])
        idx, s = idx[keep], s[keep]
        best[idx] = s
        points = origin + s[:, None] * np.stack([d[idx] for d in dirs_w], axis=-1)
        normal[idx] = (points - centre) / sphere.radius_mm
        color[idx] = np.asarray(sphere.color_bgr, dtype=np.float64)

    for quad in scene.quads:
        centre = np.asarray(quad.center_mm, dtype=np.float64)
        u_axis = np.asarray(quad.u_axis, dtype=np.float64)
        v_axis = np.asarray(quad.v_axis, dtype=np.float64)
        n = np.cross(u_axis, v_axis)
        denom = dot(n)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = ((centre - origin) @ n) / denom
        idx = np.nonzero(np.isfinite(s) & (s > 0) & (s < best))[0]
        s = s[idx]
        rel = origin - centre
        a_coord = rel @ u_axis + s * (
            u_axis[0] * dirs_w[0][idx] + u_axis[1] * dirs_w[1][idx] + u_axis[2] * dirs_w[2][idx]
        )
        b_coord = rel @ v_axis + s * (
            v_axis[0] * dirs_w[0][idx] + v_axis[1] * dirs_w[1][idx] + v_axis[2] * dirs_w[2][idx]
        )
        inside = (np.abs(a_coord) <= quad.half_u_mm) & (np.abs(b_coord) <= quad.half_v_mm)
        idx, s, a_coord, b_coord = idx[inside], s[inside], a_coord[inside], b_coord[inside]
        best[idx] = s
        normal[idx] = np.where((denom[idx] < 0)[:, None], n, -n)  # the side the camera sees
        if quad.texture is not None:
            tex_h, tex_w = quad.texture.shape[:2]
            col = (a_coord + quad.half_u_mm) / (2 * quad.half_u_mm) * tex_w - 0.5
            row = (quad.half_v_mm - b_coord) / (2 * quad.half_v_mm) * tex_h - 0.5
            color[idx] = _sample_texture(quad.texture, col, row)
        else:
            base = np.asarray(quad.color_bgr, dtype=np.float64)
            if quad.checker_mm is not None:
                cells = np.floor(a_coord / quad.checker_mm) + np.floor(b_coord / quad.checker_mm)
                fine = np.sin(a_coord * 0.05) * np.cos(b_coord * 0.043)  # mild texture inside the squares
                factor = np.where(cells % 2 == 0, 0.85, 1.1) + 0.05 * fine
                color[idx] = base[None, :] * factor[:, None]
            else:
                color[idx] = base

    lit = normal[:, 0] * _LIGHT_DIR[0] + normal[:, 1] * _LIGHT_DIR[1] + normal[:, 2] * _LIGHT_DIR[2]
    shade = _AMBIENT + (1 - _AMBIENT) * np.clip(lit, 0.0, 1.0)
    hit_any = np.isfinite(best)
    color = np.where(hit_any[:, None], color * shade[:, None], 40.0)
    color = color.reshape(height, k, width, k, 3).mean(axis=(1, 3))
    if color_noise > 0:
        color = color + color_noise * rng.standard_normal(color.shape, dtype=np.float32)
    color_u8 = np.clip(np.rint(color), 0, 255).astype(np.uint8)

    centre_ray = best.reshape(height, k, width, k)[:, k // 2, :, k // 2]  # ray parameter = depth (z)
    valid = np.isfinite(centre_ray) & (centre_ray >= range_mm[0]) & (centre_ray <= range_mm[1])
    depth = np.where(valid, centre_ray, 0.0)
    if depth_noise_mm > 0:
        depth = depth + valid * (depth_noise_mm * rng.standard_normal(depth.shape, dtype=np.float32))
    depth_u16 = np.clip(np.rint(depth), 0, 65535).astype(np.uint16)
    depth_u16[~valid] = 0
    return color_u8, depth_u16
