"""Per-instant CPU cost of the live fixed-lag smoother, against the live filter step measured in the same run.

A stream of ``--persons`` walkers (32 joints, merged positions with 10 mm noise, two views each) goes through
:class:`skelfuse.fusion.smoother.FixedLagSmoother` (``push`` per instant) and, as the reference, through the
live filter alone (one :func:`skelfuse.fusion.filters.filter_step` per person per instant: what an instant costs
without smoothing). ``--baseline FILE`` adds another ``smoother.py`` (e.g. an earlier revision's, written out
with ``git show REV:src/skelfuse/fusion/smoother.py > FILE``) run on the same stream. The variants run in turn,
``--repeats`` times; the median per-instant time of each is printed with its ratio to the reference and the
1-minute load average.

    PYTHONPATH=src python scripts/fixed_lag_cost.py [--persons 2] [--instants 300] [--lag 3] [--repeats 7]
                                                    [--baseline FILE]
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import numpy as np

from skelfuse.fusion import preset
from skelfuse.fusion import smoother as current
from skelfuse.fusion.filters import filter_step, init_filter_state
from skelfuse.sim.gestures import make_gesture

FPS = 30.0


def stream(persons: int, instants: int) -> tuple[np.ndarray, np.ndarray]:
    """(T, P, 32, 3) merged positions of ``persons`` walkers with 10 mm noise, and (T, P, 32) views behind each."""
    times = np.arange(instants) / FPS
    walkers = [make_gesture("walking", duration_s=instants / FPS, seed=p).at_times(times) for p in range(persons)]
    truth = np.stack(walkers, axis=1) + np.arange(persons)[None, :, None, None] * np.array([900.0, 0.0, 0.0])
    merged = truth + np.random.default_rng(0).normal(0.0, 10.0, truth.shape)
    return merged, np.full(merged.shape[:3], 2, dtype=np.int16)


def run_smoother(module: ModuleType, merged: np.ndarray, agree: np.ndarray, lag: int) -> float:
    """Seconds per instant of ``module.FixedLagSmoother`` over the stream (its flush included)."""
    params = preset("skelfuse")
    smoother = module.FixedLagSmoother(params, lag)
    ids = np.arange(1, merged.shape[1] + 1)
    start = time.process_time()
    for t in range(len(merged)):
        smoother.push(t / FPS, ids, merged[t], agree[t], None)
    smoother.flush()
    return (time.process_time() - start) / len(merged)


def run_filter(merged: np.ndarray, agree: np.ndarray) -> float:
    """Seconds per instant of the live filter alone, one step per person."""
    params = preset("skelfuse")
    states = [init_filter_state(merged.shape[2]) for _ in range(merged.shape[1])]
    start = time.process_time()
    for t in range(len(merged)):
        for p, (x, P, coast) in enumerate(states):
            _, x, P, coast = filter_step(x, P, coast, merged[t, p], agree[t, p], params, 1.0 / FPS)
            states[p] = (x, P, coast)
    return (time.process_time() - start) / len(merged)


def load_module(path: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location("baseline_smoother", path)
    if spec is None or spec.loader is None:
        raise SystemExit(f"cannot load {path}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--persons", type=int, default=2)
    parser.add_argument("--instants", type=int, default=300)
    parser.add_argument("--lag", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--baseline", type=Path, help="another smoother.py to time on the same stream")
    args = parser.parse_args()
    merged, agree = stream(args.persons, args.instants)
    variants: dict[str, Callable[[], float]] = {
        "live filter alone (reference)": lambda: run_filter(merged, agree),
        "fixed lag": lambda: run_smoother(current, merged, agree, args.lag),
    }
    if args.baseline is not None:
        baseline = load_module(args.baseline)
        variants[f"fixed lag of {args.baseline.name}"] = lambda: run_smoother(baseline, merged, agree, args.lag)
    for run in variants.values():  # warm up (compiled kernels, caches)
        run()
    times: dict[str, list[float]] = {name: [] for name in variants}
    load_start = os.getloadavg()[0]
    for _ in range(args.repeats):
        for name, run in variants.items():
            times[name].append(run())
    load_end = os.getloadavg()[0]
    reference = float(np.median(times["live filter alone (reference)"]))
    print(f"{args.persons} persons x 32 joints, lag {args.lag}, {args.instants} instants x {args.repeats} repeats; "
          f"load average {load_start:.2f} -> {load_end:.2f}")  # fmt: skip
    for name, values in times.items():
        median = float(np.median(values))
        print(f"{name}: {median * 1e6:.0f} us per instant ({median / reference:.1f} x the reference)")


if __name__ == "__main__":
    main()
