"""The live example of docs/python-api.md, run as written in its own process against a real rig: a fusion
node, two simulated capture workers and a recorder as ``python -m skelfuse`` processes on loopback.

Truth: the fused frames an independent in-test zenoh subscriber decoded with the wire codec
(service_helpers.Listener), and the fused stream the recorder wrote; the example must print exactly their
pelvis positions, and ``read_fused_frames`` of the recording must give back those frames.
"""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from service_helpers import RIG, Processes, start_node, worker_args, write_rig

import skelfuse
from doc_examples import write_example
from skelfuse.service.zenoh_io import loopback_args
from skelfuse.wire import keys
from skelfuse.wire.codec import encode_fused_frame

pytestmark = [pytest.mark.service, pytest.mark.live]

SENSORS = ("capture_0", "capture_1")
N_FRAMES = 60


def _app_config(rig_config: Path, node_port: int) -> Path:
    """The rig's config as an app on this machine sees it: connect to the node, listen on loopback only."""
    text = rig_config.read_text(encoding="utf-8").replace(
        "[zenoh]\n",
        f'[zenoh]\nconnect = ["tcp/127.0.0.1:{node_port}"]\nlisten = ["tcp/127.0.0.1:0"]\n',
        1,
    )
    path = rig_config.with_name("app.toml")
    path.write_text(text, encoding="utf-8")
    return path


def _alive(session: object, node: str) -> bool:
    replies = session.liveliness().get(keys.alive(RIG, node), timeout=1.0)  # type: ignore[attr-defined]
    return any(getattr(reply, "ok", None) is not None for reply in replies)


def test_subscribe_example_prints_the_fused_stream(tmp_path: Path, processes: Processes, node_port: int) -> None:
    config = write_rig(tmp_path, n_sensors=2, deadline_ms=100.0)
    example = write_example("python-api.md", "subscribe.py", tmp_path)
    output = tmp_path / "take.mcap"
    node, listener = start_node(processes, config, node_port)
    workers: list[subprocess.Popen[bytes]] = []
    try:
        common = ["--config", str(config), "--duration", "120", *loopback_args(connect_ports=[node_port])]
        recorder = processes.start("recorder", "record", "--output", str(output), *common)
        listener.wait_for(lambda: _alive(listener.session, "recorder"), 30.0, "the recorder's liveliness token")
        app = subprocess.Popen(
            [sys.executable, str(example), str(_app_config(config, node_port)), str(N_FRAMES)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        # The workers run until stopped: the example waits up to 30 s for its first frame, then reads N_FRAMES.
        workers = [
            processes.start(f"w{i}", *worker_args(config, node_port, sid, listener=listener))
            for i, sid in enumerate(SENSORS)
        ]
        try:
            out, err = app.communicate(timeout=120)
        finally:
            app.kill()
        assert app.returncode == 0, f"the example failed:\n{err}"
        for worker in workers:
            processes.stop(worker)
        listener.wait_for(
            lambda: bool(listener.fused) and time.monotonic() - listener.fused[-1][0] > 0.5,
            10.0,
            "the fused stream to settle",
        )
        assert processes.stop(recorder) == 0, processes.log(recorder)
        assert processes.stop(node) == 0, processes.log(node)
        received = {frame.time_us: frame for _, frame in listener.fused}
    finally:
        listener.close()

    rows = [line.split() for line in out.splitlines()]
    counts = re.search(r"(\d+) frames received, (\d+) rejected", err)
    assert counts is not None and int(counts[1]) >= N_FRAMES and counts[2] == "0", err
    assert 0 < len({row[0] for row in rows}) <= N_FRAMES  # frames without a person print no row
    pelvis = skelfuse.joint_index("PELVIS")
    checked = 0
    for time_us, track, x, y, z, confidence, _std in rows:
        frame = received.get(int(time_us))
        if frame is None:  # the in-test subscriber and the example subscribe at slightly different moments
            continue
        p = frame.track_ids.tolist().index(int(track))
        np.testing.assert_array_equal([float(x), float(y), float(z)], frame.positions[p, pelvis])  # exact: repr
        assert confidence == skelfuse.Confidence(int(frame.confidence[p, pelvis])).name
        checked += 1
    assert checked >= 0.9 * len(rows) and checked >= 30, (checked, len(rows))

    # The recorder's fused stream, read back through the API, holds the frames the subscriber decoded.
    recorded = list(skelfuse.read_fused_frames(output))
    common = [f for f in recorded if f.time_us in received]
    assert len(common) >= 0.9 * len(recorded) and len(common) >= N_FRAMES, (len(common), len(recorded))
    assert all(encode_fused_frame(f) == encode_fused_frame(received[f.time_us]) for f in common)
