"""Procedural ground-truth motion for the paper's six gestures, without any recorded data.

Cycle: a parametric kinematic skeleton (the 32 k4abt joints, bone lengths proportional to the subject's
height) → joint-angle tracks over time for the chosen gesture (smooth, with seeded variation of periods,
amplitudes and a little idle sway) → vectorized forward kinematics over frames (one loop over the 32
joints) → ground contact (the lowest heel or toe touches the floor, except in flight) and foot planting
(the supporting feet do not slide) → placement (facing direction and position in the world).

Body frame used while building a pose: x forward, y left, z up. World frame: z up, floor at z = 0, mm.
``facing_deg`` is measured counter-clockwise from world +x.

The six gestures follow the paper's protocol (Lee et al. 2022, section 3): both hands up and down, a
jump with the hands raised, a squat, a lunge, walking (the subject walks a path and turns), and random
movement in a standing pose (waving arms, leaning, crossing the arms in front of the chest).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from skelfuse.schema.skeleton import N_JOINTS, PARENTS, J
from skelfuse.sim.motion import Motion, axis_rotation

GESTURES = ("hands_up_down", "jump", "squat", "lunge", "walking", "random")

# Rest pose (standing, arms hanging, palms facing the thighs) for a 1750 mm adult: offset of every joint
# from its parent in the body frame (x forward, y left, z up), mm. Proportions after Drillis & Contini's
# segment-length fractions of stature (upper arm 0.186 H, forearm 0.146 H, hand 0.108 H, thigh 0.245 H,
# shank 0.246 H, ankle height 0.039 H), adapted to k4abt's joint placement.
_REST_1750 = {
    "SPINE_NAVEL": (0.0, 0.0, 180.0),
    "SPINE_CHEST": (0.0, 0.0, 150.0),
    "NECK": (0.0, 0.0, 210.0),
    "CLAVICLE_LEFT": (0.0, 35.0, 165.0),
    "SHOULDER_LEFT": (-10.0, 150.0, 0.0),
    "ELBOW_LEFT": (0.0, 0.0, -300.0),
    "WRIST_LEFT": (0.0, 0.0, -250.0),
    "HAND_LEFT": (0.0, 0.0, -80.0),
    "HANDTIP_LEFT": (0.0, 0.0, -90.0),
    "THUMB_LEFT": (40.0, -15.0, -50.0),
    "HIP_LEFT": (0.0, 90.0, -20.0),
    "KNEE_LEFT": (0.0, 0.0, -430.0),
    "ANKLE_LEFT": (0.0, 0.0, -430.0),
    "FOOT_LEFT": (140.0, 0.0, -45.0),
    "HEAD": (10.0, 0.0, 130.0),
    "NOSE": (91.07, -3.06, 30.83),  # 96 mm along the tracker's nose direction in its head frame (HEAD_NOSE_DIRECTION)
    "EYE_LEFT": (80.0, 32.0, 20.0),
    "EAR_LEFT": (-5.0, 75.0, 0.0),
}
_ANKLE_HEIGHT_1750 = 70.0  # heel contact: ankle joint above the floor when the foot is flat, mm
_FOOT_HEIGHT_1750 = 25.0  # toe contact: FOOT joint above the floor when the foot is flat, mm


def rest_offsets(height_mm: float = 1750.0) -> np.ndarray:
    """(32, 3) offset of each joint from its parent in the rest pose, body frame, mm (pelvis: zeros)."""
    offsets = np.zeros((N_JOINTS, 3))
    for name, offset in _REST_1750.items():
        offsets[J[name]] = offset
        if name.endswith("_LEFT"):
            offsets[J[name.replace("_LEFT", "_RIGHT")]] = (offset[0], -offset[1], offset[2])
    return offsets * (height_mm / 1750.0)


class _Angles(dict[str, Any]):
    """Joint-angle tracks in degrees, (T,) each or one constant; missing names are zero."""

    def __init__(self, n_frames: int) -> None:
        super().__init__()
        self.n_frames = n_frames

    def __missing__(self, key: str) -> np.ndarray:
        value = np.zeros(self.n_frames)
        self[key] = value
        return value


def _local_rotations(a: _Angles) -> np.ndarray:
    """(T, 32, 3, 3) local joint rotations from angle tracks (degrees).

    Conventions (left side; the right side mirrors them): shoulder ``abd`` raises the arm sideways,
    ``flex`` forwards, ``add`` swings it horizontally towards the midline, ``twist`` is external rotation
    about the upper-arm axis; ``elbow`` and ``knee`` are flexion; hip ``flex``/``abd``; ``ankle`` > 0
    lifts the toes. Spine ``flex`` bends forward, ``lat`` to the right, ``twist`` turns left.
    """
    n = a.n_frames
    local = np.broadcast_to(np.eye(3), (n, N_JOINTS, 3, 3)).copy()

    def rot(axis: str, deg: np.ndarray) -> np.ndarray:
        return axis_rotation(axis, np.radians(deg))

    for joint, key in (("SPINE_NAVEL", "navel"), ("SPINE_CHEST", "chest"), ("NECK", "neck")):
        # The rotation sits on the joint's parent segment's end: it turns everything above it.
        local[:, J[joint]] = rot("z", a[f"{key}_twist"]) @ rot("y", a[f"{key}_flex"]) @ rot("x", -a[f"{key}_lat"])
    for side, sign in (("LEFT", 1.0), ("RIGHT", -1.0)):
        s = side[0].lower()
        local[:, J[f"CLAVICLE_{side}"]] = rot("x", sign * a[f"{s}_shrug"])
        local[:, J[f"SHOULDER_{side}"]] = (
            rot("z", -sign * a[f"{s}_add"])
            @ rot("x", sign * a[f"{s}_abd"])
            @ rot("y", -a[f"{s}_flex"])
            @ rot("z", sign * a[f"{s}_twist"])
        )
        local[:, J[f"ELBOW_{side}"]] = rot("y", -a[f"{s}_elbow"])
        local[:, J[f"WRIST_{side}"]] = rot("y", -a[f"{s}_wrist"])
        local[:, J[f"HIP_{side}"]] = rot("x", sign * a[f"{s}_hip_abd"]) @ rot("y", -a[f"{s}_hip_flex"])
        local[:, J[f"KNEE_{side}"]] = rot("y", a[f"{s}_knee"])
        local[:, J[f"ANKLE_{side}"]] = rot("y", -a[f"{s}_ankle"])
    return local


def forward_kinematics(
    offsets: np.ndarray, local: np.ndarray, root_rotation: np.ndarray, root_position: np.ndarray
) -> np.ndarray:
    """Joint positions from rest offsets and local rotations, vectorized over frames.

    Parameters
    ----------
    offsets : (32, 3) rest offset of each joint from its parent, mm (pelvis row unused)
    local : (T, 32, 3, 3) rotation of each joint's segment relative to its parent's
    root_rotation : (T, 3, 3) world-from-pelvis rotation
    root_position : (T, 3) pelvis position, mm

    Returns
    -------
    (T, 32, 3) positions: ``p[j] = p[parent] + G[parent] @ offsets[j]``, ``G[j] = G[parent] @ local[j]``.
    """
    n = local.shape[0]
    positions = np.zeros((n, N_JOINTS, 3))
    globals_ = np.zeros((n, N_JOINTS, 3, 3))
    positions[:, 0] = root_position
    globals_[:, 0] = root_rotation @ local[:, 0]
    for joint in range(1, N_JOINTS):  # PARENTS[j] < j for every k4abt joint
        parent = PARENTS[joint]
        positions[:, joint] = positions[:, parent] + globals_[:, parent] @ offsets[joint]
        globals_[:, joint] = globals_[:, parent] @ local[:, joint]
    return positions


def _smooth_noise(rng: np.random.Generator, n: int, fps: float, sd: float, cutoff_hz: float = 0.4) -> np.ndarray:
    """Smooth random track (low-pass Gaussian noise), standard deviation ``sd``."""
    width = max(1.0, fps / (2 * np.pi * cutoff_hz))
    kernel_t = np.arange(-int(4 * width), int(4 * width) + 1)
    kernel = np.exp(-0.5 * (kernel_t / width) ** 2)
    white = rng.standard_normal(n + kernel.size)
    smooth = np.convolve(white, kernel / np.sqrt((kernel**2).sum()), mode="same")[kernel.size // 2 :][:n]
    return sd * smooth


def _raised_cosine(phase: np.ndarray) -> np.ndarray:
    """0 → 1 → 0 over one period of ``phase`` (cycles)."""
    return 0.5 * (1.0 - np.cos(2 * np.pi * phase))


def _bump(t: np.ndarray, centre: float, width: float) -> np.ndarray:
    return np.exp(-0.5 * ((t - centre) / width) ** 2)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def _foot_flat(a: _Angles, s: str, pitch: np.ndarray) -> np.ndarray:
    """Ankle angle that keeps the foot level: the leg chain's pitches cancel."""
    # Foot pitch in the world = pitch - hip_flex + knee - ankle (see _local_rotations); make it zero.
    return pitch - a[f"{s}_hip_flex"] + a[f"{s}_knee"]


def _hands_up_down(a: _Angles, t: np.ndarray, rng: np.random.Generator, fps: float) -> dict:
    period = 3.0 * rng.uniform(0.9, 1.1)
    top = 150.0 * rng.uniform(0.93, 1.07)
    raise_ = _raised_cosine(t / period)
    for s in "lr":
        a[f"{s}_abd"] = 12.0 + top * raise_ + _smooth_noise(rng, t.size, fps, 2.0)
        a[f"{s}_flex"] = 15.0 * raise_
        a[f"{s}_elbow"] = 8.0 + 12.0 * raise_
        a[f"{s}_shrug"] = 12.0 * raise_
        a[f"{s}_twist"] = 40.0 * raise_  # palms turn inwards overhead
    return {"plant": "both"}


def _jump(a: _Angles, t: np.ndarray, rng: np.random.Generator, fps: float) -> dict:
    period = 1.6 * rng.uniform(0.92, 1.08)
    height = 250.0 * rng.uniform(0.8, 1.2)
    flight = 2.0 * np.sqrt(2.0 * height / 9810.0)  # s, ballistic
    u = t % period
    takeoff = 0.55
    crouch = (_bump(u, 0.38, 0.11) + 0.7 * _bump(u, takeoff + flight + 0.15, 0.10)) * rng.uniform(0.9, 1.1)
    tau = (u - takeoff) / flight
    in_air = (tau > 0) & (tau < 1)
    lift = np.where(in_air, 4.0 * height * tau * (1.0 - tau), 0.0)
    a["pitch"] = 22.0 * crouch
    for s in "lr":
        a[f"{s}_hip_flex"] = 50.0 * crouch
        a[f"{s}_knee"] = 60.0 * crouch
        a[f"{s}_ankle"] = _foot_flat(a, s, a["pitch"]) - 25.0 * np.where(in_air, np.sin(np.pi * tau), 0.0)
        a[f"{s}_abd"] = 160.0 + _smooth_noise(rng, t.size, fps, 3.0)
        a[f"{s}_elbow"] = 12.0 + 15.0 * crouch
        a[f"{s}_twist"] = 40.0
        a[f"{s}_shrug"] = 12.0
    return {"plant": "both", "lift": lift}


SQUAT_ARMS = ("forward", "crossed", "hanging")
"""What the arms do in a squat repetition, drawn per repetition: raised forward for balance, folded in front of
the chest (the real takes' occluder: DESIGN.md "arms held in front of the chest double the torso and leg
disagreement"), or hanging."""


def _squat(a: _Angles, t: np.ndarray, rng: np.random.Generator, fps: float) -> dict:
    period = 3.5 * rng.uniform(0.88, 1.12)
    depth = _raised_cosine(t / period) * rng.uniform(0.85, 1.0)
    a["pitch"] = 35.0 * depth
    a["navel_flex"] = -8.0 * depth
    n_reps = int(np.floor(t[-1] / period)) + 1
    styles = rng.integers(0, len(SQUAT_ARMS), n_reps)
    rep = np.minimum(np.floor(t / period).astype(np.int64), n_reps - 1)
    blend = _smoothstep((t - rep * period) / (0.25 * period))  # change style while standing
    previous = styles[np.maximum(rep - 1, 0)]
    for key, per_style in (
        ("flex", lambda d: np.stack([80.0 * d, 65.0 + 0.0 * d, 10.0 * d])),
        ("elbow", lambda d: np.stack([10.0 + 10.0 * d, 120.0 + 0.0 * d, 10.0 + 0.0 * d])),
        ("twist", lambda d: np.stack([0.0 * d, -80.0 + 0.0 * d, 0.0 * d])),
        ("add", lambda d: np.stack([0.0 * d, 15.0 + 0.0 * d, 0.0 * d])),
        ("abd", lambda d: np.stack([8.0 + 0.0 * d, 0.0 * d, 8.0 + 0.0 * d])),
    ):
        table = per_style(depth)  # (styles, T)
        track = table[previous, np.arange(t.size)] * (1 - blend) + table[styles[rep], np.arange(t.size)] * blend
        for s in "lr":
            a[f"{s}_{key}"] = track
    for s in "lr":
        a[f"{s}_hip_flex"] = 115.0 * depth
        a[f"{s}_knee"] = 105.0 * depth
        a[f"{s}_hip_abd"] = 8.0 * depth
        a[f"{s}_ankle"] = _foot_flat(a, s, a["pitch"])
    return {"plant": "both"}


def _lunge(a: _Angles, t: np.ndarray, rng: np.random.Generator, fps: float) -> dict:
    period = 4.0 * rng.uniform(0.9, 1.1)
    rep = np.floor(t / period).astype(np.int64)
    first_left = rng.random() < 0.5
    front_is_left = (rep % 2 == 0) == first_left
    depth = _raised_cosine((t % period) / period) * rng.uniform(0.85, 1.0)
    a["pitch"] = 5.0 * depth
    for s, is_front in (("l", front_is_left), ("r", ~front_is_left)):
        a[f"{s}_hip_flex"] = np.where(is_front, 85.0, -15.0) * depth
        a[f"{s}_knee"] = 90.0 * depth
        flat = _foot_flat(a, s, a["pitch"])
        a[f"{s}_ankle"] = np.where(is_front, flat, flat * (1.0 - 0.7 * depth))
        a[f"{s}_abd"] = 10.0 + 10.0 * depth
        a[f"{s}_elbow"] = 15.0 + 20.0 * depth
    return {"plant": np.where(front_is_left, J["ANKLE_RIGHT"], J["ANKLE_LEFT"])}


def _walking(a: _Angles, t: np.ndarray, rng: np.random.Generator, fps: float) -> dict:
    speed = 1000.0 * rng.uniform(0.9, 1.15)  # mm/s, a comfortable indoor pace
    length = 2000.0 * rng.uniform(0.9, 1.1)  # mm walked between turns
    turn_s = 1.2 * rng.uniform(0.9, 1.1)
    accel_s = 0.5
    walk_s = length / speed + accel_s
    dt = 1.0 / fps
    n = t.size
    # Alternate: walk a straight leg, turn 180° (always to the left) in place, walk back.
    cycle = walk_s + turn_s
    u = t % cycle
    leg = np.floor(t / cycle)
    walking = u < walk_s
    ramp = np.minimum(np.minimum(u / accel_s, (walk_s - u) / accel_s), 1.0)
    v = np.where(walking, speed * _smoothstep(ramp), 0.0)
    turn = np.where(walking, 0.0, _smoothstep((u - walk_s) / turn_s))
    yaw_rel = 180.0 * (leg + turn)
    heading = np.radians(yaw_rel)
    step = np.stack([np.cos(heading), np.sin(heading)], axis=1) * (v * dt)[:, None]
    path = np.cumsum(step, axis=0) - step[0]
    # Gait: stride frequency follows speed (stride ~1.3 m at 1 m/s); steps continue slowly while turning.
    amplitude = np.clip(v / speed, 0.35, 1.0)
    stride_hz = 0.85 * rng.uniform(0.95, 1.05)
    phase = 2 * np.pi * np.cumsum(np.full(n, stride_hz * dt))
    for s, shift in (("l", 0.0), ("r", np.pi)):
        ph = phase + shift
        a[f"{s}_hip_flex"] = amplitude * (7.0 + 20.0 * np.sin(ph))
        a[f"{s}_knee"] = amplitude * (5.0 + 55.0 * ((1.0 + np.cos(ph + 0.4)) / 2.0) ** 4)
        a[f"{s}_ankle"] = _foot_flat(a, s, a["pitch"])
        a[f"{s}_flex"] = -amplitude * 18.0 * np.sin(ph)
        a[f"{s}_elbow"] = 15.0 + amplitude * 10.0 * (1.0 - np.sin(ph))
        a[f"{s}_abd"] = 6.0
    a["navel_twist"] = 4.0 * amplitude * np.sin(phase)
    return {"plant": None, "path": path, "yaw": yaw_rel}


_RANDOM_ACTIONS = ("wave_left", "wave_right", "lean_forward", "lean_side", "cross_arms", "arms_side", "rest")


def _random(a: _Angles, t: np.ndarray, rng: np.random.Generator, fps: float) -> dict:
    n = t.size
    bounds = [0.0]
    while bounds[-1] < t[-1] + 1.0:
        bounds.append(bounds[-1] + rng.uniform(1.6, 3.0))
    bounds_arr = np.array(bounds)
    episode = np.searchsorted(bounds_arr, t, side="right") - 1
    actions = [str(rng.choice(_RANDOM_ACTIONS)) for _ in range(len(bounds))]
    if len(actions) > 1 and actions[0] == "rest":
        actions[0] = "wave_right"
    targets: list[dict[str, float]] = []
    for action in actions:
        target: dict[str, float] = {"l_abd": 8.0, "r_abd": 8.0, "l_elbow": 10.0, "r_elbow": 10.0}
        if action in ("wave_left", "wave_right"):
            s = action[5]
            target |= {
                f"{s}_abd": rng.uniform(90, 120),
                f"{s}_twist": 85.0,
                f"{s}_elbow": 85.0,
                f"{s}_shrug": 8.0,
                f"wave_{s}": 1.0,
            }
        elif action == "lean_forward":
            target |= {"navel_flex": rng.uniform(12, 25), "chest_flex": rng.uniform(5, 12)}
        elif action == "lean_side":
            sign = rng.choice([-1.0, 1.0])
            target |= {
                "navel_lat": sign * rng.uniform(10, 18),
                "chest_lat": sign * rng.uniform(5, 10),
                "l_abd": 8.0 + 10.0 * (sign < 0),
                "r_abd": 8.0 + 10.0 * (sign > 0),
            }
        elif action == "cross_arms":
            target |= {
                "l_flex": 65.0,
                "r_flex": 65.0,
                "l_add": 15.0,
                "r_add": 15.0,
                "l_twist": -80.0,
                "r_twist": -80.0,
                "l_elbow": 120.0,
                "r_elbow": 120.0,
                "l_abd": 0.0,
                "r_abd": 0.0,
            }
        elif action == "arms_side":
            level = rng.uniform(70, 100)
            target |= {"l_abd": level, "r_abd": level, "l_elbow": 10.0, "r_elbow": 10.0}
        targets.append(target)
    keys = sorted({key for target in targets for key in target})
    start = bounds_arr[episode]
    blend = _smoothstep((t - start) / 0.6)
    prev = np.maximum(episode - 1, 0)
    for key in keys:
        values = np.array([target.get(key, 0.0) for target in targets])
        track = values[prev] + (values[episode] - values[prev]) * blend
        if key.startswith("wave_"):
            s = key[-1]
            a[f"{s}_elbow"] = a[f"{s}_elbow"] + track * 30.0 * np.sin(2 * np.pi * 1.8 * t)
            a[f"{s}_add"] = a[f"{s}_add"] + track * 10.0 * np.sin(2 * np.pi * 1.8 * t + 1.0)
        else:
            a[key] = a[key] + track
    a["navel_lat"] = a["navel_lat"] + _smooth_noise(rng, n, fps, 1.5)
    for s in "lr":
        a[f"{s}_ankle"] = _foot_flat(a, s, a["pitch"])
    return {"plant": "both"}


_BUILDERS: dict[str, Callable[..., dict]] = {
    "hands_up_down": _hands_up_down,
    "jump": _jump,
    "squat": _squat,
    "lunge": _lunge,
    "walking": _walking,
    "random": _random,
}


def make_gesture(
    name: str,
    *,
    duration_s: float = 10.0,
    fps: float = 30.0,
    facing_deg: float = 0.0,
    position_mm: tuple[float, float] = (0.0, 0.0),
    seed: int = 0,
    height_mm: float = 1750.0,
) -> Motion:
    """Generate one of the paper's six gestures as ground-truth :class:`Motion`.

    Parameters
    ----------
    name : one of :data:`GESTURES`.
    duration_s : length of the take, s.
    fps : frame rate, Hz.
    facing_deg : direction the subject faces (for ``walking``: the first walking direction), degrees
        counter-clockwise from world +x.
    position_mm : (x, y) world position of the subject (for ``walking``: the centre of the path), mm.
    seed : seeds the variation of periods, amplitudes, the sequence of random actions and idle sway.
    height_mm : stature of the subject; every bone scales with it.

    Returns
    -------
    Motion (T = round(duration_s * fps) frames, world mm, z up, floor at 0).
    """
    if name not in _BUILDERS:
        raise ValueError(f"unknown gesture {name!r}; expected one of {', '.join(GESTURES)}")
    if not (duration_s > 0 and fps > 0 and height_mm > 0):
        raise ValueError(f"duration_s, fps and height_mm must be positive, got {duration_s}, {fps}, {height_mm}")
    rng = np.random.default_rng([seed, GESTURES.index(name)])
    n = max(2, round(duration_s * fps))
    t = np.arange(n) / fps
    a = _Angles(n)
    # Idle sway every standing person shows (small, slow).
    a["neck_flex"] = _smooth_noise(rng, n, fps, 3.0)
    a["neck_twist"] = _smooth_noise(rng, n, fps, 4.0)
    a["chest_lat"] = _smooth_noise(rng, n, fps, 1.0)
    spec = _BUILDERS[name](a, t, rng, fps)
    scale = height_mm / 1750.0
    offsets = rest_offsets(height_mm)
    yaw = facing_deg + spec.get("yaw", 0.0) + _smooth_noise(rng, n, fps, 2.0)
    if spec.get("plant") is None:
        spec["path"] = spec["path"] @ axis_rotation("z", np.radians(facing_deg))[:2, :2].T
    root_rotation = (
        axis_rotation("z", np.radians(yaw))
        @ axis_rotation("y", np.radians(a["pitch"]))
        @ axis_rotation("x", np.radians(a["roll"]))
    )
    positions = forward_kinematics(offsets, _local_rotations(a), root_rotation, np.zeros((n, 3)))
    # Ground contact: the lowest heel (ankle) or toe (FOOT) point touches the floor.
    heel = positions[:, [J["ANKLE_LEFT"], J["ANKLE_RIGHT"]], 2] - _ANKLE_HEIGHT_1750 * scale
    toe = positions[:, [J["FOOT_LEFT"], J["FOOT_RIGHT"]], 2] - _FOOT_HEIGHT_1750 * scale
    lift = np.asarray(spec.get("lift", 0.0))
    z_shift = -np.minimum(heel.min(axis=1), toe.min(axis=1)) + lift
    plant = spec["plant"]
    if plant is None:
        xy_shift = spec["path"]
    elif isinstance(plant, str):  # "both": the mid-ankle point stays put
        xy_shift = -0.5 * (positions[:, J["ANKLE_LEFT"], :2] + positions[:, J["ANKLE_RIGHT"], :2])
    else:  # per-frame planted joint: keep it where the rest pose had it
        planted = positions[np.arange(n), plant, :2]
        rest = forward_kinematics(offsets, _local_rotations(_Angles(1)), np.eye(3)[None], np.zeros((1, 3)))[0]
        rest_xy = (axis_rotation("z", np.radians(yaw))[:, :2, :2] @ rest[plant][:, :2, None])[..., 0]
        xy_shift = rest_xy - planted
    positions = positions + np.concatenate([xy_shift, z_shift[:, None]], axis=1)[:, None, :]
    if plant is None:  # centre the walked path on position_mm
        pelvis_xy = positions[:, J["PELVIS"], :2]
        positions[..., :2] -= 0.5 * (pelvis_xy.min(axis=0) + pelvis_xy.max(axis=0))
    positions[..., 0] += position_mm[0]
    positions[..., 1] += position_mm[1]
    return Motion(name, float(fps), positions)
