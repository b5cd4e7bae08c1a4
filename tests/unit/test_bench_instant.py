"""``skelfuse bench instant``: runs alternate between the two trees, each in its own process, load recorded."""

from __future__ import annotations

import argparse
import importlib
import time
from pathlib import Path

import numpy as np
import pytest

from skelfuse.bench.instant import (
    FPS,
    OWN_SRC,
    format_instant_bench,
    instant_take,
    run_instant_bench,
    time_instants,
    use_numpy_references,
)
from skelfuse.cli.bench import _sensors_by_people
from skelfuse.fusion.reference import LIVE_STAGES


@pytest.mark.live  # bench runs are subprocesses
def test_runs_alternate_between_baseline_and_current_and_record_the_load() -> None:
    result = run_instant_bench([(2, 1)], n_frames=4, rounds=1, baseline=OWN_SRC, progress=False)
    (case,) = result["cases"]
    assert [len(case["runs"][w]) for w in ("baseline", "current")] == [1, 1]
    for run in case["runs"]["baseline"] + case["runs"]["current"]:
        assert run["n_frames"] == 4 and run["mean_persons_out"] == 1.0  # the person is confirmed after warm-up
        assert len(run["load_before"]) == 3 and run["p50_ms"] > 0
    assert case["ratio_p50"] > 0 and case["ratio_cpu_p99"] > 0 and len(case["load_1min"]) == 2
    assert "| 2 x 1 |" in format_instant_bench(result)


@pytest.mark.live  # bench runs are subprocesses
def test_reference_runs_put_the_numpy_references_in_place_of_the_kernels() -> None:
    result = run_instant_bench([(2, 1)], n_frames=3, rounds=1, reference=True, progress=False)
    (case,) = result["cases"]
    assert result["baseline_numpy_references"] and result["baseline_src"] == str(OWN_SRC)
    assert case["runs"]["baseline"][0]["n_frames"] == 3 and case["ratio_p50"] > 0
    assert "with the numpy references" in format_instant_bench(result)
    with pytest.raises(ValueError, match="not both"):
        run_instant_bench([(2, 1)], n_frames=3, rounds=1, reference=True, baseline=OWN_SRC, progress=False)


def test_the_numpy_references_replace_every_compiled_stage(monkeypatch: pytest.MonkeyPatch) -> None:
    for module, name in LIVE_STAGES:
        monkeypatch.setattr(importlib.import_module(module), name, getattr(importlib.import_module(module), name))
    use_numpy_references()
    for (module, name), numpy_form in LIVE_STAGES.items():
        assert getattr(importlib.import_module(module), name) is numpy_form
        assert numpy_form.__module__.startswith("skelfuse.fusion.reference.")
    assert {name for _, name in LIVE_STAGES} == {
        "merge_dbscan",
        "filter_step",
        "select_candidates",
        "predicted_positions",
        "plausibility_step",
        "merge_views",
        "learn_bones",
        "realign_temporal",
        "seen_motion",
        "fuse_orientations",
        "assign_to_tracks",
        "match_tracks",
        "person_descriptors",
        "position_uncertainty",
        "stack_views_to_world",
    }


@pytest.mark.live  # bench runs are subprocesses
def test_baseline_runs_import_the_baseline_tree(tmp_path: Path) -> None:
    # A baseline whose skelfuse cannot be imported: its run fails and says why. Were the baseline's runs made
    # on this tree, the bench would time it twice and never notice.
    (tmp_path / "skelfuse").mkdir()
    (tmp_path / "skelfuse" / "__init__.py").write_text('raise ImportError("the baseline tree was imported")\n')
    with pytest.raises(RuntimeError, match="the baseline tree was imported"):
        run_instant_bench([(2, 1)], n_frames=2, rounds=1, baseline=tmp_path, progress=False)


def test_cases_parse_as_sensors_by_people() -> None:
    assert _sensors_by_people("16x6") == (16, 6)
    with pytest.raises(argparse.ArgumentTypeError, match="16x6"):
        _sensors_by_people("16-6")


def test_paced_runs_give_each_instant_its_frame_period() -> None:
    # 30 warm-up + 6 timed instants, one every 1/FPS s: the run cannot take less than 35 periods.
    start = time.perf_counter()
    run = time_instants(2, 1, 6, paced=True)
    assert time.perf_counter() - start >= 35 / FPS
    assert run["paced"] is True and run["n_frames"] == 6 and run["cpu_p50_ms"] > 0
    assert time_instants(2, 1, 6)["paced"] is False


@pytest.mark.live  # bench runs are subprocesses
def test_the_table_says_whether_instants_were_paced() -> None:
    result = run_instant_bench([(2, 1)], n_frames=3, rounds=1, paced=True, progress=False)
    assert result["paced"] and result["cases"][0]["runs"]["current"][0]["paced"]
    assert f"paced at {FPS:g} Hz" in format_instant_bench(result)


@pytest.mark.live  # bench runs are subprocesses
def test_positions_only_turns_off_the_orientation_and_uncertainty_stages_and_keeps_the_positions() -> None:
    # What the option times is a rig whose consumers need positions only: the same fused positions, bit for bit,
    # without the orientations and position_std that the stages it leaves out would have added.
    full, groups = instant_take(3, 2, 40)
    lean, _ = instant_take(3, 2, 40, positions_only=True)
    persons = 0
    for group in groups:
        a, b = full.step(group).frame, lean.step(group).frame
        np.testing.assert_array_equal(a.track_ids, b.track_ids)
        np.testing.assert_array_equal(a.positions, b.positions)
        assert a.orientations is not None and a.position_std is not None
        assert b.orientations is None and b.position_std is None
        persons += a.n_persons
    assert persons > 40  # both walkers were fused for most of the take
    result = run_instant_bench([(2, 1)], n_frames=3, rounds=1, positions_only=True, progress=False)
    assert result["positions_only"] and result["cases"][0]["runs"]["current"][0]["positions_only"]
    assert "fuse positions only" in format_instant_bench(result)
