"""Rig config: loading, validation messages, poses, fusion params, zenoh config precedence."""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from skelfuse.cli.common import add_zenoh_arguments, zenoh_flags
from skelfuse.config import (
    RigConfig,
    load_calibration,
    load_rig_config,
    parse_rig_config,
    zenoh_config,
)
from skelfuse.fusion.presets import preset
from skelfuse.schema.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
IDENTITY = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]


def minimal() -> dict[str, Any]:
    return {
        "rig": {"name": "test"},
        "sensors": [
            {"id": "a", "source": "sim", "sync": {"role": "master"}, "world_from_sensor": IDENTITY},
            {"id": "b", "source": "sim", "sync": {"role": "subordinate", "delay_us": 160}},
            {"id": "c", "source": "sim", "sync": {"role": "subordinate", "delay_us": 320}},
        ],
    }


def kinect_rig() -> dict[str, Any]:
    return {
        "rig": {"name": "lab"},
        "sensors": [
            {"id": "000111", "source": "kinect", "sync": {"role": "master"}},
            {
                "id": "000222",
                "source": "kinect",
                "sync": {"role": "subordinate", "delay_us": 160},
                "kinect": {"depth_mode": "NFOV_2X2BINNED", "tracker": {"processing_mode": "cpu"}},
            },
        ],
    }


def with_change(base: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
    """Copy of ``base`` with ``path`` ("sensors.1.sync.delay_us") set to ``value`` (``...`` deletes it)."""
    data = copy.deepcopy(base)
    *parents, last = path.split(".")
    node: Any = data
    for part in parents:
        node = node[int(part)] if isinstance(node, list) else node.setdefault(part, {})
    if value is ...:
        del node[last]
    else:
        node[int(last) if isinstance(node, list) else last] = value
    return data


def config_error(data: dict[str, Any]) -> str:
    with pytest.raises(ConfigError) as info:
        parse_rig_config(data, source="rig.toml")
    return str(info.value)


# ---------------------------------------------------------------------------------------------------------
# The shipped configs
# ---------------------------------------------------------------------------------------------------------


def test_sim_rig_loads_with_four_posed_sensors() -> None:
    cfg = load_rig_config(REPO / "config" / "rig-sim-4.toml")
    assert cfg.name == "sim4"
    assert cfg.sensor_ids == ("capture_0", "capture_1", "capture_2", "capture_3")
    assert [s.sync.delay_us for s in cfg.sensors] == [0, 160, 320, 480]
    poses = cfg.poses()
    assert set(poses) == set(cfg.sensor_ids)
    from skelfuse.sim.rig import paper_rig

    for sensor in paper_rig(4):
        np.testing.assert_allclose(poses[sensor.sensor_id], sensor.world_from_sensor, atol=1e-3)
    assert cfg.sync.by == "device" and cfg.sync.tolerance_us == 10_000 and cfg.sync.deadline_us == 17_000
    assert cfg.rerun.mode == "spawn"
    assert cfg.fusion.preset == "skelfuse" and cfg.fusion.fusion_params() == preset("skelfuse")


def test_kinect_example_loads_and_says_how_to_get_a_calibration() -> None:
    path = REPO / "config" / "rig-example-kinect-4.toml"
    cfg = load_rig_config(path)
    assert len(cfg.sensors) == 4 and all(s.kinect is not None for s in cfg.sensors)
    assert [s.sync.role for s in cfg.sensors] == ["master", "subordinate", "subordinate", "subordinate"]
    assert cfg.zenoh.multicast_scouting is False and cfg.zenoh.connect
    assert cfg.calibration.file == path.parent / "calibration-lab.toml"
    assert cfg.record.directory == path.parent / "recordings"
    tracker = cfg.sensors[0].kinect.tracker  # type: ignore[union-attr]
    assert tracker.processing_mode == "cuda" and tracker.model_path is not None
    with pytest.raises(ConfigError, match=r"skelfuse calibrate") as info:
        cfg.poses()
    assert f"[calibration] file {cfg.calibration.file} does not exist" in str(info.value)
    assert cfg.poses(required=False) == {}
    assert set(cfg.pose_sources().values()) == {"none"}


def test_config_is_frozen_and_defaults_fill_in() -> None:
    cfg = parse_rig_config(minimal())
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.name = "other"  # type: ignore[misc]
    assert cfg.sync.fps == 30.0 and cfg.sync.tolerance_ms == 10.0 and cfg.sync.deadline_ms == 17.0
    assert cfg.fusion.preset == "skelfuse" and cfg.fusion.eps_mm is None
    assert cfg.fusion.fusion_params() == preset("skelfuse")  # the preset's own DBSCAN radius (75 mm)
    assert cfg.zenoh.mode == "peer" and cfg.zenoh.multicast_scouting is False  # explicit endpoints by default
    assert cfg.node.status_period_s == 1.0 and cfg.node.name is None
    assert cfg.rerun.mode == "off" and cfg.rerun.bind == "127.0.0.1"
    assert cfg.record.directory is None
    assert cfg.sensors[0].sim is not None and cfg.sensors[0].kinect is None


def test_host_sync_gets_a_wider_default_tolerance() -> None:
    cfg = parse_rig_config(with_change(minimal(), "sync", {"by": "host"}))
    assert cfg.sync.tolerance_ms == pytest.approx(13.333, abs=1e-3)


def test_kinect_defaults() -> None:
    cfg = parse_rig_config(kinect_rig())
    first, second = cfg.sensors
    assert first.kinect is not None and second.kinect is not None
    assert first.kinect.serial == "000111" and first.kinect.depth_mode == "NFOV_UNBINNED"
    assert first.kinect.color_resolution is None  # colour off unless asked
    assert first.kinect.tracker.processing_mode == "gpu" and first.kinect.tracker.temporal_smoothing == 0.0
    assert second.kinect.tracker.processing_mode == "cpu"


# ---------------------------------------------------------------------------------------------------------
# Error messages: key path, file, expected vs found, did you mean
# ---------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("path", "value", "expected"),
    [
        pytest.param(
            "sensors.2.sync.delay_us",
            -5,
            r"key sensors\[2\]\.sync\.delay_us: expected an integer in "
            r"\[160, 1e\+06\] µs, found -5 \(int\)",
            id="delay-out-of-range",
        ),
        pytest.param(
            "sensors.2.sync.delay_us",
            "320",
            r"sensors\[2\]\.sync\.delay_us: expected an integer.*"
            r"found '320' \(str\)",
            id="delay-wrong-type",
        ),
        pytest.param(
            "sensors.2.sync.delay_us",
            250,
            r"sensors\[2\]\.sync\.delay_us: expected a delay at least "
            r"160 µs away.*found 250 µs, 90 µs from sensors\[1\]",
            id="delays-too-close",
        ),
        pytest.param(
            "sensors.1.sync.delay_us", ..., r"key sensors\[1\]\.sync\.delay_us is required", id="delay-missing"
        ),
        pytest.param(
            "sensors.0.sync.delay_us",
            100,
            r"sensors\[0\]\.sync\.delay_us: expected an integer in "
            r"\[0, 0\].*only subordinates",
            id="master-with-delay",
        ),
        pytest.param(
            "sync.tolerance_ms",
            20.0,
            r"key sync\.tolerance_ms: expected a number in \(0, 16\.\d+\]",
            id="tolerance-over-half-period",
        ),
        pytest.param(
            "sync.tolerance_ms",
            0.2,
            r"sync\.tolerance_ms: expected more than the largest subordinate "
            r"delay \(320 µs\)",
            id="tolerance-below-delays",
        ),
        pytest.param("sync.by", "gps", r"sync\.by: expected one of 'device', 'host', found 'gps'", id="sync-by"),
        pytest.param(
            "sync.deadline_ms",
            True,
            r"sync\.deadline_ms: expected a number.*found True \(bool\)",
            id="bool-is-not-a-number",
        ),
        pytest.param("rig.name", "a/b", r"key rig\.name: rig name 'a/b' holds '/'", id="rig-name-chunk"),
        pytest.param("rig.name", ..., r"key rig\.name is required", id="rig-name-missing"),
        pytest.param("sensors.0.id", "*", r"sensors\[0\]\.id: sensor name '\*'", id="sensor-id-wildcard"),
        pytest.param(
            "sensors.1.id",
            "a",
            r"sensors\[1\]\.id: expected a sensor id not used before, found 'a'",
            id="duplicate-ids",
        ),
        pytest.param(
            "sensors.0.source",
            "kinnect",
            r"sensors\[0\]\.source: expected one of 'sim', 'replay', "
            r"'kinect', found 'kinnect' \(str\); did you mean 'kinect'\?",
            id="source-did-you-mean",
        ),
        pytest.param(
            "sensors.0.world_from_sensor",
            [[1, 0, 0], [0, 1, 0]],
            r"sensors\[0\]\.world_from_sensor: "
            r"expected a 4x4 list",
            id="pose-shape",
        ),
        pytest.param(
            "sensors.0.world_from_sensor",
            [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
            r"expected a rotation",
            id="pose-not-rigid",
        ),
        pytest.param(
            "sensors.0.world_from_sensor",
            [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]],
            r"expected last row \[0, 0, 0, 1\]",
            id="pose-last-row",
        ),
        pytest.param(
            "sensors.1.sync", {"role": "master"}, r"sensors\[1\]\.sync\.role: expected one master", id="two-masters"
        ),
        pytest.param("sensors", [], r"key sensors: expected at least one \[\[sensors\]\] table", id="no-sensors"),
        pytest.param(
            "sensors.0.sim", {"seed": -1}, r"sensors\[0\]\.sim\.seed: expected an integer >= 0", id="sim-seed"
        ),
        pytest.param(
            "sensors.0.kinect",
            {"serial": "x"},
            r"sensors\[0\]\.kinect: a \[sensors\[0\]\.kinect\] table "
            r"belongs to source = 'kinect' sensors, but this sensor has source = 'sim'",
            id="wrong-kind-table",
        ),
        pytest.param(
            "fusion.preset",
            "A9",
            r"fusion\.preset: expected one of skelfuse, A1, A2, A3, A4, A5, found 'A9'",
            id="fusion-preset",
        ),
        pytest.param(
            "fusion.eps_mm", 0, r"fusion\.eps_mm: expected a number in \(0, 10000\] mm, found 0", id="fusion-eps"
        ),
        pytest.param(
            "fusion.params",
            {"filtre": "cv_kalman"},
            r"unknown key fusion\.params\.filtre; did you mean "
            r"'filter'\?",
            id="fusion-params-did-you-mean",
        ),
        pytest.param(
            "fusion.params",
            {"filter": "kalman"},
            r"key fusion\.params: FusionParams\.filter must be one of",
            id="fusion-params-bad-value",
        ),
        pytest.param(
            "fusion.params",
            {"merge": "off"},
            r"fusion\.params\.merge: this field cannot be switched off",
            id="fusion-params-off-not-optional",
        ),
        pytest.param(
            "fusion.params",
            {"max_coast_frames": 1.5},
            r"fusion\.params\.max_coast_frames: expected an "
            r"integer, found 1\.5",
            id="fusion-params-type",
        ),
        pytest.param(
            "zenoh.mode", "server", r"zenoh\.mode: expected one of 'peer', 'client', 'router'", id="zenoh-mode"
        ),
        pytest.param(
            "zenoh.connect",
            "tcp/1.2.3.4:7447",
            r"zenoh\.connect: expected a list of non-empty strings",
            id="zenoh-connect-not-list",
        ),
        pytest.param(
            "zenoh.config",
            {"scouting/multicast/enabled": False},
            r'zenoh\.config\."scouting/multicast/'
            r'enabled": set this with \[zenoh\] multicast_scouting',
            id="zenoh-raw-duplicates-dedicated",
        ),
        pytest.param("rerun.mode", "save", r"rerun\.file is required when rerun\.mode = \"save\"", id="rerun-save"),
        pytest.param("rerun.grpc_port", 70000, r"rerun\.grpc_port: expected an integer in \[1, 65535\]", id="port"),
        pytest.param(
            "node.status_period_s", 0, r"node\.status_period_s: expected a number in \(0, 3600\] s", id="status-period"
        ),
    ],
)
def test_invalid_values_name_key_expected_and_found(path: str, value: Any, expected: str) -> None:
    message = config_error(with_change(minimal(), path, value))
    assert message.startswith("rig.toml: ")
    assert re.search(expected, message), message


@pytest.mark.parametrize(
    ("path", "value", "expected"),
    [
        pytest.param(
            "sensors.0.kinect",
            {"depth_mod": "NFOV_UNBINNED"},
            r"unknown key sensors\[0\]\.kinect\."
            r"depth_mod; did you mean 'depth_mode'\?",
            id="kinect-did-you-mean",
        ),
        pytest.param(
            "sensors.0.kinect",
            {"tracker": {"procesing_mode": "cpu"}},
            r"unknown key sensors\[0\]\.kinect"
            r"\.tracker\.procesing_mode; did you mean 'processing_mode'\?",
            id="tracker-did-you-mean",
        ),
        pytest.param(
            "sensors.0.tracker",
            {"processing_mode": "cpu"},
            r"did you mean sensors\[0\]\.kinect\.tracker",
            id="tracker-misplaced",
        ),
        pytest.param("sensors.1.kinect", {"depth_mode": "PASSIVE_IR"}, r"depth_mode: expected one of", id="depth-mode"),
        pytest.param(
            "sensors.1.kinect",
            {"tracker": {"temporal_smoothing": 1.5}},
            r"tracker\.temporal_smoothing: expected a number in \[0, 1\]",
            id="smoothing",
        ),
        pytest.param(
            "sensors.1.kinect",
            {"tracker": {"processing_mode": "GPU"}},
            r"processing_mode: expected one of 'gpu'.*did you mean 'gpu'",
            id="processing-mode-case",
        ),
        pytest.param(
            "sensors.1.kinect",
            {"serial": "000111"},
            r"sensors\[1\]\.kinect\.serial: expected a serial "
            r"not used before",
            id="duplicate-serial",
        ),
        pytest.param(
            "sensors.1.kinect",
            {"depth_mode": "WFOV_UNBINNED"},
            r"WFOV_UNBINNED runs at 15 fps at most",
            id="wfov-unbinned-fps",
        ),
        pytest.param("sync", {"fps": 25.0}, r"sync\.fps: expected one of \(5, 15, 30\)", id="kinect-fps"),
        pytest.param(
            "sensors.1.sync",
            {"role": "standalone"},
            r"sensors\[1\]\.sync\.role: \[sync\] by = \"device\" "
            r"needs every kinect on one wired sync chain",
            id="device-sync-needs-wires",
        ),
        pytest.param("sensors.0.sync", {"role": "standalone"}, r"a subordinate needs a master", id="no-master"),
    ],
)
def test_invalid_kinect_settings(path: str, value: Any, expected: str) -> None:
    message = config_error(with_change(kinect_rig(), path, value))
    assert re.search(expected, message), message


def test_unknown_top_level_key_suggests_the_section() -> None:
    message = config_error(with_change(minimal(), "fusoin", {"preset": "A5"}))
    assert "unknown key fusoin; did you mean 'fusion'?" in message
    assert "keys allowed in the top level" in message


def test_unknown_key_in_a_section_lists_the_allowed_keys() -> None:
    message = config_error(with_change(minimal(), "sync.tolerence_ms", 5.0))
    assert "unknown key sync.tolerence_ms; did you mean 'tolerance_ms'?" in message
    assert "deadline_ms" in message


def test_host_sync_allows_standalone_kinects() -> None:
    data = with_change(kinect_rig(), "sync", {"by": "host"})
    data["sensors"][0]["sync"] = {"role": "standalone"}
    data["sensors"][1]["sync"] = {"role": "standalone"}
    cfg = parse_rig_config(data)
    assert cfg.sync.by == "host" and {s.sync.role for s in cfg.sensors} == {"standalone"}


def test_fusion_params_overrides_and_off() -> None:
    data = with_change(
        minimal(),
        "fusion",
        {"preset": "a4", "eps_mm": 150, "params": {"previous_weight": "off", "max_coast_frames": 5}},
    )
    cfg = parse_rig_config(data)
    params = cfg.fusion.fusion_params()
    assert cfg.fusion.preset == "A4"
    assert params.eps_mm == 150.0 and params.previous_weight is None and params.max_coast_frames == 5
    assert params.filter is None  # A4 has no filter


@pytest.mark.parametrize("name", ["skelfuse", "SkelFuse", " a5 "])
def test_fusion_preset_names_are_case_insensitive_and_canonical(name: str) -> None:
    cfg = parse_rig_config(with_change(minimal(), "fusion", {"preset": name}))
    canonical = "A5" if "5" in name else "skelfuse"
    assert cfg.fusion.preset == canonical
    assert cfg.fusion.fusion_params() == preset(canonical)


def test_file_errors_name_the_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"does not exist"):
        load_rig_config(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[rig\nname = 1\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=rf"rig config {bad} is not valid TOML"):
        load_rig_config(bad)
    wrong = tmp_path / "wrong.toml"
    wrong.write_text(
        '[rig]\nname = "x"\n[[sensors]]\nid = "a"\nsource = "sim"\n[sensors.sync]\nrole = 3\n', encoding="utf-8"
    )
    with pytest.raises(ConfigError, match=rf"^{wrong}: key sensors\[0\]\.sync\.role: expected one of"):
        load_rig_config(wrong)


# ---------------------------------------------------------------------------------------------------------
# Paths and poses
# ---------------------------------------------------------------------------------------------------------


def write_rig(tmp_path: Path, extra: str = "", sensor_extra: str = "") -> Path:
    path = tmp_path / "rig.toml"
    path.write_text(
        f'[rig]\nname = "t"\n{extra}\n'
        f'[[sensors]]\nid = "a"\nsource = "sim"\n{sensor_extra}\n'
        '[[sensors]]\nid = "b"\nsource = "replay"\n[sensors.replay]\nfile = "takes/b.json"\n',
        encoding="utf-8",
    )
    return path


def test_relative_paths_resolve_against_the_config_file(tmp_path: Path) -> None:
    cfg = load_rig_config(
        write_rig(tmp_path, extra='[calibration]\nfile = "cal.toml"\n[rerun]\nmode = "save"\nfile = "out/live.rrd"\n')
    )
    assert cfg.sensors[1].replay is not None and cfg.sensors[1].replay.file == tmp_path / "takes" / "b.json"
    assert cfg.calibration.file == tmp_path / "cal.toml"
    assert cfg.rerun.file == tmp_path / "out" / "live.rrd"


def test_calibration_file_wins_over_inline_poses(tmp_path: Path) -> None:
    pose_b = [[0.0, -1.0, 0.0, 100.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 2000.0], [0.0, 0.0, 0.0, 1.0]]
    (tmp_path / "cal.toml").write_text(
        f'method = "skeleton"\n[sensors.b]\nworld_from_sensor = {json.dumps(pose_b)}\nresidual_mm = 12.5\n',
        encoding="utf-8",
    )
    path = write_rig(
        tmp_path, extra='[calibration]\nfile = "cal.toml"\n', sensor_extra=f"world_from_sensor = {json.dumps(IDENTITY)}"
    )
    poses = load_rig_config(path).poses()
    np.testing.assert_array_equal(poses["a"], np.eye(4))
    np.testing.assert_array_equal(poses["b"], np.array(pose_b))


def test_missing_pose_without_calibration_says_what_to_do(tmp_path: Path) -> None:
    cfg = load_rig_config(write_rig(tmp_path))
    with pytest.raises(ConfigError, match=r"no pose for sensor\(s\) a, b; .*`skelfuse calibrate \.\.\.`"):
        cfg.poses()


def test_malformed_calibration_file(tmp_path: Path) -> None:
    cal = tmp_path / "cal.toml"
    cal.write_text("[sensors.a]\nworld_from_sensor = [[1, 0], [0, 1]]\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"cal\.toml: key sensors\.a\.world_from_sensor: expected a 4x4"):
        load_calibration(cal)
    cal.write_text("[meta]\nx = 1\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"key sensors: expected a table \[sensors\.<id>\]"):
        load_calibration(cal)


def test_rig_sensor_lookup_suggests() -> None:
    cfg = parse_rig_config(minimal())
    assert cfg.sensor("b").sync.delay_us == 160
    with pytest.raises(ConfigError, match=r"no sensor 'bb'; did you mean 'b'"):
        cfg.sensor("bb")


# ---------------------------------------------------------------------------------------------------------
# zenoh: file < flags < --zenoh-cfg
# ---------------------------------------------------------------------------------------------------------


def zenoh_rig() -> RigConfig:
    data = minimal()
    data["zenoh"] = {
        "mode": "client",
        "connect": ["tcp/10.0.0.1:7447"],
        "multicast_scouting": False,
        "config": {"transport/unicast/max_links": 2, "scouting/gossip/enabled": False},
    }
    return parse_rig_config(data)


def test_zenoh_config_from_file() -> None:
    conf = zenoh_config(zenoh_rig())
    assert json.loads(conf.get_json("mode")) == "client"
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/10.0.0.1:7447"]
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    assert json.loads(conf.get_json("transport/unicast/max_links")) == 2
    assert json.loads(conf.get_json("scouting/gossip/enabled")) is False


def test_zenoh_flags_override_file_and_passthrough_overrides_flags() -> None:
    parser = argparse.ArgumentParser()
    add_zenoh_arguments(parser)
    args = parser.parse_args(
        [
            "--zenoh-mode",
            "peer",
            "--zenoh-connect",
            "tcp/127.0.0.1:7447",
            "--zenoh-listen",
            "tcp/127.0.0.1:7448",
            "--zenoh-cfg",
            "transport/unicast/max_links:4",
            "--zenoh-cfg",
            'connect/endpoints:["tcp/127.0.0.1:9999"]',
        ]
    )
    conf = zenoh_config(zenoh_rig(), **zenoh_flags(args))
    assert json.loads(conf.get_json("mode")) == "peer"  # flag over file
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7448"]
    assert json.loads(conf.get_json("transport/unicast/max_links")) == 4  # passthrough over file
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:9999"]  # passthrough over flag
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False  # from the file


def test_a_session_opens_without_waiting_for_scouting_and_the_wait_can_be_restored() -> None:
    """``scouting/delay`` is 0 (zenoh's 500 ms made ``zenoh.open`` wait on every node with multicast scouting
    on); the file's raw key and ``--zenoh-cfg`` win over it, as over any default."""
    assert json.loads(zenoh_config(zenoh_rig()).get_json("scouting/delay")) == 0
    data = minimal()
    data["zenoh"] = {"config": {"scouting/delay": 250}}
    assert json.loads(zenoh_config(parse_rig_config(data)).get_json("scouting/delay")) == 250
    restored = zenoh_config(zenoh_rig(), ["scouting/delay:500"])
    assert json.loads(restored.get_json("scouting/delay")) == 500


def test_no_multicast_scouting_flag() -> None:
    parser = argparse.ArgumentParser()
    add_zenoh_arguments(parser)
    conf = zenoh_config(parse_rig_config(minimal()), **zenoh_flags(parser.parse_args(["--no-multicast-scouting"])))
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False


@pytest.mark.parametrize(
    ("overrides", "expected"),
    [
        pytest.param(["max_links=2"], r"--zenoh-cfg: expected KEY:VALUE", id="no-colon"),
        pytest.param(["transport/unicast/max_links:"], r"expected KEY:VALUE", id="empty-value"),
        pytest.param(["no/such/key:1"], r"--zenoh-cfg 'no/such/key:1': zenoh rejected no/such/key = 1", id="bad-key"),
        pytest.param(
            ['transport/unicast/max_links:"many"'], r"zenoh rejected transport/unicast/max_links", id="bad-value"
        ),
    ],
)
def test_bad_zenoh_overrides_raise_config_error(overrides: list[str], expected: str) -> None:
    with pytest.raises(ConfigError, match=expected):
        zenoh_config(parse_rig_config(minimal()), overrides)


def test_bad_raw_zenoh_key_in_file_names_the_key() -> None:
    cfg = parse_rig_config(with_change(minimal(), "zenoh", {"config": {"transport/nonsense": 1}}))
    with pytest.raises(ConfigError, match=r'<dict>: zenoh\.config\."transport/nonsense": zenoh rejected'):
        zenoh_config(cfg)
