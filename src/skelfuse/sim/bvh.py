"""Load real motion capture (BVH) as a 32-joint k4abt :class:`~skelfuse.sim.motion.Motion`.

Cycle: parse the hierarchy (joints, offsets, channel orders) and the motion table → vectorized forward
kinematics over all frames (one loop over the ~31 BVH joints, numpy over frames) → map BVH joints onto
the k4abt joints, deriving those BVH lacks (pelvis centre, clavicles, head centre, face, hand, hand tip,
thumb) as points fixed in a BVH segment's frame, so every derived bone keeps a constant length →
convert Y-up BVH units to our z-up world in millimetres → place and turn the take → resample.

Both CMU BVH naming variants of B. Hahne's conversion are understood: the MotionBuilder-friendly one
(``Hips, LHipJoint, LeftUpLeg, LeftLeg, LeftFoot, LeftToeBase, LowerBack, Spine, Spine1, Neck, Neck1,
Head, LeftShoulder, LeftArm, LeftForeArm, LeftHand, LeftFingerBase, LeftHandIndex1, LThumb``) and the
3dsMax-friendly one (``Hips, LHipJoint, LeftHip, LeftKnee, LeftAnkle, LeftToe, lowerback, Chest, Chest2,
lowerneck, Neck, Head, LeftCollar, LeftShoulder, LeftElbow, LeftWrist, lhand, LFingers, LThumb``).
Note that ``LeftShoulder`` and ``Neck`` mean different bones in the two variants.

BVH conventions (CMU): Y up, the actor faces +Z in the rest pose with its left side towards +X. We map
BVH (x, y, z) to world (z, x, y): forward → +x, left → +y, up → +z (a proper rotation, no mirroring).

References
----------
CMU Graphics Lab Motion Capture Database, http://mocap.cs.cmu.edu (BVH by B. Hahne / cgspeed).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skelfuse.schema.errors import DataError
from skelfuse.schema.skeleton import N_JOINTS, J
from skelfuse.sim.motion import Motion, axis_rotation, facing_deg

CMU_UNIT_MM = 25.4 / 0.45
"""One CMU length unit in millimetres: the ASF files store inches scaled by 0.45 (about 0.0564 m)."""

# Role → BVH joint name, per naming variant. Roles are what the k4abt mapping below needs.
_ROLES_MOTIONBUILDER = {
    "hips": "Hips",
    "l_upleg": "LeftUpLeg",
    "l_knee": "LeftLeg",
    "l_ankle": "LeftFoot",
    "l_toe": "LeftToeBase",
    "r_upleg": "RightUpLeg",
    "r_knee": "RightLeg",
    "r_ankle": "RightFoot",
    "r_toe": "RightToeBase",
    "spine_low": "Spine",
    "spine_high": "Spine1",
    "neck": "Neck1",
    "head": "Head",
    "l_collar": "LeftShoulder",
    "l_shoulder": "LeftArm",
    "l_elbow": "LeftForeArm",
    "l_wrist": "LeftHand",
    "l_hand": "LeftFingerBase",
    "l_fingers": "LeftHandIndex1",
    "l_thumb": "LThumb",
    "r_collar": "RightShoulder",
    "r_shoulder": "RightArm",
    "r_elbow": "RightForeArm",
    "r_wrist": "RightHand",
    "r_hand": "RightFingerBase",
    "r_fingers": "RightHandIndex1",
    "r_thumb": "RThumb",
}
_ROLES_3DSMAX = {
    "hips": "Hips",
    "l_upleg": "LeftHip",
    "l_knee": "LeftKnee",
    "l_ankle": "LeftAnkle",
    "l_toe": "LeftToe",
    "r_upleg": "RightHip",
    "r_knee": "RightKnee",
    "r_ankle": "RightAnkle",
    "r_toe": "RightToe",
    "spine_low": "Chest",
    "spine_high": "Chest2",
    "neck": "Neck",
    "head": "Head",
    "l_collar": "LeftCollar",
    "l_shoulder": "LeftShoulder",
    "l_elbow": "LeftElbow",
    "l_wrist": "LeftWrist",
    "l_hand": "lhand",
    "l_fingers": "LFingers",
    "l_thumb": "LThumb",
    "r_collar": "RightCollar",
    "r_shoulder": "RightShoulder",
    "r_elbow": "RightElbow",
    "r_wrist": "RightWrist",
    "r_hand": "rhand",
    "r_fingers": "RFingers",
    "r_thumb": "RThumb",
}

# Face points relative to the head centre, mm for a 1750 mm adult, in BVH head axes (x left, y up,
# z forward). Anthropometric rough values: nose tip ~96 mm from the head centre along the tracker's own nose
# direction in its head frame (the schema's HEAD_NOSE_DIRECTION), eyes ~32 mm either side of the midline, ears
# ~75 mm to the side.
_FACE_MM = {
    "NOSE": (-3.06, 30.83, 91.07),
    "EYE_LEFT": (32.0, 20.0, 80.0),
    "EYE_RIGHT": (-32.0, 20.0, 80.0),
    "EAR_LEFT": (75.0, 0.0, -5.0),
    "EAR_RIGHT": (-75.0, 0.0, -5.0),
}
# Hand points as fractions of the forearm length (wrist→knuckles ~0.35, wrist→fingertip ~0.7,
# wrist→thumb tip ~0.3 of the forearm in adult anthropometry; CMU's own hand segments are stubs).
_HAND_FRACTION = 0.35
_HANDTIP_FRACTION = 0.70
_THUMB_FRACTION = 0.30


@dataclass
class BvhJoint:
    """One joint of a BVH hierarchy."""

    name: str
    parent: int
    offset: np.ndarray  # (3,) in the parent's frame, BVH units
    channels: list[str] = field(default_factory=list)
    end_offset: np.ndarray | None = None  # (3,) End Site offset, if any


@dataclass
class BvhData:
    """A parsed BVH file: hierarchy plus the motion table."""

    joints: list[BvhJoint]
    frame_time_s: float
    motion: np.ndarray  # (F, n_channels)

    def index(self, name: str) -> int:
        for idx, joint in enumerate(self.joints):
            if joint.name == name:
                return idx
        raise KeyError(name)


def parse_bvh(text: str, *, source: str = "<string>") -> BvhData:
    """Parse BVH text into its hierarchy and motion table.

    Raises
    ------
    DataError
        When the text is not a well-formed BVH file (naming the source and what was expected).
    """
    tokens = text.split()
    pos = 0

    def fail(message: str) -> DataError:
        return DataError(f"{source}: malformed BVH: {message} (near token {pos})")

    def take() -> str:
        nonlocal pos
        if pos >= len(tokens):
            raise fail("unexpected end of file")
        pos += 1
        return tokens[pos - 1]

    def expect(word: str) -> None:
        got = take()
        if got != word:
            raise fail(f"expected {word!r}, got {got!r}")

    def number() -> float:
        word = take()
        try:
            return float(word)
        except ValueError:
            raise fail(f"expected a number, got {word!r}") from None

    expect("HIERARCHY")
    joints: list[BvhJoint] = []
    stack: list[int] = []
    word = take()
    if word != "ROOT":
        raise fail(f"expected 'ROOT', got {word!r}")
    while True:
        # here `word` is ROOT/JOINT/End
        if word in ("ROOT", "JOINT"):
            name = take()
            expect("{")
            expect("OFFSET")
            offset = np.array([number(), number(), number()])
            expect("CHANNELS")
            n_channels_word = take()
            if not n_channels_word.isdigit():
                raise fail(f"expected a channel count, got {n_channels_word!r}")
            channels = [take() for _ in range(int(n_channels_word))]
            valid = {"Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation"}
            if bad := [c for c in channels if c not in valid]:
                raise fail(f"joint {name!r} has unknown channel(s) {bad}")
            parent = stack[-1] if stack else -1
            if word == "JOINT" and parent < 0:
                raise fail(f"JOINT {name!r} outside the ROOT block")
            joints.append(BvhJoint(name, parent, offset, channels))
            stack.append(len(joints) - 1)
        elif word == "End":
            expect("Site")
            expect("{")
            expect("OFFSET")
            if not stack:
                raise fail("End Site outside any joint")
            joints[stack[-1]].end_offset = np.array([number(), number(), number()])
            expect("}")
        elif word == "}":
            if not stack:
                raise fail("unbalanced '}'")
            stack.pop()
            if not stack:
                break
        else:
            raise fail(f"expected 'JOINT', 'End Site' or '}}', got {word!r}")
        word = take()

    expect("MOTION")
    expect("Frames:")
    n_frames_word = take()
    if not n_frames_word.isdigit():
        raise fail(f"expected a frame count after 'Frames:', got {n_frames_word!r}")
    n_frames = int(n_frames_word)
    expect("Frame")
    expect("Time:")
    frame_time = number()
    if not frame_time > 0:
        raise fail(f"Frame Time must be positive, got {frame_time}")
    n_channels = sum(len(j.channels) for j in joints)
    values = tokens[pos:]
    if len(values) != n_frames * n_channels:
        raise DataError(
            f"{source}: malformed BVH: the motion section holds {len(values)} numbers, expected "
            f"{n_frames} frames x {n_channels} channels = {n_frames * n_channels}"
        )
    try:
        motion = np.array(values, dtype=np.float64).reshape(n_frames, n_channels)
    except ValueError as exc:
        raise DataError(f"{source}: malformed BVH: non-numeric value in the motion section ({exc})") from None
    if not np.isfinite(motion).all():
        raise DataError(f"{source}: malformed BVH: the motion section holds NaN or Inf")
    if n_frames < 1:
        raise DataError(f"{source}: BVH holds no frames")
    return BvhData(joints, frame_time, motion)


def forward_kinematics(bvh: BvhData) -> tuple[np.ndarray, np.ndarray]:
    """Global joint positions and orientations of every BVH joint over all frames.

    Rotations compose in the order the channels are listed (``Zrotation Yrotation Xrotation`` means
    ``R = Rz @ Ry @ Rx``); a joint's position is its parent's position plus the parent's global rotation
    applied to the joint's offset. Vectorized over frames.

    Returns
    -------
    positions : (F, n_joints, 3) BVH units, BVH axes
    rotations : (F, n_joints, 3, 3) global rotation of each joint's frame
    """
    n_frames = bvh.motion.shape[0]
    n = len(bvh.joints)
    positions = np.zeros((n_frames, n, 3))
    rotations = np.zeros((n_frames, n, 3, 3))
    column = 0
    for idx, joint in enumerate(bvh.joints):
        local = np.broadcast_to(np.eye(3), (n_frames, 3, 3)).copy()
        translation = np.zeros((n_frames, 3))
        for channel in joint.channels:
            values = bvh.motion[:, column]
            column += 1
            axis = channel[0].lower()
            if channel.endswith("position"):
                translation[:, "xyz".index(axis)] = values
            else:
                local = local @ axis_rotation(axis, np.radians(values))
        if joint.parent < 0:
            positions[:, idx] = joint.offset + translation
            rotations[:, idx] = local
        else:
            parent_rot = rotations[:, joint.parent]
            positions[:, idx] = positions[:, joint.parent] + np.einsum(
                "fij,fj->fi", parent_rot, joint.offset + translation
            )
            rotations[:, idx] = parent_rot @ local
    return positions, rotations


def _roles(bvh: BvhData, source: str) -> dict[str, int]:
    names = {j.name for j in bvh.joints}
    for table in (_ROLES_MOTIONBUILDER, _ROLES_3DSMAX):
        if set(table.values()) <= names:
            return {role: bvh.index(name) for role, name in table.items()}
    missing_mb = sorted(set(_ROLES_MOTIONBUILDER.values()) - names)
    missing_max = sorted(set(_ROLES_3DSMAX.values()) - names)
    raise DataError(
        f"{source}: BVH joint names match neither CMU variant; missing for MotionBuilder naming: "
        f"{missing_mb}; missing for 3dsMax naming: {missing_max}"
    )


def bvh_to_k4abt(bvh: BvhData, *, source: str = "<string>", unit_mm: float = CMU_UNIT_MM) -> np.ndarray:
    """Map a parsed CMU BVH onto the 32 k4abt joints.

    Returns
    -------
    (F, 32, 3) float64 in BVH axes (Y up), millimetres. Every k4abt joint is a point fixed in one BVH
    segment's frame, so all k4abt bone lengths are constant over frames.
    """
    role = _roles(bvh, source)
    positions, rotations = forward_kinematics(bvh)
    joints = bvh.joints

    def at(role_name: str, local: np.ndarray | None = None) -> np.ndarray:
        idx = role[role_name]
        if local is None:
            return positions[:, idx]
        return positions[:, idx] + np.einsum("fij,j->fi", rotations[:, idx], local)

    def offset_of(role_name: str) -> np.ndarray:
        return joints[role[role_name]].offset

    def unit(vector: np.ndarray, what: str) -> np.ndarray:
        norm = np.linalg.norm(vector)
        if norm < 1e-9:
            raise DataError(f"{source}: BVH segment {what} has zero length; cannot derive k4abt joints")
        return vector / norm

    out = np.zeros((positions.shape[0], N_JOINTS, 3))
    # The BVH root is the pelvis. (Putting k4abt's pelvis lower, nearer the hip joints, would need a point
    # fixed in the Hips frame, and the spine rotates about the root, so pelvis→navel would stretch.)
    out[:, J["PELVIS"]] = at("hips")
    out[:, J["SPINE_NAVEL"]] = at("spine_low")
    out[:, J["SPINE_CHEST"]] = at("spine_high")
    out[:, J["NECK"]] = at("neck")
    head_end = joints[role["head"]].end_offset
    head_len = np.linalg.norm(head_end) if head_end is not None else 1.7
    head_up = unit(head_end, "Head End Site") if head_end is not None else np.array([0.0, 1.0, 0.0])
    head_centre = 0.5 * head_len * head_up
    # HEAD is the head segment's origin (the top of the neck, near ear level): a point fixed in the Neck
    # segment, so NECK→HEAD keeps its length; the face points ride on the head segment around its centre.
    out[:, J["HEAD"]] = at("head")
    # Body size factor for the fixed-size face offsets: leg + spine chain height versus a 1750 mm adult
    # (about 0.55 of stature for hip→head-top in BVH rest offsets, see README).
    stature_units = (
        abs(offset_of("l_upleg")[1])
        + abs(offset_of("l_knee")[1])
        + abs(offset_of("l_ankle")[1])
        + abs(offset_of("spine_low")[1])
        + abs(offset_of("spine_high")[1])
        + abs(offset_of("neck")[1])
        + abs(joints[role["head"]].offset[1])
        + head_len
    )
    face_scale = np.clip(stature_units * unit_mm / 1750.0, 0.6, 1.4) / unit_mm
    for name, local_mm in _FACE_MM.items():
        out[:, J[name]] = at("head", head_centre + face_scale * np.array(local_mm))
    for side, k4a in (("l", "LEFT"), ("r", "RIGHT")):
        out[:, J[f"CLAVICLE_{k4a}"]] = at(f"{side}_collar", 0.3 * offset_of(f"{side}_shoulder"))
        out[:, J[f"SHOULDER_{k4a}"]] = at(f"{side}_shoulder")
        out[:, J[f"ELBOW_{k4a}"]] = at(f"{side}_elbow")
        out[:, J[f"WRIST_{k4a}"]] = at(f"{side}_wrist")
        forearm = np.linalg.norm(offset_of(f"{side}_wrist"))
        finger_dir = unit(offset_of(f"{side}_fingers"), f"{side}_fingers")
        out[:, J[f"HAND_{k4a}"]] = at(f"{side}_hand", _HAND_FRACTION * forearm * finger_dir)
        out[:, J[f"HANDTIP_{k4a}"]] = at(f"{side}_hand", _HANDTIP_FRACTION * forearm * finger_dir)
        thumb_end = joints[role[f"{side}_thumb"]].end_offset
        thumb_dir = unit(thumb_end if thumb_end is not None else offset_of(f"{side}_fingers"), f"{side}_thumb")
        out[:, J[f"THUMB_{k4a}"]] = at(f"{side}_thumb", _THUMB_FRACTION * forearm * thumb_dir)
        out[:, J[f"HIP_{k4a}"]] = at(f"{side}_upleg")
        out[:, J[f"KNEE_{k4a}"]] = at(f"{side}_knee")
        out[:, J[f"ANKLE_{k4a}"]] = at(f"{side}_ankle")
        out[:, J[f"FOOT_{k4a}"]] = at(f"{side}_toe")
    return out * unit_mm


def load_bvh(
    path: str | Path,
    *,
    fps_out: float = 30.0,
    position_mm: tuple[float, float] = (0.0, 0.0),
    facing_deg: float = 0.0,
    unit_mm: float = CMU_UNIT_MM,
    drop_first_frame: bool = True,
    start_s: float = 0.0,
    end_s: float | None = None,
    repeat: int = 1,
) -> Motion:
    """Load a CMU BVH file as a k4abt :class:`Motion` in the world frame.

    Parameters
    ----------
    path : BVH file (either CMU naming variant).
    fps_out : frame rate of the returned motion, Hz.
    position_mm : (x, y) world position, mm, where the centre of the pelvis's horizontal path is put.
    facing_deg : direction, degrees counter-clockwise from world +x, the subject faces in its first frame.
    unit_mm : millimetres per BVH unit (CMU: 25.4 / 0.45 ≈ 56.44).
    drop_first_frame : drop frame 0, the T-pose the CMU conversion prepends.
    start_s, end_s : keep only this segment of the take, s from its first (kept) frame; None: to the end.
        E.g. 13_29.bvh's squats are ``start_s=31.5, end_s=37.5``.
    repeat : play the segment this many times in a row (a longer take of a repeated movement). Each copy
        starts where the recording's segment starts, so the seam jumps by however far the segment's last
        frame is from its first: pick a segment that ends about where it begins.

    Returns
    -------
    Motion named after the file stem, world frame (z up), mm. Heights are kept as recorded (CMU's floor
    is at y = 0).

    Raises
    ------
    DataError
        The file is missing, unreadable, or not a CMU-style BVH.
    ValueError
        ``repeat`` below 1, or a segment with fewer than two frames.
    """
    if repeat < 1:
        raise ValueError(f"repeat must be at least 1, got {repeat}")
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"cannot read BVH file {path}: {exc}") from None
    bvh = parse_bvh(text, source=str(path))
    if drop_first_frame:
        if bvh.motion.shape[0] < 2:
            raise DataError(f"{path}: BVH holds {bvh.motion.shape[0]} frame(s); need the T-pose plus motion")
        bvh.motion = bvh.motion[1:]
    positions_bvh = bvh_to_k4abt(bvh, source=str(path), unit_mm=unit_mm)
    # BVH (x left, y up, z forward) → world (x forward, y left, z up).
    positions = positions_bvh[..., [2, 0, 1]]
    fps_in = 1.0 / bvh.frame_time_s
    if abs(fps_in - round(fps_in)) < 1e-4 * fps_in:  # CMU writes 1/120 s as ".0083333"
        fps_in = float(round(fps_in))
    first = int(np.ceil(start_s * fps_in - 1e-9))
    last = positions.shape[0] if end_s is None else int(np.floor(end_s * fps_in + 1e-9)) + 1
    segment = positions[max(first, 0) : last]
    if segment.shape[0] < 2:
        raise ValueError(
            f"{path}: the segment {start_s}..{end_s} s holds {segment.shape[0]} frame(s) of a "
            f"{positions.shape[0] / fps_in:.1f} s take; pick start_s/end_s inside it"
        )
    motion = Motion(path.stem, fps_in, np.concatenate([segment] * repeat)).resampled(fps_out)
    return Motion(motion.name, motion.fps, _place(motion.positions, position_mm=position_mm, facing_deg_=facing_deg))


def _place(positions: np.ndarray, *, position_mm: tuple[float, float], facing_deg_: float) -> np.ndarray:
    """Turn the take about z so the first frame faces ``facing_deg_``, centre its pelvis path on position."""
    turn = np.radians(facing_deg_ - float(facing_deg(positions[0])))
    rotation = axis_rotation("z", turn)
    positions = positions @ rotation.T
    pelvis_xy = positions[:, J["PELVIS"], :2]
    centre = 0.5 * (pelvis_xy.min(axis=0) + pelvis_xy.max(axis=0))
    shift = np.array([position_mm[0] - centre[0], position_mm[1] - centre[1], 0.0])
    return positions + shift
