"""Several people in the rig: what each sensor's body tracker reports when people occlude each other.

Cycle of :func:`simulate_people`:

1. Every person is observed alone by :func:`skelfuse.sim.observe.simulate` (own seed derived from
   ``seed`` and the person's index): noise, self-occlusion, mirrored bursts with new body ids, body model.
2. Presence: a person outside their presence window (people entering or leaving the room) is neither
   seen nor occluding.
3. Other-person occlusion, per sensor: the ray from the sensor to each joint of a person against the body
   capsules (:data:`skelfuse.sim.profile.CAPSULES`, the profile's radii) of every OTHER present person. A
   hidden joint gets the tracker's guess error (AR(1) with the profile's occluded rho/sigma), is labelled
   LOW with ``occluded_low_prob``, and the skeleton is refitted to its body model (one size factor per
   frame: bones are never perturbed independently). A body whose torso tracking joints are hidden (fewer
   than ``min_torso_joints_in_view`` left) is not tracked by that sensor.
4. Body slots and ids, per sensor: each frame's tracked bodies in a shuffled order (NaN-padded to P
   slots); a body id per sensor that changes whenever the single-person tracker changes it (mirror burst,
   re-acquisition) and when the body is found again after being hidden by others. Ids are per sensor and
   never reused within a sensor.
5. Truth: every person's joints, the person behind each body slot, presence and visibility.

Scenario builders (:func:`crossing_scenario`, :func:`bystander_scenario`, :func:`enter_leave_scenario`,
:func:`crowd_scenario`) return a :class:`CrowdScenario` to pass to :func:`simulate_scenario`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skelfuse.fusion.transform import apply_transform
from skelfuse.schema.skeleton import BONES, MIRROR, N_JOINTS, TORSO_TRACKING_JOINTS, Confidence, J
from skelfuse.sim.body_model import ar1, fit_body_model, segment_distance, symmetric_bone_lengths
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.motion import Motion, axis_rotation, facing_deg
from skelfuse.sim.observe import _group_values, simulate
from skelfuse.sim.profile import CAPSULES, SimProfile
from skelfuse.sim.rig import VirtualSensor, paper_rig

_CAPSULE_START = np.array([J[c[1]] for c in CAPSULES])
_CAPSULE_END = np.array([J[c[2]] for c in CAPSULES])


@dataclass(frozen=True)
class CrowdObservations:
    """What S sensors report about P people over T frames (B = P body slots per sensor, NaN-padded).

    Attributes
    ----------
    sensor_ids : tuple[str, ...]
    positions : (T, S, B, 32, 3) float32, each sensor's camera frame, mm, tracker labels; NaN in empty slots.
    confidence : (T, S, B, 32) uint8 (0 in empty slots).
    valid : (T, S, B) bool, the slot holds a body.
    body_ids : (T, S, B) int64, the tracker's body id (-1 in empty slots).
    person_of_body : (T, S, B) int64, truth: the person in the slot (-1 in empty slots).
    mirrored : (T, S, B) bool, truth: the body's left/right labels are swapped.
    occluded_by_others : (T, S, B, 32) bool, truth, label order: hidden by another person.
    world_from_sensor : (S, 4, 4) true extrinsics.
    world_from_sensor_calibrated : (S, 4, 4) extrinsics with calibration error (what a rig would use).
    truth : (T, P, 32, 3) float64, true joints, world mm.
    present : (T, P) bool, the person is in the room (presence window).
    visible : (T, P) bool, at least one sensor tracks the person.
    times_s : (T,) frame times, s.
    device_time_us : (T, S) int64 master-clock-like device stamps (from person 0's simulation).
    """

    sensor_ids: tuple[str, ...]
    positions: np.ndarray
    confidence: np.ndarray
    valid: np.ndarray
    body_ids: np.ndarray
    person_of_body: np.ndarray
    mirrored: np.ndarray
    occluded_by_others: np.ndarray
    world_from_sensor: np.ndarray
    world_from_sensor_calibrated: np.ndarray
    truth: np.ndarray
    present: np.ndarray
    visible: np.ndarray
    times_s: np.ndarray
    device_time_us: np.ndarray

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_sensors(self) -> int:
        return int(self.positions.shape[1])

    @property
    def n_people(self) -> int:
        return int(self.truth.shape[1])

    def positions_world(self, *, calibrated: bool) -> np.ndarray:
        """(T, S, B, 32, 3) float64 world positions: ``calibrated`` picks the extrinsics with calibration error
        (what a real rig fuses with) or the true ones; no default, so every caller says which."""
        poses = self.world_from_sensor_calibrated if calibrated else self.world_from_sensor
        # apply_transform wants the sensor axis third from last: (T, B, S, 32, 3) there and back.
        by_body = np.swapaxes(self.positions.astype(np.float64), 1, 2)
        return np.swapaxes(apply_transform(poses, by_body), 1, 2)


@dataclass(frozen=True)
class CrowdScenario:
    """A scenario: who moves how, seen by which sensors.

    Attributes
    ----------
    name : str
    motions : list of Motion, one per person (same frame rate; the shortest sets the length).
    sensors : list of VirtualSensor.
    presence_s : per person (start, end) seconds in the room, or None = always.
    """

    name: str
    motions: list[Motion]
    sensors: list[VirtualSensor]
    presence_s: list[tuple[float, float] | None]


def other_person_occlusion(
    points: np.ndarray, occluders: np.ndarray, radii: dict[str, float], margin_mm: float
) -> np.ndarray:
    """Which joints other bodies hide from a camera at the origin.

    Parameters
    ----------
    points : (T, 32, 3) one person's true joints, camera frame, mm.
    occluders : (T, Q, 32, 3) other people's true joints, camera frame; NaN rows (absent people) hide nothing.
    radii : capsule radius per key of :data:`skelfuse.sim.profile.CAPSULES`, mm.
    margin_mm : the occluding surface must lie at least this far in front of the joint along the ray.

    Returns
    -------
    (T, 32) bool
    """
    T, Q = occluders.shape[:2]
    if Q == 0:
        return np.zeros(points.shape[:2], dtype=bool)
    starts = occluders[:, :, _CAPSULE_START].reshape(T, 1, -1, 3)  # (T, 1, Q*C, 3)
    ends = occluders[:, :, _CAPSULE_END].reshape(T, 1, -1, 3)
    radius = np.tile(np.array([radii[c[0]] for c in CAPSULES]), Q)  # (Q*C,)
    joints = points[:, :, None, :]
    ray_dist, s = segment_distance(np.zeros(3), joints, starts, ends)  # (T, 32, Q*C); rays from the camera
    depth = np.linalg.norm(joints, axis=-1)
    with np.errstate(invalid="ignore"):
        hides = (ray_dist < radius) & (s * depth < depth - margin_mm)
    return hides.any(axis=-1)


def simulate_people(
    motions: list[Motion],
    sensors: list[VirtualSensor],
    profile: SimProfile,
    *,
    seed: int,
    presence_s: list[tuple[float, float] | None] | None = None,
) -> CrowdObservations:
    """Simulate what each sensor's body tracker reports about several people (see the module docstring).

    Parameters
    ----------
    motions : one Motion per person.
    sensors : the rig (index 0 is the master).
    profile : observation model parameters.
    seed : everything random derives from it (per person, per sensor streams).
    presence_s : per person (start, end) in seconds, or None for always present.

    Returns
    -------
    CrowdObservations
    """
    if not motions:
        raise ValueError("simulate_people needs at least one motion")
    P, S = len(motions), len(sensors)
    presence_s = [None] * P if presence_s is None else list(presence_s)
    if len(presence_s) != P:
        raise ValueError(f"presence_s must have one entry per person ({P}), got {len(presence_s)}")
    seeds = np.random.SeedSequence([int(seed), 0xC40D]).generate_state(P)
    observed = [simulate(m, sensors, profile, seed=int(s)) for m, s in zip(motions, seeds, strict=True)]
    T = min(o.n_frames for o in observed)
    times = observed[0].times_s[:T]
    truth = np.stack([o.truth[:T] for o in observed], axis=1)  # (T, P, 32, 3)
    present = np.ones((T, P), dtype=bool)
    for p, window in enumerate(presence_s):
        if window is not None:
            present[:, p] = (times >= window[0]) & (times < window[1])

    rng = np.random.default_rng([int(seed), 0xC40D, 1])
    positions = np.full((T, S, P, N_JOINTS, 3), np.nan, dtype=np.float32)
    confidence = np.zeros((T, S, P, N_JOINTS), dtype=np.uint8)
    tracked = np.zeros((T, S, P), dtype=bool)
    per_person_ids = np.full((T, S, P), -1, dtype=np.int64)
    mirrored = np.zeros((T, S, P), dtype=bool)
    hidden_others = np.zeros((T, S, P, N_JOINTS), dtype=bool)
    dropped = np.zeros((T, S), dtype=bool)
    for o in observed:
        dropped |= o.dropped[:T]
    sigma = _group_values(profile.occluded_sigma_mm)
    bone_lengths = [symmetric_bone_lengths(truth[:, p]) for p in range(P)]
    truth_present = np.where(present[:, :, None, None], truth, np.nan)

    for s_idx, sensor in enumerate(sensors):  # loops over sensors and people only (a handful each)
        physical = sensor.to_sensor(truth_present)  # (T, P, 32, 3)
        for p, obs in enumerate(observed):
            others = np.delete(physical, p, axis=1)
            hidden = other_person_occlusion(
                physical[:, p], others, profile.capsule_radius_mm, profile.occlusion_margin_mm
            )
            m = obs.mirrored[:T, s_idx]
            hidden = np.where(m[:, None], hidden[:, MIRROR], hidden)  # label order
            # In view (the tracker labels out-of-view joints NONE; torso joints are never NONE otherwise) and
            # not hidden by someone else: self-occlusion of the trunk by an arm does not stop tracking.
            in_view = obs.confidence[:T, s_idx] > Confidence.NONE
            seen_torso = (in_view & ~hidden)[:, TORSO_TRACKING_JOINTS]
            ok = obs.tracked[:T, s_idx] & present[:, p] & ~dropped[:, s_idx]
            ok &= seen_torso.sum(axis=1) >= profile.min_torso_joints_in_view
            own = obs.positions[:T, s_idx].astype(np.float64)
            conf = obs.confidence[:T, s_idx].copy()
            extra = hidden & ok[:, None] & ~obs.occluded[:T, s_idx]  # newly hidden (self-occlusion already modelled)
            if extra.any():
                guess = ar1(rng, T, (N_JOINTS, 3), profile.occluded_rho, sigma)
                noisy = np.where(extra[:, :, None], own + guess, own)
                rows = np.nonzero(extra.any(axis=1))[0]
                fitted = own.copy()
                # One size factor per frame, read back from the tracker's own skeleton.
                bones = np.linalg.norm(own[rows][:, BONES[:, 1]] - own[rows][:, BONES[:, 0]], axis=-1)
                template = bone_lengths[p][BONES[:, 1]]
                scale = np.median(bones / np.maximum(template, 1e-9), axis=1)
                guessed = extra | obs.occluded[:T, s_idx]
                fitted[rows] = fit_body_model(noisy[rows], bone_lengths[p], scale, guessed[rows])
                own = fitted
                low = extra & (rng.random((T, N_JOINTS)) < profile.occluded_low_prob) & (conf > Confidence.LOW)
                conf[low] = Confidence.LOW
            positions[ok, s_idx, p] = own[ok].astype(np.float32)
            confidence[ok, s_idx, p] = conf[ok]
            tracked[:, s_idx, p] = ok
            per_person_ids[:, s_idx, p] = obs.body_ids[:T, s_idx]
            mirrored[:, s_idx, p] = m & ok
            hidden_others[:, s_idx, p] = hidden & ok[:, None]

    body_ids = _body_ids(tracked, per_person_ids, rng)
    # Shuffle the slots per (frame, sensor): tracked bodies first, in random order.
    keys = np.where(tracked, rng.random((T, S, P)), np.inf)
    order = np.argsort(keys, axis=-1, kind="stable")  # (T, S, P): slot -> person
    valid = np.take_along_axis(tracked, order, axis=-1)
    person_of_body = np.where(valid, order, -1)
    t_idx, s_idx_arr = np.meshgrid(np.arange(T), np.arange(S), indexing="ij")
    t_idx, s_idx_arr = t_idx[..., None], s_idx_arr[..., None]
    return CrowdObservations(
        sensor_ids=tuple(s.sensor_id for s in sensors),
        positions=positions[t_idx, s_idx_arr, order],
        confidence=confidence[t_idx, s_idx_arr, order],
        valid=valid,
        body_ids=np.where(valid, body_ids[t_idx, s_idx_arr, order], -1),
        person_of_body=person_of_body,
        mirrored=mirrored[t_idx, s_idx_arr, order] & valid,
        occluded_by_others=hidden_others[t_idx, s_idx_arr, order],
        world_from_sensor=observed[0].world_from_sensor,
        world_from_sensor_calibrated=observed[0].world_from_sensor_calibrated,
        truth=truth,
        present=present,
        visible=np.asarray(tracked.any(axis=1)),
        times_s=times,
        device_time_us=observed[0].device_time_us[:T],
    )


def _body_ids(tracked: np.ndarray, per_person_ids: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(T, S, P) per-sensor body ids: a new id at every (re)acquisition or single-person id change."""
    T, S, P = tracked.shape
    prev_tracked = np.concatenate([np.zeros((1, S, P), dtype=bool), tracked[:-1]])
    prev_ids = np.concatenate([np.full((1, S, P), -1), per_person_ids[:-1]])
    new = tracked & (~prev_tracked | (per_person_ids != prev_ids))
    segment = np.cumsum(new, axis=0)  # (T, S, P) segment count per (sensor, person)
    out = np.full((T, S, P), -1, dtype=np.int64)
    tie = rng.random((S, P))
    for s in range(S):
        t_new, p_new = np.nonzero(new[:, s])
        order = np.lexsort((tie[s, p_new], t_new))
        ids = np.empty(t_new.size, dtype=np.int64)
        ids[order] = np.arange(1, t_new.size + 1)
        lookup = np.full((P, int(segment[:, s].max(initial=0)) + 1), -1, dtype=np.int64)
        lookup[p_new, segment[t_new, s, p_new]] = ids
        out[:, s] = np.where(tracked[:, s], lookup[np.arange(P)[None, :], segment[:, s]], -1)
    return out


# ----------------------------------------------------------------------------------------------------------
# Scenarios


def place_on_path(motion: Motion, path_xy: ArrayLike, heading_deg: ArrayLike) -> Motion:
    """Move a motion's body along a path: per frame, pelvis over ``path_xy`` (mm), facing ``heading_deg``.

    The body's own horizontal pelvis travel and facing are removed first, so any gesture (walking in
    place, waving) can be carried along any path.
    """
    pos = motion.positions
    n = pos.shape[0]
    path_xy = np.broadcast_to(np.asarray(path_xy, dtype=np.float64), (n, 2))
    heading = np.broadcast_to(np.asarray(heading_deg, dtype=np.float64), (n,))
    local = pos.copy()
    local[:, :, :2] -= pos[:, None, J["PELVIS"], :2]
    turn = axis_rotation("z", np.radians(heading - facing_deg(pos)))  # (n, 3, 3)
    out = np.einsum("tij,tnj->tni", turn, local)
    out[:, :, :2] += path_xy[:, None, :]
    return Motion(f"{motion.name}@path", motion.fps, out)


def _heading_of(path_xy: np.ndarray, fps: float, window_s: float = 0.8, default_deg: float = 0.0) -> np.ndarray:
    """Facing along the direction of travel; a turnaround (or any stretch without a clear direction: a stop,
    a reversal) is a turn of at least ``window_s`` from the last clear heading to the next one, to the left
    when it reverses (within 30° of 180°), else the short way. People cannot turn round in one frame: a body
    that did would mirror every view's left/right at once, a jump no tracker or fusion ever meets."""
    velocity = np.gradient(path_xy, axis=0) * fps
    speed = np.linalg.norm(velocity, axis=1, keepdims=True)
    unit = np.where(speed > 50.0, velocity / np.maximum(speed, 1e-9), 0.0)
    k = max(1, min(round(window_s * fps), len(path_xy)))  # np.convolve's "same" output is the longer of the two
    kernel = np.ones(k) / k
    smooth = np.stack([np.convolve(unit[:, i], kernel, mode="same") for i in range(2)], axis=1)
    heading = np.degrees(np.arctan2(smooth[:, 1], smooth[:, 0]))
    clear = np.linalg.norm(smooth, axis=1) >= 0.3
    n = heading.size
    if not clear.any():
        return np.full(n, float(default_deg))
    out = heading.copy()
    edges = np.diff(np.concatenate([[1], clear.astype(np.int8), [1]]))
    for start, stop in zip(np.nonzero(edges == -1)[0].tolist(), np.nonzero(edges == 1)[0].tolist(), strict=True):
        if start == 0 or stop == n:  # before the first / after the last clear heading: hold it
            out[start:stop] = heading[stop] if start == 0 else heading[start - 1]
            continue
        grow = max(0, k - (stop - start)) // 2  # a turn takes at least window_s, centred on the unclear run
        first, last = max(start - grow, 1), min(stop + grow, n - 1)
        before, after = heading[first - 1], heading[last]
        turn = (after - before) % 360.0  # counter-clockwise (left) angle, [0, 360)
        if abs(turn - 180.0) >= 30.0 and turn > 180.0:
            turn -= 360.0  # not a reversal: the short way
        ramp = (np.arange(first, last) - (first - 1)) / (last - first + 1)
        out[first:last] = before + turn * ramp * ramp * (3.0 - 2.0 * ramp)
    return (out + 180.0) % 360.0 - 180.0


def walker(
    path_xy: np.ndarray,
    *,
    fps: float = 30.0,
    seed: int = 0,
    height_mm: float = 1750.0,
    gesture: str = "walking",
    heading_deg: np.ndarray | float | None = None,
) -> Motion:
    """A person doing ``gesture`` (walking by default) along ``path_xy`` (T, 2) mm, facing the way they go."""
    path_xy = np.asarray(path_xy, dtype=np.float64)
    n = path_xy.shape[0]
    base = make_gesture(gesture, duration_s=n / fps, fps=fps, seed=seed, height_mm=height_mm)
    heading = _heading_of(path_xy, fps) if heading_deg is None else np.broadcast_to(heading_deg, (n,))
    return place_on_path(Motion(base.name, fps, base.positions[:n]), path_xy, heading)


def crossing_scenario(
    *,
    lateral_mm: float = 350.0,
    duration_s: float = 8.0,
    fps: float = 30.0,
    amplitude_mm: float = 1400.0,
    n_sensors: int = 4,
    seed: int = 0,
) -> CrowdScenario:
    """Two people walking back and forth towards each other on parallel lines ``lateral_mm`` apart.

    They pass each other at the centre (pelvis to pelvis ``lateral_mm``) every ``half period`` = 3 s.
    """
    t = np.arange(round(duration_s * fps)) / fps
    x = -amplitude_mm * np.cos(np.pi * t / 3.0)
    a = np.stack([x, np.full_like(x, lateral_mm / 2)], axis=1)
    b = np.stack([-x, np.full_like(x, -lateral_mm / 2)], axis=1)
    motions = [walker(a, fps=fps, seed=seed), walker(b, fps=fps, seed=seed + 1, height_mm=1650.0)]
    return CrowdScenario("crossing", motions, paper_rig(n_sensors), [None, None])


def bystander_scenario(
    *, duration_s: float = 6.0, fps: float = 30.0, n_sensors: int = 4, seed: int = 0
) -> CrowdScenario:
    """A subject at the centre plus a standing bystander that only one sensor's tracker can see."""
    sensors = paper_rig(n_sensors)
    subject = make_gesture("random", duration_s=duration_s, fps=fps, seed=seed)
    spot = _spot_seen_by_one(sensors, avoid_xy=np.zeros(2))
    standing = make_gesture("hands_up_down", duration_s=duration_s, fps=fps, seed=seed + 7, height_mm=1700.0)
    to_centre = np.degrees(np.arctan2(-spot[1], -spot[0]))
    bystander = place_on_path(standing, spot, np.full(standing.n_frames, to_centre))
    return CrowdScenario("bystander", [subject, bystander], sensors, [None, None])


def _spot_seen_by_one(sensors: list[VirtualSensor], avoid_xy: np.ndarray, min_gap_mm: float = 1200.0) -> np.ndarray:
    """The floor spot nearest ``avoid_xy`` (at least min_gap_mm away) where exactly one sensor sees a standing
    person whole and no other sensor sees any torso joint (deterministic grid search)."""
    pose = make_gesture("hands_up_down", duration_s=0.1, seed=0).positions[0]
    pose = pose - np.array([*pose[J["PELVIS"], :2], 0.0])
    grid = np.stack(np.meshgrid(np.arange(-3600, 3601, 100.0), np.arange(-3600, 3601, 100.0)), -1).reshape(-1, 2)
    grid = grid[np.linalg.norm(grid - avoid_xy, axis=1) >= min_gap_mm]
    bodies = pose[None] + np.concatenate([grid, np.zeros((grid.shape[0], 1))], axis=1)[:, None]  # (G, 32, 3)
    whole = np.stack([s.in_view(s.to_sensor(bodies)).all(axis=1) for s in sensors], axis=1)
    torso = np.stack([s.in_view(s.to_sensor(bodies[:, TORSO_TRACKING_JOINTS])).any(axis=1) for s in sensors], axis=1)
    good = (whole.sum(axis=1) == 1) & (torso.sum(axis=1) == 1)
    for sensor in sensors:  # keep clear of the sensors and of their lines of sight to the subject
        start = sensor.position_mm[:2]
        seg = avoid_xy - start
        u = np.clip((grid - start) @ seg / max(float(seg @ seg), 1e-9), 0.0, 1.0)
        good &= np.linalg.norm(grid - (start + u[:, None] * seg), axis=1) >= 700.0
    if not good.any():
        raise ValueError("no floor spot is seen by exactly one sensor of this rig")
    candidates = grid[good]
    return candidates[np.argmin(np.linalg.norm(candidates - avoid_xy, axis=1))]


def enter_leave_scenario(
    *, duration_s: float = 10.0, fps: float = 30.0, n_sensors: int = 4, seed: int = 0
) -> CrowdScenario:
    """Three people: one stays, one walks in from outside the rig and out again, one appears for a while
    (steps in through a door at 2 s, leaves at 7 s)."""
    n = round(duration_s * fps)
    t = np.arange(n) / fps
    stay = place_on_path(make_gesture("random", duration_s=duration_s, fps=fps, seed=seed), (-500.0, -300.0), 30.0)
    # In from x = -4000 to x = 600 (y = 600) over 4 s, pause, out again.
    x = np.interp(t, [0.0, 4.0, 6.0, duration_s], [-4000.0, 600.0, 600.0, -4000.0])
    walk_in = walker(np.stack([x, np.full(n, 600.0)], axis=1), fps=fps, seed=seed + 1, height_mm=1800.0)
    visitor = place_on_path(
        make_gesture("hands_up_down", duration_s=duration_s, fps=fps, seed=seed + 2, height_mm=1600.0),
        (700.0, -700.0),
        150.0,
    )
    return CrowdScenario("enter_leave", [stay, walk_in, visitor], paper_rig(n_sensors), [None, None, (2.0, 7.0)])


def crowd_scenario(
    *, n_people: int = 4, n_sensors: int = 6, duration_s: float = 8.0, fps: float = 30.0, seed: int = 0
) -> CrowdScenario:
    """People walking around the centre on two rings in opposite directions (inner r = 600 mm clockwise,
    outer r = 1100 mm counter-clockwise), so they keep passing and occluding each other."""
    n = round(duration_s * fps)
    t = np.arange(n) / fps
    motions = []
    for p in range(n_people):
        inner = p % 2 == 0
        radius = 600.0 if inner else 1100.0
        omega = (-1.0 if inner else 1.0) * 900.0 / radius  # ~0.9 m/s along the ring
        phase = 2 * np.pi * p / n_people
        angle = phase + omega * t
        path = np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)
        motions.append(walker(path, fps=fps, seed=seed + p, height_mm=1600.0 + 50.0 * (p % 5)))
    return CrowdScenario("crowd", motions, paper_rig(n_sensors), [None] * n_people)


def simulate_scenario(scenario: CrowdScenario, profile: SimProfile, *, seed: int) -> CrowdObservations:
    """:func:`simulate_people` on a scenario."""
    return simulate_people(scenario.motions, scenario.sensors, profile, seed=seed, presence_s=scenario.presence_s)
