"""One person's fused skeleton as an OpenSim TRC marker file (the k4abt joints as markers).

The Track Row Column format (Motion Analysis; OpenSim's marker file, read by its ``TRCFileAdapter``), tab
separated, as OpenSim documents it:

* line 1: ``PathFileType  4  (X/Y/Z)  <file name>``
* line 2: ``DataRate  CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  OrigDataStartFrame  OrigNumFrames``
* line 3: their values (rates in Hz, ``Units`` = ``mm``)
* line 4: ``Frame#  Time`` and each marker name followed by two empty cells (its Y and Z columns)
* line 5: two empty cells, then ``X1 Y1 Z1 X2 Y2 Z2 ...``
* line 6: empty
* then one row per frame: frame number, time (s), and x y z per marker; a gap is three empty cells. A row
  whose last marker is a gap ends with one more tab: OpenSim's reader (4.6) drops a row's trailing empty
  cells and then refuses the row as too short; with the closing tab it reads the gap as NaN.

Frame numbers are the frames of the take's grid (1-based), so the files of several people of one take line
up, and the time of frame f is ``(f - 1) / DataRate`` with ``OrigDataStartFrame`` = 1 (OpenSim's
``t = (f - OrigDataStartFrame) / DataRate``). Axes: OpenSim's ground is y up, skelfuse's world z up; TRC
markers are written in OpenSim's axes, ``(X, Y, Z) = (x, z, -y)`` (a rotation of -90° about x, so the file
stays right-handed), unless ``opensim_axes`` is False.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from skelfuse.export.tracks import PersonTrack, TakeTracks
from skelfuse.schema.skeleton import JOINT_NAMES, N_JOINTS

HEADER_KEYS = (
    "DataRate",
    "CameraRate",
    "NumFrames",
    "NumMarkers",
    "Units",
    "OrigDataRate",
    "OrigDataStartFrame",
    "OrigNumFrames",
)
"""Line 2 of a TRC file."""

WORLD_TO_OPENSIM = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""skelfuse world (z up) -> OpenSim ground (y up): (X, Y, Z) = (x, z, -y)."""


def _number(value: float) -> str:
    return "" if not np.isfinite(value) else f"{value:.4f}"


def trc_lines(person: PersonTrack, take: TakeTracks, *, file_name: str, opensim_axes: bool = True) -> list[str]:
    """The lines of the TRC file (without line ends)."""
    rate = f"{take.rate_hz:.6g}"
    header = [
        "\t".join(["PathFileType", "4", "(X/Y/Z)", file_name]),
        "\t".join(HEADER_KEYS),
        "\t".join([rate, rate, str(person.n_frames), str(N_JOINTS), "mm", rate, "1", str(take.n_frames)]),
        "\t".join(["Frame#", "Time", *(cell for name in JOINT_NAMES for cell in (name, "", ""))]),
        "\t".join(["", "", *(f"{axis}{j + 1}" for j in range(N_JOINTS) for axis in "XYZ")]),
        "",
    ]
    xyz = person.positions @ WORLD_TO_OPENSIM.T if opensim_axes else person.positions
    rows = []
    for k in range(person.n_frames):
        frame = person.first_frame + k + 1
        cells = [str(frame), f"{(frame - 1) / take.rate_hz:.6f}"]
        cells += [_number(v) for v in xyz[k].reshape(-1).tolist()]
        if not cells[-1]:
            cells.append("")  # a closing tab: OpenSim's reader drops a row's trailing empty cells (see above)
        rows.append("\t".join(cells))
    return header + rows


def write_trc(
    person: PersonTrack, take: TakeTracks, path: str | os.PathLike[str], *, opensim_axes: bool = True
) -> Path:
    """Write one person of a take to ``path`` (``.trc``); returns the path."""
    path = Path(path)
    lines = trc_lines(person, take, file_name=path.name, opensim_axes=opensim_axes)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
