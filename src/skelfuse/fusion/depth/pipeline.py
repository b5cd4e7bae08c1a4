"""One person's depth-level fusion for one instant: world clouds → (ICP) → merge → frontalize → render.

The stages are those of the paper (Eq. 2, Sec. 3.4-3.5), each its own function in this package; this module
only chains them so that the fusion node, the benchmark and the tests run the same sequence. The tracker
call on :attr:`PersonDepthView.image` is an adapter (``sources/k4abt.py``); its skeleton comes back to the
world through :meth:`PersonDepthView.frontal.to_world`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skelfuse.fusion.camera import Intrinsics
from skelfuse.fusion.depth.cloud import MergedCloud, clouds_to_world, merge_clouds
from skelfuse.fusion.depth.frontal import DEFAULT_WORKING_DISTANCE_MM, FrontalView, frontal_view
from skelfuse.fusion.depth.icp import IcpResult, refine_clouds
from skelfuse.fusion.depth.render import DEFAULT_FILL_RADIUS_PX, VirtualImage, render_points


@dataclass(frozen=True)
class DepthFusionParams:
    """Settings of the depth-level fusion.

    Attributes
    ----------
    voxel_mm : voxel edge of the merged cloud, mm (the capture side voxelizes with the same size).
    icp : refine each sensor's cloud against the reference sensor's by point-to-plane ICP.
    icp_max_pair_mm : pairs farther apart are ignored by ICP (the calibration error it can absorb).
    distance_mm : the virtual camera's distance in front of the person.
    fill_radius_px : Eq. 10's ε.
    splat : render each voxel over its footprint (``render_points(splat_mm=voxel_mm)``), so the back of the
        body cannot show through the gaps between the front's voxels.
    """

    voxel_mm: float = 15.0
    icp: bool = False
    icp_max_pair_mm: float = 60.0
    distance_mm: float = DEFAULT_WORKING_DISTANCE_MM
    fill_radius_px: float = DEFAULT_FILL_RADIUS_PX
    splat: bool = True


@dataclass(frozen=True)
class PersonDepthView:
    """Everything the depth-level fusion made of one person at one instant."""

    merged: MergedCloud
    frontal: FrontalView
    image: VirtualImage
    icp: list[IcpResult | None] | None


def fuse_person_depth(
    sensor_clouds: list[np.ndarray],
    world_from_sensor: np.ndarray,
    intrinsics: Intrinsics,
    *,
    reference: int = 0,
    skeleton_facing_deg: float | None = None,
    ir: list[np.ndarray] | None = None,
    params: DepthFusionParams = DepthFusionParams(),
) -> PersonDepthView:
    """Fuse one person's clouds (one per sensor, sensor frame mm; empty where unseen) into a frontal
    virtual depth (and IR) image.

    Parameters
    ----------
    world_from_sensor : (S, 4, 4) calibration.
    intrinsics : the virtual camera's (the reference sensor's).
    reference : index of the reference sensor (ICP target; front/back fallback).
    skeleton_facing_deg : the fused skeleton's facing, degrees from world +x, None / NaN when unknown.
    """
    world = clouds_to_world(sensor_clouds, world_from_sensor)
    corrections, results = None, None
    if params.icp:
        positions = np.asarray(world_from_sensor, np.float64)[:, :3, 3]
        corrections, results = refine_clouds(world, positions, reference=reference, max_pair_mm=params.icp_max_pair_mm)
    merged = merge_clouds(world, voxel_mm=params.voxel_mm, ir=ir, refinements=corrections)
    reference_position = np.asarray(world_from_sensor, np.float64)[reference, :3, 3]
    frontal = frontal_view(
        merged.points,
        intrinsics,
        skeleton_facing_deg=skeleton_facing_deg,
        reference_position_mm=reference_position,
        distance_mm=params.distance_mm,
    )
    image = render_points(
        merged.points,
        frontal.world_from_camera,
        intrinsics,
        ir=merged.ir,
        fill_radius_px=params.fill_radius_px,
        splat_mm=params.voxel_mm if params.splat else 0.0,
    )
    return PersonDepthView(merged, frontal, image, results)
