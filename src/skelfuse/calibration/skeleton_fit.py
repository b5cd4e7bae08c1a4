"""The fits of the skeleton calibration (:mod:`skelfuse.calibration.skeleton`): corresponding joints of each
sensor pair, a robust rigid fit per pair, the poses relative to the master over a spanning tree of the pairs
(refined jointly), their residuals; then the floor from the feet, which anchors the world frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from skelfuse.calibration.rigid import fit_rigid, fit_rigid_ransac, refine_rigid_trimmed, rotation_angle_deg
from skelfuse.calibration.skeleton_records import (
    FOOT_JOINTS,
    MIDLINE_JOINTS,
    NOMINAL_PELVIS_HEIGHT_MM,
    SIDE_PAIRS,
    SIGMA_FLOOR_MM,
    SIGMA_SPINE_RAD,
    FloorFit,
    SkeletonCalibrationOptions,
)
from skelfuse.fusion.mirror import pair_costs
from skelfuse.fusion.transform import invert_transform, make_transform, transform_points
from skelfuse.progress import Progress
from skelfuse.schema.errors import CalibrationError
from skelfuse.schema.skeleton import J

# ------------------------------------------------------------------------------------------ correspondences


@dataclass
class PairEdge:
    a: int
    b: int
    src: np.ndarray  # (N, 3) b's points, b's frame
    dst: np.ndarray  # (N, 3) a's points, a's frame
    frames: np.ndarray  # (N,) frame index
    fit_rms: float
    a_from_b: np.ndarray
    side_frames: int
    mirrored_frames: int


def _midline_pairs(pos: np.ndarray, ok: np.ndarray, a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    both = ok[:, a, MIDLINE_JOINTS] & ok[:, b, MIDLINE_JOINTS]
    frames, k = np.nonzero(both)
    joints = MIDLINE_JOINTS[k]
    return pos[frames, b, joints], pos[frames, a, joints], frames


def _side_pairs(
    pos: np.ndarray, ok: np.ndarray, a: int, b: int, a_from_b: np.ndarray, margin: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    """Side-joint correspondences of the frames where both views' left/right labels agree."""
    left, right = SIDE_PAIRS[:, 0], SIDE_PAIRS[:, 1]
    decidable = ok[:, a][:, left] & ok[:, a][:, right] & ok[:, b][:, left] & ok[:, b][:, right]  # (T, P)
    with np.errstate(invalid="ignore"):
        bl, br = transform_points(a_from_b, pos[:, b][:, left]), transform_points(a_from_b, pos[:, b][:, right])
        al, ar = pos[:, a][:, left], pos[:, a][:, right]
        keep, swap = pair_costs(al, ar, bl, br)
    keep_sum = np.where(decidable, keep, 0.0).sum(axis=1)
    swap_sum = np.where(decidable, swap, 0.0).sum(axis=1)
    any_dec = decidable.any(axis=1)
    agree = any_dec & (keep_sum < margin * swap_sum)
    mirrored = any_dec & (swap_sum < margin * keep_sum)
    side = SIDE_PAIRS.reshape(-1)
    use = agree[:, None] & ok[:, a][:, side] & ok[:, b][:, side]
    frames, k = np.nonzero(use)
    joints = side[k]
    return pos[frames, b, joints], pos[frames, a, joints], frames, int(agree.sum()), int(mirrored.sum())


def fit_pair(
    pos: np.ndarray, ok: np.ndarray, a: int, b: int, opts: SkeletonCalibrationOptions, rng: np.random.Generator
) -> PairEdge | None:
    src_m, dst_m, fr_m = _midline_pairs(pos, ok, a, b)
    if len(src_m) < opts.min_pair_points:
        return None
    try:
        fit = fit_rigid_ransac(
            src_m,
            dst_m,
            threshold_mm=opts.ransac_threshold_mm,
            iterations=opts.ransac_iterations,
            min_inliers=opts.min_pair_points // 2,
            rng=rng,
            trim_fraction=opts.trim_fraction,
        )
    except CalibrationError:
        return None
    a_from_b = fit.matrix
    side_n = mirrored_n = 0
    src, dst, frames = src_m, dst_m, fr_m
    for _ in range(2):
        src_s, dst_s, fr_s, side_n, mirrored_n = _side_pairs(pos, ok, a, b, a_from_b, opts.side_margin)
        src, dst = np.concatenate([src_m, src_s]), np.concatenate([dst_m, dst_s])
        frames = np.concatenate([fr_m, fr_s])
        try:
            fit = refine_rigid_trimmed(
                src,
                dst,
                a_from_b[:3, :3],
                a_from_b[:3, 3],
                threshold_mm=opts.final_threshold_mm,
                trim_fraction=opts.trim_fraction,
                min_inliers=opts.min_pair_points // 2,
            )
        except CalibrationError:
            return None
        a_from_b = fit.matrix
    # Correspondences kept for the joint refinement: inliers of the final pairwise fit, untrimmed.
    resid = np.linalg.norm(transform_points(a_from_b, src) - dst, axis=1)
    keep = resid < opts.final_threshold_mm
    return PairEdge(a, b, src[keep], dst[keep], frames[keep], fit.rms_mm, a_from_b, side_n, mirrored_n)


def _spanning_poses(edges: list[PairEdge], n_sensors: int, master: int, ids: tuple[str, ...]) -> np.ndarray:
    """Initial master_from_sensor (S, 4, 4) by composition along a maximum spanning tree (Prim, from master)."""
    poses = np.full((n_sensors, 4, 4), np.nan)
    poses[master] = np.eye(4)
    reached = {master}
    while len(reached) < n_sensors:
        best = None
        for e in edges:
            if (e.a in reached) != (e.b in reached) and (best is None or len(e.src) > len(best.src)):
                best = e
        if best is None:
            missing = [ids[s] for s in range(n_sensors) if s not in reached]
            raise CalibrationError(
                f"could not link sensors {', '.join(missing)} to master {ids[master]}: no chain of sensor pairs "
                "saw the person together in enough frames (MEDIUM torso joints). Record a walk that passes "
                "through each sensor's view together with another sensor's, and check that the frames are "
                "synchronized"
            )
        if best.a in reached:  # master_from_b = master_from_a @ a_from_b
            poses[best.b] = poses[best.a] @ best.a_from_b
            reached.add(best.b)
        else:
            poses[best.a] = poses[best.b] @ invert_transform(best.a_from_b)
            reached.add(best.a)
    return poses


def refine_joint(
    edges: list[PairEdge],
    poses: np.ndarray,
    master: int,
    sweeps: int,
    frame_mask: Callable[[PairEdge], np.ndarray] | None = None,
    min_points: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """Alternating least squares over all pairs; returns (poses, fitted (S,) bool)."""
    poses = poses.copy()
    n_sensors = len(poses)
    sel = [np.ones(len(e.src), bool) if frame_mask is None else frame_mask(e) for e in edges]
    counts = np.zeros(n_sensors, dtype=np.int64)
    for e, m in zip(edges, sel, strict=True):
        counts[e.a] += m.sum()
        counts[e.b] += m.sum()
    fitted = counts >= min_points
    fitted[master] = True
    for _ in range(sweeps):
        change = 0.0
        for s in range(n_sensors):
            if s == master or not fitted[s]:
                continue
            src, dst = [], []
            for e, m in zip(edges, sel, strict=True):
                if not m.any():
                    continue
                if e.b == s and fitted[e.a]:
                    src.append(e.src[m])
                    dst.append(transform_points(poses[e.a], e.dst[m]))
                elif e.a == s and fitted[e.b]:
                    src.append(e.dst[m])
                    dst.append(transform_points(poses[e.b], e.src[m]))
            if sum(len(x) for x in src) < min_points:
                fitted[s] = False
                continue
            try:
                fit = fit_rigid(np.concatenate(src), np.concatenate(dst))
            except CalibrationError:
                fitted[s] = False
                continue
            new = fit.matrix
            old = poses[s]
            change = max(
                change,
                rotation_angle_deg(new[:3, :3] @ old[:3, :3].T) / 1e-3,
                float(np.linalg.norm(new[:3, 3] - old[:3, 3])) / 1e-2,
            )
            poses[s] = new
        if change < 1.0:  # every pose moved by less than 1e-3 deg and 0.01 mm in this sweep
            break
    return poses, fitted


def half_mask(first: bool) -> Callable[[PairEdge], np.ndarray]:
    def mask(edge: PairEdge) -> np.ndarray:
        if not len(edge.frames):
            return np.zeros(0, bool)
        split = np.median(edge.frames)
        below = edge.frames < split
        if not below.any():  # every correspondence in one frame: no halves
            return np.zeros(len(edge.frames), bool) if first else np.ones(len(edge.frames), bool)
        return below if first else ~below

    return mask


def sensor_points(edges: list[PairEdge], s: int) -> np.ndarray:
    pts = [e.src for e in edges if e.b == s] + [e.dst for e in edges if e.a == s]
    return np.concatenate(pts) if pts else np.zeros((0, 3))


def pose_difference(T1: np.ndarray, T2: np.ndarray, points: np.ndarray) -> tuple[float, float]:
    """(rotation deg, translation at the subject mm): how far the sensor's mean observed point moves."""
    centre = points.mean(axis=0) if len(points) else np.zeros(3)
    return (
        rotation_angle_deg(T1[:3, :3] @ T2[:3, :3].T),
        float(np.linalg.norm(transform_points(T1, centre) - transform_points(T2, centre))),
    )


def pair_residuals(
    edges: list[PairEdge], poses: np.ndarray, n_sensors: int
) -> tuple[np.ndarray, np.ndarray, list[float]]:
    sq = np.zeros(n_sensors)
    count = np.zeros(n_sensors, dtype=np.int64)
    per_edge = []
    for e in edges:
        d2 = np.sum((transform_points(poses[e.b], e.src) - transform_points(poses[e.a], e.dst)) ** 2, axis=1)
        per_edge.append(float(np.sqrt(d2.mean())) if len(d2) else float("nan"))
        for s in (e.a, e.b):
            sq[s] += d2.sum()
            count[s] += len(d2)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(sq / count)
    return rms, count, per_edge


def calibrate_relative(
    pos: np.ndarray,
    conf: np.ndarray,
    ids: tuple[str, ...],
    master: int,
    opts: SkeletonCalibrationOptions,
    progress: Progress,
) -> tuple[np.ndarray, list[PairEdge]]:
    """Steps 1-3: master_from_sensor (S, 4, 4) and the pairwise edges with their correspondences."""
    ok = np.isfinite(pos).all(axis=-1) & (conf >= int(opts.min_confidence))
    rng = np.random.default_rng(opts.seed)
    n_sensors = len(ids)
    edges = []
    for a in range(n_sensors):
        for b in range(a + 1, n_sensors):
            edge = fit_pair(pos, ok, a, b, opts, rng)
            if edge is not None:
                edges.append(edge)
            progress.update(note=f"{ids[b]} → {ids[a]}")
    poses = _spanning_poses(edges, n_sensors, master, ids)
    poses, _ = refine_joint(edges, poses, master, opts.refine_sweeps)
    progress.update(note="joint refinement")
    return poses, edges


# ------------------------------------------------------------------------------------------------ the floor


def fit_floor(
    pos: np.ndarray, ok: np.ndarray, master_from_sensor: np.ndarray, opts: SkeletonCalibrationOptions
) -> FloorFit:
    n_sensors = pos.shape[1]
    spines, pelvises, feet = [], [], []
    for s in range(n_sensors):
        T = master_from_sensor[s]
        both = ok[:, s, J["PELVIS"]] & ok[:, s, J["NECK"]]
        pelvis = transform_points(T, pos[both, s, J["PELVIS"]])
        neck = transform_points(T, pos[both, s, J["NECK"]])
        spines.append(neck - pelvis)
        pelvises.append(pelvis)
        feet.append((transform_points(T, pos[:, s][:, FOOT_JOINTS]), ok[:, s][:, FOOT_JOINTS]))
    spine = np.concatenate(spines)
    if len(spine):
        unit = spine / np.linalg.norm(spine, axis=1, keepdims=True)
        up = unit.mean(axis=0)
        up /= np.linalg.norm(up)
    else:  # no spine seen: the master's -y (Azure Kinect y points down in the image)
        up = np.array([0.0, -1.0, 0.0])
    # Floor contacts: per frame and sensor the lowest foot joint along the spine's up. Grouped by (sensor,
    # joint): each group gets its own height (the ankle sits ~70 mm up, the toe joint ~25 mm, and each view
    # has its own constant offset of the feet, DESIGN "Real noise"), only the normal is shared.
    groups = _floor_contacts(feet, up)
    pelvis_mean = np.concatenate(pelvises).mean(axis=0) if sum(len(p) for p in pelvises) else np.zeros(3)
    n_contacts = sum(len(g) for g in groups)
    if n_contacts < 30:
        if not len(spine):
            raise CalibrationError(
                f"found only {n_contacts} floor contacts (MEDIUM ankle/foot joints) and no pelvis + neck: the "
                "world's z axis is undetermined; record a walk with the whole body in view, or give the ArUco "
                "plate's master pose"
            )
        # No feet: z from the spine alone, the floor a nominal pelvis height below the mean pelvis.
        return FloorFit(
            normal=up,
            point_mm=pelvis_mean - NOMINAL_PELVIS_HEIGHT_MM * up,
            n_points=0,
            rms_mm=float("nan"),
            spine_tilt_deg=0.0,
        )
    # Contacts of one step (~0.5 s) seen by every sensor are one foot placement, not independent samples:
    # the floor's information is scaled down to one contact per step and view, so that the spine prior keeps
    # its say across a narrow walking line (where the floor has a ~200 mm baseline only).
    n_eff = max(n_contacts / (15.0 * n_sensors), 3.0)
    prior = (np.eye(3) - np.outer(up, up)) / SIGMA_SPINE_RAD**2
    keep = [np.ones(len(g), bool) for g in groups]
    normal = up
    for _ in range(3):
        scatter = np.zeros((3, 3))
        for g, k in zip(groups, keep, strict=True):
            if k.sum() >= 2:
                d = g[k] - g[k].mean(axis=0)
                scatter += d.T @ d
        _, vecs = np.linalg.eigh(scatter * (n_eff / n_contacts) / SIGMA_FLOOR_MM**2 + prior)
        normal = vecs[:, 0] * np.sign(vecs[:, 0] @ up)
        resid = [
            (g - g[k].mean(axis=0)) @ normal if k.any() else np.zeros(len(g)) for g, k in zip(groups, keep, strict=True)
        ]
        flat = np.concatenate([r[k] for r, k in zip(resid, keep, strict=True)])
        sigma = max(1.4826 * np.median(np.abs(flat)), 5.0)
        keep = [np.abs(r) <= 3.0 * sigma for r in resid]
    flat = np.concatenate([r[k] for r, k in zip(resid, keep, strict=True)])
    # Floor height: the median height of all kept contacts, less the lowest foot joint's height above it.
    heights = np.concatenate([g[k] @ normal for g, k in zip(groups, keep, strict=True)])
    floor_height = np.median(heights) - opts.foot_joint_height_mm
    point = pelvis_mean - (pelvis_mean @ normal - floor_height) * normal
    return FloorFit(
        normal=normal,
        point_mm=point,
        n_points=len(heights),
        rms_mm=float(np.sqrt(np.mean(flat**2))),
        spine_tilt_deg=float(np.degrees(np.arccos(np.clip(normal @ up, -1, 1)))),
    )


def _floor_contacts(feet: list[tuple[np.ndarray, np.ndarray]], up: np.ndarray) -> list[np.ndarray]:
    """Per (sensor, foot joint) the points where that joint was the lowest foot joint along ``up`` (3 or more)."""
    groups = []
    for points, valid in feet:
        height = np.where(valid, points @ up, np.inf)  # (T, 4)
        lowest = np.argmin(height, axis=1)
        has = np.isfinite(height).any(axis=1)
        for j in range(len(FOOT_JOINTS)):
            sel = has & (lowest == j)
            if sel.sum() >= 3:
                groups.append(points[sel, j])
    return groups


def floor_world_from_master(floor: FloorFit) -> np.ndarray:
    z = floor.normal
    forward = np.array([0.0, 0.0, 1.0])  # master's viewing direction, master frame
    x = forward - (forward @ z) * z
    if np.linalg.norm(x) < 1e-3:  # master looks straight down: use its image x axis instead
        x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: world axes in master coordinates → p_world = R (p_master - origin)
    return make_transform(R, -R @ floor.point_mm)
