"""The simulator's true orientations and the views' simulated orientations (sim/orientation.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skelfuse.fusion.orientation import aim_directions, quat_angle_deg, quat_rotate, views_to_world
from skelfuse.schema.skeleton import (
    ANKLE_FOOT_ANGLE_DEG,
    BODY_REGIONS,
    HEAD_NOSE_DIRECTION,
    ORIENTATION_AIMED,
    ORIENTATION_DERIVED,
    J,
)
from skelfuse.sim.gestures import forward_kinematics, make_gesture, rest_offsets
from skelfuse.sim.joint_frames import TPOSE_AXES
from skelfuse.sim.motion import axis_rotation
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.orientation import ARM_TWIST_DEG, OrientationNoise, observe_orientations, truth_orientations
from skelfuse.sim.rig import paper_rig

AIM_AXES = np.tile([1.0, 0.0, 0.0], (32, 1))
"""(32, 3) each joint's aim bone in its own frame: X, except the ankles (the foot bone at the measured angle about
Z, docs/orientations.md), by scipy, and the head (the nose along its measured direction)."""
for _name, _deg in ANKLE_FOOT_ANGLE_DEG.items():
    AIM_AXES[J[_name]] = Rotation.from_euler("z", _deg, degrees=True).apply([1.0, 0.0, 0.0])
AIM_AXES[J["HEAD"]] = np.array(HEAD_NOSE_DIRECTION) / np.linalg.norm(HEAD_NOSE_DIRECTION)


@pytest.fixture(scope="module")
def take():
    motion = make_gesture("walking", duration_s=3.0, fps=30.0, facing_deg=180.0, seed=5)
    obs = simulate(motion, list(paper_rig(4)), load_profile(), seed=6)
    truth = truth_orientations(obs.truth, 30.0, seed=6)
    return obs, truth


def test_truth_swing_follows_the_true_bones_exactly(take):
    obs, truth = take
    assert np.isfinite(truth).all()
    assert np.allclose(np.linalg.norm(truth, axis=-1), 1.0, atol=1e-12)
    aim_axes = quat_rotate(truth, AIM_AXES)  # X; the ankles' foot bone (rigid to the foot, as the tracker's)
    aims = aim_directions(obs.truth)
    assert np.abs(aim_axes[:, ORIENTATION_AIMED] - aims[:, ORIENTATION_AIMED]).max() < 1e-9
    for joint, (source, offset) in ORIENTATION_DERIVED.items():
        expected = quat_angle_deg(truth[:, joint], truth[:, source])
        assert np.allclose(expected, quat_angle_deg(np.array([1.0, 0, 0, 0]), np.array(offset)), atol=1e-5)


def test_truth_arms_roll_about_their_bones(take):
    obs, truth = take
    segments = truth_orientations(obs.truth, 30.0, seed=6, arm_twist_deg=0.0)
    roll = quat_angle_deg(truth, segments)
    arms = BODY_REGIONS["arm"]
    assert 5.0 < np.median(roll[:, arms]) <= ARM_TWIST_DEG + 1e-9
    others = np.concatenate([BODY_REGIONS[r] for r in ("torso", "head", "knee", "foot")])
    assert np.allclose(roll[:, others], 0.0, atol=1e-5)  # arccos near 1: ~1e-6 deg
    x = np.array([1.0, 0.0, 0.0])
    assert np.abs(quat_rotate(truth, x) - quat_rotate(segments, x)).max() < 1e-9  # the roll is about the bone


def _t_pose(facing_deg: float) -> np.ndarray:
    """(32, 3) the gestures' skeleton with its arms straight out sideways, facing ``facing_deg``."""
    local = np.broadcast_to(np.eye(3), (1, 32, 3, 3)).copy()
    for side, sign in (("LEFT", 1.0), ("RIGHT", -1.0)):
        local[0, J[f"SHOULDER_{side}"]] = axis_rotation("x", sign * np.pi / 2)  # abduction 90 deg
    turn = axis_rotation("z", np.radians(facing_deg))[None]
    return forward_kinematics(rest_offsets(), local, turn, np.zeros((1, 3)))[0]


def test_truth_of_a_t_pose_is_the_documented_convention():
    """Hand-made case: at a T-pose each joint's frame is docs/orientations.md's table (e.g. the left arm X
    out, Y forward, Z down), turned to where the body faces, up to the smallest rotation that lays X on a
    bone not quite along the table's axis (clavicles, head, thumbs); on the bones along it, the product's
    frames from the body alone (fusion/orientation.py, another construction) agree with it. The ankles are
    rigid to the foot: Z the table's (the body's left), the foot bone at the measured angle about it."""
    from skelfuse.fusion.orientation import apply_derived, body_hint_frames, quat_from_matrix

    facing = 70.0
    pose = _t_pose(facing)
    truth = truth_orientations(pose[None], 30.0, seed=0, arm_twist_deg=0.0)[0]
    turn = axis_rotation("z", np.radians(facing))
    ankles = np.array([J["ANKLE_LEFT"], J["ANKLE_RIGHT"]])
    head = J["HEAD"]
    tabled = ORIENTATION_AIMED.copy()
    tabled[[*ankles, head]] = False
    table = quat_from_matrix(turn @ TPOSE_AXES[tabled])
    table_x = quat_rotate(table, np.array([1.0, 0.0, 0.0]))
    off_bone = np.degrees(np.arccos(np.clip(np.sum(table_x * aim_directions(pose)[tabled], -1), -1, 1)))
    error = quat_angle_deg(truth[tabled], table)
    assert (error <= off_bone + 1e-4).all()  # arccos near 1: ~1e-6 deg
    assert np.sum(off_bone < 1e-4) >= 12 and error[off_bone < 1e-4].max() < 1e-4  # arms, legs, spine: exact
    assert off_bone.max() < 45.0  # the thumbs, the most oblique bone (40.5 deg)
    left_arm = truth[J["SHOULDER_LEFT"]]
    expected = turn @ np.stack([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]], axis=-1)
    assert quat_angle_deg(left_arm, quat_from_matrix(expected)) < 1e-4
    foot = pose[[J["FOOT_LEFT"], J["FOOT_RIGHT"]]] - pose[ankles]
    foot /= np.linalg.norm(foot, axis=-1, keepdims=True)
    assert np.abs(quat_rotate(truth[ankles], AIM_AXES[ankles]) - foot).max() < 1e-9
    table_z = (turn @ TPOSE_AXES[ankles])[..., 2]
    assert np.abs(quat_rotate(truth[ankles], np.array([0.0, 0.0, 1.0])) - table_z).max() < 1e-9
    # The head is rigid to the face: the nose where the tracker's head frame holds it, and the simulated face
    # built that way (to the 0.01 mm of its rest offsets), so its frame is the table's.
    nose = pose[J["NOSE"]] - pose[head]
    assert np.abs(quat_rotate(truth[head], AIM_AXES[head]) - nose / np.linalg.norm(nose)).max() < 1e-9
    assert quat_angle_deg(truth[head], quat_from_matrix(turn @ TPOSE_AXES[head])) < 0.05
    product = apply_derived(body_hint_frames(pose))
    on_bone = np.flatnonzero(tabled)[off_bone < 1e-4]
    assert quat_angle_deg(truth[on_bone], product[on_bone]).max() < 1e-4
    for rigid in (ankles, [head]):  # the same foot or nose, the same rule
        assert quat_angle_deg(truth[rigid], product[rigid]).max() < 1e-4


def test_views_report_truth_through_their_pose_with_the_modelled_noise(take):
    obs, truth = take
    views = observe_orientations(obs, truth, seed=7)
    assert views.shape == (obs.n_frames, obs.n_sensors, 32, 4) and views.dtype == np.float32
    world = views_to_world(views, obs.world_from_sensor)  # the true poses: only the tracker error remains
    error = quat_angle_deg(world, truth[:, None])
    tracked = obs.tracked & ~obs.mirrored
    assert np.isnan(error[~obs.tracked]).all()
    torso = error[:, :, BODY_REGIONS["torso"]][tracked]
    arm = error[:, :, BODY_REGIONS["arm"]][tracked]
    assert 1.0 < np.median(torso) < 10.0 < np.median(arm) * 2.0 < 60.0
    assert np.median(torso) < np.median(arm)
    # Mirrored frames face the other way: the torso about 180 deg off.
    if obs.mirrored.any():
        assert np.median(error[:, :, BODY_REGIONS["torso"]][obs.mirrored & obs.tracked]) > 150.0
    # Deterministic in the seed; no noise gives the truth back.
    np.testing.assert_array_equal(views, observe_orientations(obs, truth, seed=7))
    quiet = OrientationNoise(
        slow_sigma_deg=dict.fromkeys(BODY_REGIONS, 0.0), white_sigma_deg=dict.fromkeys(BODY_REGIONS, 0.0)
    )
    exact = views_to_world(observe_orientations(obs, truth, seed=7, noise=quiet), obs.world_from_sensor)
    clean = obs.tracked & ~obs.mirrored
    ankles = np.array([J["ANKLE_LEFT"], J["ANKLE_RIGHT"]])
    held = np.array([*ankles, J["HEAD"]])
    copies = [J[name] for name in ("FOOT_LEFT", "FOOT_RIGHT", "NOSE", "EYE_LEFT", "EAR_LEFT", "EYE_RIGHT", "EAR_RIGHT")]
    others = np.setdiff1d(np.arange(32), [*held, *copies])  # feet: copies of the ankles; the face: of the head
    assert np.nanmax(quat_angle_deg(exact, truth[:, None])[clean][:, others]) < 0.01  # float32 rounding
    # The ankles and the head hold the view's own reported foot or nose bone where the convention puts it, as the
    # real tracker's do: their error is that bone's direction error (the positions' noise), nothing else.
    local = quat_rotate(exact[..., held, :], AIM_AXES[held])  # where the frame puts the foot or the nose, world
    feet = [J["FOOT_LEFT"], J["FOOT_RIGHT"], J["NOSE"]]
    bones = obs.positions[..., feet, :].astype(np.float64) - obs.positions[..., held, :]  # each sensor's frame
    foot = np.einsum("sij,tskj->tski", obs.world_from_sensor[:, :3, :3], bones)
    foot /= np.linalg.norm(foot, axis=-1, keepdims=True)
    assert np.abs(local - foot)[clean].max() < 1e-5
    assert np.median(quat_angle_deg(exact, truth[:, None])[clean][:, ankles]) > 5.0  # the feet's position error
    # Derived joints copy their source's reported frame with the schema's offset, as the SDK's do.
    for joint, (source, offset) in ORIENTATION_DERIVED.items():
        turn = quat_angle_deg(views[..., joint, :], views[..., source, :])[obs.tracked]
        assert np.allclose(turn, quat_angle_deg(np.array([1.0, 0, 0, 0]), np.array(offset)), atol=0.05)


CMU = Path(__file__).resolve().parents[3] / "shared" / "data" / "cmu-mocap"


@pytest.mark.skipif(not (CMU / "131_03.bvh").is_file(), reason=f"CMU BVH files not found at {CMU}")
def test_bvh_truth_follows_the_recorded_segment_rotations():
    """BVH truth: swing on the k4abt bones to 1e-9, the torso's frame faces where the body faces, and the
    arms' twist is the recorded one (it moves, unlike a frame built from the body alone)."""
    from skelfuse.fusion.depth.frontal import body_facing
    from skelfuse.fusion.orientation import apply_derived, body_hint_frames
    from skelfuse.schema.skeleton import J
    from skelfuse.sim.bvh import load_bvh
    from skelfuse.sim.orientation import load_bvh_with_orientations

    motion, truth = load_bvh_with_orientations(CMU / "131_03.bvh", facing_deg_=30.0)
    np.testing.assert_array_equal(motion.positions, load_bvh(CMU / "131_03.bvh", facing_deg=30.0).positions)
    assert truth.shape == (motion.n_frames, 32, 4) and np.isfinite(truth).all()
    aim_axes = quat_rotate(truth, AIM_AXES)
    aims = aim_directions(motion.positions)
    assert np.abs(aim_axes[:, ORIENTATION_AIMED] - aims[:, ORIENTATION_AIMED]).max() < 1e-9
    pelvis_y = quat_rotate(truth[:, J["PELVIS"]], np.array([0.0, 1.0, 0.0]))
    pelvis_y[:, 2] = 0.0
    pelvis_y /= np.linalg.norm(pelvis_y, axis=-1, keepdims=True)
    facing = np.degrees(np.arccos(np.clip(np.sum(pelvis_y * body_facing(motion.positions), axis=-1), -1, 1)))
    assert np.median(facing) < 20.0  # measured 6.3 deg
    from_body = quat_angle_deg(truth, apply_derived(body_hint_frames(motion.positions)))
    assert np.median(from_body[:, BODY_REGIONS["torso"]]) < 15.0  # measured 7.7 deg
    assert np.median(from_body[:, BODY_REGIONS["arm"]]) > 20.0  # measured 35 deg: the recorded arm roll
