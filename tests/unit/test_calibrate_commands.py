"""``skelfuse calibrate capture|sphere|marker|skeleton|check`` end to end: synthetic RGB-D folders (the
renderer), a simulated walk written as an MCAP recording, a fake pyk4a; the files written are read back with
``config.load_calibration`` and compared with the true poses."""

from __future__ import annotations

import argparse
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from skelfuse.calibration.render import Scene, Sphere, aruco_plate, render, room
from skelfuse.calibration.rgbd_folder import load_rgbd_folder, save_rgbd_folder
from skelfuse.calibration.rigid import rotation_angle_deg
from skelfuse.calibration.sphere import PAPER_RADIUS_MM
from skelfuse.cli import main
from skelfuse.cli.calibrate import add_parser as add_calibrate_parser
from skelfuse.cli.common import EXIT_ATTENTION
from skelfuse.config import load_calibration
from skelfuse.config.calibration_file import read_calibration, write_calibration
from skelfuse.fusion.camera import Intrinsics
from skelfuse.fusion.transform import invert_transform
from skelfuse.recording.mcap_io import RecordingWriter
from skelfuse.schema.errors import CalibrationError, ConfigError, DataError
from skelfuse.schema.frames import SensorFrame
from skelfuse.schema.skeleton import N_JOINTS
from skelfuse.sim import load_profile, make_gesture, paper_rig, simulate
from skelfuse.sources.kinect import KinectUnavailable

SEED = 90210
BINNED = Intrinsics.azure_kinect_nfov(binned=True)  # 320 x 288: fast renders
FULL = Intrinsics.azure_kinect_nfov()  # the marker plate needs the resolution
N_FRAMES = 16


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="skelfuse")
    add_calibrate_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["calibrate", *argv])
    return args.func(args)


def _pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    return (
        rotation_angle_deg(estimate[:3, :3] @ truth[:3, :3].T),
        float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3])),
    )


# ------------------------------------------------------------------------------------------ RGB-D takes


@pytest.fixture(scope="module")
def rig():
    return paper_rig(3)


@pytest.fixture(scope="module")
def ball_folder(tmp_path_factory, rig) -> Path:
    rng = np.random.default_rng(SEED)
    theta = np.linspace(0.0, 2 * np.pi, N_FRAMES, endpoint=False)
    centres = np.stack([600 * np.cos(theta), 450 * np.sin(2 * theta), 1100 + 400 * np.sin(1.5 * theta)], axis=1)
    background = room(floor_z_mm=-5.0)
    frames: dict[str, list] = {s.sensor_id: [] for s in rig}
    for centre in centres:
        scene = Scene(spheres=[Sphere(centre, PAPER_RADIUS_MM)], quads=background)
        for sensor in rig:
            frames[sensor.sensor_id].append(render(sensor.world_from_sensor, BINNED, scene, rng=rng))
    return save_rgbd_folder(tmp_path_factory.mktemp("ball"), frames, dict.fromkeys(frames, BINNED))


@pytest.fixture(scope="module")
def plate_folder(tmp_path_factory, rig) -> Path:
    plate, _ = aruco_plate(marker_mm=200.0, spacing_mm=400.0)  # marker 1 at the world origin, axes = world
    scene = Scene(quads=[*room(floor_z_mm=-5.0), plate])
    master = rig[0]
    view = render(master.world_from_sensor, FULL, scene, rng=np.random.default_rng(SEED + 1))
    return save_rgbd_folder(
        tmp_path_factory.mktemp("plate"), {master.sensor_id: [view]}, {master.sensor_id: FULL}, start_index=7
    )


def test_rgbd_folder_round_trip(ball_folder: Path, rig) -> None:
    frames, intrinsics = load_rgbd_folder(ball_folder)
    assert sorted(frames) == [s.sensor_id for s in rig]
    assert intrinsics["capture_0"] == BINNED
    color, depth = frames["capture_1"][3]
    assert color.shape == (BINNED.height, BINNED.width, 3) and color.dtype == np.uint8
    assert depth.dtype == np.uint16 and depth.max() > 1000
    assert len(frames["capture_2"]) == N_FRAMES
    one, _ = load_rgbd_folder(ball_folder, sensors=["capture_0"], frames=[5])
    assert one["capture_0"].numbers == (5,)


def test_rgbd_folder_errors_name_what_is_missing(tmp_path: Path, ball_folder: Path) -> None:
    with pytest.raises(DataError, match="not found"):
        load_rgbd_folder(tmp_path / "nope")
    with pytest.raises(DataError, match="holds no sensor folder"):
        load_rgbd_folder(tmp_path)
    with pytest.raises(DataError, match=r"sensor\(s\) capture_9"):
        load_rgbd_folder(ball_folder, sensors=["capture_9"])
    with pytest.raises(DataError, match=r"frame\(s\) \[999\] not found"):
        load_rgbd_folder(ball_folder, frames=[999])
    bad = tmp_path / "bad" / "cam"
    bad.mkdir(parents=True)
    (bad / "intrinsics.json").write_text('{"fx": 1}')
    with pytest.raises(DataError, match="expected a JSON object with keys fx, fy, cx, cy, width, height"):
        load_rgbd_folder(tmp_path / "bad")


def test_sphere_then_marker_put_the_rig_in_the_world(
    tmp_path: Path, ball_folder: Path, plate_folder: Path, rig, capsys
) -> None:
    out = tmp_path / "calibration.toml"
    rrd = tmp_path / "sphere.rrd"
    assert _run(["sphere", str(ball_folder), "--output", str(out), "--rrd", str(rrd), "-q"]) == 0
    printed = capsys.readouterr().out
    assert "written to" in printed and "capture_1" in printed and "master" in printed
    assert rrd.stat().st_size > 0
    poses = load_calibration(out)
    master_from_world = invert_transform(rig[0].world_from_sensor)
    for sensor in rig:  # the world of a sphere calibration is the master's frame
        angle, offset = _pose_error(poses[sensor.sensor_id], master_from_world @ sensor.world_from_sensor)
        assert angle < 0.5 and offset < 10.0, (sensor.sensor_id, angle, offset)
    assert read_calibration(out).sensors["capture_1"].residual_mm < 5.0

    # The marker re-anchors the existing file (default: the output file) into the plate's world.
    assert _run(["marker", str(plate_folder), "--output", str(out), "--marker-mm", "200"]) == 0
    printed = capsys.readouterr().out
    assert "marker 1: centre" in printed
    poses = load_calibration(out)
    for sensor in rig:
        angle, offset = _pose_error(poses[sensor.sensor_id], sensor.world_from_sensor)
        assert angle < 0.5 and offset < 10.0, (sensor.sensor_id, angle, offset)
    result = read_calibration(out)
    assert result.method == "marker" and result.sensors["capture_0"].method == "marker"
    assert result.sensors["capture_2"].method == "sphere"


def test_marker_alone_and_its_errors(tmp_path: Path, ball_folder: Path, plate_folder: Path, rig) -> None:
    out = tmp_path / "world.toml"
    assert _run(["marker", str(plate_folder), "-o", str(out), "--frame", "7"]) == 0
    pose = load_calibration(out)["capture_0"]
    angle, offset = _pose_error(pose, rig[0].world_from_sensor)
    assert angle < 0.5 and offset < 10.0
    # No plate in view: the library's message names the ids it saw.
    with pytest.raises(CalibrationError, match=r"not found; expected ArUco ids \[0, 1, 2, 3\].*detected none"):
        _run(["marker", str(ball_folder), "-o", str(tmp_path / "x.toml"), "--master", "capture_0", "--fresh"])
    with pytest.raises(DataError, match=r"frame\(s\) \[3\] not found"):
        _run(["marker", str(plate_folder), "-o", str(tmp_path / "y.toml"), "--frame", "3"])
    with pytest.raises(SystemExit) as exit_info:  # refused by the parser: a usage error, exit 2
        _run(["marker", str(plate_folder), "-o", str(tmp_path / "z.toml"), "--calibration", str(tmp_path / "no.toml")])
    assert exit_info.value.code == 2


def test_sphere_bad_inputs(tmp_path: Path, ball_folder: Path, plate_folder: Path) -> None:
    with pytest.raises(ConfigError, match="--master 'nope' is not among the sensors"):
        _run(["sphere", str(ball_folder), "-o", str(tmp_path / "a.toml"), "--master", "nope", "-q"])
    with pytest.raises(DataError, match="at least two sensors"):
        _run(["sphere", str(plate_folder), "-o", str(tmp_path / "a.toml"), "-q"])
    with pytest.raises(CalibrationError, match="frames show the ball to every sensor"):
        _run(
            [
                "sphere",
                str(ball_folder),
                "-o",
                str(tmp_path / "a.toml"),
                "--radius-mm",
                "100",
                "--min-frames",
                "8",
                "--max-frames",
                "4",
                "-q",
            ]
        )
    with pytest.raises(SystemExit):
        _run(["sphere", str(ball_folder), "--radius-mm", "-3"])
    config = tmp_path / "rig.toml"
    config.write_text('[rig]\nname = "lab"\n[[sensors]]\nid = "capture_0"\nsource = "sim"\n')
    with pytest.raises(ConfigError, match=r"sensor\(s\) capture_1, capture_2 that rig 'lab'"):
        _run(["sphere", str(ball_folder), "--config", str(config), "-q"])


# ------------------------------------------------------------------------------------------ skeleton takes


def _record(obs, path: Path, late_frames: dict[str, int] | None = None) -> Path:
    """Write simulated observations as `skelfuse record` would; ``late_frames`` delays a sensor's skeletons by
    that many frames (its timestamps unchanged): a sensor out of sync."""
    late_frames = late_frames or {}
    with RecordingWriter(path, rig="lab", sensor_ids=obs.sensor_ids) as writer:
        for t in range(obs.n_frames):
            for s, sensor_id in enumerate(obs.sensor_ids):
                if obs.dropped[t, s]:
                    continue
                k = max(t - late_frames.get(sensor_id, 0), 0)
                pos = obs.positions[k, s]
                tracked = bool(obs.tracked[k, s] and np.isfinite(pos).all())
                n = 1 if tracked else 0
                orientations = np.zeros((n, N_JOINTS, 4), np.float32)
                orientations[..., 0] = 1.0
                writer.write(
                    SensorFrame(
                        sensor_id=sensor_id,
                        sequence=t,
                        device_time_us=int(obs.device_time_us[t, s]),
                        host_time_ns=int(obs.host_time_ns[t, s]),
                        body_ids=np.arange(n, dtype=np.uint32),
                        positions=(pos[None] if tracked else np.zeros((0, N_JOINTS, 3))).astype(np.float32),
                        orientations=orientations,
                        confidence=(obs.confidence[k, s][None] if tracked else np.zeros((0, N_JOINTS))).astype(
                            np.uint8
                        ),
                    )
                )
    return path


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    """A 20 s simulated walk in the paper's 4-sensor rig, recorded as `skelfuse record` would write it."""
    obs = simulate(make_gesture("walking", duration_s=20, seed=3, facing_deg=30), paper_rig(4), load_profile(), seed=3)
    return obs, _record(obs, tmp_path_factory.mktemp("walk") / "walk.mcap")


SUBJECT_WORLD = np.array([0.0, 0.0, 900.0])  # the capture-area centre: translation errors are measured there


def _relative_errors(poses: dict, obs, subject_world: np.ndarray = SUBJECT_WORLD) -> dict:
    truth_master = invert_transform(obs.world_from_sensor[0])
    est_master = invert_transform(poses[obs.sensor_ids[0]])
    out = {}
    for s, sensor_id in enumerate(obs.sensor_ids):
        true_rel = truth_master @ obs.world_from_sensor[s]
        est_rel = est_master @ poses[sensor_id]
        subject = invert_transform(obs.world_from_sensor[s]) @ np.r_[subject_world, 1.0]
        out[sensor_id] = (
            rotation_angle_deg(est_rel[:3, :3] @ true_rel[:3, :3].T),
            float(np.linalg.norm((est_rel @ subject)[:3] - (true_rel @ subject)[:3])),
        )
    return out


@pytest.fixture(scope="module")
def skeleton_file(walk, tmp_path_factory) -> Path:
    _, recording = walk
    out = tmp_path_factory.mktemp("skel") / "calibration.toml"
    assert _run(["skeleton", "--recording", str(recording), "-o", str(out), "-q"]) == 0
    return out


def test_skeleton_command_recovers_the_rig(walk, skeleton_file: Path) -> None:
    obs, _ = walk
    poses = load_calibration(skeleton_file)
    assert sorted(poses) == sorted(obs.sensor_ids)
    for sensor_id, (angle, offset) in _relative_errors(poses, obs).items():
        assert angle < 1.0, f"{sensor_id}: {angle:.2f} deg"
        assert offset < 20.0, f"{sensor_id}: {offset:.1f} mm at the subject"
    result = read_calibration(skeleton_file)
    assert result.method == "skeleton" and result.master == "capture_0"
    for sensor in result.sensors.values():
        assert sensor.method == "skeleton" and "verdict good" in sensor.notes
        assert sensor.residual_mm is not None and 5.0 < sensor.residual_mm < 60.0
        assert sensor.n_points is not None and sensor.n_points > 500
    assert "verdicts: capture_0 good" in result.notes


def test_skeleton_report_is_printed(walk, tmp_path: Path, capsys) -> None:
    _, recording = walk
    out = tmp_path / "c.toml"
    assert (
        _run(
            [
                "skeleton",
                "--recording",
                str(recording),
                "-o",
                str(out),
                "--max-frames",
                "400",
                "--master",
                "capture_1",
                "-q",
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "Skeleton calibration: 4 sensors, master capture_1" in printed
    assert f"written to {out}" in printed


def test_bad_verdict_exits_3_and_keeps_the_file(walk, tmp_path: Path, capsys) -> None:
    obs, recording = walk
    out = tmp_path / "c.toml"
    out.write_text("# the good calibration\n")
    # One sensor's skeletons half a second late: its corresponding points are wrong, no rigid fit explains them.
    late = _record(obs, tmp_path / "late.mcap", late_frames={"capture_2": 15})
    code = _run(["skeleton", "--recording", str(late), "-o", str(out), "--max-frames", "150", "-q"])
    assert code == EXIT_ATTENTION
    printed = capsys.readouterr().out
    assert "bad" in printed and "not written" in printed and "record a longer walk" in printed
    assert out.read_text() == "# the good calibration\n"
    assert (
        _run(["skeleton", "--recording", str(late), "-o", str(out), "--max-frames", "150", "-q", "--force"])
        == EXIT_ATTENTION
    )
    assert read_calibration(out).method == "skeleton"
    # 4 frames: nothing links the sensors; the library says what to record.
    with pytest.raises(CalibrationError, match="could not link sensors"):
        _run(["skeleton", "--recording", str(recording), "-o", str(out), "--max-frames", "4", "-q"])


def test_check_passes_then_flags_a_moved_sensor(walk, skeleton_file: Path, tmp_path: Path, capsys) -> None:
    _, recording = walk
    assert _run(["check", "--recording", str(recording), "--calibration", str(skeleton_file), "-q"]) == 0
    assert "no sensor moved" in capsys.readouterr().out
    stored = read_calibration(skeleton_file)
    angle = np.radians(4.0)
    bump = np.eye(4)
    bump[:3, :3] = [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
    moved = dict(stored.sensors)
    moved["capture_2"] = type(moved["capture_2"])(
        moved["capture_2"].world_from_sensor @ bump,
        "skeleton",
        moved["capture_2"].residual_mm,
        moved["capture_2"].n_points,
    )
    knocked = write_calibration(tmp_path / "knocked.toml", type(stored)(moved, "skeleton", stored.master))
    assert _run(["check", "--recording", str(recording), "--calibration", str(knocked), "-q"]) == EXIT_ATTENTION
    printed = capsys.readouterr().out
    assert "sensor capture_2 looks moved" in printed and "MOVED" in printed
    assert "recalibrate" in printed


def test_take_files_and_bad_take_inputs(tmp_path: Path, walk, skeleton_file: Path) -> None:
    _, recording = walk
    with pytest.raises(ConfigError, match="give the walking take as --recording"):
        _run(["skeleton", "-o", str(tmp_path / "a.toml")])
    with pytest.raises(DataError, match="comes twice"):
        _run(["skeleton", "--recording", str(recording), "--take", str(recording)])
    with pytest.raises(DataError, match="no-such-file: no such file or folder"):
        _run(["skeleton", "--take", "no-such-file"])
    with pytest.raises(DataError, match="renames a one-sensor file only"):
        _run(["skeleton", "--take", f"a={recording}", "--take", f"b={recording}"])
    with pytest.raises(SystemExit) as refused:  # the parser refuses a missing input file: exit 2
        _run(["check", "--recording", str(tmp_path / "missing.mcap"), "--calibration", str(skeleton_file)])
    assert refused.value.code == 2
    with pytest.raises(ConfigError, match="needs the stored calibration"):
        _run(["check", "--recording", str(recording)])
    with pytest.raises(SystemExit) as refused:
        _run(["check", "--recording", str(recording), "--calibration", str(tmp_path / "none.toml")])
    assert refused.value.code == 2
    rig = tmp_path / "rig-none.toml"  # a rig whose [calibration] file was never made: bad input, exit 2
    rig.write_text('[rig]\nname = "r"\n[calibration]\nfile = "none.toml"\n[[sensors]]\nid = "a"\nsource = "sim"\n')
    with pytest.raises(ConfigError, match=r"none\.toml not found; make one first"):
        _run(["check", "--recording", str(recording), "--config", str(rig)])
    garbage = tmp_path / "garbage.toml"
    garbage.write_text("this is not = = toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        _run(["check", "--recording", str(recording), "--calibration", str(garbage)])


def test_takes_from_per_sensor_json_files(tmp_path: Path, walk) -> None:
    """offline_processor JSON per sensor (``--take SENSOR=FILE``): the same walk, frames matched by device time."""
    import json

    from skelfuse.schema.skeleton import JOINT_NAMES

    obs, _ = walk
    takes = []
    for s, sensor_id in enumerate(obs.sensor_ids):
        frames = []
        for t in range(300):  # 10 s
            pos = obs.positions[t, s]
            bodies = (
                []
                if not np.isfinite(pos).all()
                else [
                    {
                        "body_id": 1,
                        "joint_positions": pos.astype(float).tolist(),
                        "joint_orientations": [[1.0, 0.0, 0.0, 0.0]] * N_JOINTS,
                    }
                ]
            )
            frames.append({"timestamp_usec": t * 33333, "frame_id": t, "num_bodies": len(bodies), "bodies": bodies})
        path = tmp_path / f"{sensor_id}.json"
        path.write_text(
            json.dumps(
                {
                    "k4abt_sdk_version": "1.1.2",
                    "source_file": "x.mkv",
                    "joint_names": list(JOINT_NAMES),
                    "bone_list": [],
                    "frames": frames,
                }
            )
        )
        takes += ["--take", f"{sensor_id}={path}"]
    out = tmp_path / "c.toml"
    assert _run(["skeleton", *takes, "-o", str(out), "-q"]) == 0
    for sensor_id, (angle, offset) in _relative_errors(load_calibration(out), obs).items():
        assert angle < 1.5 and offset < 30.0, sensor_id  # a 10 s walk

    # the second command: fuse the same files with that calibration; its world is the master camera's, which
    # the skeletons level (z up, floor at 0), so the fused walk stands where the simulator's truth does
    from skelfuse.export.csv import read_fused_table
    from skelfuse.schema.skeleton import J

    fused = tmp_path / "fused.csv"
    inputs = [t for t in takes if t != "--take"]
    assert main(["fuse", "--input", *inputs, "--calibration", str(out), "-o", str(fused)]) == 0
    p = np.stack([f.positions[0] for f in read_fused_table(fused) if len(f.track_ids)])
    truth = obs.truth[:300]
    assert abs(np.nanmedian(p[:, J["PELVIS"], 2]) - np.median(truth[:, J["PELVIS"], 2])) < 60.0
    assert abs(np.nanmedian(p[:, [J["FOOT_LEFT"], J["FOOT_RIGHT"]], 2])) < 60.0


# ------------------------------------------------------------------------------------------ live capture


def _rig_config(tmp_path: Path) -> Path:
    path = tmp_path / "rig.toml"
    path.write_text(
        '[rig]\nname = "lab"\n[calibration]\nfile = "cal.toml"\n'
        '[[sensors]]\nid = "111"\nsource = "kinect"\nsync = { role = "master" }\n'
        '[[sensors]]\nid = "222"\nsource = "kinect"\nsync = { role = "subordinate", delay_us = 160 }\n'
    )
    return path


def _fake_pyk4a(scene_frames: dict[str, list], intrinsics: Intrinsics) -> types.ModuleType:
    """The slice of pyk4a the capture command uses: devices by index with serials, captures with
    transformed_color (BGRA) and depth, and the depth camera matrix."""

    class K4AException(Exception):
        pass

    class Enum:
        def __getattr__(self, name: str) -> str:
            return name

    serials = list(scene_frames)
    started: list[str] = []

    class Capture:
        def __init__(self, color: np.ndarray, depth: np.ndarray, time_us: int) -> None:
            self.transformed_color = np.concatenate([color, np.full((*color.shape[:2], 1), 255, np.uint8)], axis=2)
            self.depth = depth
            self.depth_timestamp_usec = time_us

    class Calibration:
        def get_camera_matrix(self, which: str) -> np.ndarray:
            assert which == "DEPTH"
            return intrinsics.matrix()

    class PyK4A:
        def __init__(self, config=None, device_id: int = 0, thread_safe: bool = True) -> None:
            self.config, self.serial, self.n = config, serials[device_id], 0
            self.calibration = Calibration()

        def open(self) -> None:
            pass

        def start(self) -> None:
            started.append(self.serial)

        def stop(self) -> None:
            pass

        def close(self) -> None:
            pass

        def get_capture(self, timeout: int = -1) -> Capture:
            assert timeout > 0
            frames = scene_frames[self.serial]
            color, depth = frames[self.n % len(frames)]
            # the subordinate starts one frame late: the command must catch it up by device time
            time_us = (self.n + (1 if self.serial == "222" else 0)) * 33333
            self.n += 1
            return Capture(color, depth, time_us)

    def config(**kwargs):
        return types.SimpleNamespace(**kwargs)

    module = types.ModuleType("pyk4a")
    module.__dict__.update(
        K4AException=K4AException,
        PyK4A=PyK4A,
        Config=config,
        connected_device_count=lambda: 2,
        ColorResolution=Enum(),
        ImageFormat=Enum(),
        DepthMode=Enum(),
        FPS=Enum(),
        WiredSyncMode=Enum(),
        CalibrationType=Enum(),
        started=started,
    )
    return module


def test_capture_writes_the_folder_layout(tmp_path: Path, monkeypatch, ball_folder: Path) -> None:
    frames, _ = load_rgbd_folder(ball_folder, sensors=["capture_0", "capture_1"])
    scene = {"111": list(frames["capture_0"])[:6], "222": list(frames["capture_1"])[:6]}
    fake = _fake_pyk4a(scene, BINNED)
    monkeypatch.setitem(sys.modules, "pyk4a", fake)
    out = tmp_path / "rgbd"
    assert (
        _run(
            [
                "capture",
                "--config",
                str(_rig_config(tmp_path)),
                "--out",
                str(out),
                "--frames",
                "4",
                "--every",
                "1",
                "--warmup",
                "0",
            ]
        )
        == 0
    )
    assert fake.started == ["222", "111"]  # subordinates first
    loaded, intrinsics = load_rgbd_folder(out)
    assert sorted(loaded) == ["111", "222"] and len(loaded["111"]) == 4
    assert intrinsics["222"] == BINNED
    # The subordinate's captures run one frame ahead in device time: the master is caught up, so every
    # written frame pairs the master's capture k + 1 with the subordinate's capture k (the same instant).
    for number in range(4):
        color, depth = loaded["111"][number]
        k = next(i for i, (_, d) in enumerate(scene["222"]) if np.array_equal(d, loaded["222"][number][1]))
        np.testing.assert_array_equal(depth, scene["111"][(k + 1) % 6][1])
        np.testing.assert_array_equal(color, scene["111"][(k + 1) % 6][0])


def test_capture_without_pyk4a_names_the_extra_and_the_sdk(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "pyk4a", None)  # import fails
    with pytest.raises(KinectUnavailable, match=r"skelfuse\[kinect\].*Sensor SDK"):
        _run(["capture", "--config", str(_rig_config(tmp_path)), "--out", str(tmp_path / "o"), "--frames", "2"])


def test_capture_needs_kinect_sensors(tmp_path: Path) -> None:
    config = tmp_path / "sim.toml"
    config.write_text('[rig]\nname = "lab"\n[[sensors]]\nid = "a"\nsource = "sim"\n')
    with pytest.raises(ConfigError, match='no sensor with source = "kinect"'):
        _run(["capture", "--config", str(config), "--out", str(tmp_path / "o")])


def test_every_option_is_documented() -> None:
    parser = argparse.ArgumentParser(prog="skelfuse")
    sub = parser.add_subparsers()
    add_calibrate_parser(sub)
    calibrate = sub.choices["calibrate"]
    methods = next(a for a in calibrate._actions if isinstance(a, argparse._SubParsersAction))
    assert set(methods.choices) == {"capture", "sphere", "marker", "skeleton", "check", "refine"}
    for name, command in methods.choices.items():
        for action in command._actions:
            if not isinstance(action, argparse._HelpAction):
                assert action.help, f"calibrate {name} {action.option_strings or action.dest} has no help"
        command.format_help()  # %-formatting in help strings is valid
