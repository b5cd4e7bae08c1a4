"""The systemd units in config/systemd: valid for systemd, and their command lines are ones skelfuse accepts."""

from __future__ import annotations

import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from skelfuse.cli import build_parser

ROOT = Path(__file__).resolve().parents[2]
UNITS = sorted((ROOT / "config" / "systemd").glob("*.service"))
INSTALLED = "/opt/skelfuse/venv/bin/skelfuse"
INSTANCES = {"skelfuse-capture@.service": "capture_0", "skelfuse-stream@.service": "osc"}  # %i of template units


def exec_start(unit: Path) -> list[str]:
    lines = [line for line in unit.read_text().splitlines() if line.startswith("ExecStart=")]
    assert len(lines) == 1, f"{unit.name}: expected one ExecStart"
    return shlex.split(lines[0].removeprefix("ExecStart="))


def test_every_unit_is_there() -> None:
    assert {u.name for u in UNITS} >= {
        "skelfuse-capture@.service",
        "skelfuse-fuse.service",
        "skelfuse-stream@.service",
        "skelfuse-router.service",
    }


@pytest.mark.parametrize("unit", UNITS, ids=lambda u: u.name)
def test_unit_command_line_parses_with_skelfuses_own_parser(unit: Path) -> None:
    argv = exec_start(unit)
    assert argv[0] == INSTALLED, f"{unit.name}: runs {argv[0]}, not the installed skelfuse"
    rig = str(ROOT / "config" / "rig-sim-4.toml")
    args = [a.replace("${SKELFUSE_CONFIG}", rig).replace("%i", INSTANCES.get(unit.name, "")) for a in argv[1:]]
    parsed = build_parser().parse_args(args)  # argparse exits (SystemExit) on a command line it does not know
    assert callable(parsed.func)


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed")
@pytest.mark.live
def test_units_pass_systemd_analyze_verify(tmp_path: Path) -> None:
    skelfuse = Path(sys.executable).parent / "skelfuse"  # the venv's entry point stands in for /opt/skelfuse
    assert skelfuse.exists()
    copies = []
    for unit in UNITS:
        name = unit.name.replace("@.", f"@{INSTANCES[unit.name]}.") if "@." in unit.name else unit.name
        copy = tmp_path / name
        copy.write_text(unit.read_text().replace(INSTALLED, str(skelfuse)))
        copies.append(str(copy))
    result = subprocess.run(
        ["systemd-analyze", "verify", *copies], capture_output=True, text=True, timeout=60, cwd=tmp_path
    )
    ours = [line for line in (result.stdout + result.stderr).splitlines() if "skelfuse" in line]
    assert result.returncode == 0 and not ours, result.stdout + result.stderr


@pytest.mark.parametrize("unit", UNITS, ids=lambda u: u.name)
def test_a_crashed_daemon_restarts_within_half_a_second(unit: Path) -> None:
    settings = dict(line.split("=", 1) for line in unit.read_text().splitlines() if "=" in line and line[0] != "#")
    assert settings["Restart"] == "on-failure"
    delay = settings["RestartSec"]
    seconds = float(delay.removesuffix("ms")) / 1000 if delay.endswith("ms") else float(delay.removesuffix("s"))
    assert seconds <= 0.5, f"{unit.name}: RestartSec={delay}"
    assert settings.get("StartLimitIntervalSec") == "0", "a fast restart must not hit systemd's start limit"
    assert "2" in settings.get("RestartPreventExitStatus", "").split(), "a config error is not retried"
