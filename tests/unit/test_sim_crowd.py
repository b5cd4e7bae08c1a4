"""The crowd simulator: determinism, other-person occlusion, body slots and ids."""

from __future__ import annotations

import numpy as np

from skelfuse.schema.skeleton import Confidence, J
from skelfuse.sim.crowd import (
    crossing_scenario,
    enter_leave_scenario,
    other_person_occlusion,
    place_on_path,
    simulate_people,
    simulate_scenario,
)
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.motion import facing_deg
from skelfuse.sim.observe import load_profile
from skelfuse.sim.rig import look_at


def standing(x: float, y: float, seed: int = 0):
    return place_on_path(make_gesture("hands_up_down", duration_s=1.0, seed=seed), (x, y), 180.0)


def test_deterministic_per_seed() -> None:
    scenario = crossing_scenario(duration_s=1.0)
    a = simulate_scenario(scenario, load_profile(), seed=4)
    b = simulate_scenario(scenario, load_profile(), seed=4)
    c = simulate_scenario(scenario, load_profile(), seed=5)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.body_ids, b.body_ids)
    np.testing.assert_array_equal(a.person_of_body, b.person_of_body)
    assert not np.array_equal(np.nan_to_num(a.positions), np.nan_to_num(c.positions))


def test_person_behind_another_is_not_tracked_and_a_half_hidden_one_goes_low() -> None:
    sensor = look_at("cam", np.array([3000.0, 0.0, 1000.0]), np.array([0.0, 0.0, 900.0]))
    profile = load_profile()
    front, behind = standing(1500.0, 0.0), standing(0.0, 0.0, seed=1)
    observations = simulate_people([front, behind], [sensor], profile, seed=0)
    tracked = np.zeros((observations.n_frames, 2), dtype=bool)
    for p in (0, 1):
        tracked[:, p] = ((observations.person_of_body[:, 0] == p) & observations.valid[:, 0]).any(axis=1)
    assert tracked[:, 0].all() and not tracked[:, 1].any()
    # Alone, the second person is tracked.
    alone = simulate_people([behind], [sensor], profile, seed=0)
    assert alone.valid[:, 0, 0].all()
    # Shifted sideways by a shoulder: some joints hidden by the other person, many of them LOW.
    half = simulate_people([front, standing(0.0, 550.0, seed=1)], [sensor], profile, seed=0)
    slot = half.person_of_body[:, 0] == 1
    assert slot.any(axis=1).mean() > 0.5  # tracked most of the time (not while an arm hides the trunk too)
    hidden = half.occluded_by_others[:, 0][slot]  # (T', 32)
    assert hidden.any(axis=1).all() and not hidden.all()
    conf = half.confidence[:, 0][slot]
    assert (conf[hidden] == Confidence.LOW).mean() > 0.5
    assert (conf[~hidden] == Confidence.MEDIUM).mean() > 0.5


def test_other_person_occlusion_closed_case() -> None:
    # Camera at the origin looking along +z; a vertical capsule body at z = 1000 hides a joint at z = 2000.
    body = np.zeros((1, 1, 32, 3))
    body[0, 0, :, 2] = 1000.0
    body[0, 0, :, 1] = np.linspace(-800.0, 800.0, 32)
    target = np.zeros((1, 32, 3))
    target[0, :, 2] = 2000.0
    target[0, :, 0] = 0.0
    target[0, J["PELVIS"], 0] = 1000.0  # this one is far to the side: visible
    radii = load_profile().capsule_radius_mm
    hidden = other_person_occlusion(target, body, radii, 40.0)
    assert not hidden[0, J["PELVIS"]] and hidden[0, J["NECK"]]
    absent = other_person_occlusion(target, np.full_like(body, np.nan), radii, 40.0)
    assert not absent.any()


def test_slots_are_shuffled_and_ids_unique_per_sensor() -> None:
    observations = simulate_scenario(crossing_scenario(duration_s=3.0), load_profile(), seed=0)
    persons = observations.person_of_body
    first_slot = persons[:, :, 0]
    assert (first_slot == 0).any() and (first_slot == 1).any()  # order differs from frame to frame
    ids = observations.body_ids
    both = observations.valid.all(axis=2)
    assert (ids[both][:, 0] != ids[both][:, 1]).all()  # simultaneous bodies never share an id
    # one id is one person (ids are never reused within a sensor)
    for s in range(observations.n_sensors):
        v = observations.valid[:, s]
        pairs = set(zip(ids[:, s][v].tolist(), persons[:, s][v].tolist(), strict=True))
        assert len({i for i, _ in pairs}) == len(pairs)
    assert (observations.body_ids[~observations.valid] == -1).all()
    assert np.isnan(observations.positions[~observations.valid]).all()


def test_walkers_turn_round_over_most_of_a_second_not_in_one_frame() -> None:
    # The crossing walkers reverse at x = +-1400 mm every 3 s; the enter/leave walker stops and walks back
    # out. A turnaround must take >= 0.5 s (real people: about 1 s): a body turned round in one frame
    # mirrors every view at once, which no tracker or fusion meets (it made eval tracking's crossing RMSE
    # 57 mm instead of ~20 mm).
    motions = [*crossing_scenario(duration_s=8.0).motions, enter_leave_scenario(duration_s=10.0).motions[1]]
    for motion in motions:
        facing = facing_deg(motion.positions)
        step = np.abs((np.diff(facing) + 180.0) % 360.0 - 180.0)  # degrees per frame
        turned = np.abs((facing[-1] - facing[0] + 180.0) % 360.0 - 180.0)
        assert step.max() < 180.0 / (0.5 * motion.fps) * 1.6, f"{motion.name}: {step.max():.0f} deg in one frame"
        reversals = np.abs((facing[45:] - facing[:-45] + 180.0) % 360.0 - 180.0) > 150.0  # over 1.5 s
        assert reversals.any() or turned > 150.0, f"{motion.name}: the walker never turned round"


def test_a_take_shorter_than_the_turning_window_still_walks() -> None:
    # 0.5 s is 15 frames, shorter than the 0.8 s turning window: the heading's smoothing kernel is cut to the
    # take (np.convolve's "same" mode returns the longer of its two inputs, which broke place_on_path).
    motions = crossing_scenario(duration_s=0.5).motions
    assert all(m.positions.shape[0] == 15 and np.isfinite(m.positions).all() for m in motions)
