"""The pure fusion core: numpy in, numpy out; no I/O, clocks, threads or logging.

Modules follow the data flow: :mod:`~skelfuse.fusion.transform` (sensor -> world),
:mod:`~skelfuse.fusion.realign` (left/right labels), :mod:`~skelfuse.fusion.merge` (DBSCAN per joint),
:mod:`~skelfuse.fusion.filters` (per-joint temporal filters), :mod:`~skelfuse.fusion.presets` (parameters,
the paper's A1-A5) and :mod:`~skelfuse.fusion.pipeline` (``fuse()`` chaining them).

The names below load on first use (PEP 562): importing one light module of the package (the presets, the
rigid transform, as the rig config does) must not load the pipeline and, through the association's
Hungarian assignment, SciPy, which an app that only subscribes to the fused stream never needs.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
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
_HOMES = ("skelfuse.fusion.presets", "skelfuse.fusion.pipeline")
"""Where the names of ``__all__`` live, searched in this order on first access."""


def __getattr__(name: str) -> Any:
    """Load ``name`` from its module on first access (then it is a plain module attribute)."""
    if name in __all__:
        for home in _HOMES:
            module = importlib.import_module(home)
            if hasattr(module, name):
                value = getattr(module, name)
                globals()[name] = value
                return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
