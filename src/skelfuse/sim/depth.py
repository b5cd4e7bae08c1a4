"""What each virtual sensor's depth camera sees: a depth image, an IR image and a body-index map of people
whose body surface is a set of capsules around their true skeletons.

Ray casting (one ray per pixel, analytic ray-capsule intersection) gives the exact visible surface, so the
depth-level fusion can be checked against truth: every rendered point lies on the union of capsules, mutual
occlusion of people falls out of the z-buffer, and a direct render from any camera (:func:`render_truth`) is
the reference a virtual image is compared with.

Images follow the Azure Kinect SDK: depth uint16 mm (0 = invalid), IR uint16, and the body tracker's body-index
map, uint8 per pixel holding the body's index in the frame, 255 (``K4ABT_BODY_INDEX_MAP_BACKGROUND``) elsewhere.
Here the body index is the person's index in the ``people`` array.

The capsule body (radii for a 1.75 m adult, scaled with the skeleton's size) is a stand-in for a real body
surface, and the sensor effects are simple models with assumed magnitudes (:class:`DepthNoise`): they
exercise the geometry and the plumbing, not the accuracy of a real depth camera. The image is a pinhole
projection with the sensor's intrinsics (``Intrinsics.azure_kinect_nfov``: 640 x 576, f ≈ 504 px, which
covers about 65° x 60°; the real NFOV lens covers 75° x 65° through its distortion, not modelled here).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from skelfuse.fusion.camera import Intrinsics
from skelfuse.fusion.transform import invert_transform, transform_points
from skelfuse.schema.skeleton import joint_index
from skelfuse.sim.rig import VirtualSensor

BODY_INDEX_BACKGROUND = 255
"""``K4ABT_BODY_INDEX_MAP_BACKGROUND``: body-index map value of a pixel that belongs to no body."""

_REFERENCE_SHOULDER_WIDTH_MM = 2 * 180.0  # shoulder joint spacing of the 1.75 m rest pose (sim.gestures)

BODY_CAPSULES: tuple[tuple[str, str, float], ...] = (
    # torso: a spine column and two flank columns make the oval cross-section (about 400 x 250 mm)
    ("PELVIS", "SPINE_CHEST", 115.0),
    ("HIP_LEFT", "SHOULDER_LEFT", 85.0),
    ("HIP_RIGHT", "SHOULDER_RIGHT", 85.0),
    ("HIP_LEFT", "HIP_RIGHT", 95.0),
    ("SPINE_CHEST", "NECK", 70.0),
    ("NECK", "HEAD", 55.0),
    ("HEAD", "NOSE", 95.0),
    # arms
    ("SHOULDER_LEFT", "ELBOW_LEFT", 45.0),
    ("ELBOW_LEFT", "WRIST_LEFT", 38.0),
    ("WRIST_LEFT", "HANDTIP_LEFT", 30.0),
    ("SHOULDER_RIGHT", "ELBOW_RIGHT", 45.0),
    ("ELBOW_RIGHT", "WRIST_RIGHT", 38.0),
    ("WRIST_RIGHT", "HANDTIP_RIGHT", 30.0),
    # legs
    ("HIP_LEFT", "KNEE_LEFT", 70.0),
    ("KNEE_LEFT", "ANKLE_LEFT", 50.0),
    ("ANKLE_LEFT", "FOOT_LEFT", 40.0),
    ("HIP_RIGHT", "KNEE_RIGHT", 70.0),
    ("KNEE_RIGHT", "ANKLE_RIGHT", 50.0),
    ("ANKLE_RIGHT", "FOOT_RIGHT", 40.0),
)
"""(start joint, end joint, radius mm for a 1.75 m adult): the body surface the simulator renders."""

_CAPSULE_A = np.array([joint_index(a) for a, _, _ in BODY_CAPSULES])
_CAPSULE_B = np.array([joint_index(b) for _, b, _ in BODY_CAPSULES])
_CAPSULE_R = np.array([r for _, _, r in BODY_CAPSULES])


@dataclass(frozen=True)
class DepthNoise:
    """The depth camera's imperfections, all assumed magnitudes (set to zero for exact images).

    Attributes
    ----------
    sigma_mm : one-sigma Gaussian depth noise per pixel, mm (Azure Kinect hardware spec: random error
        σ ≤ 17 mm; a few mm is typical on skin and clothes at 1-3 m; 3 mm assumed).
    dropout : fraction of body pixels randomly invalid (0 in the image), e.g. dark or shiny spots.
    grazing_deg : surfaces seen more obliquely than this (angle between ray and surface normal) come back
        invalid, as the edge pixels of a real time-of-flight camera do.
    ir_gain : IR intensity of a surface facing the camera at 1 m (falls with cos(incidence) / distance²).
    """

    sigma_mm: float = 3.0
    dropout: float = 0.01
    grazing_deg: float = 80.0
    ir_gain: float = 3000.0


EXACT = DepthNoise(sigma_mm=0.0, dropout=0.0, grazing_deg=90.0)
"""No noise, no dropout, no grazing loss: the truth render."""


@dataclass(frozen=True)
class DepthFrame:
    """One sensor's depth capture and body-index map.

    Attributes
    ----------
    sensor_id : str
    depth : (H, W) uint16 mm, 0 = invalid.
    ir : (H, W) uint16.
    body_index : (H, W) uint8, the person index per pixel, 255 = background.
    intrinsics : the depth camera's intrinsics.
    world_from_sensor : (4, 4) the sensor's true pose.
    """

    sensor_id: str
    depth: np.ndarray
    ir: np.ndarray
    body_index: np.ndarray
    intrinsics: Intrinsics
    world_from_sensor: np.ndarray = field(repr=False)


def body_capsules(people_world: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The capsules of every person: starts (P*C, 3), ends (P*C, 3), radii (P*C,), person index (P*C,).

    Radii scale with each person's shoulder width relative to the 1.75 m rest pose.
    """
    people = np.asarray(people_world, dtype=np.float64).reshape(-1, 32, 3)
    shoulder = np.linalg.norm(
        people[:, joint_index("SHOULDER_LEFT")] - people[:, joint_index("SHOULDER_RIGHT")], axis=-1
    )
    scale = np.clip(shoulder / _REFERENCE_SHOULDER_WIDTH_MM, 0.5, 1.5)
    starts = people[:, _CAPSULE_A].reshape(-1, 3)
    ends = people[:, _CAPSULE_B].reshape(-1, 3)
    radii = (scale[:, None] * _CAPSULE_R[None, :]).reshape(-1)
    person = np.repeat(np.arange(people.shape[0]), len(BODY_CAPSULES))
    return starts, ends, radii, person


def surface_distance(points_world: np.ndarray, people_world: np.ndarray) -> np.ndarray:
    """(N,) signed distance of each point to the body surface (union of capsules) of ``people_world``, mm:
    0 on the surface, negative inside, positive outside."""
    p = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    starts, ends, radii, _ = body_capsules(people_world)
    axis = ends - starts  # (C, 3)
    length2 = np.maximum(np.einsum("ci,ci->c", axis, axis), 1e-12)
    best = np.full(p.shape[0], np.inf)
    for start, direction, l2, radius in zip(starts, axis, length2, radii, strict=True):
        s = np.clip((p - start) @ direction / l2, 0.0, 1.0)
        distance = np.linalg.norm(p - (start + s[:, None] * direction), axis=1) - radius
        best = np.minimum(best, distance)
    return best


@functools.lru_cache(maxsize=4)
def _image_rays(intrinsics: Intrinsics) -> np.ndarray:
    """(H, W, 3) unit ray directions of every pixel, camera frame; read-only, formed once per camera model
    (every capsule of every frame of a take looks them up)."""
    u, v = np.meshgrid(np.arange(intrinsics.width), np.arange(intrinsics.height))
    d = np.stack([(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy, np.ones(u.shape)], -1)
    rays = d / np.linalg.norm(d, axis=-1, keepdims=True)
    rays.flags.writeable = False
    return rays


def _pixel_rays(intrinsics: Intrinsics, u0: int, u1: int, v0: int, v1: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit ray directions (n, 3) of the pixels in [u0, u1) x [v0, v1), camera frame, and their flat indices."""
    flat = np.arange(v0, v1)[:, None] * intrinsics.width + np.arange(u0, u1)[None, :]
    return _image_rays(intrinsics)[v0:v1, u0:u1].reshape(-1, 3), flat.reshape(-1)


def _ray_capsule(rd: np.ndarray, a: np.ndarray, b: np.ndarray, radius: float) -> np.ndarray:
    """Distance along unit rays from the origin to a capsule (inf where missed).

    Inigo Quilez's analytic ray-capsule intersection (cylinder body, then the nearer end sphere).
    """
    ba = b - a
    oa = -a
    baba = float(ba @ ba)
    bard = rd @ ba
    baoa = float(ba @ oa)
    rdoa = rd @ oa
    oaoa = float(oa @ oa)
    qa = baba - bard * bard
    qb = baba * rdoa - baoa * bard
    qc = baba * oaoa - baoa * baoa - radius * radius * baba
    h = qb * qb - qa * qc
    t = np.full(rd.shape[0], np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_body = (-qb - np.sqrt(np.maximum(h, 0.0))) / qa
        y = baoa + t_body * bard
        body = (h >= 0) & (qa > 1e-12) & (y > 0) & (y < baba) & (t_body > 0)
        t[body] = t_body[body]
        # The end spheres: whichever is nearer along the ray (the ray may miss the cylinder entirely).
        for centre in (a, b):
            oc = -centre
            sb = rd @ oc
            sc = float(oc @ oc) - radius * radius
            sh = sb * sb - sc
            t_sphere = -sb - np.sqrt(np.maximum(sh, 0.0))
            hit = (sh > 0) & (t_sphere > 0) & (t_sphere < t)
            t[hit] = t_sphere[hit]
    return t


def _capsule_normals(rd: np.ndarray, t: np.ndarray, a: np.ndarray, b: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """Unit surface normals of the capsule ``a``-``b`` at the rays ``rd`` (n, 3) with ``wanted`` (n,) bool, hit
    at distances ``t`` (n,). The closest points along the axis are found for every hit, as one product (its
    rounding depends on how many rows it holds), the normals only where wanted."""
    ba = b - a
    hit = np.isfinite(t)
    points = rd[hit] * t[hit, None]
    s = np.clip((points - a) @ ba / max(float(ba @ ba), 1e-12), 0.0, 1.0)
    keep = wanted[hit]
    radial = points[keep] - (a + s[keep, None] * ba)
    return radial / np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-12)


def render_truth(
    world_from_camera: np.ndarray, intrinsics: Intrinsics, people_world: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact render of the capsule bodies from a camera: depth (H, W) float64 mm (+inf = no body),
    body index (H, W) uint8 (255 = background), and cos(incidence) (H, W) (0 where no body)."""
    width, height = intrinsics.width, intrinsics.height
    depth = np.full(width * height, np.inf)
    index = np.full(width * height, BODY_INDEX_BACKGROUND, dtype=np.uint8)
    incidence = np.zeros(width * height)
    starts, ends, radii, person = body_capsules(people_world)
    if starts.shape[0] == 0:
        return depth.reshape(height, width), index.reshape(height, width), incidence.reshape(height, width)
    camera_from_world = invert_transform(np.asarray(world_from_camera, dtype=np.float64))
    starts_c = transform_points(camera_from_world, starts)
    ends_c = transform_points(camera_from_world, ends)
    for a, b, radius, who in zip(starts_c, ends_c, radii, person, strict=True):
        z_near = min(a[2], b[2]) - radius
        if max(a[2], b[2]) + radius <= 1.0:
            continue  # behind the camera
        if z_near <= 1.0:  # the camera is inside or beside the capsule's depth span: test every pixel
            u0, u1, v0, v1 = 0, width, 0, height
        else:
            uv = intrinsics.project(np.stack([a, b]))
            margin_u = intrinsics.fx * radius / z_near + 2
            margin_v = intrinsics.fy * radius / z_near + 2
            u0 = max(0, int(np.floor(uv[:, 0].min() - margin_u)))
            u1 = min(width, int(np.ceil(uv[:, 0].max() + margin_u)) + 1)
            v0 = max(0, int(np.floor(uv[:, 1].min() - margin_v)))
            v1 = min(height, int(np.ceil(uv[:, 1].max() + margin_v)) + 1)
        if u0 >= u1 or v0 >= v1:
            continue
        rays, flat = _pixel_rays(intrinsics, u0, u1, v0, v1)
        t = _ray_capsule(rays, a, b, float(radius))
        z = t * rays[:, 2]
        nearer = z < depth[flat]  # hit, and nearer than what the capsules before it put there
        depth[flat[nearer]] = z[nearer]
        index[flat[nearer]] = who
        normal = _capsule_normals(rays, t, a, b, nearer)  # only where this capsule is what the pixel sees
        incidence[flat[nearer]] = np.clip(-np.einsum("ij,ij->i", rays[nearer], normal), 0.0, 1.0)
    return depth.reshape(height, width), index.reshape(height, width), incidence.reshape(height, width)


def render_sensor(
    sensor: VirtualSensor,
    people_world: np.ndarray,
    *,
    intrinsics: Intrinsics | None = None,
    noise: DepthNoise = DepthNoise(),
    rng: np.random.Generator | None = None,
) -> DepthFrame:
    """One sensor's depth, IR and body-index images of ``people_world`` ((P, 32, 3) true world joints).

    Pixels beyond the sensor's depth range, seen at a grazing angle, or randomly dropped are invalid
    (depth 0) and belong to no body (255), as the body tracker's map leaves pixels without depth.
    """
    intrinsics = Intrinsics.azure_kinect_nfov() if intrinsics is None else intrinsics
    rng = np.random.default_rng(0) if rng is None else rng
    depth, index, incidence = render_truth(sensor.world_from_sensor, intrinsics, people_world)
    valid = np.isfinite(depth) & (depth >= sensor.range_mm[0]) & (depth <= sensor.range_mm[1])
    valid &= incidence >= np.cos(np.radians(noise.grazing_deg)) - 1e-12
    if noise.dropout > 0:
        valid &= rng.random(depth.shape) >= noise.dropout
    noisy = depth.copy()
    if noise.sigma_mm > 0:
        noisy[valid] += rng.normal(0.0, noise.sigma_mm, int(valid.sum()))
    out_depth = np.zeros(depth.shape, dtype=np.uint16)
    out_depth[valid] = np.clip(np.rint(noisy[valid]), 1, 65535).astype(np.uint16)
    ir = np.zeros(depth.shape, dtype=np.uint16)
    ir[valid] = np.clip(np.rint(noise.ir_gain * incidence[valid] * (1000.0 / depth[valid]) ** 2), 0, 65535)
    body_index = np.where(valid, index, BODY_INDEX_BACKGROUND).astype(np.uint8)
    return DepthFrame(sensor.sensor_id, out_depth, ir, body_index, intrinsics, sensor.world_from_sensor)


def render_rig(
    sensors: list[VirtualSensor],
    people_world: np.ndarray,
    *,
    intrinsics: Intrinsics | None = None,
    noise: DepthNoise = DepthNoise(),
    seed: int = 0,
) -> list[DepthFrame]:
    """:func:`render_sensor` for every sensor of a rig at one instant (independent noise per sensor)."""
    rngs = [np.random.default_rng([seed, index]) for index in range(len(sensors))]
    return [
        render_sensor(sensor, people_world, intrinsics=intrinsics, noise=noise, rng=rng)
        for sensor, rng in zip(sensors, rngs, strict=True)
    ]
