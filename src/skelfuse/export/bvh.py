"""BVH (Biovision hierarchy) export of fused people, through the fixed-length armature.

One file per person: the k4abt hierarchy (joint names as in :data:`skelfuse.schema.skeleton.JOINT_NAMES`)
with that person's rest offsets (:mod:`skelfuse.retarget.armature`, T-pose), the root (PELVIS) with six
channels ``Xposition Yposition Zposition Zrotation Xrotation Yrotation``, every other joint with three
``Zrotation Xrotation Yrotation``, leaf joints closed by an ``End Site`` (their bone tail, for tools that
draw bones). Frame Time is the take's uniform step (gaps and irregular frames are resampled and filled by
the armature fit; BVH has no way to mark a gap, so the filled joint-frames are reported by the writer instead).

Conventions (the ones Blender's importer assumes by default: ``axis_forward='-Z', axis_up='Y'``):

- axes: Y up, the rest pose faces +Z, its left towards +X. From our world (z up): BVH ``(X, Y, Z) =
  (x, z, -y)``, a proper rotation, so a file imported into Blender with the default axes lands in Blender's
  z-up world exactly where our world frame has it (Blender world = our world, in the file's unit).
- units: centimetres by default (the usual BVH unit; ``unit="mm"`` or ``"m"`` on request). Blender reads a
  BVH number as one Blender unit (metre), so import a centimetre file with Scale 0.01.
- rotation order: channels ``Zrotation Xrotation Yrotation``, composed in the listed order, ``R = Rz·Rx·Ry``
  (intrinsic Z, then X, then Y), degrees. A joint's position is its parent's position plus the parent's
  global rotation applied to the joint's OFFSET.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skelfuse.retarget.armature import CHILDREN, LEAVES, FittedMotion, fit_frames, fit_motion
from skelfuse.schema.errors import DataError
from skelfuse.schema.frames import FusedFrame
from skelfuse.schema.skeleton import JOINT_NAMES

BVH_FROM_WORLD = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""Rotation taking our world axes (z up) to BVH axes (Y up): ``(X, Y, Z) = (x, z, -y)``."""

UNIT_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0}
"""Millimetres per BVH unit, by unit name."""

ROTATION_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")
POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")


def _depth_first(joint: int = 0) -> tuple[int, ...]:
    order = [joint]
    for child in CHILDREN[joint]:
        order.extend(_depth_first(child))
    return tuple(order)


DFS_ORDER: tuple[int, ...] = _depth_first()
"""k4abt joint indices in the order the hierarchy (and so the motion columns) lists them."""


@dataclass(frozen=True)
class BvhExport:
    """What one written BVH file holds.

    path : the file; motion : the fitted armature motion it encodes (world mm); unit : its length unit;
    filled_fraction : (32,) per joint, the share of frames whose value was filled, not fused.
    """

    path: Path
    track_id: int
    unit: str
    motion: FittedMotion

    @property
    def n_frames(self) -> int:
        return self.motion.n_frames

    @property
    def filled_fraction(self) -> np.ndarray:
        return self.motion.filled.mean(axis=0)

    def retargeting_error(self) -> dict[str, dict[str, float]]:
        """FK of the file versus the fused positions, per joint group, mm (see ``FittedMotion``)."""
        return self.motion.retargeting_error()


def euler_zxy_degrees(rotation: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations → (..., 3) angles (z, x, y) in degrees with ``R = Rz(z) @ Rx(x) @ Ry(y)``.

    At the singularity (x = ±90°) y is set to 0 and z takes the whole turn about the vertical.
    """
    r = rotation
    x = np.arcsin(np.clip(r[..., 2, 1], -1.0, 1.0))
    regular = np.abs(r[..., 2, 1]) < 1.0 - 1e-12
    z = np.where(regular, np.arctan2(-r[..., 0, 1], r[..., 1, 1]), np.arctan2(r[..., 1, 0], r[..., 0, 0]))
    y = np.where(regular, np.arctan2(-r[..., 2, 0], r[..., 2, 2]), 0.0)
    return np.degrees(np.stack([z, x, y], axis=-1))


def bvh_text(motion: FittedMotion, *, unit: str = "cm") -> str:
    """The BVH file text of one fitted motion (see the module docstring for axes, unit and order)."""
    if unit not in UNIT_MM:
        raise DataError(f"unknown BVH unit {unit!r}; use one of {', '.join(UNIT_MM)}")
    scale = 1.0 / UNIT_MM[unit]
    offsets = motion.armature.offsets @ BVH_FROM_WORLD.T * scale
    tails = motion.armature.leaf_tails @ BVH_FROM_WORLD.T * scale
    lines = ["HIERARCHY"]

    digits = 4 + round(np.log10(UNIT_MM[unit]))  # lengths to 0.1 µm whatever the unit

    def number3(v: np.ndarray) -> str:
        return " ".join(f"{x:.{digits}f}" for x in v)

    def emit(joint: int, depth: int) -> None:
        pad = "  " * depth
        if joint == 0:
            lines.append(f"ROOT {JOINT_NAMES[joint]}")
        else:
            lines.append(f"{pad}JOINT {JOINT_NAMES[joint]}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}  OFFSET {number3(offsets[joint])}")
        channels = (*POSITION_CHANNELS, *ROTATION_CHANNELS) if joint == 0 else ROTATION_CHANNELS
        lines.append(f"{pad}  CHANNELS {len(channels)} {' '.join(channels)}")
        for child in CHILDREN[joint]:
            emit(child, depth + 1)
        if LEAVES[joint]:
            lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET {number3(tails[joint])}", f"{pad}  }}"])
        lines.append(f"{pad}}}")

    emit(0, 0)
    # Rotations in BVH axes: L_bvh = M L M^T.
    local = BVH_FROM_WORLD @ motion.local_rotations @ BVH_FROM_WORLD.T
    angles = euler_zxy_degrees(local[:, list(DFS_ORDER)])  # (F, 32, 3) in DFS order
    root = motion.root_positions @ BVH_FROM_WORLD.T * scale
    table = np.concatenate([root, angles.reshape(angles.shape[0], -1)], axis=1)
    lines += ["MOTION", f"Frames: {table.shape[0]}", f"Frame Time: {motion.frame_time_s:.8f}"]
    lines += [" ".join([*(f"{v:.{digits}f}" for v in row[:3]), *(f"{v:.6f}" for v in row[3:])]) for row in table]
    return "\n".join(lines) + "\n"


def _person_path(path: Path, track_id: int, several: bool) -> Path:
    return path.with_name(f"{path.stem}_person{track_id}{path.suffix}") if several else path


def write_bvh_motion(path: str | Path, motion: FittedMotion, *, unit: str = "cm") -> BvhExport:
    """Write one fitted motion as a BVH file."""
    path = Path(path)
    path.write_text(bvh_text(motion, unit=unit), encoding="ascii")
    return BvhExport(path, motion.track_id, unit, motion)


def write_bvh(
    frames: Sequence[FusedFrame], path: str | Path, *, unit: str = "cm", fps: float | None = None
) -> list[BvhExport]:
    """Write every person of a sequence of fused frames as BVH: the one entry point for ``skelfuse export``.

    Parameters
    ----------
    frames : fused frames (any order; sorted by ``time_us``); ``orientations`` are used where present
    path : the output file; with several people, one file per person named ``<stem>_person<id><suffix>``
    unit : "cm" (default), "mm" or "m"
    fps : output frame rate; default the median rate of the frames

    Returns
    -------
    One :class:`BvhExport` per person (path, frames, filled share per joint, retargeting error).

    Raises
    ------
    DataError
        No frames, an unknown unit, or a person whose pelvis was never tracked.
    """
    if unit not in UNIT_MM:
        raise DataError(f"unknown BVH unit {unit!r}; use one of {', '.join(UNIT_MM)}")
    motions = fit_frames(frames, fps=fps)
    path = Path(path)
    return [write_bvh_motion(_person_path(path, m.track_id, len(motions) > 1), m, unit=unit) for m in motions]


def write_bvh_arrays(
    path: str | Path,
    times_s: np.ndarray,
    positions: np.ndarray,
    *,
    orientations: np.ndarray | None = None,
    unit: str = "cm",
    fps: float | None = None,
    track_id: int = 0,
) -> BvhExport:
    """Write one person's arrays as BVH: ``times_s`` (F,) seconds, ``positions`` (F, 32, 3) mm world, NaN gaps;
    ``orientations`` (F, 32, 4) w, x, y, z optional."""
    if unit not in UNIT_MM:
        raise DataError(f"unknown BVH unit {unit!r}; use one of {', '.join(UNIT_MM)}")
    motion = fit_motion(times_s, positions, orientations=orientations, fps=fps, track_id=track_id)
    return write_bvh_motion(path, motion, unit=unit)


def world_positions_from_bvh(positions_bvh: np.ndarray, names: Sequence[str], *, unit: str = "cm") -> np.ndarray:
    """(F, n, 3) joint positions in a BVH file's axes and unit, named → (F, 32, 3) world mm in k4abt order.

    For reading our own files back (tests, Blender comparisons); raises DataError if a k4abt joint is missing.
    """
    index = {name: k for k, name in enumerate(names)}
    missing = [n for n in JOINT_NAMES if n not in index]
    if missing:
        raise DataError(f"the BVH holds no joint(s) {', '.join(missing)}; was it written by skelfuse?")
    ordered = positions_bvh[:, [index[n] for n in JOINT_NAMES]]
    return ordered @ BVH_FROM_WORLD * UNIT_MM[unit]
