"""Live streams, unit level: OSC datagrams decoded by python-osc's own parser, a python-osc UDP server fed by
OscSender, a dead receiver that never blocks, the daemon's bounded queue, LSL through a real pylsl inlet, and
the ``[stream]`` config section."""

from __future__ import annotations

import dataclasses
import socket
import sys
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest
from pythonosc.dispatcher import Dispatcher
from pythonosc.osc_bundle import OscBundle
from pythonosc.osc_server import BlockingOSCUDPServer

from skelfuse.config import StreamConfig, parse_rig_config
from skelfuse.retarget.armature import build_armature
from skelfuse.schema.errors import ConfigError
from skelfuse.schema.frames import FusedFrame, SensorFrame
from skelfuse.schema.skeleton import JOINT_NAMES, N_JOINTS
from skelfuse.service.lifecycle import Lifecycle, RunLimits
from skelfuse.service.zenoh_io import Received, free_port, loopback_config
from skelfuse.sim.gestures import make_gesture
from skelfuse.stream import lsl
from skelfuse.stream.daemon import BoundedSampleQueue, StreamReport, run_stream
from skelfuse.stream.osc import MAX_DATAGRAM_BYTES, OscSender, frame_bundles
from skelfuse.stream.vmc import VMC_BONES, VmcSender, vmc_messages
from skelfuse.wire import keys
from skelfuse.wire.codec import encode_fused_frame, encode_sensor_frame
from waiting import wait_for_subscriber, wait_until


def fused(persons: int = 2, time_us: int = 1_234_567_890_123, seed: int = 0) -> FusedFrame:
    rng = np.random.default_rng(seed)
    positions = rng.normal(0, 800, (persons, N_JOINTS, 3))
    if persons:
        positions[0, 7] = np.nan
    return FusedFrame(
        time_us=time_us,
        track_ids=np.arange(persons, dtype=np.int64) * 5 + 3,
        positions=positions,
        n_agree=rng.integers(0, 4, (persons, N_JOINTS)).astype(np.int16),
        confidence=rng.integers(0, 3, (persons, N_JOINTS)).astype(np.uint8),
        contributors=np.ones((persons, 2), bool),
        sensor_ids=("a", "b"),
    )


def with_orientations(frame: FusedFrame) -> FusedFrame:
    """The frame with its optional fields filled: unit quaternions w,x,y,z with one unknown joint, and a
    per-joint one-sigma position uncertainty."""
    rng = np.random.default_rng(1)
    q = rng.normal(size=(frame.n_persons, N_JOINTS, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q[0, 2] = np.nan
    std = rng.uniform(1, 30, (frame.n_persons, N_JOINTS))
    return dataclasses.replace(frame, orientations=q, position_std=std)


def decode(dgram: bytes) -> list[tuple[str, list]]:
    return [(m.address, list(m.params)) for m in OscBundle(dgram)]


def test_the_bundles_of_a_frame_decode_to_the_fused_skeleton() -> None:
    frame = fused()
    dgrams = frame_bundles(frame, counter=17)
    assert len(dgrams) == 3  # two people do not fit one 8 KiB datagram: a header bundle, then one per person
    assert all(OscBundle.dgram_is_bundle(d) and len(d) <= MAX_DATAGRAM_BYTES for d in dgrams)
    messages = [m for d in dgrams for m in decode(d)]
    assert messages[0] == ("/skelfuse/frame", [frame.time_us, 2, 17])
    assert messages[1] == ("/skelfuse/persons", [3, 8])
    by_address = dict(messages)
    assert len(by_address) == len(messages)  # each address once per frame
    for p, track in enumerate((3, 8)):
        for j, name in enumerate(JOINT_NAMES):
            base = f"/skelfuse/person/{track}/{name.lower()}"
            if np.isnan(frame.positions[p, j]).any():
                assert f"{base}/position" not in by_address  # no estimate: no position, receivers keep the last
            else:
                np.testing.assert_allclose(by_address[f"{base}/position"], frame.positions[p, j], rtol=1e-6)
            assert by_address[f"{base}/confidence"] == [int(frame.confidence[p, j]), int(frame.n_agree[p, j]), -1.0]
            assert f"{base}/orientation" not in by_address  # wire 1.0 frames carry none
    assert len(messages) == 2 + 2 * 32 * 2 - 1
    (single,) = frame_bundles(fused(1))  # one person: one bundle
    assert [a for a, _ in decode(single)][:3] == [
        "/skelfuse/frame",
        "/skelfuse/persons",
        "/skelfuse/person/3/pelvis/position",
    ]


def test_orientation_uncertainty_and_metres() -> None:
    frame = with_orientations(fused(1))
    by_address = dict(decode(frame_bundles(frame, prefix="/lab/sk", units="m")[0]))
    base = "/lab/sk/person/3"
    np.testing.assert_allclose(by_address[f"{base}/pelvis/position"], frame.positions[0, 0] / 1000, rtol=1e-6)
    np.testing.assert_allclose(by_address[f"{base}/pelvis/orientation"], frame.orientations[0, 0], rtol=1e-6)
    assert f"{base}/spine_chest/orientation" not in by_address  # NaN quaternion: not sent
    assert by_address[f"{base}/neck/confidence"][2] == pytest.approx(frame.position_std[0, 3], rel=1e-6)


def test_a_crowd_is_split_into_one_bundle_per_person() -> None:
    frame = with_orientations(fused(24))
    dgrams = frame_bundles(frame)
    assert len(dgrams) == 25 and all(len(d) <= MAX_DATAGRAM_BYTES for d in dgrams)
    assert [a for a, _ in decode(dgrams[0])] == ["/skelfuse/frame", "/skelfuse/persons"]
    for p, dgram in enumerate(dgrams[1:]):
        assert {a.split("/")[3] for a, _ in decode(dgram)} == {str(int(frame.track_ids[p]))}


def test_a_python_osc_server_receives_what_the_sender_sends() -> None:
    received: list[tuple[str, list]] = []
    dispatcher = Dispatcher()
    dispatcher.set_default_handler(lambda address, *args: received.append((address, list(args))))
    server = BlockingOSCUDPServer(("127.0.0.1", 0), dispatcher)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    try:
        sender = OscSender("127.0.0.1", server.server_address[1])
        frames = [fused(1, time_us=1000 + 33_333 * i, seed=i) for i in range(5)]  # one datagram each
        for frame in frames:
            sender.send(frame)
        wait_until(lambda: sum(a == "/skelfuse/frame" for a, _ in received) >= 5, "5 frames at the OSC server")
        sender.close()
    finally:
        server.shutdown()
        server.server_close()
    assert [args[0] for a, args in received if a == "/skelfuse/frame"] == [f.time_us for f in frames]
    assert sender.stats.frames == 5 and sender.stats.datagrams == 5 and sender.stats.send_errors == 0


def test_a_dead_or_silent_receiver_never_blocks_the_sender() -> None:
    # A port nobody listens on, and a socket that is bound but never read: sending stays quick and never raises.
    dead = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    dead.bind(("127.0.0.1", 0))
    dead_port = dead.getsockname()[1]
    dead.close()
    silent = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    silent.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    silent.bind(("127.0.0.1", 0))
    try:
        frame = fused(4)
        for port in (dead_port, silent.getsockname()[1]):
            sender = OscSender("127.0.0.1", port)
            for _ in range(300):
                sender.send(frame)
            assert sender.stats.frames == 300
            assert sender.stats.datagrams + sender.stats.send_errors == 300 * len(frame_bundles(frame))
            sender.close()
    finally:
        silent.close()


def test_bounded_queue_keeps_the_newest() -> None:
    q = BoundedSampleQueue(3)
    for i in range(10):
        q.put(Received(i, "k", bytes([i])))
    assert q.dropped == 7 and q.qsize() == 3
    assert [q.get(0.01).payload for _ in range(3)] == [bytes([7]), bytes([8]), bytes([9])]
    assert q.get(0.01) is None
    with pytest.raises(ValueError):
        BoundedSampleQueue(0)


def test_lsl_slots_stay_with_their_person() -> None:
    slots = lsl.SlotMap(2)
    assert slots.update([5, 9]) == 0 and slots.slots == [5, 9]
    assert slots.update([9]) == 0 and slots.slots == [None, 9]
    assert slots.update([9, 11, 12]) == 1 and slots.slots == [11, 9]  # 12 left out: no free slot
    sample = lsl.frame_sample(fused(2), [8, None]).reshape(2, -1)
    assert sample[0, 0] == 8 and sample[1, 0] == -1 and np.isnan(sample[1, 1:]).all()
    frame = fused(2)
    joints = sample[0, 1:].reshape(N_JOINTS, len(lsl.PER_JOINT))
    np.testing.assert_allclose(joints[:, :3], frame.positions[1].astype(np.float32), equal_nan=True)
    np.testing.assert_array_equal(joints[:, 7], frame.confidence[1])


def test_lsl_without_pylsl_says_how_to_get_it(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "pylsl", None)  # import pylsl raises ImportError
    with pytest.raises(ConfigError, match="pip install"):
        lsl.LslOutlet(name="x", source_id="y", max_persons=1, rate_hz=30.0)


def test_lsl_outlet_seen_by_a_real_inlet() -> None:
    import pylsl  # a dev dependency: its wheel bundles liblsl

    source_id = f"skelfuse-test-{time.monotonic_ns()}"
    outlet = lsl.LslOutlet(name="skelfuse-test", source_id=source_id, max_persons=2, rate_hz=30.0, rig="lab")
    try:
        streams = pylsl.resolve_byprop("source_id", source_id, timeout=10.0)
        assert streams, "a real inlet did not discover the outlet (LSL needs loopback multicast/broadcast)"
        inlet = pylsl.StreamInlet(streams[0])
        info = inlet.info(timeout=10.0)
        assert info.type() == "Mocap" and info.channel_count() == 2 * lsl.CHANNELS_PER_PERSON
        assert info.nominal_srate() == 30.0
        labels = []
        channel = info.desc().child("channels").child("channel")
        while not channel.empty():
            labels.append(channel.child_value("label"))
            channel = channel.next_sibling()
        assert labels == lsl.channel_labels(2)
        assert info.desc().child("skelfuse").child_value("units") == "mm"
        inlet.open_stream(timeout=10.0)
        frame = fused(1)

        def pulled() -> list[float] | None:  # the inlet may join after the first sends: send until one arrives
            outlet.send(frame)
            return inlet.pull_sample(timeout=0.2)[0]

        sample = wait_until(pulled, "a sample at the inlet")
        values = np.asarray(sample, np.float32).reshape(2, -1)
        assert values[0, 0] == 3 and values[1, 0] == -1
        xyz = values[0, 1:].reshape(N_JOINTS, len(lsl.PER_JOINT))[:, :3]
        np.testing.assert_allclose(xyz, frame.positions[0].astype(np.float32), equal_nan=True)
    finally:
        outlet.close()


RIG = {
    "rig": {"name": "lab"},
    "sensors": [{"id": "a", "source": "sim", "world_from_sensor": np.eye(4).tolist()}],
}


def test_stream_section_defaults_and_errors() -> None:
    assert parse_rig_config(RIG).stream == StreamConfig()
    cfg = parse_rig_config({**RIG, "stream": {"host": "10.0.0.5", "osc_port": 7000, "osc_units": "m"}})
    assert (cfg.stream.host, cfg.stream.osc_port, cfg.stream.osc_units) == ("10.0.0.5", 7000, "m")
    for bad, message in [
        ({"osc_prefix": "skelfuse"}, "OSC address prefix"),
        ({"osc_units": "cm"}, "did you mean"),
        ({"queue_size": 0}, "queue_size"),
        ({"osc_port": 70000}, "osc_port"),
        ({"lsl_max_persons": 0}, "lsl_max_persons"),
        ({"port": 9000}, "unknown key stream.port"),
    ]:
        with pytest.raises(ConfigError, match=message):
            parse_rig_config({**RIG, "stream": bad})


class FlakySender:
    """Records what it is given; fails on the frames whose time is in ``fail_at`` (a receiver library error)."""

    def __init__(self, fail_at: set[int]) -> None:
        self.fail_at = fail_at
        self.sent: list[int] = []
        self.closed = False
        self.stats = SimpleNamespace()

    def send(self, frame: FusedFrame) -> None:
        if frame.time_us in self.fail_at:
            raise RuntimeError("receiver library exploded")
        self.sent.append(frame.time_us)

    def close(self) -> None:
        self.closed = True

    def describe(self) -> str:
        return "a test sender"


@pytest.mark.live
def test_the_daemon_survives_bad_payloads_and_a_failing_sender() -> None:
    """In-process daemon on a real zenoh loopback session: garbage and a sensor frame on the fused key are
    rejected by reason, a sender error is counted, the good frames go through, request_exit stops it."""
    import zenoh

    port = free_port()
    cfg = parse_rig_config({**RIG, "stream": {"drain_timeout_s": 0.5}})
    sender = FlakySender(fail_at={2000})
    lifecycle = Lifecycle("stream-test")
    result: dict[str, StreamReport] = {}

    def run() -> None:
        result["report"] = run_stream(
            cfg,
            loopback_config(listen_port=port),
            sender,
            node="stream-test",
            limits=RunLimits(duration_s=60),
            lifecycle=lifecycle,
        )

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    session = zenoh.open(loopback_config(connect_ports=[port]))
    try:
        publisher = session.declare_publisher(keys.fused_skeletons("lab"))
        wait_for_subscriber(publisher, "the daemon's subscription")
        sensor_payload = encode_sensor_frame(
            SensorFrame(
                "a",
                0,
                0,
                0,
                np.zeros(0, np.uint32),
                np.zeros((0, N_JOINTS, 3), np.float32),
                np.zeros((0, N_JOINTS, 4), np.float32),
                np.zeros((0, N_JOINTS), np.uint8),
            )
        )
        for payload in (
            encode_fused_frame(fused(1, time_us=1000)),
            b"not a skelfuse payload",
            sensor_payload,
            encode_fused_frame(fused(1, time_us=2000)),
            encode_fused_frame(fused(1, time_us=3000)),
        ):
            publisher.put(payload)
        # in order: once 3000 is through, the rejects and the failed send before it have been counted
        wait_until(lambda: 3000 in sender.sent, "the last good frame to be sent", details=lambda: str(sender.sent))
    finally:
        lifecycle.request_exit()
        thread.join(10)
        session.close()
    assert not thread.is_alive()
    report = result["report"]
    assert sender.sent == [1000, 3000] and sender.closed
    assert report.frames_in == 5 and report.frames_out == 2 and report.send_failures == 1
    assert sum(report.rejects.values()) == 2 and report.dropped == 0


def _two_people(n_frames: int) -> list[FusedFrame]:
    """Two walkers (track ids 4 and 9) as fused frames."""
    a = make_gesture("walking", duration_s=n_frames / 30.0, fps=30.0, facing_deg=0.0, seed=1).positions
    b = make_gesture("squat", duration_s=n_frames / 30.0, fps=30.0, facing_deg=90.0, seed=2).positions
    b = b + np.array([1500.0, 0.0, 0.0])
    return [
        FusedFrame(
            time_us=1_000_000 + t * 33_333,
            track_ids=np.array([9, 4], np.int64),
            positions=np.stack([b[t], a[t]]).astype(np.float64),
            n_agree=np.full((2, N_JOINTS), 2, np.int16),
            confidence=np.full((2, N_JOINTS), 2, np.uint8),
            contributors=np.ones((2, 1), bool),
            sensor_ids=("s0",),
        )
        for t in range(n_frames)
    ]


@pytest.mark.parametrize("person", [None, 9])
def test_vmc_sender_drives_one_avatar_with_the_chosen_person(person: int | None) -> None:
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.settimeout(2.0)
    sender = VmcSender("127.0.0.1", receiver.getsockname()[1], person=person)
    chosen = 4 if person is None else person  # default: the lowest track id
    frames = _two_people(40)
    try:
        for frame in frames:
            sender.send(frame)
        # python-osc's parser, not the sender's builder; recv's timeout only bounds a lost datagram.
        got = [decode(receiver.recv(65536)) for _ in range(sender.stats.datagrams)]
        receiver.setblocking(False)
        with pytest.raises(BlockingIOError):  # and nothing more on the way
            receiver.recv(65536)
    finally:
        sender.close()
        receiver.close()
    # Nothing until the armature is built from the person's first 30 frames, then one bundle per frame.
    warmup = 30
    assert len(got) == len(frames) - warmup + 1
    assert sender.stats.frames == 40 and sender.stats.datagrams == len(got) and sender.stats.send_errors == 0
    rows = [int(np.flatnonzero(f.track_ids == chosen)[0]) for f in frames]
    track = np.stack([f.positions[row] for f, row in zip(frames, rows, strict=True)])  # (40, 32, 3) mm
    armature = build_armature(track[:warmup])
    for k, messages in enumerate(got):
        t = warmup - 1 + k
        assert [address for address, _ in messages] == [
            "/VMC/Ext/Root/Pos",
            *["/VMC/Ext/Bone/Pos"] * len(VMC_BONES),
            "/VMC/Ext/OK",
            "/VMC/Ext/T",
        ]
        assert messages[0][1] == ["root", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
        hips = messages[1][1]
        assert hips[0] == "Hips"  # the pelvis in Unity axes (x, y, z) = (-x, z, -y) of ours, metres
        pelvis = track[t, 0]
        np.testing.assert_allclose(hips[1:4], [-pelvis[0] / 1000, pelvis[2] / 1000, -pelvis[1] / 1000], atol=1e-6)
        assert messages[-1][1] == [pytest.approx((frames[t].time_us - frames[0].time_us) * 1e-6, abs=1e-6)]
        # The bones: the pure per-instant function on this person's frame and armature (tests/stream checks it
        # against the simulator's truth); the sender's per-track state must add nothing on a fully seen take.
        pure = [list(m.params) for m in vmc_messages(track[t], armature, time_s=0.0)[1:-2]]
        np.testing.assert_allclose([m[1:] for _, m in messages[1:-2]], [m[1:] for m in pure], atol=1e-6)
        assert [m[0] for _, m in messages[1:-2]] == list(VMC_BONES)
