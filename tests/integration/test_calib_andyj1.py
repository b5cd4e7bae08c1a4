"""Skeleton calibration on the real 2-sensor andyj1 take (10 frames), next to the authors' own mapping.

``joints_sync_2.csv`` is the subordinate in its own camera frame, ``joints_sync_1.csv`` the master and
``joints_sync_tf.csv`` the subordinate mapped into the master frame by the authors' per-frame SVD estimate.
Ten frames of a person standing ~0.9 m away are far below the ~30 s walk the method is designed for: the
verdict must say so ("bad": too few points, no stable half-take estimate); the fit itself still maps the
torso an order of magnitude closer than the authors' mapping, in and out of sample.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skelfuse.calibration.rigid import fit_rigid, rotation_angle_deg
from skelfuse.calibration.skeleton import (
    MIDLINE_JOINTS,
    SIDE_PAIRS,
    SkeletonCalibrationOptions,
    calibrate_from_skeletons,
    stack_sensor_takes,
)
from skelfuse.schema.skeleton import Confidence
from skelfuse.sources.recorded import load_andyj1_csv

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "azure-kinect-andyj1" / "extrinsic_calculation"
TORSO = np.r_[MIDLINE_JOINTS, SIDE_PAIRS.ravel()]

pytestmark = [
    pytest.mark.integration,
    pytest.mark.skipif(not DATA.is_dir(), reason=f"andyj1 recordings not found at {DATA} (../shared/data)"),
]


def _rms(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=-1)[mask])))


@pytest.fixture(scope="module")
def take():
    master = load_andyj1_csv(DATA / "joints_sync_1.csv").single_body()
    sub = load_andyj1_csv(DATA / "joints_sync_2.csv").single_body()
    authors = load_andyj1_csv(DATA / "joints_sync_tf.csv").single_body()
    return master, sub, authors


def test_skeleton_fit_beats_the_authors_mapping(take):
    master, sub, authors = take
    positions, confidence, ids = stack_sensor_takes({"master": master, "sub": sub})
    assert positions.shape == (10, 2, 32, 3)
    cal = calibrate_from_skeletons(positions, confidence, ids, progress=False)
    T = cal.master_from_sensor["sub"]
    mapped = sub[0] @ T[:3, :3].T + T[:3, 3]
    both = (master[1] >= Confidence.MEDIUM) & (sub[1] >= Confidence.MEDIUM)
    torso = np.zeros(32, bool)
    torso[TORSO] = True
    ours_torso = _rms(mapped, master[0], both & torso)
    ours_all = _rms(mapped, master[0], both)
    theirs_torso = _rms(authors[0], master[0], both & torso)
    theirs_all = _rms(authors[0], master[0], both)
    print(
        f"\nandyj1 sub→master: rotation {rotation_angle_deg(T[:3, :3]):.1f}°, t = {np.round(T[:3, 3], 1)} mm; "
        f"torso RMS ours {ours_torso:.1f} mm vs authors {theirs_torso:.1f} mm; "
        f"all MEDIUM joints ours {ours_all:.1f} vs authors {theirs_all:.1f} mm"
    )
    assert ours_torso < 25.0
    assert theirs_torso > 2.5 * ours_torso
    assert ours_all < theirs_all
    # Honest about 10 frames: too few points for a "good" verdict.
    assert {q.verdict for q in cal.quality.values()} == {"bad"}
    assert "corresponding points" in cal.report()


def test_leave_one_frame_out_residual_stays_small(take):
    # In-sample residuals flatter a fit on 10 frames; fit on 9 frames, measure on the 10th.
    master, sub, _ = take
    both = (master[1] >= Confidence.MEDIUM) & (sub[1] >= Confidence.MEDIUM)
    errors = []
    for held_out in range(10):
        train = np.arange(10) != held_out
        use = both[train][:, TORSO]
        fit = fit_rigid(sub[0][train][:, TORSO][use], master[0][train][:, TORSO][use])
        test = both[held_out, TORSO]
        errors.append(np.linalg.norm(fit.apply(sub[0][held_out, TORSO]) - master[0][held_out, TORSO], axis=1)[test])
    rms = float(np.sqrt(np.mean(np.concatenate(errors) ** 2)))
    print(f"\nandyj1 leave-one-frame-out torso RMS {rms:.1f} mm")
    assert rms < 30.0


def test_half_take_agreement_on_five_frames(take):
    master, sub, _ = take
    positions, confidence, ids = stack_sensor_takes({"master": master, "sub": sub})
    options = SkeletonCalibrationOptions(min_pair_points=20, min_half_points=20)
    cal = calibrate_from_skeletons(positions, confidence, ids, options=options, progress=False)
    q = cal.quality["sub"]
    print(f"\nandyj1 halves (5 frames each): {q.half_rotation_deg:.2f}° / {q.half_translation_mm:.1f} mm; {q.verdict}")
    assert q.half_rotation_deg is not None
    assert q.half_rotation_deg < 10.0
