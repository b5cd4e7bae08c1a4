"""The simulator's tracker-loss family: upside down, then re-acquired elsewhere under new body ids."""

import numpy as np

from skelfuse.schema.skeleton import J
from skelfuse.sim.failures import family_profile
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.rig import paper_rig
from skelfuse.sim.tracker_loss import tracker_loss_episodes

SEED = 350


def test_episodes_have_their_phases_and_new_ids():
    rng = np.random.default_rng(SEED)
    tracked = np.ones(400, dtype=bool)
    flipped, away, starts = tracker_loss_episodes(rng, tracked, 0.02, 3, 10)
    first = np.flatnonzero(starts)[0]
    assert flipped[first : first + 3].all() and not flipped[first + 3]
    assert away[first + 3 : first + 13].all() and starts[first + 3]
    assert not (flipped & away).any()
    assert not tracker_loss_episodes(rng, tracked, 0.0, 3, 10)[2].any()


def test_simulated_views_turn_upside_down_and_jump():
    motion = make_gesture("hands_up_down", duration_s=8.0, seed=SEED)
    rig = paper_rig(2)
    base = load_profile()
    profile = family_profile(base, "tracker_loss")
    clean = simulate(motion, rig, base, seed=SEED)
    lossy = simulate(motion, rig, profile, seed=SEED)
    world = lossy.positions_world(calibrated=False)
    clean_world = clean.positions_world(calibrated=False)
    up = world[..., J["NECK"], 2] - world[..., J["PELVIS"], 2]  # (T, S), world z up
    both = clean.tracked & lossy.tracked
    upside_down = both & (up < -300.0)
    assert upside_down.any()  # the family happened on this seed
    assert not (both & (clean_world[..., J["NECK"], 2] - clean_world[..., J["PELVIS"], 2] < 0)).any()
    shift = np.linalg.norm(world[..., J["PELVIS"], :] - clean_world[..., J["PELVIS"], :], axis=-1)
    assert (shift[both] > 300.0).sum() >= 10  # re-acquired ~350 mm away for 10 frames
    assert np.nanmax(shift[both]) < 400.0
    # Each episode brings two new body ids.
    assert lossy.body_ids.max() >= clean.body_ids.max() + 2
