"""The one fused-skeleton table: one row per person x joint x instant, as CSV or Parquet, and its reader.

Every tabular output of fused skeletons uses this layout: ``skelfuse fuse --input REC --output OUT.csv``,
``skelfuse export FUSED --format csv``, and whatever reads fused tables back (:func:`read_fused_table`). The
columns are fixed (:data:`FUSED_COLUMNS`, documented in ``docs/export.md``): a frame that carries no fused
orientation or position uncertainty (``FusedFrame.orientations`` / ``position_std`` absent or None) leaves
those cells empty (CSV) or null (Parquet), so a reader never has to guess which layout it holds.

Floats are written with Python's shortest round-trip ``repr``: reading a CSV back gives the same float64.
"""

from __future__ import annotations

import csv
import dataclasses
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.progress import Progress
from skelfuse.schema.errors import DataError
from skelfuse.schema.frames import FusedFrame
from skelfuse.schema.skeleton import JOINT_NAMES, N_JOINTS

__all__ = ["FUSED_COLUMNS", "FUSED_FORMATS", "read_fused_table", "write_fused"]

FUSED_COLUMNS = (
    "time_us",
    "track_id",
    "joint",
    "joint_name",
    "x_mm",
    "y_mm",
    "z_mm",
    "n_agree",
    "confidence",
    "qw",
    "qx",
    "qy",
    "qz",
    "position_std_mm",
)
"""Columns of the fused table, in order (meaning and units in ``docs/export.md``)."""
FUSED_FORMATS = (".csv", ".parquet")
"""File extensions of the fused table."""
REQUIRED_COLUMNS = FUSED_COLUMNS[:9]
"""Columns a fused table must hold to be read (the orientation and uncertainty columns may be absent)."""

_ORIENTATION_COLUMNS = ("qw", "qx", "qy", "qz")
_FLOAT_COLUMNS = ("x_mm", "y_mm", "z_mm", *_ORIENTATION_COLUMNS, "position_std_mm")


def _optional(frame: Any, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """``frame.<name>`` as float64 of ``shape``; all NaN when the frame does not carry it (None or absent)."""
    value = getattr(frame, name, None)
    if value is None:
        return np.full(shape, np.nan)
    array = np.asarray(value, dtype=np.float64)
    if array.shape != shape:
        raise ValueError(f"FusedFrame.{name} has shape {array.shape}, expected {shape}")
    return array


def frame_columns(frame: FusedFrame) -> dict[str, np.ndarray]:
    """The table's columns for one frame (P x 32 rows, person-major), as numpy arrays keyed by column name."""
    n = frame.n_persons
    rows = n * N_JOINTS
    xyz = np.asarray(frame.positions, np.float64).reshape(rows, 3)
    quat = _optional(frame, "orientations", (n, N_JOINTS, 4)).reshape(rows, 4)
    std = _optional(frame, "position_std", (n, N_JOINTS)).reshape(rows)
    joints = np.tile(np.arange(N_JOINTS, dtype=np.int16), n)
    return {
        "time_us": np.full(rows, int(frame.time_us), np.int64),
        "track_id": np.repeat(np.asarray(frame.track_ids, np.int64), N_JOINTS),
        "joint": joints,
        "joint_name": np.asarray(JOINT_NAMES, dtype=object)[joints],
        "x_mm": xyz[:, 0],
        "y_mm": xyz[:, 1],
        "z_mm": xyz[:, 2],
        "n_agree": np.asarray(frame.n_agree, np.int16).reshape(rows),
        "confidence": np.asarray(frame.confidence, np.uint8).reshape(rows),
        "qw": quat[:, 0],
        "qx": quat[:, 1],
        "qy": quat[:, 2],
        "qz": quat[:, 3],
        "position_std_mm": std,
    }


def write_fused(
    frames: Iterable[FusedFrame], output_path: str | os.PathLike[str], *, progress: Progress | None = None
) -> int:
    """Write fused frames as the fused table; the format follows the extension (``.csv`` or ``.parquet``).

    Parameters
    ----------
    frames : iterable of FusedFrame
        Instants with no person produce no rows.
    output_path : str or Path
        ``.csv`` (UTF-8, header row, comma separated, missing values empty) or ``.parquet`` (needs pyarrow;
        missing values null).
    progress : Progress, optional
        Advanced by one per frame.

    Returns
    -------
    int
        Rows written.

    Raises
    ------
    ValueError
        The extension is not one of :data:`FUSED_FORMATS`.
    """
    path = Path(output_path)
    suffix = path.suffix.lower()
    if suffix not in FUSED_FORMATS:
        raise ValueError(
            f"cannot write fused frames to {path}: unknown extension {path.suffix!r}; "
            f"supported: {', '.join(FUSED_FORMATS)}"
        )
    if suffix == ".csv":
        return _write_csv(frames, path, progress)
    return _write_parquet(frames, path, progress)


def _cell(value: Any) -> Any:
    if isinstance(value, float):
        return "" if value != value else repr(value)  # NaN -> empty
    return value


def _write_csv(frames: Iterable[FusedFrame], path: Path, progress: Progress | None) -> int:
    n = 0
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(FUSED_COLUMNS)
        for frame in frames:
            if progress is not None:
                progress.update()
            if not frame.n_persons:
                continue
            columns = frame_columns(frame)
            lists = [columns[name].tolist() for name in FUSED_COLUMNS]
            writer.writerows([[_cell(v) for v in row] for row in zip(*lists, strict=True)])
            n += len(lists[0])
    return n


def _parquet_schema() -> Any:
    import pyarrow as pa

    types = {"time_us": pa.int64(), "track_id": pa.int64(), "joint": pa.int16(), "joint_name": pa.string()}
    types |= {"n_agree": pa.int16(), "confidence": pa.uint8()}
    return pa.schema([(name, types.get(name, pa.float64())) for name in FUSED_COLUMNS])


def _write_parquet(
    frames: Iterable[FusedFrame], path: Path, progress: Progress | None, batch_frames: int = 1000
) -> int:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError as exc:
        raise ModuleNotFoundError("writing .parquet needs pyarrow (pip install pyarrow); or write .csv") from exc
    schema = _parquet_schema()
    n = 0
    pending: list[dict[str, np.ndarray]] = []

    def flush(writer: Any) -> int:
        if not pending:
            return 0
        arrays = []
        for name in FUSED_COLUMNS:
            values = np.concatenate([p[name] for p in pending])
            if name == "joint_name":
                arrays.append(pa.array(values.tolist(), pa.string()))
            elif name in _FLOAT_COLUMNS:
                arrays.append(pa.array(values, mask=np.isnan(values)))
            else:
                arrays.append(pa.array(values, schema.field(name).type))
        table = pa.Table.from_arrays(arrays, schema=schema)
        writer.write_table(table)
        pending.clear()
        return table.num_rows

    with pq.ParquetWriter(path, schema) as writer:
        for frame in frames:
            if progress is not None:
                progress.update()
            if frame.n_persons:
                pending.append(frame_columns(frame))
            if len(pending) >= batch_frames:
                n += flush(writer)
        n += flush(writer)
    return n


# --------------------------------------------------------------------------------------------------------
# Reading


def _read_columns(path: Path) -> dict[str, np.ndarray]:
    """Every column of a fused table as numpy arrays (floats NaN where empty / null)."""
    suffix = path.suffix.lower()
    if suffix == ".parquet":
        try:
            import pyarrow.parquet as pq
        except ImportError as exc:
            raise ModuleNotFoundError("reading .parquet needs pyarrow (pip install pyarrow)") from exc
        try:
            table = pq.read_table(path)
        except Exception as exc:  # pyarrow raises ArrowInvalid and friends for a damaged file
            raise DataError(f"{path} is not a readable Parquet file: {exc}") from None
        header = list(table.column_names)
        raw = {name: table.column(name).to_numpy(zero_copy_only=False) for name in header}
    else:
        with open(path, newline="", encoding="utf-8") as f:
            reader = csv.reader(f)
            header = next(reader, [])
            cells = list(reader)
        bad = [i + 2 for i, row in enumerate(cells) if len(row) != len(header)]
        if bad:
            raise DataError(f"{path}: line {bad[0]} has a different number of cells than the header row")
        raw = {name: np.asarray([row[i] for row in cells], dtype=object) for i, name in enumerate(header)}
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:
        raise DataError(
            f"{path} is not a skelfuse fused table: it lacks the column(s) {', '.join(missing)} "
            f"(expected {', '.join(FUSED_COLUMNS)}; written by `skelfuse fuse --output` or `skelfuse export --format "
            f"csv`, see docs/export.md)"
        )
    out: dict[str, np.ndarray] = {}
    try:
        for name in FUSED_COLUMNS:
            if name == "joint_name":
                continue
            values = raw.get(name)
            if name in _FLOAT_COLUMNS:
                if values is None:
                    out[name] = np.full(len(raw["time_us"]), np.nan)
                else:
                    out[name] = np.asarray([np.nan if v in ("", None) else float(v) for v in values], np.float64)
            else:
                out[name] = np.asarray([int(v) for v in values], np.int64)  # type: ignore[union-attr]  # None: the TypeError below names the missing column
    except (TypeError, ValueError) as exc:
        raise DataError(f"{path}: a cell of the fused table is not a number: {exc}") from None
    return out


def read_fused_table(path: str | os.PathLike[str]) -> Iterator[FusedFrame]:
    """Fused frames from a fused table (CSV or Parquet, the layout of :func:`write_fused`), in time order.

    Rows are grouped into one frame per ``time_us`` and one person per ``track_id`` (ascending); joints a
    person has no row for are NaN. ``contributors`` is not in the table: frames come back with no sensor
    columns (``sensor_ids`` empty). ``orientations`` / ``position_std`` are filled where the FusedFrame type
    has those fields and the table holds values.

    Raises
    ------
    DataError
        The file is missing, is not a fused table (columns), or holds a cell that is not a number, a joint
        outside 0..31 or a confidence outside 0..3.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"fused table {path} not found (or not a file); check the path")
    if path.suffix.lower() not in FUSED_FORMATS:
        raise DataError(f"{path}: a fused table is .csv or .parquet, got {path.suffix!r}")
    cols = _read_columns(path)
    if len(cols["joint"]) and (cols["joint"].min() < 0 or cols["joint"].max() >= N_JOINTS):
        raise DataError(f"{path}: joint index outside 0..{N_JOINTS - 1}")
    if len(cols["confidence"]) and (cols["confidence"].min() < 0 or cols["confidence"].max() > 3):
        raise DataError(f"{path}: confidence outside 0..3")
    return _frames(cols)


def _frames(cols: dict[str, np.ndarray]) -> Iterator[FusedFrame]:
    fields = {f.name for f in dataclasses.fields(FusedFrame)}
    order = np.lexsort((cols["joint"], cols["track_id"], cols["time_us"]))
    times = cols["time_us"][order]
    if not len(times):
        return
    starts = np.flatnonzero(np.r_[True, times[1:] != times[:-1]])
    ends = np.r_[starts[1:], len(times)]
    for start, end in zip(starts, ends, strict=True):
        rows = order[start:end]
        tracks, person = np.unique(cols["track_id"][rows], return_inverse=True)
        joint = cols["joint"][rows]
        n = len(tracks)
        positions = np.full((n, N_JOINTS, 3), np.nan)
        positions[person, joint] = np.stack([cols["x_mm"][rows], cols["y_mm"][rows], cols["z_mm"][rows]], axis=1)
        n_agree = np.zeros((n, N_JOINTS), np.int16)
        n_agree[person, joint] = cols["n_agree"][rows]
        confidence = np.zeros((n, N_JOINTS), np.uint8)
        confidence[person, joint] = cols["confidence"][rows]
        extra: dict[str, np.ndarray] = {}
        quat = np.stack([cols[c][rows] for c in _ORIENTATION_COLUMNS], axis=1)
        if "orientations" in fields and not np.isnan(quat).all():
            extra["orientations"] = np.full((n, N_JOINTS, 4), np.nan)
            extra["orientations"][person, joint] = quat
        std = cols["position_std_mm"][rows]
        if "position_std" in fields and not np.isnan(std).all():
            extra["position_std"] = np.full((n, N_JOINTS), np.nan)
            extra["position_std"][person, joint] = std
        yield FusedFrame(
            time_us=int(times[start]),
            track_ids=tracks.astype(np.int64),
            positions=positions,
            n_agree=n_agree,
            confidence=confidence,
            contributors=np.zeros((n, 0), bool),
            sensor_ids=(),
            **extra,
        )
