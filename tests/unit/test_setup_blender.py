"""``skelfuse setup blender`` installs bpy only when asked, saying what, where and how big, with pip's progress;
an environment already there is recognised. The install path runs for real (``venv``, then ``pip install``)
against a stand-in ``python3.11`` whose pip "installs" a tiny bpy, so no gigabyte is downloaded."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.live  # starts interpreters and builds a virtual environment

STUB_PIP = """\
import pathlib, sys, sysconfig
print("Collecting", sys.argv[-1], flush=True)
print("Downloading bpy-4.5.0-fake.whl (1 kB) 100%", flush=True)
if "{outcome}" == "fail":
    print("ERROR: No matching distribution found for", sys.argv[-1], file=sys.stderr)
    sys.exit(1)
package = pathlib.Path(sysconfig.get_paths()["purelib"]) / "bpy"
package.mkdir()
(package / "__init__.py").write_text("class app:\\n    version_string = '4.5.0 stand-in'\\n")
print("Successfully installed bpy-4.5.0", flush=True)
"""

FAKE_PYTHON = """\
#!/bin/sh
# stands in for python3.11: `-m venv DIR` builds a real environment (without pip) with a stub pip in it
if [ "$1" = "-m" ] && [ "$2" = "venv" ]; then
    "{real}" -m venv --without-pip "$3" || exit 1
    site=$("$3/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
    mkdir -p "$site/pip" && touch "$site/pip/__init__.py" && cp "{stub}" "$site/pip/__main__.py"
    exit 0
fi
exec "{real}" "$@"
"""


def _setup(tmp_path: Path, outcome: str, *extra: str) -> subprocess.CompletedProcess[str]:
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(exist_ok=True)
    stub = tmp_path / "stub_pip.py"
    stub.write_text(STUB_PIP.format(outcome=outcome))
    fake = bin_dir / "python3.11"
    fake.write_text(FAKE_PYTHON.format(real=sys.executable, stub=stub))
    fake.chmod(0o755)
    env = {
        **os.environ,
        "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}",
        "SKELFUSE_BPY_VENV": str(tmp_path / "cache" / "bpy-venv"),
    }
    return subprocess.run(
        [sys.executable, "-m", "skelfuse", "setup", "blender", *extra],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )


def test_setup_says_what_where_and_how_big_then_recognises_it(tmp_path: Path) -> None:
    venv = tmp_path / "cache" / "bpy-venv"
    assert _setup(tmp_path, "ok", "--check").returncode == 1  # not there yet: --check says so, builds nothing
    assert not venv.exists()
    first = _setup(tmp_path, "ok")
    assert first.returncode == 0, first.stderr
    assert "bpy==4.5.*" in first.stderr and str(venv) in first.stderr and "950 MB on disk" in first.stderr
    assert "Downloading bpy" in first.stderr  # pip's own progress reaches the user
    assert f"bpy 4.5.0 stand-in is installed at {venv}" in first.stdout
    assert [p.name for p in venv.parent.iterdir()] == ["bpy-venv"]  # no staging folder left behind
    again = _setup(tmp_path, "ok")
    assert again.returncode == 0 and "nothing to do" in again.stdout and "Downloading" not in again.stderr


def test_a_failed_install_leaves_nothing_and_says_why(tmp_path: Path) -> None:
    done = _setup(tmp_path, "fail")
    assert done.returncode == 1
    assert "pip could not install bpy==4.5.*" in done.stderr and "Traceback" not in done.stderr
    assert not any((tmp_path / "cache").iterdir())  # neither the environment nor a half-built one
