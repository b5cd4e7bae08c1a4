"""The numpy form of the temporal realignment's votes: the test reference of
:func:`skelfuse.fusion.realign.pair_votes` (the live path runs :mod:`skelfuse.fusion.kernels.realign` and never
imports this module). The rule is documented in :mod:`skelfuse.fusion.realign`.
"""

from __future__ import annotations

import numpy as np

from skelfuse.schema.skeleton import PAPER_REALIGN_PAIRS

_N_PAIRS = len(PAPER_REALIGN_PAIRS)
_LEFT, _RIGHT = PAPER_REALIGN_PAIRS[:, 0], PAPER_REALIGN_PAIRS[:, 1]
_PAIR_BOTH = np.concatenate([_LEFT, _RIGHT, _RIGHT, _LEFT])  # (4P,) labels as given, then swapped
_ONES3 = np.ones(3)  # x @ ones sums the last axis of 3 faster than x.sum(-1)
_ONES_P = np.ones(_N_PAIRS)
# Weights over the four cost blocks (keep left, keep right, swap left, swap right): swap - keep per pair.
_SWAP_MINUS_KEEP = np.array([-1.0, -1.0, 1.0, 1.0])


def pair_votes(positions: np.ndarray, anchor: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`skelfuse.fusion.realign.pair_votes` in numpy: every view and pair at once."""
    both = positions[:, :, _PAIR_BOTH]  # (B, S, 4P, 3): left, right, then the swapped labels
    n_views = (~np.isnan(both[:, :, :_N_PAIRS, 0] + both[:, :, _N_PAIRS : 2 * _N_PAIRS, 0])).any(axis=2).sum(axis=1)
    diff = both - np.concatenate([anchor, anchor], axis=1)[:, None]
    cost = np.sqrt((diff * diff) @ _ONES3)  # (B, S, 4P): keep costs, then swap costs
    pair_delta = _SWAP_MINUS_KEEP @ cost.reshape(*cost.shape[:2], 4, _N_PAIRS)  # (B, S, P) swap - keep
    width = anchor[:, :_N_PAIRS] - anchor[:, _N_PAIRS:]  # (B, P, 3): anchor left - right
    width = np.sqrt((width * width) @ _ONES3)
    pair_delta = pair_delta / np.maximum(2.0 * width, 1.0)[:, None]  # each pair's vote in [-1, 1]
    # A pair decides only where both of the view's joints and both anchors exist: NaN propagates.
    decidable = pair_delta == pair_delta
    margin = np.where(decidable, pair_delta, 0.0) @ _ONES_P  # (B, S)
    return margin, decidable.any(axis=2), n_views.astype(np.int64)
