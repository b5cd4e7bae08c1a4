"""The plain long CSV: one row per sensor, frame, body and joint, that any tool can write.

Columns (comma separated, a header row naming them; ``#`` lines are comments)::

    timestamp_us,sensor,body_id,joint,x,y,z[,qw,qx,qy,qz][,confidence]

* ``timestamp_us``: the frame's device time in µs (integer); frames of different sensors are matched by it.
* ``sensor``: the sensor's id (any text without commas); one file may hold several sensors.
* ``body_id``: the tracker's body id (integer >= 0).
* ``joint``: the k4abt joint name (``PELVIS``, ``SPINE_NAVEL``, ...) or its index 0-31.
* ``x, y, z``: position in mm, in the sensor's depth-camera frame (or in one shared frame, see
  ``--registered`` in docs/recordings.md).
* ``qw, qx, qy, qz`` (optional, all four or none): joint orientation, quaternion w x y z.
* ``confidence`` (optional): 0-3 or NONE / LOW / MEDIUM / HIGH. Absent: ``--assume-confidence`` decides.

Every body of a frame needs all 32 joints. Rows may come in any order; the reader sorts them by sensor,
time, body and joint. Numbers are read as written, so a writer that prints enough digits (``repr`` of a
float) round-trips exactly (:func:`write_long_csv` does).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.schema.errors import DataError
from skelfuse.schema.skeleton import JOINT_NAMES, N_JOINTS, Confidence
from skelfuse.sources.recorded import (
    Recording,
    _joint_name_key,
    _pad_bodies,
    assumed_confidence_level,
    parse_confidence,
)

REQUIRED_COLUMNS = ("timestamp_us", "sensor", "body_id", "joint", "x", "y", "z")
ORIENTATION_COLUMNS = ("qw", "qx", "qy", "qz")
CONFIDENCE_COLUMN = "confidence"

EXAMPLE = """\
# a 10-line example: sensor "master" and "sub", one body, two joints shown of the 32 each body needs
timestamp_us,sensor,body_id,joint,x,y,z,qw,qx,qy,qz,confidence
1000000,master,1,PELVIS,12.5,-310.0,2450.0,1.0,0.0,0.0,0.0,MEDIUM
1000000,master,1,SPINE_NAVEL,14.0,-480.2,2460.5,0.99,0.1,0.0,0.0,2
1000950,sub,3,PELVIS,-820.1,-300.4,2110.0,0.7,0.0,0.7,0.0,MEDIUM
1000950,sub,3,SPINE_NAVEL,-818.7,-470.0,2125.3,0.7,0.1,0.7,0.0,LOW
1033333,master,1,PELVIS,13.1,-309.5,2449.2,1.0,0.0,0.0,0.0,MEDIUM
1033333,master,1,SPINE_NAVEL,14.6,-479.9,2459.8,0.99,0.1,0.0,0.0,MEDIUM
1034290,sub,3,PELVIS,-819.5,-300.1,2109.4,0.7,0.0,0.7,0.0,MEDIUM
1034290,sub,3,SPINE_NAVEL,-818.2,-469.6,2124.9,0.7,0.1,0.7,0.0,MEDIUM
"""
"""The documented example (docs/recordings.md shows it; a test checks that its header parses)."""

_JOINT_BY_KEY = {name: index for index, name in enumerate(JOINT_NAMES)}


def _joint_of(cell: str) -> int | None:
    text = cell.strip()
    if text.isdigit():
        value = int(text)
        return value if value < N_JOINTS else None
    return _JOINT_BY_KEY.get(_joint_name_key(text))


def load_long_csv(
    path: str | Path, *, assume_confidence: str = "medium", sensor_id: str | None = None
) -> list[Recording]:
    """Read a long CSV into one :class:`Recording` per sensor (in order of first appearance).

    Parameters
    ----------
    path : the CSV file.
    assume_confidence : what a file without a ``confidence`` column gets (:data:`ASSUME_CONFIDENCE`).
    sensor_id : rename the file's only sensor (an ``ID=PATH`` spec); an error if the file holds several.

    Raises
    ------
    DataError
        Missing or malformed file, naming the file and line and what to fix: a missing column, a wrong
        column count, a non-numeric or non-finite number, an unknown joint or confidence, a joint given
        twice for one body, a body lacking joints.
    """
    path = Path(path)
    level = assumed_confidence_level(assume_confidence)
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            lines = [(n, row) for n, row in enumerate(csv.reader(handle), start=1)]
    except FileNotFoundError:
        raise DataError(f"{path}: no such file; expected a long skeleton CSV") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read as UTF-8 text CSV: {exc}") from exc
    lines = [(n, row) for n, row in lines if row and row[0].strip()[:1] != "#" and any(c.strip() for c in row)]
    if not lines:
        raise DataError(f"{path}: no header row; expected {','.join(REQUIRED_COLUMNS)}[,qw,qx,qy,qz][,confidence]")
    header_line, header = lines[0]
    names = [cell.strip().lower() for cell in header]
    missing = [c for c in REQUIRED_COLUMNS if c not in names]
    if missing:
        raise DataError(
            f"{path}:{header_line}: the header lacks column(s) {', '.join(missing)}; expected "
            f"{','.join(REQUIRED_COLUMNS)}[,qw,qx,qy,qz][,confidence] (see docs/recordings.md)"
        )
    quat_present = [c in names for c in ORIENTATION_COLUMNS]
    if any(quat_present) and not all(quat_present):
        raise DataError(f"{path}:{header_line}: give all four of qw,qx,qy,qz or none of them")
    col = {name: names.index(name) for name in names if name}
    has_quat = all(quat_present)
    has_conf = CONFIDENCE_COLUMN in col

    # (sensor, time, body) -> [positions (32,3), quats (32,4), conf (32,), seen (32,), first line]
    bodies: dict[tuple[str, int, int], list] = {}
    sensor_order: list[str] = []
    for line_no, row in lines[1:]:
        if len(row) != len(names):
            raise DataError(f"{path}:{line_no}: expected {len(names)} columns as the header says, got {len(row)}")
        sensor, timestamp, body_id, joint, xyz, quat, conf = _parse_row(path, line_no, row, col, has_quat, level)
        key = (sensor, timestamp, body_id)
        entry = bodies.get(key)
        if entry is None:
            if sensor not in sensor_order:
                sensor_order.append(sensor)
            entry = bodies[key] = [
                np.full((N_JOINTS, 3), np.nan, np.float32),
                np.full((N_JOINTS, 4), np.nan, np.float32),
                np.zeros(N_JOINTS, np.uint8),
                np.zeros(N_JOINTS, bool),
                line_no,
            ]
        if entry[3][joint]:
            raise DataError(
                f"{path}:{line_no}: joint {JOINT_NAMES[joint]} of body {body_id} of sensor {sensor!r} at "
                f"{timestamp} µs given twice; one row per joint"
            )
        entry[0][joint], entry[1][joint], entry[2][joint], entry[3][joint] = xyz, quat, conf, True
    _check_complete(path, bodies)
    if sensor_id is not None and len(sensor_order) > 1:
        raise DataError(
            f"{path}: holds sensors {', '.join(sensor_order)}; an ID=PATH spec renames a one-sensor file only "
            "(give the path alone: the file names its sensors)"
        )
    return _recordings(path, bodies, sensor_order, sensor_id, None if has_conf else assume_confidence)


def _recordings(
    path: Path,
    bodies: dict[tuple[str, int, int], list[Any]],
    sensor_order: list[str],
    sensor_id: str | None,
    confidence_assumed: str | None,
) -> list[Recording]:
    """One :class:`Recording` per sensor, in the file's order, its frames in time order."""
    recordings = []
    for sensor in sensor_order:
        keys = sorted(k for k in bodies if k[0] == sensor)
        times = sorted({k[1] for k in keys})
        frames = [[(k[2], *bodies[k][:3]) for k in keys if k[1] == t] for t in times]
        positions, orientations, confidence, body_ids = _pad_bodies(frames)
        recordings.append(
            Recording(
                sensor_id=sensor if sensor_id is None else sensor_id,
                positions=positions,
                orientations=orientations,
                confidence=confidence,
                body_ids=body_ids,
                device_time_us=np.asarray(times, dtype=np.int64),
                source=str(path),
                confidence_assumed=confidence_assumed,
                file_format="long",
            )
        )
    return recordings


def _parse_row(
    path: Path, line_no: int, row: list[str], col: dict[str, int], has_quat: bool, level: Confidence
) -> tuple[str, int, int, int, list[float], list[float], int]:
    """One joint row: sensor, time (µs), body id, joint index, position, quaternion (NaN without), confidence.

    Raises
    ------
    DataError
        Naming the file and line: an empty sensor, a non-numeric or non-finite value, a negative body id, an
        unknown joint or confidence.
    """
    has_conf = CONFIDENCE_COLUMN in col
    sensor = row[col["sensor"]].strip()
    if not sensor:
        raise DataError(f"{path}:{line_no}: empty sensor id")
    try:
        timestamp = int(row[col["timestamp_us"]])
        body_id = int(row[col["body_id"]])
        xyz = [float(row[col[c]]) for c in ("x", "y", "z")]
        quat = [float(row[col[c]]) for c in ORIENTATION_COLUMNS] if has_quat else [math.nan] * 4
    except ValueError as exc:
        raise DataError(
            f"{path}:{line_no}: non-numeric value ({exc}); timestamp_us and body_id are integers, x y z "
            "(and qw..qz) numbers"
        ) from None
    if body_id < 0:
        raise DataError(f"{path}:{line_no}: body_id {body_id} is negative; leave frames without a body out")
    if not all(math.isfinite(v) for v in xyz + (quat if has_quat else [])):
        raise DataError(f"{path}:{line_no}: non-finite position or orientation; leave the joint's body out")
    joint = _joint_of(row[col["joint"]])
    if joint is None:
        raise DataError(
            f"{path}:{line_no}: unknown joint {row[col['joint']]!r}; expected a k4abt joint name "
            "(PELVIS, SPINE_NAVEL, ...) or an index 0-31"
        )
    if has_conf:
        parsed = parse_confidence(row[col[CONFIDENCE_COLUMN]])
        if parsed is None:
            raise DataError(
                f"{path}:{line_no}: unknown confidence {row[col[CONFIDENCE_COLUMN]]!r}; expected 0-3 or "
                "NONE / LOW / MEDIUM / HIGH"
            )
        conf = int(parsed)
    else:
        conf = int(level)
    return sensor, timestamp, body_id, joint, xyz, quat, conf


def _check_complete(path: Path, bodies: dict[tuple[str, int, int], list[Any]]) -> None:
    """Every body of every sensor and time has all 32 joints (DataError naming its first line otherwise)."""
    for (sensor, timestamp, body_id), entry in bodies.items():
        if not entry[3].all():
            absent = [JOINT_NAMES[j] for j in np.nonzero(~entry[3])[0]]
            raise DataError(
                f"{path}:{entry[4]}: body {body_id} of sensor {sensor!r} at {timestamp} µs lacks "
                f"{len(absent)} joint(s) ({', '.join(absent[:4])}{'...' if len(absent) > 4 else ''}); every "
                "body needs all 32 joints"
            )


def write_long_csv(recordings: Sequence[Recording], path: str | Path, *, orientations: bool = True) -> int:
    """Write recordings as one long CSV (every column, floats as ``repr``: exact round trip). Returns rows."""
    path = Path(path)
    header = [*REQUIRED_COLUMNS, *(ORIENTATION_COLUMNS if orientations else ()), CONFIDENCE_COLUMN]
    n = 0
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for recording in recordings:
            times = recording.frame_times_us()
            for t in range(recording.n_frames):
                for b in np.nonzero(recording.body_ids[t] >= 0)[0]:
                    for j in range(N_JOINTS):
                        row = [int(times[t]), recording.sensor_id, int(recording.body_ids[t, b]), JOINT_NAMES[j]]
                        row += [repr(float(v)) for v in recording.positions[t, b, j]]
                        if orientations:
                            row += [repr(float(v)) for v in recording.orientations[t, b, j]]
                        row.append(int(recording.confidence[t, b, j]))
                        writer.writerow(row)
                        n += 1
    return n
