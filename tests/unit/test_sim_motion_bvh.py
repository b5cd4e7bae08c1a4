"""Motion container and the BVH parser / forward kinematics, against hand-computed positions."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.schema.errors import DataError
from skelfuse.sim.bvh import forward_kinematics, parse_bvh
from skelfuse.sim.motion import Motion, axis_rotation, facing_deg

TINY_BVH = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Up
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    End Site
    {
      OFFSET 0 0 5
    }
  }
  JOINT Side
  {
    OFFSET 10 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 0 0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.5
1 2 3  90 0 0   0 0 0   0 0 0
1 2 3  0 0 90   90 0 0  0 0 0
0 0 0  90 90 0  0 0 0   0 0 0
"""


def test_parse_bvh_reads_hierarchy_and_motion() -> None:
    bvh = parse_bvh(TINY_BVH)
    assert [j.name for j in bvh.joints] == ["Hips", "Up", "Side"]
    assert [j.parent for j in bvh.joints] == [-1, 0, 0]
    assert bvh.joints[2].channels == ["Zrotation", "Xrotation", "Yrotation"]
    np.testing.assert_allclose(bvh.joints[1].end_offset, [0, 0, 5])
    assert bvh.motion.shape == (3, 12)
    assert bvh.frame_time_s == 0.5


def test_forward_kinematics_matches_hand_computed_positions() -> None:
    positions, rotations = forward_kinematics(parse_bvh(TINY_BVH))
    # Frame 0: root at (1,2,3) turned 90° about z: (0,10,0) -> (-10,0,0), (10,0,0) -> (0,10,0).
    np.testing.assert_allclose(positions[0], [[1, 2, 3], [-9, 2, 3], [1, 12, 3]], atol=1e-9)
    # Frame 1: root turned 90° about x: (0,10,0) -> (0,0,10); the Up joint's own 90° about z then turns
    # its End Site (0,0,5): Rx(90) @ Rz(90) @ (0,0,5) = Rx(90) @ (0,0,5) = (0,-5,0).
    np.testing.assert_allclose(positions[1, 1], [1, 2, 13], atol=1e-9)
    np.testing.assert_allclose(rotations[1, 1] @ [0, 0, 5], [0, -5, 0], atol=1e-9)
    # Frame 2: channel order Z then Y means R = Rz(90) @ Ry(90): (10,0,0) -> Ry: (0,0,-10) -> Rz: (0,0,-10).
    np.testing.assert_allclose(positions[2, 2], [0, 0, -10], atol=1e-9)


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        pytest.param("", "unexpected end", id="empty"),
        pytest.param("MOTION", "expected 'HIERARCHY'", id="no-hierarchy"),
        pytest.param(TINY_BVH.replace("Frames: 3", "Frames: 4"), "expected 4 frames", id="frame-count"),
        pytest.param(TINY_BVH.replace("OFFSET 0 10 0", "OFFSET 0 ten 0"), "expected a number", id="offset"),
        pytest.param(TINY_BVH.replace("Xposition", "Wposition"), "unknown channel", id="channel"),
        pytest.param(TINY_BVH.replace("1 2 3  0 0 90", "1 2 x  0 0 90"), "non-numeric", id="motion-value"),
        pytest.param(TINY_BVH.split("MOTION")[0], "unexpected end", id="truncated"),
    ],
)
def test_malformed_bvh_raises_data_error(text: str, fragment: str) -> None:
    with pytest.raises(DataError, match=fragment):
        parse_bvh(text, source="tiny.bvh")


def test_load_bvh_names_missing_file(tmp_path) -> None:
    from skelfuse.sim.bvh import load_bvh

    with pytest.raises(DataError, match="cannot read BVH"):
        load_bvh(tmp_path / "nope.bvh")


def test_load_bvh_rejects_unknown_naming(tmp_path) -> None:
    from skelfuse.sim.bvh import load_bvh

    path = tmp_path / "tiny.bvh"
    path.write_text(TINY_BVH)
    with pytest.raises(DataError, match="neither CMU variant"):
        load_bvh(path)


def test_motion_resampled_picks_exact_frames_and_interpolates() -> None:
    positions = np.zeros((121, 32, 3))
    positions[:, :, 0] = np.arange(121)[:, None]  # x = frame index
    motion = Motion("ramp", 120.0, positions)
    assert motion.duration_s == pytest.approx(121 / 120)
    at30 = motion.resampled(30.0)
    assert at30.n_frames == 31
    np.testing.assert_array_equal(at30.positions[:, 0, 0], np.arange(0, 121, 4))
    at50 = motion.resampled(50.0)
    np.testing.assert_allclose(at50.positions[1, 0, 0], 120 / 50)


def test_motion_validates_shape_and_values() -> None:
    with pytest.raises(DataError, match="shape"):
        Motion("bad", 30.0, np.zeros((5, 31, 3)))
    with pytest.raises(DataError, match="NaN"):
        Motion("bad", 30.0, np.full((5, 32, 3), np.nan))
    with pytest.raises(DataError, match="fps"):
        Motion("bad", 0.0, np.zeros((5, 32, 3)))


def test_axis_rotation_is_right_handed() -> None:
    np.testing.assert_allclose(axis_rotation("z", np.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(axis_rotation("x", np.pi / 2) @ [0, 1, 0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(axis_rotation("y", np.pi / 2) @ [0, 0, 1], [1, 0, 0], atol=1e-12)


def test_facing_deg_from_hips_and_shoulders() -> None:
    from skelfuse.schema.skeleton import J

    pose = np.zeros((32, 3))
    # Facing +y: the body's left is -x.
    pose[J["HIP_LEFT"]] = [-100, 0, 900]
    pose[J["HIP_RIGHT"]] = [100, 0, 900]
    pose[J["SHOULDER_LEFT"]] = [-180, 0, 1400]
    pose[J["SHOULDER_RIGHT"]] = [180, 0, 1400]
    assert facing_deg(pose) == pytest.approx(90.0)
