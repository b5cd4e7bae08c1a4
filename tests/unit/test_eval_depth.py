"""``skelfuse eval depth``: its logic on simulated input (the stand-in tracker, the truth known), and its
refusal, naming what is missing, where the SDK is not installed (as here)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skelfuse.cli import main
from skelfuse.eval.depth import evaluate_depth, sim_tracker, simulated_instants
from skelfuse.fusion.presets import preset
from skelfuse.rig.instant import GroupFuser
from skelfuse.schema.skeleton import EVAL_JOINTS

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def crossing():
    return simulated_instants("crossing", 1.0, 3, max_instants=12)


def test_the_three_modes_on_one_take_against_the_truth(crossing) -> None:
    instants, obs = crossing
    result = evaluate_depth(instants, obs.sensor_ids, obs.world_from_sensor_calibrated, sim_tracker, progress=False)
    assert result.instants == len(instants) == 12 and result.tracker == "simulated"
    # skeleton mode: exactly what a GroupFuser makes of the same instants, scored independently here
    fuser = GroupFuser(obs.sensor_ids, obs.world_from_sensor_calibrated, preset("skelfuse"))
    errors = []
    for instant in instants:
        for person in fuser.step(instant.group).frame.positions:
            errors.append(
                min(np.nanmean(np.linalg.norm(person[EVAL_JOINTS] - t[EVAL_JOINTS], axis=-1)) for t in instant.truth)
            )
    np.testing.assert_allclose(result.figures["skeleton"].error_mm, errors)
    depth, hybrid = result.figures["depth"], result.figures["hybrid"]
    assert depth.persons > 0 and hybrid.persons > 0
    assert len(depth.agreement_mm) == depth.persons  # every depth person has its skeleton track
    assert len(result.tracker_ms) >= depth.persons  # one timed tracker call per person and mode
    assert np.median(depth.error_mm) < 60.0 and np.median(hybrid.error_mm) < 60.0
    table = result.table()
    assert "| depth |" in table and "| hybrid |" in table and "tracker (simulated)" in table


def test_without_the_sdk_it_stops_at_once_naming_what_is_missing(tmp_path: Path, capsys) -> None:
    takes = []
    for sensor_id in ("000123412512", "000234512612"):  # sensors of the example kinect rig
        path = tmp_path / f"{sensor_id}.mkv"
        path.write_bytes(b"")
        takes += ["--take", f"{sensor_id}={path}"]
    config = ROOT / "config" / "rig-example-kinect-4.toml"
    code = main(["eval", "depth", "--config", str(config), *takes])
    err = capsys.readouterr().err
    assert code != 0
    assert "pyk4a" in err and "Body Tracking SDK" in err, err


def test_a_take_of_a_sensor_the_rig_lacks_is_refused(tmp_path: Path, capsys) -> None:
    path = tmp_path / "x.mkv"
    path.write_bytes(b"")
    config = ROOT / "config" / "rig-example-kinect-4.toml"
    code = main(["eval", "depth", "--config", str(config), "--take", f"nope={path}", "--take", f"000123412512={path}"])
    assert code != 0 and "nope" in capsys.readouterr().err


def test_hybrid_never_flips_and_the_control_echoes_skeleton_fusion() -> None:
    """A 2 s crossing take holds rear views the simulator mirrors: a prior made of raw bodies turned hybrid's
    virtual camera behind the person (p90 322 mm against skeleton fusion's 36). Its prior is now the realigned
    fused skeleton: hybrid's p90 stays within 10 % of skeleton fusion's. The control (a tracker returning its
    prior) scores what skeleton fusion scores, person for person."""
    instants, obs = simulated_instants("crossing", 2.0, 3)
    result = evaluate_depth(
        instants, obs.sensor_ids, obs.world_from_sensor_calibrated, sim_tracker, progress=False, control=True
    )
    skeleton, hybrid, control = (result.figures[m] for m in ("skeleton", "hybrid", "control"))
    assert np.percentile(hybrid.error_mm, 90) <= 1.10 * np.percentile(skeleton.error_mm, 90)
    np.testing.assert_allclose(control.error_mm, skeleton.error_mm, atol=1e-9)
    assert control.agreement_mm and max(control.agreement_mm) < 1e-9
    assert "unmeasured until a real body tracker runs on the virtual image" in result.table()
