"""VMC messages: python-osc parses them back, the bone set and argument layout follow the protocol's
Marionette spec, and an avatar posed by them (Unity's transform maths, in Unity's left-handed y-up axes)
stands where the fused person stands."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from pythonosc.dispatcher import Dispatcher
from pythonosc.osc_bundle import OscBundle
from pythonosc.osc_message import OscMessage
from pythonosc.osc_server import BlockingOSCUDPServer
from pythonosc.udp_client import SimpleUDPClient
from scipy.spatial.transform import Rotation

from skelfuse.retarget.armature import build_armature
from skelfuse.schema.skeleton import N_JOINTS, J
from skelfuse.stream.vmc import VMC_BONES, VmcPerson, vmc_bundle, vmc_messages

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "export"))
from export_takes import as_frames, truth_take

# Unity's HumanBodyBones enum (the names VMC sends), body part; and the humanoid hierarchy's parents.
HUMAN_BODY_BONES = {
    "Hips", "LeftUpperLeg", "RightUpperLeg", "LeftLowerLeg", "RightLowerLeg", "LeftFoot", "RightFoot", "Spine",
    "Chest", "UpperChest", "Neck", "Head", "LeftShoulder", "RightShoulder", "LeftUpperArm", "RightUpperArm",
    "LeftLowerArm", "RightLowerArm", "LeftHand", "RightHand", "LeftToes", "RightToes", "LeftEye", "RightEye", "Jaw",
}  # fmt: skip
UNITY_REQUIRED = {
    "Hips", "Spine", "Head", "LeftUpperLeg", "LeftLowerLeg", "LeftFoot", "RightUpperLeg", "RightLowerLeg",
    "RightFoot", "LeftUpperArm", "LeftLowerArm", "LeftHand", "RightUpperArm", "RightLowerArm", "RightHand",
}  # fmt: skip
UNITY_PARENT = {
    "Spine": "Hips", "Chest": "Spine", "Neck": "Chest", "Head": "Neck",
    "LeftShoulder": "Chest", "LeftUpperArm": "LeftShoulder", "LeftLowerArm": "LeftUpperArm", "LeftHand": "LeftLowerArm",
    "RightShoulder": "Chest", "RightUpperArm": "RightShoulder", "RightLowerArm": "RightUpperArm",
    "RightHand": "RightLowerArm", "LeftUpperLeg": "Hips", "LeftLowerLeg": "LeftUpperLeg", "LeftFoot": "LeftLowerLeg",
    "RightUpperLeg": "Hips", "RightLowerLeg": "RightUpperLeg", "RightFoot": "RightLowerLeg",
}  # fmt: skip


def _parse(messages: list[OscMessage]) -> list[OscMessage]:
    """Through the wire: one bundle's bytes parsed by python-osc's own reader."""
    bundle = OscBundle(vmc_bundle(messages).dgram)
    return [OscMessage(m.dgram) for m in bundle]  # each message re-parsed from its own bytes too


def _unity_world(bones: dict[str, tuple]) -> dict[str, np.ndarray]:
    """World positions of the bones, by Unity's rules: world = parent.world * localPosition, rotations compose."""
    world: dict[str, tuple[np.ndarray, Rotation]] = {
        "Hips": (np.array(bones["Hips"][0]), Rotation.from_quat(bones["Hips"][1]))
    }
    for name in UNITY_PARENT:  # parents come first in this dict
        p_pos, p_rot = world[UNITY_PARENT[name]]
        pos, quat = bones[name]
        world[name] = (p_pos + p_rot.apply(pos), p_rot * Rotation.from_quat(quat))
    return {name: value[0] for name, value in world.items()}


def test_messages_follow_the_marionette_spec() -> None:
    truth = truth_take("random")
    armature = build_armature(truth)
    parsed = _parse(vmc_messages(truth[10], armature, time_s=1.25))
    assert parsed[0].address == "/VMC/Ext/Root/Pos" and parsed[0].params[0] == "root" and len(parsed[0].params) == 8
    bones = [m for m in parsed if m.address == "/VMC/Ext/Bone/Pos"]
    names = [m.params[0] for m in bones]
    assert set(names) <= HUMAN_BODY_BONES and UNITY_REQUIRED <= set(names) and len(set(names)) == len(names)
    for message in bones:
        assert b",sfffffff\0" in message.dgram  # OSC type tags: one string, seven float32
        assert len(message.params) == 8 and all(isinstance(v, float) for v in message.params[1:])
        assert np.linalg.norm(message.params[4:]) == pytest.approx(1.0, abs=1e-6)
    ok, time = parsed[-2:]
    assert (ok.address, ok.params) == ("/VMC/Ext/OK", [1])
    assert time.address == "/VMC/Ext/T" and time.params[0] == pytest.approx(1.25)


def test_an_avatar_posed_by_the_messages_stands_where_the_person_stands() -> None:
    # Unity axes: x = -world x, y = world z (up), z = -world y; metres. Posed by Unity's transform maths,
    # every driven bone's head lands on the fused joint (a rigid simulated body: exactly, to float32).
    truth = truth_take("random")
    armature = build_armature(truth)
    for t in (0, 40, 90):
        parsed = _parse(vmc_messages(truth[t], armature, time_s=0.0))
        bones = {m.params[0]: (m.params[1:4], m.params[4:]) for m in parsed if m.address == "/VMC/Ext/Bone/Pos"}
        world = _unity_world(bones)
        for name, joint in VMC_BONES.items():
            x, y, z = truth[t, joint] / 1000.0
            np.testing.assert_allclose(world[name], [-x, z, -y], atol=2e-5, err_msg=name)
    assert world["Hips"][1] > 0.7  # y up: the pelvis is above the floor


def test_unity_rotation_signs_for_arms_hanging_down() -> None:
    # The simulator's rest body hangs its arms; from our T-pose that is the upper arm turned down by about
    # 90 degrees. In Unity (left-handed) that is a positive turn about +z for the left arm, negative for the
    # right (what VMC users send to lower a VRM avatar's arms).
    truth = truth_take("walking")
    person = vmc_messages(truth[0], build_armature(truth), time_s=0.0)
    bones = {m.params[0]: np.array(m.params[4:]) for m in person if m.address == "/VMC/Ext/Bone/Pos"}
    for name, sign in (("LeftUpperArm", 1.0), ("RightUpperArm", -1.0)):
        rotvec = Rotation.from_quat(bones[name]).as_rotvec(degrees=True)
        assert sign * rotvec[2] > 60.0, (name, rotvec)


def test_the_live_person_warms_up_then_streams_and_holds_unknown_joints() -> None:
    truth = truth_take("random")
    frames = as_frames(truth, track_id=5)
    person = VmcPerson(warmup_frames=10)
    out = [person.messages(frame, 5) for frame in frames[:12]]
    assert all(not m for m in out[:9]) and all(len(m) == 2 + len(VMC_BONES) + 1 for m in out[9:])
    assert person.messages(frames[12], 99) == []  # another track id: not this person
    hole = truth[13].copy()
    hole[J["WRIST_LEFT"]] = np.nan  # the forearm's child unknown: the elbow keeps its last rotation
    before = {m.params[0]: m.params[4:] for m in out[-1] if m.address == "/VMC/Ext/Bone/Pos"}
    held = vmc_messages(hole, person.armature, time_s=0.0)  # without state: the parent's rotation (identity)
    assert {m.params[0]: m.params[4:] for m in held if m.address == "/VMC/Ext/Bone/Pos"}[
        "LeftLowerArm"
    ] == pytest.approx([0, 0, 0, 1], abs=1e-6)
    frame = type(frames[13])(
        frames[13].time_us,
        frames[13].track_ids,
        hole[None],
        frames[13].n_agree,
        frames[13].confidence,
        frames[13].contributors,
    )
    live = {m.params[0]: m.params[4:] for m in person.messages(frame, 5) if m.address == "/VMC/Ext/Bone/Pos"}
    assert live["LeftLowerArm"] == pytest.approx(before["LeftLowerArm"], abs=1e-6)
    nan_pelvis = np.full((N_JOINTS, 3), np.nan)
    assert vmc_messages(nan_pelvis, person.armature, time_s=0.0) == []


def test_a_python_osc_server_receives_the_bundle_over_udp() -> None:
    # python-osc's own UDP server and dispatcher, as a Marionette would listen (an ephemeral port here).
    truth = truth_take("walking")
    messages = vmc_messages(truth[5], build_armature(truth), time_s=2.0)
    received: list[tuple[str, tuple]] = []
    dispatcher = Dispatcher()
    dispatcher.map("/VMC/Ext/*", lambda address, *args: received.append((address, args)))
    server = BlockingOSCUDPServer(("127.0.0.1", 0), dispatcher)
    server.timeout = 5.0
    client = SimpleUDPClient("127.0.0.1", server.server_address[1])
    try:
        client.send(vmc_bundle(messages))
        server.handle_request()
    finally:
        client.close()
        server.server_close()
    assert [address for address, _ in received] == [m.address for m in messages]
    hips = next(args for address, args in received if address == "/VMC/Ext/Bone/Pos" and args[0] == "Hips")
    x, y, z = truth[5, J["PELVIS"]] / 1000.0
    np.testing.assert_allclose(hips[1:4], [-x, z, -y], atol=1e-6)
