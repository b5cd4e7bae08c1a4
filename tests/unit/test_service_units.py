"""The service's pure parts without zenoh: lifecycle, CLI parsing, the node core, the sim source."""

from __future__ import annotations

import dataclasses
import logging
import signal
import threading
from pathlib import Path

import numpy as np
import pytest

from skelfuse import cli
from skelfuse.config import RigConfig, load_rig_config, parse_rig_config
from skelfuse.schema.errors import ServiceError
from skelfuse.service.lifecycle import JsonLogFormatter, Lifecycle, RunLimits
from skelfuse.service.node import FusionCore, calibration_document
from skelfuse.service.worker import SimSource, WorkerOptions, make_source, simulate_rig
from skelfuse.wire.codec import encode_sensor_frame

RIG_SIM_4 = Path(__file__).resolve().parents[2] / "config" / "rig-sim-4.toml"


# -- lifecycle ---------------------------------------------------------------------------------------------


def test_first_signal_asks_for_a_clean_exit(caplog: pytest.LogCaptureFixture) -> None:
    lifecycle = Lifecycle("fusion")
    with caplog.at_level(logging.INFO, logger="skelfuse.service"):
        lifecycle.handle_exit(signal.SIGTERM, None)
    assert lifecycle.should_exit and not lifecycle.force_exit
    assert "fusion: received SIGTERM, shutting down" in caplog.text


def test_second_ctrl_c_forces_exit(caplog: pytest.LogCaptureFixture) -> None:
    lifecycle = Lifecycle("demo")
    with caplog.at_level(logging.INFO, logger="skelfuse.service"):
        lifecycle.handle_exit(signal.SIGINT, None)
        lifecycle.handle_exit(signal.SIGINT, None)
    assert lifecycle.should_exit and lifecycle.force_exit
    assert "second SIGINT, forcing exit" in caplog.text


def test_capture_signals_installs_and_restores_handlers() -> None:
    lifecycle = Lifecycle()
    before = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    with lifecycle.capture_signals():
        assert signal.getsignal(signal.SIGTERM) == lifecycle.handle_exit
        signal.raise_signal(signal.SIGTERM)
        assert lifecycle.should_exit
    assert {sig: signal.getsignal(sig) for sig in before} == before


def test_capture_signals_outside_the_main_thread_is_a_no_op() -> None:
    lifecycle = Lifecycle()
    seen = []

    def body() -> None:
        with lifecycle.capture_signals():
            seen.append(signal.getsignal(signal.SIGTERM))

    thread = threading.Thread(target=body)
    thread.start()
    thread.join(5)
    assert seen == [signal.getsignal(signal.SIGTERM)]


def test_wait_returns_early_on_request_exit() -> None:
    lifecycle = Lifecycle()
    threading.Timer(0.05, lifecycle.request_exit).start()
    assert lifecycle.wait(10.0) is True


@pytest.mark.parametrize(
    ("limits", "frames", "elapsed", "reached"),
    [
        pytest.param(RunLimits(), 10**9, 10**6, False, id="no-limits"),
        pytest.param(RunLimits(max_frames=5), 5, 0.0, True, id="max-frames"),
        pytest.param(RunLimits(duration_s=2.0), 0, 1.9, False, id="before-duration"),
        pytest.param(RunLimits(duration_s=2.0), 0, 2.0, True, id="duration"),
    ],
)
def test_run_limits(limits: RunLimits, frames: int, elapsed: float, reached: bool) -> None:
    assert limits.reached(frames, 100.0, now=100.0 + elapsed) is reached


@pytest.mark.parametrize("kwargs", [{"duration_s": 0.0}, {"duration_s": float("inf")}, {"max_frames": 0}])
def test_run_limits_reject_nonsense(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError, match="--"):
        RunLimits(**kwargs)  # type: ignore[arg-type]


def test_json_logs_are_one_object_per_line() -> None:
    import json

    record = logging.LogRecord("skelfuse.x", logging.WARNING, __file__, 1, "bad %s", ("frame",), None)
    record.sensor = "capture_0"
    doc = json.loads(JsonLogFormatter().format(record))
    assert doc["msg"] == "bad frame" and doc["level"] == "WARNING" and doc["sensor"] == "capture_0"


# -- CLI ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        pytest.param(
            ["capture", "--config", "r.toml", "--sensor", "s1", "--duration", "2"],
            {"config": Path("r.toml"), "sensor": "s1", "duration": 2.0, "max_frames": None},
            id="capture",
        ),
        pytest.param(
            ["fuse", "--config", "r.toml", "--rrd", "v.rrd", "--max-frames", "9"],
            {"rrd": Path("v.rrd"), "max_frames": 9, "input": None, "serve": False},
            id="fuse-live",
        ),
        pytest.param(
            ["fuse", "--input", "t.mcap", "--output", "f.csv"],
            {"input": ["t.mcap"], "output": Path("f.csv"), "config": None},
            id="fuse-offline",
        ),
        pytest.param(
            ["fuse", "--config", "r.toml", "--serve", "--web-port", "9090", "--zenoh-connect", "tcp/h:1"],
            {"serve": True, "web_port": 9090, "zenoh_connect": ["tcp/h:1"]},
            id="fuse-serve",
        ),
        pytest.param(
            ["record", "--config", "r.toml", "--output", "x.mcap", "--duration", "1"],
            {"output": Path("x.mcap"), "duration": 1.0},
            id="record",
        ),
        pytest.param(
            ["replay", "t.mcap", "--fast", "--rig", "lab2"],
            {"file": ["t.mcap"], "fast": True, "rig": "lab2", "speed": 1.0},
            id="replay",
        ),
        pytest.param(
            ["bench", "latency", "--sensors", "4", "8", "--json"],
            {"sensors": [4, 8], "json": True, "duration": 5.0},
            id="bench-latency",
        ),
        pytest.param(["status", "--config", "r.toml", "--max-frames", "3"], {"max_frames": 3}, id="status"),
        pytest.param(
            ["demo", "--duration", "5", "--json"], {"duration": 5.0, "offline": False, "serve": False}, id="demo-live"
        ),
    ],
)
def test_parse_service_commands(
    argv: list[str], expected: dict[str, object], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # input files must exist: the parser checks them
    for name in ("r.toml", "t.mcap"):
        (tmp_path / name).write_text("")
    args = cli.build_parser().parse_args(argv)
    for key, value in expected.items():
        assert getattr(args, key) == value, key


def test_capture_passes_config_and_limits(monkeypatch: pytest.MonkeyPatch) -> None:
    from skelfuse.service import worker

    calls = {}

    def fake_run(cfg: RigConfig, sensor_id: str, conf: object, *, options: WorkerOptions, lifecycle: Lifecycle):
        calls.update(cfg=cfg, sensor_id=sensor_id, options=options)
        return worker.WorkerReport(frames_out=3)

    monkeypatch.setattr(worker, "run_capture_worker", fake_run)
    argv = ["capture", "--config", str(RIG_SIM_4), "--sensor", "capture_2", "--max-frames", "3", "--seed", "4"]
    assert cli.main(argv) == cli.EXIT_OK
    assert calls["sensor_id"] == "capture_2" and calls["cfg"].name == "sim4"
    assert calls["options"].limits == RunLimits(max_frames=3) and calls["options"].seed == 4


def test_unknown_config_key_is_exit_2_naming_key_and_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "rig.toml"
    bad.write_text(RIG_SIM_4.read_text().replace("[node]\n", "[node]\nstatus_perod_s = 2.0\n"))
    assert cli.main(["fuse", "--config", str(bad)]) == cli.EXIT_USAGE
    err = capsys.readouterr().err
    assert "status_perod_s" in err and str(bad) in err


def test_offline_fuse_without_output_is_a_usage_error(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    Path("x.mcap").write_text("")
    assert cli.main(["fuse", "--input", "x.mcap"]) == cli.EXIT_USAGE
    assert "--output" in capsys.readouterr().err


# -- node core ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rig() -> RigConfig:
    return load_rig_config(RIG_SIM_4)


@pytest.fixture(scope="module")
def sim_frames(rig: RigConfig) -> dict[str, SimSource]:
    return {sid: SimSource(rig, sid, take_duration_s=1.0) for sid in rig.sensor_ids}


def test_sim_source_gives_each_worker_its_column_of_the_full_simulation(
    rig: RigConfig, sim_frames: dict[str, SimSource]
) -> None:
    full = simulate_rig(rig, gesture="walking", take_duration_s=1.0, seed=0)
    for column, sid in enumerate(full.sensor_ids):
        frame = sim_frames[sid].frame_at(1_000_003)
        f = 1_000_003 % full.n_frames
        np.testing.assert_array_equal(frame.positions[0], full.positions[f, column])
        np.testing.assert_array_equal(frame.confidence[0], full.confidence[f, column])
        delay = full.device_time_us[f, column] - full.device_time_us[f, 0]
        assert frame.device_time_us == round(1_000_003 * 1e6 / 30) + delay
        assert frame.sequence == 1_000_003


def test_core_groups_fuses_and_counts_rejects(rig: RigConfig, sim_frames: dict[str, SimSource]) -> None:
    core = FusionCore(rig)
    out = []
    for n in range(100, 110):
        now = n * 33_333_333  # arrivals keep the frames' pace (each sensor's clock is checked against them)
        for sid in rig.sensor_ids:
            frame = dataclasses.replace(sim_frames[sid].frame_at(n), host_time_ns=n)
            now += 1000
            out += core.receive(f"skelfuse/sim4/sensors/{sid}/skeletons", encode_sensor_frame(frame), now)
        payload = encode_sensor_frame(dataclasses.replace(sim_frames["capture_0"].frame_at(n), host_time_ns=1))
        core.receive("skelfuse/sim4/sensors/capture_1/skeletons", payload, now)  # on another sensor's key
        core.receive("skelfuse/sim4/sensors/capture_2/skeletons", payload[:20], now)
    assert len(out) == 10 and all(o.complete and o.trigger_arrival_ns is not None for o in out)
    assert all(o.frame.contributors.all() for o in out)
    assert core.rejects == {"capture_1": {"key_mismatch": 10}, "capture_2": {"truncated": 10}}
    report = core.sensor_report(now, 1.0)
    assert report["capture_2"]["invalid"] == 10 and report["capture_0"]["grouped"] == 10


def test_core_emits_at_the_deadline_without_a_dead_sensor(rig: RigConfig, sim_frames: dict[str, SimSource]) -> None:
    core = FusionCore(rig)
    outs = []
    for n in range(200, 203):  # three instants: the person is output once its track is confirmed
        now = 10**9 + (n - 200) * 33_333_333
        for sid in rig.sensor_ids[:3]:
            frame = dataclasses.replace(sim_frames[sid].frame_at(n), host_time_ns=1)
            assert core.receive(f"skelfuse/sim4/sensors/{sid}/skeletons", encode_sensor_frame(frame), now) == []
        assert core.poll(now + 16_000_000) == []
        outs += core.poll(now + 17_000_000)
    assert len(outs) == 3 and not any(out.complete for out in outs)
    assert outs[-1].frame.track_ids.tolist() == [1]
    assert outs[-1].frame.contributors[0].tolist() == [True, True, True, False]


def test_calibration_document_round_trips_the_poses(rig: RigConfig) -> None:
    import json

    core = FusionCore(rig)
    doc = json.loads(json.dumps(calibration_document(rig, core.poses)))
    assert doc["units"] == "mm" and doc["sensor_ids"] == list(rig.sensor_ids)
    np.testing.assert_array_equal(np.array(doc["world_from_sensor"]["capture_1"]), rig.poses()["capture_1"])


def test_kinect_source_without_pyk4a_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "pyk4a", None)  # as on a machine without the Azure Kinect SDK
    cfg = parse_rig_config({"rig": {"name": "k"}, "sensors": [{"id": "000123", "source": "kinect"}]})
    source = make_source(cfg, "000123", WorkerOptions())
    with pytest.raises(ServiceError, match=r"skelfuse\[kinect\]"):
        next(iter(source.frames()))


# -- kinect start order across workers ---------------------------------------------------------------------


class _FakeKinect:
    def __init__(self, events: list[str], sensor_id: str) -> None:
        self.events, self.sensor_id = events, sensor_id

    def ensure_available(self) -> None:
        pass

    def open(self) -> None:
        self.events.append(f"open {self.sensor_id}")

    def read(self, timeout_s: float) -> None:
        return None

    def close(self) -> None:
        self.events.append(f"close {self.sensor_id}")


class _FakeToken:
    def __init__(self, events: list[str], key: str) -> None:
        self.events, self.key = events, key
        events.append(f"declare {key}")

    def undeclare(self) -> None:
        self.events.append(f"undeclare {self.key}")


class _FakeSession:
    def __init__(self, events: list[str]) -> None:
        self.events = events

    def liveliness(self) -> _FakeSession:
        return self

    def declare_token(self, key: str) -> _FakeToken:
        return _FakeToken(self.events, key)


_KINECT_RIG = {
    "rig": {"name": "k"},
    "sync": {"by": "host"},
    "sensors": [
        {"id": "m1", "source": "kinect", "sync": {"role": "master"}},
        {"id": "s1", "source": "kinect", "sync": {"role": "subordinate", "delay_us": 160}},
        {"id": "s2", "source": "kinect", "sync": {"role": "subordinate", "delay_us": 320}},
        {"id": "x1", "source": "kinect"},
    ],
}


@pytest.fixture
def kinect_events(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    from skelfuse.service import capture_sources
    from skelfuse.sources import kinect

    events: list[str] = []
    monkeypatch.setattr(
        kinect.KinectSource,
        "from_config",
        classmethod(lambda cls, cfg, sensor_id, **kw: _FakeKinect(events, sensor_id)),
    )

    def fake_wait(session: object, rig: str, ids: list[str], *, timeout_s: float, should_exit: object) -> list[str]:
        events.append(f"wait {rig} {','.join(ids)} {timeout_s:g}")
        return ["s2"]

    monkeypatch.setattr(capture_sources, "wait_for_subordinates", fake_wait)  # where the kinect source calls it
    return events


def test_kinect_master_waits_for_subordinates_before_opening(
    kinect_events: list[str], caplog: pytest.LogCaptureFixture
) -> None:
    cfg = parse_rig_config(_KINECT_RIG)
    source = make_source(cfg, "m1", WorkerOptions(subordinate_wait_s=7.0))
    source.attach(_FakeSession(kinect_events), should_exit=lambda: False)  # type: ignore[attr-defined]
    with caplog.at_level(logging.INFO, logger="skelfuse.service.worker"):
        frames = source.frames()
        assert next(frames)[1] is None
        frames.close()
    assert kinect_events == ["wait k s1,s2 7", "open m1", "close m1"]
    assert "s2 not started after 7 s" in caplog.text and "starting the master anyway" in caplog.text


def test_kinect_master_without_pyk4a_fails_before_waiting_for_subordinates(
    kinect_events: list[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from skelfuse.sources import kinect
    from skelfuse.sources.kinect import KinectUnavailable

    def missing(self: object) -> None:
        raise KinectUnavailable("cannot import pyk4a (No module named 'pyk4a')")

    monkeypatch.setattr(_FakeKinect, "ensure_available", missing)
    assert kinect.KinectSource.from_config  # the fixture's fake
    cfg = parse_rig_config(_KINECT_RIG)
    source = make_source(cfg, "m1", WorkerOptions(subordinate_wait_s=30.0))
    source.attach(_FakeSession(kinect_events), should_exit=lambda: False)  # type: ignore[attr-defined]
    with pytest.raises(KinectUnavailable, match="pyk4a"):
        next(source.frames())
    assert kinect_events == []  # neither waited for the subordinates nor touched a device


def test_kinect_subordinate_declares_its_camera_token_after_opening(kinect_events: list[str]) -> None:
    from skelfuse.service.worker import KinectFrameSource

    cfg = parse_rig_config(_KINECT_RIG)
    source = KinectFrameSource(cfg, "s1", session=_FakeSession(kinect_events))
    frames = source.frames()
    next(frames)
    frames.close()
    key = "skelfuse/k/alive/camera-s1"
    assert kinect_events == ["open s1", f"declare {key}", f"undeclare {key}", "close s1"]


def test_kinect_standalone_and_sessionless_sources_do_not_wait(kinect_events: list[str]) -> None:
    from skelfuse.service.worker import KinectFrameSource

    cfg = parse_rig_config(_KINECT_RIG)
    for source in (KinectFrameSource(cfg, "x1", session=_FakeSession(kinect_events)), KinectFrameSource(cfg, "m1")):
        frames = source.frames()
        next(frames)
        frames.close()
    assert kinect_events == ["open x1", "close x1", "open m1", "close m1"]
