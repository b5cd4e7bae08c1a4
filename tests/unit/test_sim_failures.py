"""Failure families against the simulator's ground truth: each does what it says, and only when switched on."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.eval.metrics import best_lag, lag_error_curve, swap_counts
from skelfuse.schema.skeleton import PAPER_REALIGN_PAIRS
from skelfuse.sim.failures import FAMILIES, MIXTURE, family_profile
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.rig import best_view_sensor

BASE = load_profile()
PAIR_NAMES = ("shoulders", "elbows", "wrists", "hips", "knees", "ankles")


def _world(obs, index: int = 0) -> np.ndarray:
    return obs.positions_world(calibrated=False)[:, index]


def _swapped_share(obs, index: int = 0) -> dict[str, float]:
    swapped, valid = swap_counts(_world(obs, index), obs.truth, PAPER_REALIGN_PAIRS)
    return {name: swapped[k] / max(valid[k], 1) for k, name in enumerate(PAIR_NAMES)}


def test_every_family_is_a_valid_profile_and_unknown_names_fail() -> None:
    for name in [*FAMILIES, MIXTURE.name]:
        family_profile(BASE, name)
    with pytest.raises(ValueError, match="unknown failure family"):
        family_profile(BASE, "gremlins")


def test_limb_swaps_swap_one_limb_pair_in_a_front_view() -> None:
    motion = make_gesture("hands_up_down", duration_s=8.0, seed=1)
    front = [best_view_sensor(0.0)]
    plain = _swapped_share(simulate(motion, front, BASE, seed=2))
    swapped = _swapped_share(simulate(motion, front, family_profile(BASE, "limb_swaps"), seed=2))
    assert max(plain.values()) < 0.01  # a front view never mirrors
    assert swapped["elbows"] > 0.03 and swapped["knees"] > 0.03
    assert swapped["shoulders"] < 0.01 and swapped["hips"] < 0.01  # the torso keeps its labels


def test_side_flips_mirror_a_side_view_only_with_the_family() -> None:
    motion = make_gesture("squat", duration_s=8.0, seed=1)
    side = [best_view_sensor(90.0)]  # the subject faces +x, the sensor sees its left side
    assert not simulate(motion, side, BASE, seed=4).mirrored.any()
    assert simulate(motion, side, family_profile(BASE, "side_flips"), seed=4).mirrored.mean() > 0.2


def test_common_bias_is_shared_by_all_views() -> None:
    motion = make_gesture("squat", duration_s=6.0, seed=3)
    rig = [best_view_sensor(angle, sensor_id=f"s{angle:g}") for angle in (-40.0, 0.0, 40.0)]
    obs = simulate(motion, rig, family_profile(BASE, "common_bias"), seed=5)
    errors = obs.positions_world(calibrated=False) - obs.truth[:, None]  # (T, S, 32, 3)
    torso = [0, 1, 2, 3]
    mean_errors = errors[:, :, torso].mean(axis=0)  # (S, 4, 3) constant part per view
    shared = np.corrcoef(mean_errors[0].ravel(), mean_errors[1].ravel())[0, 1]
    assert shared > 0.8
    plain = simulate(motion, rig, BASE, seed=5).positions_world(calibrated=False) - obs.truth[:, None]
    assert (
        np.linalg.norm(errors.mean(axis=1)[:, torso], axis=-1).mean()
        > 2 * np.linalg.norm(plain.mean(axis=1)[:, torso], axis=-1).mean()
    )


def test_distance_speed_family_reports_late() -> None:
    motion = make_gesture("jump", duration_s=6.0, seed=0)
    obs = simulate(motion, [best_view_sensor(0.0)], family_profile(BASE, "distance_speed"), seed=1)
    shifts = np.arange(-3, 6)
    sums, counts = lag_error_curve(_world(obs), obs.truth, shifts)
    lag, _ = best_lag(sums, counts, shifts)
    assert lag == pytest.approx(1.5, abs=0.6)


def test_flip_reconverge_starts_each_burst_off_target() -> None:
    motion = make_gesture("hands_up_down", duration_s=12.0, seed=0, facing_deg=180.0)  # back to the sensor
    rear = [best_view_sensor(180.0, distance_mm=2300.0, sensor_id="front"), best_view_sensor(0.0, sensor_id="rear")]
    obs = simulate(motion, rear, family_profile(BASE, "flip_reconverge"), seed=7)
    mirrored = obs.mirrored[:, 1]
    starts = np.flatnonzero(mirrored[1:] & ~mirrored[:-1]) + 1
    assert starts.size >= 2
    ids = obs.body_ids[:, 1]
    assert all(ids[s] != ids[s - 1] for s in starts)


def test_partial_view_drags_the_visible_joints() -> None:
    # a sensor 1.2 m away, low: the feet are below its field of view while the upper body is in it
    from skelfuse.sim.rig import look_at

    motion = make_gesture("hands_up_down", duration_s=4.0, seed=0)
    near = [look_at("near", np.array([1200.0, 0.0, 1400.0]), np.array([0.0, 0.0, 1300.0]))]
    plain = simulate(motion, near, BASE, seed=8)
    dragged = simulate(motion, near, family_profile(BASE, "partial_view"), seed=8)
    outside = plain.confidence[:, 0] == 0  # NONE: out of view (and the hands' NONE episodes)
    assert outside[:, [20, 24]].mean() > 0.9  # the ankles are out of view
    head = 26
    err_plain = np.linalg.norm(_world(plain)[:, head] - plain.truth[:, head], axis=-1).mean()
    err_dragged = np.linalg.norm(_world(dragged)[:, head] - dragged.truth[:, head], axis=-1).mean()
    assert err_dragged > err_plain + 15.0  # the visible head is pulled along with the guessed legs


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def test_tilted_mounts_tilt_the_true_pose_and_hang_guessed_arms_along_the_cameras_down() -> None:
    from skelfuse.sim.rig import paper_rig

    motion = make_gesture("walking", duration_s=4.0, seed=2, facing_deg=0.0)
    rig = paper_rig(4)
    # No noise on guesses and a full pull to the default pose: a hidden arm hangs exactly along "down".
    quiet = {
        "occluded_sigma_mm": dict.fromkeys(BASE.occluded_sigma_mm, 0.01),
        "occluded_pull": 1.0,
        "flip_on_prob": 0.0,
    }
    level = simulate(motion, rig, BASE.replace(**quiet), seed=3)
    tilted = simulate(motion, rig, family_profile(BASE.replace(**quiet), "tilted_mounts"), seed=3)
    for k, sensor in enumerate(rig):
        relative = sensor.world_from_sensor[:3, :3].T @ tilted.world_from_sensor[k, :3, :3]
        turn = np.degrees(np.arccos(np.clip((np.trace(relative) - 1.0) / 2.0, -1.0, 1.0)))
        assert 0.0 < turn <= 15.0 * np.sqrt(2) + 1e-6  # rolled and pitched by up to 15 deg each
    np.testing.assert_allclose(level.world_from_sensor, np.stack([s.world_from_sensor for s in rig]))
    # the reported joints are the truth seen through the tilted (true) pose: the torso agrees with the truth
    torso = [0, 1, 2, 3]
    err = np.linalg.norm(tilted.positions_world(calibrated=False)[:, :, torso] - tilted.truth[:, None, torso], axis=-1)
    assert np.nanmedian(err) < 30.0
    # a hidden right elbow whose wrist is hidden too hangs from the shoulder along the camera's own "down": vertical in
    # the level rig, tilted with the mount in the tilted one
    angles = {}
    for name, obs in (("level", level), ("tilted", tilted)):
        world = obs.positions_world(calibrated=False)
        elbow, wrist = 13, 14  # ELBOW_RIGHT, WRIST_RIGHT (shoulder 12)
        hung = obs.occluded[:, :, elbow] & obs.occluded[:, :, wrist] & obs.tracked
        assert hung.sum() > 20, name
        bone = world[:, :, elbow] - world[:, :, elbow - 1]  # shoulder -> elbow
        angles[name] = np.median(_angle_deg(bone[hung], np.array([0.0, 0.0, -1.0])))
    assert angles["level"] < 3.0 and angles["tilted"] > 3.0 + angles["level"]


def test_sitting_and_lying_pose_the_truth_and_keep_every_bone() -> None:
    from skelfuse.schema.skeleton import BONES, J
    from skelfuse.sim.rig import paper_rig

    motion = make_gesture("random", duration_s=3.0, seed=4)
    standing = simulate(motion, paper_rig(3), BASE, seed=1).truth
    bones = np.linalg.norm(standing[:, BONES[:, 1]] - standing[:, BONES[:, 0]], axis=-1)
    for name in ("sitting", "lying"):
        obs = simulate(motion, paper_rig(3), family_profile(BASE, name), seed=1)
        truth = obs.truth
        np.testing.assert_allclose(
            np.linalg.norm(truth[:, BONES[:, 1]] - truth[:, BONES[:, 0]], axis=-1), bones, rtol=1e-6, atol=1e-6
        )
        assert obs.tracked.any(axis=1).mean() > 0.9, name  # still tracked by some sensor
        if name == "sitting":
            for side in ("LEFT", "RIGHT"):
                hip, knee, ankle = (J[f"{n}_{side}"] for n in ("HIP", "KNEE", "ANKLE"))
                np.testing.assert_allclose(truth[:, knee, 2], truth[:, hip, 2], atol=1e-6)  # thighs level
                np.testing.assert_allclose(truth[:, ankle, :2], truth[:, knee, :2], atol=1e-6)  # shins upright
            feet = truth[:, [J["ANKLE_LEFT"], J["ANKLE_RIGHT"]], 2].min(axis=1)
            np.testing.assert_allclose(feet, standing[:, [J["ANKLE_LEFT"], J["ANKLE_RIGHT"]], 2].min(), atol=1e-6)
            assert 350.0 < truth[:, J["PELVIS"], 2].mean() < 650.0  # a chair's height, not standing
        else:
            np.testing.assert_allclose(truth[:, J["PELVIS"], 2], 120.0, atol=1e-6)
            trunk = truth[:, J["NECK"]] - truth[:, J["PELVIS"]]
            assert np.abs(trunk[:, 2]).max() < 0.25 * np.linalg.norm(trunk, axis=-1).min()  # the trunk lies flat
            assert truth[:, J["HEAD"], 2].max() < 450.0


def test_close_people_swap_or_merge_the_first_view_with_the_neighbour_only() -> None:
    from skelfuse.fusion.depth.frontal import body_facing
    from skelfuse.sim.rig import paper_rig

    motion = make_gesture("hands_up_down", duration_s=10.0, seed=5)
    rig = paper_rig(3)
    plain = simulate(motion, rig, BASE, seed=6)
    close = simulate(motion, rig, family_profile(BASE, "close_people"), seed=6)
    # the neighbour, computed here from its definition: the motion 1 s behind, 450 mm to the subject's right
    forward = body_facing(close.truth)
    right = np.stack([forward[:, 1], -forward[:, 0], np.zeros(len(forward))], axis=1)
    neighbour = motion.at_times(np.maximum(close.times_s - 1.0, 0.0)) + 450.0 * right[:, None]
    world = close.positions_world(calibrated=False)
    torso = [0, 1, 2, 3]
    to_subject = np.linalg.norm(world[:, 0, torso] - close.truth[:, torso], axis=-1).mean(axis=1)
    to_neighbour = np.linalg.norm(world[:, 0, torso] - neighbour[:, torso], axis=-1).mean(axis=1)
    midpoint = 0.5 * (close.truth + neighbour)
    to_midpoint = np.linalg.norm(world[:, 0, torso] - midpoint[:, torso], axis=-1).mean(axis=1)
    swapped = to_neighbour < 100.0
    merged = to_midpoint < 100.0
    own = to_subject < 100.0
    assert swapped.mean() > 0.05 and merged.mean() > 0.05 and own.mean() > 0.5
    assert not (swapped & own).any() and not (merged & own).any()
    # the other views see the subject as without the family: same streams, same reports
    np.testing.assert_array_equal(close.positions[:, 1:], plain.positions[:, 1:])
