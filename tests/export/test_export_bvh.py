"""BVH export: the file's own forward kinematics reproduces the fitted armature, read back two ways: with
bvhio (a BVH library from PyPI) against axes written out by hand here, and with the simulator's BVH reader and
our axis constant; header, units, rotation order and multi-person naming as documented.

Our own reader alone would not do: an axis mistake in ``BVH_FROM_WORLD`` cancels out on the way back."""

from __future__ import annotations

from pathlib import Path

import bvhio
import numpy as np
import pytest
from export_takes import FPS, as_frames, fused_take, truth_take
from scipy.spatial.transform import Rotation

from skelfuse.cli import main
from skelfuse.export.bvh import (
    BVH_FROM_WORLD,
    DFS_ORDER,
    euler_zxy_degrees,
    world_positions_from_bvh,
    write_bvh,
    write_bvh_arrays,
)
from skelfuse.export.csv import write_fused
from skelfuse.schema.errors import DataError
from skelfuse.schema.skeleton import JOINT_NAMES, N_JOINTS, PARENTS
from skelfuse.sim.bvh import forward_kinematics, parse_bvh


def _read_back(path: Path, unit: str) -> tuple[np.ndarray, object]:
    bvh = parse_bvh(path.read_text(), source=str(path))
    positions, _ = forward_kinematics(bvh)
    return world_positions_from_bvh(positions, [j.name for j in bvh.joints], unit=unit), bvh


BVH_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""BVH is Y up, Z toward the viewer: (X, Y, Z) = (x, z, -y) of our z-up world (x right, y forward), by hand."""
MM_PER_UNIT = {"cm": 10.0, "mm": 1.0, "m": 1000.0}


def _read_with_bvhio(path: Path) -> np.ndarray:
    """(F, 32, 3) joint positions in the file's own axes and unit, k4abt order, by bvhio's forward kinematics."""
    root = bvhio.readAsHierarchy(str(path))
    joints = {joint.Name: joint for joint, _, _ in root.layout()}
    n_frames = len(bvhio.readAsBvh(str(path)).Root.Keyframes)
    out = np.empty((n_frames, N_JOINTS, 3))
    for frame in range(n_frames):
        root.loadPose(frame)
        for j, name in enumerate(JOINT_NAMES):
            position = joints[name].PositionWorld
            out[frame, j] = (position.x, position.y, position.z)
    return out


@pytest.mark.parametrize("unit", ["cm", "m"])
def test_an_independent_reader_finds_the_fitted_positions_in_bvh_axes(tmp_path: Path, unit: str) -> None:
    fused, _ = fused_take("random")
    export = write_bvh_arrays(tmp_path / "take.bvh", np.arange(len(fused)) / FPS, fused, unit=unit)
    in_file = _read_with_bvhio(export.path) * MM_PER_UNIT[unit]
    np.testing.assert_allclose(in_file, export.motion.positions @ BVH_AXES.T, rtol=0, atol=1e-3)  # mm


@pytest.mark.parametrize("unit", ["cm", "mm", "m"])
def test_the_file_reproduces_the_fitted_positions(tmp_path: Path, unit: str) -> None:
    fused, _ = fused_take("random")
    export = write_bvh_arrays(tmp_path / "take.bvh", np.arange(len(fused)) / FPS, fused, unit=unit)
    world, bvh = _read_back(export.path, unit)
    assert np.abs(world - export.motion.positions).max() < 1e-3  # mm; 6 decimals in the file
    assert bvh.motion.shape == (len(fused), 6 + 3 * (N_JOINTS - 1))
    assert bvh.frame_time_s == pytest.approx(1 / FPS, abs=1e-8)


def test_a_rigid_skeleton_survives_the_file(tmp_path: Path) -> None:
    truth = truth_take("squat")
    export = write_bvh_arrays(tmp_path / "squat.bvh", np.arange(len(truth)) / FPS, truth)
    world, _ = _read_back(export.path, "cm")
    assert np.abs(world - truth).max() < 1e-3


def test_hierarchy_channels_and_axes(tmp_path: Path) -> None:
    truth = truth_take("walking")
    export = write_bvh_arrays(tmp_path / "walk.bvh", np.arange(len(truth)) / FPS, truth)
    _, bvh = _read_back(export.path, "cm")
    names = [j.name for j in bvh.joints]
    assert names == [JOINT_NAMES[j] for j in DFS_ORDER] and sorted(names) == sorted(JOINT_NAMES)
    for joint in bvh.joints:  # the k4abt parents
        expected_parent = PARENTS[JOINT_NAMES.index(joint.name)]
        assert (joint.parent < 0 and expected_parent < 0) or names[joint.parent] == JOINT_NAMES[expected_parent]
        rotations = ["Zrotation", "Xrotation", "Yrotation"]
        assert joint.channels == (
            ["Xposition", "Yposition", "Zposition", *rotations] if joint.parent < 0 else rotations
        )
    leaves = {j.name for j in bvh.joints if j.end_offset is not None}
    assert leaves == {"HANDTIP_LEFT", "THUMB_LEFT", "HANDTIP_RIGHT", "THUMB_RIGHT", "FOOT_LEFT", "FOOT_RIGHT",
                      "NOSE", "EYE_LEFT", "EAR_LEFT", "EYE_RIGHT", "EAR_RIGHT"}  # fmt: skip
    # Y up and the T-pose: the spine's offsets point up (+Y), the left arm's to +X, the legs down.
    offset = {j.name: j.offset for j in bvh.joints}
    assert offset["SPINE_CHEST"][1] > 0 and abs(offset["SPINE_CHEST"][0]) < 1e-9
    assert offset["ELBOW_LEFT"][0] > 0 and offset["ELBOW_RIGHT"][0] < 0
    assert offset["KNEE_LEFT"][1] < 0 and offset["FOOT_LEFT"][2] > 0  # feet forward: +Z
    # Root channels are the pelvis position in cm, BVH axes.
    np.testing.assert_allclose(bvh.motion[:, :3], truth[:, 0] @ BVH_FROM_WORLD.T / 10.0, atol=1e-5)


def test_euler_order_matches_scipy_intrinsic_zxy() -> None:
    rotations = Rotation.random(200, random_state=3)
    ours = euler_zxy_degrees(rotations.as_matrix())
    back = Rotation.from_euler("ZXY", ours, degrees=True).as_matrix()
    np.testing.assert_allclose(back, rotations.as_matrix(), atol=1e-9)
    lock = Rotation.from_euler("ZXY", [[30.0, 90.0, 0.0], [-20.0, -90.0, 15.0]], degrees=True).as_matrix()
    np.testing.assert_allclose(
        Rotation.from_euler("ZXY", euler_zxy_degrees(lock), degrees=True).as_matrix(), lock, atol=1e-6
    )


def test_several_people_write_one_file_each(tmp_path: Path) -> None:
    truth = truth_take("walking")[:30]
    frames = as_frames(truth, track_id=4)
    other = as_frames(truth + np.array([500.0, 0.0, 0.0]), track_id=11)
    merged = [
        type(a)(a.time_us, np.concatenate([a.track_ids, b.track_ids]), np.concatenate([a.positions, b.positions]),
                np.concatenate([a.n_agree, b.n_agree]), np.concatenate([a.confidence, b.confidence]),
                np.concatenate([a.contributors, b.contributors]), a.sensor_ids)
        for a, b in zip(frames, other, strict=True)
    ]  # fmt: skip
    exports = write_bvh(merged, tmp_path / "take.bvh")
    assert [e.path.name for e in exports] == ["take_person4.bvh", "take_person11.bvh"]
    world, _ = _read_back(exports[1].path, "cm")
    assert np.abs(world - (truth + np.array([500.0, 0.0, 0.0]))).max() < 1e-3
    single = write_bvh(frames, tmp_path / "one.bvh")
    assert [e.path.name for e in single] == ["one.bvh"] and single[0].n_frames == 30


def test_bad_unit_is_refused(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="unknown BVH unit"):
        write_bvh(as_frames(truth_take("walking")[:5]), tmp_path / "x.bvh", unit="inch")


def test_skelfuse_export_writes_bvh_per_person_from_a_fused_table(tmp_path: Path, capsys) -> None:
    """The command end to end: a fused CSV in, one BVH whose forward kinematics lands on the fused positions."""
    fused, _ = fused_take("walking")
    table = tmp_path / "take.csv"
    write_fused(as_frames(fused, track_id=5), table)
    assert main(["export", str(table), "--format", "bvh", "--output", str(tmp_path / "walk.bvh"), "--json"]) == 0
    capsys.readouterr()
    world, bvh = _read_back(tmp_path / "walk.bvh", "cm")
    assert bvh.motion.shape[0] == len(fused)
    seen = np.isfinite(fused).all(axis=-1)
    distance = np.linalg.norm(world - np.nan_to_num(fused), axis=-1)[seen]
    assert np.median(distance) < 10.0  # mm: the armature's documented retargeting error on body joints
