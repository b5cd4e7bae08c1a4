"""Every user input is checked where it enters, and bad input never shows the user a traceback.

The first tests walk the parser itself (every sub-command, every option: commands added later are covered)
and feed each option the kinds of bad value its declared type must refuse: 0 and negatives where a count or
a duration is expected, garbage, a missing file, a missing folder, an unknown preset or choice. The others
are the faults the issue listed, each run through ``cli.main`` as a user would.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import logging
import re
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from skelfuse import cli
from skelfuse.cli.common import EXIT_ERROR, EXIT_USAGE, Number, PathArg, preset_name
from skelfuse.config import load_rig_config
from skelfuse.recording import RecordingWriter
from skelfuse.schema.errors import ConfigError
from skelfuse.service.node import NodeReport
from skelfuse.service.worker import SimSource

REPO = Path(__file__).resolve().parents[2]
SIM_RIG = REPO / "config" / "rig-sim-4.toml"
MISSING = "/nonexistent-skelfuse/dir"


def _leaf_commands(
    parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()
) -> Iterator[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    subcommands = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subcommands:
        yield prefix, parser
    for action in subcommands:
        for name, sub in action.choices.items():
            yield from _leaf_commands(sub, (*prefix, name))


def _options(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    skip = (argparse._HelpAction, argparse._VersionAction, argparse._SubParsersAction)
    return [a for a in parser._actions if not isinstance(a, skip) and a.nargs != 0]


def _bad_values(action: argparse.Action) -> list[str]:
    """The values the option's declared type or choices must refuse."""
    kind = action.type
    if isinstance(kind, Number):
        bad = ["garbage", "nan"]
        if kind.gt is not None:
            bad += [f"{kind.gt:g}", f"{kind.gt - 5:g}"]
        if kind.ge is not None:
            bad += [str(int(kind.ge) - 1), str(int(kind.ge) - 5)]
        if kind.le is not None:
            bad.append(str(int(kind.le) + 1))
        return bad
    if isinstance(kind, PathArg):
        return {"file": [f"{MISSING}/x.toml"], "dir": [MISSING], "output": [f"{MISSING}/x.csv"]}.get(kind.must, [])
    if kind is preset_name:
        return ["A9"]
    if kind in (int, float):
        return ["garbage"]
    if action.choices is not None:
        return ["bogus-choice"]
    return []


def _filler(action: argparse.Action, tmp: Path) -> str:
    """A value the option accepts (for required options around the one under test)."""
    if action.choices is not None:
        return str(next(iter(action.choices)))
    kind = action.type
    candidates = ["1", str(tmp / "input.txt"), str(tmp), str(tmp / "out.csv"), "x", f"a={tmp / 'input.txt'}"]
    for candidate in candidates:
        if kind is None or kind is str:
            return "x"
        try:
            kind(candidate)  # type: ignore[operator]
            return candidate
        except (argparse.ArgumentTypeError, ValueError, TypeError):
            continue
    raise AssertionError(f"no filler accepted by {action.dest} ({kind!r})")


def _cases(tmp: Path) -> list[tuple[list[str], str, str]]:
    """(argv, option, bad value) for every option of every command."""
    (tmp / "input.txt").write_text("x")
    cases = []
    for command, parser in _leaf_commands(cli.build_parser()):
        options = _options(parser)
        required = [a for a in options if a.required or not a.option_strings]
        for action in options:
            for bad in _bad_values(action):
                argv = list(command)
                for other in required:
                    value = bad if other is action else _filler(other, tmp)
                    argv += [other.option_strings[0], value] if other.option_strings else [value]
                if action.option_strings:
                    argv += [action.option_strings[0], bad]
                cases.append((argv, action.option_strings[0] if action.option_strings else action.dest, bad))
    return cases


def test_every_option_of_every_command_refuses_its_bad_values_without_a_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cases = _cases(tmp_path)
    assert len(cases) > 100, "the parser walk found too few options"
    failures = []
    for argv, option, _bad in cases:
        try:
            code = cli.main(argv)
        except SystemExit as exc:
            code = exc.code
        err = capsys.readouterr().err
        if code != EXIT_USAGE or "Traceback" in err or "error:" not in err:
            failures.append(f"skelfuse {' '.join(argv)} -> exit {code}: {err.strip()[-300:]}")
        elif option.startswith("-") and option.lstrip("-") not in err:
            failures.append(f"skelfuse {' '.join(argv)}: the message does not name {option}: {err.strip()[-200:]}")
    assert not failures, f"{len(failures)} of {len(cases)} bad values not refused cleanly:\n" + "\n".join(failures)


def test_every_numeric_option_declares_its_range() -> None:
    """A bare ``type=int`` / ``type=float`` accepts 0 and negatives unchecked: use cli.common.Number."""
    bare = [
        f"{' '.join(command)} {action.option_strings[0] if action.option_strings else action.dest}"
        for command, parser in _leaf_commands(cli.build_parser())
        for action in _options(parser)
        if action.type in (int, float)
    ]
    assert not bare, "options with a bare int/float type (use cli.common.Number / COUNT / POSITIVE ...): " + ", ".join(
        bare
    )


@pytest.mark.parametrize(
    "argv",
    [
        ["demo", "--duration", "0"],
        ["demo", "--duration", "-5"],
        ["demo", "--preset", "A9"],
        ["eval", "paper", "--workers", "0"],
        ["bench", "fusion", "--sensors", "0"],
        ["fuse", "--config", str(SIM_RIG), "--status-period", "0"],
        ["fuse", "--config", str(SIM_RIG), "--preset", "A9"],
        ["fuse", "--input", str(SIM_RIG), "--output", f"{MISSING}/x.csv"],
        ["fuse", "--input", str(SIM_RIG), "--output", "x.csv", "--preset", "A9"],
    ],
    ids=lambda argv: " ".join(a for a in argv if "/" not in a),
)
def test_the_reported_tracebacks_are_usage_errors(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as refused:
        cli.main(argv)
    err = capsys.readouterr().err
    assert refused.value.code == EXIT_USAGE and "Traceback" not in err
    assert re.search(rf"argument (-\w/)?{argv[-2]}", err)  # names the option, not a temporary file's key
    assert "tmp" not in err


# -- poses: where they come from, never a silent fallback ------------------------------------------------------


def _rig_text(name: str, sensor_ids: tuple[str, ...], calibration: str | None = None) -> str:
    lines = ["[rig]", f'name = "{name}"']
    if calibration is not None:
        lines += ["[calibration]", f'file = "{calibration}"']
    for sid in sensor_ids:
        lines += ["[[sensors]]", f'id = "{sid}"', 'source = "sim"', "world_from_sensor = " + str(np.eye(4).tolist())]
    return "\n".join(lines) + "\n"


def test_a_missing_calibration_file_is_an_error_naming_it_and_the_fix(tmp_path: Path) -> None:
    rig = tmp_path / "rig.toml"
    rig.write_text(_rig_text("lab", ("a", "b"), calibration="calibration-lab.toml"))
    cfg = load_rig_config(rig)
    with pytest.raises(ConfigError) as info:
        cfg.poses()  # before: the inline poses, silently
    message = str(info.value)
    assert str(tmp_path / "calibration-lab.toml") in message and "skelfuse calibrate" in message
    assert "remove the key" in message
    assert set(cfg.pose_sources().values()) == {"inline world_from_sensor"}  # start-up says so


def test_a_calibration_naming_only_unknown_sensors_is_an_error(tmp_path: Path) -> None:
    (tmp_path / "cal.toml").write_text("[sensors.zz]\nworld_from_sensor = " + str(np.eye(4).tolist()) + "\n")
    cfg = load_rig_config(_write(tmp_path / "rig.toml", _rig_text("lab", ("a", "b"), calibration="cal.toml")))
    with pytest.raises(ConfigError, match=r"holds poses of zz, none of which is a sensor of rig 'lab'"):
        cfg.poses()


def test_pose_sources_say_which_sensor_takes_its_pose_from_where(tmp_path: Path) -> None:
    pose = np.eye(4)
    pose[:3, 3] = [100.0, 0.0, 0.0]
    (tmp_path / "cal.toml").write_text("[sensors.a]\nworld_from_sensor = " + str(pose.tolist()) + "\n")
    cfg = load_rig_config(_write(tmp_path / "rig.toml", _rig_text("lab", ("a", "b"), calibration="cal.toml")))
    assert cfg.pose_sources() == {"a": f"calibration file {tmp_path / 'cal.toml'}", "b": "inline world_from_sensor"}
    np.testing.assert_allclose(cfg.poses()["a"], pose)
    assert cfg.describe_poses() == f"calibration file {tmp_path / 'cal.toml'}: a; inline world_from_sensor: b"


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _recording(path: Path, *, chunks_every: int | None = None) -> Path:
    cfg = load_rig_config(SIM_RIG)
    sources = [SimSource(cfg, sid, take_duration_s=2.0, loop=False, clock_ns=lambda: 10**18) for sid in cfg.sensor_ids]
    with RecordingWriter(path, rig=cfg.name, sensor_ids=cfg.sensor_ids, world_from_sensor=cfg.poses()) as writer:
        for n in range(60):
            for source in sources:
                frame = source.frame_at(n)
                if frame is not None:
                    writer.write(dataclasses.replace(frame, host_time_ns=10**18 + n * 33_333_333 + 1000))
            if chunks_every and n % chunks_every == chunks_every - 1:
                writer.flush()
    return path


def test_offline_fusion_with_another_rigs_config_is_an_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recording = _recording(tmp_path / "take.mcap")
    other = _write(tmp_path / "other.toml", _rig_text("other", ("k1",)))
    code = cli.main(["fuse", "--input", str(recording), "--config", str(other), "--output", str(tmp_path / "o.csv")])
    err = capsys.readouterr().err
    assert code == EXIT_USAGE, err  # before: exit 0, output byte-identical to no config at all
    assert "is not the rig of recording" in err and "rig 'sim4'" in err and "no sensor capture_0" in err
    assert not (tmp_path / "o.csv").exists()


def test_offline_fusion_says_where_the_poses_came_from_and_that_a_file_ended_early(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    whole = _recording(tmp_path / "take.mcap", chunks_every=15)
    data = whole.read_bytes()
    cut = _write(tmp_path / "cut.mcap", "")
    cut.write_bytes(data[: int(len(data) * 0.6)])  # a recorder killed mid-take
    with caplog.at_level(logging.INFO, logger="skelfuse.recording"):
        code = cli.main(["fuse", "--input", str(cut), "--output", str(tmp_path / "cut.csv"), "--json"])
    assert code == 0
    assert f"recording {cut} ends early" in caplog.text
    assert f"from the calibration metadata of {cut}" in caplog.text


def test_a_file_cut_inside_its_first_chunk_says_it_ends_early(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = _recording(tmp_path / "take.mcap").read_bytes()  # one chunk: the writer never flushed
    cut = _write(tmp_path / "cut.mcap", "")
    cut.write_bytes(data[: len(data) // 2])
    code = cli.main(["fuse", "--input", str(cut), "--output", str(tmp_path / "cut.csv")])
    err = capsys.readouterr().err
    assert code == EXIT_USAGE and "ends early: cut before its first complete chunk" in err, err
    assert "Traceback" not in err


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (a device whose writes fail: disk full)")
def test_an_output_on_a_full_disk_is_a_message_not_a_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recording = _recording(tmp_path / "take.mcap")
    output = tmp_path / "fused.csv"
    output.symlink_to("/dev/full")  # writes there fail with ENOSPC, as on a full disk
    code = cli.main(["fuse", "--input", str(recording), "--config", str(SIM_RIG), "--output", str(output)])
    err = capsys.readouterr().err
    assert code == EXIT_ERROR, err
    assert "No space left on device" in err and "free disk space" in err and "Traceback" not in err, err


def test_live_fuse_honours_preset(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from skelfuse.cli import service

    seen = {}

    def fake_node(cfg: object, zenoh_conf: object, **kwargs: object) -> NodeReport:
        seen["preset"] = cfg.fusion.preset  # type: ignore[attr-defined]
        return NodeReport()

    monkeypatch.setattr(service, "run_fusion_node", fake_node)
    assert cli.main(["fuse", "--config", str(SIM_RIG), "--preset", "A3", "--no-view", "--duration", "1"]) == 0
    assert seen["preset"] == "A3"  # before: the config's preset, --preset silently ignored


# -- help texts and messages that were wrong ------------------------------------------------------------------


def _help(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit):
        cli.main([*argv, "--help"])
    return capsys.readouterr().out


def test_help_texts_are_current(capsys: pytest.CaptureFixture[str]) -> None:
    assert "separate issue" not in _help(["capture"], capsys)
    assert "kinect" in _help(["capture"], capsys)
    assert "%%" not in _help(["calibrate", "capture"], capsys)
    status = _help(["status"], capsys)
    assert "--max-messages N" in status and "status messages" in status


def test_devices_says_each_install_step_once() -> None:
    from skelfuse.sources import devices

    text = devices.describe_environment(k4a_path="/nonexistent/libk4a.so", k4abt_path="/nonexistent/libk4abt.so")
    lines = text.splitlines()
    assert len(lines) == len(set(lines))
    assert text.count("Microsoft's package repository") <= 1 and text.count("See docs/kinect.md") == 1


def test_calibrate_check_exits_2_for_a_missing_or_invalid_calibration(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = _write(tmp_path / "rig.toml", _rig_text("lab", ("a",), calibration="never-made.toml"))
    recording = _recording(tmp_path / "take.mcap")
    assert cli.main(["calibrate", "check", "--config", str(rig), "--recording", str(recording)]) == EXIT_USAGE
    assert "never-made.toml not found" in capsys.readouterr().err
    bad = _write(tmp_path / "bad.toml", "not = = toml")
    assert cli.main(["calibrate", "check", "--calibration", str(bad), "--recording", str(recording)]) == EXIT_USAGE
    assert "not valid TOML" in capsys.readouterr().err


# -- the example subscriber never listens silently on the wrong rig -------------------------------------------


def _example() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "skelfuse_example_subscriber_inputs", REPO / "scripts" / "example_subscriber.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules.pop(spec.name, None)
    spec.loader.exec_module(module)
    return module


def test_example_subscriber_needs_a_rig_and_takes_it_from_the_config(capsys: pytest.CaptureFixture[str]) -> None:
    example = _example()
    with pytest.raises(SystemExit):
        example.parse_args([])  # before: listened on rig "default", silently
    assert "--rig NAME" in capsys.readouterr().err
    args = example.parse_args(["--config", str(SIM_RIG)])
    cfg = load_rig_config(SIM_RIG)
    assert args.rig == cfg.name and args.mode == cfg.zenoh.mode
    with pytest.raises(SystemExit):
        example.parse_args(["--config", str(SIM_RIG), "--rig", "other"])
    assert "give one of them" in capsys.readouterr().err
