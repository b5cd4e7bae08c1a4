"""The real CMU BVH files (both naming variants) load into plausible k4abt skeletons."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skelfuse.schema.skeleton import BONES, J
from skelfuse.sim.bvh import load_bvh
from skelfuse.sim.motion import facing_deg

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "cmu-mocap"

pytestmark = [
    pytest.mark.integration,
    pytest.mark.skipif(not DATA.is_dir(), reason=f"CMU mocap data not found at {DATA} (../shared/data absent)"),
]

FILES = [
    pytest.param("13_29.bvh", id="motionbuilder-names"),
    pytest.param("131_01.bvh", id="3dsmax-names-walk"),
    pytest.param("131_03.bvh", id="3dsmax-names-hop"),
]


@pytest.fixture(scope="module", params=FILES)
def take(request):
    return request.param, load_bvh(DATA / request.param, fps_out=30.0, facing_deg=0.0)


def test_loads_at_30_hz_without_the_t_pose(take) -> None:
    name, motion = take
    frames_120 = {"13_29.bvh": 4593, "131_01.bvh": 994, "131_03.bvh": 1102}[name] - 1
    assert motion.fps == 30.0
    assert motion.n_frames == (frames_120 - 1) // 4 + 1
    assert np.isfinite(motion.positions).all()


def test_bone_lengths_constant_over_frames(take) -> None:
    _, motion = take
    p = motion.positions
    lengths = np.linalg.norm(p[:, BONES[:, 1]] - p[:, BONES[:, 0]], axis=-1)
    assert lengths.min() > 20.0
    assert np.abs(lengths - lengths[0]).max() < 0.1  # mm


def test_hips_stand_about_a_metre_high_and_feet_on_the_floor(take) -> None:
    _, motion = take
    p = motion.positions
    pelvis = np.median(p[:, J["PELVIS"], 2])
    hips = np.median(p[:, [J["HIP_LEFT"], J["HIP_RIGHT"]], 2])
    assert 850.0 < pelvis < 1100.0
    assert 750.0 < hips < 1000.0
    lowest_foot = p[:, [J["FOOT_LEFT"], J["FOOT_RIGHT"], J["ANKLE_LEFT"], J["ANKLE_RIGHT"]], 2].min(axis=1)
    assert np.median(lowest_foot) < 120.0
    assert lowest_foot.min() > -30.0
    assert np.median(p[:, J["HEAD"], 2]) > pelvis + 300.0


def test_left_is_on_the_subjects_left_and_face_in_front(take) -> None:
    _, motion = take
    p = motion.positions
    forward = np.array([1.0, 0.0, 0.0])  # facing_deg=0 for the first frame
    left = np.cross([0.0, 0.0, 1.0], forward)  # up x forward = left
    assert facing_deg(p[0]) == pytest.approx(0.0, abs=1e-6)
    for l_name, r_name in (("HIP_LEFT", "HIP_RIGHT"), ("SHOULDER_LEFT", "SHOULDER_RIGHT"), ("EAR_LEFT", "EAR_RIGHT")):
        assert (p[0, J[l_name]] - p[0, J[r_name]]) @ left > 50.0
    assert (p[0, J["NOSE"]] - p[0, J["HEAD"]]) @ forward > 30.0
    assert (p[0, J["FOOT_LEFT"]] - p[0, J["ANKLE_LEFT"]]) @ forward > 50.0


def test_placement_honours_facing_and_position() -> None:
    motion = load_bvh(DATA / "13_29.bvh", facing_deg=120.0, position_mm=(500.0, -300.0))
    assert facing_deg(motion.positions[0]) == pytest.approx(120.0, abs=1e-6)
    pelvis_xy = motion.positions[:, J["PELVIS"], :2]
    centre = 0.5 * (pelvis_xy.min(axis=0) + pelvis_xy.max(axis=0))
    np.testing.assert_allclose(centre, [500.0, -300.0], atol=1e-6)


def test_segment_and_repeat_cut_the_squats_out() -> None:
    whole = load_bvh(DATA / "13_29.bvh", fps_out=30.0)
    squats = load_bvh(DATA / "13_29.bvh", fps_out=30.0, start_s=31.5, end_s=37.5)
    assert squats.duration_s == pytest.approx(6.0, abs=0.05)
    # the README's squats: the pelvis drops by more than 200 mm in the segment, not in the first seconds
    drop = squats.positions[:, J["PELVIS"], 2].max() - squats.positions[:, J["PELVIS"], 2].min()
    assert drop > 200.0
    assert whole.positions[:60, J["PELVIS"], 2].std() < squats.positions[:, J["PELVIS"], 2].std()
    twice = load_bvh(DATA / "13_29.bvh", fps_out=30.0, start_s=31.5, end_s=37.5, repeat=2)
    assert twice.n_frames == pytest.approx(2 * squats.n_frames, abs=2)
    half = squats.n_frames
    first, second = twice.positions[:half, J["PELVIS"], 2], twice.positions[half:, J["PELVIS"], 2]
    assert second.min() == pytest.approx(first.min(), abs=5.0)  # the same squats again
    assert second.max() == pytest.approx(first.max(), abs=5.0)
    with pytest.raises(ValueError, match="segment"):
        load_bvh(DATA / "13_29.bvh", start_s=100.0)
