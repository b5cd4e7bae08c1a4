"""The numpy form of the association's cost matrix and track assignment, with scipy's Hungarian solver: the test
reference of :func:`skelfuse.fusion.association.assign_to_tracks` (the live path runs
:mod:`skelfuse.fusion.kernels.association` and never imports this module). The rules are documented in
:mod:`skelfuse.fusion.association`.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from skelfuse.fusion.association import N_DESCRIPTOR, descriptor_distance, nanmedian_axis, torso_descriptor

BIG_COST = 1e12  # stands for "no cost" in the assignment matrices; such pairs are rejected afterwards


def assign_to_tracks(
    body_desc: np.ndarray,
    usable: np.ndarray,
    tracks: np.ndarray,
    confirmed: np.ndarray,
    gate_mm: np.ndarray,
    min_common_points: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`skelfuse.fusion.association.assign_to_tracks` in numpy and scipy."""
    S, B = usable.shape
    K = tracks.shape[0]
    gate = np.asarray(gate_mm, dtype=np.float64)
    confirmed = np.asarray(confirmed, dtype=bool)
    cost = descriptor_distance(body_desc[:, :, None], tracks[None, None], min_common_points)  # (S, B, K)
    allowed = usable[:, :, None] & (cost <= gate[None, None, :])
    person = np.full((S, B), -1, dtype=np.int64)
    assigned_cost = np.full((S, B), np.nan)
    stages = (confirmed,) if confirmed.all() else (confirmed, ~confirmed)
    for stage in stages:  # cascade; Python loop over sensors only (a handful)
        cols = np.nonzero(stage)[0]
        if cols.size == 0:
            continue
        sub = allowed[:, :, cols] if cols.size < K else allowed
        sub = sub & (person < 0)[:, :, None]  # (S, B, len(cols)): the stage's gated pairs of free bodies
        # Fast path, exactly the Hungarian result: in a sensor where every body has at most one gated
        # track and every track at most one gated body, any optimal assignment holds every gated pair
        # (leaving one out costs BIG_COST more), and only the gated pairs are kept.
        simple = (sub.sum(axis=2) <= 1).all(axis=1) & (sub.sum(axis=1) <= 1).all(axis=1)
        s_idx, b_idx, c_idx = np.nonzero(sub & simple[:, None, None])
        if s_idx.size:
            k_idx = cols[c_idx]
            person[s_idx, b_idx] = k_idx
            assigned_cost[s_idx, b_idx] = cost[s_idx, b_idx, k_idx]
        for s in np.nonzero(~simple)[0]:
            rows = np.nonzero(usable[s] & (person[s] < 0))[0]
            ok = allowed[s][rows[:, None], cols]
            matrix = np.where(ok, cost[s][rows[:, None], cols], BIG_COST)
            r, c = linear_sum_assignment(matrix)
            keep = ok[r, c]
            person[s, rows[r[keep]]] = cols[c[keep]]
            assigned_cost[s, rows[r[keep]]] = matrix[r[keep], c[keep]]
    return person, assigned_cost, cost


def person_descriptors(body_desc: np.ndarray, person: np.ndarray, n_persons: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`skelfuse.fusion.association.person_descriptors` in numpy."""
    S = person.shape[0]
    person_desc = np.full((n_persons, S, N_DESCRIPTOR, 3), np.nan)
    s_idx, b_idx = np.nonzero(person >= 0)
    person_desc[person[s_idx, b_idx], s_idx] = body_desc[s_idx, b_idx]
    seen = np.zeros((n_persons, S), dtype=bool)
    seen[person[s_idx, b_idx], s_idx] = True
    return nanmedian_axis(person_desc, axis=1), seen.sum(axis=1).astype(np.int64)


def match_tracks(
    positions: np.ndarray,
    valid: np.ndarray,
    tracks: np.ndarray,
    confirmed: np.ndarray,
    gate_mm: np.ndarray,
    min_common_points: int,
    duplicate_mm: float | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`skelfuse.fusion.association.match_tracks` in numpy and scipy."""
    S, B = valid.shape
    K = tracks.shape[0]
    body_desc = torso_descriptor(positions)  # (S, B, D, 3)
    usable = valid & (np.isfinite(body_desc).all(axis=-1).sum(axis=-1) >= min_common_points)
    person, assigned_cost, cost = assign_to_tracks(body_desc, usable, tracks, confirmed, gate_mm, min_common_points)
    # Duplicates: a leftover close to a track that already holds a body of the same sensor.
    leftover = usable & (person < 0)
    duplicates = np.zeros((S, B), dtype=bool)
    if duplicate_mm is not None and K and leftover.any():
        taken = np.zeros((S, K), dtype=bool)
        s_idx, b_idx = np.nonzero(person >= 0)
        taken[s_idx, person[s_idx, b_idx]] = True
        duplicates = leftover & ((cost <= float(duplicate_mm)) & taken[:, None, :]).any(axis=2)
        leftover &= ~duplicates
    return body_desc, usable, person, assigned_cost, cost, duplicates, leftover
