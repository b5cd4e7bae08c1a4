"""``skelfuse export``: C3D read back by ezc3d AND the independent ``c3d`` package, TRC read by OpenSim's own
TRCFileAdapter (and checked line by line against the format), CSV from every kind of input, bad inputs.

The take is built by hand so every value, gap and time is known: two people, one arriving later, an instant
dropped (a grid slot no instant fell on), a joint without estimate, ~30 Hz device timestamps.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import c3d
import ezc3d
import numpy as np
import pytest

from skelfuse.bench.latency import synthetic_frames
from skelfuse.cli import main
from skelfuse.export.csv import read_fused_table, write_fused
from skelfuse.export.tracks import take_tracks
from skelfuse.export.trc import HEADER_KEYS
from skelfuse.recording import RecordingWriter, fuse_recording
from skelfuse.schema.frames import FusedFrame
from skelfuse.schema.skeleton import JOINT_NAMES, N_JOINTS
from skelfuse.sim.rig import paper_rig

T0_US = 7_000_000
STEP_US = 33_333  # a k4a 30 fps device clock
N_INSTANTS = 40
DROPPED = 12  # no instant at this grid slot
LATE = 20  # track 8 appears from this instant
NAN_JOINT = (5, 9)  # (instant, joint) of track 3 without an estimate
SENSORS = ("s0", "s1")


def truth(track: int, i: int) -> np.ndarray:
    """Known positions of a track at instant i (mm), distinct per joint, axis and frame."""
    joints = np.arange(N_JOINTS)[:, None]
    axes = np.arange(3)[None, :]
    return 1000.0 * track + 10.0 * joints + 0.25 * axes + 1.5 * i - 500.0


def take() -> list[FusedFrame]:
    frames = []
    for i in range(N_INSTANTS):
        if i == DROPPED:
            continue
        tracks = [3] if i < LATE else [3, 8]
        positions = np.stack([truth(t, i) for t in tracks])
        if i == NAN_JOINT[0]:
            positions[0, NAN_JOINT[1]] = np.nan
        p = len(tracks)
        frames.append(
            FusedFrame(
                time_us=T0_US + i * STEP_US + (i % 3),  # a little jitter, as device clocks have
                track_ids=np.array(tracks, np.int64),
                positions=positions,
                n_agree=np.full((p, N_JOINTS), 2, np.int16),
                confidence=np.full((p, N_JOINTS), 2, np.uint8),
                contributors=np.ones((p, 2), bool),
                sensor_ids=SENSORS,
            )
        )
    return frames


@pytest.fixture
def fused_csv(tmp_path: Path) -> Path:
    path = tmp_path / "take.csv"
    write_fused(take(), path)
    return path


def export(*args: str, capsys: pytest.CaptureFixture[str] | None = None) -> dict:
    code = main(["export", *args, "--json"])
    assert code == 0
    return json.loads(capsys.readouterr().out) if capsys is not None else {}


def expected_person(track: int) -> tuple[int, np.ndarray]:
    """(first grid frame, (T, 32, 3) positions with NaN gaps) of a track on the 30 Hz grid."""
    first = 0 if track == 3 else LATE
    out = np.stack([truth(track, i) for i in range(first, N_INSTANTS)])
    out[DROPPED - first] = np.nan if first <= DROPPED else out[DROPPED - first]
    if track == 3:
        out[NAN_JOINT[0], NAN_JOINT[1]] = np.nan
    return first, out


def test_tracks_on_the_grid() -> None:
    tracks = take_tracks(take())
    assert tracks.rate_hz == pytest.approx(1e6 / STEP_US, rel=1e-4)
    assert tracks.n_frames == N_INSTANTS and tracks.instants == N_INSTANTS - 1 and tracks.collisions == 0
    assert [p.track_id for p in tracks.persons] == [3, 8]
    for person in tracks.persons:
        first, positions = expected_person(person.track_id)
        assert person.first_frame == first
        np.testing.assert_array_equal(person.positions, positions)


def test_c3d_read_back_by_ezc3d_and_by_c3d(tmp_path: Path, fused_csv: Path, capsys) -> None:
    summary = export(str(fused_csv), "--format", "c3d", "--output", str(tmp_path / "out.c3d"), capsys=capsys)
    files = [Path(f) for f in summary["files"]]
    assert [f.name for f in files] == ["out_track3.c3d", "out_track8.c3d"]
    assert summary["rate_hz"] == pytest.approx(1e6 / STEP_US, rel=1e-4)
    for track, path in zip((3, 8), files, strict=True):
        first, positions = expected_person(track)
        gaps = np.isnan(positions).any(axis=-1)  # (T, 32)

        # ezc3d (C++ implementation)
        data = ezc3d.c3d(str(path))
        point = data["parameters"]["POINT"]
        assert list(point["LABELS"]["value"]) == list(JOINT_NAMES)
        assert list(point["UNITS"]["value"]) == ["mm"]
        assert point["RATE"]["value"][0] == pytest.approx(1e6 / STEP_US, rel=1e-4)
        assert data["header"]["points"]["first_frame"] == first
        xyz = data["data"]["points"][:3]  # (3, 32, T)
        np.testing.assert_allclose(np.transpose(xyz, (2, 1, 0)), positions, rtol=0, atol=1e-3)  # float32 in file
        residuals = data["data"]["meta_points"]["residuals"][0].T  # (T, 32)
        np.testing.assert_array_equal(residuals == -1, gaps)
        assert data["parameters"]["SKELFUSE"]["TRACK_ID"]["value"] == [str(track)]

        # c3d (pure Python, an independent reader of the same file)
        with open(path, "rb") as handle, warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "no analog data": we write none
            reader = c3d.Reader(handle)
            assert [label.strip() for label in reader.point_labels] == list(JOINT_NAMES)
            assert reader.point_rate == pytest.approx(1e6 / STEP_US, rel=1e-4)
            assert reader.first_frame == first + 1  # 1-based in the header
            assert reader.get("POINT:UNITS").string_value.strip() == "mm"
            frames = [(index, points.copy()) for index, points, _ in reader.read_frames()]
        assert [index for index, _ in frames] == list(range(first + 1, first + 1 + len(positions)))
        values = np.stack([p[:, :3] for _, p in frames])  # (T, 32, 3)
        residual = np.stack([p[:, 3] for _, p in frames])
        np.testing.assert_array_equal(residual == -1, gaps)
        np.testing.assert_allclose(values[~gaps], positions[~gaps], rtol=0, atol=1e-3)


OPENSIM_MISSING = "OpenSim's TRC reader: the optional extra `opensim` is not installed (pip install -e '.[opensim]')"


def osim_table(path: Path):
    osim = pytest.importorskip("opensim", reason=OPENSIM_MISSING)
    return osim, osim.TimeSeriesTableVec3(str(path))


def test_trc_read_by_opensim(tmp_path: Path, fused_csv: Path, capsys) -> None:
    pytest.importorskip("opensim", reason=OPENSIM_MISSING)
    summary = export(str(fused_csv), "--format", "trc", "--output", str(tmp_path / "out.trc"), capsys=capsys)
    rate = summary["rate_hz"]  # from the timestamps: 1e6 / the median step
    assert rate == pytest.approx(1e6 / STEP_US, rel=1e-4)
    for track, path in zip((3, 8), map(Path, summary["files"]), strict=True):
        first, positions = expected_person(track)
        osim, table = osim_table(path)
        assert table.getNumRows() == len(positions)
        assert list(table.getColumnLabels()) == list(JOINT_NAMES)
        assert table.getTableMetaDataAsString("Units") == "mm"
        assert float(table.getTableMetaDataAsString("DataRate")) == pytest.approx(rate, rel=1e-4)
        times = np.array(table.getIndependentColumn())
        np.testing.assert_allclose(times, (first + np.arange(len(positions))) / rate, atol=1e-6)
        got = np.array(
            [
                [[row[j][k] for k in range(3)] for j in range(N_JOINTS)]
                for row in map(table.getRowAtIndex, range(len(positions)))
            ]
        )
        # OpenSim's axes: (X, Y, Z) = (x, z, -y)
        expected = np.stack([positions[..., 0], positions[..., 2], -positions[..., 1]], axis=-1)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-4, equal_nan=True)
        # The older reader OpenSim's tools use (MarkerData) agrees on frames, rate and units.
        markers = osim.MarkerData(str(path))
        assert markers.getNumFrames() == len(positions)
        assert markers.getDataRate() == pytest.approx(rate, rel=1e-4)
        assert markers.getUnits().getAbbreviation() == "mm"


@pytest.mark.parametrize("track", [3, 8], ids=["with-gap-row", "arriving-late"])
def test_trc_layout_line_by_line(tmp_path: Path, fused_csv: Path, track: int) -> None:
    """The layout OpenSim's documentation gives for .trc files, without OpenSim."""
    out = tmp_path / "p.trc"
    export(str(fused_csv), "--format", "trc", "--person", str(track), "--output", str(out), "--world-axes")
    lines = out.read_text(encoding="utf-8").split("\n")
    assert lines[0].split("\t") == ["PathFileType", "4", "(X/Y/Z)", "p.trc"]
    assert tuple(lines[1].split("\t")) == HEADER_KEYS
    values = dict(zip(HEADER_KEYS, lines[2].split("\t"), strict=True))
    first, positions = expected_person(track)
    assert float(values["DataRate"]) == float(values["CameraRate"]) == float(values["OrigDataRate"])
    assert int(values["NumFrames"]) == len(positions) and int(values["NumMarkers"]) == N_JOINTS
    assert values["Units"] == "mm" and values["OrigDataStartFrame"] == "1"
    assert int(values["OrigNumFrames"]) == N_INSTANTS
    names = lines[3].split("\t")
    assert names[:2] == ["Frame#", "Time"] and names[2::3] == list(JOINT_NAMES)
    assert all(cell == "" for k, cell in enumerate(names[2:]) if k % 3)
    assert lines[4].split("\t") == ["", "", *(f"{a}{j + 1}" for j in range(N_JOINTS) for a in "XYZ")]
    assert lines[5] == ""
    rows = [line.split("\t") for line in lines[6:] if line]
    assert len(rows) == len(positions)
    for k, row in enumerate(rows):
        assert int(row[0]) == first + k + 1
        cells = row[2 : 2 + 3 * N_JOINTS]
        got = np.array([np.nan if c == "" else float(c) for c in cells]).reshape(N_JOINTS, 3)
        np.testing.assert_allclose(got, positions[k], atol=1e-4, equal_nan=True)  # --world-axes: z up as fused
    if first > DROPPED:
        assert track == 8  # it arrives after the dropped slot: no gap row in its file
        return
    # The dropped slot is a row of its own, with its frame number and time and no marker value.
    gap_row = rows[DROPPED - first]
    assert int(gap_row[0]) == DROPPED + 1 and float(gap_row[1]) == pytest.approx(DROPPED * STEP_US / 1e6, abs=1e-3)
    assert gap_row[2 : 2 + 3 * N_JOINTS] == [""] * (3 * N_JOINTS)
    nan_row = rows[NAN_JOINT[0] - first]  # one joint without an estimate: only its three cells are empty
    empty = [k // 3 for k, cell in enumerate(nan_row[2 : 2 + 3 * N_JOINTS]) if cell == ""]
    assert empty == [NAN_JOINT[1]] * 3


def test_csv_export_from_a_fused_recording_and_a_sensor_recording(tmp_path: Path, capsys) -> None:
    """A recording's fused stream is exported as recorded; a sensor recording is fused on the way."""
    frames = take()
    rig = paper_rig(2)
    poses = {s.sensor_id: s.world_from_sensor for s in rig}
    path = tmp_path / "take.mcap"
    with RecordingWriter(path, rig="lab", sensor_ids=list(poses), world_from_sensor=poses) as writer:
        for i, instant in enumerate(synthetic_frames(2, 30)):
            for frame in instant:
                writer.write(
                    type(frame)(
                        frame.sensor_id,
                        i,
                        T0_US + i * STEP_US,
                        1_700_000_000_000_000_000 + i * 33_333_333,
                        frame.body_ids,
                        frame.positions,
                        frame.orientations,
                        frame.confidence,
                    )
                )
    # 1. sensor frames only: fused on the way, as fuse --input would
    summary = export(str(path), "--format", "csv", "--output", str(tmp_path / "a.csv"), capsys=capsys)
    assert summary["source"] == "fused from the sensor frames"
    expected = tmp_path / "expected.csv"
    write_fused(fuse_recording(path, progress=False), expected)
    assert (tmp_path / "a.csv").read_bytes() == expected.read_bytes()

    # 2. with a recorded fused stream: that stream, not a new fusion (unless --fuse)
    with_fused = tmp_path / "with_fused.mcap"
    with RecordingWriter(with_fused, rig="lab", sensor_ids=list(poses), world_from_sensor=poses) as writer:
        for i, frame in enumerate(frames):
            writer.write_fused(frame, log_time_ns=1_700_000_000_000_000_000 + i)
    summary = export(str(with_fused), "--format", "csv", "--output", str(tmp_path / "b.csv"), capsys=capsys)
    assert summary["source"] == "recorded fused stream"
    back = list(read_fused_table(tmp_path / "b.csv"))
    assert [f.time_us for f in back] == [f.time_us for f in frames]
    for got, want in zip(back, frames, strict=True):
        np.testing.assert_array_equal(got.positions, want.positions)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["missing.csv", "--format", "c3d"], "not found"),
        (["{bad}", "--format", "trc"], "unknown extension"),
        (["{csv}", "--format", "c3d", "--person", "99"], "track id 99 is not in the take"),
        (["{csv}", "--format", "csv", "--rate", "30"], "--rate applies"),
        (["{csv}", "--format", "c3d", "--output", "{tmp}/x.trc"], "writes .c3d files"),
        (["{csv}", "--format", "csv"], "is the input file"),
        (["{csv}", "--format", "trc", "--min-frames", "1000"], "lower --min-frames"),
        (["{empty}", "--format", "c3d"], "holds no fused instant"),
    ],
)
def test_bad_inputs_get_clear_errors(tmp_path: Path, fused_csv: Path, capsys, args: list[str], message: str) -> None:
    bad = tmp_path / "take.json"
    bad.write_text("{}", encoding="utf-8")
    empty = tmp_path / "empty.csv"
    write_fused([], empty)
    args = [a.format(csv=fused_csv, bad=bad, tmp=tmp_path, empty=empty) for a in args]
    assert main(["export", *args]) == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(
    ("rate_hz", "span_s", "expected"),
    [
        (30.0003, 20.0, 30.0),  # a device clock's 33333/33334 us steps over a 20 s take: drift 0.006 frames
        (30.0003, 3600.0, 30.0003),  # over an hour the same difference drifts a whole frame: kept as measured
        (29.97, 10.0, 29.97),  # NTSC's rate is not 30
        (14.9995, 60.0, 15.0),
    ],
)
def test_a_measured_rate_snaps_to_the_nominal_one_only_where_it_cannot_drift(
    rate_hz: float, span_s: float, expected: float
) -> None:
    from skelfuse.export.tracks import nominal_rate_hz

    assert nominal_rate_hz(rate_hz, span_s) == expected
