"""Point-to-plane ICP of one world-frame cloud against another: the ``T_ICP^i`` of the paper's Eq. 2.

Why our own small ICP on scipy's cKDTree instead of a kept library (Open3D's ``registration_icp``): the pure
core imports numpy and scipy only (``docs/architecture.md``); Open3D installs here but is a 400 MB wheel
(0.20.0, cp311 manylinux, checked with pip) for one function; our clouds are small (a few thousand voxels per
person and sensor); and the guards people need (below) would have to be written around it anyway.

The method is the standard linearized point-to-plane step (Chen & Medioni; Low 2004): for pairs
(source p, target q, target normal n), minimize Σ ((R p + t − q) · n)² with R ≈ I + [ω]×, solve the 6x6
normal equations, compose, repeat. Two guards specific to people:

* Sensors around a person see different sides of the body: only pairs closer than ``max_pair_mm`` whose
  normals (turned towards the sensor that saw each point) agree count, so the back of an arm seen by one
  sensor never pulls on the front of it seen by another; and each cloud is registered to all the others
  together (:func:`refine_clouds`), not to the reference alone, with which an opposite sensor shares no
  surface.
* A standing body is nearly a vertical cylinder: a rotation about its axis is barely constrained by the
  surface. A small Levenberg-Marquardt damping keeps the unconstrained directions at zero instead of
  letting noise turn the cloud.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from skelfuse.fusion.transform import transform_points

_MIN_PAIRS = 50


@dataclass(frozen=True)
class IcpResult:
    """Outcome of :func:`icp_point_to_plane`.

    Attributes
    ----------
    transform : (4, 4) world-to-world correction to apply to the source cloud (identity when ICP gave up).
    rmse_before_mm, rmse_after_mm : point-to-plane RMS residual of the kept pairs before and after, mm.
    n_pairs : pairs kept in the last iteration.
    iterations : iterations run.
    converged : the last step moved less than the tolerances (False also when too few pairs were found).
    """

    transform: np.ndarray
    rmse_before_mm: float
    rmse_after_mm: float
    n_pairs: int
    iterations: int
    converged: bool


def estimate_normals(
    points: np.ndarray, k: int = 12, tree: cKDTree | None = None, viewpoint: np.ndarray | None = None
) -> np.ndarray:
    """(N, 3) unit normals: the smallest principal axis of each point's k nearest neighbours, turned towards
    ``viewpoint`` (the sensor that saw the points, world mm) when given, else of arbitrary sign."""
    p = np.asarray(points, dtype=np.float64)
    k = int(min(k, p.shape[0]))
    tree = cKDTree(p) if tree is None else tree
    _, neighbours = tree.query(p, k=k)
    gathered = p[neighbours]  # (N, k, 3)
    local = gathered - gathered.mean(axis=1, keepdims=True)
    covariance = np.einsum("nki,nkj->nij", local, local)
    _, vectors = np.linalg.eigh(covariance)  # ascending eigenvalues
    normals = vectors[:, :, 0]
    if viewpoint is not None:
        away = np.einsum("ij,ij->i", normals, np.asarray(viewpoint, np.float64) - p) < 0
        normals[away] *= -1.0
    return normals


def _skew_step(x: np.ndarray) -> np.ndarray:
    """The rigid transform of a small step (ω, t): the rotation by Rodrigues' formula (exact, orthonormal)."""
    omega, t = x[:3], x[3:]
    angle = float(np.linalg.norm(omega))
    K = np.array([[0.0, -omega[2], omega[1]], [omega[2], 0.0, -omega[0]], [-omega[1], omega[0], 0.0]])
    if angle < 1e-12:
        R = np.eye(3)
    else:
        K_unit = K / angle
        R = np.eye(3) + np.sin(angle) * K_unit + (1.0 - np.cos(angle)) * (K_unit @ K_unit)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def icp_point_to_plane(
    source: np.ndarray,
    target: np.ndarray,
    *,
    target_normals: np.ndarray,
    source_normals: np.ndarray | None = None,
    max_pair_mm: float = 60.0,
    min_normal_cos: float = 0.5,
    iterations: int = 15,
    damping: float = 1e-2,
    tolerance_mm: float = 0.05,
    max_source_points: int = 800,
    source_frames: np.ndarray | None = None,
    target_frames: np.ndarray | None = None,
) -> IcpResult:
    """Rigid correction that moves ``source`` onto ``target`` (both (N, 3) world mm).

    Parameters
    ----------
    target_normals : (N_target, 3) unit normals of ``target``, turned towards the sensors that saw them
        (:func:`estimate_normals` with ``viewpoint``).
    source_normals : (N_source, 3) the same for ``source``; when given, pairs whose normals disagree by more
        than ``arccos(min_normal_cos)`` are ignored: the front of a limb seen by one sensor is never paired
        with the back of it seen by another, although they may lie a few centimetres apart.
    max_pair_mm : pairs farther apart than this are ignored (the calibration error this can absorb).
    iterations : at most this many linearized steps.
    damping : Levenberg-Marquardt damping, relative to the mean diagonal of the rotation and of the
        translation block of the normal equations (each block its own scale: mm² against 1).
    tolerance_mm : stop when a step moves no source point by more than about this.
    max_source_points : ICP runs on an even subsample of at most this many source points (speed: six
        unknowns need far fewer pairs than a cloud has).
    source_frames, target_frames : optional (N,) frame numbers: a point pairs only with points of its own
        frame (for clouds stacked over the frames of a walk-through; the people move between frames).
    """
    src = np.asarray(source, dtype=np.float64).reshape(-1, 3)
    dst = np.asarray(target, dtype=np.float64).reshape(-1, 3)
    dst_normals = np.asarray(target_normals, dtype=np.float64).reshape(-1, 3)
    src_normals = None if source_normals is None else np.asarray(source_normals, dtype=np.float64).reshape(-1, 3)
    if (source_frames is None) != (target_frames is None):
        raise ValueError("give frame numbers for both clouds or for neither")
    src_label = None if source_frames is None else np.asarray(source_frames, np.float64).reshape(-1)
    if src.shape[0] > max_source_points:
        keep = np.linspace(0, src.shape[0] - 1, max_source_points).astype(np.int64)
        src = src[keep]
        src_normals = None if src_normals is None else src_normals[keep]
        src_label = None if src_label is None else src_label[keep]
    if src.shape[0] < _MIN_PAIRS or dst.shape[0] < _MIN_PAIRS:
        return IcpResult(np.eye(4), float("nan"), float("nan"), 0, 0, False)
    # Frame numbers become a fourth coordinate far larger than any pairing distance: pairs stay within a frame.
    frame_gap = 100.0 * max_pair_mm
    if target_frames is None:
        target = dst
    else:
        target = np.column_stack([dst, np.asarray(target_frames, np.float64).reshape(-1) * frame_gap])
    # Split at midpoints, not medians: on these clouds (frames far apart along the fourth coordinate) that
    # builds the tree 40% faster and answers the queries faster too; the nearest neighbours are the same.
    tree = cKDTree(target, balanced_tree=False)
    extent = float(np.linalg.norm(src - src.mean(axis=0), axis=1).max())

    def pairs(total: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        moved = transform_points(total, src)
        query = moved if src_label is None else np.column_stack([moved, src_label * frame_gap])
        distance, nearest = tree.query(query, distance_upper_bound=max_pair_mm)
        keep = np.isfinite(distance)
        if src_normals is not None:
            turned = src_normals @ total[:3, :3].T
            agree = np.einsum("ij,ij->i", turned, dst_normals[np.minimum(nearest, dst.shape[0] - 1)])
            keep &= agree >= min_normal_cos
        q, n = dst[nearest[keep]], dst_normals[nearest[keep]]
        return moved[keep], q, n, np.einsum("ij,ij->i", q - moved[keep], n)

    total = np.eye(4)
    rmse_before = float("nan")
    converged = False
    iteration = 0
    for iteration in range(1, iterations + 1):
        p, _, n, residual = pairs(total)
        if residual.shape[0] < _MIN_PAIRS:
            break
        if iteration == 1:
            rmse_before = float(np.sqrt(np.mean(residual**2)))
        # Linearized about the pairs' centroid, so rotation and translation are balanced:
        # residual after the step = r - ω·((p - c) × n) - t·n.
        centre = p.mean(axis=0)
        A = np.concatenate([np.cross(p - centre, n), n], axis=1)
        normal_matrix = A.T @ A
        diagonal = np.diag(normal_matrix)
        normal_matrix += damping * np.diag(np.repeat([diagonal[:3].mean(), diagonal[3:].mean()], 3))
        step = np.linalg.solve(normal_matrix, A.T @ residual)
        to_centre, from_centre = np.eye(4), np.eye(4)
        to_centre[:3, 3], from_centre[:3, 3] = centre, -centre
        total = to_centre @ _skew_step(step) @ from_centre @ total
        if np.linalg.norm(step[3:]) + np.linalg.norm(step[:3]) * extent < tolerance_mm:
            converged = True
            break
    _, _, _, residual = pairs(total)
    if residual.shape[0] < _MIN_PAIRS:
        return IcpResult(np.eye(4), rmse_before, float("nan"), int(residual.shape[0]), iteration, False)
    return IcpResult(
        total, rmse_before, float(np.sqrt(np.mean(residual**2))), int(residual.shape[0]), iteration, converged
    )


def refine_clouds(
    world_clouds: list[np.ndarray],
    sensor_positions: np.ndarray,
    *,
    reference: int,
    passes: int = 2,
    **icp_options: float,
) -> tuple[np.ndarray, list[IcpResult | None]]:
    """Every cloud's ``T_ICP^i`` (Eq. 2); identity for the reference.

    The paper registers each cloud to the reference sensor's. Around a person, a sensor opposite the
    reference shares almost no surface with it (they see front and back), and two sensors 90° apart share
    only the body's sides, where a pairwise fit is biased (off by a degree or two even from a perfect
    calibration). So
    each cloud is registered to the union of all the others, in turn, for ``passes`` rounds (Gauss-Seidel:
    each registration sees the others' latest corrections), the reference staying put. A sensor whose
    calibration is off is pulled onto the consensus of the others; the others, pulled a little by it in the
    first round, settle back in the next. Normals are turned towards their own sensor and pairs must agree
    in normal (see :func:`icp_point_to_plane`).

    Parameters
    ----------
    world_clouds : S arrays (N_s, 3), world mm (after the calibration).
    sensor_positions : (S, 3) each sensor's position in the world, mm (orients the normals).
    reference : the cloud left where the calibration puts it.
    passes : rounds over all the clouds.

    Returns (S, 4, 4) corrections for :func:`skelfuse.fusion.depth.cloud.merge_clouds` and the per-cloud
    :class:`IcpResult` (None for the reference and for clouds too small to register).
    """
    if not 0 <= reference < len(world_clouds):
        raise ValueError(f"reference {reference} is not one of the {len(world_clouds)} clouds")
    clouds = [np.asarray(c, dtype=np.float64).reshape(-1, 3) for c in world_clouds]
    positions = np.asarray(sensor_positions, dtype=np.float64).reshape(-1, 3)
    usable = [c.shape[0] >= _MIN_PAIRS for c in clouds]
    normals = [
        estimate_normals(c, viewpoint=pos) if ok else np.zeros((c.shape[0], 3))
        for c, pos, ok in zip(clouds, positions, usable, strict=True)
    ]
    corrections = np.repeat(np.eye(4)[None], len(clouds), axis=0)
    results: list[IcpResult | None] = [None] * len(clouds)
    if not usable[reference]:
        return corrections, results
    current = list(clouds)
    current_normals = list(normals)
    for _ in range(passes):
        for index in range(len(clouds)):
            others = [j for j in range(len(clouds)) if j != index and usable[j]]
            if index == reference or not usable[index] or not others:
                continue
            result = icp_point_to_plane(
                current[index],
                np.concatenate([current[j] for j in others]),
                target_normals=np.concatenate([current_normals[j] for j in others]),
                source_normals=current_normals[index],
                **icp_options,  # type: ignore[arg-type]  # keyword options passed through to icp_point_to_plane as given
            )
            corrections[index] = result.transform @ corrections[index]
            results[index] = result
            current[index] = transform_points(corrections[index], clouds[index])
            current_normals[index] = normals[index] @ corrections[index][:3, :3].T
    return corrections, results


def refine_poses_from_walk(
    frames: list[list[np.ndarray]],
    world_from_sensor: np.ndarray,
    *,
    reference: int,
    passes: int = 3,
    max_pair_mm: float = 80.0,
    max_source_points: int = 4000,
    normals: list[list[np.ndarray | None]] | None = None,
) -> tuple[np.ndarray, list[IcpResult | None]]:
    """Refine every sensor's pose by ICP on a person walking through (the paper's calibration refinement).

    One frame of a roughly cylindrical body barely constrains a turn about its axis; a walk-through, the
    person at many places and in many poses, does. Each sensor's clouds of all frames, stacked, are
    registered to the other sensors' clouds of the same frames (points pair only within their frame), in
    turn, for ``passes`` rounds; the reference sensor stays put.

    Parameters
    ----------
    frames : T lists of S clouds (N, 3) in each sensor's frame, mm (empty where a sensor does not see anyone).
    world_from_sensor : (S, 4, 4) the calibration to refine.
    reference : the sensor that defines the world with the calibration (not moved).
    normals : :func:`walk_normals` of ``frames`` when the caller has them already (refining the same clouds
        several times); None: computed here.

    Returns
    -------
    (S, 4, 4) refined ``world_from_sensor`` and, per sensor, the last pass's :class:`IcpResult` (None for the
    reference and for sensors that saw too little).
    """
    poses = np.array(world_from_sensor, dtype=np.float64)
    n_sensors = poses.shape[0]
    if not 0 <= reference < n_sensors:
        raise ValueError(f"reference {reference} is not one of the {n_sensors} sensors")
    if any(len(clouds) != n_sensors for clouds in frames):
        raise ValueError(f"every frame needs one cloud per sensor ({n_sensors})")
    if normals is None:
        normals = walk_normals(frames)
    elif len(normals) != len(frames):
        raise ValueError(f"normals has {len(normals)} instants, frames {len(frames)}")
    local: list[np.ndarray] = []
    local_normals: list[np.ndarray] = []
    labels: list[np.ndarray] = []
    for s in range(n_sensors):
        points, sensor_normals, frame_numbers = [], [], []
        for t, clouds in enumerate(frames):
            cloud = np.asarray(clouds[s], dtype=np.float64).reshape(-1, 3)
            cloud_normals = normals[t][s]
            if cloud.shape[0] < _MIN_PAIRS or cloud_normals is None:
                continue
            points.append(cloud)
            sensor_normals.append(cloud_normals)
            frame_numbers.append(np.full(cloud.shape[0], t))
        local.append(np.concatenate(points) if points else np.zeros((0, 3)))
        local_normals.append(np.concatenate(sensor_normals) if sensor_normals else np.zeros((0, 3)))
        labels.append(np.concatenate(frame_numbers) if frame_numbers else np.zeros(0, np.int64))
    results: list[IcpResult | None] = [None] * n_sensors
    usable = [points.shape[0] >= _MIN_PAIRS for points in local]
    for _ in range(passes):
        for s in range(n_sensors):
            others = [j for j in range(n_sensors) if j != s and usable[j]]
            if s == reference or not usable[s] or not others:
                continue
            result = icp_point_to_plane(
                transform_points(poses[s], local[s]),
                np.concatenate([transform_points(poses[j], local[j]) for j in others]),
                target_normals=np.concatenate([local_normals[j] @ poses[j][:3, :3].T for j in others]),
                source_normals=local_normals[s] @ poses[s][:3, :3].T,
                source_frames=labels[s],
                target_frames=np.concatenate([labels[j] for j in others]),
                max_pair_mm=max_pair_mm,
                max_source_points=max_source_points,
            )
            poses[s] = result.transform @ poses[s]
            results[s] = result
    return poses, results


def walk_normals(frames: list[list[np.ndarray]]) -> list[list[np.ndarray | None]]:
    """Per instant and sensor, the normals of the cloud in the sensor's frame, turned towards the sensor (the
    origin there); None for a cloud too small to pair (fewer than the points ICP needs)."""
    normals: list[list[np.ndarray | None]] = []
    for clouds in frames:
        row: list[np.ndarray | None] = []
        for cloud in clouds:
            points = np.asarray(cloud, dtype=np.float64).reshape(-1, 3)
            row.append(estimate_normals(points, viewpoint=np.zeros(3)) if points.shape[0] >= _MIN_PAIRS else None)
        normals.append(row)
    return normals
