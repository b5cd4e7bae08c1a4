"""Hybrid mode: the skeleton the tracker found on each person's virtual image enters skeleton fusion as one
more, virtual, sensor.

The depth-level fusion's skeletons are already in the world frame (``FrontalView.to_world``), so the virtual
sensor's pose is the identity; it is appended as the last sensor row of one instant's arrays, in the layout
:meth:`skelfuse.fusion.people.PeopleFuser.step` takes, and association, realignment, the DBSCAN merge and the
filters treat it like any sensor. Its joints carry the tracker's confidence when given, else MEDIUM.
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
