"""``skelfuse eval paper``: experiment bookkeeping, report files, and a seeded end-to-end run."""

from __future__ import annotations

import dataclasses
import io
import json
import math

import numpy as np
import pytest

from skelfuse.eval import paper, paper_reference, report
from skelfuse.eval.metrics import ErrorAccumulator, lag_error_curve
from skelfuse.progress import Progress
from skelfuse.schema.skeleton import EVAL_JOINTS, JOINT_GROUPS

# ------------------------------------------------------------------------------------------------------------
# Bookkeeping.


def test_experiment3_uses_every_combination_4_6_4_1() -> None:
    combos = paper.sensor_combinations(4)
    assert {n: len(keys) for n, keys in combos.items()} == {1: 4, 2: 6, 3: 4, 4: 1}
    assert combos[1] == ["raw[0]", "raw[1]", "raw[2]", "raw[3]"]
    assert combos[4] == ["A5_100"]
    assert "A5_100[0,3]" in combos[2] and "A5_100[1,2,3]" in combos[3]
    assert paper_reference.N_SENSORS_COMBINATIONS == {n: len(k) for n, k in combos.items()}
    ours = paper.sensor_combinations(4, algorithm="skelfuse")
    assert ours[1] == combos[1]  # one sensor is the raw skeleton, shared by both algorithms
    assert ours[4] == ["skelfuse"] and "skelfuse[0,3]" in ours[2] and len(ours[3]) == 4


def test_fusion_runs_cover_the_grid_and_the_subsets_once() -> None:
    runs = paper.fusion_runs(4)
    keys = [r.key for r in runs]
    assert len(keys) == len(set(keys))
    # A1, A2, 3 presets x 4 eps and ours on all sensors, then A5 and ours on the 6 pairs and 4 triples.
    assert len(runs) == 2 + 3 * 4 + 1 + 2 * (6 + 4)
    assert {r.key for r in runs if len(r.sensors) == 4} == {
        "A1",
        "A2",
        *(f"A{n}_{e}" for n in (3, 4, 5) for e in (50, 100, 150, 200)),
        "skelfuse",
    }
    subsets = [r for r in runs if len(r.sensors) < 4]
    assert all(r.eps_mm == 100.0 for r in subsets if r.preset == "A5")
    assert {r.preset for r in subsets} == {"A5", "skelfuse"}
    # eps is handed to A3-A5 only; A1, A2 and ours run at their preset's own default.
    assert {r.preset for r in runs if r.eps_mm is None} == {"A1", "A2", "skelfuse"}
    # Every key experiment 3 averages is produced by a run or is a raw sensor.
    produced = set(keys) | {f"raw[{s}]" for s in range(4)}
    for algorithm in ("A5", "skelfuse"):
        assert all(k in produced for ks in paper.sensor_combinations(4, algorithm=algorithm).values() for k in ks)
    assert len(paper.fusion_runs(4, ours=())) == 2 + 3 * 4 + 6 + 4


def test_runs_pass_eps_only_where_set(monkeypatch) -> None:
    from skelfuse.fusion import presets

    calls: list[tuple] = []
    monkeypatch.setattr(presets, "preset", lambda name, **kwargs: calls.append((name, kwargs)) or name)
    paper.FusionRun("skelfuse", "skelfuse", None, (0, 1)).params()
    paper.FusionRun("A4_150", "A4", 150.0, (0, 1)).params()
    assert calls == [("skelfuse", {}), ("A4", {"eps_mm": 150.0})]


def test_scenarios_switch_mirroring_off_only_in_the_paper_scenario() -> None:
    from skelfuse.sim.observe import load_profile

    default = load_profile()
    assert default.flip_on_prob > 0
    assert paper.scenario_profile(default, "rear_mirroring") == default
    paper_profile = paper.scenario_profile(default, "paper")
    assert paper_profile.flip_on_prob == 0.0
    assert paper_profile == dataclasses.replace(default, flip_on_prob=0.0)  # nothing else changes
    with pytest.raises(ValueError, match="scenario"):
        paper.scenario_profile(default, "mirror")
    tasks = paper.plan_takes(
        quick=True, seed=3, duration_s=1.0, profile_path=None, gestures=("jump",), scenarios=paper.SCENARIOS
    )
    by_scenario = {t.scenario: t for t in tasks if t.facing_deg == 0.0}
    # Common random numbers: the same take has the same seeds in every scenario.
    assert by_scenario["paper"].sim_seed == by_scenario["rear_mirroring"].sim_seed
    with pytest.raises(ValueError, match="scenario"):
        paper.plan_takes(quick=True, seed=0, duration_s=1.0, profile_path=None, scenarios=("nope",))


def test_takes_have_distinct_seeds_and_follow_the_plan() -> None:
    tasks = paper.plan_takes(
        quick=False,
        seed=3,
        duration_s=2.0,
        profile_path=None,
        gestures=("jump", "squat", "lunge"),
        directions_deg=(0, 90, 180, 270),
    )
    assert len(tasks) == 12
    assert len({t.sim_seed for t in tasks}) == 12
    again = paper.plan_takes(
        quick=False,
        seed=3,
        duration_s=2.0,
        profile_path=None,
        gestures=("jump", "squat", "lunge"),
        directions_deg=(0, 90, 180, 270),
    )
    assert [t.sim_seed for t in tasks] == [t.sim_seed for t in again]
    with pytest.raises(ValueError, match="duration_s"):
        paper.plan_takes(quick=True, seed=0, duration_s=0.0, profile_path=None, gestures=("jump",))


def _fake_take(gesture: str, facing: float, rng: np.random.Generator, scale: dict[str, float]) -> paper.TakeResult:
    """A take result whose every output has errors of a known size: ``scale[key]`` mm along x per joint,
    with joint k of the 16 eval joints displaced by (k + 1) * scale."""
    keys = [*(f"raw[{s}]" for s in range(4)), paper.BEST_VIEW_RAW, *(r.key for r in paper.fusion_runs(4))]
    n_frames = 20
    ref = rng.normal(0.0, 100.0, (n_frames, len(EVAL_JOINTS), 3))
    errors = {}
    lag = {}
    jitter = {paper.EXACT_TRUTH: {g: (1.0 * n_frames, n_frames) for g in JOINT_GROUPS}}
    for key in keys:
        est = ref.copy()
        est[..., 0] += scale.get(key, 10.0) * (np.arange(len(EVAL_JOINTS)) + 1.0)
        protocols = ("truth",) if key == paper.BEST_VIEW_RAW else paper.PROTOCOLS
        errors[key] = {p: ErrorAccumulator.zeros(len(EVAL_JOINTS)).add(est, ref) for p in protocols}
        lag[key] = {g: lag_error_curve(est[:, :2], ref[:, :2], paper.LAG_SHIFTS) for g in JOINT_GROUPS}
        # Jitter sums whose RMS is the scale: scale² x n over n samples.
        jitter[key] = {g: (scale.get(key, 10.0) ** 2 * n_frames, n_frames) for g in JOINT_GROUPS}
    info = {
        "gesture": gesture,
        "facing_deg": facing,
        "n_frames": n_frames,
        "tracked_fraction": [1.0] * 5,
        "mirrored_fraction": [0.0] * 5,
        "simulate_s": 0.0,
        "fuse_s": 0.0,
        "n_fusion_steps": 0,
    }
    return paper.TakeResult(gesture, facing, errors, lag, info, jitter=jitter)


_FAKE_SETTINGS = {
    "quick": True,
    "seed": 0,
    "gestures": ["jump", "squat"],
    "directions_deg": [0.0, 180.0],
    "duration_s": 1.0,
    "fps": 30.0,
    "eps_mm": list(paper.EPS_MM),
    "ours": ["skelfuse"],
    "workers": 1,
    "n_takes": 4,
}


def _fake_result(scale: dict[str, float], scenario: str = "rear_mirroring") -> paper.PaperEvalResult:
    rng = np.random.default_rng(1124)
    takes = [_fake_take(g, d, rng, scale) for g in _FAKE_SETTINGS["gestures"] for d in (0.0, 180.0)]
    return paper.collect(takes, {**_FAKE_SETTINGS, "scenario": scenario})


def test_group_value_is_the_mean_of_its_joints_and_rows_average_their_members() -> None:
    scale = {"A3_50": 1.0, "A3_100": 2.0, "A3_150": 3.0, "A3_200": 6.0}
    result = _fake_result(scale)
    # Joint k (in EVAL_JOINTS order) is off by (k + 1) * scale; the row "A3" averages its four eps runs.
    col = {int(j): k for k, j in enumerate(EVAL_JOINTS)}
    groups = result.group_stats("algorithms", "A3", "truth")
    mean_scale = np.mean(list(scale.values()))
    for g, idx in JOINT_GROUPS.items():
        expected = mean_scale * np.mean([col[int(j)] + 1.0 for j in idx])
        assert groups[g]["ae_mm"] == pytest.approx(expected)
        assert groups[g]["rmse_mm"] == pytest.approx(expected)
        assert groups[g]["std_mm"] == pytest.approx(0.0, abs=1e-6)
    # The eps sweep keeps the members apart.
    assert result.group_stats("eps_sweep", "A3_200", "truth")["torso"]["ae_mm"] == pytest.approx(
        6.0 * np.mean([col[int(j)] + 1.0 for j in JOINT_GROUPS["torso"]])
    )
    # Two directions x 20 frames pooled per gesture, two gestures: 80 frames per joint and output.
    assert result.joint_stats("algorithms", "A1", "truth").n_frames.tolist() == [80] * len(EVAL_JOINTS)
    assert result.members("n_sensors", "2") == paper.sensor_combinations(4)[2]
    assert result.members("n_sensors", "skelfuse_3") == paper.sensor_combinations(4, algorithm="skelfuse")[3]


def test_rows_mark_ours_and_average_lag_and_jitter_over_their_members() -> None:
    scale = {"A5_50": 1.0, "A5_100": 2.0, "A5_150": 3.0, "A5_200": 6.0, "skelfuse": 0.5}
    result = _fake_result(scale)
    assert result.experiment_configs("algorithms") == ["A1", "A2", "A3", "A4", "A5", "skelfuse"]
    assert result.experiment_configs("n_sensors") == ["1", "2", "3", "4", "skelfuse_2", "skelfuse_3", "skelfuse_4"]
    assert paper.is_ours("skelfuse_3") and paper.is_ours("skelfuse[0,1]") and not paper.is_ours("A5_100[0,1]")
    # Jitter of a row = mean over its eps members of the pooled RMS (each member's RMS is its scale).
    assert result.row_jitter("algorithms", "A5", "upper_limb") == pytest.approx(3.0)
    assert result.row_jitter("algorithms", "skelfuse", "torso") == pytest.approx(0.5)
    assert result.jitter[paper.EXACT_TRUTH]["torso"] == pytest.approx(1.0)
    lags = [result.lag[k]["torso"]["lag_frames"] for k in result.members("algorithms", "A5")]
    assert result.row_lag("algorithms", "A5", "torso") == pytest.approx(np.mean(lags))
    # The paper has no figure for our rows.
    assert result.paper_value("algorithms", "skelfuse", "ae_mm", "torso") is None
    assert result.paper_value("n_sensors", "skelfuse_4", "ae_mm", "torso") is None
    assert result.paper_value("n_sensors", "4", "ae_mm", "torso") == 39.6


@pytest.mark.live
def test_report_files_markdown_and_json(tmp_path) -> None:
    from skelfuse.eval.report import write_report

    result = _fake_result({"A1": 20.0})
    paths = write_report(result, tmp_path / "out")
    names = {p.name for p in paths}
    for exp in paper.EXPERIMENTS:
        for protocol in paper.PROTOCOLS:
            assert f"{exp}_{protocol}_joints.csv" in names and f"{exp}_{protocol}_groups.csv" in names
    assert {
        "report.md",
        "result.json",
        "lag.csv",
        "fig09_algorithms.png",
        "fig10_eps.png",
        "fig11_n_sensors.png",
    } <= names
    for p in paths:
        assert p.exists() and p.stat().st_size > 0
    assert (tmp_path / "out" / "fig09_algorithms.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = report.format_markdown(result)
    assert "Experiment 1" in md and "Experiment 3" in md and "| A5 | paper |" in md
    assert "| **skelfuse (ours)** | **ours** |" in md and "| **4 sensors, skelfuse (ours)** | **ours** |" in md
    assert "39.1 ± 9.6" in md  # the paper's A5 at eps 10 cm, printed beside ours
    assert "jitter (mm/frame²)" in md
    data = json.loads((tmp_path / "out" / "result.json").read_text())
    assert data["scenario"] == "rear_mirroring"
    algorithms = data["experiments"]["algorithms"]["truth"]
    assert algorithms["A1"]["paper"]["upper_limb"]["ae_mm"] == 90.9
    assert algorithms["skelfuse"]["algorithm"] == "ours" and algorithms["A5"]["algorithm"] == "paper"
    assert algorithms["skelfuse"]["jitter_mm_per_frame2"]["torso"] == pytest.approx(10.0)
    assert set(data["experiments"]["n_sensors"]["truth"]) == {
        "1",
        "2",
        "3",
        "4",
        "skelfuse_2",
        "skelfuse_3",
        "skelfuse_4",
    }
    json.dumps(result.to_dict(), allow_nan=False)  # strictly JSON (NaN -> null)
    joints_csv = (tmp_path / "out" / "algorithms_truth_joints.csv").read_text().splitlines()
    assert joints_csv[0].startswith("config,gesture,joint,ae_mm,rmse_mm,std_mm")
    assert joints_csv[0].endswith(",algorithm")
    assert len(joints_csv) == 1 + 6 * 3 * len(EVAL_JOINTS)  # 6 rows x ("all" + 2 gestures) x 16 joints
    assert sum(line.endswith(",ours") for line in joints_csv) == 3 * len(EVAL_JOINTS)


def test_summary_puts_both_scenarios_beside_the_paper() -> None:
    suite = paper.PaperEvalSuite(
        {name: _fake_result({"skelfuse": 1.0}, name) for name in paper.SCENARIOS},
        {**_FAKE_SETTINGS, "scenarios": list(paper.SCENARIOS)},
    )
    summary = report.format_markdown(suite)
    assert "paper: vs truth" in summary and "rear_mirroring: vs best view" in summary
    assert "rear_mirroring: jitter" in summary and "paper: swapped" in summary
    assert "| **skelfuse (ours)** | **ours** |" in summary and "| 1 sensor (raw) | raw |" in summary
    assert "| A5 | paper |" in summary and "40 / 56 / 36 |" in summary  # the paper's A5 figure beside ours
    data = suite.to_dict()
    json.dumps(data, allow_nan=False)
    assert set(data["scenarios"]) == set(paper.SCENARIOS)
    assert data["scenarios"]["paper"]["scenario"] == "paper"


def test_paper_reference_figures_are_the_text_values() -> None:
    assert paper_reference.ALGORITHMS["A5"]["ae_mm"] == {
        "torso": 39.9,
        "upper_limb": 55.9,
        "lower_limb": 36.2,
    }
    assert paper_reference.reference_value("eps_sweep", 100, "ae_mm", "upper_limb") == 51.6
    assert paper_reference.reference_value("n_sensors", 1, "std_mm", "upper_limb") == 64.2
    assert paper_reference.reference_value("algorithms", "A2", "ae_mm", "torso") is None
    # The paper's numbers fall with the number of sensors in every group.
    for g in paper_reference.GROUPS:
        values = [paper_reference.N_SENSORS[n]["ae_mm"][g] for n in (1, 2, 3, 4)]
        assert values == sorted(values, reverse=True)


def test_progress_draws_only_when_enabled() -> None:
    stream = io.StringIO()  # not a TTY: quiet by default
    with Progress(3, "x", stream=stream) as bar:
        bar.update()
    assert stream.getvalue() == ""
    ticks = iter(range(100))
    forced = io.StringIO()
    with Progress(2, "eval", stream=forced, enabled=True, min_interval_s=0.0, clock=lambda: next(ticks)) as bar:
        bar.update(note="jump 0°")
        bar.update()
    text = forced.getvalue()
    assert "eval [" in text and "2/2" in text and "jump 0°" in text and text.endswith("\n")


# ------------------------------------------------------------------------------------------------------------
# End to end on the simulator and the fusion core.


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    """Both scenarios, 3 gestures x 2 directions x 5 s, seed 1124 (about 20 s on one core)."""
    out = tmp_path_factory.mktemp("paper")
    suite = paper.run_paper_eval(
        quick=True,
        seed=1124,
        progress=False,
        gestures=("hands_up_down", "squat", "walking"),
        directions_deg=(0.0, 180.0),
        duration_s=5.0,
    )
    report.write_suite(suite, out)
    return suite, out


def _upper(result: paper.PaperEvalResult, experiment: str, config: str, group: str = "upper_limb") -> float:
    return result.group_stats(experiment, config, "truth")[group]["rmse_mm"]


def test_quick_run_writes_files_and_finite_results(quick_run) -> None:
    suite, out = quick_run
    assert list(suite.scenarios) == list(paper.SCENARIOS)
    for file in ("report.md", "result.json", "summary_algorithms.png", "summary_n_sensors.png"):
        assert str(out / file) in suite.files and (out / file).stat().st_size > 0
    summary = (out / "report.md").read_text()
    assert "Experiment 1" in summary and "rear_mirroring: vs truth" in summary and "(ours)" in summary
    data = suite.to_dict()
    json.dumps(data, allow_nan=False)
    assert set(data["scenarios"]) == set(paper.SCENARIOS)
    assert set(json.loads((out / "result.json").read_text())["scenarios"]) == set(paper.SCENARIOS)
    for name, result in suite.scenarios.items():
        for file in ("report.md", "result.json", "fig09_algorithms.png", "algorithms_truth_groups.csv"):
            assert (out / name / file).stat().st_size > 0
        for exp in paper.EXPERIMENTS:
            for protocol in paper.PROTOCOLS:
                for config in result.experiment_configs(exp):
                    for g, v in result.group_stats(exp, config, protocol).items():
                        assert math.isfinite(v["rmse_mm"]) and v["rmse_mm"] > 0, (name, exp, protocol, config, g)
        assert "skelfuse" in result.experiment_configs("algorithms")
        for key in ("A5_100", "skelfuse"):
            assert all(math.isfinite(v["lag_frames"]) for v in result.lag[key].values())
            assert all(math.isfinite(v) and v > 0 for v in result.jitter[key].values())


def test_paper_scenario_has_no_mirrored_view_and_rear_views_mirror_otherwise(quick_run) -> None:
    suite, _ = quick_run
    assert all(max(t["mirrored_fraction"]) == 0.0 for t in suite["paper"].takes)
    # Without mirroring a pair ends up swapped only where left and right cross (A5's lag: ~0.2%).
    assert all(suite["paper"].swapped[k] < 0.01 for k in ("A1", "A5_100", "skelfuse"))
    mirrored = [np.mean(t["mirrored_fraction"][:4]) for t in suite["rear_mirroring"].takes]
    assert np.mean(mirrored) > 0.2


# ---- The paper's claims, in the paper's conditions (no mirrored view), against exact truth.
# Measured on this quick run (3 gestures x 2 directions x 5 s, seed 1124), RMSE torso / upper / lower, mm:
#   A1 16.8 / 24.4 / 22.0, A3 16.9 / 23.5 / 22.0, A4 16.8 / 23.5 / 22.1, A5 113 / 192 / 110,
#   1 sensor (raw) 30.0 / 44.9 / 43.4, 4 sensors A5 113 / 191 / 110, A3 eps 100 mm 16.8 / 22.8 / 21.2,
#   skelfuse 16.8 / 22.5 / 21.1 (2 sensors 22.4 / 31.3 / 30.5, 3 sensors 18.9 / 25.6 / 24.5).
# The full default run (6 x 4 x 33 s, seed 0) shows the same pattern: A1 18.5 / 32.4 / 26.2, A3 18.2 / 31.1 / 25.3,
# A5 104 / 174 / 101, 1 sensor 32 / 60 / 47, skelfuse 18.6 / 31.6 / 24.4.

_NO_MARGIN = (
    "measured: without mirrored views all four views agree within DBSCAN's radius, so DBSCAN (A3/A4) merges the "
    "same candidates as the plain average and is only ~4% better on upper limbs (23.5 vs 24.4 mm), not the "
    "paper's 27-34%; A5 is far worse (192 mm) because the paper's Kalman (Q=0.01, R=1) lags ~9 frames"
)
_A5_LAGS = (
    "measured: A5 with 4 sensors is worse than one raw sensor (torso 113 vs 30 mm, upper limb 191 vs 45 mm) "
    "because the paper's Kalman (Q=0.01, R=1) lags ~9 frames; the merge alone (A3, no filter) does beat one "
    "sensor, see test_paper_scenario_merging_four_sensors_beats_one"
)


def test_paper_scenario_dbscan_is_no_worse_than_the_plain_average(quick_run) -> None:
    """The direction of the paper's Figure 9 holds without mirroring: A3 and A4 are at least as good as A1 on
    the upper limbs (the size of the gain does not, see the xfail below)."""
    result = quick_run[0]["paper"]
    a1 = _upper(result, "algorithms", "A1")
    for config in ("A3", "A4"):
        assert _upper(result, "algorithms", config) <= a1, config


@pytest.mark.xfail(strict=True, reason=_NO_MARGIN)
def test_paper_scenario_fusion_beats_plain_average_on_upper_limbs(quick_run) -> None:
    """The paper's central claim, against exact truth: DBSCAN fusion (best of A3-A5) beats the plain average
    (A1) on the upper limbs by a clear margin (paper: 55.9-66.0 vs 90.9 mm)."""
    result = quick_run[0]["paper"]
    a1 = _upper(result, "algorithms", "A1")
    best = min(_upper(result, "algorithms", c) for c in ("A3", "A4", "A5"))
    assert best < 0.85 * a1, f"A3-A5 best {best:.1f} mm vs A1 {a1:.1f} mm on upper limbs"


@pytest.mark.xfail(strict=True, reason=_A5_LAGS)
def test_paper_scenario_four_sensors_beat_one(quick_run) -> None:
    """The paper's Figure 11 (A5 at eps 100 mm, 1 = raw): error falls from 1 to 4 sensors in every group."""
    result = quick_run[0]["paper"]
    for g in ("torso", "upper_limb", "lower_limb"):
        one, four = _upper(result, "n_sensors", "1", g), _upper(result, "n_sensors", "4", g)
        assert four < one, f"{g}: 4 sensors {four:.1f} mm vs 1 sensor {one:.1f} mm"


def test_paper_scenario_merging_four_sensors_beats_one(quick_run) -> None:
    """Without the lagging filter, the paper's merge (A3, eps 100 mm) of four views beats one raw view by a
    clear margin in every group (measured 16.8 / 22.8 / 21.2 vs 30.0 / 44.9 / 43.4 mm)."""
    result = quick_run[0]["paper"]
    raw = result.group_stats("n_sensors", "1", "truth")
    merged = result.group_stats_key("A3_100", "truth")
    for g in ("torso", "upper_limb", "lower_limb"):
        assert merged[g]["rmse_mm"] < 0.75 * raw[g]["rmse_mm"], g


# ---- The same claims with rear views mirrored (the default simulator): the paper's algorithm fails them.

_MIRRORED = (
    "measured with rear views mirrored (two of four views, ~40% of frames): the paper's per-pair realignment "
    "cannot out-vote a 2-against-2 split, ~35% of fused limb pairs stay swapped and DBSCAN then picks whole "
    "mirrored clusters: A1 265, A3 355, A4 317, A5 292 mm on upper limbs; A5 with 4 sensors 150 / 288 / 153 vs "
    "one raw sensor 103 / 384 / 165 mm (torso / upper / lower)"
)


@pytest.mark.xfail(strict=True, reason=_MIRRORED)
def test_rear_mirroring_fusion_beats_plain_average_on_upper_limbs(quick_run) -> None:
    result = quick_run[0]["rear_mirroring"]
    a1 = _upper(result, "algorithms", "A1")
    best = min(_upper(result, "algorithms", c) for c in ("A3", "A4", "A5"))
    assert best < 0.85 * a1, f"A3-A5 best {best:.1f} mm vs A1 {a1:.1f} mm on upper limbs"


@pytest.mark.xfail(strict=True, reason=_MIRRORED)
def test_rear_mirroring_four_sensors_beat_one(quick_run) -> None:
    result = quick_run[0]["rear_mirroring"]
    for g in ("torso", "upper_limb", "lower_limb"):
        one, four = _upper(result, "n_sensors", "1", g), _upper(result, "n_sensors", "4", g)
        assert four < one, f"{g}: 4 sensors {four:.1f} mm vs 1 sensor {one:.1f} mm"


# ---- Ours, in both scenarios, against exact truth.


_OURS_NO_MARGIN_OVER_A1 = (
    "measured: without mirrored views the plain average is already close to the views' shared error; skelfuse "
    "is 8% better than A1 on upper limbs in this quick run (22.5 vs 24.4 mm) and only 2.5% in the full default "
    "run (31.6 vs 32.4 mm), where it is worse on 'jump' (44.2 vs 35.3 mm), a gesture this quick run lacks"
)


@pytest.mark.parametrize(
    "scenario",
    [
        pytest.param("paper", marks=pytest.mark.xfail(strict=True, reason=_OURS_NO_MARGIN_OVER_A1), id="paper"),
        # With mirroring ours keeps its accuracy (23.0 mm here, 31.4 mm in the full run) while A1 is at 265 mm.
        pytest.param("rear_mirroring", id="rear_mirroring"),
    ],
)
def test_skelfuse_beats_a1_on_upper_limbs_by_a_clear_margin(quick_run, scenario: str) -> None:
    result = quick_run[0][scenario]
    ours, a1 = _upper(result, "algorithms", "skelfuse"), _upper(result, "algorithms", "A1")
    assert ours < 0.85 * a1, f"skelfuse {ours:.1f} mm vs A1 {a1:.1f} mm"


@pytest.mark.parametrize("scenario", paper.SCENARIOS)
def test_skelfuse_beats_a5_on_upper_limbs_without_lag_or_swaps(quick_run, scenario: str) -> None:
    result = quick_run[0][scenario]
    ours, a5 = _upper(result, "algorithms", "skelfuse"), _upper(result, "algorithms", "A5")
    assert ours < 0.25 * a5, f"skelfuse {ours:.1f} mm vs A5 {a5:.1f} mm"
    assert result.row_swapped("algorithms", "skelfuse") < 0.01
    assert all(abs(result.row_lag("algorithms", "skelfuse", g)) < 1.0 for g in ("torso", "upper_limb"))


@pytest.mark.parametrize("scenario", paper.SCENARIOS)
def test_skelfuse_with_four_sensors_beats_one(quick_run, scenario: str) -> None:
    result = quick_run[0][scenario]
    for g in ("torso", "upper_limb", "lower_limb"):
        one, four = _upper(result, "n_sensors", "1", g), _upper(result, "n_sensors", "skelfuse_4", g)
        assert four < 0.75 * one, f"{g}: skelfuse 4 sensors {four:.1f} mm vs 1 sensor {one:.1f} mm"


def test_fused_orientations_are_scored_against_truth_and_beat_the_views(quick_run) -> None:
    """The orientation table: ours against the simulator's true orientations, finite, and better than the
    raw views (in the rear-mirroring scenario the mirrored rear views are about 180 deg off; ours leaves them
    out)."""
    suite, out = quick_run
    assert "Fused orientations against the true orientations" in (out / "report.md").read_text()
    for name, result in suite.scenarios.items():
        assert "Fused orientations, against the true orientations" in (out / name / "report.md").read_text()
        ours = result.orientation["skelfuse"]
        for g in paper.GROUP_NAMES:
            assert ours[g]["n"] > 0 and math.isfinite(ours[g]["median_deg"]), (name, g)
            raw = [result.orientation[f"raw[{i}]"][g]["median_deg"] for i in range(paper.N_CAPTURE)]
            assert ours[g]["median_deg"] < min(raw), (name, g, ours[g], raw)
        assert ours["torso"]["median_deg"] < 10.0
        assert json.loads((out / name / "result.json").read_text())["orientation_error_deg"]["skelfuse"]


def test_orientations_do_not_change_the_fused_positions() -> None:
    from skelfuse.fusion.orientation import aim_directions, views_to_world
    from skelfuse.schema.skeleton import ORIENTATION_DERIVED_SOURCE
    from skelfuse.sim.gestures import make_gesture
    from skelfuse.sim.observe import load_profile, simulate
    from skelfuse.sim.orientation import observe_orientations, truth_orientations
    from skelfuse.sim.rig import paper_rig

    motion = make_gesture("squat", duration_s=1.0, fps=30.0, facing_deg=0.0, seed=2)
    obs = simulate(motion, list(paper_rig(4)), load_profile(), seed=3)
    world = paper._world_skeletons(obs)
    quats = views_to_world(
        observe_orientations(obs, truth_orientations(obs.truth, 30.0, seed=3), seed=3), obs.world_from_sensor_calibrated
    )
    run = paper.FusionRun("skelfuse", "skelfuse", None, (0, 1, 2, 3))
    plain = paper.fuse_take(run, world, obs.confidence, 30.0)
    oriented, fused_quats = paper.fuse_take_oriented(run, world, obs.confidence, quats, 30.0)
    np.testing.assert_array_equal(plain, oriented)
    # The preset as the live node runs it (orientations and position uncertainty on) fuses the same positions
    # as these runs, which leave the outputs they do not score off.
    fuser = paper.Fuser(run.params(), n_bodies=1)
    assert fuser.params.orientations and fuser.params.position_std
    live = [fuser.step(world[t][None], obs.confidence[t][None], dt_s=1 / 30.0).positions[0] for t in range(len(world))]
    np.testing.assert_array_equal(plain, np.array(live))
    # an orientation wherever its bone is known (a hand that no view saw yet has none, nor has its wrist)
    knowable = np.isfinite(aim_directions(plain)).all(axis=-1)[..., ORIENTATION_DERIVED_SOURCE]
    assert knowable[:, :26].mean() > 0.9
    assert np.isfinite(fused_quats[knowable]).all()


def test_the_experiment_gives_every_fusion_run_the_positions_of_its_own_sensors(monkeypatch) -> None:
    """The live node knows where its sensors stand (the rear-view rule of the temporal realignment needs it);
    the paper experiment must fuse with the same knowledge, each run with the positions of the sensors it uses.
    Runs fuse side by side, each body with its own sensors' positions: the last test below shows that gives the
    same positions bit for bit."""
    from skelfuse.sim.gestures import make_gesture
    from skelfuse.sim.observe import load_profile, simulate
    from skelfuse.sim.rig import best_view_sensor, paper_rig

    task = paper.TakeTask("squat", 0.0, 1.0, 30.0, 4, 5, None, (100.0,))
    seen: list[tuple[str | None, np.ndarray | None]] = []
    real_fuser = paper.Fuser

    def spy(params, n_bodies=1, sensor_positions=None):
        positions = None if sensor_positions is None else np.array(sensor_positions)
        per_body = positions if positions is not None and positions.ndim == 3 else [positions] * n_bodies
        seen.extend((params.realign, body) for body in per_body)  # what each fused body is given
        return real_fuser(params, n_bodies=n_bodies, sensor_positions=sensor_positions)

    monkeypatch.setattr(paper, "Fuser", spy)
    paper.evaluate_take(task)
    # the same take, simulated the same way: where its capture sensors stand
    motion = make_gesture("squat", duration_s=1.0, fps=30.0, facing_deg=0.0, seed=4)
    sensors = [*list(paper_rig(paper.N_CAPTURE)), best_view_sensor(0.0)]
    obs = simulate(motion, sensors, paper.scenario_profile(load_profile(None), "rear_mirroring"), seed=5)
    where = obs.world_from_sensor_calibrated[: paper.N_CAPTURE, :3, 3]
    runs = paper.fusion_runs(paper.N_CAPTURE, (100.0,), ours=(paper.OURS,))
    temporal = [run for run in runs if run.params().realign == "temporal"]
    given = [positions for realign, positions in seen if realign == "temporal"]
    assert temporal and len(given) == len(temporal)
    for run in temporal:  # one fused body per such run, given the positions of exactly its sensors
        matches = [
            k
            for k, p in enumerate(given)
            if p is not None and p.shape == (len(run.sensors), 3) and np.allclose(p, where[list(run.sensors)])
        ]
        assert matches, run.key
        given.pop(matches[0])


def test_runs_fused_side_by_side_equal_each_run_fused_alone() -> None:
    from skelfuse.sim.gestures import make_gesture
    from skelfuse.sim.observe import load_profile, simulate
    from skelfuse.sim.rig import paper_rig

    motion = make_gesture("walking", duration_s=1.0, fps=30.0, facing_deg=150.0, seed=6)
    obs = simulate(motion, list(paper_rig(paper.N_CAPTURE)), load_profile(), seed=7)
    world, confidence = paper._world_skeletons(obs), np.asarray(obs.confidence)
    where = obs.world_from_sensor_calibrated[:, :3, 3]
    runs = paper.fusion_runs(paper.N_CAPTURE)
    together = paper.fuse_runs(runs, world, confidence, 30.0, where)
    assert list(together) == [run.key for run in runs]
    for run in runs:
        alone = paper.fuse_take(run, world, confidence, 30.0, where)
        assert np.isfinite(alone).any(), run.key
        np.testing.assert_array_equal(together[run.key], alone, err_msg=run.key)
