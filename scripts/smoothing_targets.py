"""Offline smoothing against its targets, on simulated two-view takes with exact truth.

For every seed: a gesture (in turn) seen by two sensors of the paper's ring with the calibrated simulator
profile, fused as the live node does (the "skelfuse" preset, causal), then smoothed by the fixed-lag smoother
(3 frames, the live option: per axis, with the process noise the live filter's own velocities set), the
offline default ("rts": the RTS smoother, its adaptive second pass and its constant-acceleration third pass;
:mod:`skelfuse.fusion.smoother`, :mod:`skelfuse.fusion.jerk_smoother`), and as controls the offline default
without its third pass ("rts cv": what the acceleration state buys) and both the fixed lag and the RTS
smoother over the live model's constant process noise ("lag 3 fixed", "rts fixed": what the adaptive noise buys
and costs). Per joint group (torso, arms, legs of the paper's 16 joints), against the truth:

- jitter: median |second difference| of the *error* (output minus truth, mm/frame^2), as a share of the better
  single view's (the views' own jitter: what a smoother has to remove). Every smoother here is linear in its
  measurements (for the adaptive passes: once their process noise is set), so the error splits exactly into the
  smoother run on the truth alone ("distortion": what smoothing does to real motion) and on the measurement
  error alone ("noise": what is left of the views' jitter); both are reported;
- error: mean distance to the truth, mm, and its largest excess over the causal filter's across takes;
- lag, three ways, positive = late: the sub-frame shift that best fits the truth (``eval.metrics.best_lag``;
  the views' own slow and mirrored errors move it, so the views are listed too); the timing of the smoothing
  alone (the same shift, of the smoother run on the truth); the sub-frame velocity cross-correlation peak
  against the smoother's own input, the merged unfiltered positions (``eval.rig.velocity_lag``);
- squat depth (squat takes): the lowest pelvis height, output minus truth, mm, beside what the views bring
  (their pelvis height error around the truth's lowest frame, and the merged input's lowest point) and what the
  smoothing alone does (the smoother run on the truth).

Targets: smoothed jitter <= 0.25 of the better view at |lag| <= 0.05 frame, squat depth within 5 mm where it is
the smoothing's doing, error no worse than causal; fixed lag 3: jitter <= 0.35 at |lag| <= 0.05 frame. The
adaptive passes' constants were chosen on the training seeds (0-5, one take of each gesture); the held-out seeds
(1000 up, those of ``eval robustness``) are reported apart.

    PYTHONPATH=src python scripts/smoothing_targets.py [--training 0 1 ...] [--held-out 1000 ...] [--duration 10]
                                                       [--json]

``--json`` prints every take's figures with the run's stamp (docs/evidence.md, "Smoothing", renders them with
:func:`format_markdown`).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import Any

import numpy as np

from skelfuse.cli.common import print_json
from skelfuse.cli.stamp import RunStamp
from skelfuse.eval.metrics import best_lag, lag_error_curve, nan_for_none, none_for_nan
from skelfuse.eval.rig import velocity_lag
from skelfuse.fusion import Fuser, preset
from skelfuse.fusion.jerk_smoother import jerk_sigma, jerk_smooth
from skelfuse.fusion.smoother import (
    adaptive_accel_sigma,
    backward_pass,
    causal_accel_sigma,
    fixed_lag_smooth,
    forward_pass,
    rts_smooth,
    smooth_per_axis,
)
from skelfuse.schema.skeleton import JOINT_GROUPS, J
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.rig import paper_rig

FPS = 30.0
GESTURES = ("squat", "random", "hands_up_down", "walking", "jump", "lunge")
SHIFTS = np.arange(-3, 6)
GROUPS = {"torso": JOINT_GROUPS["torso"], "arms": JOINT_GROUPS["upper_limb"], "legs": JOINT_GROUPS["lower_limb"]}
SMOOTHERS = ("causal", "lag 3", "lag 3 fixed", "rts fixed", "rts cv", "rts")
BOTTOM_FRAMES = 3  # the views' pelvis error is averaged over the truth's lowest frame +- this many


def error_jitter(error: np.ndarray, joints: np.ndarray) -> float:
    """Median |second difference| of an error (T, 32, 3) over frames and ``joints``, mm/frame^2."""
    e = error[:, joints]
    second = np.linalg.norm(e[2:] - 2 * e[1:-1] + e[:-2], axis=-1)
    second = second[np.isfinite(second)]
    return float(np.median(second)) if second.size else float("nan")


def fused_take(seed: int, duration_s: float) -> dict:
    """The simulated take of ``seed`` through the live fusion: views, truth, merged input, flags, live output."""
    rng = np.random.default_rng([seed, 2])
    gesture = GESTURES[seed % len(GESTURES)]
    motion = make_gesture(gesture, duration_s=duration_s, fps=FPS, facing_deg=float(rng.uniform(-60, 60)), seed=seed)
    obs = simulate(motion, paper_rig(2), load_profile(), seed=seed)
    world = np.where(obs.tracked[..., None, None], obs.positions_world(calibrated=True), np.nan)
    fuser = Fuser(preset("skelfuse"), 1, obs.world_from_sensor_calibrated[:, :3, 3])
    T = len(world)
    merged, live = np.full((T, 32, 3), np.nan), np.full((T, 32, 3), np.nan)
    n_agree = np.zeros((T, 32), dtype=np.int16)
    restart = np.zeros(T, dtype=bool)
    for t in range(T):
        result = fuser.step(world[t][None], obs.confidence[t][None], 1.0 / FPS)
        live[t], merged[t], n_agree[t] = result.positions[0], result.merged[0], result.n_agree[0]
        restart[t] = bool(result.restarted[0]) if result.restarted is not None else False
    truth = np.asarray(obs.truth, dtype=np.float64)
    return {"gesture": gesture, "world": world, "truth": truth, "merged": merged, "n_agree": n_agree,
            "restart": restart, "live": live}  # fmt: skip


def smoothers(take: dict) -> dict[str, Callable[[np.ndarray], np.ndarray]]:
    """Each output as a linear map of the measurements (the adaptive pass's noise set from the real ones)."""
    params = preset("skelfuse")
    n_agree, restart = take["n_agree"], take["restart"]
    dt = np.full(len(n_agree), 1.0 / FPS)
    fwd = forward_pass(take["merged"], n_agree, dt, restart, params)
    alive = np.isfinite(fwd.out)
    if not np.allclose(fwd.out, take["live"], equal_nan=True, rtol=0, atol=1e-9):
        raise SystemExit("the smoother's forward pass is not the live filter")
    sigma = adaptive_accel_sigma(backward_pass(fwd, dt), fwd.linked, dt, params.cv_accel_sigma_mm_s2)
    second = np.where(alive, smooth_per_axis(take["merged"], n_agree, dt, restart, params, sigma), np.nan)
    jerk = jerk_sigma(second, fwd.linked, dt)
    live_sigma = causal_accel_sigma(fwd, dt, params.cv_accel_sigma_mm_s2)
    constant = np.full_like(live_sigma, params.cv_accel_sigma_mm_s2)
    maps = {
        "causal": lambda z: forward_pass(z, n_agree, dt, restart, params).out,
        "lag 3": lambda z: np.where(alive, smooth_per_axis(z, n_agree, dt, restart, params, live_sigma, 3), np.nan),
        "lag 3 fixed": lambda z: np.where(alive, smooth_per_axis(z, n_agree, dt, restart, params, constant, 3), np.nan),
        "rts fixed": lambda z: rts_smooth(z, n_agree, dt, restart, params)[0],
        "rts cv": lambda z: np.where(alive, smooth_per_axis(z, n_agree, dt, restart, params, sigma), np.nan),
        "rts": lambda z: np.where(alive, jerk_smooth(z, n_agree, dt, fwd.linked, params, jerk), np.nan),
    }
    default, _ = rts_smooth(take["merged"], n_agree, dt, restart, params, adaptive=True)
    live_lag = fixed_lag_smooth(take["merged"], n_agree, dt, restart, params, 3)
    for name, want in (("rts", default), ("lag 3", live_lag)):
        if not np.allclose(maps[name](take["merged"]), want, equal_nan=True, rtol=0, atol=1e-9):
            raise SystemExit(f"the {name} pass split here is not the smoother's own")
    return maps


def shift_lag(output: np.ndarray, truth: np.ndarray, joints: np.ndarray) -> float:
    """The sub-frame shift of ``output`` that best fits ``truth`` (mean distance), frames; + = late."""
    sums, counts = lag_error_curve(output[:, joints], truth[:, joints], SHIFTS)
    return best_lag(sums, counts, SHIFTS)[0]


def measure(seed: int, duration_s: float) -> dict:
    """Per output and group: jitter (total, distortion, noise), error, lags; squat depths on squat takes."""
    take = fused_take(seed, duration_s)
    world, truth, merged = take["world"], take["truth"], take["merged"]
    seen_truth = np.where(np.isfinite(merged), truth, np.nan)  # the truth where the smoother had a measurement
    rows: dict = {"seed": seed, "gesture": take["gesture"]}
    for s in range(world.shape[1]):
        rows[f"view {s}"] = {g: {"shift": shift_lag(world[:, s], truth, j)} for g, j in GROUPS.items()}
    squat = take["gesture"] == "squat"
    for name, smooth in smoothers(take).items():
        out, on_truth, on_error = smooth(merged), smooth(seen_truth), smooth(merged - seen_truth)
        rows[name] = {}
        for group, joints in GROUPS.items():
            views = min(error_jitter(world[:, s] - truth, joints) for s in range(world.shape[1]))
            error = np.linalg.norm(out[:, joints] - truth[:, joints], axis=-1)
            rows[name][group] = {
                "jitter": error_jitter(out - truth, joints) / views,
                "distortion": error_jitter(on_truth - truth, joints) / views,
                "noise": error_jitter(on_error, joints) / views,
                "error": float(np.nanmean(error)),
                "shift": shift_lag(out, truth, joints),
                "timing": shift_lag(on_truth, seen_truth, joints),
                "vel input": velocity_lag(out, merged, joints, max_lag=3, subframe=True),
            }
        if squat:
            rows[name]["depth"] = depth(out, truth)
            rows[name]["depth by smoothing"] = depth(on_truth, truth)
    if squat:
        rows["bottom"] = bottom_errors(take)
    return rows


def depth(output: np.ndarray, truth: np.ndarray) -> float:
    """The lowest pelvis height of ``output`` minus the truth's, mm (negative = too deep)."""
    return float(np.nanmin(output[:, J["PELVIS"], 2]) - np.nanmin(truth[:, J["PELVIS"], 2]))


def bottom_errors(take: dict) -> dict[str, float]:
    """What the views bring to the squat depth, mm: each view's and the merged input's lowest pelvis height
    against the truth's (:func:`depth`), and their mean pelvis height error around the truth's lowest frame."""
    truth, pelvis = take["truth"], J["PELVIS"]
    low = int(np.nanargmin(truth[:, pelvis, 2]))
    around = slice(max(low - BOTTOM_FRAMES, 0), low + BOTTOM_FRAMES + 1)
    sources = {f"view {s}": take["world"][:, s] for s in range(take["world"].shape[1])} | {"merged": take["merged"]}
    lowest = {f"{name} lowest": depth(x, truth) for name, x in sources.items()}
    at_bottom = {f"{name} at the bottom": float(np.nanmean(x[around, pelvis, 2] - truth[around, pelvis, 2]))
                 for name, x in sources.items()}  # fmt: skip
    return lowest | at_bottom


def cell(values: list[float], digits: int) -> str:
    a = np.asarray(values, dtype=np.float64)
    a = a[np.isfinite(a)]
    if not a.size:
        return "-"
    return f"{np.median(a):.{digits}f} [{a.min():.{digits}f}, {a.max():.{digits}f}]"


def report(title: str, per_take: list[dict]) -> list[str]:
    """The split's tables (markdown lines)."""
    names = [name for name in SMOOTHERS if name in per_take[0]]  # a record from before a row was added lacks it
    out = [f"**{title}**: seeds {', '.join(str(r['seed']) for r in per_take)}; median [min, max] over takes", ""]
    out.append(
        "| output | " + " | ".join(f"{g} jitter (worst take: distortion / noise)" for g in GROUPS) + " | error mm |"
    )
    out.append("|---|" + "---|" * (len(GROUPS) + 1))
    for name in names:
        cells = []
        for g in GROUPS:
            worst = max(per_take, key=lambda r: r[name][g]["jitter"])[name][g]
            total = cell([r[name][g]["jitter"] for r in per_take], 2)
            cells.append(f"{total} ({worst['distortion']:.2f} / {worst['noise']:.2f})")
        excess = [r[name][g]["error"] - r["causal"][g]["error"] for r in per_take for g in GROUPS]
        errors = " / ".join(f"{np.median([r[name][g]['error'] for r in per_take]):.1f}" for g in GROUPS)
        out.append(f"| {name} | " + " | ".join(cells) + f" | {errors} (worst vs causal {max(excess):+.1f}) |")
    out += ["", "Lag, frames (+ = late): best shift against the truth / timing of the smoothing alone / velocity"
            " correlation against the smoother's input", ""]  # fmt: skip
    out.append("| output | " + " | ".join(GROUPS) + " |")
    out.append("|---|" + "---|" * len(GROUPS))
    for name in ("view 0", "view 1", *names):
        cells = []
        for g in GROUPS:
            measures = ("shift",) if name.startswith("view") else ("shift", "timing", "vel input")
            cells.append(" / ".join(cell([r[name][g][m] for r in per_take], 2) for m in measures))
        out.append(f"| {name} | " + " | ".join(cells) + " |")
    squats = [r for r in per_take if "bottom" in r]
    if squats:
        out += ["", "Squat depth, mm (output minus truth; negative = too deep), per squat take", ""]
        bottom = list(squats[0]["bottom"])
        out.append("| seed | " + " | ".join(bottom)
                   + " | " + " | ".join(f"{n} (by smoothing)" for n in names) + " |")  # fmt: skip
        out.append("|---|" + "---|" * (len(bottom) + len(names)))
        for r in squats:
            views = " | ".join(f"{r['bottom'][k]:+.1f}" for k in bottom)
            outs = " | ".join(f"{r[n]['depth']:+.1f} ({r[n]['depth by smoothing']:+.1f})" for n in names)
            out.append(f"| {r['seed']} | {views} | {outs} |")
    return [*out, ""]


def format_markdown(result: dict[str, Any]) -> str:
    """Every split's tables, from :func:`run`'s result (or its JSON, NaN written as null)."""
    splits = nan_for_none(result["splits"])
    lines = [
        f"{result['duration_s']:g} s takes, 2 sensors; jitter as a share of the better single view's error jitter",
        "",
    ]
    for title, per_take in splits.items():
        lines += report(title, per_take)
    return "\n".join(lines).rstrip()


def run(training: list[int], held_out: list[int], duration_s: float) -> dict[str, Any]:
    """Every seed of both splits measured (:func:`measure`); NaN as None, so that it is JSON."""
    splits = {title: [measure(seed, duration_s) for seed in seeds]
              for title, seeds in (("Training seeds", training), ("Held-out seeds", held_out)) if seeds}  # fmt: skip
    return {"duration_s": duration_s, "splits": none_for_nan(splits)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--training", type=int, nargs="*", default=list(range(6)))
    parser.add_argument("--held-out", type=int, nargs="*", default=list(range(1000, 1012)))
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--json", action="store_true", help="print the per-take figures as JSON, stamped")
    args = parser.parse_args()
    args.stamp = RunStamp.begin(sys.argv[1:], program=("python", "scripts/smoothing_targets.py")) if args.json else None
    result = run(args.training, args.held_out, args.duration)
    if args.json:
        print_json(result, args)
    else:
        print(format_markdown(result))


if __name__ == "__main__":
    main()
