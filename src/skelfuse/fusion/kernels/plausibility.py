"""The plausibility stage's view checks (:func:`skelfuse.fusion.plausibility.check_views`) as a compiled loop.

Per body and view: the mean offset of the torso joints from the prediction (a teleport), the pelvis-to-neck
direction against the prediction's (upside down), the median ratio of the bone lengths to the learned ones
(another body). The same sums in the same order as the numpy reference
(:mod:`skelfuse.fusion.reference.plausibility`); the rules are documented in :mod:`skelfuse.fusion.plausibility`.
"""

from __future__ import annotations

import numba
import numpy as np

from skelfuse.fusion.kernels.signatures import BOOL, FLOAT, INT, array

PLAUSIBLE, TELEPORT, UPSIDE_DOWN, BONES = 0, 1, 2, 3  # as skelfuse.fusion.plausibility's reasons


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _teleported(view: np.ndarray, predicted: np.ndarray, torso: np.ndarray, gate_sq: float) -> bool:
    """The mean offset of the torso joints both have (two or more) is longer than the gate."""
    sx = sy = sz = 0.0
    n_common = 0
    for joint in torso:
        dx = view[joint, 0] - predicted[joint, 0]
        dy = view[joint, 1] - predicted[joint, 1]
        dz = view[joint, 2] - predicted[joint, 2]
        if np.isfinite(dx) and np.isfinite(dy) and np.isfinite(dz):
            sx += dx
            sy += dy
            sz += dz
            n_common += 1
    if n_common < 2:
        return False
    mx, my, mz = sx / n_common, sy / n_common, sz / n_common
    return mx * mx + my * my + mz * mz > gate_sq


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _up(body: np.ndarray, neck: int, pelvis: int) -> tuple[float, float, float]:
    """Unit pelvis-to-neck direction (NaN where either joint is missing or they coincide)."""
    ux = body[neck, 0] - body[pelvis, 0]
    uy = body[neck, 1] - body[pelvis, 1]
    uz = body[neck, 2] - body[pelvis, 2]
    norm = np.sqrt(ux * ux + uy * uy + uz * uz)
    return ux / norm, uy / norm, uz / norm


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _median_bone_ratio(view: np.ndarray, learned: np.ndarray, bones: np.ndarray, ratios: np.ndarray) -> float:
    """Median of the finite ratios view bone length / learned length; NaN when fewer than three are known."""
    n = 0
    for k in range(bones.shape[0]):
        a, b = bones[k, 0], bones[k, 1]
        dx = view[b, 0] - view[a, 0]
        dy = view[b, 1] - view[a, 1]
        dz = view[b, 2] - view[a, 2]
        ratio = np.sqrt(dx * dx + dy * dy + dz * dz) / learned[k]
        if np.isfinite(ratio):
            i = n  # insertion sort: a dozen bones
            while i > 0 and ratios[i - 1] > ratio:
                ratios[i] = ratios[i - 1]
                i -= 1
            ratios[i] = ratio
            n += 1
    if n < 3:
        return np.nan
    return 0.5 * (ratios[(n - 1) // 2] + ratios[n // 2])


_SIGNATURE = (
    array(FLOAT, 4),  # candidates
    array(FLOAT, 3),  # predicted
    array(FLOAT, 2),  # learned_bones
    array(BOOL, 1),  # bones_ready
    array(INT, 1),  # torso
    array(INT, 2),  # bones
    INT,  # neck
    INT,  # pelvis
    FLOAT,  # gate_mm
    FLOAT,  # up_cos
    FLOAT,  # log_bone_ratio
)


@numba.njit(_SIGNATURE, cache=True, nogil=True, error_model="numpy")
def check_views(
    candidates: np.ndarray,
    predicted: np.ndarray,
    learned_bones: np.ndarray,
    bones_ready: np.ndarray,
    torso: np.ndarray,
    bones: np.ndarray,
    neck: int,
    pelvis: int,
    gate_mm: float,
    up_cos: float,
    log_bone_ratio: float,
) -> np.ndarray:
    """(B, S) uint8 reason each view fails (UPSIDE_DOWN before BONES before TELEPORT; 0 = passes or no evidence).

    Parameters
    ----------
    candidates : (B, S, J, 3) float64 mm; predicted : (B, J, 3) float64 mm; learned_bones : (B, NB) float64 mm;
    bones_ready : (B,) bool; torso : (T,) int64 joint indices; bones : (NB, 2) int64 joint pairs (parent, child);
    neck, pelvis : joint indices; gate_mm, up_cos : thresholds; log_bone_ratio : log1p(bone_ratio).
    """
    B, S = candidates.shape[0], candidates.shape[1]
    reason = np.zeros((B, S), dtype=np.uint8)
    ratios = np.empty(bones.shape[0])
    gate_sq = gate_mm * gate_mm
    for b in range(B):
        px, py, pz = _up(predicted[b], neck, pelvis)
        for s in range(S):
            view = candidates[b, s]
            vx, vy, vz = _up(view, neck, pelvis)
            if vx * px + vy * py + vz * pz < up_cos:  # NaN compares False
                reason[b, s] = UPSIDE_DOWN
                continue
            if bones_ready[b]:
                median = _median_bone_ratio(view, learned_bones[b], bones, ratios)
                if np.abs(np.log(median)) > log_bone_ratio:  # NaN (too few bones) compares False
                    reason[b, s] = BONES
                    continue
            if _teleported(view, predicted[b], torso, gate_sq):
                reason[b, s] = TELEPORT
    return reason


def warm_up() -> None:
    """Compile (or load) :func:`check_views` for its one signature."""
    candidates = np.zeros((1, 1, 4, 3))
    bones = np.array([[0, 1], [1, 2], [2, 3]], dtype=np.int64)
    check_views(
        candidates,
        candidates[:, 0],
        np.ones((1, 3)),
        np.ones(1, dtype=np.bool_),
        np.arange(4),
        bones,
        3,
        0,
        250.0,
        0.0,
        0.2,
    )
