"""The pure fusion core: numpy in, numpy out; no I/O, clocks, threads or logging.

Modules follow the data flow: :mod:`~skelfuse.fusion.transform` (sensor -> world),
:mod:`~skelfuse.fusion.realign` (left/right labels), :mod:`~skelfuse.fusion.merge` (DBSCAN per joint),
:mod:`~skelfuse.fusion.filters` (per-joint temporal filters), :mod:`~skelfuse.fusion.presets` (parameters,
the paper's A1-A5) and :mod:`~skelfuse.fusion.pipeline` (``fuse()`` chaining them).
"""

from skelfuse.fusion.pipeline import Fuser, FusionResult, FusionState, fuse, init_state
from skelfuse.fusion.presets import ALL_PRESETS, PAPER_PRESETS, FusionParams, preset

__all__ = [
    "ALL_PRESETS",
    "PAPER_PRESETS",
    "Fuser",
    "FusionParams",
    "FusionResult",
    "FusionState",
    "fuse",
    "init_state",
    "preset",
]
