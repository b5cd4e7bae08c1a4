"""The live service: long-running nodes of a rig (capture workers, the fusion node) and their pure helpers.

- :mod:`skelfuse.rig.grouping`: :class:`FrameGrouper`, which groups the sensors' frames of one instant
  (pure: no clocks, no threads; time is passed in).

The nodes read a :class:`skelfuse.config.RigConfig` (``load_rig_config``) and open zenoh with
:func:`skelfuse.config.zenoh_config`.
"""

from skelfuse.rig.grouping import FrameGroup, FrameGrouper, GrouperStats, SensorCounters

__all__ = ["FrameGroup", "FrameGrouper", "GrouperStats", "SensorCounters"]
