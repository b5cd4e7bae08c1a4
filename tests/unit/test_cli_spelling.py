"""One spelling across commands: every command that writes a file takes -o/--output; what a command refuses
about its output it refuses before doing anything (no folder created behind the user's back)."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from skelfuse.cli import build_parser, main
from skelfuse.cli.common import EXIT_USAGE


def _commands(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*prefix, name), sub
                yield from _commands(sub, (*prefix, name))


def test_every_output_option_is_also_o() -> None:
    writers = []
    for name, parser in _commands(build_parser()):
        flags = {flag for action in parser._actions for flag in action.option_strings}
        if "--output" in flags or "--out" in flags:
            writers.append(" ".join(name))
            assert {"-o", "--output"} <= flags, f"skelfuse {' '.join(name)}: -o/--output"
    assert {"export", "convert", "fuse", "record", "calibrate skeleton", "eval real", "calibrate capture"} <= set(
        writers
    )


def test_export_refuses_an_output_folder_that_does_not_exist(tmp_path: Path, capsys) -> None:
    table = tmp_path / "fused.csv"
    table.write_text("time_us,track_id\n")
    with pytest.raises(SystemExit) as stop:
        main(["export", str(table), "--format", "csv", "-o", str(tmp_path / "nowhere" / "out.csv")])
    assert stop.value.code == EXIT_USAGE
    assert "does not exist; create it first" in capsys.readouterr().err
    assert not (tmp_path / "nowhere").exists()


def test_export_help_describes_every_format(capsys) -> None:
    with pytest.raises(SystemExit):
        main(["export", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for what in ("csv =", "c3d =", "trc =", "bvh =", "fbx =", "skelfuse setup blender"):
        assert what in text, what
