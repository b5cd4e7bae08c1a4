"""``skelfuse eval robustness --bases`` / ``--mirroring-sweep``: how much of skelfuse's margin the assumed
rear-view mirroring makes.

The calibrated profile mirrors rear views in bursts (``flip_on_prob`` 0.15, ``flip_off_prob_away`` 0.02,
``flip_off_prob_front`` 0.5 per frame): assumed rates, never measured. Every failure family of the robustness
matrix is layered on that profile, so a family's figures mix its own effect with the mirroring's. Two
analyses separate them (A1 and skelfuse only, the same seeds, gestures and facings as the matrix: paired):

- **Bases** (:func:`run_bases`): every family on the mirroring base (the calibrated profile) and on a base
  without rear-view mirroring (``flip_on_prob`` 0; a family that sets its own mirroring keys, such as
  ``flip_reconverge``, keeps them). Each cell is reported as its effect beyond its base: per preset the
  family's error minus the base world's error on the same seeds, and skelfuse - A1 in the family minus
  skelfuse - A1 in the base world, each with its paired 95 % interval over seeds.
- **Sweep** (:func:`run_sweep`): the base world with ``flip_on_prob`` from 0 past the assumption; per point
  the share of tracked view-frames that came out mirrored (what ``skelfuse eval real`` measures per view on a
  real rig: its "mirrored" share) and skelfuse - A1 per group; the break-even share per group and rig size is
  the mirrored share from which skelfuse is significantly better than A1 (:func:`break_even`). No fusion
  parameter is tuned on any of this.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from skelfuse.eval.robustness import (
    CANDIDATE,
    FAMILY_NAMES,
    GROUPS,
    HELD_OUT_SEED,
    REFERENCE,
    _Task,
    paired_interval,
    run_tasks,
)

BASES: dict[str, dict[str, float]] = {"mirroring": {}, "no_mirroring": {"flip_on_prob": 0.0}}
"""The two bases every family runs on: the calibrated profile, and the same without rear-view mirroring."""
BASE_FAMILY = "baseline"
SWEEP_FLIP_ON: tuple[float, ...] = (0.0, 0.002, 0.005, 0.01, 0.02, 0.05, 0.15, 0.5)
"""``flip_on_prob`` values of the sweep: 0, the assumption (0.15) and beyond."""
PAIR = (REFERENCE, CANDIDATE)


def _margin(take: dict[str, Any], group: str) -> float:
    return float(take["scores"][CANDIDATE][group] - take["scores"][REFERENCE][group])


def _interval(values: Sequence[float]) -> dict[str, float]:
    mean, low, high = paired_interval(values)
    return {"mean": mean, "low": low, "high": high}


def run_bases(
    *,
    families: Sequence[str] = FAMILY_NAMES,
    sensors: Sequence[int] = (2, 3, 4),
    n_seeds: int = 6,
    duration_s: float = 10.0,
    workers: int = 2,
    progress: bool = False,
) -> dict[str, Any]:
    """Every family (and the base world itself) on both :data:`BASES`; cells of effects beyond the base."""
    names = [BASE_FAMILY, *[f for f in families if f != BASE_FAMILY]]
    tasks = [
        _Task(family, n, HELD_OUT_SEED + k, float(duration_s), PAIR, tuple(overrides.items()))
        for base, overrides in BASES.items()
        for family in names
        for n in sensors
        for k in range(n_seeds)
    ]
    t0 = time.perf_counter()
    takes = run_tasks(tasks, workers, progress, "eval robustness --bases")
    for take, task in zip(takes, tasks, strict=True):
        take["base"] = next(b for b, o in BASES.items() if tuple(o.items()) == task.base)
    cells = []
    for base in BASES:
        for family in names:
            for n in sensors:
                rows = {t["seed"]: t for t in takes if (t["base"], t["family"], t["n_sensors"]) == (base, family, n)}
                base_rows = {
                    t["seed"]: t for t in takes if (t["base"], t["family"], t["n_sensors"]) == (base, BASE_FAMILY, n)
                }
                seeds = sorted(rows)
                cell: dict[str, Any] = {"base": base, "family": family, "n_sensors": n, "n_seeds": len(seeds)}
                cell["mirrored"] = float(np.mean([rows[s]["mirrored"] for s in seeds]))
                cell["mean"] = {
                    p: {g: float(np.mean([rows[s]["scores"][p][g] for s in seeds])) for g in GROUPS} for p in PAIR
                }
                cell["margin"] = {g: _interval([_margin(rows[s], g) for s in seeds]) for g in GROUPS}
                cell["effect"] = {
                    p: {
                        g: _interval([rows[s]["scores"][p][g] - base_rows[s]["scores"][p][g] for s in seeds])
                        for g in GROUPS
                    }
                    for p in PAIR
                }
                cell["margin_beyond_base"] = {
                    g: _interval([_margin(rows[s], g) - _margin(base_rows[s], g) for s in seeds]) for g in GROUPS
                }
                cells.append(cell)
    settings = {"families": names, "sensors": list(sensors), "seeds": [HELD_OUT_SEED, HELD_OUT_SEED + n_seeds - 1]}
    settings |= {"duration_s": float(duration_s), "bases": {b: dict(o) for b, o in BASES.items()}}
    return {"settings": settings, "cells": cells, "elapsed_s": time.perf_counter() - t0}


def break_even(shares: Sequence[float], upper_bounds: Sequence[float]) -> float | None:
    """The mirrored share from which skelfuse is significantly better than A1: where the upper bound of the 95 %
    interval of skelfuse - A1 (``upper_bounds``, per sweep point) first falls below 0, linear between sweep
    points; 0.0 when it is below 0 at the first point already, None when it never is in the swept range."""
    pairs = sorted((float(s), float(m)) for s, m in zip(shares, upper_bounds, strict=True) if math.isfinite(m))
    if not pairs:
        return None
    if pairs[0][1] < 0:
        return 0.0
    for (s0, m0), (s1, m1) in itertools.pairwise(pairs):
        if m1 < 0 <= m0:
            return s0 + (s1 - s0) * m0 / (m0 - m1)
    return None


def run_sweep(
    *,
    flip_on: Sequence[float] = SWEEP_FLIP_ON,
    sensors: Sequence[int] = (2, 3, 4),
    n_seeds: int = 6,
    duration_s: float = 10.0,
    workers: int = 2,
    progress: bool = False,
) -> dict[str, Any]:
    """The base world at every ``flip_on_prob`` of ``flip_on``; per point and rig size the mirrored share and
    skelfuse - A1; per rig size and group the break-even mirrored share (:func:`break_even`)."""
    tasks = [
        _Task(BASE_FAMILY, n, HELD_OUT_SEED + k, float(duration_s), PAIR, (("flip_on_prob", float(rate)),))
        for rate in flip_on
        for n in sensors
        for k in range(n_seeds)
    ]
    t0 = time.perf_counter()
    takes = run_tasks(tasks, workers, progress, "eval robustness --mirroring-sweep")
    points: list[dict[str, Any]] = []
    for rate in flip_on:
        for n in sensors:
            rows = [t for t, task in zip(takes, tasks, strict=True) if task.base[0][1] == rate and task.n_sensors == n]
            points.append(
                {
                    "flip_on_prob": float(rate),
                    "n_sensors": n,
                    "mirrored": float(np.mean([r["mirrored"] for r in rows])),
                    "mean": {p: {g: float(np.mean([r["scores"][p][g] for r in rows])) for g in GROUPS} for p in PAIR},
                    "margin": {g: _interval([_margin(r, g) for r in rows]) for g in GROUPS},
                }
            )
    even = {}
    for n in sensors:
        mine = [p for p in points if p["n_sensors"] == n]
        even[str(n)] = {
            g: break_even([p["mirrored"] for p in mine], [p["margin"][g]["high"] for p in mine]) for g in GROUPS
        }
    settings = {"flip_on_prob": [float(r) for r in flip_on], "sensors": list(sensors), "duration_s": float(duration_s)}
    settings["seeds"] = [HELD_OUT_SEED, HELD_OUT_SEED + n_seeds - 1]
    return {"settings": settings, "points": points, "break_even": even, "elapsed_s": time.perf_counter() - t0}


def _ci(d: dict[str, float]) -> str:
    def f(v: float) -> str:
        return f"{v:.1f}" if math.isfinite(v) else "n/a"

    return f"{f(d['mean'])} [{f(d['low'])}, {f(d['high'])}]"


def format_bases(result: dict[str, Any]) -> str:
    """The bases as markdown: per base, family and rig size, each preset's effect beyond the base world and
    skelfuse - A1 beyond the base world's, mm (paired 95 % intervals over seeds)."""
    s = result["settings"]
    lines = [
        f"Every family on two bases ({', '.join(s['bases'])}); seeds {s['seeds'][0]}-{s['seeds'][1]}, "
        f"{s['duration_s']:g} s takes; {result['elapsed_s']:.0f} s. Effect = the family's error minus the base "
        "world's on the same seeds, mm, mean [95% CI]; margin = skelfuse - A1 (negative: skelfuse better).",
        "",
        "| base | family | sensors | mirrored | "
        + " | ".join(f"{g}: A1 effect / skelfuse effect / margin / margin beyond base" for g in GROUPS)
        + " |",
        "|---|---|---|---|" + "---|" * len(GROUPS),
    ]
    for c in result["cells"]:
        parts = [
            f"{_ci(c['effect'][REFERENCE][g])} / {_ci(c['effect'][CANDIDATE][g])} / {_ci(c['margin'][g])} / "
            f"{_ci(c['margin_beyond_base'][g])}"
            for g in GROUPS
        ]
        lines.append(
            f"| {c['base']} | {c['family']} | {c['n_sensors']} | {100 * c['mirrored']:.1f}% | "
            + " | ".join(parts)
            + " |"
        )
    return "\n".join(lines) + "\n"


def format_sweep(result: dict[str, Any]) -> str:
    """The sweep as markdown: per point the mirrored share and A1 / skelfuse / skelfuse - A1 per group; then the
    break-even mirrored shares."""
    s = result["settings"]
    lines = [
        f"Rear-view mirroring swept (flip_on_prob {', '.join(f'{r:g}' for r in s['flip_on_prob'])}; the calibrated "
        f"profile assumes 0.15); seeds {s['seeds'][0]}-{s['seeds'][1]}, {s['duration_s']:g} s takes; "
        f"{result['elapsed_s']:.0f} s. mirrored = share of tracked view-frames mirrored (``eval real`` measures it "
        "per view on a real rig). Per group: A1 / skelfuse / skelfuse - A1 [95% CI], mm.",
        "",
        "| flip_on_prob | sensors | mirrored | " + " | ".join(GROUPS) + " |",
        "|---|---|---|" + "---|" * len(GROUPS),
    ]
    for p in result["points"]:
        parts = [
            f"{p['mean'][REFERENCE][g]:.1f} / {p['mean'][CANDIDATE][g]:.1f} / {_ci(p['margin'][g])}" for g in GROUPS
        ]
        lines.append(
            f"| {p['flip_on_prob']:g} | {p['n_sensors']} | {100 * p['mirrored']:.1f}% | " + " | ".join(parts) + " |"
        )
    lines += [
        "",
        "Break-even: the mirrored share from which skelfuse is significantly better than A1 (95% CI of "
        "skelfuse - A1 wholly below 0), per rig size:",
        "",
    ]
    lines += ["| sensors | " + " | ".join(GROUPS) + " |", "|---|" + "---|" * len(GROUPS)]
    for n, groups in result["break_even"].items():
        cells = ["not in the swept range" if v is None else f"{100 * v:.1f}%" for v in groups.values()]
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
