"""The observation model against ground truth: statistics match the profile, behaviours where expected."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skelfuse.schema.errors import ConfigError
from skelfuse.schema.skeleton import BONES, MIRROR, Confidence, J
from skelfuse.sim.body_model import ar1, facing_away_deg, fit_body_model, segment_distance, student_t
from skelfuse.sim.gestures import forward_kinematics, make_gesture, rest_offsets
from skelfuse.sim.motion import Motion
from skelfuse.sim.observe import simulate
from skelfuse.sim.profile import SimProfile, default_profile_path, load_profile
from skelfuse.sim.rig import best_view_sensor, look_at, paper_rig

PROFILE = load_profile()
QUIET = {g: 0.0 for g in PROFILE.slow_sigma_mm}


def standing_still(n_frames: int, *, facing: float = 0.0) -> Motion:
    """A subject standing still in the rest pose at the origin, facing ``facing`` degrees."""
    pose = make_gesture("hands_up_down", duration_s=1.0, seed=0, facing_deg=facing).positions[0]
    return Motion("still", 30.0, np.broadcast_to(pose, (n_frames, 32, 3)).copy())


@pytest.fixture(scope="module")
def walking_obs():
    rig = [*paper_rig(), best_view_sensor(0.0)]
    return simulate(make_gesture("walking", duration_s=20.0, seed=2), rig, PROFILE, seed=11)


# ---- profile ------------------------------------------------------------------------------------------


def test_default_profile_is_packaged_and_matches_the_dataclass() -> None:
    assert default_profile_path().is_file()
    assert load_profile() == SimProfile()
    assert load_profile(default_profile_path()) == SimProfile()


@pytest.mark.parametrize(
    ("toml", "fragment"),
    [
        pytest.param("[noise]\nslow_rhoo = 0.9\n", "slow_rhoo", id="unknown-key"),
        pytest.param("[noise]\nfps = 30.0\n", "'fps'", id="key-in-wrong-section"),
        pytest.param("[nosie]\njump_prob = 0.1\n", "nosie", id="unknown-section"),
        pytest.param("[noise]\njump_prob = 'often'\n", "jump_prob", id="wrong-type"),
        pytest.param("[tracking]\nmin_torso_joints_in_view = 2.5\n", "min_torso_joints_in_view", id="not-int"),
        pytest.param("[noise]\nslow_rho = { torso = 1.5 }\n", "slow_rho", id="rho-range"),
        pytest.param("[noise]\nslow_rho = { belly = 0.5 }\n", "belly", id="unknown-group"),
        pytest.param("[noise]\nwhite_dof = 2.0\n", "white_dof", id="dof"),
        pytest.param("[noise\n", "not valid TOML", id="syntax"),
    ],
)
def test_bad_profile_names_key_and_file(tmp_path: Path, toml: str, fragment: str) -> None:
    path = tmp_path / "bad_profile.toml"
    path.write_text(toml)
    with pytest.raises(ConfigError, match=fragment) as info:
        load_profile(path)
    assert "bad_profile.toml" in str(info.value)


def test_partial_profile_keeps_defaults(tmp_path: Path) -> None:
    path = tmp_path / "p.toml"
    path.write_text("[noise]\nslow_sigma_mm = { torso = 7 }\n[timing]\ndropped_frame_prob = 0\n")
    profile = load_profile(path)
    assert profile.slow_sigma_mm["torso"] == 7.0
    assert profile.slow_sigma_mm["hand"] == PROFILE.slow_sigma_mm["hand"]
    assert profile.dropped_frame_prob == 0.0


# ---- building blocks against closed forms -------------------------------------------------------------


def test_ar1_has_the_requested_rho_and_sigma() -> None:
    rng = np.random.default_rng(1124)
    x = ar1(rng, 40_000, (2,), np.array([0.8, 0.94]), np.array([5.0, 9.0]))
    for k, (rho, sigma) in enumerate([(0.8, 5.0), (0.94, 9.0)]):
        assert np.std(x[:, k]) == pytest.approx(sigma, rel=0.06)
        assert np.corrcoef(x[:-1, k], x[1:, k])[0, 1] == pytest.approx(rho, abs=0.015)


def test_student_t_has_the_requested_sd_and_heavy_tails() -> None:
    x = student_t(np.random.default_rng(5), (200_000,), 2.0, 5.0)
    assert np.std(x) == pytest.approx(2.0, rel=0.05)
    kurtosis = np.mean((x / np.std(x)) ** 4)
    assert kurtosis > 4.0  # Gaussian: 3


def test_segment_distance_closed_forms() -> None:
    p0, p1 = np.zeros(3), np.array([10.0, 0, 0])
    distance, s = segment_distance(p0, p1, np.array([5.0, 3, -1]), np.array([5.0, 3, 1]))
    assert distance == pytest.approx(3.0) and s == pytest.approx(0.5)
    distance, s = segment_distance(p0, p1, np.array([13.0, 4, 0]), np.array([13.0, 4, 0]))  # a point
    assert distance == pytest.approx(5.0) and s == pytest.approx(1.0)
    distance, _ = segment_distance(p0, p1, np.array([2.0, 1, 0]), np.array([8.0, 1, 0]))  # parallel
    assert distance == pytest.approx(1.0)


# ---- determinism ---------------------------------------------------------------------------------------


def test_deterministic_per_seed_and_per_sensor_streams() -> None:
    motion = make_gesture("squat", duration_s=4.0, seed=0)
    rig = paper_rig()
    a = simulate(motion, rig, PROFILE, seed=7)
    b = simulate(motion, rig, PROFILE, seed=7)
    c = simulate(motion, rig, PROFILE, seed=8)
    for name in (
        "positions",
        "confidence",
        "body_ids",
        "device_time_us",
        "host_time_ns",
        "world_from_sensor_calibrated",
    ):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert np.nanmax(np.abs(a.positions - c.positions)) > 1.0
    # appending a sensor leaves the others' observations unchanged
    d = simulate(motion, [*rig, best_view_sensor(0.0)], PROFILE, seed=7)
    np.testing.assert_array_equal(d.positions[:, :4], a.positions)
    np.testing.assert_array_equal(d.confidence[:, :4], a.confidence)


# ---- error statistics ----------------------------------------------------------------------------------


def test_slow_error_matches_the_profile_over_a_long_run() -> None:
    profile = PROFILE.replace(jump_prob=0.0, convergence_sigma_mm=0.0, dropped_frame_prob=0.0)
    rig = [best_view_sensor(angle, sensor_id=f"front_{angle:+.0f}") for angle in (-40.0, -15.0, 15.0, 40.0)]
    obs = simulate(standing_still(4000), rig, profile, seed=3)
    assert obs.tracked.all() and not obs.occluded[:, :, J["PELVIS"]].any()
    world = obs.positions_world(calibrated=False)[:, :, J["PELVIS"]]  # the root: untouched by the body-model refit
    error = world - obs.truth[:, None, J["PELVIS"]]
    error = error - error.mean(axis=0)  # the constant per-view offsets
    series = error.reshape(error.shape[0], -1)  # 4 views x 3 axes, independent
    rho = profile.slow_rho["torso"]
    slow_var = profile.slow_sigma_mm["torso"] ** 2
    white_var = profile.white_sigma_mm["torso"] ** 2
    assert np.mean(series**2) == pytest.approx(slow_var + white_var, rel=0.12)
    lag1 = np.mean(series[1:] * series[:-1])
    lag2 = np.mean(series[2:] * series[:-2])
    assert lag1 / slow_var == pytest.approx(rho, abs=0.05)  # white jitter does not reach lag 1
    assert lag2 / lag1 == pytest.approx(rho, abs=0.05)


def test_bone_proportions_fixed_within_each_view(walking_obs) -> None:
    p = walking_obs.positions.astype(np.float64)
    lengths = np.linalg.norm(p[..., BONES[:, 1], :] - p[..., BONES[:, 0], :], axis=-1)  # (T, S, 31)
    ratios = lengths / lengths[..., :1]
    tracked = walking_obs.tracked
    spread = np.nanstd(ratios[tracked], axis=0) / np.nanmean(ratios[tracked], axis=0)
    assert spread.max() < 1e-4  # every bone / pelvis→navel: constant, mirrored frames included
    # ... while the common size factor varies by a few percent
    cv = np.nanstd(lengths[..., 0], axis=0) / np.nanmean(lengths[..., 0], axis=0)
    assert (cv > 0.005).all() and (cv < 0.08).all()


def test_scale_shrinks_at_the_bottom_of_a_squat() -> None:
    profile = PROFILE.replace(scale_slow_sd=0.0)
    obs = simulate(make_gesture("squat", seed=0), [best_view_sensor(0.0)], profile, seed=1)
    p = obs.positions[:, 0].astype(np.float64)
    thigh = np.linalg.norm(p[:, J["KNEE_LEFT"]] - p[:, J["HIP_LEFT"]], axis=1)
    pelvis_z = obs.truth[:, J["PELVIS"], 2]
    bottom, top = pelvis_z < np.percentile(pelvis_z, 10), pelvis_z > np.percentile(pelvis_z, 90)
    shrink = 1.0 - thigh[bottom].mean() / thigh[top].mean()
    assert 0.03 < shrink <= profile.scale_max_shrink + 1e-6


def test_error_in_sensor_frame_and_typical_sizes(walking_obs) -> None:
    obs = walking_obs
    front = obs.sensor_ids.index("best_view")
    ok = obs.tracked[:, front] & ~obs.mirrored[:, front]
    error = np.linalg.norm(obs.positions_world(calibrated=False)[ok, front] - obs.truth[ok], axis=-1)
    medium = obs.confidence[ok, front] == Confidence.MEDIUM
    torso = [J["SPINE_NAVEL"], J["NECK"], J["SHOULDER_LEFT"], J["HIP_RIGHT"]]
    assert 3.0 < np.median(error[:, torso][medium[:, torso]]) < 40.0
    # positions are in the sensor's own frame, not the world
    raw = obs.positions[ok, front, J["PELVIS"]]
    assert np.median(raw[:, 2]) > 1000.0  # depth in front of the camera
    assert np.median(np.abs(raw - obs.truth[ok, J["PELVIS"]])) > 100.0


# ---- behaviours ----------------------------------------------------------------------------------------


def test_mirrored_only_when_facing_away(walking_obs) -> None:
    obs = walking_obs
    for index, pose in enumerate(obs.world_from_sensor):
        angle = facing_away_deg(obs.truth, pose[:3, 3])
        mirrored = obs.mirrored[:, index]
        assert not mirrored[angle <= PROFILE.front_free_deg].any()
        starts = mirrored & ~np.concatenate([[False], mirrored[:-1]])
        assert (angle[starts] > PROFILE.away_threshold_deg).all()  # bursts start only when facing away
        # ... and end soon after the subject turns back (below threshold - hysteresis)
        turned_back = mirrored & (angle < PROFILE.away_threshold_deg - PROFILE.hysteresis_deg)
        assert turned_back.sum() <= 0.1 * max(mirrored.sum(), 1)
    assert obs.mirrored.any()


def test_rear_view_is_mirrored_in_bursts_with_new_body_ids() -> None:
    behind = look_at("behind", np.array([-2300.0, 0.0, 1000.0]), np.array([0.0, 0.0, 900.0]))
    front = best_view_sensor(0.0)
    obs = simulate(standing_still(900), [front, behind], PROFILE.replace(dropped_frame_prob=0.0), seed=4)
    assert not obs.mirrored[:, 0].any()
    assert obs.mirrored[:, 1].mean() > 0.5
    starts = np.flatnonzero(obs.mirrored[1:, 1] & ~obs.mirrored[:-1, 1]) + 1
    assert len(starts) >= 2
    assert (obs.body_ids[starts, 1] != obs.body_ids[starts - 1, 1]).all()
    assert len(np.unique(obs.body_ids[:, 0])) == 1
    # a mirrored view's "left wrist" is the subject's right wrist
    frames = obs.mirrored[:, 1]
    seen = obs.positions_world(calibrated=False)[frames, 1]
    truth = obs.truth[frames]
    wrist = J["WRIST_LEFT"]
    to_right = np.linalg.norm(seen[:, wrist] - truth[:, MIRROR[wrist]], axis=-1)
    to_left = np.linalg.norm(seen[:, wrist] - truth[:, wrist], axis=-1)
    assert np.median(to_right) < np.median(to_left)


def arm_behind_back() -> Motion:
    """Standing, facing +x, right forearm across the lower back (hidden from the front)."""
    offsets = rest_offsets()
    pose = forward_kinematics(
        offsets, np.broadcast_to(np.eye(3), (1, 32, 3, 3)).copy(), np.eye(3)[None], np.array([[0.0, 0.0, 950.0]])
    )[0]
    pose[J["ELBOW_RIGHT"]] = pose[J["SHOULDER_RIGHT"]] + [-120.0, -30.0, -260.0]
    pose[J["WRIST_RIGHT"]] = [-160.0, 30.0, 1050.0]
    pose[J["HAND_RIGHT"]] = [-165.0, 110.0, 1050.0]
    pose[J["HANDTIP_RIGHT"]] = [-170.0, 190.0, 1050.0]
    pose[J["THUMB_RIGHT"]] = [-130.0, 80.0, 1060.0]
    return Motion("arm_behind_back", 30.0, np.broadcast_to(pose, (600, 32, 3)).copy())


def test_arm_behind_the_torso_is_low_and_guessed() -> None:
    obs = simulate(arm_behind_back(), [best_view_sensor(0.0)], PROFILE.replace(dropped_frame_prob=0.0), seed=9)
    hidden, visible = J["WRIST_RIGHT"], J["WRIST_LEFT"]
    assert obs.occluded[:, 0, hidden].all()
    assert not obs.occluded[:, 0, visible].any()
    low = np.mean(obs.confidence[:, 0, hidden] == Confidence.LOW)
    assert low == pytest.approx(PROFILE.occluded_low_prob, abs=0.08)
    assert np.all(obs.confidence[:, 0, hidden] >= Confidence.LOW)  # LOW or still MEDIUM
    error = np.linalg.norm(obs.positions_world(calibrated=False)[:, 0] - obs.truth, axis=-1)
    assert np.median(error[:, hidden]) > 2.0 * np.median(error[:, visible])
    jumps = np.linalg.norm(np.diff(obs.positions[:, 0, hidden], axis=0), axis=-1)
    assert (jumps > 100.0).mean() > 0.02  # the guess jumps around


def test_out_of_view_none_and_untracked() -> None:
    # Close sensor at pelvis height: head and feet leave the vertical field of view, torso stays.
    close = look_at("close", np.array([1000.0, 0.0, 900.0]), np.array([0.0, 0.0, 900.0]))
    far = look_at("far", np.array([6000.0, 0.0, 900.0]), np.array([0.0, 0.0, 900.0]))
    obs = simulate(standing_still(60), [close, far], PROFILE.replace(dropped_frame_prob=0.0), seed=0)
    assert obs.tracked[:, 0].all()
    assert (obs.confidence[:, 0, J["HEAD"]] == Confidence.NONE).all()
    assert (obs.confidence[:, 0, J["ANKLE_LEFT"]] == Confidence.NONE).all()
    assert np.isfinite(obs.positions[:, 0, J["HEAD"]]).all()  # NONE still carries a guess
    assert (obs.confidence[:, 0, J["SPINE_CHEST"]] == Confidence.MEDIUM).all()
    assert not obs.tracked[:, 1].any()
    assert np.isnan(obs.positions[:, 1]).all()
    assert (obs.body_ids[:, 1] == -1).all() and (obs.confidence[:, 1] == Confidence.NONE).all()


def test_confidence_mix_from_the_front(walking_obs) -> None:
    obs = simulate(make_gesture("hands_up_down", seed=0), [best_view_sensor(0.0)], PROFILE, seed=2)
    conf = obs.confidence[obs.tracked[:, 0], 0]
    torso = [J["PELVIS"], J["SPINE_NAVEL"], J["SPINE_CHEST"], J["NECK"], J["HEAD"]]
    assert np.mean(conf[:, torso] == Confidence.MEDIUM) > 0.97
    assert not (conf == Confidence.HIGH).any()
    hands = [J["HAND_LEFT"], J["HANDTIP_LEFT"], J["THUMB_LEFT"], J["HAND_RIGHT"], J["HANDTIP_RIGHT"], J["THUMB_RIGHT"]]
    none_fraction = np.mean(conf[:, hands] == Confidence.NONE, axis=0)
    assert none_fraction.min() > 0.05 and none_fraction.mean() > 0.3


def test_dropped_frames_and_timestamps() -> None:
    profile = PROFILE.replace(dropped_frame_prob=0.01)
    rig = [*paper_rig(), best_view_sensor(0.0)]
    obs = simulate(standing_still(2000), rig, profile, seed=6)
    rate = obs.dropped.mean()
    assert rate == pytest.approx(0.01, abs=0.004)  # 10 000 sensor frames
    assert np.isnan(obs.positions[obs.dropped]).all() and not obs.tracked[obs.dropped].any()
    assert (obs.device_time_us[obs.dropped] == -1).all() and (obs.host_time_ns[obs.dropped] == -1).all()
    ok = ~obs.dropped
    master = obs.device_time_us[:, 0]
    both = ok[:, 0] & np.roll(ok[:, 0], 1)
    interval = np.diff(master)[both[1:]]
    assert np.median(interval) == pytest.approx(1e6 / 30.0, abs=1.0)
    assert np.std(interval) == pytest.approx(profile.frame_interval_jitter_us, rel=0.25)
    for index in range(1, len(rig)):
        lag = (obs.device_time_us[:, index] - master)[ok[:, 0] & ok[:, index]]
        expected = index * profile.subordinate_delay_us - profile.subordinate_delay_spread_us / 2
        assert np.mean(lag) == pytest.approx(expected, abs=5.0)
    host_minus_device_ms = (obs.host_time_ns[ok] - obs.device_time_us[ok] * 1000 - profile.host_epoch_s * 1e9) / 1e6
    assert np.median(host_minus_device_ms) == pytest.approx(profile.host_latency_mean_ms, abs=8.0)
    for index in range(len(rig)):
        host = obs.host_time_ns[ok[:, index], index]
        assert (np.diff(host) > 0).all()


def test_calibration_error_on_subordinates_only(walking_obs) -> None:
    obs = walking_obs
    np.testing.assert_array_equal(obs.world_from_sensor_calibrated[0], obs.world_from_sensor[0])
    for true, calibrated in zip(obs.world_from_sensor[1:], obs.world_from_sensor_calibrated[1:], strict=True):
        delta = np.linalg.inv(true) @ calibrated
        angle = np.degrees(np.arccos(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1, 1)))
        assert 0.0 < angle < 4 * PROFILE.calibration_rotation_sd_deg
        assert 0.0 < np.linalg.norm(delta[:3, 3]) < 5 * PROFILE.calibration_translation_sd_mm


def test_convergence_over_the_first_frames() -> None:
    profile = PROFILE.replace(convergence_sigma_mm=200.0, dropped_frame_prob=0.0)
    obs = simulate(standing_still(120), [best_view_sensor(0.0)], profile, seed=1)
    error = np.linalg.norm(obs.positions_world(calibrated=False)[:, 0] - obs.truth, axis=-1).mean(axis=1)
    assert error[:3].mean() > 3 * error[60:].mean()


def test_a_guessed_elbow_is_fitted_around_the_wrist_the_tracker_sees() -> None:
    # The elbow is hidden and guessed 120 mm off; the wrist is seen where it is. Walking the chain would carry
    # the elbow's guess down to the wrist; the body model keeps both bones and puts the wrist where it was seen.
    truth = make_gesture("hands_up_down", duration_s=1.0, seed=3).positions[:5]
    lengths = np.linalg.norm(truth[0, BONES[:, 1]] - truth[0, BONES[:, 0]], axis=-1)
    bone_lengths = np.concatenate([[0.0], lengths])  # BONES[:, 1] is 1..31: the bone ending at each joint
    noisy = truth.copy()
    noisy[:, J["ELBOW_LEFT"]] += np.array([0.0, 120.0, 0.0])
    guessed = np.zeros(truth.shape[:2], dtype=bool)
    guessed[:, J["ELBOW_LEFT"]] = True
    scale = np.ones(truth.shape[0])
    walked = fit_body_model(noisy, bone_lengths, scale)
    fitted = fit_body_model(noisy, bone_lengths, scale, guessed)
    wrist, elbow, shoulder = J["WRIST_LEFT"], J["ELBOW_LEFT"], J["SHOULDER_LEFT"]
    assert np.linalg.norm(walked[:, wrist] - truth[:, wrist], axis=-1).min() > 20.0  # the carry-down
    np.testing.assert_allclose(fitted[:, wrist], truth[:, wrist], atol=1e-6)
    for joint in (elbow, wrist, J["HAND_LEFT"]):  # every bone keeps its length
        parent = {elbow: shoulder, wrist: elbow}.get(joint, wrist)
        np.testing.assert_allclose(
            np.linalg.norm(fitted[:, joint] - fitted[:, parent], axis=-1), bone_lengths[joint], rtol=1e-9
        )
    # the guessed elbow lies on the side of its guess: closer to the guess than the mirrored solution
    assert (np.linalg.norm(fitted[:, elbow] - noisy[:, elbow], axis=-1) < 120.0 + 1e-6).all()
    assert not np.allclose(fitted[:, elbow], truth[:, elbow], atol=1.0)  # still a guess, not the truth
