"""The one fused table (export/csv.py): written as CSV and Parquet, read back by the stdlib csv module and by
pyarrow (independent readers), and by our reader; optional orientation / uncertainty columns; bad tables."""

from __future__ import annotations

import csv
import dataclasses
import math
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from skelfuse.export.csv import FUSED_COLUMNS, read_fused_table, write_fused
from skelfuse.schema.errors import DataError
from skelfuse.schema.frames import FusedFrame
from skelfuse.schema.skeleton import JOINT_NAMES, N_JOINTS

SEED = 20240612
SENSORS = ("000111", "000222", "000333")


def fused_frames() -> list[FusedFrame]:
    rng = np.random.default_rng(SEED)
    out = []
    for t, persons in [(1000, 1), (2000, 0), (3000, 2)]:
        positions = rng.normal(0, 1000, (persons, N_JOINTS, 3))
        if persons:
            positions[0, 5] = np.nan
        out.append(
            FusedFrame(
                time_us=t,
                track_ids=np.arange(1, persons + 1, dtype=np.int64) * 7,
                positions=positions,
                n_agree=rng.integers(0, 4, (persons, N_JOINTS)).astype(np.int16),
                confidence=rng.integers(0, 4, (persons, N_JOINTS)).astype(np.uint8),
                contributors=np.ones((persons, 3), bool),
                sensor_ids=SENSORS,
            )
        )
    return out


def with_orientations(frame: FusedFrame) -> FusedFrame:
    """The frame with its optional fields filled: unit quaternions w,x,y,z with one unknown joint, and a
    per-joint one-sigma position uncertainty."""
    rng = np.random.default_rng([SEED, frame.time_us])
    q = rng.normal(size=(frame.n_persons, N_JOINTS, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    if frame.n_persons:
        q[0, 3] = np.nan
    std = rng.uniform(2, 40, (frame.n_persons, N_JOINTS))
    return dataclasses.replace(frame, orientations=q, position_std=std)


def expected_rows(frames: list) -> list[tuple]:
    rows = []
    for f in frames:
        q = getattr(f, "orientations", None)
        std = getattr(f, "position_std", None)
        for p in range(f.n_persons):
            for j in range(N_JOINTS):
                quat = [math.nan] * 4 if q is None else q[p, j].tolist()
                rows.append(
                    (
                        f.time_us,
                        int(f.track_ids[p]),
                        j,
                        JOINT_NAMES[j],
                        *f.positions[p, j].tolist(),
                        int(f.n_agree[p, j]),
                        int(f.confidence[p, j]),
                        *quat,
                        math.nan if std is None else float(std[p, j]),
                    )
                )
    return rows


FLOAT_AT = (4, 5, 6, 9, 10, 11, 12, 13)


def same_rows(got: list[tuple], expected: list[tuple]) -> None:
    assert len(got) == len(expected)
    for g, e in zip(got, expected, strict=True):
        for k, (a, b) in enumerate(zip(g, e, strict=True)):
            if k in FLOAT_AT:
                assert (a is None and math.isnan(b)) or a == b, (k, a, b)  # exact: floats written with repr
            else:
                assert a == b, (k, a, b)


def read_with_stdlib(path: Path) -> tuple[list[str], list[tuple]]:
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    parsed = []
    for r in rows[1:]:
        cells: list = [int(r[0]), int(r[1]), int(r[2]), r[3]]
        cells += [None if v == "" else float(v) for v in r[4:7]]
        cells += [int(r[7]), int(r[8])]
        cells += [None if v == "" else float(v) for v in r[9:14]]
        parsed.append(tuple(cells))
    return rows[0], parsed


@pytest.mark.parametrize("orient", [False, True], ids=["positions only", "with orientations"])
def test_csv_layout_read_by_the_stdlib(tmp_path: Path, orient: bool) -> None:
    frames = [with_orientations(f) if orient else f for f in fused_frames()]
    path = tmp_path / "fused.csv"
    assert write_fused(iter(frames), path) == 3 * N_JOINTS
    header, rows = read_with_stdlib(path)
    assert tuple(header) == FUSED_COLUMNS
    same_rows(rows, expected_rows(frames))


@pytest.mark.parametrize("orient", [False, True], ids=["positions only", "with orientations"])
def test_parquet_layout_read_by_pyarrow(tmp_path: Path, orient: bool) -> None:
    frames = [with_orientations(f) if orient else f for f in fused_frames()]
    path = tmp_path / "fused.parquet"
    assert write_fused(frames, path) == 3 * N_JOINTS
    table = pq.read_table(path)
    assert tuple(table.column_names) == FUSED_COLUMNS
    columns = [table.column(name).to_pylist() for name in FUSED_COLUMNS]
    same_rows(list(zip(*columns, strict=True)), expected_rows(frames))


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_reader_gives_back_the_frames(tmp_path: Path, suffix: str) -> None:
    frames = fused_frames()
    path = tmp_path / f"fused{suffix}"
    write_fused(frames, path)
    back = list(read_fused_table(path))
    with_people = [f for f in frames if f.n_persons]  # an instant with nobody writes no row
    assert [f.time_us for f in back] == [f.time_us for f in with_people]
    for got, want in zip(back, with_people, strict=True):
        np.testing.assert_array_equal(got.track_ids, want.track_ids)
        np.testing.assert_array_equal(got.positions, want.positions)
        np.testing.assert_array_equal(got.n_agree, want.n_agree)
        np.testing.assert_array_equal(got.confidence, want.confidence)
        assert got.contributors.shape == (want.n_persons, 0)
        assert getattr(got, "orientations", None) is None  # none were written


def test_reader_accepts_rows_in_any_order_and_missing_joints(tmp_path: Path) -> None:
    path = tmp_path / "hand.csv"
    path.write_text(
        ",".join(FUSED_COLUMNS[:9])
        + "\n"
        + "2000,4,1,SPINE_NAVEL,1.0,2.0,3.0,2,2\n"
        + "1000,9,0,PELVIS,,,,0,0\n"
        + "2000,3,0,PELVIS,10.5,-2.25,900.0,3,2\n",
        encoding="utf-8",
    )
    f1, f2 = read_fused_table(path)
    assert f1.time_us == 1000 and f1.track_ids.tolist() == [9] and np.isnan(f1.positions).all()
    assert f2.track_ids.tolist() == [3, 4]
    np.testing.assert_array_equal(f2.positions[0, 0], [10.5, -2.25, 900.0])
    np.testing.assert_array_equal(f2.positions[1, 1], [1.0, 2.0, 3.0])
    assert np.isnan(f2.positions[0, 1:]).all() and np.isnan(f2.positions[1, [0, *range(2, 32)]]).all()
    assert f2.n_agree[0, 0] == 3 and f2.n_agree[1, 1] == 2


def test_bad_tables_raise_data_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"\.csv, \.parquet"):
        write_fused(fused_frames(), tmp_path / "fused.json")
    assert not (tmp_path / "fused.json").exists()
    with pytest.raises(DataError, match="not found"):
        read_fused_table(tmp_path / "absent.csv")
    other = tmp_path / "other.csv"
    other.write_text("a,b,c\n1,2,3\n", encoding="utf-8")
    with pytest.raises(DataError, match="lacks the column"):
        read_fused_table(other)
    bad = tmp_path / "bad.csv"
    bad.write_text(",".join(FUSED_COLUMNS[:9]) + "\n1000,1,40,X,1,2,3,1,2\n", encoding="utf-8")
    with pytest.raises(DataError, match="joint index"):
        read_fused_table(bad)
    text = tmp_path / "text.csv"
    text.write_text(",".join(FUSED_COLUMNS[:9]) + "\n1000,1,0,PELVIS,one,2,3,1,2\n", encoding="utf-8")
    with pytest.raises(DataError, match="not a number"):
        read_fused_table(text)
