"""One person's fused skeleton as a C3D file (biomechanics: Visual3D, Mokka, OpenSim via conversion), via ezc3d.

Layout (``docs/export.md``): one 3D point per k4abt joint, ``POINT:LABELS`` = the joint names
(``PELVIS`` ... ``EAR_RIGHT``), ``POINT:UNITS`` = ``mm``, ``POINT:RATE`` = the take's grid rate, floats
(``POINT:SCALE`` -1), coordinates in the skelfuse world frame (right-handed, z up). The first frame in the
header is the person's first frame on the take's grid, so the files of several people of one take line up.
Residuals: -1 (invalid, the C3D way to say "no data") in gaps; otherwise the fused one-sigma position
uncertainty in mm where the fused frames carry one, else 0 (valid, but filtered: no measured residual).
A ``SKELFUSE`` parameter group holds ``TRACK_ID``, ``START_TIME_US`` (time of grid frame 0, µs, as text: it
does not fit a C3D float) and ``SOURCE``.

ezc3d (pyomeca, a C++ library with Python bindings, maintained) writes the file; the test suite reads it
back with ezc3d and with the independent pure-Python ``c3d`` package.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from skelfuse.export.tracks import PersonTrack, TakeTracks
from skelfuse.schema.skeleton import JOINT_NAMES, N_JOINTS

INVALID_RESIDUAL = -1.0
"""The C3D residual of a point without data."""


def c3d_arrays(person: PersonTrack) -> tuple[np.ndarray, np.ndarray]:
    """(4, 32, T) homogeneous points (NaN in gaps) and (1, 32, T) residuals, as ezc3d stores them."""
    gaps = person.gaps  # (T, 32)
    points = np.ones((4, N_JOINTS, person.n_frames))
    points[:3] = np.transpose(person.positions, (2, 1, 0))
    points[:3, gaps.T] = np.nan
    residual = np.zeros((N_JOINTS, person.n_frames))
    if person.position_std is not None:
        std = person.position_std.T
        residual = np.where(np.isfinite(std) & (std > 0), std, 0.0)
    residual[gaps.T] = INVALID_RESIDUAL
    return points, residual[None]


def write_c3d(person: PersonTrack, take: TakeTracks, path: str | os.PathLike[str], *, source: str = "") -> Path:
    """Write one person of a take to ``path`` (``.c3d``); returns the path.

    Raises
    ------
    ModuleNotFoundError
        ezc3d is not installed (``pip install ezc3d``).
    """
    try:
        import ezc3d
    except ImportError as exc:
        raise ModuleNotFoundError("C3D export needs ezc3d (pip install ezc3d)") from exc
    path = Path(path)
    c3d = ezc3d.c3d()
    point = c3d["parameters"]["POINT"]
    point["RATE"]["value"] = [float(take.rate_hz)]
    point["UNITS"]["value"] = ["mm"]
    point["LABELS"]["value"] = list(JOINT_NAMES)
    point["DESCRIPTIONS"]["value"] = [f"k4abt joint {j}, fused by skelfuse" for j in range(N_JOINTS)]
    points, residuals = c3d_arrays(person)
    c3d["data"]["points"] = points
    c3d["data"]["meta_points"] = {"residuals": residuals}
    c3d["header"]["points"]["first_frame"] = int(person.first_frame)
    c3d.add_parameter("SKELFUSE", "TRACK_ID", [str(person.track_id)])
    c3d.add_parameter("SKELFUSE", "START_TIME_US", [str(take.start_time_us)])
    c3d.add_parameter("SKELFUSE", "SOURCE", [source or "skelfuse export"])
    c3d.write(str(path))
    return path
