"""Blender (the ``bpy`` wheel) driven in its own virtual environment, through a subprocess.

bpy 4.5 needs Python 3.11 and pins numpy < 2, while our environment needs numpy ≥ 2 (rerun, OpenCV), so
the two cannot share one environment. This module finds (or builds, on request, and caches) a separate
environment with bpy, and runs :mod:`skelfuse.export.blender_driver` there as a script, exchanging JSON.

Where the environment lives: ``$SKELFUSE_BPY_VENV`` if set, else ``~/.cache/skelfuse/bpy-venv``. It is
built only when a person asks: ``skelfuse setup blender`` (:func:`install_bpy`: ``python3.11 -m venv DIR``
+ ``pip install "bpy==4.5.*"``, pip's own progress shown, about 950 MB on disk); every other use refuses
with a :class:`BlenderError` naming that command (no silent gigabyte).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from skelfuse.schema.errors import SkelfuseError

BPY_REQUIREMENT = "bpy==4.5.*"
BPY_PYTHON = "python3.11"
BPY_SIZE_MB = 950
"""What the environment takes on disk once built (947 MB measured with bpy 4.5.15 on Linux x86-64)."""
SETUP_COMMAND = "skelfuse setup blender"
DRIVER = Path(__file__).with_name("blender_driver.py")


class BlenderError(SkelfuseError):
    """Blender's bpy is not available (and could not be installed), or it failed on a file."""


def bpy_venv_dir() -> Path:
    """Where the bpy environment is (``$SKELFUSE_BPY_VENV``, else ``~/.cache/skelfuse/bpy-venv``)."""
    configured = os.environ.get("SKELFUSE_BPY_VENV")
    return Path(configured) if configured else Path.home() / ".cache" / "skelfuse" / "bpy-venv"


def _python_in(venv: Path) -> Path:
    return venv / ("Scripts/python.exe" if sys.platform == "win32" else "bin/python")


_WORKING: set[Path] = set()  # interpreters that imported bpy once in this process (the probe takes seconds)


def bpy_python() -> Path | None:
    """The bpy environment's interpreter if it exists and imports bpy, else None."""
    python = _python_in(bpy_venv_dir())
    if python in _WORKING:
        return python
    if not python.exists():
        return None
    probe = subprocess.run([str(python), "-c", "import bpy"], capture_output=True, timeout=120, check=False)
    if probe.returncode != 0:
        return None
    _WORKING.add(python)
    return python


def ensure_bpy() -> Path:
    """The bpy interpreter; refuses, naming ``skelfuse setup blender``, where there is none.

    Raises
    ------
    BlenderError
        No working bpy environment at :func:`bpy_venv_dir`.
    """
    python = bpy_python()
    if python is not None:
        return python
    venv = bpy_venv_dir()
    state = "does not import bpy" if _python_in(venv).exists() else "does not exist"
    raise BlenderError(
        f"FBX is written by Blender's own exporter, which needs Blender's bpy; the environment at {venv} {state}. "
        f"Install it once with `{SETUP_COMMAND}` ({BPY_REQUIREMENT} for {BPY_PYTHON}, about {BPY_SIZE_MB} MB on "
        "disk; $SKELFUSE_BPY_VENV chooses where)"
    )


def folder_size_bytes(path: Path) -> int:
    """Bytes of the files under ``path`` (what ``du`` would count, without following links)."""
    return sum(f.lstat().st_size for f in path.rglob("*") if f.is_file() and not f.is_symlink())


def install_bpy(*, log: Callable[[str], None], stream: IO[str] | None = None) -> Path:
    """Build the bpy environment at :func:`bpy_venv_dir` (``skelfuse setup blender``); pip's own output,
    with its download progress, goes to ``stream``. The environment appears complete or not at all.

    Raises
    ------
    BlenderError
        No Python 3.11 to build it with, or pip could not install bpy (the message carries pip's last lines).
    """
    venv = bpy_venv_dir()
    base = shutil.which(BPY_PYTHON)
    if base is None:
        raise BlenderError(
            f"bpy 4.5 needs {BPY_PYTHON}, which is not on PATH; install Python 3.11 or set "
            f"SKELFUSE_BPY_VENV to an environment that has bpy"
        )
    venv.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix="bpy-venv-", dir=venv.parent))
    try:
        log(f"creating a {BPY_PYTHON} environment ({base})")
        subprocess.run([base, "-m", "venv", str(staging)], check=True, capture_output=True, timeout=600)
        log(f"pip install {BPY_REQUIREMENT} (the download is about 400 MB)")
        pip = subprocess.run(
            [str(_python_in(staging)), "-m", "pip", "install", "--progress-bar", "on", BPY_REQUIREMENT],
            stdout=stream,
            stderr=subprocess.STDOUT if stream is not None else subprocess.PIPE,
            text=True,
            timeout=1800,
            check=False,
        )
        if pip.returncode != 0:
            tail = "\n".join((pip.stderr or "").strip().splitlines()[-5:])
            raise BlenderError(
                f"pip could not install {BPY_REQUIREMENT} (exit {pip.returncode}; no wheel for this platform, "
                f"or no network?){': ' + tail if tail else ''}"
            )
        shutil.rmtree(venv, ignore_errors=True)
        staging.rename(venv)  # complete or absent: a half-built environment is never found at `venv`
    except subprocess.SubprocessError as exc:
        raise BlenderError(f"building the bpy environment at {venv} failed: {exc}") from exc
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    python = bpy_python()
    if python is None:
        raise BlenderError(f"the bpy environment at {venv} was built but 'import bpy' fails there")
    return python


def bpy_version(python: Path) -> str:
    """bpy's version string in the environment of ``python``."""
    done = subprocess.run(
        [str(python), "-c", "import bpy; print(bpy.app.version_string)"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    return done.stdout.strip().splitlines()[-1] if done.returncode == 0 and done.stdout.strip() else "unknown"


def run_blender(request: dict[str, Any], *, timeout_s: float = 900.0) -> dict[str, Any]:
    """Run one driver command in Blender and return its JSON result.

    Raises
    ------
    BlenderError
        bpy unavailable, or the driver failed (its stderr's last lines in the message).
    """
    python = ensure_bpy()
    with tempfile.TemporaryDirectory(prefix="skelfuse-blender-") as work:
        request_path = Path(work) / "request.json"
        result_path = Path(work) / "result.json"
        request_path.write_text(json.dumps(request), encoding="utf-8")
        done = subprocess.run(
            [str(python), str(DRIVER), str(request_path), str(result_path)],
            capture_output=True,
            text=True,
            timeout=timeout_s,
            check=False,
        )
        if done.returncode != 0 or not result_path.exists():
            tail = "\n".join((done.stderr or done.stdout).strip().splitlines()[-8:])
            raise BlenderError(f"Blender failed on {request.get('command')!r} (exit {done.returncode}):\n{tail}")
        return json.loads(result_path.read_text(encoding="utf-8"))
