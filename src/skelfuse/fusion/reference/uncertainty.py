"""The numpy form of the position uncertainty stage: the test reference of
:func:`skelfuse.fusion.uncertainty.position_uncertainty` (the live path runs
:mod:`skelfuse.fusion.kernels.uncertainty` and never imports this module): the stage's numpy parts composed.
"""

from __future__ import annotations

import numpy as np

from skelfuse.fusion.presets import FusionParams
from skelfuse.fusion.uncertainty import measurement_variance, uncertainty_step, view_agreement


def position_uncertainty(
    candidates: np.ndarray,
    merged: np.ndarray,
    n_agree: np.ndarray,
    fused: np.ndarray,
    previous_cov: np.ndarray,
    coast_before: np.ndarray,
    coast_after: np.ndarray,
    torso: np.ndarray,
    params: FusionParams,
    dt_s: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`skelfuse.fusion.uncertainty.position_uncertainty` in numpy."""
    B, J = fused.shape[:2]
    agreement = view_agreement(candidates, merged, torso)
    members = np.zeros((B, J, candidates.shape[1]), dtype=bool)  # not read: every present view counts
    r = measurement_variance(candidates, members, merged, n_agree, params.cv_meas_sigma_mm)
    std, cov = uncertainty_step(
        previous_cov.reshape(B * J, 3), coast_before, coast_after, r.reshape(B * J), params, dt_s
    )
    std = np.where(np.isfinite(fused).all(axis=-1), std.reshape(B, J), np.nan)
    return std, cov.reshape(B, J, 3), agreement
