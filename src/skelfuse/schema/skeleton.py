"""The Azure Kinect body-tracking joint set, shared by every part of skelfuse.

The 32 joints are in k4abt SDK order (``k4abt_joint_id_t`` in ``k4abttypes.h``), so index ``j`` here is
index ``j`` in every SDK skeleton, recording and payload. The SDK header spells joint 1
``K4ABT_JOINT_SPINE_NAVEL`` while its documentation says "SPINE_NAVAL"; we follow the header.

Everything here is a constant numpy array, so the fusion core can index with it without Python loops.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np

JOINT_NAMES: tuple[str, ...] = (
    "PELVIS",
    "SPINE_NAVEL",
    "SPINE_CHEST",
    "NECK",
    "CLAVICLE_LEFT",
    "SHOULDER_LEFT",
    "ELBOW_LEFT",
    "WRIST_LEFT",
    "HAND_LEFT",
    "HANDTIP_LEFT",
    "THUMB_LEFT",
    "CLAVICLE_RIGHT",
    "SHOULDER_RIGHT",
    "ELBOW_RIGHT",
    "WRIST_RIGHT",
    "HAND_RIGHT",
    "HANDTIP_RIGHT",
    "THUMB_RIGHT",
    "HIP_LEFT",
    "KNEE_LEFT",
    "ANKLE_LEFT",
    "FOOT_LEFT",
    "HIP_RIGHT",
    "KNEE_RIGHT",
    "ANKLE_RIGHT",
    "FOOT_RIGHT",
    "HEAD",
    "NOSE",
    "EYE_LEFT",
    "EAR_LEFT",
    "EYE_RIGHT",
    "EAR_RIGHT",
)
N_JOINTS = len(JOINT_NAMES)
J = {name: idx for idx, name in enumerate(JOINT_NAMES)}
"""Joint index by SDK name, e.g. ``J["WRIST_LEFT"] == 7``."""

PARENTS = np.array(
    [-1, 0, 1, 2, 2, 4, 5, 6, 7, 8, 7, 2, 11, 12, 13, 14, 15, 14, 0, 18, 19, 20, 0, 22, 23, 24, 3, 26, 26, 26, 26, 26],
    dtype=np.int64,
)
"""Parent joint of each joint (-1 for the pelvis, the root), as in the SDK's skeleton diagram."""

BONES = np.stack([PARENTS[1:], np.arange(1, N_JOINTS)], axis=1)
"""(31, 2) array of (parent, child) joint indices."""

MIRROR_PAIRS = np.array(
    [
        [4, 11],
        [5, 12],
        [6, 13],
        [7, 14],
        [8, 15],
        [9, 16],
        [10, 17],
        [18, 22],
        [19, 23],
        [20, 24],
        [21, 25],
        [28, 30],
        [29, 31],
    ],
    dtype=np.int64,
)
"""(13, 2) array of (left, right) joint index pairs."""

MIRROR = np.arange(N_JOINTS)
MIRROR[MIRROR_PAIRS[:, 0]] = MIRROR_PAIRS[:, 1]
MIRROR[MIRROR_PAIRS[:, 1]] = MIRROR_PAIRS[:, 0]
"""Permutation that swaps every left joint with its right twin: ``skeleton[..., MIRROR, :]``."""


class Confidence(IntEnum):
    """k4abt joint confidence levels. The SDK emits at most MEDIUM today; HIGH is reserved."""

    NONE = 0  # out of range (too far from the depth camera), position is still a guess
    LOW = 1  # not observed (likely occluded), position predicted
    MEDIUM = 2  # the level of a normally tracked joint
    HIGH = 3  # reserved by the SDK


# The paper's 16 evaluation joints and its three groups (Lee et al. 2022, section 3 / Appendix A).
EVAL_JOINT_NAMES: tuple[str, ...] = (
    "PELVIS",
    "SPINE_NAVEL",
    "NECK",
    "HEAD",
    "SHOULDER_LEFT",
    "SHOULDER_RIGHT",
    "ELBOW_LEFT",
    "ELBOW_RIGHT",
    "WRIST_LEFT",
    "WRIST_RIGHT",
    "HIP_LEFT",
    "HIP_RIGHT",
    "KNEE_LEFT",
    "KNEE_RIGHT",
    "ANKLE_LEFT",
    "ANKLE_RIGHT",
)
EVAL_JOINTS = np.array([J[name] for name in EVAL_JOINT_NAMES], dtype=np.int64)

JOINT_GROUPS: dict[str, np.ndarray] = {
    "torso": np.array(
        [
            J[n]
            for n in (
                "PELVIS",
                "SPINE_NAVEL",
                "NECK",
                "HEAD",
                "HIP_LEFT",
                "HIP_RIGHT",
                "SHOULDER_LEFT",
                "SHOULDER_RIGHT",
            )
        ],
        dtype=np.int64,
    ),
    "upper_limb": np.array([J[n] for n in ("ELBOW_LEFT", "ELBOW_RIGHT", "WRIST_LEFT", "WRIST_RIGHT")], dtype=np.int64),
    "lower_limb": np.array([J[n] for n in ("KNEE_LEFT", "KNEE_RIGHT", "ANKLE_LEFT", "ANKLE_RIGHT")], dtype=np.int64),
}
"""The paper's joint groups (torso / upper limb / lower limb), as joint indices."""

# Joints whose left/right labels the paper realigns: limbs, hips and shoulders (section 2.2.1).
PAPER_REALIGN_PAIRS = np.array(
    [
        [J["SHOULDER_LEFT"], J["SHOULDER_RIGHT"]],
        [J["ELBOW_LEFT"], J["ELBOW_RIGHT"]],
        [J["WRIST_LEFT"], J["WRIST_RIGHT"]],
        [J["HIP_LEFT"], J["HIP_RIGHT"]],
        [J["KNEE_LEFT"], J["KNEE_RIGHT"]],
        [J["ANKLE_LEFT"], J["ANKLE_RIGHT"]],
    ],
    dtype=np.int64,
)


def joint_index(name: str) -> int:
    """Index of a joint by SDK name (case-insensitive; "SPINE_NAVAL" accepted for the docs' spelling)."""
    key = name.strip().upper().replace("SPINE_NAVAL", "SPINE_NAVEL")
    if key not in J:
        raise KeyError(f"unknown joint {name!r}; expected one of {', '.join(JOINT_NAMES)}")
    return J[key]


BODY_REGIONS: dict[str, np.ndarray] = {
    name: np.array([J[n] for n in members], dtype=np.int64)
    for name, members in {
        "torso": (
            "PELVIS",
            "SPINE_NAVEL",
            "SPINE_CHEST",
            "NECK",
            "CLAVICLE_LEFT",
            "CLAVICLE_RIGHT",
            "SHOULDER_LEFT",
            "SHOULDER_RIGHT",
            "HIP_LEFT",
            "HIP_RIGHT",
        ),
        "head": ("HEAD",),
        "face": ("NOSE", "EYE_LEFT", "EYE_RIGHT", "EAR_LEFT", "EAR_RIGHT"),
        "arm": ("ELBOW_LEFT", "ELBOW_RIGHT", "WRIST_LEFT", "WRIST_RIGHT"),
        "hand": ("HAND_LEFT", "HAND_RIGHT", "HANDTIP_LEFT", "HANDTIP_RIGHT", "THUMB_LEFT", "THUMB_RIGHT"),
        "knee": ("KNEE_LEFT", "KNEE_RIGHT"),
        "foot": ("ANKLE_LEFT", "ANKLE_RIGHT", "FOOT_LEFT", "FOOT_RIGHT"),
    }.items()
}
"""Every joint in exactly one body region: how the tracker's error differs over the body (the simulator's noise
tables and the real-data statistics are kept per region)."""

TORSO_TRACKING_JOINTS = np.array([J["PELVIS"], J["SPINE_NAVEL"], J["SPINE_CHEST"], J["NECK"]], dtype=np.int64)
"""The joints a body tracker needs to see to track a body at all."""


# ---------------------------------------------------------------------------------------------------------------
# Joint orientation convention (k4abt joint frames). The SDK's body-joints page shows every joint's axes only as a
# figure; the table below was MEASURED on the real andyj1 recordings (../shared/data/azure-kinect-andyj1, 5 files,
# one subject, mostly facing the sensor; docs/orientations.md has the method and figures): each joint's local
# axes against its bones and against the body's left / up / forward directions. Summary: the local X axis lies
# along a bone (spine, left arm, right leg: pointing to the child; right arm, left leg: pointing to the parent),
# and the other two axes follow the body: Z = the body's left on the spine and both legs, Y = forward on the left
# arm, Y = backward on the right arm. Hand tips, feet and the face joints are rigid copies of another joint's
# frame (measured to 1e-3). A quaternion q maps joint-local vectors to the parent frame: ``v_world = q v q*``.

ORIENTATION_AIM = np.array(
    [
        # (from, to, sign): local axis sign*X points from joint `from` to joint `to`; -1 rows are derived joints.
        [0, 1, 1],  # PELVIS: X up the spine
        [1, 2, 1],  # SPINE_NAVEL
        [2, 3, 1],  # SPINE_CHEST
        [3, 26, 1],  # NECK
        [4, 5, 1],  # CLAVICLE_LEFT: X out along the left arm
        [5, 6, 1],  # SHOULDER_LEFT
        [6, 7, 1],  # ELBOW_LEFT
        [7, 8, 1],  # WRIST_LEFT
        [8, 9, 1],  # HAND_LEFT
        [-1, -1, 0],  # HANDTIP_LEFT = HAND_LEFT
        [7, 10, 1],  # THUMB_LEFT
        [11, 12, -1],  # CLAVICLE_RIGHT: X in along the right arm (towards the parent)
        [12, 13, -1],  # SHOULDER_RIGHT
        [13, 14, -1],  # ELBOW_RIGHT
        [14, 15, -1],  # WRIST_RIGHT
        [15, 16, -1],  # HAND_RIGHT
        [-1, -1, 0],  # HANDTIP_RIGHT = HAND_RIGHT
        [14, 17, -1],  # THUMB_RIGHT
        [18, 19, -1],  # HIP_LEFT: X up the left leg (towards the parent)
        [19, 20, -1],  # KNEE_LEFT
        [20, 21, 1],  # ANKLE_LEFT: the foot bone, at a fixed angle from X (ORIENTATION_AIM_OFFSET)
        [-1, -1, 0],  # FOOT_LEFT = ANKLE_LEFT turned 90 deg about Z
        [22, 23, 1],  # HIP_RIGHT: X down the right leg (towards the child)
        [23, 24, 1],  # KNEE_RIGHT
        [24, 25, 1],  # ANKLE_RIGHT: the foot bone, at a fixed angle from X (ORIENTATION_AIM_OFFSET)
        [-1, -1, 0],  # FOOT_RIGHT = ANKLE_RIGHT turned 90 deg about Z
        [26, 27, 1],  # HEAD: the nose bone, at a fixed direction in the head frame (ORIENTATION_AIM_OFFSET)
        [-1, -1, 0],  # NOSE = HEAD
        [-1, -1, 0],  # EYE_LEFT = HEAD turned 90 deg about Z
        [-1, -1, 0],  # EAR_LEFT = HEAD turned 180 deg about Z
        [-1, -1, 0],  # EYE_RIGHT = HEAD turned 90 deg about Z
        [-1, -1, 0],  # EAR_RIGHT = HEAD
    ],
    dtype=np.int64,
)
"""(32, 3) per joint: the bone (from, to) its local X axis follows and the sign (+1: X points from -> to)."""

ANKLE_FOOT_ANGLE_DEG = {"ANKLE_LEFT": 127.15, "ANKLE_RIGHT": -53.29}
"""Where the foot bone (ankle -> foot) lies in the SDK's ankle frame: this angle about local Z from X towards Y.
The same in every frame of every real recording in its own camera frame, the foot in the frame's XY plane
(``scripts/measure_orientation_convention.py``; docs/evidence.md, "Orientations"). The ankle frame is rigid to
the foot, not to the shin: its X leans off the shin by the ankle's flexion (docs/orientations.md)."""


HEAD_NOSE_DIRECTION = (0.32046, 0.94673, -0.03178)
"""Where the nose lies in the SDK's head frame (the unit HEAD -> NOSE bone in local x, y, z): the same to 1e-5 in
every frame of every real recording in its own camera frame (``scripts/measure_orientation_convention.py``). The
head frame is rigid to the face, not to the neck: its X lies 2-9 deg off NECK -> HEAD as the neck bends."""


def _about_z(angle_deg: float) -> tuple[float, float, float, float]:
    half = np.radians(angle_deg) / 2.0
    return (float(np.cos(half)), 0.0, 0.0, float(np.sin(half)))


def _from_aim_frame(direction: tuple[float, float, float]) -> tuple[float, float, float, float]:
    """The offset of a joint whose aim bone lies along ``direction`` in its SDK frame: its aim frame there has X on
    the bone, Z the SDK's Z made normal to it (so the body hint that turns Z keeps its meaning), Y = Z x X."""
    x = np.asarray(direction, dtype=np.float64) / np.linalg.norm(direction)
    z = np.array([0.0, 0.0, 1.0]) - x[2] * x
    z /= np.linalg.norm(z)
    R = np.stack([x, np.cross(z, x), z], axis=0)  # the offset: the transpose of the aim frame's axes in the SDK's
    w = np.sqrt(1.0 + np.trace(R)) / 2.0  # the rotation is well under 180 deg (w > 0)
    return (float(w), (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w))


ORIENTATION_AIM_OFFSET = np.array(
    [
        _from_aim_frame(HEAD_NOSE_DIRECTION) if name == "HEAD" else _about_z(-ANKLE_FOOT_ANGLE_DEG.get(name, 0.0))
        for name in JOINT_NAMES
    ],
    dtype=np.float64,
)
"""(32, 4) per joint, the fixed rotation from its aim frame (local X on the aim bone) to the SDK's frame:
``q_sdk = q_aim * offset``. Identity except the ankles, whose aim bone (the foot) lies at
:data:`ANKLE_FOOT_ANGLE_DEG` about local Z from the SDK's X, and the head, whose aim bone (the nose) lies along
:data:`HEAD_NOSE_DIRECTION`."""

ORIENTATION_AIMED = ORIENTATION_AIM[:, 2] != 0
"""(32,) bool: the joint's frame follows a bone of its own (False: a rigid copy, see ORIENTATION_DERIVED)."""

_SQRT_HALF = float(np.sqrt(0.5))
ORIENTATION_DERIVED = {
    # joint: (source joint, local offset quaternion w, x, y, z):  q_joint = q_source * offset
    J["HANDTIP_LEFT"]: (J["HAND_LEFT"], (1.0, 0.0, 0.0, 0.0)),
    J["HANDTIP_RIGHT"]: (J["HAND_RIGHT"], (1.0, 0.0, 0.0, 0.0)),
    J["FOOT_LEFT"]: (J["ANKLE_LEFT"], (_SQRT_HALF, 0.0, 0.0, _SQRT_HALF)),
    J["FOOT_RIGHT"]: (J["ANKLE_RIGHT"], (_SQRT_HALF, 0.0, 0.0, _SQRT_HALF)),
    J["NOSE"]: (J["HEAD"], (1.0, 0.0, 0.0, 0.0)),
    J["EYE_LEFT"]: (J["HEAD"], (_SQRT_HALF, 0.0, 0.0, _SQRT_HALF)),
    J["EAR_LEFT"]: (J["HEAD"], (0.0, 0.0, 0.0, 1.0)),
    J["EYE_RIGHT"]: (J["HEAD"], (_SQRT_HALF, 0.0, 0.0, _SQRT_HALF)),
    J["EAR_RIGHT"]: (J["HEAD"], (1.0, 0.0, 0.0, 0.0)),
}
"""Joints whose k4abt frame is a fixed rotation of another joint's frame (measured: identical to 1e-3 in every
frame of the andyj1 recordings)."""

ORIENTATION_DERIVED_SOURCE = np.array([ORIENTATION_DERIVED.get(j, (j, None))[0] for j in range(N_JOINTS)], np.int64)
"""(32,) the joint whose frame each joint copies (itself for aimed joints)."""

ORIENTATION_DERIVED_OFFSET = np.array(
    [ORIENTATION_DERIVED.get(j, (j, (1.0, 0.0, 0.0, 0.0)))[1] for j in range(N_JOINTS)], dtype=np.float64
)
"""(32, 4) local offset quaternion of each joint's frame from its source's (identity for aimed joints)."""

BODY_LEFT, BODY_UP, BODY_FORWARD = 0, 1, 2
"""Body directions used by ORIENTATION_HINT: the person's left (hip to hip), up (pelvis to neck), forward."""

ORIENTATION_HINT = np.array(
    [
        # (local axis 0..2, sign, body direction): local axis sign*e_axis points as close as it can to the body
        # direction. Used only where no view gives the twist about the bone (a track's first frame without
        # orientations); the measured convention, rounded to the nearest axis.
        [2, 1, BODY_LEFT],  # PELVIS: Z left (Y forward)
        [2, 1, BODY_LEFT],
        [2, 1, BODY_LEFT],
        [2, 1, BODY_LEFT],
        [1, 1, BODY_FORWARD],  # CLAVICLE_LEFT: Y forward (Z down in a T-pose)
        [1, 1, BODY_FORWARD],
        [1, 1, BODY_FORWARD],
        [1, 1, BODY_FORWARD],
        [1, 1, BODY_FORWARD],
        [1, 1, BODY_FORWARD],
        [1, 1, BODY_FORWARD],
        [1, -1, BODY_FORWARD],  # CLAVICLE_RIGHT: Y backward (Z up in a T-pose)
        [1, -1, BODY_FORWARD],
        [1, -1, BODY_FORWARD],
        [1, -1, BODY_FORWARD],
        [1, -1, BODY_FORWARD],
        [1, -1, BODY_FORWARD],
        [1, -1, BODY_FORWARD],
        [2, 1, BODY_LEFT],  # HIP_LEFT: Z left (Y forward)
        [2, 1, BODY_LEFT],
        [2, 1, BODY_LEFT],
        [2, 1, BODY_LEFT],
        [2, 1, BODY_LEFT],  # HIP_RIGHT: Z left (Y backward)
        [2, 1, BODY_LEFT],
        [2, 1, BODY_LEFT],
        [2, 1, BODY_LEFT],
        [2, 1, BODY_LEFT],  # HEAD
        [2, 1, BODY_LEFT],
        [2, 1, BODY_LEFT],
        [2, 1, BODY_LEFT],
        [2, 1, BODY_LEFT],
        [2, 1, BODY_LEFT],
    ],
    dtype=np.int64,
)
"""(32, 3) per joint: (local axis, sign, body direction) that fixes the twist about the bone without a view."""
