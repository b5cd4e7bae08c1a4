"""Reader for the CSV files of HPI-CH/azure-kinect-mkv-extractor (``joint_extractor.cpp``), no SDK needed.

The tool writes, per camera, a ``skeleton`` folder holding (among others) two ``;``-separated files:

* ``positions_3d.csv``: header ``timestamp;body_idx;PELVIS (c);PELVIS (x);PELVIS (y);PELVIS (z);...``
  (per joint, in SDK order, the confidence level 0-3 then x y z in mm); one row per body and frame, the
  timestamp being the body frame's device timestamp (µs). A frame without a body is one row with
  ``body_idx`` -1 and -1 in every joint column ("error line").
* ``orientations_3d.csv``: header ``timestamp;body_idx;PELVIS (w);PELVIS (x);PELVIS (y);PELVIS (z);...``
  (quaternion w x y z per joint); rows only for frames with bodies (no error line).

Rows of the two files are joined by (timestamp, body_idx), never by row number, since the orientation
file skips the body-less frames. A body without an orientation row gets NaN orientations; an orientation
row without a position row (a take whose orientation file begins earlier) is left out; both are reported.
Numbers are written with C++ ``std::to_string`` (6 decimals), so positions are exact to 1e-6 mm.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from skelfuse.schema.errors import DataError
from skelfuse.schema.skeleton import JOINT_NAMES, N_JOINTS, Confidence
from skelfuse.sources.recorded import Recording, _joint_name_key, _pad_bodies

POSITIONS_FILE = "positions_3d.csv"
ORIENTATIONS_FILE = "orientations_3d.csv"
DELIMITER = ";"
NO_BODY = -1


def extractor_files(path: str | Path) -> tuple[Path, Path | None]:
    """(positions_3d.csv, orientations_3d.csv or None) of a camera folder, its ``skeleton`` folder or a file.

    Raises DataError when no positions_3d.csv is there.
    """
    path = Path(path)
    if path.is_file():
        positions = path
    else:
        candidates = [path / POSITIONS_FILE, path / "skeleton" / POSITIONS_FILE]
        found = [c for c in candidates if c.is_file()]
        if not found:
            raise DataError(
                f"{path}: no {POSITIONS_FILE} in it or in its skeleton/ folder; give the camera folder that "
                "azure-kinect-mkv-extractor wrote (or its positions_3d.csv)"
            )
        positions = found[0]
    orientations = positions.with_name(ORIENTATIONS_FILE)
    return positions, orientations if orientations.is_file() else None


def expected_header(axes: str) -> list[str]:
    """The header the tool writes for per-joint ``axes`` ("cxyz" for positions, "wxyz" for orientations)."""
    return ["timestamp", "body_idx"] + [f"{name} ({axis})" for name in JOINT_NAMES for axis in axes]


def _read_rows(path: Path, axes: str) -> list[tuple[int, list[str]]]:
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            rows = list(enumerate(csv.reader(handle, delimiter=DELIMITER), start=1))
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read as UTF-8 text: {exc}") from exc
    if not rows:
        raise DataError(f"{path}:1: empty file; expected the header 'timestamp;body_idx;PELVIS ({axes[0]});...'")
    header = [cell.strip() for cell in rows[0][1]]
    if header and header[-1] == "":
        header = header[:-1]
    want = expected_header(axes)
    if len(header) != len(want) or header[:2] != want[:2]:
        raise DataError(
            f"{path}:1: expected the azure-kinect-mkv-extractor header of {len(want)} columns "
            f"'timestamp;body_idx;PELVIS ({axes[0]});...' , got {len(header)} columns starting "
            f"{DELIMITER.join(header[:3])!r}; is this a {POSITIONS_FILE if axes == 'cxyz' else ORIENTATIONS_FILE}?"
        )
    for index, (cell, expected) in enumerate(zip(header[2:], want[2:], strict=True)):
        name, _, axis = cell.rpartition(" ")
        if _joint_name_key(name) + " " + axis != expected:
            raise DataError(f"{path}:1: column {index + 3} is {cell!r}, expected {expected!r} (k4abt SDK joint order)")
    return rows[1:]


def _numbers(path: Path, line_no: int, row: list[str], width: int) -> list[float]:
    if row and row[-1].strip() == "" and len(row) == width + 1:
        row = row[:-1]
    if len(row) != width:
        raise DataError(
            f"{path}:{line_no}: expected {width} ';'-separated columns (timestamp, body_idx, 4 per joint), "
            f"got {len(row)}; a truncated line? re-export or cut the line"
        )
    try:
        values = [float(cell) for cell in row]
    except ValueError as exc:
        raise DataError(f"{path}:{line_no}: non-numeric value ({exc}); fix or remove the line") from None
    if not all(math.isfinite(v) for v in values):
        raise DataError(f"{path}:{line_no}: non-finite value; fix or remove the line")
    return values


def load_extractor_csv(path: str | Path, *, sensor_id: str | None = None) -> Recording:
    """Read one camera's positions_3d.csv (+ orientations_3d.csv) into a :class:`Recording`.

    Parameters
    ----------
    path : the camera folder, its ``skeleton`` folder, or the positions_3d.csv itself.
    sensor_id : name of the sensor; default the camera folder's name.

    Raises
    ------
    DataError
        Missing file, wrong header, wrong column count, non-numeric value, confidence outside 0-3, a body
        repeated within a frame, timestamps going backwards (each naming the file and line), or an
        orientation file none of whose rows joins a position row. Orientation rows without a position row
        are left out and reported in the recording's notes.
    """
    positions_path, orientations_path = extractor_files(path)
    width = 2 + 4 * N_JOINTS
    if sensor_id is None:
        folder = positions_path.parent
        sensor_id = folder.parent.name if folder.name == "skeleton" else folder.name

    frames: dict[int, list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]] = {}
    body_line: dict[tuple[int, int], int] = {}
    last_time: int | None = None
    for line_no, row in _read_rows(positions_path, "cxyz"):
        if not row or all(not cell.strip() for cell in row):
            continue
        values = _numbers(positions_path, line_no, row, width)
        timestamp, body = int(values[0]), int(values[1])
        if last_time is not None and timestamp < last_time:
            raise DataError(
                f"{positions_path}:{line_no}: timestamp {timestamp} before the previous row's {last_time}; "
                "rows must be in time order (the tool writes them so): sort the file by timestamp"
            )
        last_time = timestamp
        bodies = frames.setdefault(timestamp, [])
        if body == NO_BODY:
            continue
        if (timestamp, body) in body_line:
            raise DataError(
                f"{positions_path}:{line_no}: body {body} at timestamp {timestamp} already on line "
                f"{body_line[(timestamp, body)]}; one row per body and frame"
            )
        per_joint = np.asarray(values[2:], dtype=np.float64).reshape(N_JOINTS, 4)
        levels = per_joint[:, 0]
        bad = (levels != np.round(levels)) | (levels < 0) | (levels > int(Confidence.HIGH))
        if bad.any():
            joint = int(np.argmax(bad))
            raise DataError(
                f"{positions_path}:{line_no}: confidence {levels[joint]:g} of {JOINT_NAMES[joint]} is not 0-3"
            )
        body_line[(timestamp, body)] = line_no
        quat = np.full((N_JOINTS, 4), np.nan, dtype=np.float32)
        bodies.append((body, per_joint[:, 1:].astype(np.float32), quat, levels.astype(np.uint8)))

    notes: list[str] = []
    if orientations_path is not None:
        notes += _join_orientations(orientations_path, positions_path, frames, width)
    unoriented = [t for t, bodies in frames.items() for b in bodies if np.isnan(b[2]).all()]
    if unoriented:
        notes.append(
            f"{len(unoriented)} bodies without an orientation row (timestamps {min(unoriented)}-{max(unoriented)} "
            "us): NaN orientations"
        )

    times = sorted(frames)
    positions, orientations, confidence, body_ids = _pad_bodies([frames[t] for t in times])
    return Recording(
        sensor_id=sensor_id,
        positions=positions,
        orientations=orientations,
        confidence=confidence,
        body_ids=body_ids,
        device_time_us=np.asarray(times, dtype=np.int64),
        source=str(positions_path),
        file_format="extractor",
        notes=tuple(notes),
    )


def _join_orientations(
    orientations_path: Path,
    positions_path: Path,
    frames: dict[int, list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]],
    width: int,
) -> list[str]:
    """Fill the bodies' orientations from ``orientations_3d.csv``, joined on (timestamp, body_idx).

    Rows with no position row (the tool's orientation file may begin frames before its position file) are
    left out and reported: how many and over which times. Refuses only when no row joins at all (two files
    of different exports)."""
    index = {(t, b[0]): b for t, bodies in frames.items() for b in bodies}
    joined, orphans = 0, []
    for line_no, row in _read_rows(orientations_path, "wxyz"):
        if not row or all(not cell.strip() for cell in row):
            continue
        values = _numbers(orientations_path, line_no, row, width)
        key = (int(values[0]), int(values[1]))
        if key[1] == NO_BODY:
            continue
        target = index.get(key)
        if target is None:
            orphans.append(key[0])
            continue
        target[2][:] = np.asarray(values[2:], dtype=np.float32).reshape(N_JOINTS, 4)
        joined += 1
    if not orphans:
        return []
    if joined == 0:
        raise DataError(
            f"{orientations_path}: none of its {len(orphans)} rows has a row in {positions_path.name} (same "
            "timestamp and body_idx); are the two files from the same export?"
        )
    first, last = min(orphans), max(orphans)
    return [
        f"{len(orphans)} rows of {orientations_path.name} have no row in {positions_path.name} (timestamps "
        f"{first}-{last} us, {(last - first) / 1e6:.2f} s): left out"
    ]


def write_extractor_csv(recording: Recording, folder: str | Path) -> Path:
    """Write ``recording`` as the tool would: ``folder/positions_3d.csv`` and ``folder/orientations_3d.csv``.

    For fixtures and for handing a take to tools that read this layout. Frames without a body get the
    tool's error line in the positions file only. Returns the positions file.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    times = recording.frame_times_us()
    pos_path, ori_path = folder / POSITIONS_FILE, folder / ORIENTATIONS_FILE
    with pos_path.open("w", newline="", encoding="utf-8") as pf, ori_path.open("w", newline="", encoding="utf-8") as of:
        pf.write(DELIMITER.join(expected_header("cxyz")) + "\n")
        of.write(DELIMITER.join(expected_header("wxyz")) + "\n")
        for t in range(recording.n_frames):
            present = np.nonzero(recording.body_ids[t] >= 0)[0]
            if not len(present):
                pf.write(DELIMITER.join([str(int(times[t])), "-1"] + ["-1"] * (4 * N_JOINTS)) + "\n")
                continue
            for b in present:
                head = [str(int(times[t])), str(int(recording.body_ids[t, b]))]
                pos_cells: list[str] = []
                ori_cells: list[str] = []
                for j in range(N_JOINTS):
                    pos_cells.append(str(int(recording.confidence[t, b, j])))
                    pos_cells.extend(f"{v:.6f}" for v in recording.positions[t, b, j])
                    ori_cells.extend(f"{v:.6f}" for v in recording.orientations[t, b, j])
                pf.write(DELIMITER.join(head + pos_cells) + "\n")
                of.write(DELIMITER.join(head + ori_cells) + "\n")
    return pos_path
