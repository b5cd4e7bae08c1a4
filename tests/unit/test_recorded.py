"""Recorded-skeleton loaders (andyj1 CSV, offline_processor JSON) on small files the tests write themselves,
plus the pure metric functions of the real-data report (skelfuse.eval.real) on hand-made arrays."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from skelfuse.eval import real
from skelfuse.schema.errors import DataError
from skelfuse.schema.skeleton import BONES, JOINT_NAMES, MIRROR, N_JOINTS, Confidence, J
from skelfuse.sources.recorded import (
    FRAME_PERIOD_US,
    load_andyj1_csv,
    load_offline_processor_json,
    parse_confidence,
)

HEADER = ",,Position,,,Orientation,,,,Confidence Level\nBody ID,Joint #,x,y,z,x,y,z,w\n"
MEDIUM_TEXT = "Medium confidence in joint pose"
LOW_TEXT = "The joint is not observed(likely due to occlusion) - predicted joint pose"


def _block(body_id: int, offset: float, confidences: list[str] | None = None) -> list[str]:
    """32 CSV rows of one body: position (j + offset, 2j, 3j), quaternion columns (0.1, 0.2, 0.3, 0.9): w x y z."""
    rows = []
    for j in range(N_JOINTS):
        text = confidences[j] if confidences else MEDIUM_TEXT
        rows.append(f"{body_id},{j},{j + offset},{2 * j},{3 * j},0.1,0.2,0.3,0.9,{text},")
    return rows


def _write_csv(path: Path, blocks: list[list[str]]) -> Path:
    path.write_text(HEADER + "\n".join(row for block in blocks for row in block) + "\n")
    return path


# ------------------------------------------------------------------------------------------------- CSV


def test_csv_round_trip_values_and_quaternion_order(tmp_path: Path) -> None:
    conf = [MEDIUM_TEXT] * N_JOINTS
    conf[7] = LOW_TEXT
    path = _write_csv(tmp_path / "view.csv", [_block(1, 0.5, conf), _block(1, 10.5)])
    rec = load_andyj1_csv(path)
    assert rec.sensor_id == "view"
    assert rec.positions.shape == (2, 1, N_JOINTS, 3) and rec.positions.dtype == np.float32
    assert rec.device_time_us is None and rec.duplicates_dropped == 0
    np.testing.assert_allclose(rec.positions[0, 0, 5], [5.5, 10, 15])
    np.testing.assert_allclose(rec.positions[1, 0, 5], [15.5, 10, 15])
    np.testing.assert_allclose(rec.orientations[0, 0, 3], [0.1, 0.2, 0.3, 0.9], rtol=1e-6)  # as the file holds them
    assert rec.confidence[0, 0, 7] == Confidence.LOW and rec.confidence[0, 0, 6] == Confidence.MEDIUM
    np.testing.assert_array_equal(rec.body_ids, [[1], [1]])


def test_csv_frames_yield_valid_sensor_frames(tmp_path: Path) -> None:
    rec = load_andyj1_csv(_write_csv(tmp_path / "v.csv", [_block(3, 0), _block(3, 1), _block(3, 2)]), sensor_id="cam")
    frames = list(rec.frames())
    assert [f.sequence for f in frames] == [0, 1, 2]
    assert [f.device_time_us for f in frames] == [0, FRAME_PERIOD_US, 2 * FRAME_PERIOD_US]
    for frame in frames:
        frame.validate()
        assert frame.sensor_id == "cam" and frame.body_ids.tolist() == [3]
        assert frame.body_ids.dtype == np.uint32


def test_csv_frame_written_twice_is_dropped(tmp_path: Path) -> None:
    a, b = _block(1, 0), _block(1, 7)
    path = _write_csv(tmp_path / "m.csv", [a, a, b, b])
    rec = load_andyj1_csv(path)
    assert rec.n_frames == 2 and rec.duplicates_dropped == 2
    np.testing.assert_allclose(rec.positions[:, 0, 0, 0], [0, 7])
    assert load_andyj1_csv(path, duplicates="keep").n_frames == 4
    assert load_andyj1_csv(path, duplicates="drop").n_frames == 2


def test_csv_occasional_repeat_is_kept(tmp_path: Path) -> None:
    # a tracker can repeat one frame; only a file where *every* pair repeats is a written-twice file
    a, b = _block(1, 0), _block(1, 7)
    path = _write_csv(tmp_path / "m.csv", [a, a, b, _block(1, 9)])
    assert load_andyj1_csv(path).n_frames == 4
    with pytest.raises(DataError, match="written twice"):
        load_andyj1_csv(path, duplicates="drop")


def test_csv_group_bodies_by_id(tmp_path: Path) -> None:
    path = _write_csv(tmp_path / "two.csv", [_block(1, 0), _block(2, 1), _block(1, 2), _block(2, 3), _block(1, 4)])
    rec = load_andyj1_csv(path, group_bodies_by_id=True)
    assert rec.positions.shape[:2] == (3, 2)
    np.testing.assert_array_equal(rec.body_ids, [[1, 2], [1, 2], [1, -1]])
    assert np.isnan(rec.positions[2, 1]).all() and (rec.confidence[2, 1] == 0).all()
    assert [f.n_bodies for f in rec.frames()] == [2, 2, 1]
    with pytest.raises(DataError, match="2 bodies"):
        rec.single_body()


@pytest.mark.parametrize(
    ("text", "level"),
    [
        (MEDIUM_TEXT, Confidence.MEDIUM),
        (LOW_TEXT, Confidence.LOW),
        ("The joint is not observed (likely due to occlusion), predicted joint pose", Confidence.LOW),
        ("The joint is out of range (too far from depth camera)", Confidence.NONE),
        ("High confidence in joint pose", Confidence.HIGH),
        (
            "Medium confidence in joint pose. Current SDK will only provide joints up to this confidence level",
            Confidence.MEDIUM,
        ),
        (" medium CONFIDENCE in joint pose ", Confidence.MEDIUM),
        ("2", Confidence.MEDIUM),
        ("K4ABT_JOINT_CONFIDENCE_LOW", Confidence.LOW),
    ],
)
def test_confidence_sentences(text: str, level: Confidence) -> None:
    assert parse_confidence(text) is level


def _lines_with(tmp_path: Path, line_index: int, new_row: str) -> Path:
    rows = _block(1, 0) + _block(1, 1)
    rows[line_index] = new_row
    return _write_csv(tmp_path / "bad.csv", [rows])


@pytest.mark.parametrize(
    ("row_index", "row", "message"),
    [
        (4, "1,4,1,2,3,0,0,0,1", r"bad\.csv:7: expected 10 columns.*got 9"),
        (4, "1,4,1,2,3,0,0,0,1,Medium confidence in joint pose,,extra", r"bad\.csv:7: expected 10 columns"),
        (
            4,
            "1,5,1,2,3,0,0,0,1,Medium confidence in joint pose,",
            r"bad\.csv:7: joint index 5 out of order, expected 4",
        ),
        (
            33,
            "1,0,1,2,3,0,0,0,1,Medium confidence in joint pose,",
            r"bad\.csv:36: joint index 0 out of order",
        ),
        (4, "1,4,abc,2,3,0,0,0,1,Medium confidence in joint pose,", r"bad\.csv:7: non-numeric value"),
        (4, "x,4,1,2,3,0,0,0,1,Medium confidence in joint pose,", r"bad\.csv:7: non-numeric value"),
        (4, "1,4,nan,2,3,0,0,0,1,Medium confidence in joint pose,", r"bad\.csv:7: non-finite"),
        (
            4,
            "1,4,1,2,3,0,0,0,1,Quite sure about this one,",
            r"bad\.csv:7: unknown confidence sentence 'Quite sure",
        ),
        (
            4,
            "2,4,1,2,3,0,0,0,1,Medium confidence in joint pose,",
            r"bad\.csv:7: body id 2 inside the 32-row block",
        ),
    ],
)
def test_csv_malformed_rows_name_file_and_line(tmp_path: Path, row_index: int, row: str, message: str) -> None:
    path = _lines_with(tmp_path, row_index, row)
    with pytest.raises(DataError, match=message):
        load_andyj1_csv(path)


def test_csv_truncated_and_bad_header_and_missing(tmp_path: Path) -> None:
    truncated = _write_csv(tmp_path / "t.csv", [_block(1, 0)[:20]])
    with pytest.raises(DataError, match=r"t\.csv: last body block \(from line 3\) is truncated: 20 of 32"):
        load_andyj1_csv(truncated)
    bad_header = tmp_path / "h.csv"
    bad_header.write_text("a,b\nc,d\n")
    with pytest.raises(DataError, match=r"h\.csv:2: expected the column header"):
        load_andyj1_csv(bad_header)
    with pytest.raises(DataError, match="no such file"):
        load_andyj1_csv(tmp_path / "absent.csv")


def test_csv_blank_lines_are_skipped(tmp_path: Path) -> None:
    path = tmp_path / "b.csv"
    path.write_text(HEADER + "\n".join(_block(1, 0)) + "\n\n" + "\n".join(_block(1, 1)) + "\n\n")
    assert load_andyj1_csv(path).n_frames == 2


# ------------------------------------------------------------------------------------------------ JSON


def _body(body_id: int, offset: float) -> dict:
    return {
        "body_id": body_id,
        "joint_positions": [[j + offset, -j, 1000.0 + j] for j in range(N_JOINTS)],
        "joint_orientations": [[1.0, 0.0, 0.0, 0.0] for _ in range(N_JOINTS)],
    }


def _document(frames: list[list[dict]] | None = None) -> dict:
    names = [name.replace("SPINE_NAVEL", "SPINE_NAVAL") for name in JOINT_NAMES]  # the docs' spelling
    frames = frames if frames is not None else [[_body(1, 0.0)], [_body(1, 1.0), _body(4, 2.0)], []]
    return {
        "k4abt_sdk_version": "1.1.2",
        "source_file": "take.mkv",
        "joint_names": names,
        "bone_list": [[JOINT_NAMES[p], JOINT_NAMES[c]] for p, c in BONES],
        "frames": [
            {
                "timestamp_usec": 100_000 + 33_333 * t,
                "frame_id": t,
                "num_bodies": len(bodies),
                "bodies": bodies,
            }
            for t, bodies in enumerate(frames)
        ],
    }


def _write_json(path: Path, document: dict) -> Path:
    path.write_text(json.dumps(document))
    return path


def test_json_round_trip(tmp_path: Path) -> None:
    rec = load_offline_processor_json(_write_json(tmp_path / "take.json", _document()))
    assert rec.sensor_id == "take"
    assert rec.positions.shape == (3, 2, N_JOINTS, 3)
    np.testing.assert_array_equal(rec.body_ids, [[1, -1], [1, 4], [-1, -1]])
    np.testing.assert_allclose(rec.positions[1, 1, 5], [7.0, -5.0, 1005.0])
    np.testing.assert_allclose(rec.orientations[0, 0, 0], [1, 0, 0, 0])  # already w x y z: kept
    assert (rec.confidence[rec.body_ids >= 0] == Confidence.MEDIUM).all()
    assert (rec.confidence[rec.body_ids < 0] == Confidence.NONE).all()
    np.testing.assert_array_equal(rec.device_time_us, [100_000, 133_333, 166_666])
    frames = list(rec.frames())
    assert [f.n_bodies for f in frames] == [1, 2, 0]
    assert [f.device_time_us for f in frames] == [100_000, 133_333, 166_666]
    for frame in frames:
        frame.validate()


def test_json_confidence_is_configurable(tmp_path: Path) -> None:
    rec = load_offline_processor_json(_write_json(tmp_path / "t.json", _document()), confidence=Confidence.LOW)
    assert (rec.confidence[rec.body_ids >= 0] == Confidence.LOW).all()


def _broken(mutate) -> dict:
    document = _document()
    mutate(document)
    return document


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda d: d.pop("frames"), r"the root lacks key\(s\) frames"),
        (lambda d: d.pop("joint_names"), r"lacks key\(s\) joint_names"),
        (lambda d: d["joint_names"].pop(), r"joint_names holds 31 entries, expected the 32"),
        (lambda d: d["joint_names"].__setitem__(3, "HEAD"), r"joint_names\[3\] is 'HEAD', expected 'NECK'"),
        (
            lambda d: d["frames"][1].pop("timestamp_usec"),
            r"frames\[1\]: the frame lacks key\(s\) timestamp_usec",
        ),
        (
            lambda d: d["frames"][1].__setitem__("num_bodies", 3),
            r"frames\[1\]: num_bodies is 3 but 'bodies' holds 2",
        ),
        (
            lambda d: d["frames"][1]["bodies"][1].pop("joint_orientations"),
            r"frames\[1\]\.bodies\[1\]: the body lacks key\(s\) joint_orientations",
        ),
        (
            lambda d: d["frames"][0]["bodies"][0]["joint_positions"].pop(),
            r"frames\[0\]\.bodies\[0\]: joint_positions has shape \(31, 3\), expected \(32, 3\)",
        ),
        (
            lambda d: d["frames"][0]["bodies"][0]["joint_orientations"][2].pop(),
            r"joint_orientations is not a numeric array|joint_orientations has shape",
        ),
        (
            lambda d: d["frames"][0]["bodies"][0]["joint_positions"][6].__setitem__(1, math.nan),
            r"frames\[0\]\.bodies\[0\]: joint_positions of joint 6 \(ELBOW_LEFT\) is not finite",
        ),
        (
            lambda d: d["frames"][0]["bodies"][0]["joint_positions"][6].__setitem__(1, "x"),
            r"joint_positions is not a numeric array",
        ),
        (lambda d: d["frames"][0]["bodies"][0].__setitem__("body_id", "one"), r"body_id is 'one'"),
    ],
)
def test_json_malformed(tmp_path: Path, mutate, message: str) -> None:
    path = _write_json(tmp_path / "bad.json", _broken(mutate))
    with pytest.raises(DataError, match=message):
        load_offline_processor_json(path)


def test_json_not_json_and_missing(tmp_path: Path) -> None:
    path = tmp_path / "x.json"
    path.write_text("{ not json")
    with pytest.raises(DataError, match=r"x\.json: invalid JSON at line 1"):
        load_offline_processor_json(path)
    with pytest.raises(DataError, match="no such file"):
        load_offline_processor_json(tmp_path / "absent.json")


def test_json_accepts_prefixed_and_lowercase_names(tmp_path: Path) -> None:
    document = _document()
    document["joint_names"] = [f"K4ABT_JOINT_{name}".lower() for name in JOINT_NAMES]
    assert load_offline_processor_json(_write_json(tmp_path / "t.json", document)).n_frames == 3


# ------------------------------------------------------------------------ metrics of skelfuse.eval.real


def _standing(n_frames: int = 5) -> np.ndarray:
    """(T, J, 3) a still skeleton with its left shoulder and hip at -x, right ones at +x."""
    rng = np.random.default_rng(7)
    base = rng.normal(0.0, 50.0, size=(N_JOINTS, 3))
    base[J["SHOULDER_LEFT"]] = [-200, -400, 2000]
    base[J["SHOULDER_RIGHT"]] = [200, -400, 2000]
    base[J["HIP_LEFT"]] = [-100, 0, 2000]
    base[J["HIP_RIGHT"]] = [100, 0, 2000]
    return np.repeat(base[None], n_frames, axis=0)


def test_distance_stats_pools_joints_and_mask() -> None:
    dist = np.array([[1.0, 2.0, np.nan], [3.0, 4.0, 10.0]])
    stats = real.distance_stats(dist, [0, 1])
    assert stats["n"] == 4 and stats["mean"] == pytest.approx(2.5) and stats["median"] == pytest.approx(2.5)
    masked = real.distance_stats(dist, [0, 1, 2], mask=np.array([[True, False, True], [False, False, True]]))
    assert masked["n"] == 2 and masked["mean"] == pytest.approx(5.5)
    empty = real.distance_stats(dist, [2], mask=np.zeros_like(dist, dtype=bool))
    assert empty["n"] == 0 and math.isnan(empty["mean"])


def test_jitter_zero_for_constant_velocity_and_known_for_alternation() -> None:
    t = np.arange(10, dtype=float)
    moving = np.zeros((10, N_JOINTS, 3))
    moving[..., 0] = 5.0 * t[:, None]
    assert real.jitter_rms(moving, [0, 1]) == pytest.approx(0.0)
    shaking = moving.copy()
    shaking[::2, :, 1] += 1.0  # +1, 0, +1, 0 ... -> second difference of magnitude 2 everywhere
    assert real.jitter_rms(shaking, [3, 4]) == pytest.approx(2.0)
    assert math.isnan(real.jitter_rms(moving[:2], [0]))


def test_mirrored_frames_vote_of_views() -> None:
    skeleton = _standing(4)
    views = np.stack([skeleton, skeleton, skeleton[..., MIRROR, :]])  # two straight views, one mirrored
    mirrored, decided = real.mirrored_frames(skeleton, views)
    assert not mirrored.any() and decided.all()
    flipped = skeleton.copy()
    flipped[2] = skeleton[2][MIRROR]
    mirrored, decided = real.mirrored_frames(flipped, views)
    np.testing.assert_array_equal(mirrored, [False, False, True, False])
    tie, decided = real.mirrored_frames(skeleton, views[1:])
    assert not tie.any() and not decided.any()
    missing = skeleton.copy()
    missing[1, J["HIP_LEFT"]] = np.nan
    _, decided = real.mirrored_frames(missing, views)
    np.testing.assert_array_equal(decided, [True, False, True, True])


def test_bone_cv_scaled_skeleton_and_groups() -> None:
    skeleton = _standing(1)[0]
    scales = np.array([0.9, 1.0, 1.1])
    sequence = skeleton[None] * scales[:, None, None]  # every bone scales together
    cv = real.bone_length_cv(sequence)
    assert cv.shape == (BONES.shape[0],)
    np.testing.assert_allclose(cv, scales.std() / scales.mean(), rtol=1e-9)
    assert real.group_bone_cv(cv, real.REPORT_GROUPS["torso"]) == pytest.approx(scales.std() / scales.mean())
    assert math.isnan(real.group_bone_cv(cv, [J["PELVIS"]]))  # the root ends no bone


def test_repeated_frames_counts_exact_copies() -> None:
    sequence = _standing(5)
    sequence[2] += 1.0
    assert real.repeated_frames(sequence) == 2  # frames 1 and 4 repeat the frame before


def test_missing_take_raises_with_guidance(tmp_path: Path) -> None:
    with pytest.raises(DataError, match=r"looked for .*joints_gen_master\.csv.*--data"):
        real.run_real_eval(tmp_path)


def test_offset_split_separates_constant_offset() -> None:
    a = _standing(6)
    wobble = np.zeros_like(a)
    wobble[::2, :, 2] = 3.0  # alternating 0 / 3 mm along z: 1.5 mm from the mean every frame
    b = a + np.array([30.0, 40.0, 0.0]) + wobble
    offset_mm, residual_mm = real.offset_split(a, b, real.REPORT_GROUPS["torso"])
    assert offset_mm == pytest.approx(np.hypot(50.0, 1.5))
    assert residual_mm == pytest.approx(1.5)
