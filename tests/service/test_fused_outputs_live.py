"""The fused stream's live consumers as real processes on loopback: ``skelfuse record`` (``[record] fused``) and
``skelfuse stream osc``, beside a fusion node, simulated workers, an independent zenoh subscriber and a
python-osc UDP server in the test (one rig for both, to keep the suite short).

- The fused frames the recorder wrote equal, payload for payload and in order, what the subscriber received.
- The OSC messages decode to those fused skeletons; SIGTERM stops the stream daemon within its drain timeout.
"""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pythonosc.dispatcher import Dispatcher
from pythonosc.osc_server import BlockingOSCUDPServer
from service_helpers import RIG, Processes, start_node, worker_args, write_rig

from skelfuse.recording import RecordingReader
from skelfuse.schema.skeleton import JOINT_NAMES
from skelfuse.service.zenoh_io import loopback_args
from skelfuse.wire import keys
from skelfuse.wire.codec import encode_fused_frame
from waiting import SCHEDULING_ALLOWANCE_S

pytestmark = pytest.mark.live

SENSORS = ("capture_0", "capture_1")
DRAIN_S = 1.0


def _alive(session, node: str) -> bool:
    replies = session.liveliness().get(keys.alive(RIG, node), timeout=1.0)
    return any(getattr(reply, "ok", None) is not None for reply in replies)


SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)  # Linux; the constant is missing from some builds
RECEIVE_BUFFER_BYTES = 32 << 20
"""Far more than the whole take's datagrams (about a megabyte): a receiving thread starved of CPU by a loaded
machine then delays them but loses none, so every datagram a daemon sends is checked, not a share of them."""


def widen_receive_buffer(sock: socket.socket) -> None:
    """Set the UDP receive buffer to :data:`RECEIVE_BUFFER_BYTES` (as root past ``net.core.rmem_max``)."""
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, RECEIVE_BUFFER_BYTES)
    except PermissionError:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)


def stream_summary(processes: Processes, daemon: subprocess.Popen[bytes]) -> dict[str, Any]:
    """The ``--json`` summary a stream daemon printed at exit (the last JSON object in its output)."""
    text = Path(daemon.log_path).read_text()  # type: ignore[attr-defined]
    start = text.rfind('{\n  "protocol"')
    assert start >= 0, processes.log(daemon)
    summary, _ = json.JSONDecoder().raw_decode(text[start:])
    return dict(summary)


class VmcBundles:
    """A python-osc server that keeps each VMC bundle's bones under its ``/VMC/Ext/T`` time."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.bones: dict[float, dict[str, list]] = {}
        self._pending: dict[str, list] = {}
        self.received = 0  # bundles (each ends with its /VMC/Ext/T)
        dispatcher = Dispatcher()
        dispatcher.map("/VMC/Ext/Bone/Pos", self._bone)
        dispatcher.map("/VMC/Ext/T", self._time)
        self.server = BlockingOSCUDPServer(("127.0.0.1", 0), dispatcher)
        widen_receive_buffer(self.server.socket)
        self.port = self.server.server_address[1]
        self.thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
        self.thread.start()

    def _bone(self, _address: str, name: str, *values: float) -> None:
        with self.lock:
            self._pending[name] = list(values)

    def _time(self, _address: str, time_s: float) -> None:  # the bundle's last message
        with self.lock:
            self.bones[float(time_s)], self._pending = self._pending, {}
            self.received += 1

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


class OscFrames:
    """A python-osc server that groups the messages of each fused frame under its ``/skelfuse/frame`` time."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.frames: dict[int, dict[str, list]] = {}
        self._current: dict[str, list] | None = None
        dispatcher = Dispatcher()
        dispatcher.set_default_handler(self._on_message)
        self.server = BlockingOSCUDPServer(("127.0.0.1", 0), dispatcher)  # one thread: datagrams stay in order
        widen_receive_buffer(self.server.socket)
        self.port = self.server.server_address[1]
        self.thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
        self.thread.start()

    def _on_message(self, address: str, *args: object) -> None:
        with self.lock:
            if address == "/skelfuse/frame":
                self._current = self.frames.setdefault(int(args[0]), {})
            if self._current is not None:
                self._current[address] = list(args)

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


def test_recorder_and_osc_stream_carry_the_fused_skeletons(
    tmp_path: Path, processes: Processes, node_port: int
) -> None:
    config = write_rig(tmp_path, n_sensors=2, deadline_ms=100.0)
    config.write_text(config.read_text() + f"\n[stream]\ndrain_timeout_s = {DRAIN_S}\n", encoding="utf-8")
    output = tmp_path / "take.mcap"
    osc = OscFrames()
    vmc = VmcBundles()
    node, listener = start_node(processes, config, node_port)
    try:
        common = ["--config", str(config), "--duration", "120", *loopback_args(connect_ports=[node_port])]
        recorder = processes.start("recorder", "record", "--output", str(output), *common)
        daemon = processes.start("stream", "stream", "osc", "--port", str(osc.port), "--json", *common)
        vmc_daemon = processes.start("vmc", "stream", "vmc", "--port", str(vmc.port), "--json", *common)
        for process, name in ((recorder, "recorder"), (daemon, "stream-osc"), (vmc_daemon, "stream-vmc")):
            listener.wait_for(
                lambda name=name: _alive(listener.session, name),
                30.0,
                f"the {name}'s liveliness token",
                lambda process=process: processes.log(process),
            )
        # Each declared its subscriptions before its token, on its one link to the node, and the token reached
        # this session through the node: the node knows their subscriptions.
        workers = [
            processes.start(f"w{i}", *worker_args(config, node_port, sid, "--duration", "3", listener=listener))
            for i, sid in enumerate(SENSORS)
        ]
        for worker in workers:
            worker.wait(60.0)
            assert worker.returncode == 0, processes.log(worker)
        listener.wait_for(
            lambda: bool(listener.fused) and time.monotonic() - listener.fused[-1][0] > 0.5,
            10.0,
            "the fused stream to settle",
        )
        stop_at = time.monotonic()
        assert processes.stop(daemon, signal.SIGTERM, timeout_s=10.0) == 0, processes.log(daemon)
        stop_s = time.monotonic() - stop_at
        assert processes.stop(vmc_daemon, signal.SIGTERM, timeout_s=10.0) == 0, processes.log(vmc_daemon)
        assert processes.stop(recorder) == 0, processes.log(recorder)
        assert processes.stop(node) == 0, processes.log(node)
        received = [frame for _, frame in listener.fused]
        sensor_frames = listener.sensor_frames()
    finally:
        listener.close()
        osc.close()
        vmc.close()
    assert len(received) >= 60, f"only {len(received)} fused frames reached the subscriber"
    assert sum(f.n_persons for f in received) > 0

    # --- the recording ------------------------------------------------------------------------------------
    rec = RecordingReader(output)
    assert rec.indexed, rec.problems  # closed cleanly on SIGTERM
    assert rec.fused_topic == keys.fused_skeletons(RIG)
    recorded = list(rec.fused_records())
    # The same frames, in the same order, with identical payloads (the wire codec is deterministic, so
    # re-encoding what the subscriber decoded gives the bytes it received).
    assert [r.frame.time_us for r in recorded] == [f.time_us for f in received]
    assert [r.payload for r in recorded] == [encode_fused_frame(f) for f in received]
    log_times = np.array([r.log_time_ns for r in recorded])
    assert (np.diff(log_times) >= 0).all() and abs(log_times[0] / 1e9 - time.time()) < 300  # host clock
    # The sensor channels are still there beside. The recorder and the test's subscriber are independent
    # subscribers that start at slightly different moments: their counts agree closely, not exactly.
    assert set(rec.sensors) == set(SENSORS)
    assert abs(len(list(rec.frames())) - len(sensor_frames)) <= max(3, 0.02 * len(sensor_frames))

    # --- the OSC stream -----------------------------------------------------------------------------------
    assert stop_s < DRAIN_S + SCHEDULING_ALLOWANCE_S, f"SIGTERM took {stop_s:.1f} s"
    with osc.lock:
        osc_frames = dict(osc.frames)
    # The daemon subscribed a moment after this session did, and it drops the oldest queued frame rather than
    # fall behind (counted in its summary): every frame it sent arrived (loopback UDP into a buffer larger than
    # the take).
    osc_summary = stream_summary(processes, daemon)
    assert len(osc_frames) == osc_summary["frames_out"], (len(osc_frames), osc_summary)
    assert len(osc_frames) >= 0.5 * len(received), (len(osc_frames), len(received), osc_summary)
    checked = 0
    for frame in received:
        messages = osc_frames.get(int(frame.time_us))
        if messages is None:
            continue
        assert messages["/skelfuse/frame"][1] == frame.n_persons
        assert messages["/skelfuse/persons"] == frame.track_ids.tolist()
        for p, track in enumerate(frame.track_ids.tolist()):
            for j, name in enumerate(JOINT_NAMES):
                base = f"/skelfuse/person/{track}/{name.lower()}"
                if np.isfinite(frame.positions[p, j]).all():
                    got = messages[f"{base}/position"]
                    np.testing.assert_allclose(got, frame.positions[p, j], rtol=1e-6, atol=1e-3)  # float32
                    checked += 1
                else:
                    assert f"{base}/position" not in messages
                assert messages[f"{base}/confidence"][:2] == [int(frame.confidence[p, j]), int(frame.n_agree[p, j])]
    assert checked >= 60 * 16, checked

    # --- the VMC stream (same rig, one more daemon) -------------------------------------------------------
    with vmc.lock:
        bundles = list(vmc.bones.values())
        vmc_received = vmc.received
    # Hips carries the fused pelvis in Unity's axes (x = -x, y = z, z = -y), metres, float32 on the wire
    pelvises = np.array([f.positions[int(np.argmin(f.track_ids)), 0] for f in received if f.n_persons]) / 1000.0
    unity = np.stack([-pelvises[:, 0], pelvises[:, 2], -pelvises[:, 1]], axis=1)
    for bones in bundles:
        assert {"Hips", "Spine", "Head", "LeftUpperArm", "RightLowerLeg"} <= set(bones)
        assert np.abs(unity - np.array(bones["Hips"][:3])).max(axis=1).min() < 1e-5  # one of the fused frames
    # A person's armature is built from its first 30 frames; then every frame is sent. The daemon drops the
    # oldest queued frame rather than fall behind (counted): every bundle (one datagram) it sent arrived.
    vmc_summary = stream_summary(processes, vmc_daemon)
    assert vmc_received == vmc_summary["sender"]["datagrams"] > 0, (vmc_received, vmc_summary)
    assert vmc_received >= 0.5 * (len(pelvises) - 30), (vmc_received, len(pelvises), vmc_summary)
