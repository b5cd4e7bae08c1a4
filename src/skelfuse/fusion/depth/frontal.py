"""Frontal view warping (paper Sec. 3.4, Eqs. 3-8) and the virtual camera in front of the person.

The paper projects the merged cloud onto the floor plane (Eq. 3), takes the principal axis of that oval
(Eqs. 4-5: the shoulder-to-shoulder direction of a standing person) and rotates the cloud about the vertical
by the axis angle θ (Eq. 6) so that the person faces the reference camera (Eqs. 7-8). Three things go beyond
(or fix) the paper here:

* **Front or back.** A principal axis has two ends: θ and θ + 180° fit the cloud equally well, so the PCA
  alone cannot tell the person's front from their back, and a tracker shown a back view labels left and right
  the wrong way round. When the fused skeleton knows which way the body faces (:func:`body_facing`, from hips
  and shoulders), that decides; without it the side that faces the reference sensor is taken (the paper's
  implicit choice).
* **The full axis angle.** Eq. 6's ``arccos(v̂ · u_x)`` gives the same θ for axes mirrored about x (+30° and
  −30°); we use ``atan2`` of the eigenvector, folded to [0°, 180°), which is what Eq. 6 means for an axis.
* **Centre, then rotate.** Eq. 7 as printed subtracts the centroid after rotating; the warp intended (and
  implemented here) is ``R (p − p̄)``.

Rather than warping the cloud in front of a fixed camera, we place the virtual camera in front of the person
(same image: rendering is invariant to moving both by one rigid transform); :class:`FrontalView` holds both
the warp (:attr:`FrontalView.frontal_from_world`, Eqs. 7-8) and the camera pose, and maps a skeleton found in
the virtual image back to the world (:meth:`FrontalView.to_world`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skelfuse.fusion.camera import Intrinsics, look_at_pose
from skelfuse.fusion.transform import invert_transform, transform_points
from skelfuse.schema.skeleton import joint_index

_HIP_L, _HIP_R = joint_index("HIP_LEFT"), joint_index("HIP_RIGHT")
_SHOULDER_L, _SHOULDER_R = joint_index("SHOULDER_LEFT"), joint_index("SHOULDER_RIGHT")

DEFAULT_WORKING_DISTANCE_MM = 2300.0
"""How far in front of the person the virtual camera stands: the paper rig's best-view distance, well inside
the NFOV depth range (0.5-3.86 m) with a 1.9 m person inside the 65° vertical field of view."""


def body_facing(positions: np.ndarray) -> np.ndarray:
    """Horizontal unit vector the body faces, from the hips and shoulders.

    Parameters
    ----------
    positions : (..., 32, 3) world mm (z up).

    Returns
    -------
    (..., 3) unit vectors with zero z: forward = left × up, where left points from the right hip and
    shoulder to the left ones. NaN where those joints are missing.
    """
    left = (
        positions[..., _HIP_L, :]
        - positions[..., _HIP_R, :]
        + positions[..., _SHOULDER_L, :]
        - positions[..., _SHOULDER_R, :]
    )
    forward = np.stack([left[..., 1], -left[..., 0], np.zeros_like(left[..., 0])], axis=-1)
    norm = np.linalg.norm(forward, axis=-1, keepdims=True)
    return forward / np.maximum(norm, 1e-9)


CHEST_BAND = (0.65, 0.82)
"""Heights, as fractions of the cloud's z extent from its lowest point, of the points the principal axis is
taken from: the chest, below the shoulders and above the hanging hands. The paper uses the whole cloud and
notes that the arms disturb the axis (its Sec. 3.4 names a torso-only cloud as future work); legs in a
stride, a lunge or a squat disturb it more, since they stretch the floor projection along the facing
direction: on the simulator's squats, walks and lunges the whole cloud's axis can be off by nearly a right
angle, the band's by a few degrees (``scripts/measure_frontal_axis.py``). ``None`` uses every point, as the
paper does."""


def principal_axis_deg(
    points_world: np.ndarray, *, band: tuple[float, float] | None = CHEST_BAND
) -> tuple[float, np.ndarray]:
    """Eqs. 3-6: the floor-plane principal axis of a cloud.

    Parameters
    ----------
    points_world : (N, 3) world mm, z up.
    band : keep only points within this height band (fractions of the z extent), see :data:`CHEST_BAND`.

    Returns
    -------
    axis_deg : the angle of the major axis of the cloud's xy projection from world +x, degrees in [0, 180).
    centroid_xy : (2,) p̄ of Eq. 4 (of the points used), mm.
    """
    p = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    if band is not None and p.shape[0]:
        low, high = float(p[:, 2].min()), float(p[:, 2].max())
        z_fraction = (p[:, 2] - low) / max(high - low, 1e-9)
        p = p[(z_fraction >= band[0]) & (z_fraction <= band[1])]
    xy = p[:, :2]  # Eq. 3: drop z
    if xy.shape[0] < 3:
        raise ValueError(f"frontalization needs at least 3 points, got {xy.shape[0]}")
    centroid = xy.mean(axis=0)
    centred = xy - centroid
    covariance = centred.T @ centred / xy.shape[0]  # Eq. 4
    _, vectors = np.linalg.eigh(covariance)  # Eq. 5, ascending eigenvalues
    major = vectors[:, 1]  # v̂ = the eigenvector of the larger eigenvalue
    return float(np.degrees(np.arctan2(major[1], major[0])) % 180.0), centroid  # Eq. 6 (full angle)


def _angle_gap_deg(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def choose_facing_deg(
    axis_deg: float,
    *,
    skeleton_facing_deg: float | None = None,
    toward_xy: np.ndarray | None = None,
    centroid_xy: np.ndarray | None = None,
) -> tuple[float, str]:
    """The front/back decision: which normal of the principal axis the person faces, and what decided it.

    The two candidates are ``axis_deg ± 90°``. The skeleton's facing decides when known (finite); otherwise
    the candidate pointing towards ``toward_xy`` (the reference sensor, seen from ``centroid_xy``); otherwise
    ``axis_deg + 90°``. Returns (facing_deg in (-180, 180], "skeleton" | "reference" | "default").
    """
    candidates = ((axis_deg + 90.0 + 180.0) % 360.0 - 180.0, (axis_deg - 90.0 + 180.0) % 360.0 - 180.0)
    if skeleton_facing_deg is not None and np.isfinite(skeleton_facing_deg):
        gaps = [_angle_gap_deg(c, float(skeleton_facing_deg)) for c in candidates]
        return candidates[int(np.argmin(gaps))], "skeleton"
    if toward_xy is not None and centroid_xy is not None:
        direction = np.asarray(toward_xy, np.float64) - np.asarray(centroid_xy, np.float64)
        toward_deg = float(np.degrees(np.arctan2(direction[1], direction[0])))
        gaps = [_angle_gap_deg(c, toward_deg) for c in candidates]
        return candidates[int(np.argmin(gaps))], "reference"
    return candidates[0], "default"


@dataclass(frozen=True)
class FrontalView:
    """A person's frontal warp and the virtual camera that looks at the front of them.

    Attributes
    ----------
    axis_deg : principal axis of the floor projection (Eq. 6, full angle), degrees in [0, 180).
    facing_deg : the direction the person is taken to face, degrees from world +x.
    decided_by : "skeleton", "reference" or "default": what chose between the two ends of the axis.
    centroid_mm : (3,) the cloud's floor-plane centroid p̄, at the height of the middle of its z extent.
    frontal_from_world : (4, 4) the warp of Eqs. 7-8: origin at p̄ (floor level), the person facing +y,
        z up (so the person's left is −x).
    world_from_camera : (4, 4) the virtual camera (x right, y down, z forward), in front of the person.
    intrinsics : the virtual camera's intrinsics (the reference sensor's).
    """

    axis_deg: float
    facing_deg: float
    decided_by: str
    centroid_mm: np.ndarray
    frontal_from_world: np.ndarray
    world_from_camera: np.ndarray
    intrinsics: Intrinsics

    @property
    def camera_from_world(self) -> np.ndarray:
        return invert_transform(self.world_from_camera)

    def to_camera(self, points_world: np.ndarray) -> np.ndarray:
        """(..., 3) world points into the virtual camera frame (the frame its depth image is in)."""
        return transform_points(self.camera_from_world, points_world)

    def to_world(self, points_camera: np.ndarray) -> np.ndarray:
        """The inverse warp: (..., 3) points in the virtual camera frame (a skeleton a tracker found in the
        virtual image) back to the world. NaN stays NaN."""
        return transform_points(self.world_from_camera, points_camera)


def frontal_view(
    points_world: np.ndarray,
    intrinsics: Intrinsics,
    *,
    skeleton_facing_deg: float | None = None,
    reference_position_mm: np.ndarray | None = None,
    distance_mm: float = DEFAULT_WORKING_DISTANCE_MM,
    camera_height_mm: float | None = None,
) -> FrontalView:
    """Frontalize a person's merged world cloud and place the virtual camera in front of them.

    Parameters
    ----------
    points_world : (N, 3) merged cloud, world mm (z up).
    intrinsics : the virtual camera's intrinsics (the reference sensor's).
    skeleton_facing_deg : the fused skeleton's facing (degrees from world +x, e.g. from :func:`body_facing`);
        None or NaN when unknown.
    reference_position_mm : (3,) the reference sensor's position, used for front/back when the skeleton
        does not say.
    distance_mm : horizontal distance from the person's axis to the camera, mm.
    camera_height_mm : camera height above the floor; None puts it level with the middle of the cloud
        (a level camera, looking horizontally at the person's centre).
    """
    if not (np.isfinite(distance_mm) and distance_mm > 0):
        raise ValueError(f"distance_mm must be a positive number, got {distance_mm!r}")
    p = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    axis_deg, centroid_xy = principal_axis_deg(p)
    toward = None if reference_position_mm is None else np.asarray(reference_position_mm, np.float64)[:2]
    facing_deg, decided_by = choose_facing_deg(
        axis_deg, skeleton_facing_deg=skeleton_facing_deg, toward_xy=toward, centroid_xy=centroid_xy
    )
    z_mid = 0.5 * (float(p[:, 2].min()) + float(p[:, 2].max()))
    height = z_mid if camera_height_mm is None else float(camera_height_mm)
    # Eq. 7 (centre, then rotate): the person's facing direction becomes +y.
    turn = np.radians(90.0 - facing_deg)
    c, s = np.cos(turn), np.sin(turn)
    frontal_from_world = np.eye(4)
    frontal_from_world[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    frontal_from_world[:3, 3] = -(frontal_from_world[:3, :3] @ np.array([centroid_xy[0], centroid_xy[1], 0.0]))
    camera_in_frontal = look_at_pose(np.array([0.0, distance_mm, height]), np.array([0.0, 0.0, z_mid]))
    world_from_camera = invert_transform(frontal_from_world) @ camera_in_frontal
    return FrontalView(
        axis_deg=axis_deg,
        facing_deg=facing_deg,
        decided_by=decided_by,
        centroid_mm=np.array([centroid_xy[0], centroid_xy[1], z_mid]),
        frontal_from_world=frontal_from_world,
        world_from_camera=world_from_camera,
        intrinsics=intrinsics,
    )
