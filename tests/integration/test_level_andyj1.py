"""The andyj1 take fused with --registered (no calibration defines its world) comes out standing: levelled
from the skeletons, head above pelvis and feet on the floor in the fused table, in Blender's import of the
BVH and in OpenSim's reader of the TRC; --no-level keeps the camera's frame (the control: it lies on its side)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skelfuse.cli import main
from skelfuse.export.blender import BlenderError, ensure_bpy, run_blender
from skelfuse.export.bvh import UNIT_MM
from skelfuse.export.csv import read_fused_table
from skelfuse.schema.skeleton import JOINT_NAMES, J

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "azure-kinect-andyj1" / "saved_data_2_3dev"
VIEWS = ("master", "sub1", "sub2")

pytestmark = [
    pytest.mark.integration,
    pytest.mark.skipif(not DATA.is_dir(), reason=f"andyj1 recordings not found at {DATA} (../shared/data)"),
]


def _fuse(tmp_path: Path, *extra: str) -> np.ndarray:
    out = tmp_path / f"fused{len(extra)}.csv"
    inputs = [f"{v}={DATA / f'joints_gen_{v}.csv'}" for v in VIEWS]
    assert main(["fuse", "--input", *inputs, "--registered", "-o", str(out), *extra]) == 0
    return out


def _positions(table: Path) -> np.ndarray:
    return np.stack([f.positions[0] for f in read_fused_table(table) if len(f.track_ids)])


@pytest.fixture(scope="module")
def levelled(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _fuse(tmp_path_factory.mktemp("level"))


def test_the_fused_take_stands_on_the_floor(levelled: Path, tmp_path: Path, capsys) -> None:
    p = _positions(levelled)
    assert (p[:, J["HEAD"], 2] - p[:, J["PELVIS"], 2] > 400).mean() > 0.95
    feet = p[:, [J["FOOT_LEFT"], J["FOOT_RIGHT"]], 2]
    assert abs(np.nanmedian(feet)) < 100  # on the floor, not 1.3 m away along y
    control = _positions(_fuse(tmp_path, "--no-level"))  # the camera's frame: y down
    assert (control[:, J["HEAD"], 2] - control[:, J["PELVIS"], 2] > 400).mean() < 0.05


@pytest.mark.live
def test_blender_imports_the_bvh_standing(levelled: Path, tmp_path: Path, capsys) -> None:
    try:
        ensure_bpy()
    except BlenderError:
        pytest.skip("Blender's bpy is not installed here; `skelfuse setup blender` installs it")
    bvh = tmp_path / "take.bvh"
    assert main(["export", str(levelled), "--format", "bvh", "-o", str(bvh)]) == 0
    result = run_blender({"command": "sample", "bvh": str(bvh), "scale": UNIT_MM["cm"] / 1000.0, "frames": [0, 40, 80]})
    heads = result["heads"]
    head, pelvis = np.array(heads["HEAD"]), np.array(heads["PELVIS"])
    assert (head[:, 2] - pelvis[:, 2] > 0.4).all(), (head, pelvis)  # Blender's world: z up, metres


def test_opensim_reads_the_trc_standing(levelled: Path, tmp_path: Path) -> None:
    osim = pytest.importorskip("opensim", reason="OpenSim's TRC reader: the optional extra `opensim` is not installed")
    trc = tmp_path / "take.trc"
    assert main(["export", str(levelled), "--format", "trc", "-o", str(trc)]) == 0
    table = osim.TimeSeriesTableVec3(str(trc))
    labels = list(table.getColumnLabels())
    assert labels == list(JOINT_NAMES)
    row = table.getRowAtIndex(0)
    head, pelvis = row[labels.index("HEAD")], row[labels.index("PELVIS")]
    assert head[1] - pelvis[1] > 400  # OpenSim: y up, mm


@pytest.fixture(scope="module")
def registered_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The take converted with --registered: an MCAP of sensor frames whose recorded poses are all identity."""
    out = tmp_path_factory.mktemp("convert") / "take.mcap"
    inputs = [f"{v}={DATA / f'joints_gen_{v}.csv'}" for v in VIEWS]
    assert main(["convert", *inputs, "--registered", "-o", str(out)]) == 0
    return out


def test_export_levels_a_recording_it_fuses_on_the_way(registered_recording: Path, tmp_path: Path, capsys) -> None:
    """``export`` of sensor frames levels as ``fuse --input`` does: the same report, --no-level the control."""
    table = tmp_path / "exported.csv"
    assert main(["export", str(registered_recording), "--format", "csv", "-o", str(table)]) == 0
    assert "levelled the world from the skeletons" in capsys.readouterr().err
    p = _positions(table)
    assert (p[:, J["HEAD"], 2] - p[:, J["PELVIS"], 2] > 400).mean() > 0.95
    assert abs(np.nanmedian(p[:, [J["FOOT_LEFT"], J["FOOT_RIGHT"]], 2])) < 100
    control = tmp_path / "control.csv"
    assert main(["export", str(registered_recording), "--format", "csv", "--no-level", "-o", str(control)]) == 0
    assert "levelled" not in capsys.readouterr().err
    c = _positions(control)  # the master camera's frame: y down, the trunk along -y
    assert (c[:, J["HEAD"], 2] - c[:, J["PELVIS"], 2] > 400).mean() < 0.05
    assert (c[:, J["PELVIS"], 1] - c[:, J["HEAD"], 1] > 400).mean() > 0.95


def test_export_up_names_the_axis_and_is_refused_for_a_fused_input(
    registered_recording: Path, levelled: Path, tmp_path: Path, capsys
) -> None:
    table = tmp_path / "up.csv"
    assert main(["export", str(registered_recording), "--format", "csv", "--up=-y", "-o", str(table)]) == 0
    p = _positions(table)
    assert (p[:, J["HEAD"], 2] - p[:, J["PELVIS"], 2] > 400).mean() > 0.95  # the camera's -y is up
    capsys.readouterr()
    assert main(["export", str(levelled), "--format", "csv", "--up=-y", "-o", str(tmp_path / "x.csv")]) == 2
    assert "already fused" in capsys.readouterr().err
