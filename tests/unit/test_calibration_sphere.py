"""Sphere calibration (paper 2.1.1) on synthetic RGB-D frames with known poses, and the paper's errata."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.calibration.render import Quad, Scene, Sphere, render, room
from skelfuse.calibration.rigid import rotation_angle_deg
from skelfuse.calibration.sphere import (
    PAPER_RADIUS_MM,
    calibrate_from_sphere,
    calibrate_from_trajectories,
    detect_sphere_center,
    fit_sphere_known_radius,
    red_histogram,
    sphere_histogram,
)
from skelfuse.fusion.camera import Intrinsics
from skelfuse.fusion.transform import invert_transform, make_transform
from skelfuse.schema.errors import CalibrationError
from skelfuse.sim.rig import look_at, paper_rig

SEED = 2131
INTRINSICS = Intrinsics.azure_kinect_nfov(binned=True)  # 320 x 288 keeps the renders fast
N_FRAMES = 24
HIDDEN = (0, 1, 2)  # frames in which capture_1 does not see the ball


def _trajectory(n: int) -> np.ndarray:
    """A person carrying the ball through the capture area: a wobbly loop, 0.6-1.6 m high."""
    theta = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.stack(
        [650 * np.cos(theta), 500 * np.sin(2 * theta) + 100 * np.cos(3 * theta), 1100 + 450 * np.sin(1.5 * theta)],
        axis=1,
    )


def _pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(rotation error deg, translation error mm) between two 4x4 poses."""
    return (
        rotation_angle_deg(estimate[:3, :3] @ truth[:3, :3].T),
        float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3])),
    )


@pytest.fixture(scope="module")
def sphere_take() -> tuple[list, dict, np.ndarray]:
    rng = np.random.default_rng(SEED)
    rig = paper_rig(3)
    background = room(floor_z_mm=-5.0)
    distractors = [
        Sphere((-900.0, 700.0, 250.0), 150.0, (40, 160, 40)),
        Sphere((900.0, -800.0, 200.0), 120.0, (180, 90, 30)),
    ]
    centres = _trajectory(N_FRAMES)
    frames: dict[str, list] = {s.sensor_id: [] for s in rig}
    for i, centre in enumerate(centres):
        with_ball = Scene(spheres=[Sphere(centre, PAPER_RADIUS_MM), *distractors], quads=background)
        without = Scene(spheres=distractors, quads=background)
        for sensor in rig:
            scene = without if (sensor.sensor_id == "capture_1" and i in HIDDEN) else with_ball
            frames[sensor.sensor_id].append(
                render(sensor.world_from_sensor, INTRINSICS, scene, rng=rng, depth_noise_mm=2.5)
            )
    return rig, frames, centres


def test_detect_sphere_center_is_within_a_millimetre(sphere_take) -> None:
    rig, frames, centres = sphere_take
    sensor = rig[0]
    color, depth = frames[sensor.sensor_id][5]
    found = detect_sphere_center(color, depth, INTRINSICS, PAPER_RADIUS_MM, red_histogram())
    assert found is not None
    center, n_inliers, residual = found
    assert np.linalg.norm(center - sensor.to_sensor(centres[5])) < 1.5
    assert n_inliers > 500
    assert 1.5 < residual < 4.0  # about the 2.5 mm depth noise


def test_histogram_from_a_sample_of_the_ball_finds_it_too(sphere_take) -> None:
    rig, frames, centres = sphere_take
    color, depth = frames["capture_0"][0]
    in_sensor = rig[0].to_sensor(centres[0])
    u, v = INTRINSICS.project(in_sensor).round().astype(int)
    half = int(0.6 * INTRINSICS.fx * PAPER_RADIUS_MM / in_sensor[2])  # a box inside the ball's disc
    roi = np.zeros(depth.shape, np.uint8)
    roi[v - half : v + half + 1, u - half : u + half + 1] = 1
    hist = sphere_histogram(color, roi)
    found = detect_sphere_center(*frames["capture_0"][10], INTRINSICS, PAPER_RADIUS_MM, hist)
    assert found is not None
    assert np.linalg.norm(found[0] - rig[0].to_sensor(centres[10])) < 3.0


def test_sphere_calibration_recovers_the_rig(sphere_take) -> None:
    rig, frames, _ = sphere_take
    result = calibrate_from_sphere(
        frames, dict.fromkeys(frames, INTRINSICS), PAPER_RADIUS_MM, "capture_0", progress=False
    )
    assert result.master == "capture_0" and result.method == "sphere"
    master_from_world = invert_transform(rig[0].world_from_sensor)
    for sensor in rig:
        entry = result.sensors[sensor.sensor_id]
        truth = master_from_world @ sensor.world_from_sensor  # the world of a sphere calibration = master frame
        angle_deg, offset_mm = _pose_error(entry.world_from_sensor, truth)
        assert angle_deg < 0.5, sensor.sensor_id
        assert offset_mm < 10.0, sensor.sensor_id
        if sensor.sensor_id != "capture_0":
            assert entry.n_points == N_FRAMES - len(HIDDEN)  # frames the ball was hidden from capture_1 are dropped
            assert entry.residual_mm is not None and entry.residual_mm < 3.0
    assert {len(p) for p in result.points_by_sensor.values()} == {N_FRAMES - len(HIDDEN)}


def test_ransac_ignores_a_red_poster_touching_the_ball() -> None:
    """A flat red poster behind the ball merges with it into one blob: RANSAC keeps the sphere."""
    rng = np.random.default_rng(SEED + 1)
    sensor = look_at("cam", (2000.0, 0.0, 1100.0), (0.0, 0.0, 1000.0))
    ball = np.array([0.0, 0.0, 1000.0])
    # Poster 600 mm behind the ball, shifted sideways so it overlaps the ball's silhouette by about a third.
    poster = Quad((-600.0, 300.0, 1050.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), 230.0, 200.0, (35, 35, 190))
    scene = Scene(spheres=[Sphere(ball, PAPER_RADIUS_MM)], quads=[*room(floor_z_mm=-5.0), poster])
    color, depth = render(sensor.world_from_sensor, INTRINSICS, scene, rng=rng)
    truth = sensor.to_sensor(ball)
    found = detect_sphere_center(color, depth, INTRINSICS, PAPER_RADIUS_MM, red_histogram(), min_inlier_ratio=0.3)
    assert found is not None
    assert np.linalg.norm(found[0] - truth) < 2.0
    # Without outlier rejection (every blob point an inlier) the poster drags the centre far off.
    from skelfuse.calibration.sphere import sphere_mask
    from skelfuse.fusion.camera import lift_mask

    points = lift_mask(depth, sphere_mask(color, red_histogram()), INTRINSICS)
    naive = fit_sphere_known_radius(points, PAPER_RADIUS_MM, rng=np.random.default_rng(0), threshold_mm=1e6)
    assert naive is not None
    assert np.linalg.norm(naive[0] - truth) > 20.0


def test_no_ball_gives_none() -> None:
    rng = np.random.default_rng(SEED + 2)
    sensor = paper_rig(1)[0]
    color, depth = render(
        sensor.world_from_sensor,
        INTRINSICS,
        Scene(spheres=[Sphere((0.0, 0.0, 800.0), 200.0, (40, 160, 40))], quads=room()),
        rng=rng,
    )
    assert detect_sphere_center(color, depth, INTRINSICS, PAPER_RADIUS_MM, red_histogram()) is None


# ----------------------------------------------------------------------------------------------------------
# The paper's errata (seeds/README.md): T = mean_M - R mean_p, and the reflection fix
# ----------------------------------------------------------------------------------------------------------


def _rotation(axis: np.ndarray, angle_deg: float) -> np.ndarray:
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = np.radians(angle_deg)
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def test_translation_keeps_the_rotation_of_the_mean() -> None:
    """With a 120° rotation, the paper's T = mean_M - mean_p (R dropped) is off by metres; ours is exact."""
    rng = np.random.default_rng(SEED + 3)
    master_from_sensor = make_transform(_rotation([0.3, 1.0, 0.2], 120.0), np.array([2500.0, -400.0, 1800.0]))
    in_sensor = rng.uniform(-800, 800, size=(50, 3)) + np.array([0.0, 0.0, 2500.0])
    in_master = in_sensor @ master_from_sensor[:3, :3].T + master_from_sensor[:3, 3]
    noisy = {"m": in_master + rng.normal(0, 1.0, in_master.shape), "p": in_sensor + rng.normal(0, 1.0, in_sensor.shape)}
    result = calibrate_from_trajectories(noisy, "m")
    angle_deg, offset_mm = _pose_error(result.sensors["p"].world_from_sensor, master_from_sensor)
    assert angle_deg < 0.2 and offset_mm < 5.0
    paper_t = in_master.mean(axis=0) - in_sensor.mean(axis=0)  # the erratum
    assert np.linalg.norm(paper_t - master_from_sensor[:3, 3]) > 1000.0


def test_planar_trajectory_gives_a_rotation_not_a_reflection() -> None:
    """Ball carried at one height: the centres are coplanar, so the cross-covariance has rank 2 and a
    rotation and a reflection fit equally well; the fit must return the rotation."""
    rng = np.random.default_rng(SEED + 4)
    master_from_sensor = make_transform(_rotation([1.0, -0.5, 0.3], 70.0), np.array([-1200.0, 300.0, 2400.0]))
    theta = rng.uniform(0, 2 * np.pi, 40)
    planar = np.stack([900 * np.cos(theta), 900 * np.sin(theta), np.zeros_like(theta)], axis=1)  # z = 0 plane
    in_master = planar @ master_from_sensor[:3, :3].T + master_from_sensor[:3, 3]
    result = calibrate_from_trajectories({"m": in_master, "p": planar}, "m")
    pose = result.sensors["p"].world_from_sensor
    assert np.linalg.det(pose[:3, :3]) == pytest.approx(1.0)
    angle_deg, offset_mm = _pose_error(pose, master_from_sensor)
    assert angle_deg < 0.01 and offset_mm < 0.01


def test_mirrored_sensor_data_is_flagged_by_the_residual_not_fitted_by_a_reflection() -> None:
    """A sensor whose points come mirrored (y flipped): plain SVD returns det -1 and fits exactly; with the
    fix the pose stays a proper rotation and the residual exposes the problem."""
    rng = np.random.default_rng(SEED + 5)
    in_master = rng.uniform(-800, 800, size=(40, 3)) + np.array([0.0, 0.0, 2500.0])
    mirrored = in_master * [1.0, -1.0, 1.0]
    src, dst = mirrored - mirrored.mean(0), in_master - in_master.mean(0)
    U, _, Vt = np.linalg.svd(dst.T @ src)
    assert np.linalg.det(U @ Vt) == pytest.approx(-1.0)  # the paper's R = U V' would be a reflection
    result = calibrate_from_trajectories({"m": in_master, "p": mirrored}, "m", threshold_mm=1e4)
    entry = result.sensors["p"]
    assert np.linalg.det(entry.world_from_sensor[:3, :3]) == pytest.approx(1.0)
    assert entry.residual_mm is not None and entry.residual_mm > 100.0


def test_too_few_common_frames_says_how_many_each_sensor_saw() -> None:
    seen = np.zeros((20, 3))
    unseen = np.full((20, 3), np.nan)
    unseen[:4] = 0.0
    with pytest.raises(CalibrationError, match=r"only 4 of 20 frames.*m: 20, p: 4"):
        calibrate_from_trajectories({"m": seen, "p": unseen}, "m")


def test_sphere_then_marker_puts_the_rig_in_the_plate_world(sphere_take) -> None:
    """The paper's two steps end to end: every sensor within 0.5° and 10 mm of its true world pose."""
    from skelfuse.calibration.marker import calibrate_world_from_marker
    from skelfuse.calibration.render import aruco_plate

    rig, frames, _ = sphere_take
    sphere = calibrate_from_sphere(
        frames, dict.fromkeys(frames, INTRINSICS), PAPER_RADIUS_MM, "capture_0", progress=False
    )
    plate, _ = aruco_plate(marker_mm=200.0, spacing_mm=400.0)  # defines the true world: marker 1 at the origin
    full = Intrinsics.azure_kinect_nfov()
    color, depth = render(
        rig[0].world_from_sensor,
        full,
        Scene(quads=[*room(floor_z_mm=-5.0), plate]),
        rng=np.random.default_rng(SEED + 9),
    )
    result, _ = calibrate_world_from_marker(color, depth, full, "capture_0", calibration=sphere)
    for sensor in rig:
        angle_deg, offset_mm = _pose_error(result.sensors[sensor.sensor_id].world_from_sensor, sensor.world_from_sensor)
        assert angle_deg < 0.5 and offset_mm < 10.0, sensor.sensor_id
