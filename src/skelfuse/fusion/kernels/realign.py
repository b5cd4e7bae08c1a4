"""The left/right votes of the temporal realignment (:func:`skelfuse.fusion.realign.pair_votes`) as a compiled loop.

Per body and view, per left/right pair: the swap cost minus the keep cost against the anchor pair, as a vote in
[-1, 1] (divided by twice the anchor's width), summed over the pairs that can decide. The same arithmetic as the
numpy reference (:mod:`skelfuse.fusion.reference.realign`) up to the order of its sums of three and of the pairs
(last bits); the rule is documented in :mod:`skelfuse.fusion.realign`.
"""

from __future__ import annotations

import numba
import numpy as np

from skelfuse.fusion.kernels.signatures import FLOAT, INT, array


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _distance(a: np.ndarray, i: int, b: np.ndarray, k: int) -> float:
    """|a[i] - b[k]| of two (n, 3) point rows, mm."""
    dx = a[i, 0] - b[k, 0]
    dy = a[i, 1] - b[k, 1]
    dz = a[i, 2] - b[k, 2]
    return np.sqrt(dx * dx + dy * dy + dz * dz)


_SIGNATURE = (array(FLOAT, 4), array(FLOAT, 3), array(INT, 1), array(INT, 1))


@numba.njit(_SIGNATURE, cache=True, nogil=True, error_model="numpy")
def pair_votes(
    positions: np.ndarray, anchor: np.ndarray, left: np.ndarray, right: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each view's margin for keeping its labels, whether any pair decided, and the views that see a pair.

    Parameters
    ----------
    positions : (B, S, J, 3) float64 mm, NaN = missing; anchor : (B, 2P, 3) float64 mm, the anchor's left joints
    then its right joints; left, right : (P,) int64 joint indices of the pairs.

    Returns
    -------
    margin (B, S) float64, decided (B, S) bool, n_views (B,) int64.
    """
    B, S = positions.shape[0], positions.shape[1]
    P = left.shape[0]
    margin = np.zeros((B, S))
    decided = np.zeros((B, S), dtype=np.bool_)
    n_views = np.zeros(B, dtype=np.int64)
    for b in range(B):
        for s in range(S):
            view = positions[b, s]
            sees_pair = False
            for p in range(P):
                lj, rj = left[p], right[p]
                if view[lj, 0] + view[rj, 0] == view[lj, 0] + view[rj, 0]:  # both x present (NaN: not equal)
                    sees_pair = True
                keep_left = _distance(view, lj, anchor[b], p)
                keep_right = _distance(view, rj, anchor[b], P + p)
                swap_left = _distance(view, rj, anchor[b], p)
                swap_right = _distance(view, lj, anchor[b], P + p)
                width = _distance(anchor[b], p, anchor[b], P + p)
                vote = (-keep_left - keep_right + swap_left + swap_right) / max(2.0 * width, 1.0)
                if vote == vote:  # both of the view's joints and both anchors exist
                    margin[b, s] += vote
                    decided[b, s] = True
            if sees_pair:
                n_views[b] += 1
    return margin, decided, n_views


def warm_up() -> None:
    """Compile (or load) :func:`pair_votes` for its one signature."""
    pairs = np.array([0], dtype=np.int64)
    pair_votes(np.zeros((1, 1, 2, 3)), np.zeros((1, 2, 3)), pairs, pairs + 1)
