"""``skelfuse bench instant``: runs alternate between the two trees, each in its own process, load recorded."""

from __future__ import annotations

import argparse

import pytest

from skelfuse.bench.instant import OWN_SRC, format_instant_bench, run_instant_bench
from skelfuse.cli.bench import _sensors_by_people


def test_runs_alternate_between_baseline_and_current_and_record_the_load() -> None:
    result = run_instant_bench([(2, 1)], n_frames=4, rounds=1, baseline=OWN_SRC, progress=False)
    (case,) = result["cases"]
    assert [len(case["runs"][w]) for w in ("baseline", "current")] == [1, 1]
    for run in case["runs"]["baseline"] + case["runs"]["current"]:
        assert run["n_frames"] == 4 and run["mean_persons_out"] == 1.0  # the person is confirmed after warm-up
        assert len(run["load_before"]) == 3 and run["p50_ms"] > 0
    assert case["ratio_p50"] > 0 and case["ratio_cpu_p99"] > 0 and len(case["load_1min"]) == 2
    assert "| 2 x 1 |" in format_instant_bench(result)


def test_cases_parse_as_sensors_by_people() -> None:
    assert _sensors_by_people("16x6") == (16, 6)
    with pytest.raises(argparse.ArgumentTypeError, match="16x6"):
        _sensors_by_people("16-6")
