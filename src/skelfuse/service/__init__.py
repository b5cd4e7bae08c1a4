"""The live service: long-running nodes of a rig (capture workers, the fusion node) and their pure helpers.

- :mod:`skelfuse.rig.grouping`: :class:`FrameGrouper`, which groups the sensors' frames of one instant
  (pure: no clocks, no threads; time is passed in).

The nodes read a :class:`skelfuse.config.RigConfig` (``load_rig_config``) and open zenoh with
:func:`skelfuse.config.zenoh_config`.

The grouper's names load on first access (PEP 562): the light modules of the package (``lifecycle``,
``zenoh_io``) are what the command line's start-up imports, and they need no numpy.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from skelfuse.rig.grouping import FrameGroup, FrameGrouper, GrouperStats, SensorCounters

__all__ = ["FrameGroup", "FrameGrouper", "GrouperStats", "SensorCounters"]


def __getattr__(name: str) -> Any:
    """Load the grouper's names from :mod:`skelfuse.rig.grouping` on first access."""
    if name in __all__:
        value = getattr(importlib.import_module("skelfuse.rig.grouping"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
