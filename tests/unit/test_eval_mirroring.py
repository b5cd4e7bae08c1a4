"""``eval robustness --bases / --mirroring-sweep``: the break-even rule by hand, and a tiny run whose bases
behave as defined (the simulator's own mirroring flags say which base mirrors)."""

from __future__ import annotations

import pytest

from skelfuse.eval import mirroring


def test_break_even_by_hand() -> None:
    # upper bounds of skelfuse - A1 at mirrored shares 0, 0.1, 0.3: crosses 0 a quarter of the way to 0.3
    assert mirroring.break_even([0.0, 0.1, 0.3], [2.0, 1.0, -3.0]) == pytest.approx(0.15)
    assert mirroring.break_even([0.3, 0.0], [-1.0, -0.5]) == 0.0
    assert mirroring.break_even([0.0, 0.3], [1.0, 0.5]) is None


def test_bases_and_sweep_on_a_tiny_matrix() -> None:
    result = mirroring.run_bases(families=("limb_swaps",), sensors=(2,), n_seeds=2, duration_s=2.0, workers=1)
    cells = {(c["base"], c["family"]): c for c in result["cells"]}
    assert set(cells) == {(b, f) for b in mirroring.BASES for f in ("baseline", "limb_swaps")}
    assert cells["mirroring", "baseline"]["mirrored"] > 0.05  # the calibrated profile mirrors rear views
    assert cells["no_mirroring", "baseline"]["mirrored"] == 0.0 == cells["no_mirroring", "limb_swaps"]["mirrored"]
    for base in mirroring.BASES:  # a base against itself: no effect, no margin beyond it
        base_cell, family_cell = cells[base, "baseline"], cells[base, "limb_swaps"]
        assert base_cell["effect"]["A1"]["torso"]["mean"] == 0.0
        expected = family_cell["margin"]["upper_limb"]["mean"] - base_cell["margin"]["upper_limb"]["mean"]
        assert family_cell["margin_beyond_base"]["upper_limb"]["mean"] == pytest.approx(expected)
    sweep = mirroring.run_sweep(flip_on=(0.0, 0.5), sensors=(2,), n_seeds=2, duration_s=2.0, workers=1)
    shares = [p["mirrored"] for p in sweep["points"]]
    assert shares[0] == 0.0 < shares[1]
    assert set(sweep["break_even"]["2"]) == {"torso", "upper_limb", "lower_limb"}
    assert "Break-even" in mirroring.format_sweep(sweep) and "no_mirroring" in mirroring.format_bases(result)


def test_the_cli_prints_the_sweep_with_its_break_even_table(capsys) -> None:
    from skelfuse.cli import main

    code = main(
        [
            "eval",
            "robustness",
            "--mirroring-sweep",
            "--sensors",
            "2",
            "--seeds",
            "2",
            "--duration",
            "1",
            "--workers",
            "1",
            "-q",
        ]
    )
    out = capsys.readouterr().out
    assert code == 0
    assert "| 0.15 | 2 |" in out and "Break-even" in out and "| 2 |" in out.split("Break-even")[1]
