"""Depth-level fusion (the second paper) against simulator truth: the body surface the simulator renders, the
merged clouds on it, the frontalization angle against the true facing, the virtual image against a direct
render from the virtual camera, and the inverse warp back onto the true skeleton."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.fusion.camera import Intrinsics, lift_mask
from skelfuse.fusion.depth.cloud import clouds_to_world, merge_clouds, person_clouds, voxelize
from skelfuse.fusion.depth.frontal import DEFAULT_WORKING_DISTANCE_MM, choose_facing_deg, principal_axis_deg
from skelfuse.fusion.depth.icp import (
    estimate_normals,
    icp_point_to_plane,
    refine_clouds,
    refine_poses_from_walk,
    walk_normals,
)
from skelfuse.fusion.depth.pipeline import DepthFusionParams, fuse_person_depth
from skelfuse.fusion.depth.render import fill_holes, render_points, to_k4a_depth
from skelfuse.fusion.transform import make_transform, transform_points
from skelfuse.schema.skeleton import EVAL_JOINTS, J
from skelfuse.sim.depth import BODY_INDEX_BACKGROUND, EXACT, DepthNoise, render_rig, render_truth, surface_distance
from skelfuse.sim.gestures import GESTURES, make_gesture
from skelfuse.sim.motion import axis_rotation, facing_deg
from skelfuse.sim.rig import look_at, paper_rig

K = Intrinsics.azure_kinect_nfov()
VOXEL = 15.0
RIG = paper_rig()
POSES = np.stack([s.world_from_sensor for s in RIG])


def _gap(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def _scene(gesture: str, facing: float, frame: int, *, seed: int = 0):
    """One person, the paper rig's 4 sensors: (true skeleton (32, 3), per-sensor clouds in the sensor frame)."""
    truth = make_gesture(gesture, duration_s=3.0, facing_deg=facing, seed=seed).positions[frame]
    frames = render_rig(RIG, truth[None], seed=seed + frame)
    clouds = []
    for depth_frame in frames:
        found = person_clouds(depth_frame.depth, depth_frame.body_index, K, voxel_mm=VOXEL)
        clouds.append(found[0].points if found else np.zeros((0, 3)))
    return truth, clouds


@pytest.fixture(scope="module")
def squat_scene():
    return _scene("squat", 200.0, 40)


# ------------------------------------------------------------------------------------------ pure pieces


def test_voxelize_averages_each_cell_and_takes_the_majority_label() -> None:
    points = np.array([[1.0, 1.0, 1.0], [9.0, 3.0, 5.0], [11.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    centroids, ir, labels = voxelize(
        points, 10.0, values=np.array([10.0, 20.0, 30.0, 40.0]), labels=np.array([1, 1, 0, 2])
    )
    # cells: (0,0,0) x2, (1,0,0), (-1,0,0); lexicographic order of the integer cell coordinates
    np.testing.assert_allclose(centroids, [[-1.0, 0, 0], [5.0, 2.0, 3.0], [11.0, 0, 0]])
    np.testing.assert_allclose(ir, [40.0, 15.0, 30.0])
    np.testing.assert_array_equal(labels, [2, 1, 0])


def test_voxelize_matches_a_dictionary_reference() -> None:
    rng = np.random.default_rng(4)
    points = rng.uniform(-500, 500, (3000, 3))
    centroids, _, _ = voxelize(points, 37.0)
    cells: dict[tuple[int, ...], list[np.ndarray]] = {}
    for p in points:
        cells.setdefault(tuple(np.floor(p / 37.0).astype(int)), []).append(p)
    reference = np.array([np.mean(cells[key], axis=0) for key in sorted(cells)])
    np.testing.assert_allclose(centroids, reference, atol=1e-9)


def test_zbuffer_keeps_the_nearest_point_and_hole_filling_stays_within_epsilon() -> None:
    camera = np.eye(4)  # the camera frame is the world here
    small = Intrinsics(100.0, 100.0, 10.0, 10.0, 21, 21)
    near, far = np.array([0.0, 0.0, 1000.0]), np.array([0.0, 0.0, 1500.0])
    image = render_points(np.stack([far, near]), camera, small, ir=np.array([7.0, 9.0]), fill_radius_px=0)
    assert image.depth_mm[10, 10] == 1000.0 and image.ir[10, 10] == 9.0
    assert np.isinf(image.depth_mm).sum() == 21 * 21 - 1
    filled, _ = fill_holes(image.depth_mm, None, 2.0)
    assert filled[10, 12] == 1000.0 and filled[11, 11] == 1000.0  # 2 and 1.41 px away
    assert np.isinf(filled[10, 13]) and np.isinf(filled[12, 12])  # 3 and 2.83 px away: Eq. 10 leaves +inf
    np.testing.assert_array_equal(to_k4a_depth(np.array([np.inf, 1000.4, np.nan, 70000.0])), [0, 1000, 0, 0])


def test_principal_axis_of_an_oval_and_the_front_back_choice() -> None:
    rng = np.random.default_rng(0)
    angle = np.linspace(0, 2 * np.pi, 4000, endpoint=False)
    oval = np.stack([200 * np.cos(angle), 120 * np.sin(angle), rng.uniform(0, 1000, 4000)], axis=1)
    turned = oval @ axis_rotation("z", np.radians(-30.0)).T + [500.0, -200.0, 0.0]
    axis, centroid = principal_axis_deg(turned, band=None)
    assert _gap(axis, 150.0) < 0.5  # -30° is the same axis as 150°, reported in [0, 180)
    np.testing.assert_allclose(centroid, [500.0, -200.0], atol=10.0)
    # arccos (Eq. 6 as printed) would give 30° for both +30° and -30° axes; the full angle tells them apart
    mirrored, _ = principal_axis_deg(oval @ axis_rotation("z", np.radians(30.0)).T, band=None)
    assert _gap(mirrored, 30.0) < 0.5
    assert choose_facing_deg(150.0, skeleton_facing_deg=-110.0) == (-120.0, "skeleton")
    assert choose_facing_deg(150.0, toward_xy=np.array([1000.0, 2000.0]), centroid_xy=np.zeros(2)) == (
        60.0,
        "reference",
    )


# ------------------------------------------------------------------------------------------ the simulator


def test_rendered_depth_lies_on_the_capsule_surface_and_people_occlude_each_other() -> None:
    front = make_gesture("hands_up_down", duration_s=1.0, facing_deg=0.0, position_mm=(600.0, 0.0)).positions[10]
    back = make_gesture("random", duration_s=1.0, facing_deg=0.0, position_mm=(-500.0, 50.0)).positions[10]
    people = np.stack([front, back])
    sensor = look_at("s", np.array([2500.0, 0.0, 1100.0]), np.array([0.0, 0.0, 900.0]))
    (frame,) = render_rig([sensor], people, noise=EXACT)
    assert frame.depth.shape == (576, 640) and frame.depth.dtype == np.uint16 and frame.body_index.dtype == np.uint8
    for who in (0, 1):
        points = transform_points(frame.world_from_sensor, lift_mask(frame.depth, frame.body_index == who, K))
        assert len(points) > 1000
        # on this person's surface (uint16 rounding: < 0.5 mm along the ray), not the other's
        assert np.abs(surface_distance(points, people[who : who + 1])).max() < 0.6
    # Occlusion: where both bodies project, the body-index map holds the nearer one.
    alone = [render_truth(sensor.world_from_sensor, K, people[who : who + 1])[0] for who in (0, 1)]
    both = np.isfinite(alone[0]) & np.isfinite(alone[1])
    assert both.sum() > 2000  # the person behind is partly hidden
    nearer = np.where(alone[0] <= alone[1], 0, 1)
    np.testing.assert_array_equal(frame.body_index[both], nearer[both])
    assert (frame.body_index[~(np.isfinite(alone[0]) | np.isfinite(alone[1]))] == BODY_INDEX_BACKGROUND).all()


def test_noise_dropout_and_range_invalidate_pixels() -> None:
    truth = make_gesture("jump", duration_s=1.0).positions[5][None]
    far = look_at("far", np.array([4500.0, 0.0, 1000.0]), np.array([0.0, 0.0, 900.0]))  # beyond 3.86 m
    near = look_at("near", np.array([2200.0, 0.0, 1000.0]), np.array([0.0, 0.0, 900.0]))
    far_frame, near_frame = render_rig([far, near], truth, noise=DepthNoise(sigma_mm=3.0, dropout=0.05), seed=2)
    assert (far_frame.depth == 0).all() and (far_frame.body_index == BODY_INDEX_BACKGROUND).all()
    exact = render_truth(near.world_from_sensor, K, truth)[0]
    body = np.isfinite(exact)
    valid = near_frame.depth > 0
    assert 0.03 < 1 - valid[body].mean() < 0.15  # 5% dropout plus the grazing edge
    residual = near_frame.depth[valid].astype(float) - exact[valid]
    assert 2.5 < residual.std() < 3.5


# ------------------------------------------------------------------------------------------ geometry vs truth


def test_merged_points_lie_on_the_true_surface_within_the_noise(squat_scene) -> None:
    truth, clouds = squat_scene
    merged = merge_clouds(clouds_to_world(clouds, POSES), voxel_mm=VOXEL)
    distance = np.abs(surface_distance(merged.points, truth[None]))
    assert len(merged) > 3000
    assert np.median(distance) < 2.0  # 3 mm noise, averaged in 15 mm voxels
    assert np.percentile(distance, 99) < 10.0
    assert set(np.unique(merged.sensor_index)) == {0, 1, 2, 3}


def test_frontalization_angle_follows_the_true_facing_and_is_never_reversed() -> None:
    errors = []
    for gesture, facing, frame in zip(
        GESTURES, (20.0, 160.0, -100.0, 70.0, -30.0, 250.0), (10, 45, 80, 30, 60, 20), strict=True
    ):
        truth, clouds = _scene(gesture, facing, frame, seed=1)
        true_facing = float(facing_deg(truth))
        view = fuse_person_depth(clouds, POSES, K, skeleton_facing_deg=true_facing)
        assert view.frontal.decided_by == "skeleton"
        errors.append(_gap(view.frontal.facing_deg, true_facing))
    assert max(errors) < 10.0, dict(zip(GESTURES, errors, strict=True))
    assert np.median(errors) < 5.0, dict(zip(GESTURES, errors, strict=True))


def test_without_the_skeleton_a_person_facing_away_is_turned_round() -> None:
    # The reference (capture_0, at 45°) sees this person's back: PCA alone picks the end of the axis that
    # faces the reference, 180° off. The skeleton's facing puts it right.
    truth, clouds = _scene("hands_up_down", 225.0, 20)
    true_facing = float(facing_deg(truth))
    alone = fuse_person_depth(clouds, POSES, K, skeleton_facing_deg=None)
    assert alone.frontal.decided_by == "reference" and _gap(alone.frontal.facing_deg, true_facing) > 170.0
    knowing = fuse_person_depth(clouds, POSES, K, skeleton_facing_deg=true_facing)
    assert _gap(knowing.frontal.facing_deg, true_facing) < 5.0


def test_virtual_depth_image_equals_a_direct_render_up_to_the_voxel_size(squat_scene) -> None:
    truth, clouds = squat_scene
    view = fuse_person_depth(clouds, POSES, K, skeleton_facing_deg=float(facing_deg(truth)))
    direct = render_truth(view.frontal.world_from_camera, K, truth[None])[0]
    ours = view.image.depth_mm
    # Compare where the surface the virtual camera sees was seen by at least one real sensor: elsewhere no
    # data-level method can know it (the image shows what lies behind instead).
    rows, cols = np.nonzero(np.isfinite(direct))
    surface = view.frontal.to_world(K.lift(cols, rows, direct[rows, cols]))
    seen = np.zeros(rows.shape[0], dtype=bool)
    for sensor in RIG:
        local = sensor.to_sensor(surface)
        uv = np.rint(K.project(local)).astype(int)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < K.width) & (uv[:, 1] >= 0) & (uv[:, 1] < K.height)
        exact = render_truth(sensor.world_from_sensor, K, truth[None])[0]
        seen[inside] |= np.abs(exact[uv[inside, 1], uv[inside, 0]] - local[inside, 2]) < 10.0
    assert seen.mean() > 0.9  # the four sensors see nearly all of what the frontal camera sees
    seen_image = np.zeros(direct.shape, dtype=bool)
    seen_image[rows[seen], cols[seen]] = True
    both = seen_image & np.isfinite(ours)
    difference = np.abs(ours[both] - direct[both])
    assert np.median(difference) < VOXEL / 3
    assert np.percentile(difference, 95) < VOXEL
    # The silhouettes agree: most of the body is covered, and what the image adds is its edge.
    assert both.sum() / seen_image.sum() > 0.9
    assert (np.isfinite(direct) & np.isfinite(ours)).sum() / np.isfinite(ours).sum() > 0.85
    # Without the visibility pass the back of the body shows through the front's gaps (the paper's Eq. 9 as is).
    plain = fuse_person_depth(
        clouds, POSES, K, skeleton_facing_deg=float(facing_deg(truth)), params=DepthFusionParams(splat=False)
    )
    plain_both = seen_image & np.isfinite(plain.image.depth_mm)
    assert np.percentile(np.abs(plain.image.depth_mm[plain_both] - direct[plain_both]), 95) > 5 * VOXEL


def test_the_inverse_warp_maps_a_skeleton_in_the_virtual_image_back_onto_the_truth(squat_scene) -> None:
    truth, clouds = squat_scene
    view = fuse_person_depth(clouds, POSES, K, skeleton_facing_deg=float(facing_deg(truth)))
    # The virtual camera, built by hand from what the view decided (facing, centroid): level with the cloud's
    # middle, the working distance ahead of the person, looking back at them; image x is the person's left.
    frontal = view.frontal
    facing = np.radians(frontal.facing_deg)
    ahead = np.array([np.cos(facing), np.sin(facing), 0.0])
    camera_at = frontal.centroid_mm + DEFAULT_WORKING_DISTANCE_MM * ahead
    camera_axes = np.stack([[-np.sin(facing), np.cos(facing), 0.0], [0.0, 0.0, -1.0], -ahead])  # rows: x, y, z
    # What a perfect tracker would report on the virtual image: the true skeleton in the virtual camera frame.
    found = frontal.to_camera(truth)
    np.testing.assert_allclose(found, (truth - camera_at) @ camera_axes.T, atol=1e-6)
    found[J["HANDTIP_LEFT"]] = np.nan  # a joint the tracker did not report
    back = frontal.to_world(found)
    keep = np.arange(32) != J["HANDTIP_LEFT"]
    np.testing.assert_allclose(back[keep], camera_at + found[keep] @ camera_axes, atol=1e-6)
    np.testing.assert_allclose(back[keep], truth[keep], atol=1e-6)
    assert np.isnan(back[J["HANDTIP_LEFT"]]).all()
    # ... and that skeleton faces the virtual camera: the person's left on the image's right (+x), the
    # pelvis at the working distance, every evaluated joint inside the rendered body, behind its surface.
    assert found[J["SHOULDER_LEFT"], 0] > found[J["SHOULDER_RIGHT"], 0] + 200.0
    assert found[J["PELVIS"], 2] == pytest.approx(DEFAULT_WORKING_DISTANCE_MM, abs=300.0)  # squatting: hips back
    uv = np.rint(K.project(found[EVAL_JOINTS])).astype(int)
    # the nearest surface within 2 px of each joint's pixel (a joint may fall on a hole wider than Eq. 10's ε)
    window = np.stack([view.image.depth_mm[uv[:, 1] + dv, uv[:, 0] + du] for du in range(-2, 3) for dv in range(-2, 3)])
    surface = window.min(axis=0)
    assert np.isfinite(surface).all()
    behind = found[EVAL_JOINTS, 2] - surface
    assert (behind > -VOXEL).all() and (behind < 250.0).all()


# ------------------------------------------------------------------------------------------ ICP


def test_icp_recovers_a_known_offset_of_a_cloud_against_itself(squat_scene) -> None:
    _, clouds = squat_scene
    target = clouds_to_world(clouds, POSES)[0]
    normals = estimate_normals(target, viewpoint=POSES[0, :3, 3])
    error = make_transform(axis_rotation("z", np.radians(2.0)), np.array([20.0, -15.0, 10.0]))
    result = icp_point_to_plane(transform_points(error, target), target, target_normals=normals)
    assert result.converged and result.rmse_after_mm < 0.1
    np.testing.assert_allclose(result.transform @ error, np.eye(4), atol=1e-3)


def test_icp_pulls_a_miscalibrated_sensor_back_onto_the_others(squat_scene) -> None:
    truth, clouds = squat_scene
    wrong = POSES.copy()
    wrong[1] = make_transform(axis_rotation("z", np.radians(2.5)), np.array([30.0, -25.0, 15.0])) @ POSES[1]
    world = clouds_to_world(clouds, wrong)
    corrections, results = refine_clouds(world, wrong[:, :3, 3], reference=0)
    assert results[0] is None and all(r is not None and r.n_pairs > 300 for r in results[1:])
    before = np.abs(surface_distance(world[1], truth[None]))
    after = np.abs(surface_distance(transform_points(corrections[1], world[1]), truth[None]))
    assert np.median(before) > 10.0
    assert np.median(after) < 0.5 * np.median(before)


def test_a_walk_through_refines_a_miscalibrated_pose() -> None:
    walk = make_gesture("walking", duration_s=6.0, facing_deg=30.0)
    frames = []
    for t in range(0, walk.n_frames, 30):  # 6 frames across the capture area
        clouds = []
        for depth_frame in render_rig(RIG, walk.positions[t][None], seed=t):
            found = person_clouds(depth_frame.depth, depth_frame.body_index, K, voxel_mm=VOXEL)
            clouds.append(found[0].points if found else np.zeros((0, 3)))
        frames.append(clouds)
    wrong = POSES.copy()
    turn = axis_rotation("z", np.radians(2.0)) @ axis_rotation("x", np.radians(1.0))
    wrong[2] = make_transform(turn, np.array([30.0, -20.0, 15.0])) @ POSES[2]
    fixed, results = refine_poses_from_walk(frames, wrong, reference=0, passes=2, max_source_points=2000)

    def error(pose: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
        delta = pose @ np.linalg.inv(truth)
        angle = np.degrees(np.arccos(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1, 1)))
        centre = np.array([0.0, 0.0, 900.0])  # the middle of the capture area
        return float(angle), float(np.linalg.norm(transform_points(delta, centre) - centre))

    assert error(wrong[2], POSES[2])[1] > 45.0  # 2.2°, 49 mm at the centre of the capture area
    np.testing.assert_array_equal(fixed[0], POSES[0])  # the reference stays put
    assert results[0] is None and all(r is not None and r.n_pairs > 1000 for r in results[1:])
    angle, shift = error(fixed[2], POSES[2])
    assert angle < 0.5 and shift < 20.0  # measured: 0.32°, 12 mm
    for s in (1, 3):  # the well-calibrated sensors stay close to the truth
        angle, shift = error(fixed[s], POSES[s])
        assert angle < 0.5 and shift < 20.0  # measured: up to 0.24°, 11 mm (a bias of single-frame voxels)
    # Normals handed in (computed once for several refinements of the same clouds) give the same poses.
    again, _ = refine_poses_from_walk(
        frames, wrong, reference=0, passes=2, max_source_points=2000, normals=walk_normals(frames)
    )
    np.testing.assert_array_equal(again, fixed)
    with pytest.raises(ValueError, match="instants"):
        refine_poses_from_walk(frames, wrong, reference=0, normals=walk_normals(frames[1:]))
