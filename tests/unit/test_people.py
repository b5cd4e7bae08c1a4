"""PeopleFuser: multi-person fusion against the single-person pipeline (oracle) and the bystander case."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.fusion.people import PeopleFuser
from skelfuse.fusion.pipeline import Fuser
from skelfuse.fusion.presets import preset
from skelfuse.sim.crowd import bystander_scenario, simulate_scenario
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.rig import paper_rig


@pytest.mark.parametrize("name", ["skelfuse", "A5"])
def test_one_person_equals_the_pipeline(name: str) -> None:
    params = preset(name)
    observations = simulate(make_gesture("squat", duration_s=2.0, seed=1), paper_rig(4), load_profile(), seed=1)
    world = observations.positions_world(calibrated=True)  # (T, S, J, 3)
    people = PeopleFuser(params, birth_frames=1)
    oracle = Fuser(params, n_bodies=1)
    for t in range(observations.n_frames):
        valid = observations.tracked[t][:, None]
        result = people.step(world[t][:, None], observations.confidence[t][:, None], valid, observations.times_s[t])
        expected = oracle.step(world[t][None], observations.confidence[t][None], 1.0 / 30.0)
        assert result.track_ids.tolist() == [1]
        assert (result.assignment[valid] == 0).all()
        np.testing.assert_allclose(result.positions, expected.positions, atol=1e-9)
        np.testing.assert_array_equal(result.n_agree, expected.n_agree)
        np.testing.assert_array_equal(result.contributors, expected.contributors)


def test_bystander_is_never_merged_into_the_subject() -> None:
    observations = simulate_scenario(bystander_scenario(duration_s=2.0, seed=0), load_profile(), seed=0)
    world = observations.positions_world(calibrated=True)
    fuser = PeopleFuser(preset("skelfuse"))
    owner: dict[int, set[int]] = {0: set(), 1: set()}
    for t in range(observations.n_frames):
        result = fuser.step(world[t], observations.confidence[t], observations.valid[t], observations.times_s[t])
        persons = observations.person_of_body[t]
        for p in (0, 1):
            owner[p] |= set(result.body_track_ids[persons == p].tolist()) - {-1}
    assert observations.valid[..., :].sum(axis=(0, 2))[np.argmax(observations.valid.sum(axis=(0, 2)))] > 0
    assert len(owner[0]) == 1 and len(owner[1]) == 1 and owner[0] != owner[1]
    assert result.n_persons == 2
    bystander_row = int(np.nonzero(result.track_ids == next(iter(owner[1])))[0][0])
    assert result.contributors[bystander_row].sum() == 1  # fused from its one sensor only


def test_time_must_increase() -> None:
    fuser = PeopleFuser(preset("skelfuse"))
    empty = (np.full((2, 1, 32, 3), np.nan), np.zeros((2, 1, 32), np.uint8), np.zeros((2, 1), bool))
    result = fuser.step(*empty, 0.0)
    assert result.n_persons == 0 and result.positions.shape == (0, 32, 3)
    with pytest.raises(ValueError, match="increase"):
        fuser.step(*empty, 0.0)


def test_coasting_tracks_with_orientations_are_fused_when_no_body_is_seen() -> None:
    """Regression: the orientation gather sized its row map by the highest row a body took, so a frame where
    two confirmed tracks coast (nobody seen) raised IndexError instead of predicting both."""
    pose = make_gesture("squat", duration_s=0.2, seed=1).positions[0]  # (J, 3) world mm
    bodies = np.stack([pose, pose + np.array([2000.0, 0.0, 0.0])])  # two people 2 m apart
    quats = np.zeros((2, 2, 32, 4))
    quats[..., 0] = 1.0
    world = np.stack([bodies, bodies])  # (S=2, B=2, J, 3): both sensors see both
    conf = np.full((2, 2, 32), 2, np.uint8)
    fuser = PeopleFuser(preset("skelfuse"), birth_frames=1)
    seen = fuser.step(world, conf, np.ones((2, 2), bool), 0.0, world_orientations=quats)
    assert seen.track_ids.tolist() == [1, 2]
    nobody = fuser.step(
        np.full_like(world, np.nan), np.zeros_like(conf), np.zeros((2, 2), bool), 1 / 30, world_orientations=quats
    )
    assert nobody.track_ids.tolist() == [1, 2] and nobody.coasting.all()
    np.testing.assert_allclose(nobody.positions, seen.positions, atol=50.0)  # predicted, not lost
    assert nobody.orientations is not None and np.isfinite(nobody.orientations[:, 0]).all()
