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
