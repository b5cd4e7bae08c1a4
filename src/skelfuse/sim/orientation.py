"""Ground-truth joint orientations of a simulated take, and the trackers' orientations as the views report them.

Truth (:func:`truth_orientations`), in the k4abt joint-frame convention (docs/orientations.md), world frame,
built from the simulator's own segment geometry (:mod:`skelfuse.sim.joint_frames`), never from the product's
orientation code (an import-linter contract keeps ``skelfuse.fusion.orientation`` out of ``skelfuse.sim``):

* procedural gestures: the T-pose frame of each joint carried by its segment (torso joints by the line across
  the body their segment holds, limbs by their parent and their own bone), then a twist about each arm and
  hand bone, a smooth random roll (a sum of two slow sines per joint, up to :data:`ARM_TWIST_DEG`), so that
  the twist cannot be guessed from the body and must come from the views. The gestures' forearm roll is
  ASSUMED; their shoulder twist angle is not carried (a limb frame has no twist of its own from its parent);
* BVH motions (:func:`load_bvh_with_orientations`): the recorded segment rotations, fixed to the frames of the
  file's rest pose (built by the same rule) and laid on the k4abt bones by the smallest rotation;
* derived joints (hand tips, feet, face) copy their source joint with the schema's fixed offsets (the SDK
  does the same, measured).

Views (:func:`observe_orientations`): each sensor reports the truth seen through its TRUE pose, turned by a
tracker error: per joint a slow AR(1) rotation vector (rho 0.9 per frame) plus white jitter, the sizes per
body region in :class:`OrientationNoise`. The sizes are set from the real andyj1 3-sensor take (three views of
the same frames, twist left after putting each view on the same bones: median disagreement torso 4-7 deg,
knees 3.5-10, arms 10-21, head 10-24; frame-to-frame change 1-2 deg, hands 4 deg), divided by sqrt(2) for one
view: a rough model of one short take, not a measurement of the tracker in general. Occluded joints get
``occluded_factor`` times more. A mirrored view (``Observations.mirrored``) reports the frames of a body
facing the other way: the true frames of the mirror joints turned 180 deg about the vertical (an ASSUMED
model of the tracker's flip). A view's ankle and head frames then hold the view's own reported foot or nose
bone where the convention puts it (turned by the smallest rotation): the real tracker's ankle frame is rigid to
the foot it reports and its head frame to the face (measured: the same angle or direction in every frame,
docs/orientations.md), so its ankle and head error is that bone's position error; mirrored frames are left as
they are. The derived joints (hand tips, feet, face) copy their
source joint's reported frame with the schema's offsets, as the SDK's do (measured). Where a view tracked
nothing the orientation is NaN.

Nothing here changes the positions the simulator draws: orientations use their own random streams.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skelfuse.schema.errors import DataError
from skelfuse.schema.skeleton import BODY_REGIONS, MIRROR, N_JOINTS, ORIENTATION_AIM_OFFSET, J
from skelfuse.sim.body_model import ar1
from skelfuse.sim.bvh import CMU_UNIT_MM, _roles, bvh_to_k4abt, forward_kinematics, load_bvh, parse_bvh
from skelfuse.sim.joint_frames import (
    AIM_OFFSETS,
    bone_directions,
    matrix_to_quat,
    quat_to_matrix,
    rotvec_to_matrix,
    swing_matrix,
    true_joint_frames,
    with_derived,
)
from skelfuse.sim.motion import Motion, axis_rotation, facing_deg
from skelfuse.sim.observe import Observations

ARM_TWIST_DEG = 35.0
"""Largest simulated roll of an arm or hand bone about itself, deg (assumed)."""

_TWIST_REGIONS = ("arm", "hand")
_HELD_ON_OWN_BONE = np.flatnonzero(np.abs(ORIENTATION_AIM_OFFSET[:, 0]) < 1.0 - 1e-12)  # the ankles and the head
_TURN_180_Z = np.diag([-1.0, -1.0, 1.0])


def truth_orientations(
    positions: np.ndarray, fps: float, *, seed: int, arm_twist_deg: float = ARM_TWIST_DEG
) -> np.ndarray:
    """(T, 32, 4) float64 true world orientations of a take's (T, 32, 3) true positions (module docstring).

    ``arm_twist_deg`` 0 gives the segment frames without the assumed arm and hand roll.
    """
    positions = np.asarray(positions, dtype=np.float64)
    T = positions.shape[0]
    frames = true_joint_frames(positions)
    rng = np.random.default_rng([int(seed), 0x0F1E])
    twisting = np.concatenate([BODY_REGIONS[r] for r in _TWIST_REGIONS])
    t = np.arange(T)[:, None] / float(fps)
    freq = rng.uniform(0.1, 0.5, (2, twisting.size))
    phase = rng.uniform(0.0, 2.0 * np.pi, (2, twisting.size))
    angle = (
        0.5
        * np.radians(arm_twist_deg)
        * (np.sin(2 * np.pi * freq[0] * t + phase[0]) + np.sin(2 * np.pi * freq[1] * t + phase[1]))
    )  # (T, n)
    frames[:, twisting] = frames[:, twisting] @ axis_rotation("x", angle)  # about the local X axis: the bone
    return matrix_to_quat(with_derived(frames))


@dataclass(frozen=True)
class OrientationNoise:
    """Tracker orientation error per body region (see the module docstring for where the sizes come from).

    Attributes
    ----------
    slow_sigma_deg : dict region -> SD of each axis of the slow (AR(1)) error rotation vector, deg.
    slow_rho : AR(1) coefficient per frame.
    white_sigma_deg : dict region -> SD of each axis of the white jitter, deg.
    occluded_factor : multiplier of both for joints the view does not see.
    """

    slow_sigma_deg: dict[str, float] = field(
        default_factory=lambda: {
            "torso": 3.0,
            "head": 7.0,
            "face": 7.0,
            "arm": 8.0,
            "hand": 10.0,
            "knee": 4.0,
            "foot": 5.0,
        }
    )
    slow_rho: float = 0.9
    white_sigma_deg: dict[str, float] = field(
        default_factory=lambda: {
            "torso": 0.7,
            "head": 1.0,
            "face": 1.0,
            "arm": 1.3,
            "hand": 2.8,
            "knee": 1.0,
            "foot": 1.0,
        }
    )
    occluded_factor: float = 2.0

    def per_joint(self) -> tuple[np.ndarray, np.ndarray]:
        """(32,) slow and white SDs in radians."""
        slow = np.zeros(N_JOINTS)
        white = np.zeros(N_JOINTS)
        for region, joints in BODY_REGIONS.items():
            slow[joints] = np.radians(self.slow_sigma_deg[region])
            white[joints] = np.radians(self.white_sigma_deg[region])
        return slow, white


def observe_orientations(
    obs: Observations, truth: np.ndarray, *, seed: int, noise: OrientationNoise | None = None
) -> np.ndarray:
    """The views' joint orientations of one simulated take, each in its sensor's own frame.

    Parameters
    ----------
    obs : Observations of :func:`skelfuse.sim.observe.simulate` (its ``mirrored``, ``tracked``, ``occluded``
        and true poses are used).
    truth : (T, 32, 4) true world orientations (:func:`truth_orientations`).
    seed : random seed of the tracker errors (separate from the position streams).
    noise : OrientationNoise; default the module's.

    Returns
    -------
    (T, S, 32, 4) float32 quaternions w, x, y, z in each sensor's frame; NaN where the view tracked nothing.
    """
    noise = OrientationNoise() if noise is None else noise
    truth = np.asarray(truth, dtype=np.float64)
    T, S = obs.n_frames, obs.n_sensors
    slow_sd, white_sd = noise.per_joint()
    sensor_from_world = np.swapaxes(np.asarray(obs.world_from_sensor)[:, :3, :3], -1, -2)  # (S, 3, 3)
    true_frames = quat_to_matrix(truth)
    # A mirrored view: the frames of the mirror joints, turned 180 deg about the vertical.
    mirrored_frames = _TURN_180_Z @ true_frames[:, MIRROR]
    out = np.full((T, S, N_JOINTS, 4), np.nan, dtype=np.float32)
    for s in range(S):  # a handful of sensors; everything inside is vectorized over frames and joints
        rng = np.random.default_rng([int(seed), 0x0F1F, s])
        slow = ar1(rng, T, (N_JOINTS, 3), noise.slow_rho, slow_sd[:, None])
        white = rng.standard_normal((T, N_JOINTS, 3)) * white_sd[:, None]
        factor = np.where(np.asarray(obs.occluded)[:, s, :, None], noise.occluded_factor, 1.0)
        error = rotvec_to_matrix(factor * (slow + white))
        world = np.where(np.asarray(obs.mirrored)[:, s, None, None, None], mirrored_frames, true_frames)
        seen_frames = sensor_from_world[s] @ world @ error
        held = ~np.asarray(obs.mirrored)[:, s]
        seen = matrix_to_quat(with_derived(_held_on_own_bones(seen_frames, np.asarray(obs.positions)[:, s], held)))
        tracked = np.asarray(obs.tracked)[:, s] & np.isfinite(np.asarray(obs.positions)[:, s]).all(axis=(-1, -2))
        out[:, s] = np.where(tracked[:, None, None], seen, np.nan)
    return out


def _held_on_own_bones(frames: np.ndarray, positions: np.ndarray, held: np.ndarray) -> np.ndarray:
    """(T, 32, 3, 3) a view's frames with its ankles and head turned by the smallest rotation that puts their aim
    axis on the view's own (T, 32, 3) foot or nose bone, in the frames where ``held`` (T,) and the bone is known."""
    joints = _HELD_ON_OWN_BONE
    aim = frames[:, joints] @ np.swapaxes(AIM_OFFSETS[joints], -1, -2)  # the aim frames: X on the foot or nose
    bone = bone_directions(np.asarray(positions, dtype=np.float64))[:, joints]
    swung = swing_matrix(aim[..., 0], bone) @ aim @ AIM_OFFSETS[joints]
    use = held[:, None] & np.isfinite(bone).all(axis=-1) & np.isfinite(swung).all(axis=(-1, -2))
    out = frames.copy()
    out[:, joints] = np.where(use[..., None, None], swung, frames[:, joints])
    return out


# The BVH segment whose rotation carries each k4abt joint's frame (its bone, and the twist about it); None for
# the derived joints (copied from their source).
_BVH_SEGMENT: dict[str, str] = {
    "PELVIS": "hips",
    "SPINE_NAVEL": "spine_low",
    "SPINE_CHEST": "spine_high",
    "NECK": "neck",
    "HEAD": "head",
    **{
        f"{joint}_{side.upper()}": f"{side[0].lower()}_{segment}"
        for side in ("Left", "Right")
        for joint, segment in (
            ("CLAVICLE", "collar"),
            ("SHOULDER", "shoulder"),
            ("ELBOW", "elbow"),
            ("WRIST", "wrist"),
            ("HAND", "hand"),
            ("THUMB", "wrist"),
            ("HIP", "upleg"),
            ("KNEE", "knee"),
            ("ANKLE", "ankle"),
        )
    },
}
_BVH_TO_WORLD = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # as load_bvh: (x, y, z) -> (z, x, y)


def load_bvh_with_orientations(
    path: str | Path,
    *,
    fps_out: float = 30.0,
    position_mm: tuple[float, float] = (0.0, 0.0),
    facing_deg_: float = 0.0,
    unit_mm: float = CMU_UNIT_MM,
) -> tuple[Motion, np.ndarray]:
    """A CMU BVH take as :func:`skelfuse.sim.bvh.load_bvh` loads it, and its true joint orientations.

    Each k4abt joint's frame rides on one BVH segment (``_BVH_SEGMENT``): at the file's T-pose (frame 0,
    which the CMU conversion prepends; its arms hang) the offset between that segment's rotation and the
    joint's frame in that pose (:func:`~skelfuse.sim.joint_frames.true_joint_frames`, the rule of the
    procedural motions) is fixed; in every frame the segment's rotation times that offset gives the frame,
    swung onto the k4abt bone exactly (the k4abt points are not all on the segment's axis). Rotations are
    taken at the nearest source frame (CMU's 120 Hz to 30 Hz is exact).

    Returns
    -------
    motion : Motion, the same as ``load_bvh(path, fps_out=..., position_mm=..., facing_deg=..., unit_mm=...)``.
    orientations : (T, 32, 4) float64 world quaternions w, x, y, z, k4abt convention.

    Raises
    ------
    DataError
        As :func:`~skelfuse.sim.bvh.load_bvh`.
    """
    path = Path(path)
    motion = load_bvh(path, fps_out=fps_out, position_mm=position_mm, facing_deg=facing_deg_, unit_mm=unit_mm)
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"cannot read BVH file {path}: {exc}") from None
    bvh = parse_bvh(text, source=str(path))
    role = _roles(bvh, str(path))
    world_rest = bvh_to_k4abt(bvh, source=str(path), unit_mm=unit_mm)[..., [2, 0, 1]]  # all frames, T-pose first
    _, rotations = forward_kinematics(bvh)
    joints = [J[name] for name in _BVH_SEGMENT]
    segments = [role[_BVH_SEGMENT[name]] for name in _BVH_SEGMENT]
    segment_frames = _BVH_TO_WORLD @ rotations[:, segments]  # (F, n, 3, 3), world axes
    rest = true_joint_frames(world_rest[:1])[0, joints]  # the rest pose's frames, by the gestures' own rule
    offset = np.swapaxes(segment_frames[0], -1, -2) @ rest  # fixed per joint
    fps_in = 1.0 / bvh.frame_time_s
    if abs(fps_in - round(fps_in)) < 1e-4 * fps_in:
        fps_in = float(round(fps_in))
    source = 1 + np.rint(np.arange(motion.n_frames) * fps_in / motion.fps).astype(np.int64)
    source = np.minimum(source, segment_frames.shape[0] - 1)
    # load_bvh turned the take about z so that its first frame faces facing_deg_: the same turn here.
    unturned = Motion(motion.name, fps_in, world_rest[1:]).resampled(fps_out).positions[0]
    turn = np.radians(facing_deg_ - float(facing_deg(unturned)))
    frames = np.full((motion.n_frames, N_JOINTS, 3, 3), np.nan)
    frames[:, joints] = axis_rotation("z", turn) @ segment_frames[source] @ offset
    aims = bone_directions(motion.positions)
    frames = frames @ np.swapaxes(AIM_OFFSETS, -1, -2)  # aim frames (the ankles' X on the foot), swung, turned back
    frames = swing_matrix(frames[..., 0], aims) @ frames @ AIM_OFFSETS
    return motion, matrix_to_quat(with_derived(frames))
