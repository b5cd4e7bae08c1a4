"""The real andyj1 Azure Kinect recordings (../shared/data): loaders, facts of the data, and the real-data
report with every fusion preset. Skips where the shared data is absent."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from skelfuse.eval import real
from skelfuse.schema.skeleton import JOINT_GROUPS, N_JOINTS, Confidence
from skelfuse.sources.recorded import load_andyj1_csv

DATA_DIR = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
ANDYJ1 = DATA_DIR / "azure-kinect-andyj1"
TAKE = ANDYJ1 / "saved_data_2_3dev"

pytestmark = [
    pytest.mark.integration,
    pytest.mark.skipif(
        not TAKE.is_dir(),
        reason=f"real recordings not found at {TAKE.resolve()} (../shared/data is absent)",
    ),
]

N_FRAMES = 98


@pytest.fixture(scope="module")
def take() -> real.RealTake:
    return real.load_take(DATA_DIR)


@pytest.fixture(scope="module")
def report() -> real.RealEvalResult:
    return real.run_real_eval(DATA_DIR)


@pytest.mark.parametrize("name", [*real.VIEW_FILES.values(), real.AUTHORS_FILE])
def test_take_files_load(name: str) -> None:
    rec = load_andyj1_csv(TAKE / name)
    assert rec.n_frames == N_FRAMES
    assert rec.positions.shape == (N_FRAMES, 1, N_JOINTS, 3)
    assert np.isfinite(rec.positions).all() and np.isfinite(rec.orientations).all()
    if name != real.AUTHORS_FILE:  # the authors average quaternions componentwise: not unit length
        np.testing.assert_allclose(np.linalg.norm(rec.orientations, axis=-1), 1.0, atol=1e-3)
    assert set(np.unique(rec.confidence)) <= {Confidence.LOW, Confidence.MEDIUM}  # HIGH never occurs
    assert rec.duplicates_dropped == (N_FRAMES if name == "joints_gen_master.csv" else 0)
    for frame in rec.frames():
        frame.validate()


@pytest.mark.parametrize("name", ["joints_sync_1.csv", "joints_sync_2.csv", "joints_sync_tf.csv"])
def test_extrinsic_take_loads(name: str) -> None:
    rec = load_andyj1_csv(ANDYJ1 / "extrinsic_calculation" / name)
    assert rec.n_frames == 10 and rec.duplicates_dropped == 0
    assert np.isfinite(rec.positions).all()


def test_sub_views_sit_near_the_master_on_the_torso(take: real.RealTake) -> None:
    # independent fact: the authors mapped sub1/sub2 into the master frame, roughly (tens of mm, not metres)
    torso = JOINT_GROUPS["torso"]
    for s in (1, 2):
        both = (take.confidence[0] >= Confidence.MEDIUM) & (take.confidence[s] >= Confidence.MEDIUM)
        dist = np.linalg.norm(take.positions[s] - take.positions[0], axis=-1)
        median = np.median(dist[:, torso][both[:, torso]])
        assert 5.0 < median < 100.0, (take.view_names[s], median)


def test_authors_file_is_the_mean_of_the_medium_views(take: real.RealTake) -> None:
    # The authors' file is a confidence-gated average: the mean of the views that are MEDIUM, and the
    # master's position where no view is. Holds only with frames matched by order and the master's doubled
    # frames dropped, so it checks the loader too.
    medium = take.confidence >= Confidence.MEDIUM  # (S, T, J)
    weights = medium[..., None].astype(float)
    gated = (take.positions * weights).sum(axis=0) / np.maximum(weights.sum(axis=0), 1.0)
    some = medium.any(axis=0)
    assert some.sum() > 500 and (~some).sum() > 500
    np.testing.assert_allclose(take.authors_positions[some], gated[some], atol=0.01)
    np.testing.assert_array_equal(take.authors_positions[~some], take.positions[0][~some])


def test_no_view_is_mirrored(take: real.RealTake) -> None:
    for s in range(3):
        mirrored, decided = real.mirrored_frames(take.positions[s], np.delete(take.positions, s, axis=0))
        assert decided.all() and not mirrored.any()


@pytest.mark.parametrize("preset_name", ["A1", "A2", "A3", "A4", "A5"])
def test_every_preset_fuses_the_take(take: real.RealTake, preset_name: str) -> None:
    fused = real.fuse_views(take.positions, take.confidence, preset_name)
    assert fused.shape == (N_FRAMES, N_JOINTS, 3)
    assert np.isfinite(fused).all()
    mirrored, decided = real.mirrored_frames(fused, take.positions)
    assert decided.all() and not mirrored.any()
    # the fused torso lies among the views: within the views' own spread of the master
    dist = np.linalg.norm(fused - take.positions[0], axis=-1)[:, JOINT_GROUPS["torso"]]
    assert np.median(dist) < 100.0


def test_report_end_to_end(report: real.RealEvalResult) -> None:
    assert report.n_frames == N_FRAMES and report.presets == ["A1", "A2", "A3", "A4", "A5", "skelfuse"]
    for method in [*report.presets, "authors"]:
        assert report.mirrored[method]["mirrored"] == 0 and report.mirrored[method]["undecided"] == 0
    for held_out, table in report.leave_one_out.items():
        for method in [*report.presets, "authors"]:
            torso = table[method]["torso"]
            assert torso["n"] > 0 and np.isfinite(torso["mean"]), (held_out, method)
    for method, row in report.jitter.items():
        assert all(np.isfinite(v) for v in row.values()), method
    text = json.dumps(report.to_dict(), allow_nan=False)
    assert '"leave_one_out"' in text
    markdown = real.format_markdown(report)
    for heading in ("Cross-view disagreement", "Jitter", "Leave-one-out", "mirrored", "Bone-length CV"):
        assert heading in markdown
    assert real.BONE_CV_NOTE in markdown
