"""Run the ``skelfuse`` command line against the fake Azure Kinect stack: ``python run_skelfuse.py ARGS...``.

For tests that need a real skelfuse process with a "device": the fake ``pyk4a`` module of harness.py (its
captures carry handles made by the compiled fake libk4a) is put in ``sys.modules`` before skelfuse imports
it, and skelfuse loads the compiled fake libk4abt through ``SKELFUSE_K4ABT_LIBRARY``. Environment:

``FAKE_K4A_LIBRARY``     the compiled fake libk4a (required)
``FAKE_K4A_SERIALS``     comma-separated serials of the connected devices (default ``000111``)
``FAKE_K4A_PERIOD_S``    seconds between captures (default 1/30: a 30 fps camera)
``SKELFUSE_K4ABT_LIBRARY`` the compiled fake libk4abt; ``FAKE_K4ABT_FAULT`` its faults (fake_k4abt.c)
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _harness():
    spec = importlib.util.spec_from_file_location("skelfuse_fake_k4a_harness", HERE / "harness.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def main() -> None:
    serials = os.environ.get("FAKE_K4A_SERIALS", "000111").split(",")
    os.environ.setdefault("FAKE_K4A_DEVICES", ";".join(f"{serial}:0:0" for serial in serials))  # what libk4a reports
    harness = _harness()
    world = harness.FakeWorld(
        k4a=harness.FakeK4a(Path(os.environ["FAKE_K4A_LIBRARY"])),
        serials=serials,
        capture_period_s=float(os.environ.get("FAKE_K4A_PERIOD_S", str(1 / 30))),
    )
    sys.modules["pyk4a"] = harness.make_fake_pyk4a(world)
    from skelfuse.cli import entrypoint

    sys.argv = ["skelfuse", *sys.argv[1:]]
    entrypoint()


if __name__ == "__main__":
    main()
