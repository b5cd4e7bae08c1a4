"""``eval real``'s per-view mirrored share: against the simulator's own mirroring flags, and on a hand-made
three-view take whose mirrored frames are known."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.eval.view_mirroring import view_mirroring
from skelfuse.schema.skeleton import MIRROR, N_JOINTS, Confidence
from skelfuse.sim import load_profile, make_gesture, paper_rig, simulate


@pytest.mark.parametrize("seed", [0, 2])
def test_the_realigned_share_is_the_simulators_mirrored_share(seed: int) -> None:
    """A walking take seen by 3 sensors, rear views mirrored by the simulator: per view, the share of instants
    the realignment found mirrored is the share the simulator mirrored (measured: equal to 3 decimals)."""
    motion = make_gesture("walking", duration_s=6.0, seed=seed, facing_deg=40.0 * seed)
    obs = simulate(motion, paper_rig(3), load_profile(), seed=seed)
    world = np.where(obs.tracked[..., None, None], obs.positions_world(calibrated=True), np.nan)
    shares = view_mirroring(world, obs.confidence, obs.sensor_ids, obs.world_from_sensor_calibrated[:, :3, 3])
    truth = (obs.mirrored & obs.tracked).sum(axis=0) / obs.tracked.sum(axis=0)
    assert truth.max() > 0.05  # the take does hold mirrored rear views
    for s, sensor_id in enumerate(obs.sensor_ids):
        assert shares[sensor_id]["realigned"] == pytest.approx(truth[s], abs=0.03)


def test_a_view_mirrored_in_a_quarter_of_the_instants_is_counted_against_the_majority() -> None:
    """Three identical views of a person, two in front and one behind; the rear view has its left/right labels
    swapped in 10 of 40 instants (a rear view is where trackers mirror): it points against the majority in
    exactly those, and the realignment finds exactly those; the front views never."""
    motion = make_gesture("hands_up_down", duration_s=40 / 30, seed=0, facing_deg=0.0)
    truth = motion.positions[:40]
    world = np.repeat(truth[:, None], 3, axis=1).copy()
    world[10:20, 2] = world[10:20, 2][:, MIRROR]
    confidence = np.full((40, 3, N_JOINTS), int(Confidence.MEDIUM), np.uint8)
    sensors = np.array([[3000.0, 0.0, 1000.0], [2500.0, 1500.0, 1000.0], [-3000.0, 0.0, 1000.0]])
    shares = view_mirroring(world, confidence, ("a", "b", "c"), sensors)
    assert shares["c"]["against_majority"] == pytest.approx(0.25)
    assert shares["a"]["against_majority"] == shares["b"]["against_majority"] == 0.0
    assert shares["c"]["realigned"] == pytest.approx(0.25)
    assert shares["a"]["realigned"] == 0.0 and shares["c"]["instants"] == 40
