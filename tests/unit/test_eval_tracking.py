"""CLEAR-MOT / IDF1 metrics on hand-made cases, and the tracking evaluation end to end."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.eval.tracking import clear_mot, run_tracking_eval
from skelfuse.schema.errors import ConfigError
from skelfuse.sim.gestures import make_gesture

POSE = make_gesture("hands_up_down", duration_s=0.1, seed=0).positions[0]


def at(x: float) -> np.ndarray:
    pose = POSE.copy()
    pose[:, 0] += x - pose[0, 0]
    return pose


def case(T: int, truth_x: list[float], hyps: list[list[tuple[int, float]]]):
    truth = np.stack([np.stack([at(x) for x in truth_x])] * T)
    H = max(1, max(len(h) for h in hyps))
    ids = np.full((T, H), -1)
    pos = np.full((T, H, 32, 3), np.nan)
    for t, row in enumerate(hyps):
        for h, (tid, x) in enumerate(row):
            ids[t, h] = tid
            pos[t, h] = at(x)
    return truth, np.ones((T, len(truth_x)), bool), ids, pos


def test_one_id_switch_counted_once() -> None:
    hyps = [[(1, 0.0)]] * 5 + [[(3, 0.0)]] * 5
    m = clear_mot(*case(10, [0.0], hyps))
    assert (m.id_switches, m.fragmentations, m.false_negatives, m.false_positives) == (1, 0, 0, 0)
    assert m.mota == pytest.approx(0.9)
    assert m.idf1 == pytest.approx(0.5)  # best id covers 5 of 10 frames: 2*5 / (10 + 10)


def test_fragmentation_counted() -> None:
    hyps = [[(1, 0.0)]] * 4 + [[]] * 2 + [[(1, 10.0)]] * 4
    m = clear_mot(*case(10, [0.0], hyps))
    assert (m.id_switches, m.fragmentations, m.false_negatives) == (0, 1, 2)
    assert m.motp_mm == pytest.approx(0.4 * 0.0 + 0.6 * 0.0 + 10.0 * 4 / 8)


def test_mota_and_idf1_by_hand() -> None:
    # one person; frames: id 1, id 1, id 2, miss + a false positive 3 m away.
    hyps = [[(1, 0.0)], [(1, 0.0)], [(2, 0.0)], [(5, 3000.0)]]
    m = clear_mot(*case(4, [0.0], hyps))
    assert (m.gt, m.matches, m.false_negatives, m.false_positives, m.id_switches) == (4, 3, 1, 1, 1)
    assert m.mota == pytest.approx(1 - 3 / 4)
    assert m.idtp == 2 and m.idf1 == pytest.approx(2 * 2 / (4 + 4))


def test_crossing_people_no_swap_when_tracks_hold() -> None:
    hyps = [[(1, 0.0), (2, 2000.0)]] * 3 + [[(2, 2000.0), (1, 0.0)]] * 3  # slot order changes: no switch
    m = clear_mot(*case(6, [0.0, 2000.0], hyps))
    assert m.id_switches == 0 and m.mota == 1.0 and m.idf1 == 1.0


def test_per_person_rmse() -> None:
    m = clear_mot(*case(3, [0.0], [[(1, 30.0)]] * 3))
    assert m.per_person_rmse_mm[0]["torso"] == pytest.approx(30.0)


def test_run_tracking_eval_quick() -> None:
    result = run_tracking_eval(quick=True, preset_name="A5")
    assert result.preset == "A5"
    names = [s.name for s in result.scenarios]
    assert names == ["crossing", "bystander", "enter_leave", "crowd"]
    for s in result.scenarios:
        assert s.metrics.id_switches == 0
        assert s.metrics.n_track_ids == s.n_people
    text = result.format_markdown()
    assert "| crossing |" in text and "IDF1" in text
    assert result.to_dict()["scenarios"][0]["metrics"]["gt"] > 0


def test_unknown_preset_is_an_error_naming_the_presets() -> None:
    with pytest.raises(ConfigError, match=r"A9.*skelfuse"):
        run_tracking_eval(quick=True, preset_name="A9")
