"""Every ``--help`` of the command line imports only what parsing needs: no simulator, evaluation, benchmark,
scipy, numba, Rerun, OpenCV or matplotlib (each command imports what it runs, when it runs).

The probe runs the real command line in a fresh interpreter and reads ``sys.modules`` after it, so a module
pulled in by any route (``importlib`` included) counts. Start-up *speed* is measured, not asserted: docs/service.md,
"Start-up".
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import pytest

from skelfuse.cli import build_parser
from skelfuse.cli.commands import COMMANDS

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


PROBE = """
import json, sys
from skelfuse.cli import main
try:
    main(sys.argv[1:])
except SystemExit:
    pass
print("\\nMODULES " + json.dumps(sorted(sys.modules)))
"""
"""Runs the command line as ``python -m skelfuse`` does, then lists every module the interpreter holds (a
module imported by any route, ``importlib`` included, is there)."""


def imported_modules(argv: list[str]) -> tuple[set[str], str]:
    """Modules a fresh interpreter holds after ``skelfuse ARGV``; and what the command printed."""
    done = subprocess.run(
        [sys.executable, "-c", PROBE, *argv],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONWARNINGS": "ignore"},
    )
    assert done.returncode == 0, done.stderr[-2000:]
    out, _, listing = done.stdout.rpartition("\nMODULES ")
    return set(json.loads(listing)), out


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


@pytest.mark.parametrize("argv", [["--help"], ["--version"]], ids=" ".join)
def test_the_top_level_loads_no_numpy(argv: list[str]) -> None:
    """``skelfuse --help`` lists the commands from their table: neither the public API (PEP 562) nor the exit
    codes nor the service's lifecycle may pull in numpy (or the config, which loads it)."""
    modules, out = imported_modules(argv)
    assert "skelfuse" in out
    assert "skelfuse.cli" in modules
    loaded = sorted(m for m in modules if m.split(".")[0] == "numpy" or m.startswith("skelfuse.config"))
    assert not loaded, f"`skelfuse {' '.join(argv)}` imported {loaded[:8]}"


def test_each_command_imports_only_its_own_module() -> None:
    """``skelfuse --help`` builds no command's module; ``skelfuse fuse --help`` only the service commands'."""
    groups = {module for module, _ in COMMANDS.values()}
    top, _ = imported_modules(["--help"])
    assert not groups & top, sorted(groups & top)
    fuse, _ = imported_modules(["fuse", "--help"])
    assert groups & fuse == {"skelfuse.cli.service"}


def test_every_listed_command_is_built_by_its_module() -> None:
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert list(commands.choices) == list(COMMANDS)  # the listing's order is the table's
    for name, sub in commands.choices.items():
        assert sub._actions, f"{name} is only a placeholder"  # a built command has options (--help at least)


def test_the_probe_sees_a_heavy_import() -> None:
    """The control: a command that runs the simulator does show it in the log."""
    modules, _ = imported_modules(["sim", "check", "--seeds", "1", "--duration", "0.5", "--no-real", "--json", "-q"])
    assert "skelfuse.sim" in modules and "scipy" in modules
    fuse, _ = imported_modules(["fuse", "--help"])
    assert "numpy" in fuse  # a command's parser still reads the config, which loads numpy: the probe sees it
