"""Loaders for recorded body-tracking skeletons: no Azure Kinect SDK needed.

Two formats are read, both into one :class:`Recording` (arrays over frames, bodies and joints):

* the CSV layout of the andyj1 "Low-Cost Motion Capture System using Synchronized Azure Kinect Systems"
  recordings (``../shared/data/azure-kinect-andyj1``): :func:`load_andyj1_csv`;
* the JSON written by the Body Tracking SDK's ``offline_processor`` sample:
  :func:`load_offline_processor_json`.

A :class:`Recording` replays as :class:`skelfuse.schema.frames.SensorFrame` objects (:meth:`Recording.frames`), so
anything that consumes live sensor frames can consume a file. Positions stay in the frame they were written
in (for the andyj1 files the authors already mapped the subordinates into the master camera frame).

Every malformed input raises :class:`skelfuse.schema.errors.DataError` naming the file, the line (CSV) or the
frame/body (JSON), what was expected and what was found.
"""

from __future__ import annotations

import csv
import json
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from skelfuse.schema.errors import DataError
from skelfuse.schema.frames import SensorFrame
from skelfuse.schema.skeleton import JOINT_NAMES, N_JOINTS, Confidence

FRAME_PERIOD_US = 33_333
"""Nominal frame interval of the Azure Kinect at 30 fps, used to number frames of files without timestamps."""

DuplicatePolicy = Literal["auto", "drop", "keep"]


@dataclass(frozen=True)
class Recording:
    """The skeletons one sensor recorded, as arrays over T frames and up to B bodies per frame.

    Bodies are padded to the largest body count of any frame: a padded slot has ``body_ids == -1``,
    NaN positions and orientations and confidence NONE (0).

    Attributes
    ----------
    sensor_id : str
        Name of the sensor (by default the file's stem, e.g. ``"joints_gen_master"``).
    positions : (T, B, 32, 3) float32
        Joint positions in mm, in the frame the file was written in. NaN in padded body slots.
    orientations : (T, B, 32, 4) float32
        Joint orientations as quaternions **w, x, y, z** (our convention, whatever the file's order).
    confidence : (T, B, 32) uint8
        :class:`skelfuse.schema.skeleton.Confidence` values.
    body_ids : (T, B) int64
        The tracker's body id of each slot, -1 for padding.
    device_time_us : (T,) int64 or None
        Device timestamps in µs where the file has them (offline_processor JSON), None where frames only
        match by order (andyj1 CSV).
    source : str
        Path of the file that was read.
    duplicates_dropped : int
        Frames dropped because the file wrote every frame twice (see :func:`load_andyj1_csv`); 0 otherwise.
    host_time_ns : (T,) int64 or None
        Host receive times where the file has them (skelfuse MCAP), else None.
    sequences : (T,) int64 or None
        The sensor's frame counters where the file has them (gaps are drops), else the frame index is used.
    confidence_assumed : str or None
        None when the confidence comes from the file; else what was assumed for a file that stores none
        (``"medium"``, ``"low"`` or ``"unknown"``, see :data:`ASSUME_CONFIDENCE`).
    file_format : str
        The format the file was read as (``"andyj1"``, ``"offline_processor"``, ``"extractor"``, ``"long"``,
        ``"mcap"``, ``"mkv"``).
    notes : tuple of str
        What the reader noticed and the user should hear (e.g. bodies without orientations).
    """

    sensor_id: str
    positions: np.ndarray
    orientations: np.ndarray
    confidence: np.ndarray
    body_ids: np.ndarray
    device_time_us: np.ndarray | None
    source: str = ""
    duplicates_dropped: int = 0
    host_time_ns: np.ndarray | None = None
    sequences: np.ndarray | None = None
    confidence_assumed: str | None = None
    file_format: str = ""
    notes: tuple[str, ...] = ()

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def max_bodies(self) -> int:
        return int(self.positions.shape[1])

    @property
    def has_timestamps(self) -> bool:
        """True when frames carry device timestamps; False when they only match by order (index)."""
        return self.device_time_us is not None

    def frame_times_us(self, frame_period_us: int = FRAME_PERIOD_US) -> np.ndarray:
        """(T,) int64 device times: the recorded ones, else ``index * frame_period_us`` (match by order)."""
        if self.device_time_us is not None:
            return self.device_time_us.astype(np.int64)
        return np.arange(self.n_frames, dtype=np.int64) * int(frame_period_us)

    def frames(self, frame_period_us: int = FRAME_PERIOD_US) -> Iterator[SensorFrame]:
        """Yield one :class:`SensorFrame` per recorded frame, padded body slots removed.

        ``sequence`` is the recorded sequence number, else the frame index. Files without timestamps get
        ``device_time_us = index * frame_period_us`` (30 fps by default); ``host_time_ns`` is the recorded
        host time where the file has one, else the device time in ns.
        """
        times_us = self.frame_times_us(frame_period_us)
        for index in range(self.n_frames):
            present = self.body_ids[index] >= 0
            host_ns = int(times_us[index]) * 1000 if self.host_time_ns is None else int(self.host_time_ns[index])
            yield SensorFrame(
                sensor_id=self.sensor_id,
                sequence=index if self.sequences is None else int(self.sequences[index]),
                device_time_us=int(times_us[index]),
                host_time_ns=host_ns,
                body_ids=self.body_ids[index, present].astype(np.uint32),
                positions=self.positions[index, present].copy(),
                orientations=self.orientations[index, present].copy(),
                confidence=self.confidence[index, present].copy(),
            )

    def single_body(self) -> tuple[np.ndarray, np.ndarray]:
        """Positions (T, 32, 3) float64 and confidence (T, 32) uint8 of a one-person take.

        Takes the first body slot of each frame (NaN / NONE where a frame has no body). Raises DataError
        when some frame holds more than one body, since then "the" person is ambiguous.
        """
        n_present = (self.body_ids >= 0).sum(axis=1)
        if (n_present > 1).any():
            first = int(np.argmax(n_present > 1))
            raise DataError(
                f"{self.source or self.sensor_id}: frame {first} holds {int(n_present[first])} bodies; "
                "single_body() needs a one-person take. Index Recording.positions[:, body] instead."
            )
        if self.max_bodies == 0:
            return (
                np.full((self.n_frames, N_JOINTS, 3), np.nan),
                np.zeros((self.n_frames, N_JOINTS), dtype=np.uint8),
            )
        return self.positions[:, 0].astype(np.float64), self.confidence[:, 0].copy()


# --------------------------------------------------------------------------------------------- confidence


def _sentence_key(text: str) -> str:
    """Lower-case words only, so that 'observed(likely' and 'observed (likely' compare equal."""
    return " ".join(re.findall(r"[a-z0-9]+", text.lower()))


# The k4abt header's comments on k4abt_joint_confidence_level_t, as the andyj1 writer and others print them.
# Variants seen: the andyj1 files write "The joint is not observed(likely due to occlusion) - predicted joint
# pose" and "Medium confidence in joint pose"; the header itself says "...occlusion), predicted joint
# pose" and some tools append the header's second sentence ("Current SDK will only provide joints up to this
# confidence level", "Placeholder for future SDK"). Numbers and enum names are accepted too.
_CONFIDENCE_SENTENCES: dict[str, Confidence] = {
    _sentence_key(text): level
    for text, level in [
        ("The joint is out of range (too far from depth camera)", Confidence.NONE),
        ("The joint is not observed (likely due to occlusion), predicted joint pose", Confidence.LOW),
        ("Medium confidence in joint pose", Confidence.MEDIUM),
        (
            "Medium confidence in joint pose. Current SDK will only provide joints up to this confidence level",
            Confidence.MEDIUM,
        ),
        ("High confidence in joint pose", Confidence.HIGH),
        ("High confidence in joint pose. Placeholder for future SDK", Confidence.HIGH),
        *[(level.name, level) for level in Confidence],
        *[(f"K4ABT_JOINT_CONFIDENCE_{level.name}", level) for level in Confidence],
        *[(str(int(level)), level) for level in Confidence],
    ]
}


ASSUME_CONFIDENCE: dict[str, Confidence] = {
    "medium": Confidence.MEDIUM,
    "low": Confidence.LOW,
    "unknown": Confidence.MEDIUM,
}
"""What ``--assume-confidence`` gives every joint of a file that stores no confidence.

* ``medium``: what the SDK reports for a normally tracked joint (HIGH never occurs) and what most joints
  carry (torso and head about 100 %, unoccluded legs 97-100 %); occluded, predicted joints become MEDIUM
  too, so fusion must reject them by geometry (as it must for the SDK's own over-confident MEDIUM).
* ``low``: treat every joint as predicted (a cautious choice for takes with much occlusion; a skeleton
  calibration uses MEDIUM joints only, so it finds nothing to fit on such a take).
* ``unknown``: do not use confidence at all. Every joint gets one and the same level (stored as MEDIUM, so
  that fusion prefers no joint over another; it is *not* the SDK's NONE, which means out of range), and
  every metric that relies on MEDIUM is reported as meaningless for the input.
"""


def assumed_confidence_level(assume: str) -> Confidence:
    """The level :data:`ASSUME_CONFIDENCE` gives for ``assume``; ValueError naming the choices otherwise."""
    try:
        return ASSUME_CONFIDENCE[assume]
    except KeyError:
        raise ValueError(f"assume_confidence must be one of {', '.join(ASSUME_CONFIDENCE)}, got {assume!r}") from None


def parse_confidence(text: str) -> Confidence | None:
    """Map a confidence sentence (or enum name / number) to :class:`Confidence`; None when unknown."""
    return _CONFIDENCE_SENTENCES.get(_sentence_key(text))


# -------------------------------------------------------------------------------------------------- CSV

_CSV_HEADER_ROWS = 2
_CSV_MIN_COLUMNS = 10  # body id, joint, x y z, qx qy qz qw, confidence (a trailing comma adds an empty 11th)


def _pad_bodies(
    frames: list[list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Stack per-frame lists of (body_id, positions, orientations, confidence) into padded arrays."""
    n_frames = len(frames)
    max_bodies = max((len(bodies) for bodies in frames), default=0)
    positions = np.full((n_frames, max_bodies, N_JOINTS, 3), np.nan, dtype=np.float32)
    orientations = np.full((n_frames, max_bodies, N_JOINTS, 4), np.nan, dtype=np.float32)
    confidence = np.zeros((n_frames, max_bodies, N_JOINTS), dtype=np.uint8)
    body_ids = np.full((n_frames, max_bodies), -1, dtype=np.int64)
    for t, bodies in enumerate(frames):
        for b, (body_id, pos, quat, conf) in enumerate(bodies):
            body_ids[t, b] = body_id
            positions[t, b] = pos
            orientations[t, b] = quat
            confidence[t, b] = conf
    return positions, orientations, confidence, body_ids


def load_andyj1_csv(
    path: str | Path,
    *,
    sensor_id: str | None = None,
    duplicates: DuplicatePolicy = "auto",
    group_bodies_by_id: bool = False,
) -> Recording:
    """Read one andyj1 CSV file (two header rows, then 32 rows per body and frame).

    Columns: body id, joint index 0-31, position x y z (mm), orientation quaternion, confidence as an English
    sentence, optionally a trailing empty column. The header names the quaternion columns x y z w, but the values
    are in the SDK's own order w, x, y, z (measured on the real takes: read as w x y z, each joint's X axis lies
    along its bone as the SDK documents, mean |cos| 0.98; read as the header says, 0.69; docs/orientations.md),
    so they are taken as they stand.
    Blank lines are skipped. Frames have no timestamps: they match across files by order.

    Parameters
    ----------
    path : path of the CSV file.
    sensor_id : name for the recording; default the file's stem.
    duplicates : {"auto", "drop", "keep"}
        ``joints_gen_master.csv`` of the 3-sensor take writes every frame twice in a row (196 blocks for the
        98 frames of its sibling files). "auto" drops the second copy when, and only when, the block count
        is even and every block 2k+1 is identical to block 2k (a real tracker can repeat one frame, never
        all of them). "drop" insists on that pattern and raises DataError if it is not there; "keep"
        keeps every block.
    group_bodies_by_id : bool
        The format does not mark frame boundaries, only 32-row body blocks. False (default): every block is
        one frame with one body (all the andyj1 takes are single-person). True: consecutive blocks form
        one frame until a body id repeats (k4abt body ids are unique within a frame); this cannot tell two
        one-body frames of different people from one two-body frame.

    Raises
    ------
    DataError
        The file is missing or malformed (naming file and line): wrong header, wrong column count, joint
        index out of order, a non-numeric or non-finite number, an unknown confidence sentence, a
        truncated last frame.
    """
    path = Path(path)
    if duplicates not in ("auto", "drop", "keep"):
        raise ValueError(f"duplicates must be 'auto', 'drop' or 'keep', got {duplicates!r}")
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            rows = list(enumerate(csv.reader(handle), start=1))
    except FileNotFoundError:
        raise DataError(f"{path}: no such file; expected an andyj1 joints CSV") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read as UTF-8 text CSV: {exc}") from exc

    if len(rows) < _CSV_HEADER_ROWS:
        raise DataError(f"{path}: expected 2 header rows ('Body ID,Joint #,x,y,z,...'), file has {len(rows)} lines")
    header = [cell.strip() for cell in rows[1][1]]
    if not header or header[0] != "Body ID":
        raise DataError(
            f"{path}:2: expected the column header 'Body ID,Joint #,x,y,z,x,y,z,w', got {','.join(header)!r}"
        )

    blocks = _andyj1_blocks(path, rows)
    blocks, dropped = _drop_written_twice(path, blocks, duplicates)

    frames: list[list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]] = []
    for block in blocks:
        if group_bodies_by_id and frames and all(block[0] != other[0] for other in frames[-1]):
            frames[-1].append(block)
        else:
            frames.append([block])
    positions, orientations, confidence, body_ids = _pad_bodies(frames)
    return Recording(
        sensor_id=sensor_id if sensor_id is not None else path.stem,
        positions=positions,
        orientations=orientations,
        confidence=confidence,
        body_ids=body_ids,
        device_time_us=None,
        source=str(path),
        duplicates_dropped=dropped,
        file_format="andyj1",
    )


def _andyj1_blocks(
    path: Path, rows: list[tuple[int, list[str]]]
) -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    """The 32-row body blocks of an andyj1 CSV after its header: (body id, positions, quaternions, confidence)."""
    blocks: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []
    block_lines: list[int] = []
    pos = np.empty((N_JOINTS, 3), dtype=np.float32)
    quat = np.empty((N_JOINTS, 4), dtype=np.float32)
    conf = np.empty(N_JOINTS, dtype=np.uint8)
    body_id = -1
    expected_joint = 0
    for line_no, row in rows[_CSV_HEADER_ROWS:]:
        if not row or all(not cell.strip() for cell in row):
            continue
        row_body, joint, values, level = _andyj1_row(path, line_no, row, expected_joint)
        if joint == 0:
            body_id = row_body
            block_lines.append(line_no)
        elif row_body != body_id:
            raise DataError(
                f"{path}:{line_no}: body id {row_body} inside the 32-row block of body {body_id} "
                f"that starts at line {block_lines[-1]}"
            )
        pos[joint] = values[0:3]
        quat[joint] = values[3:7]  # w x y z, whatever the header says (see the docstring)
        conf[joint] = int(level)
        expected_joint += 1
        if expected_joint == N_JOINTS:
            blocks.append((body_id, pos.copy(), quat.copy(), conf.copy()))
            expected_joint = 0
    if expected_joint != 0:
        raise DataError(
            f"{path}: last body block (from line {block_lines[-1]}) is truncated: {expected_joint} of "
            f"{N_JOINTS} joint rows"
        )
    return blocks


def _andyj1_row(
    path: Path, line_no: int, row: list[str], expected_joint: int
) -> tuple[int, int, list[float], Confidence]:
    """One joint row of an andyj1 CSV: body id, joint index, x y z and the quaternion, confidence.

    Raises
    ------
    DataError
        Naming the file and line: a wrong column count, a non-numeric or non-finite value, a joint out of
        order, an unknown confidence sentence.
    """
    if len(row) == _CSV_MIN_COLUMNS + 1 and not row[-1].strip():
        row = row[:-1]
    if len(row) != _CSV_MIN_COLUMNS:
        raise DataError(
            f"{path}:{line_no}: expected {_CSV_MIN_COLUMNS} columns (body id, joint, x, y, z, "
            f"qx, qy, qz, qw, confidence), got {len(row)}"
        )
    try:
        row_body = int(row[0])
        joint = int(row[1])
        values = [float(cell) for cell in row[2:9]]
    except ValueError as exc:
        raise DataError(f"{path}:{line_no}: non-numeric value: {exc}") from None
    if not all(math.isfinite(v) for v in values):
        raise DataError(f"{path}:{line_no}: non-finite position or orientation {row[2:9]}")
    if joint != expected_joint:
        raise DataError(
            f"{path}:{line_no}: joint index {joint} out of order, expected {expected_joint} "
            f"(32 rows per body in SDK joint order 0-31)"
        )
    level = parse_confidence(row[9])
    if level is None:
        raise DataError(
            f"{path}:{line_no}: unknown confidence sentence {row[9]!r}; known: 'Medium confidence in "
            "joint pose', 'The joint is not observed(likely due to occlusion) - predicted joint pose', "
            "'The joint is out of range (too far from depth camera)', 'High confidence in joint pose'"
        )
    return row_body, joint, values, level


def _blocks_equal(
    a: tuple[int, np.ndarray, np.ndarray, np.ndarray], b: tuple[int, np.ndarray, np.ndarray, np.ndarray]
) -> bool:
    return a[0] == b[0] and all(np.array_equal(x, y) for x, y in zip(a[1:], b[1:], strict=True))


def _drop_written_twice(
    path: Path,
    blocks: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]],
    policy: DuplicatePolicy,
) -> tuple[list[tuple[int, np.ndarray, np.ndarray, np.ndarray]], int]:
    """Detect a file that wrote every block twice in a row; drop the copies per ``policy``."""
    if policy == "keep":
        return blocks, 0
    written_twice = (
        len(blocks) >= 2
        and len(blocks) % 2 == 0
        and all(_blocks_equal(blocks[k], blocks[k + 1]) for k in range(0, len(blocks), 2))
    )
    if written_twice:
        return blocks[::2], len(blocks) // 2
    if policy == "drop":
        raise DataError(
            f"{path}: duplicates='drop' expects every body block written twice in a row, but the file has "
            f"{len(blocks)} blocks that do not pair up identically; use duplicates='auto' or 'keep'"
        )
    return blocks, 0


# ------------------------------------------------------------------------------------------------- JSON

OFFLINE_PROCESSOR_CONFIDENCE = Confidence.MEDIUM
"""Confidence given to every joint of an offline_processor JSON, which stores none.

MEDIUM because it is what the SDK reports for a normally tracked joint (HIGH never occurs) and what the
large majority of joints carry (torso and head about 100%, unoccluded legs 97-100%). The cost: occluded,
predicted joints are MEDIUM too, so fusion must reject them by geometry (the DBSCAN step), as it must for
the SDK's own over-confident MEDIUM anyway. Pass ``confidence=`` to choose otherwise.
"""

_JSON_ROOT_KEYS = ("k4abt_sdk_version", "source_file", "joint_names", "bone_list", "frames")
_JSON_FRAME_KEYS = ("timestamp_usec", "frame_id", "num_bodies", "bodies")
_JSON_BODY_KEYS = ("body_id", "joint_positions", "joint_orientations")


def _joint_name_key(name: str) -> str:
    key = name.strip().upper()
    key = key.removeprefix("K4ABT_JOINT_")
    return key.replace("SPINE_NAVAL", "SPINE_NAVEL")


def _require_keys(where: str, obj: Any, keys: tuple[str, ...], what: str) -> None:
    if not isinstance(obj, dict):
        raise DataError(f"{where}: expected {what} to be a JSON object, got {type(obj).__name__}")
    missing = [key for key in keys if key not in obj]
    if missing:
        raise DataError(f"{where}: {what} lacks key(s) {', '.join(missing)}; expected {', '.join(keys)}")


def _joint_array(where: str, value: Any, width: int, what: str) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise DataError(f"{where}: {what} is not a numeric array") from None
    if array.shape != (N_JOINTS, width):
        raise DataError(f"{where}: {what} has shape {array.shape}, expected ({N_JOINTS}, {width})")
    bad = ~np.isfinite(array).all(axis=1)
    if bad.any():
        joint = int(np.argmax(bad))
        raise DataError(f"{where}: {what} of joint {joint} ({JOINT_NAMES[joint]}) is not finite: {array[joint]}")
    return array


JSON_CONFIDENCE_KEYS = ("joint_confidences", "joint_confidence_levels", "confidence_levels", "joint_confidence")
"""Per-body keys holding 32 per-joint confidence levels, as tools that extend the offline_processor output
write them (numbers 0-3, enum names or the SDK header's sentences); the first one present is used."""


def _json_confidence(where: str, value: Any) -> np.ndarray:
    if not isinstance(value, list) or len(value) != N_JOINTS:
        count = len(value) if isinstance(value, list) else type(value).__name__
        raise DataError(f"{where}: the per-joint confidence holds {count} entries, expected {N_JOINTS} (one per joint)")
    out = np.empty(N_JOINTS, dtype=np.uint8)
    for joint, item in enumerate(value):
        level = parse_confidence(str(item)) if isinstance(item, int | str) and not isinstance(item, bool) else None
        if level is None:
            raise DataError(
                f"{where}: confidence of joint {joint} ({JOINT_NAMES[joint]}) is {item!r}; expected 0-3 "
                "(NONE, LOW, MEDIUM, HIGH), an enum name or the SDK header's sentence"
            )
        out[joint] = int(level)
    return out


def load_offline_processor_json(
    path: str | Path,
    *,
    sensor_id: str | None = None,
    confidence: Confidence = OFFLINE_PROCESSOR_CONFIDENCE,
    assume_confidence: str | None = None,
) -> Recording:
    """Read the JSON the Body Tracking SDK's offline_processor sample writes.

    Root keys ``k4abt_sdk_version``, ``source_file``, ``joint_names`` (32), ``bone_list``, ``frames``; each
    frame ``timestamp_usec``, ``frame_id``, ``num_bodies``, ``bodies``; each body ``body_id``,
    ``joint_positions`` (32 x [x, y, z] mm), ``joint_orientations`` (32 x [w, x, y, z]).

    ``joint_names`` must name our 32 joints in SDK order (case-insensitive, with or without the
    ``K4ABT_JOINT_`` prefix; the docs' "SPINE_NAVAL" spelling is accepted). The sample stores no confidence:
    every joint gets ``confidence`` (default MEDIUM, see :data:`OFFLINE_PROCESSOR_CONFIDENCE`), or the
    level of ``assume_confidence`` (:data:`ASSUME_CONFIDENCE`), and the recording says it was assumed.
    Variants that add a per-joint confidence per body (:data:`JSON_CONFIDENCE_KEYS`) are read as they are;
    then every body must carry it.

    Raises
    ------
    DataError
        Missing file, invalid JSON, a missing key, joint names that differ from ours, a wrong joint count,
        ``num_bodies`` disagreeing with ``bodies``, or a non-finite value, naming the frame and body.
    """
    path = Path(path)
    if assume_confidence is not None:
        confidence = assumed_confidence_level(assume_confidence)
    root = _read_offline_processor_json(path)

    frames: list[list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]] = []
    times: list[int] = []
    confidence_key: str | None = None  # decided by the first body: every body must then carry it
    decided = False
    for frame_index, frame in enumerate(root["frames"]):
        where = f"{path}: frames[{frame_index}]"
        bodies, timestamp = _json_frame(where, frame)
        times.append(int(timestamp))
        parsed = []
        for body_index, body in enumerate(bodies):
            body_where = f"{where}.bodies[{body_index}]"
            _require_keys(body_where, body, _JSON_BODY_KEYS, "the body")
            if not isinstance(body["body_id"], int):
                raise DataError(f"{body_where}: body_id is {body['body_id']!r}, expected an integer")
            positions = _joint_array(body_where, body["joint_positions"], 3, "joint_positions")
            quats = _joint_array(body_where, body["joint_orientations"], 4, "joint_orientations")
            if not decided:
                confidence_key = next((k for k in JSON_CONFIDENCE_KEYS if k in body), None)
                decided = True
            if confidence_key is None:
                levels = np.full(N_JOINTS, int(confidence), dtype=np.uint8)
            elif confidence_key not in body:
                raise DataError(
                    f"{body_where}: lacks {confidence_key!r}, which the file's first body carries; every body "
                    "needs its per-joint confidence (or none has it)"
                )
            else:
                levels = _json_confidence(f"{body_where}.{confidence_key}", body[confidence_key])
            parsed.append((int(body["body_id"]), positions.astype(np.float32), quats.astype(np.float32), levels))
        frames.append(parsed)

    positions, orientations, conf, body_ids = _pad_bodies(frames)
    return Recording(
        sensor_id=sensor_id if sensor_id is not None else path.stem,
        positions=positions,
        orientations=orientations,
        confidence=conf,
        body_ids=body_ids,
        device_time_us=np.asarray(times, dtype=np.int64),
        source=str(path),
        confidence_assumed=None if confidence_key is not None else (assume_confidence or confidence.name.lower()),
        file_format="offline_processor",
    )


def _read_offline_processor_json(path: Path) -> dict[str, Any]:
    """The parsed root of an offline_processor JSON, its keys, joint names and frame list checked."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise DataError(f"{path}: no such file; expected an offline_processor JSON") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read as UTF-8 text: {exc}") from exc
    try:
        root = json.loads(text)
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}: invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None

    _require_keys(str(path), root, _JSON_ROOT_KEYS, "the root")
    names = root["joint_names"]
    if not isinstance(names, list) or len(names) != N_JOINTS:
        count = len(names) if isinstance(names, list) else type(names).__name__
        raise DataError(f"{path}: joint_names holds {count} entries, expected the {N_JOINTS} k4abt joints")
    for index, name in enumerate(names):
        if not isinstance(name, str) or _joint_name_key(name) != JOINT_NAMES[index]:
            raise DataError(
                f"{path}: joint_names[{index}] is {name!r}, expected {JOINT_NAMES[index]!r} (k4abt SDK joint order)"
            )
    if not isinstance(root["frames"], list):
        raise DataError(f"{path}: 'frames' must be a list, got {type(root['frames']).__name__}")
    return root


def _json_frame(where: str, frame: Any) -> tuple[list[Any], int | float]:
    """One frame's bodies and timestamp (µs), its keys and counts checked."""
    _require_keys(where, frame, _JSON_FRAME_KEYS, "the frame")
    bodies = frame["bodies"]
    if not isinstance(bodies, list):
        raise DataError(f"{where}: 'bodies' must be a list, got {type(bodies).__name__}")
    if frame["num_bodies"] != len(bodies):
        raise DataError(f"{where}: num_bodies is {frame['num_bodies']} but 'bodies' holds {len(bodies)}")
    timestamp = frame["timestamp_usec"]
    if not isinstance(timestamp, int | float) or not math.isfinite(timestamp):
        raise DataError(f"{where}: timestamp_usec is {timestamp!r}, expected a number of microseconds")
    return bodies, timestamp
