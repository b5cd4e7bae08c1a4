"""The numpy form of the plausibility stage's view checks: the test reference of
:func:`skelfuse.fusion.plausibility.check_views` (the live path runs :mod:`skelfuse.fusion.kernels.plausibility`
and never imports this module). The rules are documented in :mod:`skelfuse.fusion.plausibility`.
"""

from __future__ import annotations

import math

import numpy as np

from skelfuse.fusion.plausibility import (
    BONES,
    PLAUSIBLE,
    TELEPORT,
    UPSIDE_DOWN,
    PlausibilityParams,
    bone_lengths,
    median_of_finite,
    torso_offset,
)
from skelfuse.schema.skeleton import J


def _up(positions: np.ndarray) -> np.ndarray:
    """(..., J, 3) -> (..., 3) unit pelvis-to-neck direction (NaN where either joint is missing)."""
    up = positions[..., J["NECK"], :] - positions[..., J["PELVIS"], :]
    norm = np.sqrt(np.sum(up * up, axis=-1, keepdims=True))
    with np.errstate(invalid="ignore", divide="ignore"):
        return up / norm


def check_views(
    candidates: np.ndarray,
    predicted: np.ndarray,
    learned_bones: np.ndarray,
    bones_ready: np.ndarray,
    p: PlausibilityParams,
) -> np.ndarray:
    """The reason each view fails this frame (0 = passes or no evidence), no hysteresis: numpy over all views.

    Parameters
    ----------
    candidates : (B, S, J, 3) mm, NaN = missing.
    predicted : (B, J, 3) mm, the track's prediction (NaN = no track for that joint).
    learned_bones : (B, NB) mm; bones_ready : (B,) bool, the lengths are learned enough to judge.
    p : PlausibilityParams

    Returns
    -------
    (B, S) uint8 reason (UPSIDE_DOWN before BONES before TELEPORT where several hold).
    """
    mean_offset = torso_offset(candidates, predicted)
    teleport = np.sum(mean_offset * mean_offset, axis=-1) > p.gate_mm**2  # NaN compares False

    cos_up = np.sum(_up(candidates) * _up(predicted)[:, None], axis=-1)  # NaN where unknown: compares False
    upside_down = cos_up < p.up_cos

    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = bone_lengths(candidates) / learned_bones[:, None]  # (B, S, NB)
    known = np.isfinite(ratio)
    enough = known.sum(axis=-1) >= 3
    median = median_of_finite(ratio, known)
    wrong_size = (
        enough & bones_ready[:, None] & (np.abs(np.log(np.where(enough, median, 1.0))) > math.log1p(p.bone_ratio))
    )

    reason = np.where(teleport, TELEPORT, PLAUSIBLE)
    reason = np.where(wrong_size, BONES, reason)
    return np.where(upside_down, UPSIDE_DOWN, reason).astype(np.uint8)
