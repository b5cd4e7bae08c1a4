"""``skelfuse eval paper``: experiment bookkeeping, report files, and a seeded end-to-end run."""

from __future__ import annotations

import io
import json
import math

import numpy as np
import pytest

from skelfuse.eval import paper, paper_reference
from skelfuse.eval.metrics import ErrorAccumulator, lag_error_curve
from skelfuse.eval.progress import Progress
from skelfuse.skeleton import EVAL_JOINTS, JOINT_GROUPS

# ------------------------------------------------------------------------------------------------------------
# Bookkeeping.


def test_experiment3_uses_every_combination_4_6_4_1() -> None:
    combos = paper.sensor_combinations(4)
    assert {n: len(keys) for n, keys in combos.items()} == {1: 4, 2: 6, 3: 4, 4: 1}
    assert combos[1] == ["raw[0]", "raw[1]", "raw[2]", "raw[3]"]
    assert combos[4] == ["A5_100"]
    assert "A5_100[0,3]" in combos[2] and "A5_100[1,2,3]" in combos[3]
    assert paper_reference.N_SENSORS_COMBINATIONS == {n: len(k) for n, k in combos.items()}


def test_fusion_runs_cover_the_grid_and_the_subsets_once() -> None:
    runs = paper.fusion_runs(4)
    keys = [r.key for r in runs]
    assert len(keys) == len(set(keys))
    # A1, A2, 3 presets x 4 eps on all sensors, then A5 on the 6 pairs and 4 triples.
    assert len(runs) == 2 + 3 * 4 + 6 + 4
    assert {r.key for r in runs if len(r.sensors) == 4} == {
        "A1",
        "A2",
        *(f"A{n}_{e}" for n in (3, 4, 5) for e in (50, 100, 150, 200)),
    }
    assert all(r.preset == "A5" and r.eps_mm == 100.0 for r in runs if len(r.sensors) < 4)
    # Every key experiment 3 averages is produced by a run or is a raw sensor.
    produced = set(keys) | {f"raw[{s}]" for s in range(4)}
    assert all(k in produced for ks in paper.sensor_combinations(4).values() for k in ks)


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
    for key in keys:
        est = ref.copy()
        est[..., 0] += scale.get(key, 10.0) * (np.arange(len(EVAL_JOINTS)) + 1.0)
        protocols = ("truth",) if key == paper.BEST_VIEW_RAW else paper.PROTOCOLS
        errors[key] = {p: ErrorAccumulator.zeros(len(EVAL_JOINTS)).add(est, ref) for p in protocols}
        lag[key] = {g: lag_error_curve(est[:, :2], ref[:, :2], paper.LAG_SHIFTS) for g in JOINT_GROUPS}
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
    return paper.TakeResult(gesture, facing, errors, lag, info)


def _fake_result(scale: dict[str, float]) -> paper.PaperEvalResult:
    rng = np.random.default_rng(1124)
    gestures = ["jump", "squat"]
    takes = [_fake_take(g, d, rng, scale) for g in gestures for d in (0.0, 180.0)]
    settings = {
        "quick": True,
        "seed": 0,
        "gestures": gestures,
        "directions_deg": [0.0, 180.0],
        "duration_s": 1.0,
        "fps": 30.0,
        "eps_mm": list(paper.EPS_MM),
        "n_takes": len(takes),
    }
    return paper.collect(takes, settings)


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
    md = paper.format_markdown(result)
    assert "Experiment 1" in md and "Experiment 3" in md and "| A5 |" in md
    assert "39.1 ± 9.6" in md  # the paper's A5 at eps 10 cm, printed beside ours
    data = json.loads((tmp_path / "out" / "result.json").read_text())
    assert data["experiments"]["algorithms"]["truth"]["A1"]["paper"]["upper_limb"]["ae_mm"] == 90.9
    assert set(data["experiments"]["n_sensors"]["truth"]) == {"1", "2", "3", "4"}
    json.dumps(result.to_dict(), allow_nan=False)  # strictly JSON (NaN -> null)
    joints_csv = (tmp_path / "out" / "algorithms_truth_joints.csv").read_text().splitlines()
    assert joints_csv[0].startswith("config,gesture,joint,ae_mm,rmse_mm,std_mm")
    assert len(joints_csv) == 1 + 5 * 3 * len(EVAL_JOINTS)  # 5 rows x ("all" + 2 gestures) x 16 joints


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


def _require_core() -> None:
    for module in (
        "skelfuse.fusion.pipeline",
        "skelfuse.sim.observe",
        "skelfuse.sim.rig",
        "skelfuse.sim.gestures",
    ):
        pytest.importorskip(module)


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    _require_core()
    out = tmp_path_factory.mktemp("paper")
    result = paper.run_paper_eval(
        out_dir=out,
        quick=True,
        seed=1124,
        progress=False,
        gestures=("hands_up_down", "squat", "walking"),
        directions_deg=(0.0, 180.0),
        duration_s=5.0,
    )
    return result, out


def test_quick_run_writes_files_and_finite_results(quick_run) -> None:
    result, out = quick_run
    for name in ("report.md", "result.json", "fig09_algorithms.png", "algorithms_truth_groups.csv"):
        assert (out / name).stat().st_size > 0
    for exp in paper.EXPERIMENTS:
        for protocol in paper.PROTOCOLS:
            for config in result.experiment_configs(exp):
                for g, v in result.group_stats(exp, config, protocol).items():
                    assert math.isfinite(v["rmse_mm"]) and v["rmse_mm"] > 0, (exp, protocol, config, g)
    data = result.to_dict()
    json.dumps(data, allow_nan=False)
    assert all(math.isfinite(v["lag_frames"]) for v in result.lag["A5_100"].values())


# The two claims below are the paper's; they FAIL on the current simulator + fusion core, and are marked
# xfail(strict) so that they turn red again (XPASS) the day they hold. Cause, from `skelfuse eval paper`: with
# the subject facing between sensors (paper_rig 45°/135°/..., facing 0/90/180/270), two of the four capture
# views are rear views, mirrored ~43% of frames; the paper's per-pair realignment (reference = mean of all
# candidates) cannot resolve a 2-against-2 split, so 31-39% of fused limb pairs stay left/right swapped (A1-A5)
# and the paper's Kalman (Q=0.01, R=1) makes A5 lag ~8-9 frames (torso ~99 mm on walking).
_CLAIM_FAILS = (
    "fails today: rear views mirrored ~43% of frames defeat the paper's realignment (31-39% of fused limb pairs "
    "swapped) and the paper Kalman lags ~8-9 frames; see the comment above and the eval paper report"
)


@pytest.mark.xfail(strict=True, reason=_CLAIM_FAILS)
def test_fusion_beats_plain_average_on_upper_limbs(quick_run) -> None:
    """The paper's central claim, against exact truth: DBSCAN fusion (A5) beats the plain average (A1) on the
    upper limbs by a clear margin (paper: 55.9 vs 90.9 mm)."""
    result, _ = quick_run
    a1 = result.group_stats("algorithms", "A1", "truth")["upper_limb"]["rmse_mm"]
    best = min(result.group_stats("algorithms", c, "truth")["upper_limb"]["rmse_mm"] for c in ("A3", "A4", "A5"))
    assert best < 0.85 * a1, f"A3-A5 best {best:.1f} mm vs A1 {a1:.1f} mm on upper limbs"


@pytest.mark.xfail(strict=True, reason=_CLAIM_FAILS)
def test_four_sensors_beat_one(quick_run) -> None:
    result, _ = quick_run
    for g in ("torso", "upper_limb", "lower_limb"):
        one = result.group_stats("n_sensors", "1", "truth")[g]["rmse_mm"]
        four = result.group_stats("n_sensors", "4", "truth")[g]["rmse_mm"]
        assert four < one, f"{g}: 4 sensors {four:.1f} mm vs 1 sensor {one:.1f} mm"
