"""Compile the fake libk4a / libk4abt of the test suite with gcc (used by pytest fixtures).

``build_fake_libs(directory, abi="1.1")`` writes ``libk4a.so`` and ``libk4abt.so`` (``.dll`` on Windows) built
from ``fake_k4a.c`` / ``fake_k4abt.c`` and ``k4a_abi.h`` next to this file, and returns their paths. ``abi``
selects the Body Tracking SDK generation the fake mimics ("1.0" or "1.1"). Needs gcc on PATH; callers skip
when :func:`gcc_path` is None.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
ABI_FLAGS = {"1.0": "10", "1.1": "11"}


@dataclass(frozen=True)
class FakeLibs:
    k4a: Path
    k4abt: Path
    abi: str


def gcc_path() -> str | None:
    return shutil.which("gcc")


def _suffix() -> str:
    return ".dll" if sys.platform == "win32" else ".so"


def _compile(source: str, output: Path, abi: str) -> None:
    gcc = gcc_path()
    if gcc is None:
        raise RuntimeError("gcc is not on PATH: cannot build the fake Azure Kinect libraries")
    command = [
        gcc,
        "-shared",
        "-fPIC",
        "-O1",
        "-std=c11",
        "-D_POSIX_C_SOURCE=200809L",
        "-Wall",
        "-Wextra",
        "-Werror",
        f"-DFAKE_K4ABT_ABI={ABI_FLAGS[abi]}",
        f"-I{HERE}",
        str(HERE / source),
        "-o",
        str(output),
    ]
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"gcc failed building {source}:\n{' '.join(command)}\n{result.stderr}")


def build_fake_libs(directory: Path, abi: str = "1.1") -> FakeLibs:
    """Compile both fakes into ``directory`` (created if missing)."""
    if abi not in ABI_FLAGS:
        raise ValueError(f"abi must be one of {sorted(ABI_FLAGS)}, got {abi!r}")
    directory.mkdir(parents=True, exist_ok=True)
    k4a = directory / f"libk4a{_suffix()}"
    k4abt = directory / f"libk4abt{_suffix()}"
    _compile("fake_k4a.c", k4a, abi)
    _compile("fake_k4abt.c", k4abt, abi)
    return FakeLibs(k4a=k4a, k4abt=k4abt, abi=abi)
