"""Per-joint merge of the sensors' candidates into one position (Lee et al. 2022, section 2.2.2).

``merge_dbscan`` is the paper's DBSCAN merge with Nc = 1 (``min_samples=1``). With Nc = 1 every point is a
core point, so the clusters are exactly the connected components of the graph "distance <= eps" (inclusive,
like scikit-learn's ``eps``). The work runs in a compiled kernel (:mod:`skelfuse.fusion.kernels.merge`: per
joint, label the components, score them, take the best); its numpy form, which closes each joint's adjacency
matrix by repeated boolean squaring, is the test reference (:mod:`skelfuse.fusion.reference.merge`).

Candidates of one joint, in this order: one per sensor (S), then the reference position (trick 1, if
``reference_weight`` is set), then the previous frame's merged position (trick 2, if ``previous_weight`` is
set). Missing candidates (NaN) belong to no cluster.

Choices the paper leaves open, and what this module does:

Weights
    A sensor candidate weighs 1, the reference ``reference_weight`` (default 2), the previous position
    ``previous_weight`` (default 1). Weights count only in the cluster score (the summed weight of the
    cluster's members); they never change the clustering. The reference and previous points do take part
    in the clustering as points, so either can bridge two groups of sensors that are each within eps of
    it (exactly what DBSCAN on the full candidate set does).
Winner
    Only clusters that hold at least one sensor candidate can win: a cluster of the reference and/or the
    previous position alone has nothing to average, and its position is already represented elsewhere.
    Among those, the cluster with the largest score wins; ties are broken, in order, by
    (1) containing the previous position (temporal continuity), (2) more sensor candidates,
    (3) containing the reference, (4) larger summed tracker confidence of its sensor candidates,
    (5) smallest centroid x, then y, then z (rounded to 1e-6 mm). Every key depends only on the cluster's
    content, so the result does not depend on the order of the sensors; only clusters identical in every
    key (which would need identical centroids) fall back to the lowest sensor index.
Output
    The merged position is the centroid of the winning cluster's *sensor* candidates; the reference and
    the previous position vote but are not averaged (paper). ``n_agree`` is the number of those sensor
    candidates, ``confidence`` the highest tracker confidence among them, ``members`` which sensors they
    came from. A joint no sensor reports comes out NaN with ``n_agree`` 0 and confidence 0, whatever the
    reference or previous position say.

``merge_average`` is the paper's A1/A2 merge: the plain mean of the valid sensor candidates.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from skelfuse.fusion import kernels


@dataclass(frozen=True)
class MergeResult:
    """Output of a merge stage.

    Attributes
    ----------
    positions : (B, J, 3) float64, mm. NaN where no sensor reports the joint.
    n_agree : (B, J) int16, sensor candidates averaged into the joint.
    confidence : (B, J) uint8, highest tracker confidence among those candidates (0 if none).
    members : (B, J, S) bool, which sensors were averaged into the joint.
    """

    positions: np.ndarray
    n_agree: np.ndarray
    confidence: np.ndarray
    members: np.ndarray


@lru_cache(maxsize=64)
def rank_table(n_sensors: int, reference_weight: float | None, previous_weight: float | None) -> np.ndarray:
    """Rank of each (n_sensors, has_ref, has_prev) code under (score, has_prev, n_sensors, has_ref).

    The code of a cluster is ``n + (S+1) * has_ref + 2 (S+1) * has_prev``; the score is computed from the
    same integers in one fixed order, so two clusters with equal content get bit-identical scores.
    """
    span = n_sensors + 1
    w_ref = 0.0 if reference_weight is None else float(reference_weight)
    w_prev = 0.0 if previous_weight is None else float(previous_weight)
    codes = []
    for has_prev in (0, 1):
        for has_ref in (0, 1):
            for n in range(span):
                score = float(n) + has_ref * w_ref + has_prev * w_prev
                codes.append(((score, has_prev, n, has_ref), n + span * has_ref + 2 * span * has_prev))
    order = sorted(codes)
    table = np.empty(4 * span, dtype=np.int64)
    for rank, (_, code) in enumerate(order):
        table[code] = rank
    table[0] = -1  # a sensor candidate's cluster holds at least itself: code 0 means a missing candidate
    table.setflags(write=False)
    return table


def merge_dbscan(
    positions: np.ndarray,
    confidence: np.ndarray,
    reference: np.ndarray | None = None,
    previous: np.ndarray | None = None,
    eps_mm: float = 100.0,
    reference_weight: float | None = 2.0,
    previous_weight: float | None = 1.0,
) -> MergeResult:
    """DBSCAN (Nc = 1) merge of every joint; see the module docstring for weights, ties and empty cases.

    Parameters
    ----------
    positions : (B, S, J, 3) float, mm, world frame; NaN = missing candidate.
    confidence : (B, S, J) int, tracker confidence of each candidate.
    reference : (B, J, 3) float, mm, or None
        Trick-1 candidate per joint (see :func:`skelfuse.fusion.realign.reference_positions`). Ignored
        when ``reference_weight`` is None.
    previous : (B, J, 3) float, mm, or None
        Trick-2 candidate per joint (last frame's merged position). Ignored when ``previous_weight`` is None.
    eps_mm : float
        Searching radius, mm.
    reference_weight, previous_weight : float or None
        Weights in the cluster score; None leaves that candidate out.

    Returns
    -------
    MergeResult
    """
    positions = np.ascontiguousarray(positions, dtype=np.float64)
    if positions.ndim != 4 or positions.shape[3] != 3:
        raise ValueError(f"positions must have shape (B, S, J, 3), got {positions.shape}")
    B, S, J, _ = positions.shape
    confidence = np.ascontiguousarray(confidence, dtype=np.int64)
    if confidence.shape != (B, S, J):
        raise ValueError(f"confidence must have shape {(B, S, J)} (B, S, J), got {confidence.shape}")
    use_ref = reference_weight is not None and reference is not None
    use_prev = previous_weight is not None and previous is not None
    rank = rank_table(S, reference_weight if use_ref else None, previous_weight if use_prev else None)
    merged, n_agree, best_conf, members = kernels.load().merge.merge_dbscan(
        positions,
        confidence,
        _joint_points("reference", reference, B, J) if use_ref else _NO_POINTS,
        _joint_points("previous", previous, B, J) if use_prev else _NO_POINTS,
        use_ref,
        use_prev,
        float(eps_mm),
        rank,
    )
    return MergeResult(positions=merged, n_agree=n_agree, confidence=best_conf, members=members)


_NO_POINTS = np.zeros((0, 0, 3))  # the kernel's placeholder for a candidate left out (one signature for all calls)


def _joint_points(name: str, points: np.ndarray | None, n_bodies: int, n_joints: int) -> np.ndarray:
    """One candidate per joint as the kernel reads it: (B, J, 3) float64, C order (the shape checked: the
    kernel does not check its indices)."""
    out = np.ascontiguousarray(points, dtype=np.float64)
    if out.shape != (n_bodies, n_joints, 3):
        raise ValueError(f"{name} must have shape {(n_bodies, n_joints, 3)} (B, J, 3), got {out.shape}")
    return out


def merge_average(positions: np.ndarray, confidence: np.ndarray) -> MergeResult:
    """Plain mean of the valid sensor candidates of each joint (the paper's A1/A2).

    Parameters
    ----------
    positions : (B, S, J, 3) float, mm; NaN = missing.
    confidence : (B, S, J) int.

    Returns
    -------
    MergeResult; a joint no sensor reports is NaN with n_agree 0.
    """
    B, _, J, _ = positions.shape
    valid = ~np.isnan(positions).any(axis=-1)  # (B, S, J)
    n_agree = np.count_nonzero(valid, axis=1)  # (B, J)
    total = np.where(valid[..., None], positions, 0.0).sum(axis=1)  # (B, J, 3)
    merged = np.full((B, J, 3), np.nan)
    np.divide(total, n_agree[..., None], out=merged, where=n_agree[..., None] > 0)
    best_conf = np.where(valid, confidence, 0).max(axis=1)
    return MergeResult(
        positions=merged,
        n_agree=n_agree.astype(np.int16),
        confidence=best_conf.astype(np.uint8),
        members=np.transpose(valid, (0, 2, 1)),
    )
