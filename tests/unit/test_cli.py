"""The command line: arguments reach the library as typed, errors become exit codes with a message."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from skelfuse import cli
from skelfuse.schema.errors import DataError


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        pytest.param(["eval", "paper"], {"quick": False, "json": False, "seed": 0, "workers": 2}, id="paper-defaults"),
        pytest.param(
            ["eval", "paper", "--quick", "--json", "--seed", "7", "--workers", "1", "--out", "x"],
            {"quick": True, "json": True, "seed": 7, "workers": 1, "out": Path("x")},
            id="paper-flags",
        ),
        pytest.param(["eval", "real", "--eps", "150"], {"eps": 150.0, "json": False}, id="real-eps"),
        pytest.param(
            ["bench", "fusion", "--sensors", "5", "8", "--bodies", "1", "--quick"],
            {"sensors": [5, 8], "bodies": [1], "quick": True, "preset": "A5"},
            id="bench-cases",
        ),
        pytest.param(
            ["bench", "instant", "--cases", "4x1", "16X6", "--baseline", "base/src", "--rounds", "2"],
            {"cases": [(4, 1), (16, 6)], "baseline": Path("base/src"), "rounds": 2, "frames": 300},
            id="bench-instant",
        ),
        pytest.param(["bench", "instant", "--paced"], {"paced": True, "cases": [(4, 1), (16, 6)]}, id="bench-paced"),
        pytest.param(
            ["bench", "instant", "--positions-only"], {"positions_only": True, "paced": False}, id="bench-positions"
        ),
        pytest.param(
            ["bench", "latency", "--sensors", "8", "--people", "6", "--node-src", "base/src"],
            {"sensors": [8], "people": 6, "node_src": Path("base/src")},
            id="bench-latency-people",
        ),
        pytest.param(
            ["demo", "--duration", "3", "--rrd", "d.rrd", "--no-realtime"],
            {"duration": 3.0, "rrd": Path("d.rrd"), "realtime": False, "gesture": "walking"},
            id="demo-rrd",
        ),
    ],
)
def test_parse_args(argv: list[str], expected: dict[str, object]) -> None:
    args = cli.build_parser().parse_args(argv)
    for key, value in expected.items():
        assert getattr(args, key) == value, key


def test_unknown_gesture_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["demo", "--gesture", "moonwalk"])
    assert exit_info.value.code == 2
    assert "moonwalk" in capsys.readouterr().err


def test_data_error_becomes_exit_2_with_message(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    from skelfuse.eval import rig

    def missing(*_args: object, **_kwargs: object) -> None:
        raise DataError("no recording in /nowhere: pass --data")

    monkeypatch.setattr(rig, "run_rig_eval", missing)
    assert cli.main(["eval", "real", "--data", str(tmp_path)]) == cli.EXIT_USAGE  # a folder without the take
    assert "joints_gen_master.csv: no such file" in capsys.readouterr().err


def test_json_output_is_strict_json(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    import numpy as np

    from skelfuse.cli import evaluate
    from skelfuse.eval import rig, rig_report

    result = SimpleNamespace(to_dict=lambda: {"value": np.float64(1.5), "rows": np.arange(2)})
    monkeypatch.setattr(rig, "run_rig_eval", lambda *_a, **_k: result)
    monkeypatch.setattr(rig_report, "format_markdown", lambda *_a: "")
    monkeypatch.setattr(evaluate, "open_take", lambda *_a, **_k: None)
    assert cli.main(["eval", "real", "--json"]) == cli.EXIT_OK
    assert json.loads(capsys.readouterr().out) == {"value": 1.5, "rows": [0, 1]}
