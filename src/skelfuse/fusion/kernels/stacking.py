"""One instant's bodies stacked sensor by sensor and moved to the world frame
(:func:`skelfuse.fusion.transform.stack_views_to_world`) as one compiled loop over bodies and joints.

Per body of each frame: its slot (sensor row, body index), its joints' world positions ``R p + t`` and, with
orientations, its joints' world quaternions ``q M`` (the calibration as a quaternion product matrix), normalized.
The same arithmetic as the numpy reference (:mod:`skelfuse.fusion.reference.transform`) up to the order of its
sums of three and four (last bits).
"""

from __future__ import annotations

import numba
import numpy as np

from skelfuse.fusion.kernels.signatures import BOOL, FLOAT, INT, KERNEL, UINT8, array

_SIGNATURE = (
    array(FLOAT, 3),  # positions (N, J, 3)
    array(UINT8, 2),  # confidence (N, J)
    array(FLOAT, 3),  # orientations (N, J, 4), or (0, J, 4)
    array(INT, 1),  # frame_rows (F,)
    array(INT, 1),  # frame_counts (F,)
    array(FLOAT, 3),  # world_from_sensor (S, 4, 4)
    array(FLOAT, 3),  # quat_matrices (S, 4, 4)
    array(FLOAT, 4, writable=True),  # world (S, B, J, 3)
    array(UINT8, 3, writable=True),  # stacked confidence (S, B, J)
    array(BOOL, 2, writable=True),  # valid (S, B)
    array(FLOAT, 4, writable=True),  # world orientations (S, B, J, 4), or (0, 0, J, 4)
)


@numba.njit(numba.boolean(*_SIGNATURE), **KERNEL)
def stack_to_world(
    positions: np.ndarray,
    confidence: np.ndarray,
    orientations: np.ndarray,
    frame_rows: np.ndarray,
    frame_counts: np.ndarray,
    world_from_sensor: np.ndarray,
    quat_matrices: np.ndarray,
    world: np.ndarray,
    stacked_confidence: np.ndarray,
    valid: np.ndarray,
    world_orientations: np.ndarray,
) -> bool:
    """Fill the stacked outputs (every slot, NaN / 0 / False where no body) from the frames' bodies; False (and
    nothing written) when the frames do not fit the slots (a row out of range, more bodies than slots, counts
    that do not sum to the bodies given).

    Parameters
    ----------
    positions (N, J, 3) float64 mm, confidence (N, J) uint8, orientations (N, J, 4) float64 (or N = 0: no
    orientations): the frames' bodies, frame after frame; frame_rows (F,), frame_counts (F,) int64: each frame's
    sensor row and number of bodies (summing to N); world_from_sensor (S, 4, 4); quat_matrices (S, 4, 4), ``q_world
    = q @ M``. Outputs: world (S, B, J, 3), stacked_confidence (S, B, J), valid (S, B), world_orientations
    (S, B, J, 4) (or an empty array: none).
    """
    S, B, J = world.shape[0], world.shape[1], world.shape[2]
    n_frames, with_orientations = frame_rows.shape[0], world_orientations.shape[0] > 0
    total = 0
    for f in range(n_frames):
        if frame_rows[f] < 0 or frame_rows[f] >= S or frame_counts[f] < 0 or frame_counts[f] > B:
            return False
        total += frame_counts[f]
    if total != positions.shape[0] or (with_orientations and orientations.shape[0] != total):
        return False
    for s in range(S):
        for b in range(B):
            valid[s, b] = False
    n = 0
    for f in range(n_frames):
        s = frame_rows[f]
        T = world_from_sensor[s]
        M = quat_matrices[s]
        for b in range(frame_counts[f]):
            valid[s, b] = True
            for j in range(J):
                x, y, z = positions[n, j, 0], positions[n, j, 1], positions[n, j, 2]
                for a in range(3):
                    world[s, b, j, a] = x * T[a, 0] + y * T[a, 1] + z * T[a, 2] + T[a, 3]
                stacked_confidence[s, b, j] = confidence[n, j]
                if with_orientations:  # q @ M, normalized; NaN when zero (norm <= 1e-9) or not finite
                    q0, q1, q2, q3 = (
                        orientations[n, j, 0],
                        orientations[n, j, 1],
                        orientations[n, j, 2],
                        orientations[n, j, 3],
                    )
                    r0 = q0 * M[0, 0] + q1 * M[1, 0] + q2 * M[2, 0] + q3 * M[3, 0]
                    r1 = q0 * M[0, 1] + q1 * M[1, 1] + q2 * M[2, 1] + q3 * M[3, 1]
                    r2 = q0 * M[0, 2] + q1 * M[1, 2] + q2 * M[2, 2] + q3 * M[3, 2]
                    r3 = q0 * M[0, 3] + q1 * M[1, 3] + q2 * M[2, 3] + q3 * M[3, 3]
                    norm = np.sqrt(r0 * r0 + r1 * r1 + r2 * r2 + r3 * r3)
                    if not (norm > 1e-9 and norm < np.inf):  # NaN compares False
                        norm = np.nan
                    world_orientations[s, b, j, 0] = r0 / norm
                    world_orientations[s, b, j, 1] = r1 / norm
                    world_orientations[s, b, j, 2] = r2 / norm
                    world_orientations[s, b, j, 3] = r3 / norm
            n += 1
    for s in range(S):  # the empty slots, written once (plain loops: a slice assignment compiles far longer)
        for b in range(B):
            if valid[s, b]:
                continue
            for j in range(J):
                stacked_confidence[s, b, j] = 0
                for a in range(3):
                    world[s, b, j, a] = np.nan
                if with_orientations:
                    for a in range(4):
                        world_orientations[s, b, j, a] = np.nan
    return True


def warm_up() -> None:
    """Compile (or load) :func:`stack_to_world` for its one signature."""
    poses = np.eye(4)[None].copy()
    stack_to_world(
        np.zeros((1, 2, 3)),
        np.zeros((1, 2), dtype=np.uint8),
        np.zeros((1, 2, 4)),
        np.zeros(1, dtype=np.int64),
        np.ones(1, dtype=np.int64),
        poses,
        poses,
        np.empty((1, 1, 2, 3)),
        np.empty((1, 1, 2), dtype=np.uint8),
        np.empty((1, 1), dtype=np.bool_),
        np.empty((1, 1, 2, 4)),
    )
