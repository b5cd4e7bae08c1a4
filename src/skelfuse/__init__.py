"""skelfuse: fuse the skeletons of several Azure Kinect body trackers into one accurate, smooth skeleton.

The public Python API is what this module exports (``__all__``); docs/python-api.md shows it at work::

    import skelfuse

    with skelfuse.subscribe("lab", connect=["tcp/192.168.1.10:7447"]) as fused:
        for frame in fused:                     # skelfuse.FusedFrame: numpy arrays, mm, world frame
            print(frame.time_us, frame.track_ids, frame.positions[:, skelfuse.joint_index("PELVIS")])

Everything else (``skelfuse.fusion``, ``skelfuse.wire``, ...) is internal: it may change in any 0.x release.
Every exported name loads on first use (PEP 562): ``import skelfuse`` (and so the ``skelfuse`` command line,
whose ``--help`` needs none of them) imports no numpy, and an app that only subscribes imports numpy and
zenoh, not the recording container or the fusion pipeline's SciPy.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # what mypy and IDEs see; at run time each name loads on first access (below)
    from skelfuse.api.live import FusedSubscriber, subscribe
    from skelfuse.api.recordings import fuse_recording, read_fused_frames, read_sensor_frames
    from skelfuse.schema.errors import ConfigError, DataError, ServiceError, SkelfuseError
    from skelfuse.schema.frames import FusedFrame, SensorFrame
    from skelfuse.schema.skeleton import BONES, JOINT_NAMES, MIRROR, N_JOINTS, PARENTS, Confidence, joint_index

from skelfuse.version import __version__

__all__ = [
    "BONES",
    "JOINT_NAMES",
    "MIRROR",
    "N_JOINTS",
    "PARENTS",
    "Confidence",
    "ConfigError",
    "DataError",
    "FusedFrame",
    "FusedSubscriber",
    "SensorFrame",
    "ServiceError",
    "SkelfuseError",
    "__version__",
    "fuse_recording",
    "joint_index",
    "read_fused_frames",
    "read_sensor_frames",
    "subscribe",
]

_HOMES = {
    "skelfuse.api.live": ("FusedSubscriber", "subscribe"),
    "skelfuse.api.recordings": ("fuse_recording", "read_fused_frames", "read_sensor_frames"),
    "skelfuse.schema.errors": ("ConfigError", "DataError", "ServiceError", "SkelfuseError"),
    "skelfuse.schema.frames": ("FusedFrame", "SensorFrame"),
    "skelfuse.schema.skeleton": ("BONES", "JOINT_NAMES", "MIRROR", "N_JOINTS", "PARENTS", "Confidence", "joint_index"),
}
_HOME_OF = {name: module for module, names in _HOMES.items() for name in names}
"""Where each exported name is defined: it loads from there on first access."""


def __getattr__(name: str) -> Any:
    """Load an exported name on first access (then it is a plain module attribute)."""
    if name in _HOME_OF:
        value = getattr(importlib.import_module(_HOME_OF[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
