"""Observation model: what each virtual Azure Kinect body tracker reports for a true motion.

Cycle, per sensor (numpy over frames and joints; Python loops only over sensors, joints along the
kinematic chain, and scalar per-frame state machines):

1. truth → sensor frame; field of view and depth range per joint; the body is tracked only while enough
   torso joints are in view; dropped frames.
2. Self-occlusion: rays from the sensor to every joint against capsules around the same body's bones.
3. Facing: a body facing away is mirrored in bursts (Markov chain with hysteresis); a burst starts with a
   new body id. A mirrored fit also puts the face and toes on the sensor's side.
4. Error, in the tracker's label space: constant per-view offsets + slow AR(1) + heavy-tailed white jitter
   + rare jumps; occluded or out-of-view joints get the tracker's guess instead (pulled towards a default
   pose, with a large AR(1) error that jumps); newly found bodies converge over a few frames.
5. Body model: the noisy joints are refitted along the kinematic chain to fixed (left/right symmetric)
   bone lengths times ONE size factor per frame and view (view level, slow drift, shrink with pelvis drop).
6. Confidence labels, body ids, device and host timestamps, calibrated extrinsics with error.

Every parameter lives in :class:`SimProfile`, loaded from TOML (the packaged default is
``skelfuse/profiles/azure_kinect.toml``, which says where each default comes from).
"""

from __future__ import annotations

import dataclasses
import zlib
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.special import ndtri

from skelfuse.fusion.transform import apply_transform
from skelfuse.schema.skeleton import (
    BODY_REGIONS,
    MIRROR,
    N_JOINTS,
    PARENTS,
    TORSO_TRACKING_JOINTS,
    Confidence,
    J,
)
from skelfuse.sim.body_model import (
    _swap_limbs,
    ar1,
    facing_away_deg,
    fit_body_model,
    limb_swap_bursts,
    mirror_bursts,
    self_occlusion,
    student_t,
    symmetric_bone_lengths,
)
from skelfuse.sim.motion import Motion, root_facing
from skelfuse.sim.profile import JOINT_NOISE_GROUP, NOISE_GROUPS, SimProfile
from skelfuse.sim.profile import load_profile as load_profile  # re-exported: simulate's callers load with it
from skelfuse.sim.rig import VirtualSensor
from skelfuse.sim.tracker_loss import apply_tracker_loss, tracker_loss_episodes

_HAND_SIDES = tuple(np.array([J[f"{n}_{side}"] for n in ("HAND", "HANDTIP", "THUMB")]) for side in ("LEFT", "RIGHT"))
_LEG_CHAINS = tuple(np.array([J[f"{n}_{side}"] for n in ("KNEE", "ANKLE", "FOOT")]) for side in ("LEFT", "RIGHT"))
_TORSO_JOINTS_MASK = np.isin(np.arange(N_JOINTS), BODY_REGIONS["torso"])
_FACE_JOINTS = BODY_REGIONS["face"]
_FOOT_TIPS = np.array([J["FOOT_LEFT"], J["FOOT_RIGHT"]])


@dataclass(frozen=True)
class Observations:
    """What the rig's body trackers reported for one take (one person), plus the ground truth.

    T frames at the profile's frame rate, S sensors in the order given to :func:`simulate` (index 0 is
    the master). Joint arrays follow the k4abt order and hold the tracker's *labels*: where ``mirrored``
    is true, index ``WRIST_LEFT`` holds the subject's right wrist.

    Attributes
    ----------
    sensor_ids : tuple[str, ...]
    positions : (T, S, 32, 3) float32, each sensor's own camera frame (x right, y down, z forward), mm;
        NaN where the sensor did not track the body or dropped the frame.
    confidence : (T, S, 32) uint8, :class:`skelfuse.schema.skeleton.Confidence` values (NONE where NaN).
    body_ids : (T, S) int64, the tracker's body id; -1 where not tracked; a new id when the body is found
        again and when a mirrored burst starts.
    tracked : (T, S) bool, the sensor reported the body in that frame.
    mirrored : (T, S) bool, ground truth: the view's left/right labels are swapped.
    device_time_us : (T, S) int64 device timestamps, µs; -1 where the frame was dropped.
    host_time_ns : (T, S) int64 host timestamps, ns; -1 where the frame was dropped.
    world_from_sensor : (S, 4, 4) true extrinsics.
    world_from_sensor_calibrated : (S, 4, 4) extrinsics with the profile's calibration error (the master's
        is exact): what a real rig would use.
    truth : (T, 32, 3) float64, the true joints in the world frame, mm, at the frame times.
    dropped : (T, S) bool, the sensor delivered no frame at all.
    occluded : (T, S, 32) bool, ground truth, label order: the joint was self-occluded or out of view.
    times_s : (T,) nominal frame times from the start of the take, s.
    """

    sensor_ids: tuple[str, ...]
    positions: np.ndarray
    confidence: np.ndarray
    body_ids: np.ndarray
    tracked: np.ndarray
    mirrored: np.ndarray
    device_time_us: np.ndarray
    host_time_ns: np.ndarray
    world_from_sensor: np.ndarray
    world_from_sensor_calibrated: np.ndarray
    truth: np.ndarray
    dropped: np.ndarray
    occluded: np.ndarray
    times_s: np.ndarray

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_sensors(self) -> int:
        return int(self.positions.shape[1])

    def positions_world(self, *, calibrated: bool) -> np.ndarray:
        """(T, S, 32, 3) float64 world positions: ``calibrated`` picks the extrinsics with the profile's calibration
        error (what a real rig fuses with) or the true ones; no default, so every caller says which."""
        poses = self.world_from_sensor_calibrated if calibrated else self.world_from_sensor
        return apply_transform(poses, self.positions.astype(np.float64))


def _sensor_rngs(seed: int, sensor_id: str) -> dict[str, np.random.Generator]:
    """Independent streams per sensor, keyed by its id: adding a sensor leaves the others' draws alone."""
    key = zlib.crc32(sensor_id.encode("utf-8"))
    names = ("tracking", "noise", "confidence", "timing", "calibration", "scale", "failures", "loss")
    return {name: np.random.default_rng([seed, key, idx]) for idx, name in enumerate(names)}


def _default_pose(lab: np.ndarray, bone_lengths: np.ndarray, down: np.ndarray) -> np.ndarray:
    """The tracker's prior for a hidden limb joint: the limb hanging straight down from its shoulder/hip."""
    prior = lab.copy()
    for side in ("LEFT", "RIGHT"):
        for root, chain in (
            (f"SHOULDER_{side}", ("ELBOW", "WRIST", "HAND", "HANDTIP")),
            (f"HIP_{side}", ("KNEE", "ANKLE", "FOOT")),
        ):
            reach = 0.0
            for name in chain:
                reach += bone_lengths[J[f"{name}_{side}"]]
                prior[:, J[f"{name}_{side}"]] = lab[:, J[root]] + reach * down
        prior[:, J[f"THUMB_{side}"]] = prior[:, J[f"HAND_{side}"]]
    return prior


def _reflect(points: np.ndarray, centre: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Reflect (T, n, 3) points through the plane through (T, 3) centres with (T, 3) unit normals."""
    offset = points - centre[:, None]
    return points - 2.0 * np.sum(offset * normal[:, None], axis=-1, keepdims=True) * normal[:, None]


def _calibration_error(rng: np.random.Generator, profile: SimProfile) -> np.ndarray:
    """(4, 4) small rigid perturbation (rotation about a random axis, translation), sensor frame."""
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    angle = np.radians(rng.normal(0.0, profile.calibration_rotation_sd_deg))
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    delta = np.eye(4)
    delta[:3, :3] = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)
    delta[:3, 3] = rng.normal(0.0, profile.calibration_translation_sd_mm, 3)
    return delta


def _group_values(table: dict[str, float]) -> np.ndarray:
    """(32, 1) per-joint value of a per-group table, broadcastable over axes."""
    return np.array([table[g] for g in NOISE_GROUPS])[JOINT_NOISE_GROUP][:, None]


# ----------------------------------------------------------------------------------------------------------


def simulate(motion: Motion, sensors: list[VirtualSensor], profile: SimProfile, *, seed: int) -> Observations:
    """Simulate what each sensor's body tracker reports while ``motion`` happens.

    Parameters
    ----------
    motion : the ground truth (resampled to the profile's frame rate)
    sensors : the rig; index 0 is the master (exact calibration, no depth delay)
    profile : observation model parameters (:func:`load_profile`)
    seed : everything random derives from it; each sensor draws from its own streams keyed by its id

    Returns
    -------
    Observations
    """
    if not sensors:
        raise ValueError("simulate needs at least one sensor")
    ids = [s.sensor_id for s in sensors]
    if len(set(ids)) != len(ids):
        raise ValueError(f"sensor ids must be unique, got {ids}")
    motion = _posture(motion, profile)
    level_down = [-s.world_from_sensor[2, :3] for s in sensors]  # world down in each level camera's frame
    sensors = _tilted_mounts(sensors, profile, np.random.default_rng([seed, 0x7117]))
    last_s = (motion.n_frames - 1) / motion.fps
    n = int(np.floor(last_s * profile.fps + 1e-6)) + 1
    times = np.arange(n) / profile.fps
    truth = motion.at_times(times)
    n_sensors = len(sensors)
    take = _take_truth(motion, times, truth, profile, seed)

    positions = np.full((n, n_sensors, N_JOINTS, 3), np.nan, dtype=np.float32)
    confidence = np.zeros((n, n_sensors, N_JOINTS), dtype=np.uint8)
    body_ids = np.full((n, n_sensors), -1, dtype=np.int64)
    tracked_all = np.zeros((n, n_sensors), dtype=bool)
    mirrored_all = np.zeros((n, n_sensors), dtype=bool)
    dropped_all = np.zeros((n, n_sensors), dtype=bool)
    occluded_all = np.zeros((n, n_sensors, N_JOINTS), dtype=bool)
    device_time = np.zeros((n, n_sensors), dtype=np.int64)
    host_time = np.zeros((n, n_sensors), dtype=np.int64)
    poses = np.stack([s.world_from_sensor for s in sensors])
    poses_calibrated = poses.copy()

    for index, sensor in enumerate(sensors):
        view = _observe_sensor(index, sensor, profile, take, seed=seed, level_down=level_down[index])
        tracked = view.tracked
        body_ids[:, index] = view.body_ids
        positions[tracked, index] = view.positions[tracked].astype(np.float32)
        confidence[tracked, index] = view.confidence[tracked]
        tracked_all[:, index] = tracked
        mirrored_all[:, index] = view.mirrored
        dropped_all[:, index] = view.dropped
        occluded_all[:, index] = view.hidden & tracked[:, None]
        device_time[:, index], host_time[:, index] = view.device_time_us, view.host_time_ns
        if index > 0:
            poses_calibrated[index] = sensor.world_from_sensor @ view.calibration_error

    return Observations(
        sensor_ids=tuple(ids),
        positions=positions,
        confidence=confidence,
        body_ids=body_ids,
        tracked=tracked_all,
        mirrored=mirrored_all,
        device_time_us=device_time,
        host_time_ns=host_time,
        world_from_sensor=poses,
        world_from_sensor_calibrated=poses_calibrated,
        truth=truth,
        dropped=dropped_all,
        occluded=occluded_all,
        times_s=times,
    )


class _TakeTruth(NamedTuple):
    """What every sensor of one take sees the same: the truth and what the tracker model derives from it."""

    truth: np.ndarray  # (T, 32, 3) world, mm
    seen: np.ndarray  # (T, 32, 3) what the sensors see: the truth unless a common-mode family moves it
    neighbour: np.ndarray | None  # (T, 32, 3) a close neighbour the first sensor may confuse the subject with
    speed_mps: np.ndarray  # (T, 32) joint speeds
    bone_lengths: np.ndarray  # the body model's symmetric bone lengths
    pose_scale: np.ndarray  # (T,) the body model's size factor: shrinks as the pelvis drops
    forward_world: np.ndarray  # (T, 3) the body's facing


def _take_truth(motion: Motion, times: np.ndarray, truth: np.ndarray, profile: SimProfile, seed: int) -> _TakeTruth:
    """The per-take arrays every sensor shares, drawn once from the take's own stream (not the sensors')."""
    neighbour = _neighbour(motion, times, truth, profile)
    seen = _common_mode(motion, times, truth, profile, np.random.default_rng([seed, 0xC033]))
    speed_mps = np.linalg.norm(np.gradient(truth, axis=0), axis=-1) * profile.fps / 1000.0  # (T, 32)
    bone_lengths = symmetric_bone_lengths(truth)
    pelvis_z = truth[:, J["PELVIS"], 2]
    drop_mm = np.maximum(np.percentile(pelvis_z, 90) - pelvis_z, 0.0)
    pose_scale = 1.0 - np.minimum(profile.scale_per_100mm_drop * drop_mm / 100.0, profile.scale_max_shrink)
    forward_world = root_facing(truth)
    return _TakeTruth(truth, seen, neighbour, speed_mps, bone_lengths, pose_scale, forward_world)


class _SensorView(NamedTuple):
    """What one sensor's tracker reported over the take, before it is written into :class:`Observations`."""

    positions: np.ndarray  # (T, 32, 3) float64, the sensor frame, mm (valid where tracked)
    confidence: np.ndarray  # (T, 32) uint8
    body_ids: np.ndarray  # (T,) int64, -1 where not tracked
    tracked: np.ndarray  # (T,) bool
    mirrored: np.ndarray  # (T,) bool
    dropped: np.ndarray  # (T,) bool
    hidden: np.ndarray  # (T, 32) bool
    device_time_us: np.ndarray  # (T,) int64
    host_time_ns: np.ndarray  # (T,) int64
    calibration_error: np.ndarray | None  # (4, 4), None for the master (exact calibration)


def _observe_sensor(
    index: int,
    sensor: VirtualSensor,
    profile: SimProfile,
    take: _TakeTruth,
    *,
    seed: int,
    level_down: np.ndarray,
) -> _SensorView:
    """One sensor's tracker over the whole take, from its own random streams (steps 1-7 of the module docstring)."""
    truth, seen, neighbour, speed_mps, bone_lengths, pose_scale, forward_world = take
    n = int(truth.shape[0])
    rngs = _sensor_rngs(seed, sensor.sensor_id)
    rotation = sensor.world_from_sensor[:3, :3]
    physical = sensor.to_sensor(seen)  # (T, 32, 3) sensor frame (seen = truth unless a common-mode family)
    if index == 0 and neighbour is not None:  # the first sensor confuses the subject with a close neighbour
        physical = _confuse_with_neighbour(rngs["failures"], physical, sensor.to_sensor(neighbour), profile)

    # 1. visibility and tracking
    in_view = sensor.in_view(physical)
    dropped = rngs["tracking"].random(n) < profile.dropped_frame_prob
    torso_visible = in_view[:, TORSO_TRACKING_JOINTS].sum(axis=1) >= profile.min_torso_joints_in_view
    tracked = torso_visible & ~dropped
    # 2. self-occlusion (geometry of the true body)
    hidden = self_occlusion(physical, profile.capsule_radius_mm, profile.occlusion_margin_mm) | ~in_view
    # 3. mirroring and body ids
    angle = facing_away_deg(truth, sensor.position_mm)
    mirrored = mirror_bursts(rngs["tracking"], angle, tracked, profile)
    prev_tracked = np.concatenate([[False], tracked[:-1]])
    prev_mirrored = np.concatenate([[False], mirrored[:-1]])
    new_body = tracked & (~prev_tracked | (mirrored & ~prev_mirrored))
    loss_flipped, loss_away, loss_starts = tracker_loss_episodes(
        rngs["loss"],
        tracked,
        profile.tracker_loss_prob,
        profile.tracker_loss_flip_frames,
        profile.tracker_loss_away_frames,
    )
    new_body |= loss_starts

    # 4-7. what the tracker reports: labels, error, body-model refit, confidence, timestamps
    lab, hidden, in_view = _label_space(physical, hidden, in_view, mirrored, forward_world[mirrored] @ rotation)
    swaps = limb_swap_bursts(rngs["failures"], angle, tracked & ~mirrored, profile)
    lab, hidden, in_view = _swap_limbs(lab, hidden, in_view, swaps)
    restarts = new_body if profile.flip_restarts_fit else new_body & ~(mirrored & prev_tracked)
    lost = leg_low_episodes(rngs["confidence"], n, profile) & ~hidden
    gain = _noise_gain(lab, np.where(mirrored[:, None], speed_mps[:, MIRROR], speed_mps), profile)
    # The tracker's prior for hidden limbs hangs them along its idea of down: the level camera's (a tilted
    # mount does not tell the tracker it is tilted; without the tilt family the two are the same).
    down = level_down if profile.mount_tilt_deg > 0 else -rotation[2]
    noisy = _tracker_error(rngs["noise"], lab, hidden, restarts, bone_lengths, down, profile, lost, gain)
    noisy = _partial_view_drag(noisy, lab, in_view, profile.partial_view_drag)
    fitted = _body_model(rngs["scale"], noisy, bone_lengths, pose_scale, profile, hidden | lost)
    labels = _confidence_labels(rngs["confidence"], hidden, in_view, profile, lost)
    if loss_starts.any():
        fitted = apply_tracker_loss(
            fitted, loss_flipped, loss_away, -rotation[2], profile.tracker_loss_offset_mm, rngs["loss"]
        )

    device_time_us, host_time_ns = _timestamps(rngs["timing"], n, index, dropped, profile)
    calibration_error = _calibration_error(rngs["calibration"], profile) if index > 0 else None
    return _SensorView(
        fitted,
        labels,
        np.where(tracked, np.cumsum(new_body), -1),
        tracked,
        mirrored,
        dropped,
        hidden,
        device_time_us,
        host_time_ns,
        calibration_error,
    )


def _label_space(
    physical: np.ndarray, hidden: np.ndarray, in_view: np.ndarray, mirrored: np.ndarray, forward: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The true joints as the tracker labels them (stage 3 of :func:`simulate`).

    A mirrored fit faces the sensor, so face and toes go to the sensor's side (``forward``: the body's facing
    in the sensor frame, for the mirrored frames) and the left/right labels swap, with the joints' occlusion
    and visibility.
    """
    lab = physical.copy()
    if not mirrored.any():
        return lab, hidden, in_view
    m_lab = lab[mirrored]
    m_lab[:, _FACE_JOINTS] = _reflect(m_lab[:, _FACE_JOINTS], m_lab[:, J["HEAD"]], forward)
    for tip in _FOOT_TIPS:
        ankle = PARENTS[tip]
        m_lab[:, [tip]] = _reflect(m_lab[:, [tip]], m_lab[:, ankle], forward)
    lab[mirrored] = m_lab[:, MIRROR]
    hidden = np.where(mirrored[:, None], hidden[:, MIRROR], hidden)
    in_view = np.where(mirrored[:, None], in_view[:, MIRROR], in_view)
    return lab, hidden, in_view


def _tracker_error(
    noise: np.random.Generator,
    lab: np.ndarray,
    hidden: np.ndarray,
    restarts: np.ndarray,
    bone_lengths: np.ndarray,
    down: np.ndarray,
    profile: SimProfile,
    lost: np.ndarray | None = None,
    gain: np.ndarray | None = None,
) -> np.ndarray:
    """Stage 4 of :func:`simulate`: constant offsets, slow AR(1) error with jumps, heavy-tailed white jitter, the
    pull of hidden joints toward a default pose plus their guess error, and the convergence after a (re)start.

    ``restarts``: frames where the tracker starts a new fit; ``down``: world -z in the sensor frame; ``lost``:
    (n, 32) visible joints the tracker lost for a moment (leg LOW episodes): they carry the guess error too,
    without the pull; ``gain``: (n, 32) factor on the slow and white error (failure family "distance_speed").
    """
    n = lab.shape[0]
    offsets = noise.normal(0.0, 1.0, (N_JOINTS, 3)) * _group_values(profile.offset_sigma_mm)
    jumps = (noise.random((n, N_JOINTS, 1)) < profile.jump_prob) & ~hidden[:, :, None]
    impulses = jumps * noise.normal(0.0, profile.jump_sigma_mm, (n, N_JOINTS, 3))
    slow = ar1(noise, n, (N_JOINTS, 3), _group_values(profile.slow_rho), _group_values(profile.slow_sigma_mm), impulses)
    white = student_t(noise, (n, N_JOINTS, 3), _group_values(profile.white_sigma_mm), profile.white_dof)
    guess = _occluded_guess_error(noise, n, profile)
    prior = _default_pose(lab, bone_lengths, down)
    noisy = lab + offsets + (slow + white) * (1.0 if gain is None else gain[:, :, None])
    noisy = noisy + hidden[:, :, None] * (profile.occluded_pull * (prior - lab) + guess)
    if lost is not None:
        noisy = noisy + lost[:, :, None] * guess
    if profile.convergence_frames > 0:
        run_start = np.maximum.accumulate(np.where(restarts, np.arange(n), 0))
        since = np.arange(n) - run_start
        initial = noise.normal(0.0, profile.convergence_sigma_mm, (N_JOINTS, 3))
        noisy = noisy + np.exp(-since / profile.convergence_frames)[:, None, None] * initial
    return noisy


def _body_model(
    scale_rng: np.random.Generator,
    noisy: np.ndarray,
    bone_lengths: np.ndarray,
    pose_scale: np.ndarray,
    profile: SimProfile,
    guessed: np.ndarray | None = None,
) -> np.ndarray:
    """Stage 5 of :func:`simulate`: refit the noisy joints to the body model with one size factor per frame
    (a per-view level, the pose's shrink, a slow drift); ``guessed`` joints are fitted around what is seen."""
    level = 1.0 + np.clip(scale_rng.normal(0.0, profile.scale_view_sd), -profile.scale_view_max, profile.scale_view_max)
    drift = ar1(scale_rng, noisy.shape[0], (), profile.scale_slow_rho, profile.scale_slow_sd)
    return fit_body_model(noisy, bone_lengths, level * pose_scale * (1.0 + drift), guessed)


def leg_low_episodes(rng: np.random.Generator, n: int, profile: SimProfile) -> np.ndarray:
    """(n, 32) bool: short episodes in which the tracker loses a leg (its knee, ankle and foot) although it is
    in view: each starts with ``leg_low_prob`` per frame and leg and lasts ``floor(U ** (-1 / alpha))`` frames
    (at most ``leg_low_max_frames``), a heavy tail: real episodes last a median 1 frame, the longest 6-15."""
    starts = rng.random((n, 2)) < profile.leg_low_prob
    lengths = np.minimum(
        np.floor((1.0 - rng.random((n, 2))) ** (-1.0 / profile.leg_low_length_alpha)), profile.leg_low_max_frames
    ).astype(np.int64)
    remaining = np.zeros(2, dtype=np.int64)
    legs = np.zeros((n, 2), dtype=bool)
    for k in range(n):  # a countdown per leg, vectorized over the legs
        remaining = np.where(starts[k], np.maximum(remaining, lengths[k]), remaining)
        legs[k] = remaining > 0
        remaining = np.maximum(remaining - 1, 0)
    out = np.zeros((n, N_JOINTS), dtype=bool)
    for side, leg in enumerate(_LEG_CHAINS):
        out[:, leg] = legs[:, side : side + 1]
    return out


def _confidence_labels(
    conf_rng: np.random.Generator,
    hidden: np.ndarray,
    in_view: np.ndarray,
    profile: SimProfile,
    lost: np.ndarray | None = None,
) -> np.ndarray:
    """Stage 6 of :func:`simulate`: (n, 32) confidence: MEDIUM, LOW for hidden limb joints and lost legs (torso
    joints rarely: the tracker sees the trunk around a limb), NONE for whole-hand episodes and out of view."""
    n = hidden.shape[0]
    labels = np.full((n, N_JOINTS), Confidence.MEDIUM, dtype=np.uint8)
    if lost is not None:
        labels[lost] = Confidence.LOW
    low_prob = np.where(_TORSO_JOINTS_MASK, profile.torso_occluded_low_prob, profile.occluded_low_prob)
    hidden_low = hidden & (conf_rng.random((n, N_JOINTS)) < low_prob)
    labels[hidden_low] = Confidence.LOW
    fraction = conf_rng.uniform(profile.hand_none_fraction_min, profile.hand_none_fraction_max, len(_HAND_SIDES))
    latent = ar1(conf_rng, n, (len(_HAND_SIDES),), profile.hand_none_rho, 1.0)
    hand_none = latent < ndtri(np.clip(fraction, 1e-9, 1 - 1e-9))  # (n, 2): the tracker drops a whole hand
    for side, joints in enumerate(_HAND_SIDES):
        labels[np.ix_(hand_none[:, side], joints)] = Confidence.NONE
    labels[~in_view] = Confidence.NONE
    return labels


def _timestamps(
    timing: np.random.Generator, n: int, index: int, dropped: np.ndarray, profile: SimProfile
) -> tuple[np.ndarray, np.ndarray]:
    """Stage 7 of :func:`simulate`: device timestamps (µs; subordinates after the master by their delay) and host
    timestamps (ns; latency and a per-host offset, never running backwards); -1 for dropped frames."""
    period_us = 1e6 / profile.fps
    device = (
        profile.device_time_start_us
        + np.arange(n) * period_us
        + timing.normal(0.0, profile.frame_interval_jitter_us / np.sqrt(2.0), n)
    )
    if index > 0:
        device = (
            device + index * profile.subordinate_delay_us - timing.uniform(0.0, profile.subordinate_delay_spread_us, n)
        )
    latency_ms = np.maximum(
        profile.host_latency_mean_ms
        + timing.normal(0.0, profile.host_offset_sd_ms)
        + timing.normal(0.0, profile.host_latency_jitter_ms, n),
        0.0,
    )
    host = profile.host_epoch_s * 1e9 + device * 1e3 + latency_ms * 1e6
    host = np.maximum.accumulate(host)  # a host clock never runs backwards
    return np.where(dropped, -1, np.rint(device).astype(np.int64)), np.where(
        dropped, -1, np.rint(host).astype(np.int64)
    )


def _posture(motion: Motion, profile: SimProfile) -> Motion:
    """The motion as the subject performs it sitting or lying (families "sitting", "lying"); unchanged otherwise.

    Sitting: per frame each thigh points level along the body's facing from its hip, the shin straight down, the
    foot forward (every bone keeps its length), and the whole body is lowered until the lower ankle is at the
    height the standing ankles had (on a chair, feet on the floor). Lying: the whole body turned 90 degrees
    about the lateral axis through the pelvis (head away from the facing, face up) and lowered until the pelvis
    is 120 mm above the floor (on the back).
    """
    if not (profile.sitting or profile.lying):
        return motion
    pos = motion.positions.astype(np.float64).copy()
    forward = root_facing(pos)  # (T, 3) horizontal
    if profile.sitting:
        ankle_floor = np.min(pos[:, [J["ANKLE_LEFT"], J["ANKLE_RIGHT"]], 2])
        down = np.array([0.0, 0.0, -1.0])
        for side in ("LEFT", "RIGHT"):
            hip, knee, ankle, foot = (J[f"{name}_{side}"] for name in ("HIP", "KNEE", "ANKLE", "FOOT"))
            thigh = np.linalg.norm(pos[:, knee] - pos[:, hip], axis=1, keepdims=True)
            shin = np.linalg.norm(pos[:, ankle] - pos[:, knee], axis=1, keepdims=True)
            sole = np.linalg.norm(pos[:, foot] - pos[:, ankle], axis=1, keepdims=True)
            pos[:, knee] = pos[:, hip] + thigh * forward
            pos[:, ankle] = pos[:, knee] + shin * down
            pos[:, foot] = pos[:, ankle] + sole * forward
        lowest = np.min(pos[:, [J["ANKLE_LEFT"], J["ANKLE_RIGHT"]], 2], axis=1)
        pos[:, :, 2] -= (lowest - ankle_floor)[:, None]
    else:
        axis = np.cross(forward, np.array([0.0, 0.0, 1.0]))  # lateral: turns up into -forward, forward into up
        pelvis = pos[:, J["PELVIS"]][:, None]
        offset = pos - pelvis
        cross = np.cross(axis[:, None], offset)
        along = np.sum(axis[:, None] * offset, axis=-1, keepdims=True) * axis[:, None]
        pos = pelvis + cross + along  # Rodrigues at 90 degrees: v' = a x v + a (a . v)
        pos[:, :, 2] += 120.0 - pos[:, J["PELVIS"], 2][:, None]
    return Motion(motion.name, motion.fps, pos)


def _tilted_mounts(sensors: list[VirtualSensor], profile: SimProfile, rng: np.random.Generator) -> list[VirtualSensor]:
    """Every sensor rolled about its optical axis and pitched about its x axis by angles drawn uniformly in
    +-``mount_tilt_deg`` (family "tilted_mounts"): the true poses; the rig's calibration measures them (as a rig
    calibrated where it stands), but the body tracker keeps assuming a level camera (see :func:`simulate`)."""
    if profile.mount_tilt_deg <= 0:
        return sensors
    out = []
    for sensor in sensors:
        roll, pitch = np.radians(rng.uniform(-profile.mount_tilt_deg, profile.mount_tilt_deg, 2))
        tilt = np.eye(4)
        tilt[:3, :3] = _rotation_z(roll) @ _rotation_x(pitch)
        out.append(dataclasses.replace(sensor, world_from_sensor=sensor.world_from_sensor @ tilt))
    return out


def _rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rotation_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _neighbour(motion: Motion, times: np.ndarray, truth: np.ndarray, profile: SimProfile) -> np.ndarray | None:
    """(T, 32, 3) world joints of a second person beside the subject (family "close_people"): the same motion
    one second behind, ``neighbour_distance_mm`` to the subject's right. None when the family is off."""
    if profile.neighbour_distance_mm <= 0 or (profile.neighbour_swap_prob <= 0 and profile.neighbour_merge_prob <= 0):
        return None
    forward = root_facing(truth)
    right = np.stack([forward[:, 1], -forward[:, 0], np.zeros(len(times))], axis=1)
    behind = motion.at_times(np.maximum(times - 1.0, 0.0))
    return behind + profile.neighbour_distance_mm * right[:, None]


def _confuse_with_neighbour(
    rng: np.random.Generator, physical: np.ndarray, neighbour: np.ndarray, profile: SimProfile
) -> np.ndarray:
    """The subject's joints as a view that confuses the subject with the neighbour reports them: in swap bursts
    the neighbour's joints (ids swapped), in merge bursts the midpoint of both (one skeleton for two people).
    Bursts start with ``neighbour_swap_prob`` / ``neighbour_merge_prob`` per frame, end with
    ``neighbour_off_prob``."""
    n = physical.shape[0]
    uniform = rng.random((n, 2))
    state = np.zeros(n, dtype=np.int8)  # 0 none, 1 swapped, 2 merged
    current = 0
    for k in range(n):  # a three-state chain over frames
        if current:
            current = 0 if uniform[k, 0] < profile.neighbour_off_prob else current
        elif uniform[k, 0] < profile.neighbour_swap_prob:
            current = 1
        elif uniform[k, 1] < profile.neighbour_merge_prob:
            current = 2
        state[k] = current
    out = np.where((state == 1)[:, None, None], neighbour, physical)
    return np.where((state == 2)[:, None, None], 0.5 * (physical + neighbour), out)


def _partial_view_drag(noisy: np.ndarray, lab: np.ndarray, in_view: np.ndarray, drag: float) -> np.ndarray:
    """A body partly outside the view: the fit to the visible part is dragged by the guessed part. Every in-view
    joint moves by ``drag`` times the mean error of the out-of-view joints of its frame (failure family
    "partial_view"); frames with the whole body in view are left alone."""
    if drag <= 0:
        return noisy
    outside = ~in_view
    count = outside.sum(axis=1)
    partly = (count > 0) & (count < N_JOINTS)
    if not partly.any():
        return noisy
    error = np.where(outside[:, :, None], noisy - lab, 0.0).sum(axis=1) / np.maximum(count, 1)[:, None]
    shift = drag * error[:, None, :] * (partly[:, None] & in_view)[:, :, None]
    return noisy + shift


def _noise_gain(lab: np.ndarray, speed_mps: np.ndarray, profile: SimProfile) -> np.ndarray | None:
    """(n, 32) factor on a view's slow and white error: 1 + noise_gain_per_m per metre of depth beyond 2 m +
    noise_gain_per_mps per m/s of the joint's speed (None when both gains are off)."""
    if profile.noise_gain_per_m == 0 and profile.noise_gain_per_mps == 0:
        return None
    beyond_m = np.maximum(lab[..., 2] / 1000.0 - 2.0, 0.0)
    return 1.0 + profile.noise_gain_per_m * beyond_m + profile.noise_gain_per_mps * speed_mps


def _common_mode(
    motion: Motion, times: np.ndarray, truth: np.ndarray, profile: SimProfile, rng: np.random.Generator
) -> np.ndarray:
    """(T, 32, 3) world joints as every tracker sees them: the truth, late by ``lag_frames`` and with a body-model
    error shared by all views (a constant plus a slow AR(1) per joint and axis), which averaging views cannot
    remove. The truth itself when the failure families that set these are off."""
    seen = truth
    if profile.lag_frames > 0:
        seen = motion.at_times(np.maximum(times - profile.lag_frames / profile.fps, 0.0))
    if profile.common_offset_sigma_mm > 0 or profile.common_slow_sigma_mm > 0:
        n = truth.shape[0]
        offset = rng.normal(0.0, profile.common_offset_sigma_mm, (N_JOINTS, 3))
        slow = ar1(rng, n, (N_JOINTS, 3), _group_values(profile.slow_rho), profile.common_slow_sigma_mm)
        seen = seen + offset + slow
    return seen


def _occluded_guess_error(rng: np.random.Generator, n: int, profile: SimProfile) -> np.ndarray:
    """(n, 32, 3) the tracker's guess error for hidden joints: AR(1) that is redrawn on jumps."""
    sigma = _group_values(profile.occluded_sigma_mm)
    rho = profile.occluded_rho
    draws = rng.standard_normal((n, N_JOINTS, 3)) * sigma
    redraw = rng.random((n, N_JOINTS, 1)) < profile.occluded_jump_prob
    innovation = draws * np.sqrt(1.0 - rho**2)
    out = np.empty((n, N_JOINTS, 3))
    state = draws[0]
    for k in range(n):  # recursion over frames, vectorized over joints and axes
        state = np.where(redraw[k], draws[k], rho * state + innovation[k]) if k else state
        out[k] = state
    return out
