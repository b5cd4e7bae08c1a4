"""Per-frame association: which bodies of which sensors are the same person (pure numpy and a compiled kernel).

Every sensor's body tracker reports its own list of bodies, in its own order, with its own body ids, and
the SDK changes a body's id when the view flips left/right. The pipeline (:func:`skelfuse.fusion.pipeline.fuse`)
needs one row per *person*, holding what every sensor saw of that person. This module builds those rows
from geometry alone, in the world frame; body ids are ignored on purpose (they change on flips and on
re-acquisition, so they carry no identity a tracker could rely on).

Cycle of :func:`associate`:

1. Descriptor per body: the mirror-invariant torso descriptor (:data:`DESCRIPTOR_NAMES`: pelvis, spine
   navel, spine chest, neck, head and the midpoints of the shoulder and hip pairs). A left/right flip
   swaps the shoulders and hips, but not their midpoints, so a mirrored view keeps its descriptor.
2. Cost between a body and a track's predicted descriptor: the mean distance (mm) over the descriptor
   points both have (at least ``min_common_points``), else no cost (never matched).
3. Per sensor, Hungarian assignment (:func:`skelfuse.fusion.kernels.association.linear_sum_assignment`, scipy's
   method and tie-breaking) of the sensor's bodies to
   the tracks, pairs costlier than the gate rejected. One sensor's bodies are distinct people, so each
   track takes at most one body per sensor. Cascade: confirmed tracks first, then the tentative ones
   with the bodies left over (an established person is never out-bid by a track being born).
4. Leftover bodies that lie within ``duplicate_mm`` of a track that already took a body of the same
   sensor are dropped as duplicates (the tracker split one person into two skeletons).
4b. Re-acquisition: a leftover whose pelvis lies within ``duplicate_mm`` of the predicted pelvis of a confirmed
   track that holds no body of the same sensor is that person re-acquired (a tracker that lost the person
   and found them again under a new body id, upside down or off for a few frames) and goes to that track,
   closest first, one body per sensor and track; the fusion's plausibility stage judges whether it is used.
   Two people's pelvises are never that close, so no bystander is taken.
5. Remaining leftovers are clustered across sensors (complete linkage under the gate, at most one body
   per sensor per cluster, closest pairs first); each cluster is a candidate new person. A body seen by
   one sensor only forms its own cluster: a bystander is never merged into the subject.

Ambiguity policies
------------------
- Two bodies of one sensor within the gate of one track: the Hungarian step gives the track the one that
  minimises the sensor's total cost (the closer one when no other track competes); the other is a
  leftover: a duplicate if within ``duplicate_mm`` of that track, otherwise a candidate new person.
- Exact cost ties: the Hungarian solver is deterministic; the lower track index wins (tracks are
  passed oldest first, so the older track wins) and, within a sensor, the lower body index.
- Clustering ties: pairs are merged in order of distance, then sensor, then body index.
- A body with fewer than ``min_common_points`` finite descriptor points is ignored (never assigned).

Shapes: S sensors, B (= Bmax) body slots per sensor, NaN-padded; J = 32 joints; D = 7 descriptor points;
K tracks. Units: mm, world frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skelfuse.fusion import kernels
from skelfuse.schema.skeleton import N_JOINTS, J

DESCRIPTOR_NAMES: tuple[str, ...] = ("PELVIS", "SPINE_NAVEL", "SPINE_CHEST", "NECK", "HEAD", "MID_SHOULDER", "MID_HIP")
"""The mirror-invariant torso points, in descriptor order."""
N_DESCRIPTOR = len(DESCRIPTOR_NAMES)
_CENTRAL = np.array([J["PELVIS"], J["SPINE_NAVEL"], J["SPINE_CHEST"], J["NECK"], J["HEAD"]], dtype=np.int64)
_PAIRS = np.array([[J["SHOULDER_LEFT"], J["SHOULDER_RIGHT"]], [J["HIP_LEFT"], J["HIP_RIGHT"]]], dtype=np.int64)
for _table in (_CENTRAL, _PAIRS):
    _table.setflags(write=False)

DEFAULT_GATE_MM = 450.0
DEFAULT_DUPLICATE_MM = 250.0
DEFAULT_MIN_COMMON_POINTS = 3


@dataclass(frozen=True)
class Association:
    """The persons of one frame.

    Attributes
    ----------
    person_of_body : (S, B) int64, person row of each body slot: ``0..K-1`` = the track of that index,
        ``K..K+n_new-1`` = a new cluster; -1 = not assigned (padding, invalid, duplicate).
    n_tracks : int, K.
    n_new : int, number of new clusters (candidate new persons).
    candidates : (K + n_new, S, J, 3) float64, mm, world: row p, column s = the body of sensor s assigned
        to person p; NaN where sensor s does not see p. Ready for :func:`skelfuse.fusion.pipeline.fuse`.
    confidence : (K + n_new, S, J) uint8, 0 where missing.
    descriptors : (K + n_new, D, 3) float64, per person the median over its sensors of the body
        descriptors (NaN where no sensor has that point).
    n_sensors_seen : (K + n_new,) int64, how many sensors see each person this frame.
    duplicates : (S, B) bool, leftovers dropped as duplicates of an assigned body.
    cost : (S, B) float64, the cost (mm) of each assigned body to its track; NaN otherwise.
    """

    person_of_body: np.ndarray
    n_tracks: int
    n_new: int
    candidates: np.ndarray
    confidence: np.ndarray
    descriptors: np.ndarray
    n_sensors_seen: np.ndarray
    duplicates: np.ndarray
    cost: np.ndarray

    @property
    def n_persons(self) -> int:
        return self.n_tracks + self.n_new


def torso_descriptor(positions: np.ndarray) -> np.ndarray:
    """Mirror-invariant torso points of skeletons.

    Parameters
    ----------
    positions : (..., 32, 3) mm; NaN = missing.

    Returns
    -------
    (..., D, 3) float64: pelvis, spine navel, spine chest, neck, head, mid-shoulder, mid-hip (NaN where a
    joint, or either joint of a pair, is missing). Swapping every left/right label leaves it unchanged.
    """
    positions = np.asarray(positions, dtype=np.float64)
    central = positions[..., _CENTRAL, :]
    mids = 0.5 * (positions[..., _PAIRS[:, 0], :] + positions[..., _PAIRS[:, 1], :])
    return np.concatenate([central, mids], axis=-2)


def descriptor_distance(a: np.ndarray, b: np.ndarray, min_common_points: int = DEFAULT_MIN_COMMON_POINTS) -> np.ndarray:
    """Mean distance (mm) over the descriptor points both ``a`` and ``b`` have (broadcasting).

    Parameters
    ----------
    a, b : (..., D, 3) descriptors, broadcastable.
    min_common_points : fewer common finite points than this gives ``inf``.

    Returns
    -------
    (...) float64 mean distance, ``inf`` where undecidable.
    """
    diff = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    # x^2 + y^2 + z^2 in this order, as the compiled assignment sums them: equal costs tie in both (NaN: missing).
    x, y, z = diff[..., 0], diff[..., 1], diff[..., 2]
    dist = np.sqrt(x * x + y * y + z * z)
    ok = np.isfinite(dist)
    count = ok.sum(axis=-1)
    total = np.where(ok, dist, 0.0).sum(axis=-1)
    return np.where(count >= max(int(min_common_points), 1), total / np.maximum(count, 1), np.inf)


def nanmedian_axis(values: np.ndarray, axis: int) -> np.ndarray:
    """Median over ``axis`` ignoring NaN (NaN where all are NaN), without numpy's all-NaN warnings."""
    values = np.asarray(values, dtype=np.float64)
    axis = axis % values.ndim
    # The axis last by a plain transpose (np.moveaxis costs a dozen Python-level calls on the hot path).
    values = values.transpose([i for i in range(values.ndim) if i != axis] + [axis])
    if values.shape[-1] == 0:
        return np.full(values.shape[:-1], np.nan)
    n = values.shape[-1]
    finite = np.isfinite(values)
    count = finite.sum(axis=-1)
    ordered = np.where(finite, values, np.inf)  # missing sort last
    ordered.sort(axis=-1)
    ordered = ordered.reshape(-1, n)
    lo = np.maximum((count - 1) // 2, 0).ravel()
    hi = np.minimum(count // 2, n - 1).ravel()
    lane = np.arange(ordered.shape[0])
    median = (0.5 * (ordered[lane, lo] + ordered[lane, hi])).reshape(count.shape)
    return np.where(count > 0, median, np.nan)


def gather_candidates(
    positions: np.ndarray, confidence: np.ndarray, person_of_body: np.ndarray, n_persons: int
) -> tuple[np.ndarray, np.ndarray]:
    """Scatter sensor bodies into person rows (vectorized).

    Parameters
    ----------
    positions : (S, B, J, 3) mm, world.
    confidence : (S, B, J) uint8.
    person_of_body : (S, B) int, row of each body or -1. At most one body per (row, sensor).
    n_persons : P.

    Returns
    -------
    candidates : (P, S, J, 3) float64, NaN where the sensor does not see the person.
    confidence : (P, S, J) uint8, 0 there.
    """
    S = positions.shape[0]
    candidates = np.full((n_persons, S, N_JOINTS, 3), np.nan)
    conf = np.zeros((n_persons, S, N_JOINTS), dtype=np.uint8)
    sensor_idx, body_idx = np.nonzero(person_of_body >= 0)
    rows = person_of_body[sensor_idx, body_idx]
    candidates[rows, sensor_idx] = positions[sensor_idx, body_idx]
    conf[rows, sensor_idx] = confidence[sensor_idx, body_idx]
    return candidates, conf


def associate(
    positions: np.ndarray,
    confidence: np.ndarray,
    valid: np.ndarray,
    track_descriptors: np.ndarray,
    track_confirmed: np.ndarray | None = None,
    *,
    gate_mm: float = DEFAULT_GATE_MM,
    track_gate_mm: np.ndarray | None = None,
    duplicate_mm: float | None = DEFAULT_DUPLICATE_MM,
    min_common_points: int = DEFAULT_MIN_COMMON_POINTS,
) -> Association:
    """Associate the bodies of all sensors with the tracks and with each other (see the module docstring).

    Parameters
    ----------
    positions : (S, B, J, 3) float, mm, world frame, NaN-padded.
    confidence : (S, B, J) uint8.
    valid : (S, B) bool, the body slot holds a body.
    track_descriptors : (K, D, 3) predicted descriptors of the tracks, oldest track first.
    track_confirmed : (K,) bool or None (all confirmed): the cascade matches confirmed tracks first.
    gate_mm : a body farther than this (mean descriptor distance) from a track is never assigned to it, and
        leftovers farther apart than this never form one new person.
    track_gate_mm : (K,) or None: per-track gate overriding ``gate_mm`` for the track assignment (e.g. wider
        for a coasting track).
    duplicate_mm : leftovers this close to a track that took a body of the same sensor are dropped;
        None: never drop.
    min_common_points : descriptor points two skeletons must share to be compared.

    Returns
    -------
    Association
    """
    positions = np.asarray(positions, dtype=np.float64)
    confidence = np.asarray(confidence)
    valid = np.asarray(valid, dtype=bool)
    if positions.ndim != 4 or positions.shape[2:] != (N_JOINTS, 3):
        raise ValueError(f"positions must have shape (S, B, {N_JOINTS}, 3), got {positions.shape}")
    if confidence.shape != positions.shape[:3] or valid.shape != positions.shape[:2]:
        raise ValueError(
            f"confidence {confidence.shape} and valid {valid.shape} must match positions {positions.shape[:3]}"
        )
    tracks = np.asarray(track_descriptors, dtype=np.float64).reshape(-1, N_DESCRIPTOR, 3)
    K = tracks.shape[0]
    confirmed = np.ones(K, dtype=bool) if track_confirmed is None else np.asarray(track_confirmed, dtype=bool)
    if confirmed.shape != (K,):
        raise ValueError(f"track_confirmed must have shape ({K},), got {confirmed.shape}")
    if track_gate_mm is None:
        gate = np.full(K, float(gate_mm))
    else:
        gate = np.asarray(track_gate_mm, dtype=np.float64)
        if gate.shape != (K,):
            gate = np.broadcast_to(gate, (K,))
    body_desc, _, person, assigned_cost, _, duplicates, leftover = match_tracks(
        positions, valid, tracks, confirmed, gate, min_common_points, duplicate_mm
    )
    if duplicate_mm is not None and K and leftover.any():
        _reacquire(body_desc, tracks, confirmed, leftover, person, float(duplicate_mm))

    n_new = _cluster_leftovers(body_desc, leftover, person, K, float(gate_mm), min_common_points)
    n_persons = K + n_new
    candidates, cand_conf = gather_candidates(positions, confidence, person, n_persons)
    descriptors, n_sensors_seen = person_descriptors(body_desc, person, n_persons)
    return Association(
        person_of_body=person,
        n_tracks=K,
        n_new=n_new,
        candidates=candidates,
        confidence=cand_conf,
        descriptors=descriptors,
        n_sensors_seen=n_sensors_seen,
        duplicates=duplicates,
        cost=assigned_cost,
    )


def _reacquire(
    body_desc: np.ndarray,
    tracks: np.ndarray,
    confirmed: np.ndarray,
    leftover: np.ndarray,
    person: np.ndarray,
    radius_mm: float,
) -> None:
    """Step 4b in place: leftovers whose pelvis is within ``radius_mm`` of a confirmed track's predicted pelvis,
    where that track holds no body of the sensor, join the track (closest first); ``leftover`` is updated."""
    S, _ = person.shape
    diff = body_desc[:, :, None, 0] - tracks[None, None, :, 0]  # (S, B, K): pelvis to predicted pelvis
    distance = np.sqrt(np.sum(diff * diff, axis=-1))
    taken = np.zeros((S, tracks.shape[0]), dtype=bool)
    s_idx, b_idx = np.nonzero(person >= 0)
    taken[s_idx, person[s_idx, b_idx]] = True
    near = leftover[:, :, None] & confirmed[None, None, :] & ~taken[:, None, :] & (distance <= radius_mm)
    for s, b, k in sorted(zip(*np.nonzero(near), strict=True), key=lambda sbk: distance[sbk]):
        if person[s, b] < 0 and not taken[s, k]:
            person[s, b] = k
            taken[s, k] = True
            leftover[s, b] = False


def _cluster_leftovers(
    body_desc: np.ndarray, leftover: np.ndarray, person: np.ndarray, first_row: int, gate_mm: float, min_common: int
) -> int:
    """Complete-linkage clustering of the leftover bodies across sensors; writes rows into ``person``.

    At most one body per sensor per cluster; two clusters merge only if every cross pair is within the
    gate; candidate pairs are taken closest first (ties: sensor, then body index). Returns the number of
    clusters.
    """
    s_idx, b_idx = np.nonzero(leftover)
    n = s_idx.size
    if n == 0:
        return 0
    desc = body_desc[s_idx, b_idx]  # (n, D, 3)
    dist = descriptor_distance(desc[:, None], desc[None, :], min_common)  # (n, n)
    dist[s_idx[:, None] == s_idx[None, :]] = np.inf  # one sensor's bodies are different people
    label = np.arange(n)
    members: dict[int, list[int]] = {i: [i] for i in range(n)}
    iu, ju = np.triu_indices(n, k=1)
    pair_d = dist[iu, ju]
    order = np.lexsort((ju, iu, pair_d))
    for k in order:  # bookkeeping over a few dozen leftovers at most
        if not pair_d[k] <= gate_mm:
            break
        a, b = label[iu[k]], label[ju[k]]
        if a == b:
            continue
        ma, mb = members[a], members[b]
        if not (dist[np.asarray(ma)[:, None], mb] <= gate_mm).all():  # complete linkage; also rejects a shared sensor
            continue
        members[a] = ma + mb
        label[mb] = a
        del members[b]
    roots = sorted(members, key=lambda r: min(members[r]))
    for offset, root in enumerate(roots):
        idx = np.asarray(members[root])
        person[s_idx[idx], b_idx[idx]] = first_row + offset
    return len(roots)


def assign_to_tracks(
    body_desc: np.ndarray,
    usable: np.ndarray,
    tracks: np.ndarray,
    confirmed: np.ndarray,
    gate_mm: np.ndarray,
    min_common_points: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steps 2-3 (module docstring): the body-to-track costs and the cascade of per-sensor Hungarian assignments,
    in a compiled kernel (:func:`skelfuse.fusion.kernels.association.assign_to_tracks`; its numpy form with scipy's
    solver, the test reference, is :mod:`skelfuse.fusion.reference.association`).

    Parameters
    ----------
    body_desc : (S, B, D, 3) mm; usable : (S, B) bool; tracks : (K, D, 3) mm, predicted descriptors;
    confirmed : (K,) bool; gate_mm : (K,) mm; min_common_points : int.

    Returns
    -------
    person (S, B) int64, track of each body (-1: none); assigned_cost (S, B) mm (NaN: none); cost (S, B, K) mm.
    """
    S, B = usable.shape
    K = tracks.shape[0]
    return kernels.load().association.assign_to_tracks(
        kernels.kernel_array(body_desc, np.float64, (S, B, N_DESCRIPTOR, 3), "body_desc"),
        kernels.kernel_array(usable, np.bool_, (S, B), "usable"),
        kernels.kernel_array(tracks, np.float64, (K, N_DESCRIPTOR, 3), "tracks"),
        kernels.kernel_array(confirmed, np.bool_, (K,), "confirmed"),
        kernels.kernel_array(gate_mm, np.float64, (K,), "gate_mm"),
        int(min_common_points),
    )


def match_tracks(
    positions: np.ndarray,
    valid: np.ndarray,
    tracks: np.ndarray,
    confirmed: np.ndarray,
    gate_mm: np.ndarray,
    min_common_points: int,
    duplicate_mm: float | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Steps 1-4 (module docstring) in one compiled kernel call
    (:func:`skelfuse.fusion.kernels.association.match_tracks`): the torso descriptors, which bodies can be compared,
    :func:`assign_to_tracks`, and the duplicates (``duplicate_mm`` None: none).

    Returns
    -------
    body_desc (S, B, D, 3) mm, usable (S, B) bool, person (S, B) int64, assigned_cost (S, B) mm, cost (S, B, K) mm,
    duplicates (S, B) bool, leftover (S, B) bool: usable bodies neither assigned nor dropped.
    """
    S, B = valid.shape
    K = tracks.shape[0]
    return kernels.load().association.match_tracks(
        kernels.kernel_array(positions, np.float64, (S, B, N_JOINTS, 3), "positions"),
        kernels.kernel_array(valid, np.bool_, (S, B), "valid"),
        _CENTRAL,
        _PAIRS,
        kernels.kernel_array(tracks, np.float64, (K, N_DESCRIPTOR, 3), "tracks"),
        kernels.kernel_array(confirmed, np.bool_, (K,), "confirmed"),
        kernels.kernel_array(gate_mm, np.float64, (K,), "gate_mm"),
        int(min_common_points),
        np.nan if duplicate_mm is None else float(duplicate_mm),
    )


def person_descriptors(body_desc: np.ndarray, person: np.ndarray, n_persons: int) -> tuple[np.ndarray, np.ndarray]:
    """Per person row, the median over its sensors of their bodies' descriptors (P, D, 3) (NaN where no sensor has
    the point) and how many sensors see it (P,) int64; ``person`` (S, B) as :attr:`Association.person_of_body`. In
    a compiled kernel (:func:`skelfuse.fusion.kernels.association.person_descriptors`; the numpy form is the test
    reference)."""
    S, B = person.shape
    return kernels.load().association.person_descriptors(
        kernels.kernel_array(body_desc, np.float64, (S, B, N_DESCRIPTOR, 3), "body_desc"),
        kernels.kernel_array(person, np.int64, (S, B), "person"),
        int(n_persons),
    )
