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
