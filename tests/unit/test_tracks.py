"""Track life cycle: birth, coasting, death, id stability (skelfuse.fusion.tracks via PeopleFuser)."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.eval.tracking import clear_mot, run_people
from skelfuse.fusion.people import PeopleFuser
from skelfuse.fusion.pipeline import init_state
from skelfuse.fusion.presets import preset
from skelfuse.fusion.tracks import TrackParams, TrackTable, split_state, stack_states
from skelfuse.schema.skeleton import N_JOINTS, Confidence
from skelfuse.sim.crowd import crossing_scenario, simulate_scenario
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.observe import load_profile

POSE = make_gesture("hands_up_down", duration_s=0.1, seed=0).positions[0]
DT = 1.0 / 30.0


def frame(xys: list[tuple[float, float] | None], n_sensors: int = 2, seed: int = 0):
    """Every sensor sees every listed person (None = nobody there)."""
    rng = np.random.default_rng(seed)
    people = [xy for xy in xys if xy is not None]
    B = max(len(people), 1)
    positions = np.full((n_sensors, B, N_JOINTS, 3), np.nan)
    confidence = np.zeros((n_sensors, B, N_JOINTS), dtype=np.uint8)
    valid = np.zeros((n_sensors, B), dtype=bool)
    for s in range(n_sensors):
        for b, xy in enumerate(people):
            body = POSE.copy()
            body[:, :2] += np.asarray(xy) - POSE[0, :2]
            positions[s, b] = body + rng.normal(0.0, 5.0, (N_JOINTS, 3))
            confidence[s, b] = Confidence.MEDIUM
            valid[s, b] = True
    return positions, confidence, valid


def run(fuser: PeopleFuser, xys_per_frame: list[list], start_frame: int = 0) -> list[list[int]]:
    out = []
    for k, xys in enumerate(xys_per_frame):
        result = fuser.step(*frame(xys, seed=k), (start_frame + k) * DT)
        out.append(result.track_ids.tolist())
    return out


def test_birth_after_consecutive_frames() -> None:
    fuser = PeopleFuser(preset("skelfuse"), birth_frames=3)
    ids = run(fuser, [[(0.0, 0.0)]] * 5)
    assert ids == [[], [], [1], [1], [1]]


def test_tentative_track_dies_on_a_miss_and_its_id_is_not_reused() -> None:
    fuser = PeopleFuser(preset("skelfuse"), birth_frames=3)
    ids = run(fuser, [[(0.0, 0.0)], [(0.0, 0.0)], [None], [(0.0, 0.0)], [(0.0, 0.0)], [(0.0, 0.0)]])
    assert ids == [[], [], [], [], [], [2]]


def test_survives_a_short_gap_and_dies_after_the_timeout() -> None:
    fuser = PeopleFuser(preset("skelfuse"), birth_frames=1, timeout_s=0.5)
    seen = [[(0.0, 0.0)]] * 3
    ids = run(fuser, seen + [[None]] * 10 + seen)  # gap 10 frames = 0.33 s < 0.5 s
    assert all(i == [1] for i in ids)
    ids = run(fuser, [[None]] * 20 + seen, start_frame=16)  # gap 0.67 s > 0.5 s
    assert ids[:15] == [[1]] * 15 and ids[15:20] == [[]] * 5
    assert ids[20:] == [[2]] * 3  # a new id, never 1 again


def test_coasting_prediction_follows_a_walker_through_a_gap() -> None:
    fuser = PeopleFuser(preset("skelfuse"), birth_frames=1, timeout_s=1.0)
    speed = 1200.0  # mm/s along x
    xs = [(k * DT * speed, 0.0) for k in range(60)]
    frames = [[xy] if not 20 <= k < 32 else [None] for k, xy in enumerate(xs)]  # 0.4 s unseen, 480 mm walked
    ids = run(fuser, frames)
    assert {i for row in ids for i in row} == {1}
    assert fuser.table.tracks[1].velocity[0] == pytest.approx(speed, rel=0.1)


def test_ids_do_not_swap_when_two_people_cross_350_mm_apart() -> None:
    scenario = crossing_scenario(lateral_mm=350.0, duration_s=3.5, seed=2)  # they cross at 1.5 s
    observations = simulate_scenario(scenario, load_profile(), seed=2)
    hyp_ids, hyp_pos, _ = run_people(observations, PeopleFuser(preset("skelfuse")))
    metrics = clear_mot(observations.truth, observations.present & observations.visible, hyp_ids, hyp_pos)
    assert metrics.id_switches == 0 and metrics.n_track_ids == 2
    assert metrics.idf1 > 0.95


def test_track_params_validation() -> None:
    with pytest.raises(ValueError, match="birth_frames"):
        TrackParams(birth_frames=0)
    with pytest.raises(ValueError, match="max_gate_mm"):
        TrackParams(gate_mm=500.0, max_gate_mm=400.0)


def test_stack_and_split_states_round_trip() -> None:
    params = preset("skelfuse")
    a, b = init_state(1, params), init_state(2, params)
    a.previous[:] = 1.0
    b.x[:] = 2.0
    stacked = stack_states([a, b])
    assert stacked.n_bodies == 3
    parts = split_state(stacked)
    np.testing.assert_array_equal(parts[0].previous, a.previous)
    np.testing.assert_array_equal(parts[2].x, b.x[1:])


def test_empty_table_predicts_nothing() -> None:
    prediction = TrackTable().predict(0.0)
    assert prediction.descriptors.shape == (0, 7, 3) and prediction.track_ids.size == 0
