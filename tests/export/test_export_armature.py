"""The fixed-length armature: exact on a rigid skeleton, close on fused data, gaps filled and marked."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from export_takes import as_frames, fused_take, truth_take
from scipy.spatial.transform import Rotation

from skelfuse.eval import real
from skelfuse.retarget.armature import CHILDREN, fit_frames, fit_motion, person_takes, resample
from skelfuse.retarget.rotations import (
    axis_angle_matrix,
    continuous_quaternions,
    kabsch,
    matrix_to_quaternion,
    quaternion_to_matrix,
)
from skelfuse.schema.errors import DataError
from skelfuse.schema.frames import FusedFrame
from skelfuse.schema.skeleton import BONES, N_JOINTS, J

FPS = 30.0


def _times(n: int) -> np.ndarray:
    return np.arange(n) / FPS


@pytest.mark.parametrize("gesture", ["random", "walking", "squat"])
def test_a_rigid_skeleton_is_reproduced_exactly(gesture: str) -> None:
    # The simulator's gestures are forward kinematics of a fixed-length skeleton: the fit must find its bone
    # lengths and reproduce every joint, whatever rest pose and rotation order we chose.
    truth = truth_take(gesture)
    fit = fit_motion(_times(len(truth)), truth)
    lengths = np.linalg.norm(truth[0, BONES[:, 1]] - truth[0, BONES[:, 0]], axis=-1)
    np.testing.assert_allclose(fit.armature.bone_lengths[BONES[:, 1]], lengths, atol=1e-6)
    assert np.abs(fit.positions - truth).max() < 1e-6
    assert not fit.filled.any()
    err = fit.retargeting_error()
    assert err["all"]["median"] < 1e-6 and err["all"]["n"] == truth.shape[0] * N_JOINTS


def test_rotations_are_proper_and_compose_to_the_globals() -> None:
    fit = fit_motion(_times(60), truth_take("random")[:60])
    rot = fit.local_rotations
    np.testing.assert_allclose(rot @ np.swapaxes(rot, -1, -2), np.broadcast_to(np.eye(3), rot.shape), atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-9)
    for joint in range(1, N_JOINTS):
        parent = next(p for p in range(N_JOINTS) if joint in CHILDREN[p])
        np.testing.assert_allclose(
            fit.global_rotations[:, parent] @ rot[:, joint], fit.global_rotations[:, joint], atol=1e-9
        )


def test_the_elbows_and_knees_bend_as_hinges_about_their_rest_axis() -> None:
    # The simulator bends elbows and knees about one axis; taking the upper arm's and thigh's twist from the
    # bend plane must make our elbow/knee local rotation a pure rotation about the rest hinge axis
    # (elbows: vertical, z, in the palms-down T-pose; knees: lateral, x), wherever the bend is clear.
    truth = truth_take("random", duration_s=8.0)
    fit = fit_motion(_times(len(truth)), truth)
    for joint, axis in ((J["ELBOW_LEFT"], 2), (J["ELBOW_RIGHT"], 2), (J["KNEE_LEFT"], 0), (J["KNEE_RIGHT"], 0)):
        rotvec = Rotation.from_matrix(fit.local_rotations[:, joint]).as_rotvec()
        angle = np.linalg.norm(rotvec, axis=-1)
        bent = angle > np.radians(30)
        if not bent.any():
            continue
        along = np.abs(rotvec[bent, axis]) / angle[bent]
        assert along.min() > np.cos(np.radians(3)), (joint, np.degrees(np.arccos(along.min())))
    assert (
        np.linalg.norm(Rotation.from_matrix(fit.local_rotations[:, J["ELBOW_LEFT"]]).as_rotvec(), axis=-1) > 0.5
    ).any()


def test_fused_simulator_take_meets_the_body_target() -> None:
    # The target: median FK-vs-fused distance <= 10 mm on the body joints (simulated, fused data).
    fused, _ = fused_take("random")
    fit = fit_motion(_times(len(fused)), fused)
    err = fit.retargeting_error()
    assert err["body"]["median"] <= 10.0, err
    assert err["body"]["n"] > 0.9 * len(fused) * 16


def test_gaps_are_interpolated_held_and_marked() -> None:
    truth = truth_take("walking").copy()
    positions = truth.copy()
    elbow = J["ELBOW_LEFT"]
    positions[10:20, elbow] = np.nan  # an inner gap: linear interpolation between frames 9 and 20
    positions[:5, J["KNEE_RIGHT"]] = np.nan  # a gap at the start: held at frame 5's value
    positions[:, J["EAR_LEFT"]] = np.nan  # never seen: the simulator body's default bone
    fit = fit_motion(_times(len(positions)), positions)
    expected = truth[9, elbow] + (truth[20, elbow] - truth[9, elbow]) * ((np.arange(10, 20) - 9) / 11)[:, None]
    np.testing.assert_allclose(fit.targets[10:20, elbow], expected, atol=1e-9)
    np.testing.assert_allclose(fit.targets[:5, J["KNEE_RIGHT"]], np.broadcast_to(truth[5, J["KNEE_RIGHT"]], (5, 3)))
    assert fit.filled[10:20, elbow].all() and not fit.filled[:10, elbow].any() and not fit.filled[20:, elbow].any()
    assert fit.filled[:5, J["KNEE_RIGHT"]].all() and fit.filled[:, J["EAR_LEFT"]].all()
    assert np.isfinite(fit.positions).all()
    assert fit.armature.bone_lengths[J["EAR_LEFT"]] > 0


def test_resample_puts_irregular_frames_on_a_uniform_grid() -> None:
    times = np.array([0.0, 0.1, 0.2, 0.4, 0.5])  # 0.3 dropped
    values = np.zeros((5, 1, 3))
    values[:, 0, 0] = [0.0, 1.0, 2.0, 4.0, 5.0]
    grid, out, filled = resample(times, values)
    np.testing.assert_allclose(grid, [0.0, 0.1, 0.2, 0.3, 0.4, 0.5])
    np.testing.assert_allclose(out[:, 0, 0], [0.0, 1.0, 2.0, 3.0, 4.0, 5.0])
    assert filled[:, 0].tolist() == [False, False, False, True, False, False]
    with pytest.raises(DataError, match="increase"):
        resample(times[::-1], values)


def test_the_pelvis_must_have_been_seen() -> None:
    positions = truth_take("walking").copy()
    positions[:, 0] = np.nan
    with pytest.raises(DataError, match="pelvis was never tracked"):
        fit_motion(_times(len(positions)), positions)


def test_person_takes_span_each_track_and_mark_absences() -> None:
    truth = truth_take("walking")[:6]
    frames = as_frames(truth, track_id=3)
    two = frames[2]
    frames[2] = FusedFrame(  # a second person appears at frame 2 only
        time_us=two.time_us,
        track_ids=np.array([9, 3]),
        positions=np.stack([truth[2] + 1000.0, truth[2]]),
        n_agree=np.ones((2, N_JOINTS), np.int16),
        confidence=np.full((2, N_JOINTS), 2, np.uint8),
        contributors=np.ones((2, 1), bool),
    )
    frames[4] = FusedFrame(
        frames[4].time_us,
        np.zeros(0, np.int64),
        np.zeros((0, N_JOINTS, 3)),
        np.zeros((0, N_JOINTS), np.int16),
        np.zeros((0, N_JOINTS), np.uint8),
        np.zeros((0, 1), bool),
    )
    takes = person_takes(frames[::-1])  # order does not matter
    assert [t.track_id for t in takes] == [3, 9]
    three, nine = takes
    np.testing.assert_allclose(three.times_s, np.arange(6) / FPS, atol=1e-6)
    assert np.isnan(three.positions[4]).all() and np.isfinite(three.positions[[0, 1, 2, 3, 5]]).all()
    assert nine.positions.shape == (1, N_JOINTS, 3) and three.orientations is None
    fits = fit_frames(frames)
    assert [f.track_id for f in fits] == [3, 9]
    assert fits[0].filled[4].all()
    with pytest.raises(DataError, match="no fused frames"):
        person_takes([])


def test_rotation_helpers_match_scipy() -> None:
    rng = np.random.default_rng(0)
    reference = Rotation.random(50, random_state=1)
    quats = matrix_to_quaternion(reference.as_matrix())
    xyzw = reference.as_quat()
    wxyz = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1) * np.sign(xyzw[:, 3:])
    np.testing.assert_allclose(quats, wxyz, atol=1e-12)
    np.testing.assert_allclose(quaternion_to_matrix(quats), reference.as_matrix(), atol=1e-12)
    axis = rng.normal(size=(50, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = rng.uniform(-3, 3, 50)
    np.testing.assert_allclose(
        axis_angle_matrix(axis, angle), Rotation.from_rotvec(axis * angle[:, None]).as_matrix(), atol=1e-12
    )
    source = rng.normal(size=(50, 4, 3))
    target = np.einsum("fij,fkj->fki", reference.as_matrix(), source)
    np.testing.assert_allclose(kabsch(source, target, np.ones((50, 4))), reference.as_matrix(), atol=1e-9)


def test_orientations_set_the_twist_when_given() -> None:
    # Fused orientations in an unknown axis convention: a constant per-joint offset C from our
    # segment frame, with an extra twist about the bone the positions cannot see. The fit must take that twist.
    truth = truth_take("random")
    base = fit_motion(_times(len(truth)), truth)
    n = len(truth)
    rng = np.random.default_rng(4)
    offsets = Rotation.random(N_JOINTS, random_state=5).as_matrix()
    twist_deg = 25.0 * np.sin(np.linspace(0, 4 * np.pi, n))
    forearm = J["ELBOW_LEFT"]
    bone = base.global_rotations[:, forearm] @ base.armature.offsets[J["WRIST_LEFT"]]
    bone /= np.linalg.norm(bone, axis=-1, keepdims=True)
    twisted = axis_angle_matrix(bone, np.radians(twist_deg)) @ base.global_rotations[:, forearm]
    given = base.global_rotations @ offsets
    given[:, forearm] = twisted @ offsets[forearm]
    quats = matrix_to_quaternion(given)
    quats[rng.random(n) < 0.05, :] = np.nan  # some unknown orientations
    fit = fit_motion(_times(n), truth, orientations=quats)
    ok = np.isfinite(quats[:, forearm]).all(axis=-1)
    np.testing.assert_allclose(fit.global_rotations[ok, forearm], twisted[ok], atol=1e-3)  # the offset is an estimate
    assert np.abs(fit.positions - truth).max() < 1e-6  # twist never moves a joint


DATA_DIR = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"


@pytest.mark.skipif(
    not (DATA_DIR / "azure-kinect-andyj1").is_dir(),
    reason=f"the real andyj1 take is not at {DATA_DIR} (the shared data folder beside the project)",
)
def test_the_real_three_view_take_meets_the_body_target() -> None:
    # Real k4abt skeletons of three synchronized Azure Kinects, fused by our preset (eval.real.fuse_views).
    take = real.load_take(DATA_DIR)
    fused = real.fuse_views(take.positions, take.confidence, "skelfuse")
    fit = fit_motion(_times(len(fused)), fused)
    err = fit.retargeting_error()
    assert err["body"]["median"] <= 10.0 and err["body"]["n"] >= 0.9 * len(fused) * 16, err
    lengths = np.linalg.norm(fused[:, BONES[:, 1]] - fused[:, BONES[:, 0]], axis=-1)
    np.testing.assert_allclose(fit.armature.bone_lengths[BONES[:, 1]], np.nanmedian(lengths, axis=0), rtol=1e-9)


def _offset_spread_deg(given: np.ndarray, fitted: np.ndarray) -> np.ndarray:
    """(F,) angle of each frame's offset ``given^T fitted`` from their chordal mean, degrees."""
    offsets = np.swapaxes(given, -1, -2) @ fitted
    u, _, vt = np.linalg.svd(offsets.mean(axis=0))
    cos = (np.trace(np.swapaxes(offsets, -1, -2) @ (u @ vt), axis1=-2, axis2=-1) - 1) / 2
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


@pytest.mark.skipif(
    not (DATA_DIR / "cmu-mocap" / "131_01.bvh").is_file(), reason=f"the CMU BVH take 131_01 is not in {DATA_DIR}"
)
def test_the_ankle_orientation_turns_with_the_exported_foot() -> None:
    # The retarget takes a joint's twist from its orientation where that orientation turns rigidly with the
    # segment to its child. The tracker's ankle frame is rigid to the foot (docs/orientations.md): on a recorded
    # walk, whose ankles flex, the ankle frames of that convention (the simulator's truth) keep one offset to the
    # exported foot segment (p90 0.8-1.4 deg, the knees' 0.4-0.6: resampling); frames aimed along the shin
    # instead drift by the ankle's flexion (p90 18-22 deg).
    from skelfuse.sim.orientation import load_bvh_with_orientations

    motion, truth = load_bvh_with_orientations(DATA_DIR / "cmu-mocap" / "131_01.bvh")
    fit = fit_motion(_times(motion.n_frames), motion.positions, orientations=truth)
    given = quaternion_to_matrix(truth)
    for side in ("LEFT", "RIGHT"):
        ankle, knee = J[f"ANKLE_{side}"], J[f"KNEE_{side}"]
        assert np.percentile(_offset_spread_deg(given[:, ankle], fit.global_rotations[:, ankle]), 90) < 2.0, side
        shin = motion.positions[:, ankle] - motion.positions[:, knee]
        shin /= np.linalg.norm(shin, axis=-1, keepdims=True)
        x_axes = given[:, ankle, :, 0]
        swing = Rotation.align_vectors  # per frame: the smallest rotation of the frame's X onto the shin
        along_shin = np.stack(
            [swing(shin[f][None], x_axes[f][None])[0].as_matrix() @ given[f, ankle] for f in range(motion.n_frames)]
        )
        assert np.percentile(_offset_spread_deg(along_shin, fit.global_rotations[:, ankle]), 90) > 10.0, side


def test_quaternion_tracks_are_made_continuous() -> None:
    rng = np.random.default_rng(2)
    track = Rotation.from_rotvec(np.linspace(0, 1, 20)[:, None] * rng.normal(size=3)).as_quat()[:, None, :]
    flipped = track * np.where(rng.random(20) < 0.5, -1.0, 1.0)[:, None, None]
    flipped[5] = np.nan
    smooth = continuous_quaternions(flipped)
    ok = np.isfinite(smooth[:, 0, 0])
    assert (np.sum(smooth[ok][1:, 0] * smooth[ok][:-1, 0], axis=-1) > 0).all()
    np.testing.assert_allclose(np.abs(smooth[ok]), np.abs(track[ok]))
    assert np.isnan(smooth[5]).all()
