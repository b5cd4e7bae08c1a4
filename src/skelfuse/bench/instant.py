"""``skelfuse bench instant``: time of the whole per-instant path, against another source tree in the same run.

The per-instant path is what the fusion node does with one complete instant: a
:class:`~skelfuse.rig.grouping.FrameGroup` of the sensors' frames through
:meth:`GroupFuser.step <skelfuse.rig.instant.GroupFuser.step>` (stack the bodies, to the world, joint
orientations to the world, associate, update the tracks, fuse with the orientation and uncertainty stages) and
:func:`~skelfuse.wire.codec.encode_fused_frame`. Input: the crowd simulator
(:func:`skelfuse.sim.crowd.crowd_scenario`) seen by N sensors, with joint orientations from each view's own
bones (:func:`skelfuse.fusion.orientation.body_hint_frames`) turned by 0.15 rad of noise, so every stage runs.

Both the wall-clock time and the thread's CPU time (``time.thread_time_ns``) of every instant are recorded: on a
machine shared with other work, the CPU time is the fairer comparison (it leaves out the waits for a core).

By default the instants run back to back, which keeps the processor's caches warm with this path's code and
data. A live node gets an instant every 1/30 s and idles in between; ``--paced`` times that (the run sleeps to
each instant's due time). Paced, the same code costs about twice the CPU time per instant, close to the
fusion step's time inside a live node (``skelfuse bench latency``): quote the paced figure for what a node
spends (why: docs/service.md, "Where the time goes"; the figures: docs/evidence.md, "Speed").
``--positions-only`` times the same path with the preset's orientation and uncertainty stages off (a rig whose
consumers need positions only: ``[fusion.params] orientations = false, position_std = false``); the fused
positions are the same either way (those stages never change them).
Each timing runs in a fresh subprocess: this file executed as a script with ``PYTHONPATH`` set to a source tree
(it imports only interfaces that any checkout with fused orientations has), so ``--baseline SRC`` times another
checkout of skelfuse (e.g. the revision before a change) on the same inputs, alternating baseline / current
run by run, and the ratio is taken per round (then the median over rounds). ``--reference`` does the same
against this tree with the numpy forms of the compiled stages in place of the kernels
(:data:`skelfuse.fusion.reference.LIVE_STAGES`): the speed-up of the kernels, measured in the same run. Every run
records the machine's load (``os.getloadavg``) before and after: on a shared machine, prefer the ratios.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import os
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.fusion.orientation import apply_derived, body_hint_frames, quat_from_rotvec, quat_multiply
from skelfuse.fusion.presets import preset
from skelfuse.rig.grouping import FrameGroup
from skelfuse.rig.instant import GroupFuser
from skelfuse.schema.frames import SensorFrame
from skelfuse.sim.crowd import crowd_scenario, simulate_scenario
from skelfuse.sim.observe import load_profile
from skelfuse.wire.codec import encode_fused_frame

FPS = 30.0
OWN_SRC = Path(__file__).resolve().parents[2]
"""The source tree this module was imported from (what ``--baseline`` is compared against)."""


def instant_take(
    n_sensors: int, n_people: int, n_frames: int, seed: int = 0, positions_only: bool = False
) -> tuple[GroupFuser, list[FrameGroup]]:
    """A fresh GroupFuser ("skelfuse" preset; ``positions_only``: its orientation and uncertainty stages off) and
    the simulated crowd's instants as frame groups."""
    scenario = crowd_scenario(n_people=n_people, n_sensors=n_sensors, duration_s=n_frames / FPS, seed=seed)
    obs = simulate_scenario(scenario, load_profile(), seed=seed)
    rng = np.random.default_rng(seed)
    groups = []
    for t in range(obs.n_frames):
        time_us = round(1_000_000 + t * 1e6 / FPS)
        frames = {}
        for s, sid in enumerate(obs.sensor_ids):
            slots = obs.valid[t, s]
            positions = obs.positions[t, s][slots].astype(np.float64)
            quats = apply_derived(body_hint_frames(positions))
            quats = quat_multiply(quats, quat_from_rotvec(rng.normal(0.0, 0.15, (*positions.shape[:2], 3))))
            frames[sid] = SensorFrame(
                sid,
                t,
                time_us,
                time_us * 1000,
                obs.body_ids[t, s][slots].astype(np.uint32),
                positions.astype(np.float32),
                np.where(np.isfinite(quats), quats, 0.0).astype(np.float32),
                obs.confidence[t, s][slots],
            )
        groups.append(FrameGroup(time_us, frames, (), True))
    poses = obs.world_from_sensor_calibrated
    params = preset("skelfuse")
    if positions_only:
        params = dataclasses.replace(params, orientations=False, position_std=False)
    return GroupFuser(obs.sensor_ids, poses, params), groups


def time_instants(
    n_sensors: int,
    n_people: int,
    n_frames: int,
    warmup: int = 30,
    seed: int = 0,
    paced: bool = False,
    positions_only: bool = False,
) -> dict[str, Any]:
    """One timing run in this process: ms per instant (p50 / p99 / max) of GroupFuser.step + encode; ``paced``:
    one instant every 1/FPS s (sleeping in between, as a live node idles), else back to back."""
    fuser, groups = instant_take(n_sensors, n_people, n_frames + warmup, seed, positions_only)
    load_before = os.getloadavg()
    samples = []
    cpu_samples = []
    persons = 0
    period_ns = round(1e9 / FPS)
    due_ns = time.perf_counter_ns()
    for t, group in enumerate(groups):
        if paced:
            due_ns += period_ns
            wait_ns = due_ns - time.perf_counter_ns()
            if wait_ns > 0:
                time.sleep(wait_ns / 1e9)
        start = time.perf_counter_ns()
        cpu_start = time.thread_time_ns()
        instant = fuser.step(group)
        encode_fused_frame(instant.frame)
        cpu = time.thread_time_ns() - cpu_start
        elapsed = time.perf_counter_ns() - start
        if t >= warmup:
            samples.append(elapsed / 1e6)
            cpu_samples.append(cpu / 1e6)
            persons += instant.frame.n_persons
    ms = np.asarray(samples)
    cpu_ms = np.asarray(cpu_samples)
    return {
        "n_sensors": n_sensors,
        "n_people": n_people,
        "n_frames": int(ms.size),
        "paced": paced,
        "positions_only": positions_only,
        "p50_ms": float(np.percentile(ms, 50)),
        "p99_ms": float(np.percentile(ms, 99)),
        "max_ms": float(ms.max()),
        "cpu_p50_ms": float(np.percentile(cpu_ms, 50)),
        "cpu_p99_ms": float(np.percentile(cpu_ms, 99)),
        "mean_persons_out": persons / max(ms.size, 1),
        "load_before": [round(v, 2) for v in load_before],
        "load_after": [round(v, 2) for v in os.getloadavg()],
    }


def use_numpy_references() -> None:
    """Put the numpy references in place of the compiled stages, where the live path looks them up (this process).

    Imported by name here: a worker runs on any tree given with ``--baseline``, and trees without compiled
    stages have no reference package (nor are they ever asked to use it).
    """
    reference = importlib.import_module("skelfuse.fusion.reference")
    for (module, name), numpy_form in reference.LIVE_STAGES.items():
        setattr(importlib.import_module(module), name, numpy_form)


def _run_worker(
    src: Path, n_sensors: int, n_people: int, n_frames: int, paced: bool, positions_only: bool, numpy: bool = False
) -> dict[str, Any]:
    """One timing run in a subprocess on the source tree ``src`` (``numpy``: with the numpy references)."""
    env = dict(os.environ, PYTHONPATH=str(src))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", str(n_sensors), str(n_people), str(n_frames)]
    cmd += ["--paced"] if paced else []
    cmd += ["--positions-only"] if positions_only else []
    cmd += ["--reference"] if numpy else []
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False, timeout=600)
    if out.returncode != 0:
        raise RuntimeError(f"bench instant: the run on {src} failed:\n{out.stderr[-2000:]}")
    result = json.loads(out.stdout.strip().splitlines()[-1])
    result["src"] = str(src)
    return result


def run_instant_bench(
    cases: Sequence[tuple[int, int]],
    *,
    n_frames: int = 300,
    rounds: int = 3,
    baseline: Path | None = None,
    reference: bool = False,
    paced: bool = False,
    positions_only: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """Every (sensors, people) case ``rounds`` times, alternating baseline and current runs (baseline first in
    even rounds, current first in odd ones); ratios = baseline / current per round, median over rounds.
    ``reference``: the baseline is this tree with the numpy references in place of the compiled stages (not
    with ``baseline``). ``paced``: instants at the frame rate (see the module docstring), else back to back;
    ``positions_only``: the orientation and uncertainty stages off."""
    if reference and baseline is not None:
        raise ValueError("bench instant compares against one baseline: --baseline SRC or --reference, not both")
    if reference:
        baseline = OWN_SRC
    out: dict[str, Any] = {
        "current_src": str(OWN_SRC),
        "baseline_src": None if baseline is None else str(baseline),
        "baseline_numpy_references": reference,
        "paced": paced,
        "positions_only": positions_only,
    }
    results = []
    for n_sensors, n_people in cases:
        runs: dict[str, list[dict[str, Any]]] = {"current": [], "baseline": []}
        for r in range(rounds):
            order = (
                ["current"]
                if baseline is None
                else (["baseline", "current"] if r % 2 == 0 else ["current", "baseline"])
            )
            for which in order:
                if progress:
                    print(
                        f"bench instant: {n_sensors} sensors x {n_people} people, round {r + 1}/{rounds}, {which} ...",
                        file=sys.stderr,
                        flush=True,
                    )
                src = OWN_SRC if which == "current" else baseline
                assert src is not None
                numpy = reference and which == "baseline"
                runs[which].append(_run_worker(src, n_sensors, n_people, n_frames, paced, positions_only, numpy))
        case: dict[str, Any] = {"n_sensors": n_sensors, "n_people": n_people, "runs": runs}
        for which, items in runs.items():
            if items:
                case[which] = {k: float(np.median([i[k] for i in items])) for k in _TIMES}
        if baseline is not None:
            for key in _TIMES:
                ratios = [b[key] / c[key] for b, c in zip(runs["baseline"], runs["current"], strict=True)]
                case[f"ratio_{key.removesuffix('_ms')}"] = float(np.median(ratios))
        case["load_1min"] = [i["load_before"][0] for w in runs.values() for i in w]
        results.append(case)
    out["cases"] = results
    return out


_TIMES = ("p50_ms", "p99_ms", "max_ms", "cpu_p50_ms", "cpu_p99_ms")


def format_instant_bench(result: dict[str, Any]) -> str:
    compared = result["baseline_src"] is not None
    columns = ["p50", "p99"] + (["baseline p50", "baseline p99", "ratio p50", "ratio p99"] if compared else [])
    stages = "positions only" if result.get("positions_only") else "incl. orientations and position_std"
    lines = [
        f"Per-instant path (group -> associate -> tracks -> fuse {stages} -> encode), "
        "ms per instant, median over rounds (wall clock, and the thread's CPU time), instants "
        + (f"paced at {FPS:g} Hz (as a live node gets them):" if result.get("paced") else "back to back:"),
        "",
        "| sensors x people | clock | " + " | ".join(columns) + " | load (1 min) |",
        "|---|---|" + "---:|" * len(columns) + "---|",
    ]

    def f(d: dict[str, float] | None, k: str) -> str:
        return "-" if not d else f"{d[k]:.3f}"

    def ratio(c: dict[str, Any], k: str) -> str:
        return f"{c[k]:.2f}x" if k in c else "-"

    for c in result["cases"]:
        cur, base = c.get("current", {}), c.get("baseline")
        load = f"{min(c['load_1min']):.2f}-{max(c['load_1min']):.2f}"
        for clock, prefix in (("wall", ""), ("cpu", "cpu_")):
            cells = [f(cur, prefix + "p50_ms"), f(cur, prefix + "p99_ms")]
            if compared:
                cells += [f(base, prefix + "p50_ms"), f(base, prefix + "p99_ms")]
                cells += [ratio(c, "ratio_" + prefix + "p50"), ratio(c, "ratio_" + prefix + "p99")]
            lines.append(f"| {c['n_sensors']} x {c['n_people']} | {clock} | " + " | ".join(cells) + f" | {load} |")
    baseline = f"{result['baseline_src']}" + (
        " with the numpy references of the compiled stages" if result.get("baseline_numpy_references") else ""
    )
    trees = (
        f"current: {result['current_src']}; baseline: {baseline}. Ratio = baseline / current per round "
        "(alternating runs), median over rounds. "
        if compared
        else ""
    )
    lines += [
        "",
        trees + "cpu: time.thread_time_ns, the work itself (a shared machine's waits for a core excluded). Load: "
        f"os.getloadavg() before each run, {os.cpu_count()} CPUs.",
    ]
    return "\n".join(lines)


def _worker_main(argv: Sequence[str]) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--worker", action="store_true")
    parser.add_argument("--paced", action="store_true")
    parser.add_argument("--positions-only", action="store_true")
    parser.add_argument("--reference", action="store_true")
    parser.add_argument("numbers", type=int, nargs=3)
    args = parser.parse_args(argv)
    if args.reference:
        use_numpy_references()
    n_sensors, n_people, n_frames = args.numbers
    print(
        json.dumps(time_instants(n_sensors, n_people, n_frames, paced=args.paced, positions_only=args.positions_only))
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(_worker_main(sys.argv[1:]))
