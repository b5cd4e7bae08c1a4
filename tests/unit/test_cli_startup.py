"""Every ``--help`` of the command line imports only what parsing needs: no simulator, evaluation, benchmark,
scipy, numba, Rerun, OpenCV or matplotlib (each command imports what it runs, when it runs).

The probe is Python's own import log (``python -X importtime``) of the real command in a fresh interpreter,
so a module pulled in by any route counts. Start-up *speed* is measured, not asserted: docs/service.md,
"Start-up".
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys

import pytest

from skelfuse.cli import build_parser

pytestmark = pytest.mark.live  # starts interpreters

HEAVY = ("scipy", "numba", "rerun", "cv2", "matplotlib", "skelfuse.sim", "skelfuse.eval", "skelfuse.bench")


def _command_lines() -> list[list[str]]:
    """``[]`` (the top level), every command and every sub-command, read from the parser itself."""
    lines: list[list[str]] = [[]]

    def walk(parser: argparse.ArgumentParser, prefix: list[str]) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    lines.append([*prefix, name])
                    walk(sub, [*prefix, name])

    walk(build_parser(), [])
    return lines


def imported_modules(argv: list[str]) -> tuple[set[str], str]:
    """Modules a fresh ``python -m skelfuse ARGV`` imports, from its ``-X importtime`` log; and its stdout."""
    done = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "skelfuse", *argv],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONWARNINGS": "ignore"},
    )
    assert done.returncode == 0, done.stderr[-2000:]
    modules = {line.split("|")[-1].strip() for line in done.stderr.splitlines() if line.startswith("import time:")}
    return modules, done.stdout


def test_the_parser_lists_the_commands_a_user_runs() -> None:
    names = {" ".join(line) for line in _command_lines()}
    assert {"fuse", "capture", "demo", "export", "bench fusion", "calibrate skeleton", "eval real"} <= names


@pytest.mark.parametrize("argv", _command_lines(), ids=lambda argv: " ".join(argv) or "skelfuse")
def test_help_imports_nothing_heavy(argv: list[str]) -> None:
    modules, out = imported_modules([*argv, "--help"])
    assert "usage: skelfuse" in out
    assert "skelfuse.cli" in modules  # the probe sees our own imports
    heavy = sorted(m for m in modules if any(m == h or m.startswith(h + ".") for h in HEAVY))
    assert not heavy, f"`skelfuse {' '.join(argv)} --help` imported {heavy[:8]}"


def test_the_probe_sees_a_heavy_import() -> None:
    """The control: a command that runs the simulator does show it in the log."""
    modules, _ = imported_modules(["sim", "check", "--seeds", "1", "--duration", "0.5", "--no-real", "--json", "-q"])
    assert "skelfuse.sim" in modules and "scipy" in modules
