"""The left/right mirror primitives that every mirror rule shares.

A body tracker that sees a person from behind fits the body the wrong way round: its left and right labels
are exchanged (a *mirrored* view). Several rules decide about mirroring, on purpose differently:

- ``fusion.realign.realign_paper``: the paper's per-pair rule against the views' reference;
- ``fusion.realign.realign_body`` / ``realign_temporal``: one decision per view, from all pairs;
- ``calibration.skeleton``: leave out frames whose two views disagree about the sides;
- ``eval.metrics.swap_counts`` / ``eval.real.mirrored_frames``: measure how often an output is mirrored.

They all rest on the pieces here: the cost of keeping against swapping a pair's labels, the torso's lateral
axis, and exchanging the labels of a whole skeleton.
"""

from __future__ import annotations

import numpy as np

from skelfuse.schema.skeleton import MIRROR, J


def pair_costs(
    left: np.ndarray, right: np.ndarray, ref_left: np.ndarray, ref_right: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Distances of a left/right pair to a reference pair, labels kept and labels swapped.

    ``keep = |L - refL| + |R - refR|`` and ``swap = |L - refR| + |R - refL|`` (mm), over the last axis of
    (..., 3) arrays that broadcast together; NaN where any of the four positions is missing. The pair is
    mirrored relative to the reference when ``swap < keep``.
    """
    keep = np.linalg.norm(left - ref_left, axis=-1) + np.linalg.norm(right - ref_right, axis=-1)
    swap = np.linalg.norm(left - ref_right, axis=-1) + np.linalg.norm(right - ref_left, axis=-1)
    return keep, swap


def mirror_views(positions: np.ndarray, confidence: np.ndarray, mirrored: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exchange every left/right label (:data:`~skelfuse.schema.skeleton.MIRROR`) of the mirrored views.

    positions (..., J, 3), confidence (..., J), mirrored (...) bool; returns new arrays.
    """
    out_positions = np.where(mirrored[..., None, None], positions[..., MIRROR, :], positions)
    out_confidence = np.where(mirrored[..., None], confidence[..., MIRROR], confidence)
    return out_positions, out_confidence


def lateral_axes(positions: np.ndarray) -> np.ndarray:
    """Unit right-to-left torso axis, (left - right shoulder) + (left - right hip): (..., J, 3) -> (..., 3).

    Two skeletons whose lateral axes point against each other (negative dot product) face opposite ways
    round: one of them is mirrored. NaN where a shoulder or hip is missing or the axis has zero length.
    """
    positions = np.asarray(positions, dtype=np.float64)
    axis = (
        positions[..., J["SHOULDER_LEFT"], :]
        - positions[..., J["SHOULDER_RIGHT"], :]
        + positions[..., J["HIP_LEFT"], :]
        - positions[..., J["HIP_RIGHT"], :]
    )
    length = np.sqrt(np.sum(axis**2, axis=-1, keepdims=True))
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = axis / length
    unit[~np.isfinite(unit).all(axis=-1)] = np.nan
    return unit
