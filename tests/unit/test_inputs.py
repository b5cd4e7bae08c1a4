"""The reader layer (every recorded format), ``skelfuse convert`` round trips, and time matching.

Fixtures are made here from the simulator: a 2-sensor walk whose master file starts 57 frames after the
subordinate's (as in a real two-sensor take whose files start at different instants), written in each format
by the format's own writer or by hand (offline_processor JSON, andyj1 CSV). Nothing is read from ../shared/data.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from skelfuse.calibration.skeleton import calibrate_from_skeletons
from skelfuse.calibration.takes import take_arrays
from skelfuse.cli import main
from skelfuse.recording.inputs import open_inputs, parse_time_offsets, write_mcap
from skelfuse.rig.motion_sync import band_pass, estimate_lag, motion_features
from skelfuse.schema.errors import DataError
from skelfuse.schema.skeleton import JOINT_NAMES, N_JOINTS, Confidence
from skelfuse.sim import load_profile, make_gesture, paper_rig, simulate
from skelfuse.sources.extractor_csv import load_extractor_csv, write_extractor_csv
from skelfuse.sources.formats import InputSpec, detect_format
from skelfuse.sources.long_csv import EXAMPLE, load_long_csv, write_long_csv
from skelfuse.sources.recorded import Recording

LATE_START = 57  # the master's file starts this many frames after the subordinate's


@pytest.fixture(scope="module")
def sim_walk():
    motion = make_gesture("walking", duration_s=10, seed=0, facing_deg=30)
    return simulate(motion, paper_rig(2), load_profile(), seed=0)


def _recordings(obs, *, late_start: int = LATE_START, quat: bool = True) -> list[Recording]:
    """One Recording per simulated sensor, the master starting ``late_start`` frames late; dropped frames out."""
    out = []
    rng = np.random.default_rng(1)
    for s, sensor_id in enumerate(obs.sensor_ids):
        keep = obs.device_time_us[:, s] >= 0
        keep[: late_start if s == 0 else 0] = False
        tracked = obs.tracked[keep, s].copy()
        tracked[100:104] = False  # the person left the view for four frames: frames without a body
        pos = np.where(tracked[:, None, None], obs.positions[keep, s], np.nan)[:, None].astype(np.float32)
        n = len(pos)
        q = rng.normal(size=(n, 1, N_JOINTS, 4)).astype(np.float32)
        q /= np.linalg.norm(q, axis=-1, keepdims=True)
        q = np.where(tracked[:, None, None, None], q, np.nan) if quat else np.full_like(q, np.nan)
        out.append(
            Recording(
                sensor_id=sensor_id,
                positions=pos,
                orientations=q.astype(np.float32),
                confidence=np.where(tracked[:, None], obs.confidence[keep, s], 0)[:, None].astype(np.uint8),
                body_ids=np.where(tracked, obs.body_ids[keep, s], -1)[:, None],
                device_time_us=obs.device_time_us[keep, s].astype(np.int64),
            )
        )
    return out


def write_offline_json(recording: Recording, path: Path, *, with_confidence: bool = False) -> Path:
    """The offline_processor sample's layout (optionally the variant with per-joint confidence)."""
    frames = []
    for t in range(recording.n_frames):
        bodies = []
        for b in np.nonzero(recording.body_ids[t] >= 0)[0]:
            body = {
                "body_id": int(recording.body_ids[t, b]),
                "joint_positions": recording.positions[t, b].astype(float).tolist(),
                "joint_orientations": recording.orientations[t, b].astype(float).tolist(),
            }
            if with_confidence:
                body["joint_confidences"] = recording.confidence[t, b].astype(int).tolist()
            bodies.append(body)
        frames.append(
            {
                "timestamp_usec": int(recording.device_time_us[t]),
                "frame_id": t,
                "num_bodies": len(bodies),
                "bodies": bodies,
            }
        )
    root = {
        "k4abt_sdk_version": "1.1.2",
        "source_file": f"{recording.sensor_id}.mkv",
        "joint_names": ["SPINE_NAVAL" if n == "SPINE_NAVEL" else n for n in JOINT_NAMES],
        "bone_list": [],
        "frames": frames,
    }
    path.write_text(json.dumps(root), encoding="utf-8")
    return path


_ANDYJ1_SENTENCE = {
    0: "The joint is out of range (too far from depth camera)",
    1: "The joint is not observed(likely due to occlusion) - predicted joint pose",
    2: "Medium confidence in joint pose",
    3: "High confidence in joint pose",
}


def write_andyj1(recording: Recording, path: Path) -> Path:
    """andyj1's layout: two header rows, 32 rows per body (frames without a body cannot be written); the
    quaternion in w, x, y, z order under a header that says x,y,z,w, as the real files have it."""
    lines = ["Joint positions and orientations", "Body ID,Joint #,x,y,z,x,y,z,w,Confidence Level"]
    for t in range(recording.n_frames):
        for b in np.nonzero(recording.body_ids[t] >= 0)[0]:
            for j in range(N_JOINTS):
                x, y, z = (repr(float(v)) for v in recording.positions[t, b, j])
                w, qx, qy, qz = (repr(float(v)) for v in recording.orientations[t, b, j])
                sentence = _ANDYJ1_SENTENCE[int(recording.confidence[t, b, j])]
                lines.append(f"{int(recording.body_ids[t, b])},{j},{x},{y},{z},{w},{qx},{qy},{qz},{sentence},")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _assert_same(a: Recording, b: Recording, *, times: bool = True, orientations: bool = True) -> None:
    assert a.sensor_id == b.sensor_id
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.confidence, b.confidence)
    np.testing.assert_array_equal(a.body_ids, b.body_ids)
    if orientations:
        np.testing.assert_array_equal(a.orientations, b.orientations)
    if times:
        np.testing.assert_array_equal(a.device_time_us, b.device_time_us)


def _convert(tmp_path: Path, *inputs: str, extra: tuple[str, ...] = ()) -> list[Recording]:
    out = tmp_path / "converted.mcap"
    assert main(["convert", *inputs, "-o", str(out), *extra]) == 0
    return list(open_inputs([str(out)]).recordings)


# ------------------------------------------------------------------------------------------ round trips


def test_offline_json_round_trips_through_convert(sim_walk, tmp_path: Path) -> None:
    recs = _recordings(sim_walk)
    paths = [write_offline_json(r, tmp_path / f"{r.sensor_id}.json", with_confidence=True) for r in recs]
    back = _convert(tmp_path, *(f"{r.sensor_id}={p}" for r, p in zip(recs, paths, strict=True)))
    for original, converted in zip(recs, back, strict=True):
        _assert_same(original, converted)


def test_json_without_confidence_says_what_it_assumed(sim_walk, tmp_path: Path, capsys) -> None:
    rec = _recordings(sim_walk)[0]
    path = write_offline_json(rec, tmp_path / "m.json")
    take = open_inputs([str(path)], assume_confidence="low")
    present = take.recordings[0].body_ids >= 0
    assert (take.recordings[0].confidence[present] == Confidence.LOW).all()
    assert take.confidence_unknown and any("assumed low" in n and "meaningless" in n for n in take.notes)
    # the assumption travels with the conversion, so later readers still know
    out = tmp_path / "m.mcap"
    assert main(["convert", str(path), "-o", str(out), "--assume-confidence", "unknown"]) == 0
    assert "assumed unknown" in capsys.readouterr().err
    assert open_inputs([str(out)]).recordings[0].confidence_assumed == "unknown"


def test_extractor_csv_round_trips_and_joins_by_timestamp_and_body(sim_walk, tmp_path: Path) -> None:
    recs = _recordings(sim_walk)
    folders = []
    for r in recs:
        write_extractor_csv(r, tmp_path / r.sensor_id / "skeleton")
        folders.append(str(tmp_path / r.sensor_id))
    read = [load_extractor_csv(f) for f in folders]
    for original, got in zip(recs, read, strict=True):
        # the tool prints 6 decimals: exact to that precision
        np.testing.assert_allclose(got.positions, original.positions, atol=5e-7 * 4096, equal_nan=True)
        np.testing.assert_array_equal(got.confidence, original.confidence)
        np.testing.assert_array_equal(got.body_ids, original.body_ids)
        np.testing.assert_array_equal(got.device_time_us, original.device_time_us)
        assert np.isnan(got.positions[original.body_ids[:, 0] < 0]).all()  # the -1 rows: no body
    assert (recs[0].body_ids < 0).any(), "the fixture needs frames without a body"
    back = _convert(tmp_path, *folders)
    for got, converted in zip(read, back, strict=True):
        _assert_same(got, converted)


def test_long_csv_round_trips_with_every_column(sim_walk, tmp_path: Path) -> None:
    recs = _recordings(sim_walk)
    write_long_csv(recs, tmp_path / "take.csv")
    read = load_long_csv(tmp_path / "take.csv")
    for original, got in zip(recs, read, strict=True):
        # frames without a body have no rows in the long CSV: compare the frames that hold one
        keep = original.body_ids[:, 0] >= 0
        assert got.n_frames == int(keep.sum())
        np.testing.assert_array_equal(got.positions, original.positions[keep])
        np.testing.assert_array_equal(got.orientations, original.orientations[keep])
        np.testing.assert_array_equal(got.device_time_us, original.device_time_us[keep])
        assert got.confidence_assumed is None
    for got, converted in zip(read, _convert(tmp_path, str(tmp_path / "take.csv")), strict=True):
        _assert_same(got, converted)


def test_andyj1_round_trips_and_says_it_matches_by_index(sim_walk, tmp_path: Path, capsys) -> None:
    recs = [r for r in _recordings(sim_walk, late_start=0)]
    recs = [
        Recording(r.sensor_id, r.positions[k], r.orientations[k], r.confidence[k], r.body_ids[k], None)
        for r in recs
        for k in [r.body_ids[:, 0] >= 0]
    ]
    paths = [write_andyj1(r, tmp_path / f"{r.sensor_id}.csv") for r in recs]
    back = _convert(tmp_path, *(f"{r.sensor_id}={p}" for r, p in zip(recs, paths, strict=True)))
    assert "matched by INDEX" in capsys.readouterr().err
    for original, converted in zip(recs, back, strict=True):
        _assert_same(original, converted, times=False)
        assert converted.device_time_us is None  # still index-matched after the round trip


def test_the_documented_long_csv_example_reads_up_to_its_missing_joints(tmp_path: Path) -> None:
    path = tmp_path / "example.csv"
    path.write_text(EXAMPLE)
    assert len(EXAMPLE.strip().splitlines()) == 10
    assert detect_format(path) == "long"
    with pytest.raises(DataError, match=r"example\.csv:3: body 1 of sensor 'master' at 1000000 µs lacks 30 joint"):
        load_long_csv(path)


# ------------------------------------------------------------------------------------------ time matching


def test_files_starting_at_different_frames_calibrate_identically_in_every_format(sim_walk, tmp_path: Path) -> None:
    recs = _recordings(sim_walk)
    json_specs = [
        f"{r.sensor_id}={write_offline_json(r, tmp_path / f'{r.sensor_id}.json', with_confidence=True)}" for r in recs
    ]
    write_long_csv(recs, tmp_path / "take.csv")
    mcap = tmp_path / "take.mcap"
    write_mcap(open_inputs(json_specs), mcap)
    arrays = {}
    for name, specs in {"json": json_specs, "csv": [str(tmp_path / "take.csv")], "mcap": [str(mcap)]}.items():
        take = open_inputs(specs)
        assert take.clock == "device" and not take.estimates
        arrays[name] = take_arrays(take, progress=False)
    # the same instants, bit for bit: the (deterministic) calibration cannot differ between the formats
    for name in ("csv", "mcap"):
        np.testing.assert_array_equal(arrays[name][0], arrays["json"][0], err_msg=name)
        np.testing.assert_array_equal(arrays[name][1], arrays["json"][1], err_msg=name)
        assert arrays[name][2] == arrays["json"][2]
    positions, confidence, ids = arrays["json"]
    assert len(positions) == recs[1].n_frames  # the subordinate's first 57 frames have no master partner
    cal = calibrate_from_skeletons(positions, confidence, ids, progress=False)
    assert cal.quality[ids[1]].verdict == "good", cal.report()
    truth = np.linalg.inv(sim_walk.world_from_sensor[0]) @ sim_walk.world_from_sensor[1]
    assert np.linalg.norm(cal.master_from_sensor[ids[1]][:3, 3] - truth[:3, 3]) < 60.0


def test_groups_pair_frames_by_device_time_not_index(sim_walk, tmp_path: Path) -> None:
    recs = _recordings(sim_walk)
    take = open_inputs([str(write_offline_json(r, tmp_path / f"{r.sensor_id}.json")) for r in recs])
    for group in take.groups():
        if group.complete:
            times = [f.device_time_us for f in group.frames.values()]
            assert max(times) - min(times) < 2000  # one instant: the subordinate delay, not 57 frames
    n_complete = sum(g.complete for g in take.groups())
    assert n_complete == recs[0].n_frames  # every master frame found its partner


def test_clock_offset_between_unrelated_clocks_is_estimated_from_the_motion(sim_walk, tmp_path: Path) -> None:
    recs = _recordings(sim_walk)
    shift_us = 7_000_000  # the subordinate's clock runs 7 s ahead: the ranges do not overlap
    sub = recs[1]
    moved = Recording(
        sub.sensor_id,
        sub.positions,
        sub.orientations,
        sub.confidence,
        sub.body_ids,
        sub.device_time_us + shift_us + 30_000_000,
    )
    paths = [write_offline_json(r, tmp_path / f"{r.sensor_id}.json") for r in (recs[0], moved)]
    take = open_inputs([str(p) for p in paths])
    estimate = take.estimates[sub.sensor_id]
    assert abs(estimate.offset_us + shift_us + 30_000_000) <= 34_000  # within one frame
    assert any("estimated from the motion" in n for n in take.notes)
    # the user's offset wins over the estimate
    forced = open_inputs([str(p) for p in paths], time_offsets_ms={sub.sensor_id: -37_000.0})
    assert forced.offsets_us[sub.sensor_id] == -37_000_000 and not forced.estimates


def test_motion_lag_finds_a_known_shift(sim_walk) -> None:
    a = band_pass(motion_features(sim_walk.positions[:, 0]))
    b = band_pass(motion_features(sim_walk.positions[:, 1]))
    assert estimate_lag(a, b).lag == 0
    assert LATE_START in estimate_lag(a[LATE_START:], b).peaks[:2]


# ------------------------------------------------------------------------------------------ bad input


def _json_text(**changes) -> str:
    body = {
        "body_id": 1,
        "joint_positions": [[0.0, 0.0, 1000.0]] * N_JOINTS,
        "joint_orientations": [[1.0, 0, 0, 0]] * N_JOINTS,
    }
    body.update(changes)
    frame = {"timestamp_usec": 0, "frame_id": 0, "num_bodies": 1, "bodies": [body]}
    return json.dumps(
        {
            "k4abt_sdk_version": "1",
            "source_file": "x",
            "joint_names": list(JOINT_NAMES),
            "bone_list": [],
            "frames": [frame],
        }
    )


@pytest.mark.parametrize(
    ("name", "text", "match"),
    [
        ("bad.json", '{"frames": [', r"bad\.json: invalid JSON at line 1"),
        (
            "pos.json",
            _json_text(joint_positions=[[0, 0]] * N_JOINTS),
            r"frames\[0\]\.bodies\[0\]: joint_positions has shape",
        ),
        (
            "conf.json",
            _json_text(joint_confidences=[2] * 31),
            r"frames\[0\]\.bodies\[0\]\.joint_confidences: .*31 entries",
        ),
        ("conf9.json", _json_text(joint_confidences=[9] * 32), r"confidence of joint 0 \(PELVIS\) is 9; expected 0-3"),
        (
            "long.csv",
            "timestamp_us,sensor,body_id,joint,x,y,z\n0,a,1,PELVIS,1,2,oops\n",
            r"long\.csv:2: non-numeric value .* x y z",
        ),
        (
            "long2.csv",
            "timestamp_us,sensor,body_id,joint,x,y,z\n0,a,1,ELBOW_MIDDLE,1,2,3\n",
            r"long2\.csv:2: unknown joint 'ELBOW_MIDDLE'",
        ),
        ("long3.csv", "timestamp_us,sensor,joint,x,y,z\n", r"long3\.csv:1: the header lacks column\(s\) body_id"),
        (
            "andy.csv",
            "title\nBody ID,Joint #,x,y,z,x,y,z,w,Confidence Level\n1,0,1,2,3,0,0,0,1,Sure\n",
            r"andy\.csv:3: unknown confidence sentence 'Sure'",
        ),
        (
            "what.txt",
            "hello\nworld\n",
            r"what\.txt:1: cannot tell the recording format .* convert yours to the long CSV",
        ),
    ],
)
def test_malformed_files_name_file_line_and_fix(tmp_path: Path, name: str, text: str, match: str) -> None:
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(DataError, match=match):
        open_inputs([str(path)])


def test_malformed_extractor_files_name_file_and_line(sim_walk, tmp_path: Path) -> None:
    rec = _recordings(sim_walk)[1]
    folder = tmp_path / "cam"
    write_extractor_csv(rec, folder)
    positions = folder / "positions_3d.csv"
    lines = positions.read_text().splitlines()
    positions.write_text("\n".join([*lines[:5], lines[5][:200], *lines[6:]]) + "\n")
    with pytest.raises(DataError, match=r"positions_3d\.csv:6: expected 130 ';'-separated columns .* truncated line"):
        open_inputs([str(folder)])
    positions.write_text("\n".join([lines[0].replace("PELVIS (x)", "PELVIS (q)"), *lines[1:]]) + "\n")
    with pytest.raises(DataError, match=r"positions_3d\.csv:1: column 4 is 'PELVIS \(q\)', expected 'PELVIS \(x\)'"):
        open_inputs([str(folder)])
    positions.write_text("\n".join(lines) + "\n")
    orientations = folder / "orientations_3d.csv"
    ori = orientations.read_text().splitlines()
    cells = ori[1].split(";")
    cells[1] = "77"
    orientations.write_text("\n".join([ori[0], ";".join(cells), *ori[2:]]) + "\n")
    # one orientation row without its position row is left out and reported (it used to refuse the take)
    notes = open_inputs([str(folder)]).recordings[0].notes
    assert any(n.startswith("1 rows of orientations_3d.csv have no row in positions_3d.csv") for n in notes), notes
    other = [";".join([c[0], "77", *c[2:]]) for c in (line.split(";") for line in ori[1:])]
    orientations.write_text("\n".join([ori[0], *other]) + "\n")
    with pytest.raises(DataError, match=r"orientations_3d\.csv: none of its \d+ rows has a row in positions_3d\.csv"):
        open_inputs([str(folder)])  # nothing joins: two files of different exports


def test_an_extractor_take_whose_orientations_begin_56_frames_early_is_read(sim_walk, tmp_path: Path) -> None:
    """Made like the real case: the tool's orientations_3d.csv begins 56 body frames before positions_3d.csv."""
    rec = _recordings(sim_walk)[0]
    folder = tmp_path / "cam"
    write_extractor_csv(rec, folder)
    positions = folder / "positions_3d.csv"
    lines = positions.read_text().splitlines()
    body_frames = np.flatnonzero(rec.body_ids[:, 0] >= 0)
    early = {int(t) for t in rec.device_time_us[body_frames[:56]]}
    first_kept = int(body_frames[56])
    kept = [line for line in lines[1:] if int(line.split(";")[0]) >= rec.device_time_us[first_kept]]
    positions.write_text("\n".join([lines[0], *kept]) + "\n")

    got = open_inputs([str(folder)]).recordings[0]
    note = next(n for n in got.notes if "have no row in positions_3d.csv" in n)
    assert note.startswith("56 rows of orientations_3d.csv") and f"{min(early)}-{max(early)} us" in note
    assert got.device_time_us[0] == rec.device_time_us[first_kept]
    np.testing.assert_allclose(got.positions, rec.positions[first_kept:], atol=5e-7 * 4096, equal_nan=True)
    np.testing.assert_allclose(got.orientations, rec.orientations[first_kept:], atol=1e-6, equal_nan=True)
    assert np.isfinite(got.orientations).any()  # the orientations that join are there


def test_specs_offsets_and_duplicates(tmp_path: Path, sim_walk) -> None:
    assert InputSpec.parse("master=a.json") == InputSpec(Path("a.json"), "master")
    assert InputSpec.parse("a.json") == InputSpec(Path("a.json"))
    assert parse_time_offsets(["sub=-1.5"]) == {"sub": -1.5}
    with pytest.raises(DataError, match="expected ID=MILLISECONDS"):
        parse_time_offsets(["sub"])
    rec = _recordings(sim_walk)[0]
    path = write_offline_json(rec, tmp_path / "m.json")
    with pytest.raises(DataError, match="comes twice"):
        open_inputs([str(path), str(path)])
    with pytest.raises(DataError, match="--time-offset for unknown sensor"):
        open_inputs([str(path)], time_offsets_ms={"nobody": 1.0})


def test_a_mis_paired_take_is_flagged_and_the_timed_one_is_not(sim_walk, tmp_path: Path, capsys) -> None:
    """The issue's take: the master starts 57 frames late. As andyj1 CSV (no timestamps) the frames can only
    be paired by index, 57 frames off: the verdict must say so and not be good. As JSON (device timestamps)
    the same files pair by time and calibrate well."""
    from skelfuse.cli.common import EXIT_ATTENTION

    recs = _recordings(sim_walk)
    untimed = [
        Recording(r.sensor_id, r.positions[k], r.orientations[k], r.confidence[k], r.body_ids[k], None)
        for r in recs
        for k in [r.body_ids[:, 0] >= 0]
    ]
    csv_takes = [f"--take={r.sensor_id}={write_andyj1(r, tmp_path / f'{r.sensor_id}.csv')}" for r in untimed]
    out = tmp_path / "cal.toml"
    assert main(["calibrate", "skeleton", *csv_takes, "-o", str(out), "-q"]) == EXIT_ATTENTION
    printed = capsys.readouterr()
    assert "matched by INDEX" in printed.err
    assert "frames look paired -57 frames off" in printed.out and "--time-offset ID=-1900" in printed.out
    json_takes = [f"--take={write_offline_json(r, tmp_path / f'{r.sensor_id}.json')}" for r in recs]
    assert main(["calibrate", "skeleton", *json_takes, "-o", str(out), "-q", "--force"]) == 0
    printed = capsys.readouterr()
    assert "matched by device timestamp" in printed.err and " good " in printed.out


# ------------------------------------------------------------------------------------------ where it is used


def test_fuse_input_takes_json_views(sim_walk, tmp_path: Path, capsys) -> None:
    """The issue's first try: `fuse --input master.json sub.json` fused (poses from a calibration file)."""
    import csv

    from skelfuse.config.calibration_file import CalibrationResult, SensorCalibration, write_calibration

    recs = _recordings(sim_walk)
    specs = [str(write_offline_json(r, tmp_path / f"{r.sensor_id}.json")) for r in recs]
    cal = tmp_path / "cal.toml"
    sensors = {
        sid: SensorCalibration(sim_walk.world_from_sensor[s], "manual") for s, sid in enumerate(sim_walk.sensor_ids)
    }
    write_calibration(cal, CalibrationResult(sensors, "manual", sim_walk.sensor_ids[0]))
    rig = tmp_path / "rig.toml"
    sensor_tables = "".join(
        f'[[sensors]]\nid = "{sid}"\nsource = "replay"\nreplay = {{ file = "{p}" }}\n'
        for sid, p in zip(sim_walk.sensor_ids, specs, strict=True)
    )
    rig.write_text(f'[rig]\nname = "lab"\n[calibration]\nfile = "{cal}"\n{sensor_tables}')
    out = tmp_path / "fused.csv"
    assert main(["fuse", "--input", *specs, "--config", str(rig), "--output", str(out)]) == 0
    assert "matched by device timestamp" in capsys.readouterr().err
    with out.open() as handle:
        rows = list(csv.DictReader(handle))
    times = {int(r["time_us"]) for r in rows}
    assert len(times) >= recs[0].n_frames - 10  # every instant both sensors saw, less the track's birth
    pelvis_rows = [r for r in rows if r["joint_name"] == "PELVIS"]
    pelvis = np.array([[float(r[k]) for k in ("x_mm", "y_mm", "z_mm")] for r in pelvis_rows])
    frame = np.rint((np.array([int(r["time_us"]) for r in pelvis_rows]) - sim_walk.device_time_us[0, 0]) / (1e6 / 30))
    truth_pelvis = sim_walk.truth[frame.astype(int), 0]
    assert np.median(np.linalg.norm(pelvis - truth_pelvis, axis=1)) < 60.0


def test_replay_source_reads_json_and_paces_files_of_one_sync_chain_together(sim_walk, tmp_path: Path) -> None:
    """`[[sensors]] source = "replay"` with offline_processor JSON: frames come out (not 0), and a file that
    starts 57 frames late is published 57 frame periods after its partner's first frame."""
    from skelfuse.service.worker import ReplaySource

    recs = _recordings(sim_walk)
    paths = [write_offline_json(r, tmp_path / f"{r.sensor_id}.json") for r in recs]
    anchor = int(min(r.device_time_us[0] for r in recs))
    firsts = []
    for rec, path in zip(recs, paths, strict=True):
        source = ReplaySource(path, f"live-{rec.sensor_id}", anchor_us=anchor)  # a one-sensor file, any name
        stream = source.frames()
        started = time.monotonic_ns()
        due0, frame0 = next(stream)
        due1, _ = next(stream)
        assert frame0.sensor_id == f"live-{rec.sensor_id}"
        assert frame0.device_time_us == rec.device_time_us[0]
        assert abs((due1 - due0) / 1e3 - 33_333) < 500
        firsts.append(due0 - started)
    late_ns = firsts[0] - firsts[1]
    assert abs(late_ns / 1e9 - LATE_START / 30) < 0.05


def test_an_mcap_round_trips_with_host_times_and_sequences(sim_walk, tmp_path: Path) -> None:
    recs = _recordings(sim_walk)
    first = tmp_path / "first.mcap"
    write_mcap(open_inputs([str(write_offline_json(r, tmp_path / f"{r.sensor_id}.json")) for r in recs]), first)
    host_shifted = [
        Recording(
            r.sensor_id,
            r.positions,
            r.orientations,
            r.confidence,
            r.body_ids,
            r.device_time_us,
            host_time_ns=r.device_time_us * 1000 + 12_345_678,
            sequences=np.arange(r.n_frames) * 2,
        )
        for r in open_inputs([str(first)]).recordings
    ]
    take = open_inputs([str(first)])
    take.recordings = tuple(host_shifted)
    second = tmp_path / "second.mcap"
    write_mcap(take, second)
    for original, converted in zip(host_shifted, _convert(tmp_path, str(second)), strict=True):
        _assert_same(original, converted)
        np.testing.assert_array_equal(converted.host_time_ns, original.host_time_ns)
        np.testing.assert_array_equal(converted.sequences, original.sequences)


def test_a_damaged_mcap_is_named(tmp_path: Path) -> None:
    path = tmp_path / "cut.mcap"
    path.write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 64)
    with pytest.raises(DataError, match=r"cut\.mcap holds no sensor-frame channels \(it ends early.*; record one"):
        open_inputs([str(path)])
