"""The fake Azure Kinect stack (tests/fake_k4a/) for the unit tests: its harness module, and its libraries
compiled from C, or a skip that says why where gcc is missing.

The tests folder is not a package, so the harness is loaded from its path, once: every test file that imports
it here shares one module object (its ctypes structures and fake ``pyk4a`` are then one set of classes).
"""

from __future__ import annotations

import importlib.util
import shutil
import sys
import types
from pathlib import Path
from typing import Any

import pytest

HARNESS_PATH = Path(__file__).resolve().parents[1] / "fake_k4a" / "harness.py"


def _load_harness() -> types.ModuleType:
    spec = importlib.util.spec_from_file_location("skelfuse_fake_k4a_harness", HARNESS_PATH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault(spec.name, module)
    spec.loader.exec_module(sys.modules[spec.name])
    return sys.modules[spec.name]


harness = _load_harness()


def build_fake_libs_or_skip(directory: Path, abi: str, what: str) -> Any:
    """Compile the fake libk4a / libk4abt of SDK generation ``abi`` into ``directory``; skip where gcc is
    missing, naming ``what`` needed them."""
    if shutil.which("gcc") is None:
        pytest.skip(f"gcc is not on PATH: cannot compile the fake libk4a / libk4abt {what}")
    return harness.build.build_fake_libs(directory, abi)
