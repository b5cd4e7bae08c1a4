"""``skelfuse eval robustness``: every fusion preset in every failure world, against exact ground truth.

The matrix: failure family (:data:`skelfuse.sim.failures.FAMILIES` and their mixture) x number of sensors
(2-4, on the paper's ring, ``paper_rig(n)``) x seed. A seed picks the gesture (squat, random, hands up/down,
walking, in turn) and the direction the subject faces (uniform), so every cell mixes front, side and rear
views. Every preset fuses the same observations (common random numbers), so differences between presets are
paired per take.

Measured per take and preset, against the simulator's exact truth:

- error: mean distance per joint group (the paper's torso / upper limb / lower limb of the 16 evaluated joints),
  mm, over frames where the output has the joint (``missing`` counts the rest);
- swapped: share of (frame, left/right pair) samples whose left and right are the wrong way round;
- lag: the time shift (frames) that minimizes the mean distance of the output to the truth (positive = late).

Per cell (family, sensors): the mean over seeds, and for skelfuse minus A1 per group the paired mean difference
with its 95% t confidence interval over seeds. Verdict: "worse" when the whole interval is above 0 (skelfuse
significantly worse than the plain average), "better" when it is below 0, "tie" otherwise.

Held out: skelfuse's parameters were tuned (``scripts/tune_fusion.py``) on the default simulator, i.e. the
``baseline`` and ``no_mirroring`` worlds, with seeds below :data:`HELD_OUT_SEED`. The matrix runs seeds from
:data:`HELD_OUT_SEED` up, and every family but those two is a world no preset was tuned on: those cells are
marked held out.

Presets: the paper's A1, A3, A4, A5 (literal: the Kalman filter outputs its prediction, eq. 9), ``A5post`` (the
same filter outputting its posterior, the fairer reading) and ``skelfuse``: each fuses the take's frames as one
known body (:func:`skelfuse.eval.paper.fuse_sequence`, the offline single-person path).

``skelfuse_live``: the skelfuse preset through the path the live fusion node runs (:func:`fuse_live`): every
sensor's frame as a :class:`~skelfuse.schema.frames.SensorFrame`, one :class:`~skelfuse.rig.grouping.FrameGroup`
per instant, :class:`skelfuse.rig.instant.GroupFuser` (association, tracks, per-track fusion), over the take
played the way a capture worker loops it: first :data:`LIVE_PREROLL_S` seconds up to the frame of the take's
second half that is furthest turned from its first frame and :data:`SEAM_JUMP_MM` away (:func:`worst_seam_frame`),
then the whole take, so that the seam moves the body and turns it round in one frame (in a walking take) as the
demo's 20 s loop does;
scored on the whole take with the demo's rule (the person most views contributed to). Per cell the matrix also
gives ``skelfuse_live`` minus ``skelfuse`` with its paired interval: the live path must not lose to the offline
one (a looped take's seam is where it can, which the teleport rule of
:func:`skelfuse.fusion.realign.realign_temporal` handles; docs/evidence.md, "Robustness").
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from multiprocessing import get_context
from typing import Any

import numpy as np
from scipy import stats as scipy_stats

from skelfuse.eval.metrics import best_lag, lag_error_curve, nan_for_none, swap_counts
from skelfuse.eval.paper import fuse_sequence
from skelfuse.fusion import presets
from skelfuse.fusion.presets import FusionParams
from skelfuse.progress import Progress
from skelfuse.rig.grouping import FrameGroup
from skelfuse.rig.instant import GroupFuser
from skelfuse.schema.frames import SensorFrame
from skelfuse.schema.skeleton import EVAL_JOINTS, JOINT_GROUPS, N_JOINTS, PAPER_REALIGN_PAIRS
from skelfuse.sim.failures import FAMILIES, MIXTURE, family_profile
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.motion import facing_deg
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.rig import paper_rig

__all__ = [
    "FAMILY_NAMES",
    "GESTURES",
    "HELD_OUT_SEED",
    "PRESETS",
    "TRAINING_FAMILIES",
    "RobustnessResult",
    "format_markdown",
    "fuse_live",
    "preset_params",
    "run_robustness",
]

LIVE = "skelfuse_live"
PRESETS: tuple[str, ...] = ("A1", "A3", "A4", "A5", "A5post", "skelfuse", LIVE)
FAMILY_NAMES: tuple[str, ...] = (*FAMILIES, MIXTURE.name)
TRAINING_FAMILIES: tuple[str, ...] = ("baseline", "no_mirroring")
"""The worlds skelfuse's parameters were tuned on (the default simulator, with and without rear mirroring)."""
HELD_OUT_SEED = 1000
"""The matrix uses seeds from here up; any tuning uses seeds below it."""
GESTURES: tuple[str, ...] = ("squat", "random", "hands_up_down", "walking")
GROUPS: tuple[str, ...] = tuple(JOINT_GROUPS)
LAG_SHIFTS = np.arange(-3, 11)
FPS = 30.0
REFERENCE, CANDIDATE = "A1", "skelfuse"
LIVE_PREROLL_S = 2.0
"""The live path first fuses this much of the take before its start, as a capture worker that comes up before the
take's origin plays the end of its loop (the demo's workers run 3-8 s of it), so a loop's seam is in every run."""


SEAM_JUMP_MM = 250.0
"""The live path's seam moves the body at least this far in one frame where the take allows (the demo's 20 s
walking loop: 267 mm and a 177 deg turn at its seam)."""


def worst_seam_frame(truth: np.ndarray) -> int:
    """The frame of the take's second half where a loop would be worst to close: among the frames whose pelvis
    lies at least :data:`SEAM_JUMP_MM` from the first frame's (all of the half if none does), the one facing
    furthest from the first frame, so that the seam moves the body and turns it round in one frame."""
    facing = facing_deg(truth)
    turn = np.abs((facing - facing[0] + 180.0) % 360.0 - 180.0)
    half = truth.shape[0] // 2
    jump = np.linalg.norm(truth[half:, 0] - truth[0, 0], axis=-1)
    far = jump >= SEAM_JUMP_MM
    return half + int(np.argmax(np.where(far, turn[half:], -1.0) if far.any() else turn[half:]))


def fuse_live(params: FusionParams, obs: Any, preroll_frames: int, seam_frame: int | None = None) -> np.ndarray:
    """(T, 32, 3) world mm: the take fused the way the live node fuses it (see the module docstring).

    ``obs``: :class:`skelfuse.sim.observe.Observations`. First the ``preroll_frames`` frames up to and including
    ``seam_frame`` (default the last: a plain loop), then the whole take from frame 0; a sensor's dropped
    frame is left out of its instant, a body it did not track gives a frame without bodies (as
    :class:`skelfuse.service.worker.SimSource` sends). Per take frame, the output is the person with the most
    contributing views (the demo's scorer: no truth in the choice); NaN where no person is output.
    """
    T = obs.n_frames
    seam = T - 1 if seam_frame is None else int(seam_frame)
    preroll = min(int(preroll_frames), seam + 1)
    order = [*range(seam + 1 - preroll, seam + 1), *range(T)]
    fuser = GroupFuser(obs.sensor_ids, obs.world_from_sensor_calibrated, params)
    period_us = 1e6 / FPS
    identity = np.zeros((1, N_JOINTS, 4), dtype=np.float32)
    identity[..., 0] = 1.0
    no_body = (np.zeros(0, np.uint32), np.zeros((0, N_JOINTS, 3), np.float32), np.zeros((0, N_JOINTS), np.uint8))
    out = np.full((T, N_JOINTS, 3), np.nan)
    for k, f in enumerate(order):
        time_us = round(k * period_us) + 1_000_000
        frames = {}
        for s, sensor_id in enumerate(obs.sensor_ids):
            if obs.dropped[f, s]:
                continue
            seen = obs.tracked[f, s] and np.isfinite(obs.positions[f, s]).all()
            ids, positions, confidence = (
                (
                    np.array([max(int(obs.body_ids[f, s]), 0)], np.uint32),
                    obs.positions[f, s][None],
                    obs.confidence[f, s][None],
                )
                if seen
                else no_body
            )
            frames[sensor_id] = SensorFrame(
                sensor_id, k, time_us, 0, ids, positions.astype(np.float32), identity[: ids.size], confidence
            )
        if not frames:
            continue
        missing = tuple(sid for sid in obs.sensor_ids if sid not in frames)
        fused = fuser.step(FrameGroup(time_us, frames, missing, not missing)).frame
        if k >= preroll and fused.track_ids.size:
            seen_by = fused.contributors.sum(axis=1)
            if seen_by.any():
                out[f] = fused.positions[int(np.argmax(seen_by))]
    return out


def preset_params(name: str) -> FusionParams:
    """The parameters of a matrix preset: a fusion preset, or ``A5post`` (A5 outputting its posterior)."""
    if name == "A5post":
        return replace(presets.preset("A5"), kalman_output="posterior")
    return presets.preset(name)


@dataclass(frozen=True)
class _Task:
    family: str
    n_sensors: int
    seed: int
    duration_s: float
    presets: tuple[str, ...]
    base: tuple[tuple[str, float], ...] = ()  # profile keys set before the family's (eval/mirroring.py)


def run_tasks(tasks: list[_Task], workers: int, progress: bool, label: str) -> list[dict[str, Any]]:
    """Run the takes, in ``workers`` spawned processes when more than one, with a progress bar named ``label``."""
    bar = Progress(len(tasks), label, enabled=None if progress else False)
    takes: list[dict[str, Any]] = []
    if workers > 1:
        with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn")) as pool:
            for take in pool.map(_run_take, tasks):
                takes.append(take)
                bar.update(note=f"{take['family']} x{take['n_sensors']}")
    else:
        for task in tasks:
            takes.append(_run_take(task))
            bar.update(note=task.family)
    bar.close()
    return takes


def _run_take(task: _Task) -> dict[str, Any]:
    """Simulate one take of one family and score every preset on it."""
    rng = np.random.default_rng([task.seed, task.n_sensors])
    gesture = GESTURES[task.seed % len(GESTURES)]
    facing = float(rng.uniform(0.0, 360.0))
    motion = make_gesture(gesture, duration_s=task.duration_s, fps=FPS, facing_deg=facing, seed=task.seed)
    overrides: dict[str, Any] = dict(task.base)
    profile = family_profile(replace(load_profile(), **overrides), task.family)
    obs = simulate(motion, paper_rig(task.n_sensors), profile, seed=task.seed)
    world = obs.positions_world(calibrated=True)
    world = np.where(obs.tracked[..., None, None], world, np.nan)
    truth = np.asarray(obs.truth, dtype=np.float64)
    scores: dict[str, Any] = {}
    for name in task.presets:
        if name == LIVE:
            seam = worst_seam_frame(truth)
            fused = fuse_live(presets.preset(CANDIDATE), obs, round(LIVE_PREROLL_S * FPS), seam)
        else:
            positions = obs.world_from_sensor_calibrated[:, :3, 3]
            fused = fuse_sequence(preset_params(name), world, obs.confidence, FPS, positions)
        dist = np.linalg.norm(fused - truth, axis=-1)  # (T, 32)
        row: dict[str, float] = {}
        for group, joints in JOINT_GROUPS.items():
            values = dist[:, joints]
            row[group] = float(np.nanmean(values)) if np.isfinite(values).any() else math.nan
        row["missing"] = float(np.isnan(dist[:, EVAL_JOINTS]).mean())
        swapped, valid = swap_counts(fused, truth, PAPER_REALIGN_PAIRS)
        row["swapped"] = float(swapped.sum() / max(valid.sum(), 1))
        sums, counts = lag_error_curve(fused[:, EVAL_JOINTS], truth[:, EVAL_JOINTS], LAG_SHIFTS)
        row["lag"] = best_lag(sums, counts, LAG_SHIFTS)[0]
        scores[name] = row
    return {
        "family": task.family,
        "n_sensors": task.n_sensors,
        "seed": task.seed,
        "gesture": gesture,
        "facing_deg": facing,
        "mirrored": float(obs.mirrored[obs.tracked].mean()) if obs.tracked.any() else 0.0,
        "scores": scores,
    }


def paired_interval(differences: Sequence[float], level: float = 0.95) -> tuple[float, float, float]:
    """Mean and two-sided t confidence interval of paired differences (NaN half-width with one sample)."""
    d = np.asarray([x for x in differences if math.isfinite(x)], dtype=np.float64)
    if d.size == 0:
        return math.nan, math.nan, math.nan
    mean = float(d.mean())
    if d.size < 2:
        return mean, math.nan, math.nan
    half = float(scipy_stats.t.ppf(0.5 + level / 2, d.size - 1) * d.std(ddof=1) / math.sqrt(d.size))
    return mean, mean - half, mean + half


def verdict(low: float, high: float) -> str:
    """ "worse" / "better" when the interval of skelfuse - A1 lies wholly above / below 0, else "tie"."""
    if math.isfinite(low) and low > 0:
        return "worse"
    if math.isfinite(high) and high < 0:
        return "better"
    return "tie"


@dataclass
class RobustnessResult:
    """The matrix: ``takes`` holds every take's scores; ``cells`` the per-(family, sensors) summary."""

    settings: dict[str, Any]
    takes: list[dict[str, Any]]
    cells: list[dict[str, Any]] = field(default_factory=list)
    elapsed_s: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return _jsonable(
            {"settings": self.settings, "cells": self.cells, "takes": self.takes, "elapsed_s": self.elapsed_s}
        )

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RobustnessResult:
        """Read back what :meth:`to_dict` wrote (docs/evidence.md is rendered from the stored JSON)."""
        return cls(data["settings"], data["takes"], nan_for_none(data["cells"]), data["elapsed_s"])

    @property
    def n_worse(self) -> int:
        return sum(cell["verdict"][g] == "worse" for cell in self.cells for g in GROUPS)

    @property
    def n_live_worse(self) -> int:
        """(cell, group) where the live path is significantly worse than the offline skelfuse path."""
        return sum(cell["live"]["verdict"][g] == "worse" for cell in self.cells if "live" in cell for g in GROUPS)


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def _compare(rows: list[dict[str, Any]], candidate: str, reference: str) -> tuple[dict, dict]:
    """Per group: the paired mean of candidate - reference over a cell's seeds, its 95% interval, a verdict."""
    diff, verdicts = {}, {}
    for g in GROUPS:
        m, low, high = paired_interval([r["scores"][candidate][g] - r["scores"][reference][g] for r in rows])
        diff[g] = {"mean": m, "low": low, "high": high}
        verdicts[g] = verdict(low, high)
    return diff, verdicts


def _summarize(
    takes: list[dict[str, Any]], families: Sequence[str], sensors: Sequence[int], names: Sequence[str]
) -> list[dict[str, Any]]:
    cells = []
    for family in families:
        for n in sensors:
            rows = [t for t in takes if t["family"] == family and t["n_sensors"] == n]
            if not rows:
                continue
            mean = {
                name: {
                    key: float(np.nanmean([r["scores"][name][key] for r in rows]))
                    for key in (*GROUPS, "swapped", "lag", "missing")
                }
                for name in names
            }
            cell: dict[str, Any] = {
                "family": family,
                "n_sensors": n,
                "held_out": family not in TRAINING_FAMILIES,
                "n_seeds": len(rows),
                "mean": mean,
                "diff": {},
                "verdict": {},
            }
            if REFERENCE in names and CANDIDATE in names:
                cell["diff"], cell["verdict"] = _compare(rows, CANDIDATE, REFERENCE)
            if LIVE in names and CANDIDATE in names:
                diff, verdicts = _compare(rows, LIVE, CANDIDATE)
                cell["live"] = {"diff": diff, "verdict": verdicts}
            cells.append(cell)
    return cells


def run_robustness(
    *,
    families: Sequence[str] = FAMILY_NAMES,
    sensors: Sequence[int] = (2, 3, 4),
    n_seeds: int = 6,
    duration_s: float = 10.0,
    preset_names: Sequence[str] = PRESETS,
    workers: int = 2,
    progress: bool = False,
) -> RobustnessResult:
    """Run the matrix (seeds ``HELD_OUT_SEED`` .. ``HELD_OUT_SEED + n_seeds - 1`` in every cell)."""
    unknown = [f for f in families if f not in FAMILY_NAMES]
    if unknown:
        raise ValueError(f"unknown failure families {unknown}; expected some of {', '.join(FAMILY_NAMES)}")
    bad = [name for name in preset_names if name not in PRESETS]
    if bad:
        raise ValueError(f"unknown presets {bad}; expected some of {', '.join(PRESETS)}")
    if any(n < 2 for n in sensors) or n_seeds < 1:
        raise ValueError(f"need at least 2 sensors and 1 seed, got sensors={list(sensors)}, seeds={n_seeds}")
    tasks = [
        _Task(family, n, HELD_OUT_SEED + k, float(duration_s), tuple(preset_names))
        for family in families
        for n in sensors
        for k in range(n_seeds)
    ]
    t0 = time.perf_counter()
    takes = run_tasks(tasks, workers, progress, "eval robustness")
    settings = {
        "families": list(families),
        "sensors": [int(n) for n in sensors],
        "seeds": [HELD_OUT_SEED, HELD_OUT_SEED + n_seeds - 1],
        "duration_s": float(duration_s),
        "presets": list(preset_names),
        "training_families": list(TRAINING_FAMILIES),
    }
    result = RobustnessResult(settings, takes, elapsed_s=time.perf_counter() - t0)
    result.cells = _summarize(takes, families, sensors, preset_names)
    return result


def _fmt(value: float, digits: int = 1) -> str:
    return f"{value:.{digits}f}" if math.isfinite(value) else "n/a"


def format_markdown(result: RobustnessResult) -> str:
    """The matrix as markdown: skelfuse - A1 per cell with its interval, then every preset's figures."""
    s = result.settings
    lines = [
        f"Failure families {', '.join(s['families'])}; {', '.join(str(n) for n in s['sensors'])} sensors on the "
        f"paper's ring; seeds {s['seeds'][0]}-{s['seeds'][1]} ({s['duration_s']:g} s takes, gestures in turn, "
        "random facing); error = mean distance to the exact truth, mm. Held out (H): worlds no preset was tuned "
        f"on (tuning used {', '.join(s['training_families'])}, seeds below {HELD_OUT_SEED}).",
        "",
    ]
    if result.cells and result.cells[0]["diff"]:
        n_cells = len(result.cells) * len(GROUPS)
        lines += [
            f"**skelfuse - A1, paired 95% CI over seeds: {result.n_worse} of {n_cells} (cell, group) significantly "
            "worse.**",
            "",
            "| family | sensors | H | " + " | ".join(f"{g}: A1 / skelfuse / diff [95% CI]" for g in GROUPS) + " |",
            "|---|---|---|" + "---|" * len(GROUPS),
        ]
        for cell in result.cells:
            parts = []
            for g in GROUPS:
                d = cell["diff"][g]
                mark = {"worse": " **worse**", "better": " better", "tie": ""}[cell["verdict"][g]]
                parts.append(
                    f"{_fmt(cell['mean'][REFERENCE][g])} / {_fmt(cell['mean'][CANDIDATE][g])} / "
                    f"{_fmt(d['mean'])} [{_fmt(d['low'])}, {_fmt(d['high'])}]{mark}"
                )
            lines.append(
                f"| {cell['family']} | {cell['n_sensors']} | {'H' if cell['held_out'] else ''} | "
                + " | ".join(parts)
                + " |"
            )
        lines.append("")
    if result.cells and "live" in result.cells[0]:
        n_cells = len(result.cells) * len(GROUPS)
        lines += [
            f"**{LIVE} - skelfuse (the live node's path against the offline single-person path, the take played "
            f"as a capture worker loops it), paired 95% CI: {result.n_live_worse} of {n_cells} (cell, group) "
            "significantly worse.**",
            "",
            "| family | sensors | " + " | ".join(f"{g}: diff [95% CI]" for g in GROUPS) + " |",
            "|---|---|" + "---|" * len(GROUPS),
        ]
        for cell in result.cells:
            parts = []
            for g in GROUPS:
                d = cell["live"]["diff"][g]
                mark = {"worse": " **worse**", "better": " better", "tie": ""}[cell["live"]["verdict"][g]]
                parts.append(f"{_fmt(d['mean'])} [{_fmt(d['low'])}, {_fmt(d['high'])}]{mark}")
            lines.append(f"| {cell['family']} | {cell['n_sensors']} | " + " | ".join(parts) + " |")
        lines.append("")
    names = s["presets"]
    lines += [
        "Every preset: mean error over the three groups (mm) / swapped pairs (%) / lag (frames):",
        "",
        "| family | sensors | " + " | ".join(names) + " |",
        "|---|---|" + "---|" * len(names),
    ]
    for cell in result.cells:
        parts = []
        for name in names:
            m = cell["mean"][name]
            overall = float(np.mean([m[g] for g in GROUPS]))
            parts.append(f"{_fmt(overall)} / {_fmt(100 * m['swapped'])} / {_fmt(m['lag'], 2)}")
        lines.append(f"| {cell['family']} | {cell['n_sensors']} | " + " | ".join(parts) + " |")
    return "\n".join(lines) + "\n"
