"""Hybrid mode: the skeleton the tracker found on each person's virtual image enters skeleton fusion as one
more, virtual, sensor.

The depth-level fusion's skeletons are already in the world frame (``FrontalView.to_world``), so the virtual
sensor's pose is the identity; it is appended as the last sensor row of one instant's arrays, in the layout
:meth:`skelfuse.fusion.people.PeopleFuser.step` takes, and association, realignment, the DBSCAN merge and the
filters treat it like any sensor. Its joints carry the tracker's confidence when given, else MEDIUM.

The tracker's prior (and the facing that places the virtual camera) is each person's *realigned fused*
skeleton (:func:`fused_priors`): skeleton fusion of the real sensors alone, as the depth mode uses. A per-joint
median of the raw bodies would carry a mirrored rear view's left/right labels, turn the facing 180° and put
the virtual camera behind the person.
"""

from __future__ import annotations

import numpy as np

from skelfuse.schema.skeleton import Confidence

VIRTUAL_SENSOR_POSE = np.eye(4)
"""``world_from_sensor`` of the virtual sensor: its skeletons are already in the world frame."""


def with_virtual_sensor(
    world_positions: np.ndarray,
    confidence: np.ndarray,
    valid: np.ndarray,
    virtual_positions: np.ndarray,
    virtual_confidence: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One instant's sensor arrays with the virtual sensor appended.

    Parameters
    ----------
    world_positions : (S, B, 32, 3) world mm, NaN-padded; confidence (S, B, 32) uint8; valid (S, B) bool.
    virtual_positions : (P, 32, 3) world mm, one skeleton per person the depth fusion tracked (NaN rows or
        joints where the tracker found nothing).
    virtual_confidence : (P, 32) uint8, the tracker's; None: MEDIUM wherever the position is finite.

    Returns
    -------
    (S + 1, max(B, P), 32, 3), (S + 1, max(B, P), 32), (S + 1, max(B, P)): the real sensors' rows unchanged
    (padded), then the virtual sensor's row. A virtual body is valid when any of its joints is finite.
    """
    positions = np.asarray(world_positions, dtype=np.float64)
    n_sensors, n_bodies, n_joints, _ = positions.shape
    virtual = np.asarray(virtual_positions, dtype=np.float64).reshape(-1, n_joints, 3)
    width = max(n_bodies, virtual.shape[0])
    out_positions = np.full((n_sensors + 1, width, n_joints, 3), np.nan)
    out_confidence = np.zeros((n_sensors + 1, width, n_joints), dtype=np.uint8)
    out_valid = np.zeros((n_sensors + 1, width), dtype=bool)
    out_positions[:n_sensors, :n_bodies] = positions
    out_confidence[:n_sensors, :n_bodies] = confidence
    out_valid[:n_sensors, :n_bodies] = valid
    finite = np.isfinite(virtual).all(axis=-1)
    out_positions[n_sensors, : virtual.shape[0]] = virtual
    if virtual_confidence is None:
        out_confidence[n_sensors, : virtual.shape[0]] = np.where(finite, int(Confidence.MEDIUM), 0)
    else:
        out_confidence[n_sensors, : virtual.shape[0]] = np.where(finite, virtual_confidence, 0)
    out_valid[n_sensors, : virtual.shape[0]] = finite.any(axis=-1)
    return out_positions, out_confidence, out_valid


def fused_priors(
    assignment: np.ndarray,
    fused_assignment: np.ndarray,
    fused_positions: np.ndarray,
    n_persons: int,
) -> np.ndarray:
    """Each hybrid person's prior: the fused skeleton (of the real sensors alone) its bodies joined.

    Parameters
    ----------
    assignment : (S, B) int, the hybrid mode's person of each real body (-1: none).
    fused_assignment : (S, B') int, skeleton fusion's output row of each real body (-1: none, a tentative
        track, padding), as :attr:`skelfuse.fusion.people.PeopleResult.assignment`.
    fused_positions : (P', 32, 3) world mm, skeleton fusion's output (realigned, merged, filtered).
    n_persons : number of hybrid persons.

    Returns
    -------
    (n_persons, 32, 3) world mm: the fused row most of the person's bodies joined (ties: the lower row); NaN
    for a person none of whose bodies reached a fused skeleton (a track not yet confirmed): no prior then,
    never the raw bodies, which may be mirrored.
    """
    assignment = np.asarray(assignment)
    fused_assignment = np.asarray(fused_assignment)
    fused = np.asarray(fused_positions, dtype=np.float64)
    priors = np.full((n_persons, fused.shape[1] if fused.ndim == 3 else 32, 3), np.nan)
    sensors = min(assignment.shape[0], fused_assignment.shape[0])
    bodies = min(assignment.shape[1], fused_assignment.shape[1]) if assignment.ndim == 2 else 0
    mine = assignment[:sensors, :bodies]
    rows = fused_assignment[:sensors, :bodies]
    for person in range(n_persons):
        joined = rows[(mine == person) & (rows >= 0)]
        if joined.size:
            values, counts = np.unique(joined, return_counts=True)
            priors[person] = fused[values[np.argmax(counts)]]
    return priors
