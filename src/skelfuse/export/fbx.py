"""FBX export of fused people, through Blender's own FBX exporter (no FBX writer of ours).

FBX is a closed format whose free writers are Autodesk's SDK and Blender. We write the person's BVH (the same
armature and rotations as :mod:`skelfuse.export.bvh`), let Blender import it and export the armature with its
animation baked on every frame (no curve simplification, no added leaf bones) with Blender's default FBX axes
(``axis_forward='-Z', axis_up='Y'``, the convention of Unity, Maya and MotionBuilder). Blender runs in its own
environment (:mod:`skelfuse.export.blender`), built and cached on first use.

Units: the scene is in metres (the BVH is imported with the scale that makes it so); Blender's exporter
writes the file's unit into the FBX header, so importers scale it themselves.
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skelfuse.export.blender import run_blender
from skelfuse.export.bvh import UNIT_MM, write_bvh_motion
from skelfuse.retarget.armature import FittedMotion, fit_frames, fit_motion
from skelfuse.schema.frames import FusedFrame

_BVH_UNIT = "cm"


@dataclass(frozen=True)
class FbxExport:
    """One written FBX file: its path, person and the fitted motion it encodes (world mm)."""

    path: Path
    track_id: int
    motion: FittedMotion
    blender_version: str

    def retargeting_error(self) -> dict[str, dict[str, float]]:
        return self.motion.retargeting_error()


def write_fbx_motion(path: str | Path, motion: FittedMotion) -> FbxExport:
    """Write one fitted motion as FBX through Blender (see the module docstring).

    Raises
    ------
    BlenderError
        bpy unavailable (``skelfuse setup blender`` installs it), or Blender failed on the file.
    """
    path = Path(path).resolve()
    with tempfile.TemporaryDirectory(prefix="skelfuse-fbx-") as work:
        bvh = write_bvh_motion(Path(work) / "take.bvh", motion, unit=_BVH_UNIT)
        result = run_blender(
            {"command": "bvh_to_fbx", "bvh": str(bvh.path), "scale": UNIT_MM[_BVH_UNIT] / 1000.0, "fbx": str(path)},
        )
    return FbxExport(path, motion.track_id, motion, str(result["blender"]))


def write_fbx(frames: Sequence[FusedFrame], path: str | Path, *, fps: float | None = None) -> list[FbxExport]:
    """Write every person of a sequence of fused frames as FBX: the entry point for ``skelfuse export``.

    One file per person; with several people named ``<stem>_person<id><suffix>``. ``fps``: output rate,
    default the frames' median rate. Raises DataError for bad input, BlenderError where Blender is missing.
    """
    motions = fit_frames(frames, fps=fps)
    path = Path(path)
    several = len(motions) > 1
    return [
        write_fbx_motion(
            path.with_name(f"{path.stem}_person{m.track_id}{path.suffix}") if several else path,
            m,
        )
        for m in motions
    ]


def write_fbx_arrays(
    path: str | Path,
    times_s: np.ndarray,
    positions: np.ndarray,
    *,
    orientations: np.ndarray | None = None,
    fps: float | None = None,
    track_id: int = 0,
) -> FbxExport:
    """Write one person's arrays (``times_s`` (F,) s, ``positions`` (F, 32, 3) mm world) as FBX."""
    motion = fit_motion(times_s, positions, orientations=orientations, fps=fps, track_id=track_id)
    return write_fbx_motion(path, motion)
