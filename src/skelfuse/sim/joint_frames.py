"""The simulator's true k4abt joint frames, from its own segment geometry (rotation matrices, world frame).

The k4abt convention (docs/orientations.md) is stated once here as the frames of a T-pose facing +x
(:data:`TPOSE_AXES`), and every true frame is that T-pose frame carried by the motion's own segments:

* every joint is first built as its aim frame (local X on the schema's aim bone) and turned by the schema's
  fixed ``ORIENTATION_AIM_OFFSET`` at the end: the identity except at the ankles, whose frame is rigid to the
  foot bone (the foot at a measured angle about local Z), not aimed along the shin, and the head, rigid to the
  nose (at a measured direction), not aimed along the neck;
* a joint whose segment holds a line across the body rigidly (the pelvis: the hips; the chest: the
  clavicles; the neck and head: the ears) takes its X from its bone and its lateral axis from that line;
* every other joint rides on its parent: the parent's frame times the two joints' fixed T-pose relation,
  turned by the smallest rotation that lays X on the joint's own bone (no twist of its own);
* BVH motions (:func:`skelfuse.sim.orientation.load_bvh_with_orientations`) use the recorded segment
  rotations instead, fixed to the frames this rule gives the file's rest pose.

The product builds its frames from tracked views (fusion/orientation.py); nothing here comes from that code:
only the schema's tables of the convention (which bone each X follows, the derived joints' offsets) are
shared, as the convention itself is. Quaternions (w, x, y, z) go through scipy.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from skelfuse.schema.skeleton import (
    N_JOINTS,
    ORIENTATION_AIM,
    ORIENTATION_AIM_OFFSET,
    ORIENTATION_AIMED,
    ORIENTATION_DERIVED_OFFSET,
    ORIENTATION_DERIVED_SOURCE,
    PARENTS,
    J,
)

_FORWARD, _LEFT, _UP = np.eye(3)


def _tpose_axes() -> np.ndarray:
    """(32, 3, 3) columns local X, Y, Z of each aimed joint's frame, in a T-pose facing +x (body = world)."""
    spine = (_UP, _FORWARD, _LEFT)  # X up the spine, Y forward, Z left
    groups = {
        ("PELVIS", "SPINE_NAVEL", "SPINE_CHEST", "NECK", "HEAD"): spine,
        ("HIP_LEFT", "KNEE_LEFT", "ANKLE_LEFT"): spine,  # X up the leg (to the parent)
        ("HIP_RIGHT", "KNEE_RIGHT", "ANKLE_RIGHT"): (-_UP, -_FORWARD, _LEFT),  # X down the leg
    }
    arm = ("CLAVICLE", "SHOULDER", "ELBOW", "WRIST", "HAND", "THUMB")
    groups[tuple(f"{name}_LEFT" for name in arm)] = (_LEFT, _FORWARD, -_UP)  # X outwards, Z down
    groups[tuple(f"{name}_RIGHT" for name in arm)] = (_LEFT, -_FORWARD, _UP)  # X inwards, Y back, Z up
    axes = np.full((N_JOINTS, 3, 3), np.nan)
    for names, columns in groups.items():
        for name in names:
            axes[J[name]] = np.stack(columns, axis=-1)
    return axes


TPOSE_AXES = _tpose_axes()
"""(32, 3, 3) the k4abt convention (docs/orientations.md's table): each aimed joint's local axes as columns,
world = body axes of a T-pose facing +x (x forward, y left, z up); NaN rows for the derived joints."""

AIM_OFFSETS = Rotation.from_quat(ORIENTATION_AIM_OFFSET, scalar_first=True).as_matrix()
"""(32, 3, 3) the schema's aim-frame -> k4abt-frame offsets as matrices: ``R_k4abt = R_aim @ offset``."""

_TPOSE_AIM_AXES = TPOSE_AXES @ np.swapaxes(AIM_OFFSETS, -1, -2)
"""(32, 3, 3) the T-pose's aim frames (the ankles' X on the foot bone the measured angle puts there, the head's
on the nose)."""


_LATERAL_LINE = {
    J["PELVIS"]: (J["HIP_RIGHT"], J["HIP_LEFT"]),
    J["SPINE_CHEST"]: (J["CLAVICLE_RIGHT"], J["CLAVICLE_LEFT"]),
    J["NECK"]: (J["EAR_RIGHT"], J["EAR_LEFT"]),
    J["HEAD"]: (J["EAR_RIGHT"], J["EAR_LEFT"]),
}
"""Joints whose segment carries a line across the body rigidly: (right point, left point) of that line."""

_DERIVED = np.flatnonzero(~ORIENTATION_AIMED)


def bone_directions(positions: np.ndarray) -> np.ndarray:
    """(..., 32, 3) unit direction of each joint's local X (the schema's ORIENTATION_AIM); NaN if derived."""
    p = np.asarray(positions, dtype=np.float64)
    d = (p[..., ORIENTATION_AIM[:, 1], :] - p[..., ORIENTATION_AIM[:, 0], :]) * ORIENTATION_AIM[:, 2, None]
    d = np.where(ORIENTATION_AIMED[:, None], d, np.nan)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def swing_matrix(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) the smallest rotation taking unit vectors ``u`` onto ``v`` (Rodrigues); 180 deg: about an
    axis normal to ``u``."""
    k = np.cross(u, v)
    c = np.sum(u * v, axis=-1)[..., None, None]
    skew = np.zeros((*k.shape[:-1], 3, 3))
    skew[..., 0, 1], skew[..., 0, 2], skew[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    skew = skew - np.swapaxes(skew, -1, -2)
    opposite = c[..., 0, 0] < -1.0 + 1e-9
    out = np.eye(3) + skew + skew @ skew / np.where(opposite[..., None, None], 1.0, 1.0 + c)
    normal = np.cross(u, np.where(np.abs(u[..., :1]) < 0.9, np.eye(3)[0], np.eye(3)[1]))
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    half_turn = 2.0 * normal[..., :, None] * normal[..., None, :] - np.eye(3)
    return np.where(opposite[..., None, None], half_turn, out)


def frame_from_line(x_axis: np.ndarray, left: np.ndarray) -> np.ndarray:
    """(..., 3, 3) a torso joint's frame (the spine's T-pose axes): X = ``x_axis``, Z towards ``left`` (made
    normal to X), Y = Z x X (forward)."""
    z = left - np.sum(left * x_axis, axis=-1, keepdims=True) * x_axis
    z /= np.linalg.norm(z, axis=-1, keepdims=True)
    return np.stack([x_axis, np.cross(z, x_axis), z], axis=-1)


def true_joint_frames(positions: np.ndarray) -> np.ndarray:
    """(T, 32, 3, 3) the true frames of a take's (T, 32, 3) true positions (module docstring); derived filled."""
    p = np.asarray(positions, dtype=np.float64)
    aims = bone_directions(p)
    frames = np.full((*p.shape[:-1], 3, 3), np.nan)  # aim frames until the offsets are applied below
    for joint in range(N_JOINTS):  # PARENTS[j] < j: every parent's frame is ready before its children's
        if not ORIENTATION_AIMED[joint]:
            continue
        if joint in _LATERAL_LINE:
            right, left = _LATERAL_LINE[joint]
            frames[:, joint] = frame_from_line(aims[:, joint], p[:, left] - p[:, right])
            continue
        parent = PARENTS[joint]
        relation = _TPOSE_AIM_AXES[parent].T @ _TPOSE_AIM_AXES[joint]
        carried = frames[:, parent] @ relation
        frames[:, joint] = swing_matrix(carried[..., 0], aims[:, joint]) @ carried
    return with_derived(frames @ AIM_OFFSETS)


def with_derived(frames: np.ndarray) -> np.ndarray:
    """Fill the derived joints (hand tips, feet, face) with their source's frame times the schema's offset."""
    out = np.array(frames, dtype=np.float64, copy=True)
    offsets = quat_to_matrix(ORIENTATION_DERIVED_OFFSET[_DERIVED])
    out[..., _DERIVED, :, :] = out[..., ORIENTATION_DERIVED_SOURCE[_DERIVED], :, :] @ offsets
    return out


def quat_to_matrix(quats: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices of (..., 4) unit quaternions w, x, y, z; NaN where the quaternion is."""
    q = np.asarray(quats, dtype=np.float64).reshape(-1, 4)
    finite = np.isfinite(q).all(axis=-1)
    out = np.full((q.shape[0], 3, 3), np.nan)
    if finite.any():
        out[finite] = Rotation.from_quat(q[finite], scalar_first=True).as_matrix()
    return out.reshape(*np.shape(quats)[:-1], 3, 3)


def matrix_to_quat(matrices: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions w, x, y, z (w >= 0) of (..., 3, 3) rotation matrices; NaN where the matrix is."""
    m = np.asarray(matrices, dtype=np.float64).reshape(-1, 3, 3)
    finite = np.isfinite(m).all(axis=(-1, -2))
    out = np.full((m.shape[0], 4), np.nan)
    if finite.any():
        out[finite] = Rotation.from_matrix(m[finite]).as_quat(canonical=True, scalar_first=True)
    return out.reshape(*np.shape(matrices)[:-2], 4)


def rotvec_to_matrix(rotvecs: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices of (..., 3) rotation vectors, radians."""
    r = np.asarray(rotvecs, dtype=np.float64)
    return Rotation.from_rotvec(r.reshape(-1, 3)).as_matrix().reshape(*r.shape[:-1], 3, 3)
