"""The pure fusion core: numpy in, numpy out; no I/O, clocks, threads or logging.

Modules follow the data flow: :mod:`~skelfuse.fusion.transform` (sensor -> world),
:mod:`~skelfuse.fusion.realign` (left/right labels), :mod:`~skelfuse.fusion.merge` (DBSCAN per joint),
:mod:`~skelfuse.fusion.filters` (per-joint temporal filters), :mod:`~skelfuse.fusion.presets` (parameters,
the paper's A1-A5) and :mod:`~skelfuse.fusion.pipeline` (``fuse()`` chaining them).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from skelfuse.fusion.pipeline import Fuser, FusionResult, FusionState, fuse, init_state
    from skelfuse.fusion.presets import ALL_PRESETS, PAPER_PRESETS, FusionParams, preset

#: Where each public name lives; loaded on first use so that importing a light module of the core
#: (``skelfuse.fusion.presets``) does not pay for the pipeline's scipy (the command line's start-up).
_HOMES = {
    **dict.fromkeys(("Fuser", "FusionResult", "FusionState", "fuse", "init_state"), "skelfuse.fusion.pipeline"),
    **dict.fromkeys(("ALL_PRESETS", "PAPER_PRESETS", "FusionParams", "preset"), "skelfuse.fusion.presets"),
}


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(home), name)
    globals()[name] = value
    return value


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
