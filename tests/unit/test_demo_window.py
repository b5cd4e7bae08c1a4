"""The demo's accuracy figure covers a fixed, stated window: take seconds [1.5, take) of every whole pass of a
looping take, so any --duration of at least one pass prints the same figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skelfuse.apps.demo import CONVERGE_S, format_summary, run_demo_offline, scoring_window


def test_scoring_window_by_hand() -> None:
    fps = 2.0  # CONVERGE_S = 1.5 s: the first 3 frames of each pass are left out
    assert round(CONVERGE_S * fps) == 3
    instants = np.arange(95, 130)
    passes = scoring_window(instants, start_n=100, take_frames=10, run_frames=25, fps=fps)
    expected = np.full(len(instants), -1)
    for offset in range(25):
        if offset < 20 and offset % 10 >= 3:  # two whole passes of 10 frames; the third (partial) is not scored
            expected[offset + 5] = offset // 10
    np.testing.assert_array_equal(passes, expected)
    short = scoring_window(instants, start_n=100, take_frames=10, run_frames=5, fps=fps)  # shorter than a pass
    np.testing.assert_array_equal(np.flatnonzero(short == 0), [8, 9, 10, 11, 12, 13, 14])


def test_offline_demo_prints_the_same_figure_for_any_duration_of_a_pass_or_more(tmp_path: Path) -> None:
    take = 3.0

    def run(duration: float):
        return run_demo_offline(
            duration_s=duration, take_duration_s=take, seed=0, rrd_path=tmp_path / f"{duration}.rrd", progress=False
        )

    one, two, more = run(3.0), run(6.0), run(8.0)  # 8 s: two whole passes and part of a third (not scored)
    assert (one.passes_scored, two.passes_scored, more.passes_scored) == (1, 2, 2)
    frames_per_pass = round((take - CONVERGE_S) * 30)
    assert (one.frames_scored, two.frames_scored, more.frames_scored) == (
        frames_per_pass,
        2 * frames_per_pass,
        2 * frames_per_pass,
    )
    figure = one.error_fused_mm["all16"]
    assert np.isfinite(figure) and figure < 100.0
    for summary in (two, more):
        assert abs(summary.error_fused_mm["all16"] - figure) < 1e-6
        assert np.allclose(summary.error_fused_per_pass_mm, figure, atol=1e-6)
    text = format_summary(more)
    assert "take seconds 1.5-3.0 of each of 2 whole pass(es)" in text and "pass by pass" in text
    partial = run(2.0)
    assert partial.partial_pass and "cut short by --duration" in format_summary(partial)
