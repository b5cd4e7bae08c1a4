"""The numpy forms of the fusion step's glue stages: the test reference of
:func:`skelfuse.fusion.pipeline.select_candidates` and :func:`~skelfuse.fusion.pipeline.predicted_positions` (the
live path runs :mod:`skelfuse.fusion.kernels.merge` and :mod:`skelfuse.fusion.kernels.filters` and never imports
this module).
"""

from __future__ import annotations

import numpy as np

from skelfuse.fusion.pipeline import FusionState

_ONES3 = np.ones(3)


def select_candidates(
    candidates: np.ndarray, confidence: np.ndarray, min_confidence: int | None
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`skelfuse.fusion.pipeline.select_candidates` in numpy: every candidate at once."""
    positions = np.asarray(candidates, dtype=np.float64)
    # The sum of the three coordinates is finite exactly when all three are (inf - inf is NaN); mm-sized
    # values cannot overflow.
    valid = np.isfinite(positions @ _ONES3)
    if min_confidence is not None:
        valid &= confidence >= min_confidence
    conf = confidence * valid
    return np.where(valid[..., None], positions, np.nan), conf if conf.dtype == np.uint8 else conf.astype(np.uint8)


def predicted_positions(state: FusionState, dt_s: float) -> np.ndarray:
    """:func:`skelfuse.fusion.pipeline.predicted_positions` in numpy."""
    x = state.x
    return np.where((state.coast >= 0)[..., None], x[:, :, 0] + dt_s * x[:, :, 1], state.previous)
