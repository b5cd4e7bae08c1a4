"""Person clouds: into the world, merged across sensors, voxelized.

A person cloud is an (N, 3) float array of points in mm, optionally with one IR intensity per point. The
paper (Sec. 3.2) voxelizes every cloud before it crosses the network and merges the world-frame clouds by
concatenation (Eq. 2, the ⊕); the merged cloud is voxelized again so that a surface seen by several sensors
is not weighted by how many saw it (the PCA of :mod:`.frontal` would otherwise lean towards the best-seen side).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skelfuse.fusion.camera import Intrinsics
from skelfuse.fusion.transform import transform_points


@dataclass(frozen=True)
class MergedCloud:
    """One person's clouds from every sensor, in the world frame.

    Attributes
    ----------
    points : (N, 3) float64 world mm.
    sensor_index : (N,) int16, which input cloud each point came from (for colouring by sensor; after
        :func:`voxelize` it is the sensor with the most points in the voxel, ties to the lowest index).
    ir : (N,) float32 IR intensity, or None when the clouds carry none.
    """

    points: np.ndarray
    sensor_index: np.ndarray
    ir: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.points.shape[0])


def voxelize(
    points: np.ndarray,
    voxel_mm: float,
    *,
    values: np.ndarray | None = None,
    labels: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """One point per occupied voxel: the centroid of the points in it (PCL's VoxelGrid rule).

    Parameters
    ----------
    points : (N, 3) mm.
    voxel_mm : edge of the cubic voxel, mm (the issue suggests 15 mm; the paper used 20 mm).
    values : optional (N,) per-point values (IR), averaged per voxel.
    labels : optional (N,) small non-negative ints (sensor index), the most frequent per voxel.

    Returns
    -------
    (M, 3) float64 centroids, (M,) float32 mean values or None, (M,) int16 majority labels or None. The
    voxels come out in lexicographic order of their integer coordinates (deterministic).
    """
    if not (np.isfinite(voxel_mm) and voxel_mm > 0):
        raise ValueError(f"voxel_mm must be a positive number, got {voxel_mm!r}")
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if p.shape[0] == 0:
        empty_values = None if values is None else np.zeros(0, np.float32)
        empty_labels = None if labels is None else np.zeros(0, np.int16)
        return np.zeros((0, 3)), empty_values, empty_labels
    cells = np.floor(p / voxel_mm).astype(np.int64)
    cells -= cells.min(axis=0)
    span = cells.max(axis=0) + 1
    # One int64 key per cell, in lexicographic order of (x, y, z): a 1-D unique is far faster than axis=0.
    keys = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
    _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    n_voxels = counts.shape[0]
    centroids: np.ndarray = np.stack(
        [np.bincount(inverse, weights=p[:, axis], minlength=n_voxels) for axis in range(3)], 1
    )
    centroids /= counts[:, None]
    mean_values = None
    if values is not None:
        v = np.asarray(values, dtype=np.float64).reshape(-1)
        mean_values = (np.bincount(inverse, weights=v, minlength=n_voxels) / counts).astype(np.float32)
    majority = None
    if labels is not None:
        lab = np.asarray(labels, dtype=np.int64).reshape(-1)
        n_labels = int(lab.max()) + 1
        votes = np.zeros((n_voxels, n_labels), dtype=np.int64)
        np.add.at(votes, (inverse, lab), 1)
        majority = votes.argmax(axis=1).astype(np.int16)
    return centroids, mean_values, majority


def clouds_to_world(clouds: list[np.ndarray], world_from_sensor: np.ndarray) -> list[np.ndarray]:
    """Each sensor's cloud (sensor frame, mm) into the world by its calibration (``fusion.transform``).

    Parameters
    ----------
    clouds : S arrays (N_s, 3), one per sensor (an empty array where the sensor does not see the person).
    world_from_sensor : (S, 4, 4).
    """
    poses = np.asarray(world_from_sensor, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[0] != len(clouds):
        raise ValueError(f"one world_from_sensor per cloud: {len(clouds)} clouds, poses of shape {poses.shape}")
    return [
        transform_points(pose, np.asarray(cloud, dtype=np.float64).reshape(-1, 3))
        for pose, cloud in zip(poses, clouds, strict=True)
    ]


def merge_clouds(
    world_clouds: list[np.ndarray],
    *,
    voxel_mm: float | None,
    ir: list[np.ndarray] | None = None,
    refinements: np.ndarray | None = None,
) -> MergedCloud:
    """Eq. 2: the union of the world-frame clouds (each first moved by its ICP refinement), voxelized.

    Parameters
    ----------
    world_clouds : S arrays (N_s, 3), world mm.
    voxel_mm : voxel edge of the merged cloud, mm; None keeps every point.
    ir : optional S arrays (N_s,) of IR intensity.
    refinements : optional (S, 4, 4) world-to-world corrections (``T_ICP^i`` of Eq. 2, identity for the
        reference), e.g. from :func:`skelfuse.fusion.depth.icp.refine_clouds`.
    """
    if ir is not None and len(ir) != len(world_clouds):
        raise ValueError(f"ir must hold one array per cloud: {len(ir)} for {len(world_clouds)} clouds")
    parts = [np.asarray(c, dtype=np.float64).reshape(-1, 3) for c in world_clouds]
    if refinements is not None:
        parts = [transform_points(T, part) for T, part in zip(refinements, parts, strict=True)]
    points = np.concatenate(parts) if parts else np.zeros((0, 3))
    index = (
        np.concatenate([np.full(len(part), s, np.int16) for s, part in enumerate(parts)])
        if parts
        else np.zeros(0, np.int16)
    )
    values = None if ir is None else np.concatenate([np.asarray(v, np.float32).reshape(-1) for v in ir])
    if values is not None and values.shape[0] != points.shape[0]:
        raise ValueError("ir must hold one value per point of each cloud")
    if voxel_mm is None or points.shape[0] == 0:
        return MergedCloud(points, index, values)
    centroids, mean_ir, majority = voxelize(points, voxel_mm, values=values, labels=index)
    assert majority is not None
    return MergedCloud(centroids, majority, mean_ir)


@dataclass(frozen=True)
class PersonCloud:
    """One tracked body's points as a capture worker sends them: sensor frame, voxelized.

    Attributes
    ----------
    body_index : the body's index in the body-index map (its position in the tracker's body frame).
    points : (N, 3) float64 sensor-frame mm (voxel centroids).
    ir : (N,) float32 mean IR per voxel, or None.
    """

    body_index: int
    points: np.ndarray
    ir: np.ndarray | None = None


def pinhole_xy_table(intrinsics: Intrinsics) -> np.ndarray:
    """The xy table of a pinhole camera: (H, W, 2) float32 rays ((u - cx) / fx, (v - cy) / fy) per pixel (the
    simulator's sensors and the virtual camera have no lens distortion)."""
    u = (np.arange(intrinsics.width) - intrinsics.cx) / intrinsics.fx
    v = (np.arange(intrinsics.height) - intrinsics.cy) / intrinsics.fy
    return np.stack(np.broadcast_arrays(u[None, :], v[:, None]), axis=-1).astype(np.float32)


def lift_xy_table(xy_table: np.ndarray, rows: np.ndarray, cols: np.ndarray, depth_mm: np.ndarray) -> np.ndarray:
    """Points (x d, y d, d) of depth pixels (rows, cols) of depth ``depth_mm`` through an (H, W, 2) xy table (the
    ray of each pixel at unit depth, NaN where the lens model has none): the SDK's fastpointcloud lift, with
    the lens distortion in the table. (N, 3) float64 mm; a pixel with a NaN ray gives a NaN point."""
    ray = np.asarray(xy_table)[rows, cols].astype(np.float64)
    d = np.asarray(depth_mm, dtype=np.float64).reshape(-1)
    return np.stack([ray[:, 0] * d, ray[:, 1] * d, d], axis=1)


def person_clouds(
    depth_mm: np.ndarray,
    body_index_map: np.ndarray,
    lens: Intrinsics | np.ndarray,
    *,
    voxel_mm: float,
    ir: np.ndarray | None = None,
    background: int = 255,
) -> list[PersonCloud]:
    """Every body's cloud: the depth image masked by the body tracker's body-index map, lifted to the sensor
    frame and voxelized (paper Sec. 3.2: voxelize before sending, to keep the network load bounded).

    Parameters
    ----------
    depth_mm : (H, W) depth image, mm, 0 = invalid.
    body_index_map : (H, W) uint8, the body index per pixel, ``background`` (255) elsewhere.
    lens : the depth camera's pinhole :class:`Intrinsics`, or its (H, W, 2) xy table (the ray per pixel with
        the lens distortion, NaN where invalid: ``skelfuse.sources.k4abt.depth_xy_table``); pixels without a
        ray are dropped.
    voxel_mm : voxel edge, mm.
    ir : optional (H, W) IR image.
    """
    index_map = np.asarray(body_index_map)
    depth = np.asarray(depth_mm)
    if index_map.shape != depth.shape:
        raise ValueError(f"body-index map {index_map.shape} and depth image {depth.shape} differ in size")
    mask = (index_map != background) & (depth > 0)
    if isinstance(lens, Intrinsics):
        rows, cols = np.nonzero(mask)
        points = lens.lift(cols, rows, depth[rows, cols]) if rows.size else np.zeros((0, 3))
    else:
        table = np.asarray(lens)
        if table.shape != (*depth.shape, 2):
            raise ValueError(f"xy table {table.shape} does not fit a depth image of {depth.shape}")
        rows, cols = np.nonzero(mask & np.isfinite(table).all(axis=-1))
        points = lift_xy_table(table, rows, cols, depth[rows, cols])
    bodies = index_map[rows, cols].astype(np.int64)
    values = None if ir is None else np.asarray(ir)[rows, cols].astype(np.float64)
    out = []
    for body in np.unique(bodies):
        mine = bodies == body
        centroids, mean_ir, _ = voxelize(points[mine], voxel_mm, values=None if values is None else values[mine])
        out.append(PersonCloud(int(body), centroids, mean_ir))
    return out
