"""Left/right realignment: mirrored views fixed, correct views untouched, vectorized == per-sensor loop;
the temporal mode on constructed cold starts, recoveries and turns."""

from dataclasses import replace

import numpy as np

from skelfuse.eval.metrics import swap_counts
from skelfuse.fusion import Fuser, fuse, init_state, preset
from skelfuse.fusion.mirror import pair_costs
from skelfuse.fusion.realign import (
    _swap_pairs,
    realign_body,
    realign_paper,
    realign_temporal,
    reference_positions,
)
from skelfuse.fusion.reference.realign import teleported
from skelfuse.schema.skeleton import MIRROR, N_JOINTS, PAPER_REALIGN_PAIRS, Confidence, J

RNG_SEED = 20220418


def _skeleton(rng: np.random.Generator) -> np.ndarray:
    """A body-like skeleton: left joints at x < 0, right joints at x > 0, 300 mm apart."""
    skel = rng.normal(0.0, 30.0, (N_JOINTS, 3))
    skel[PAPER_REALIGN_PAIRS[:, 0], 0] -= 150.0
    skel[PAPER_REALIGN_PAIRS[:, 1], 0] += 150.0
    return skel


def _views(rng, n_sensors=5, mirrored=(), noise=10.0):
    truth = _skeleton(rng)
    pos = truth + rng.normal(0.0, noise, (1, n_sensors, N_JOINTS, 3))
    for s in mirrored:
        pos[0, s] = pos[0, s, MIRROR]
    conf = np.full((1, n_sensors, N_JOINTS), int(Confidence.MEDIUM), dtype=np.uint8)
    return truth, pos, conf


def test_mirrored_view_is_fixed_and_correct_views_left_alone():
    rng = np.random.default_rng(RNG_SEED)
    _, pos, conf = _views(rng, mirrored=(2,))
    out, out_conf, swapped = realign_paper(pos, conf)
    assert swapped[0, 2].all() and not swapped[0, [0, 1, 3, 4]].any()
    expected = pos.copy()
    expected[0, 2, PAPER_REALIGN_PAIRS.ravel()] = pos[0, 2, PAPER_REALIGN_PAIRS[:, ::-1].ravel()]
    np.testing.assert_array_equal(out, expected)
    assert out_conf.shape == conf.shape


def test_correct_views_come_back_unchanged():
    rng = np.random.default_rng(RNG_SEED + 1)
    _, pos, conf = _views(rng)
    out, out_conf, swapped = realign_paper(pos, conf)
    assert not swapped.any()
    np.testing.assert_array_equal(out, pos)
    np.testing.assert_array_equal(out_conf, conf)


def test_swap_applied_twice_is_identity():
    rng = np.random.default_rng(RNG_SEED + 2)
    pos = rng.normal(size=(2, 4, N_JOINTS, 3))
    conf = rng.integers(0, 3, (2, 4, N_JOINTS)).astype(np.uint8)
    flags = rng.random((2, 4, len(PAPER_REALIGN_PAIRS))) < 0.5
    left, right = PAPER_REALIGN_PAIRS[:, 0], PAPER_REALIGN_PAIRS[:, 1]
    once = _swap_pairs(pos, conf, flags, left, right)
    twice = _swap_pairs(*once, flags, left, right)
    np.testing.assert_array_equal(twice[0], pos)
    np.testing.assert_array_equal(twice[1], conf)
    assert not np.array_equal(once[0], pos)


def _loop_reference(pos, conf, j):
    ok = [s for s in range(pos.shape[0]) if not np.isnan(pos[s, j, 0])]
    if not ok:
        return None
    tiers = {s: min(int(conf[s, j]), 2) for s in ok}
    best = max(tiers.values())
    return np.mean([pos[s, j] for s in ok if tiers[s] == best], axis=0)


def _loop_realign_paper(pos, conf):
    out, out_conf = pos.copy(), conf.copy()
    for left, right in PAPER_REALIGN_PAIRS:
        ref = _loop_reference(pos, conf, right)
        for s in range(pos.shape[0]):
            if ref is None or np.isnan(pos[s, left, 0]) or np.isnan(pos[s, right, 0]):
                continue
            if np.linalg.norm(ref - pos[s, right]) > np.linalg.norm(ref - pos[s, left]):
                out[s, [left, right]] = pos[s, [right, left]]
                out_conf[s, [left, right]] = conf[s, [right, left]]
    return out, out_conf


def test_vectorized_equals_per_sensor_loop_on_random_views():
    rng = np.random.default_rng(RNG_SEED + 3)
    for _ in range(40):
        n_sensors = int(rng.integers(1, 7))
        truth = _skeleton(rng)
        pos = truth + rng.normal(0.0, 60.0, (3, n_sensors, N_JOINTS, 3))
        flip = rng.random((3, n_sensors)) < 0.3
        pos[flip] = pos[flip][:, MIRROR]
        pos[rng.random(pos.shape[:3]) < 0.2] = np.nan
        conf = rng.integers(0, 3, pos.shape[:3]).astype(np.uint8)
        out, out_conf, _ = realign_paper(pos, conf)
        for b in range(3):
            exp, exp_conf = _loop_realign_paper(pos[b], conf[b])
            np.testing.assert_array_equal(out[b], exp)
            np.testing.assert_array_equal(out_conf[b], exp_conf)


def test_reference_prefers_medium_then_low_and_is_nan_without_candidates():
    pos = np.full((1, 3, N_JOINTS, 3), np.nan)
    conf = np.zeros((1, 3, N_JOINTS), dtype=np.uint8)
    pos[0, :, 0] = [[0.0, 0, 0], [10.0, 0, 0], [100.0, 0, 0]]
    conf[0, :, 0] = [2, 3, 1]  # HIGH counts as MEDIUM: mean of the first two
    pos[0, :, 1] = [[0.0, 0, 0], [20.0, 0, 0], [np.nan] * 3]
    conf[0, :, 1] = [1, 1, 2]  # the MEDIUM one is missing: mean of the LOW ones
    ref = reference_positions(pos, conf)
    np.testing.assert_allclose(ref[0, 0], [5.0, 0, 0])
    np.testing.assert_allclose(ref[0, 1], [10.0, 0, 0])
    assert np.isnan(ref[0, 2:]).all()


def test_missing_joint_never_swaps():
    rng = np.random.default_rng(RNG_SEED + 4)
    _, pos, conf = _views(rng, mirrored=(1,))
    pos[0, 1, PAPER_REALIGN_PAIRS[:, 0]] = np.nan  # mirrored view lost its left joints: undecidable
    out, _, swapped = realign_paper(pos, conf)
    assert not swapped[0, 1].any()
    np.testing.assert_array_equal(out[0, 1], pos[0, 1])


def test_body_mode_mirrors_whole_skeleton_when_reference_is_contaminated():
    # 2 of 4 views mirrored: the paper's per-pair reference sits between left and right; the whole-body
    # vote with a recomputed reference still finds one consistent labelling.
    rng = np.random.default_rng(RNG_SEED + 5)
    truth, pos, conf = _views(rng, n_sensors=4, mirrored=(2, 3), noise=5.0)
    conf[0, :2] = int(Confidence.MEDIUM)
    conf[0, 2:] = int(Confidence.LOW)  # the mirrored ones are less sure: the reference leans to the truth
    out, out_conf, mirrored = realign_body(pos, conf)
    assert mirrored[0].tolist() == [False, False, True, True]
    np.testing.assert_array_equal(out[0, 2], pos[0, 2, MIRROR])  # hands, feet, face swapped too
    np.testing.assert_array_equal(out_conf[0, 2], conf[0, 2, MIRROR])
    spread = np.abs(out[0] - truth).max()
    assert spread < 50.0


def test_body_mode_leaves_correct_views_alone():
    rng = np.random.default_rng(RNG_SEED + 6)
    _, pos, conf = _views(rng)
    out, _, mirrored = realign_body(pos, conf)
    assert not mirrored.any()
    np.testing.assert_array_equal(out, pos)


# ----------------------------------------------------------------------------------------------------------
# realign="temporal": whole-body flips against the previous merged skeleton


def _facing_skeleton(rng: np.random.Generator, facing_deg: float) -> np.ndarray:
    """:func:`_skeleton` (facing +y: its right side at +x) turned about the vertical z axis to ``facing_deg``
    (counter-clockwise from +x)."""
    angle = np.radians(facing_deg - 90.0)
    rotation = np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0, 0, 1]])
    return _skeleton(rng) @ rotation.T


def _rig_views(truth, facing_deg, rng, noise=8.0, sensors_deg=(45.0, 135.0, 225.0, 315.0)):
    """Four views; a view more than 110 deg from the facing is mirrored and sees face and hands LOW."""
    away = np.abs((np.asarray(sensors_deg) - facing_deg + 180.0) % 360.0 - 180.0) > 110.0
    pos = truth + rng.normal(0.0, noise, (1, len(sensors_deg), N_JOINTS, 3))
    conf = np.full((1, len(sensors_deg), N_JOINTS), int(Confidence.MEDIUM), dtype=np.uint8)
    pos[0, away] = pos[0, away][:, MIRROR]
    conf[0, away, 20:] = int(Confidence.LOW)  # ankles, feet, face: occluded from behind
    return pos, conf, away


FOUR_VIEW_ANCHOR = np.array([[0, 0, 4]], dtype=np.int32)
"""Counters of a body whose anchor was built from four views: no disagreement streak yet."""


def test_temporal_cold_start_two_versus_two_picks_the_group_with_more_medium_evidence():
    rng = np.random.default_rng(RNG_SEED + 7)
    truth = _facing_skeleton(rng, 0.0)  # views at 135 and 225 deg see the back
    pos, conf, away = _rig_views(truth, 0.0, rng)
    assert away.tolist() == [False, True, True, False]
    no_previous = np.full((1, N_JOINTS, 3), np.nan)
    _, _, mirrored, streak = realign_temporal(pos, conf, no_previous, np.zeros((1, 3), np.int32))
    assert mirrored[0].tolist() == away.tolist() and streak.tolist() == [[0, 0, 4, 0]]
    # Same views, but the mirrored pair now holds more MEDIUM joints: evidence sides with them (documented
    # limit of a cold start; the anchor then keeps that choice until a clear majority disagrees).
    conf_swapped = conf[:, [1, 0, 3, 2]]
    _, _, mirrored, _ = realign_temporal(pos, conf_swapped, no_previous, np.zeros((1, 3), np.int32))
    assert mirrored[0].tolist() == [True, False, False, True]


def test_temporal_anchor_decides_a_two_versus_two_split_the_static_vote_cannot():
    rng = np.random.default_rng(RNG_SEED + 8)
    truth = _facing_skeleton(rng, 0.0)
    pos, conf, away = _rig_views(truth, 0.0, rng)
    conf[:] = int(Confidence.MEDIUM)  # no confidence hint at all
    _, _, mirrored, _ = realign_temporal(pos, conf, truth[None] + 20.0, FOUR_VIEW_ANCHOR)
    assert mirrored[0].tolist() == away.tolist()
    # The anchor mirrored: every view is realigned to it (the recovery counter does not move on 2 vs 2).
    _, _, mirrored, streak = realign_temporal(pos, conf, truth[MIRROR][None], FOUR_VIEW_ANCHOR)
    assert mirrored[0].tolist() == (~away).tolist() and streak.tolist() == [[0, 0, 4, 0]]


def test_temporal_falls_back_to_the_static_reference_for_pairs_the_previous_lacks():
    rng = np.random.default_rng(RNG_SEED + 9)
    truth = _facing_skeleton(rng, 45.0)
    pos, conf, away = _rig_views(truth, 45.0, rng)
    previous = np.full((1, N_JOINTS, 3), np.nan)
    previous[0, PAPER_REALIGN_PAIRS[0]] = truth[PAPER_REALIGN_PAIRS[0]]  # only the shoulders are known
    _, _, mirrored, _ = realign_temporal(pos, conf, previous, FOUR_VIEW_ANCHOR)
    assert mirrored[0].tolist() == away.tolist()


def test_temporal_recovers_from_a_mirrored_anchor_after_recovery_frames():
    # The anchor is deliberately mirrored; 3 of 4 views are correct: the body follows them on frame N.
    rng = np.random.default_rng(RNG_SEED + 10)
    truth = _facing_skeleton(rng, 45.0)  # only the view at 225 deg sees the back
    params = replace(preset("A4"), realign="temporal", recovery_frames=4)
    state = init_state(1, params)
    state.previous = truth[MIRROR][None].astype(np.float64)
    state.flip_counters = FOUR_VIEW_ANCHOR.copy()
    for frame in range(1, 8):
        pos, conf, away = _rig_views(truth, 45.0, rng)
        assert away.sum() == 1
        result, state = fuse(pos, conf, state, params)
        n_swapped, n_valid = swap_counts(result.positions, truth[None], PAPER_REALIGN_PAIRS)
        assert n_valid.all()
        if frame < params.recovery_frames:
            assert n_swapped.all(), f"frame {frame}: followed the majority too early"
            assert state.flip_counters.tolist() == [[frame, frame, 4, 0]]
        else:
            assert not n_swapped.any(), f"frame {frame}: still mirrored"
            assert state.flip_counters.tolist() == [[0, 0, 4, 0]]


def test_temporal_undoes_a_wrong_start_in_a_two_versus_two_split_after_majority_frames():
    # A body first seen only from behind leaves a mirrored anchor; then the two front views join. The
    # clear-majority rule never fires on 2 against 2, but the front views hold more MEDIUM evidence, so
    # the slow simple-majority rule follows them on frame N.
    rng = np.random.default_rng(RNG_SEED + 13)
    truth = _facing_skeleton(rng, 0.0)
    params = replace(preset("A4"), realign="temporal", recovery_frames=10, majority_recovery_frames=5)
    state = init_state(1, params)
    state.previous = truth[MIRROR][None].astype(np.float64)
    state.flip_counters = FOUR_VIEW_ANCHOR.copy()
    for frame in range(1, 8):
        pos, conf, away = _rig_views(truth, 0.0, rng)
        assert away.tolist() == [False, True, True, False]
        result, state = fuse(pos, conf, state, params)
        n_swapped, n_valid = swap_counts(result.positions, truth[None], PAPER_REALIGN_PAIRS)
        assert n_valid.all()
        if frame < params.majority_recovery_frames:
            assert n_swapped.all(), f"frame {frame}: followed the majority too early"
            assert state.flip_counters.tolist() == [[0, frame, 4, 0]]
        else:
            assert not n_swapped.any(), f"frame {frame}: still mirrored"


def test_temporal_starts_cold_again_when_more_views_see_the_body_than_built_its_anchor():
    # First seen by the two rear views only (both mirrored, so the anchor is mirrored); when the two front
    # views join, the body starts cold again and the group with more MEDIUM evidence (the front) wins.
    rng = np.random.default_rng(RNG_SEED + 14)
    truth = _facing_skeleton(rng, 0.0)
    params = replace(preset("A4"), realign="temporal", recovery_frames=10, majority_recovery_frames=None)
    state = init_state(1, params)
    for frame in range(4):
        pos, conf, away = _rig_views(truth, 0.0, rng)
        if frame < 2:
            pos[:, ~away] = np.nan
        result, state = fuse(pos, conf, state, params)
        n_swapped, _ = swap_counts(result.positions, truth[None], PAPER_REALIGN_PAIRS)
        assert n_swapped.all() == (frame < 2), f"frame {frame}"
        assert state.flip_counters[0, 2] == (2 if frame < 2 else 4)


def test_temporal_follows_a_person_turning_around():
    # Four sensors, a person turning 6 deg per frame through two full turns; each view more than 110 deg
    # from the facing is mirrored. The fused labels stay right in every frame.
    rng = np.random.default_rng(RNG_SEED + 11)
    body = _skeleton(rng)
    params = replace(preset("A4"), realign="temporal")
    fuser = Fuser(params)
    flipped_views = 0
    for frame in range(120):
        facing = 90.0 + 6.0 * frame
        angle = np.radians(facing - 90.0)
        rotation = np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0, 0, 1]])
        truth = body @ rotation.T
        pos, conf, away = _rig_views(truth, facing, rng)
        flipped_views += int(away.sum())
        result = fuser.step(pos, conf)
        n_swapped, n_valid = swap_counts(result.positions, truth[None], PAPER_REALIGN_PAIRS)
        assert n_valid.all() and not n_swapped.any(), f"frame {frame}, facing {facing % 360:.0f} deg"
    assert flipped_views > 100  # the test did see mirrored views


def test_temporal_two_wild_arms_do_not_outvote_shoulders_hips_and_legs():
    # Arms spread wide (wrists 1400 mm apart): a view whose occlusion guesses put both arms on the wrong
    # sides costs 2 x 1400 + 2 x 900 mm more kept than swapped, more than the other four pairs (about
    # 2 x 300 mm each) cost swapped. Each pair's vote is bounded by twice the anchor's width of that pair
    # (triangle inequality), so after dividing by it every pair weighs at most 1: 4 pairs against 2.
    rng = np.random.default_rng(RNG_SEED + 13)
    truth = _skeleton(rng)
    for name, half_width in (("ELBOW", 450.0), ("WRIST", 700.0)):
        truth[J[f"{name}_LEFT"], 0], truth[J[f"{name}_RIGHT"], 0] = -half_width, half_width
    pos = truth + rng.normal(0.0, 8.0, (1, 3, N_JOINTS, 3))
    conf = np.full((1, 3, N_JOINTS), int(Confidence.MEDIUM), dtype=np.uint8)
    for name in ("ELBOW", "WRIST"):  # view 0: both arms guessed on the other side, and further out
        left, right = J[f"{name}_LEFT"], J[f"{name}_RIGHT"]
        pos[0, 0, [left, right]] = pos[0, 0, [right, left]] * np.array([1.3, 1.0, 1.0])
    pos[0, 2] = pos[0, 2, MIRROR]  # view 2: a whole mirrored skeleton, which must still be flipped
    _, _, mirrored, _ = realign_temporal(pos, conf, truth[None] + 15.0, np.array([[0, 0, 3]], np.int32))
    assert mirrored[0].tolist() == [False, False, True]
    # The same view judged by the summed millimetres (realign_body's measure) would have been flipped:
    keep, swap = pair_costs(
        pos[:, :, PAPER_REALIGN_PAIRS[:, 0]],
        pos[:, :, PAPER_REALIGN_PAIRS[:, 1]],
        truth[None, None, PAPER_REALIGN_PAIRS[:, 0]] + 15.0,
        truth[None, None, PAPER_REALIGN_PAIRS[:, 1]] + 15.0,
    )
    assert (swap - keep)[0, 0].sum() < 0.0


def test_temporal_without_mirrored_views_changes_nothing():
    rng = np.random.default_rng(RNG_SEED + 12)
    _, pos, conf = _views(rng)
    out, out_conf, mirrored, streak = realign_temporal(pos, conf, np.full((1, N_JOINTS, 3), np.nan), np.zeros((1, 3)))
    assert not mirrored.any() and streak.tolist() == [[0, 0, 5, 0]]  # five views
    np.testing.assert_array_equal(out, pos)
    np.testing.assert_array_equal(out_conf, conf)


def test_temporal_starts_cold_when_the_body_teleports_and_not_when_it_walks():
    # A looped take's seam: the body is 300 mm further on and turned round in one frame, so the anchor (last
    # frame's skeleton) holds its left where the body's right now is. Views at 45/315 deg see the front
    # (correct), 135/225 the back (mirrored). Against the stale anchor every view decides wrong; the
    # teleport rule forgets the anchor and the cold start picks the front pair (more MEDIUM evidence).
    truth = _facing_skeleton(np.random.default_rng(RNG_SEED + 15), 0.0)
    before = _facing_skeleton(np.random.default_rng(RNG_SEED + 15), 180.0) + np.array([300.0, 0.0, 0.0])
    pos, conf, away = _rig_views(truth, 0.0, np.random.default_rng(RNG_SEED + 16))
    assert away.tolist() == [False, True, True, False]
    _, _, mirrored, _ = realign_temporal(pos, conf, before[None], FOUR_VIEW_ANCHOR)
    assert mirrored[0].tolist() == (~away).tolist()  # without the rule: all four decided wrong
    _, _, mirrored, streak = realign_temporal(pos, conf, before[None], FOUR_VIEW_ANCHOR, max_jump_mm=200.0)
    assert mirrored[0].tolist() == away.tolist() and streak.tolist() == [[0, 0, 4, 0]]
    # A walking step (60 mm, no turn) is no teleport: the anchor decides as before.
    walked = truth + np.array([60.0, 0.0, 0.0])
    assert not teleported(pos, walked[None], 200.0).any()
    assert teleported(pos, before[None], 200.0).all()
    _, _, mirrored, _ = realign_temporal(pos, conf, walked[None], FOUR_VIEW_ANCHOR, max_jump_mm=200.0)
    assert mirrored[0].tolist() == away.tolist()


def test_a_teleport_is_a_jump_of_every_view_and_unknown_centres_never_jump():
    rng = np.random.default_rng(RNG_SEED + 16)
    truth = _facing_skeleton(rng, 0.0)
    pos, _, _ = _rig_views(truth, 0.0, rng)
    pos[0, 0] += 1000.0  # one view of someone else far away: the other views did not jump
    assert not teleported(pos, truth[None], 200.0).any()
    assert not teleported(pos[:, :2], truth[None], 200.0).any()  # two views: their mean moved 500 mm, no jump
    assert teleported(pos[:, :1], truth[None], 200.0).all()  # the only view jumped
    no_hips = truth.copy()
    no_hips[J["HIP_LEFT"]] = np.nan
    assert not teleported(pos + 500.0, no_hips[None], 200.0).any()  # anchor centre unknown
    assert not teleported(np.full_like(pos, np.nan), truth[None], 200.0).any()  # no view has a centre
