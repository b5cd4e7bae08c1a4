"""The public Python API (docs/python-api.md): its exports, its weight, the guide's recording and skeleton
examples run as written, and the subscriber's queue, timeout and close on a fake zenoh session.

The live example runs against real processes in tests/service/test_python_api_live.py.
"""

from __future__ import annotations

import math
import runpy
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

import skelfuse
from doc_examples import write_example
from fake_zenoh import FakeSample
from skelfuse.api.live import FusedSubscriber
from skelfuse.fusion.transform import invert_transform, make_transform
from skelfuse.recording import RecordingWriter
from skelfuse.wire.codec import encode_fused_frame

GUIDE = "python-api.md"
SENSORS = ("front", "left", "right")
SEED = 20261128
NOISE_MM = 5.0


# ------------------------------------------------------------------------------------------------ exports


def test_every_exported_name_resolves_and_nothing_else_is_promised() -> None:
    for name in skelfuse.__all__:
        assert getattr(skelfuse, name) is not None, name
    assert set(skelfuse.__all__) <= set(dir(skelfuse))
    with pytest.raises(AttributeError, match="no attribute 'fuse'"):
        skelfuse.fuse  # noqa: B018 - the pipeline is internal, not re-exported
    assert skelfuse.__version__ == skelfuse.version.__version__


def test_the_wheel_ships_py_typed() -> None:
    """The marker sits in the package and pyproject's package data lists it (so the wheel carries it)."""
    package = Path(skelfuse.__file__).parent
    assert (package / "py.typed").is_file()
    pyproject = (package.parents[1] / "pyproject.toml").read_text(encoding="utf-8")
    assert '"py.typed"' in pyproject


@pytest.mark.live
def test_an_app_that_subscribes_imports_numpy_and_zenoh_only() -> None:
    """In a fresh interpreter: ``import skelfuse`` and the subscriber load nothing heavy."""
    heavy = ("scipy", "cv2", "rerun", "matplotlib", "mcap", "skelfuse.sim", "skelfuse.fusion.pipeline")
    code = (
        "import sys, skelfuse\n"
        "skelfuse.subscribe, skelfuse.FusedSubscriber, skelfuse.JOINT_NAMES\n"
        "import zenoh\n"
        f"print(','.join(m for m in {heavy!r} if m in sys.modules))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert result.stdout.strip() == "", f"heavy modules loaded by a subscribing app: {result.stdout}"


# ---------------------------------------------------------------------------------------------- the guide


def test_skeleton_example_prints_the_k4abt_topology(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    script = write_example(GUIDE, "skeleton.py", tmp_path)
    runpy.run_path(str(script), run_name="__main__")
    lines = capsys.readouterr().out.splitlines()
    bones = [line for line in lines if "<->" not in line]
    assert len(bones) == 31 and len(lines) == 31 + 13  # 31 bones, 13 left joints
    # hand-checked against the joint table of the k4abt SDK (index: parent)
    for bone in ("PELVIS -> SPINE_NAVEL", "SPINE_CHEST -> CLAVICLE_LEFT", "WRIST_LEFT -> THUMB_LEFT", "NECK -> HEAD"):
        assert bone in bones
    assert "PELVIS -> HIP_RIGHT" in bones and "HEAD -> EAR_RIGHT" in bones
    assert "HIP_LEFT <-> HIP_RIGHT" in lines and "EAR_LEFT <-> EAR_RIGHT" in lines


def _truth(i: int) -> np.ndarray:
    """(32, 3) world positions, mm, z up: a body 2 m in front of the origin, swaying 100 mm sideways."""
    base = np.random.default_rng(SEED).uniform([-250, 1800, 0], [250, 2200, 1800], (skelfuse.N_JOINTS, 3))
    return base + np.array([100.0 * math.sin(i / 30.0), 0.0, 0.0])


def _poses() -> dict[str, np.ndarray]:
    def rot_z(deg: float) -> np.ndarray:
        a = math.radians(deg)
        return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1.0]])

    return {
        sid: make_transform(rot_z(120.0 * s), np.array([80.0 * s, -40.0 * s, 900.0])) for s, sid in enumerate(SENSORS)
    }


def _write_take(path: Path, n_frames: int) -> None:
    """Three calibrated sensors seeing the truth with 5 mm of noise, 30 fps, calibration in the metadata."""
    rng = np.random.default_rng(SEED + 1)
    poses = _poses()
    with RecordingWriter(path, rig="api", sensor_ids=SENSORS, world_from_sensor=poses) as writer:
        for i in range(n_frames):
            for s, sid in enumerate(SENSORS):
                noisy = _truth(i) + rng.normal(0.0, NOISE_MM, (skelfuse.N_JOINTS, 3))
                local = noisy @ invert_transform(poses[sid])[:3, :3].T + invert_transform(poses[sid])[:3, 3]
                frame = skelfuse.SensorFrame(
                    sensor_id=sid,
                    sequence=i,
                    device_time_us=1_000_000 + i * 33_333 + s * 160,
                    host_time_ns=1_700_000_000_000_000_000 + i * 33_333_333 + s * 1_000_000,
                    body_ids=np.array([1], dtype=np.uint32),
                    positions=local[None].astype(np.float32),
                    orientations=np.tile(np.array([1.0, 0, 0, 0], np.float32), (1, skelfuse.N_JOINTS, 1)),
                    confidence=np.full((1, skelfuse.N_JOINTS), int(skelfuse.Confidence.MEDIUM), np.uint8),
                )
                writer.write(frame)


def test_recording_example_fuses_a_take_to_within_the_noise_of_the_truth(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    take = tmp_path / "take.mcap"
    n_frames = 60
    _write_take(take, n_frames)
    script = write_example(GUIDE, "fuse_take.py", tmp_path)
    monkeypatch.setattr(sys, "argv", [str(script), str(take)])
    runpy.run_path(str(script), run_name="__main__")
    out, err = capsys.readouterr()
    assert "sensor frames: {'front': 60, 'left': 60, 'right': 60}" in err
    rows = [line.split() for line in out.splitlines()]
    times = [1_000_000 + i * 33_333 for i in range(n_frames)]
    assert len(rows) >= n_frames - 3  # a person is output once its track is confirmed (a few instants)
    pelvis = skelfuse.joint_index("PELVIS")
    errors = []
    for time_us, track, x, y, z in rows:
        i = times.index(int(time_us))
        assert track == "1"
        errors.append(np.linalg.norm(np.array([float(x), float(y), float(z)]) - _truth(i)[pelvis]))
    # three views of 5 mm noise per axis, through the default preset's filter: within a few sigmas
    assert np.median(errors) < 4 * NOISE_MM, np.median(errors)


def test_read_fused_frames_gives_back_the_recorded_frames(tmp_path: Path) -> None:
    take = tmp_path / "fused.mcap"
    _write_take(take, 40)
    with pytest.raises(skelfuse.DataError, match="holds no fused frames"):
        skelfuse.read_fused_frames(take)
    fused = list(skelfuse.fuse_recording(take))
    assert fused and sum(f.n_persons for f in fused) >= 30
    recorded = tmp_path / "recorded.mcap"
    with RecordingWriter(recorded, rig="api", sensor_ids=SENSORS) as writer:
        for k, frame in enumerate(fused):
            writer.write_fused(frame, log_time_ns=1_700_000_000_000_000_000 + k)
    back = list(skelfuse.read_fused_frames(recorded))
    assert [encode_fused_frame(f) for f in back] == [encode_fused_frame(f) for f in fused]


def test_a_missing_recording_is_a_data_error(tmp_path: Path) -> None:
    with pytest.raises(skelfuse.DataError):
        list(skelfuse.read_sensor_frames(tmp_path / "absent.mcap"))


# ------------------------------------------------------------------------------------ the subscriber


class _FakeSession:
    """What FusedSubscriber uses of a zenoh session: a subscriber with a callback, and close()."""

    def __init__(self) -> None:
        self.callback = None
        self.closed = False
        self.undeclared = False

    def declare_subscriber(self, key: str, callback):
        self.key, self.callback = key, callback
        return self

    def undeclare(self) -> None:
        self.undeclared = True

    def close(self) -> None:
        self.closed = True

    def publish(self, payload: bytes) -> None:
        assert self.callback is not None
        self.callback(FakeSample(self.key, payload))


def _frame(time_us: int) -> skelfuse.FusedFrame:
    return skelfuse.FusedFrame(
        time_us=time_us,
        track_ids=np.array([7], dtype=np.int64),
        positions=np.full((1, skelfuse.N_JOINTS, 3), float(time_us)),
        n_agree=np.full((1, skelfuse.N_JOINTS), 2, dtype=np.int16),
        confidence=np.full((1, skelfuse.N_JOINTS), 2, dtype=np.uint8),
        contributors=np.array([[True, True]]),
        sensor_ids=("a", "b"),
    )


def test_subscriber_counts_rejects_drops_the_oldest_and_times_out() -> None:
    session = _FakeSession()
    sub = FusedSubscriber(session, "skelfuse/lab/fused/skeletons", queue_frames=2)  # type: ignore[arg-type]
    session.publish(b"not a skelfuse payload")
    for t in (1, 2, 3):
        session.publish(encode_fused_frame(_frame(t)))
    assert (sub.received, sub.rejected, sub.dropped) == (3, 1, 1)
    assert [sub.receive(timeout_s=1.0).time_us for _ in range(2)] == [2, 3]  # the oldest went first
    with pytest.raises(TimeoutError, match="no fused frame on skelfuse/lab/fused/skeletons"):
        sub.receive(timeout_s=0.05)
    with sub:
        pass
    assert sub.closed and session.closed and session.undeclared
    with pytest.raises(skelfuse.ServiceError, match="closed"):
        sub.receive(timeout_s=1.0)


def test_close_from_another_thread_ends_an_iteration() -> None:
    session = _FakeSession()
    sub = FusedSubscriber(session, "skelfuse/lab/fused/skeletons")  # type: ignore[arg-type]
    seen: list[int] = []
    started = threading.Event()

    def consume() -> None:
        started.set()
        seen.extend(frame.time_us for frame in sub)

    reader = threading.Thread(target=consume)
    reader.start()
    assert started.wait(10.0)
    session.publish(encode_fused_frame(_frame(5)))
    sub.close()
    reader.join(10.0)
    assert not reader.is_alive(), "the iteration did not end on close()"
    assert seen == [5]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        pytest.param({}, "say which rig", id="no-rig"),
        pytest.param({"rig": "lab", "tls_certificate": "app.pem"}, "TLS needs tls_ca", id="tls-without-ca"),
        pytest.param({"rig": "a/b"}, "rig", id="bad-rig-name"),
    ],
)
def test_subscribe_refuses_an_incomplete_request_before_opening_a_session(kwargs: dict, message: str) -> None:
    with pytest.raises(skelfuse.ConfigError, match=message):
        skelfuse.subscribe(**kwargs)
