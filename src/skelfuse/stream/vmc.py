"""VMC protocol messages for one fused person: the root and humanoid bone local rotations, ready to send.

The VMC protocol (https://protocol.vmc.info) is an OSC dialect for avatars: a *Performer* sends, per frame,
the avatar's root transform and each Unity ``HumanBodyBones`` bone's local transform to a *Marionette*
(VSeeFace, EVMC4U, Warudo, VMC4B ...; default UDP port 39539). Messages built here (Marionette spec, v2.0
layout; argument types as the spec lists them):

- ``/VMC/Ext/Root/Pos (s)"root" (f)p.x p.y p.z (f)q.x q.y q.z q.w``: identity at the origin (the pelvis
  carries the world placement, so a receiver that treats the root as local gets the same result);
- ``/VMC/Ext/Bone/Pos (s)name (f)p.x p.y p.z (f)q.x q.y q.z q.w`` per bone of :data:`VMC_BONES`:
  ``localPosition`` (metres) and ``localRotation`` relative to the parent bone, Hips relative to the root;
- ``/VMC/Ext/OK (i)1`` (a model is loaded, bones follow) and ``/VMC/Ext/T (f)time`` (sender time, s).

Retargeting: the same armature fit as the file exports (:mod:`skelfuse.retarget.armature`), so an avatar
driven live and a BVH of the same take move alike. Its rest pose is a T-pose with identity local rotations,
the rest pose of VRM-normalized avatars the VMC receivers drive, so the local rotations are sent as they are.

Axes: Unity is left-handed, y up; an avatar in its rest pose faces +z and its right hand points to +x. Our
rest pose faces world -y with its left towards +x, so Unity ``(x, y, z) = (-x, z, -y)`` of our world (a
reflection, ``UNITY_FROM_WORLD``); a rotation ``R`` becomes ``U R Uᵀ``. Unity units are metres.

Bones: Hips ← PELVIS, Spine ← SPINE_NAVEL, Chest ← SPINE_CHEST, Neck ← NECK, Head ← HEAD, {Left,Right}
Shoulder ← CLAVICLE, UpperArm ← SHOULDER, LowerArm ← ELBOW, Hand ← WRIST, UpperLeg ← HIP, LowerLeg ← KNEE,
Foot ← ANKLE (each k4abt joint's rotation turns the segment from that joint to its children, as the Unity bone
starting there does). Unity's optional UpperChest, toes, eyes, jaw and fingers are not sent: k4abt has no
data that turns them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pythonosc.osc_bundle import OscBundle
from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
from pythonosc.osc_message import OscMessage
from pythonosc.osc_message_builder import OscMessageBuilder

from skelfuse.retarget.armature import Armature, build_armature, solve_rotations
from skelfuse.retarget.rotations import matrix_to_quaternion
from skelfuse.schema.errors import DataError
from skelfuse.schema.frames import FusedFrame
from skelfuse.schema.skeleton import N_JOINTS, PARENTS, J
from skelfuse.stream.osc import UdpOut

DEFAULT_PORT = 39539
"""The Marionette's usual UDP port (the spec's convention)."""

UNITY_FROM_WORLD = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""Our world (right-handed, z up, rest pose facing -y) to Unity (left-handed, y up, rest pose facing +z)."""

VMC_BONES: dict[str, int] = {
    "Hips": J["PELVIS"],
    "Spine": J["SPINE_NAVEL"],
    "Chest": J["SPINE_CHEST"],
    "Neck": J["NECK"],
    "Head": J["HEAD"],
    "LeftShoulder": J["CLAVICLE_LEFT"],
    "LeftUpperArm": J["SHOULDER_LEFT"],
    "LeftLowerArm": J["ELBOW_LEFT"],
    "LeftHand": J["WRIST_LEFT"],
    "RightShoulder": J["CLAVICLE_RIGHT"],
    "RightUpperArm": J["SHOULDER_RIGHT"],
    "RightLowerArm": J["ELBOW_RIGHT"],
    "RightHand": J["WRIST_RIGHT"],
    "LeftUpperLeg": J["HIP_LEFT"],
    "LeftLowerLeg": J["KNEE_LEFT"],
    "LeftFoot": J["ANKLE_LEFT"],
    "RightUpperLeg": J["HIP_RIGHT"],
    "RightLowerLeg": J["KNEE_RIGHT"],
    "RightFoot": J["ANKLE_RIGHT"],
}
"""Unity ``HumanBodyBones`` name → the k4abt joint whose rotation drives it."""

ADDRESS_ROOT = "/VMC/Ext/Root/Pos"
ADDRESS_BONE = "/VMC/Ext/Bone/Pos"
ADDRESS_OK = "/VMC/Ext/OK"
ADDRESS_TIME = "/VMC/Ext/T"


def _message(address: str, *args: str | float | int) -> OscMessage:
    builder = OscMessageBuilder(address=address)
    for arg in args:
        if isinstance(arg, str):
            builder.add_arg(arg, OscMessageBuilder.ARG_TYPE_STRING)
        elif isinstance(arg, int):
            builder.add_arg(arg, OscMessageBuilder.ARG_TYPE_INT)
        else:
            builder.add_arg(float(arg), OscMessageBuilder.ARG_TYPE_FLOAT)
    return builder.build()


def unity_rotation(rotation: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations in our world axes → (..., 4) Unity quaternions (x, y, z, w)."""
    q = matrix_to_quaternion(UNITY_FROM_WORLD @ rotation @ UNITY_FROM_WORLD.T)
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def unity_position_m(position_mm: np.ndarray) -> np.ndarray:
    """(..., 3) mm in our world axes → metres in Unity axes."""
    return position_mm @ UNITY_FROM_WORLD.T / 1000.0


def vmc_messages(
    positions: np.ndarray,
    armature: Armature,
    *,
    time_s: float,
    local_rotations: np.ndarray | None = None,
) -> list[OscMessage]:
    """The VMC messages of one person at one instant (a pure function).

    Parameters
    ----------
    positions : (32, 3) the person's fused positions, mm, world frame (``FusedFrame.positions[row]``);
        NaN joints keep their parent's rotation
    armature : the person's armature (:func:`skelfuse.retarget.armature.build_armature` over a few frames of
        that person, or the one :class:`VmcPerson` keeps)
    time_s : the sender's relative time for ``/VMC/Ext/T``, seconds
    local_rotations : (32, 3, 3) already solved rotations (skips the fit; :class:`VmcPerson` passes them)

    Returns
    -------
    ``[Root/Pos, Bone/Pos × 19 (VMC_BONES order), OK, T]``; empty when the pelvis is unknown (nothing to
    place the avatar with: send nothing that frame).
    """
    positions = np.asarray(positions, dtype=np.float64)
    if positions.shape != (N_JOINTS, 3):
        raise DataError(f"one person's positions must be ({N_JOINTS}, 3) mm, got {positions.shape}")
    if not np.isfinite(positions[0]).all():
        return []
    if local_rotations is None:
        local_rotations = solve_rotations(armature, positions[None])[0]
    quats = unity_rotation(local_rotations)
    local_positions = unity_position_m(armature.offsets)
    local_positions[0] = unity_position_m(positions[0])  # Hips: the pelvis, relative to the root at the origin
    out = [_message(ADDRESS_ROOT, "root", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)]
    for name, joint in VMC_BONES.items():
        out.append(_message(ADDRESS_BONE, name, *local_positions[joint], *quats[joint]))
    out.append(_message(ADDRESS_OK, 1))
    out.append(_message(ADDRESS_TIME, float(time_s)))
    return out


def vmc_bundle(messages: list[OscMessage]) -> OscBundle:
    """One OSC bundle (timetag "immediately") holding a frame's messages, as Performers send them."""
    builder = OscBundleBuilder(IMMEDIATELY)
    for message in messages:
        builder.add_content(message)
    return builder.build()


@dataclass
class VmcPerson:
    """Live retargeting state of one tracked person, for the stream daemon (one per track id).

    The armature is built from the person's first ``warmup_frames`` frames (median bone lengths, as in the
    file exports) and then kept fixed, so the avatar's proportions do not wobble. Until then no messages
    are produced. A joint unknown in a frame keeps its last known local rotation (a live stream cannot
    interpolate ahead).
    """

    warmup_frames: int = 30
    armature: Armature | None = None
    _warmup: list[np.ndarray] = field(default_factory=list)
    _last_local: np.ndarray | None = None

    def messages(self, frame: FusedFrame, track_id: int, *, time_s: float | None = None) -> list[OscMessage]:
        """The VMC messages of person ``track_id`` in ``frame`` ([] while warming up or if absent)."""
        rows = np.flatnonzero(np.asarray(frame.track_ids) == track_id)
        if rows.size == 0:
            return []
        positions = np.asarray(frame.positions, dtype=np.float64)[rows[0]]
        time_s = frame.time_us * 1e-6 if time_s is None else time_s
        if self.armature is None:
            if np.isfinite(positions[0]).all():
                self._warmup.append(positions)
            if len(self._warmup) < self.warmup_frames:
                return []
            self.armature = build_armature(np.stack(self._warmup))
            self._warmup = []
        if not np.isfinite(positions[0]).all():
            return []
        local = solve_rotations(self.armature, positions[None])[0]
        known = np.isfinite(positions).all(axis=-1)
        child_known = np.zeros(N_JOINTS, dtype=bool)
        np.logical_or.at(child_known, PARENTS[1:], known[1:])
        if self._last_local is not None:  # hold the last rotation of a joint none of whose children was seen
            hold = ~child_known
            hold[0] = False
            local[hold] = self._last_local[hold]
        self._last_local = local
        return vmc_messages(positions, self.armature, time_s=time_s, local_rotations=local)


class VmcSender:
    """Send one person of each fused frame as a VMC bundle to ``host:port`` over a non-blocking UDP socket.

    VMC drives one avatar per receiver port, so one person is sent: ``person`` (a track id) when given, else the
    lowest track id in the frame (the longest-lived person, since ids are never reused). Each track keeps its own
    :class:`VmcPerson` (its armature is built from its own first frames); a track gone from the frame is
    forgotten. ``/VMC/Ext/T`` counts seconds from the first frame this sender saw. A failed send (no receiver,
    full buffer) is counted, never raised or waited for.
    """

    def __init__(self, host: str, port: int = DEFAULT_PORT, *, person: int | None = None) -> None:
        self._out = UdpOut(host, port)
        self.stats = self._out.stats
        self.address = self._out.address
        self.person = person
        self._people: dict[int, VmcPerson] = {}
        self._first_time_us: int | None = None

    def send(self, frame: FusedFrame) -> None:
        present = [int(t) for t in np.asarray(frame.track_ids)]
        for gone in set(self._people) - set(present):
            del self._people[gone]
        self.stats.frames += 1
        wanted = self.person if self.person is not None else (min(present) if present else None)
        if wanted is None or wanted not in present:
            return
        if self._first_time_us is None:
            self._first_time_us = int(frame.time_us)
        # /VMC/Ext/T is a float32 on the wire: seconds since this sender's first frame, not since 1970
        time_s = (int(frame.time_us) - self._first_time_us) * 1e-6
        messages = self._people.setdefault(wanted, VmcPerson()).messages(frame, wanted, time_s=time_s)
        if not messages:  # still building this person's armature
            return
        self._out.send(vmc_bundle(messages).dgram)

    def close(self) -> None:
        self._out.close()

    def describe(self) -> str:
        who = f"person {self.person}" if self.person is not None else "the lowest track id"
        return f"VMC to {self._out.url()} ({who})"
