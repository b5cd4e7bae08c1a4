#!/usr/bin/env python3
"""Where the fusion node's added latency goes: per-stage timestamps inside a live node, over loopback zenoh.

    python scripts/node_latency_breakdown.py [--sensors 4 16] [--people 1] [--duration 4] [--node-src SRC]

Runs ``skelfuse bench latency``'s harness (N simulated sensors at 30 Hz, the node as a subprocess) with a probe
loaded into the node process (a ``sitecustomize`` on its ``PYTHONPATH``) that wraps, without changing them, the
intake queue (``SampleQueue.__call__`` / ``get`` / ``get_nowait``), ``FusionCore.receive`` and ``_fuse``,
``FusionNode._publish`` and ``_publish_status``, and counts the garbage collector's passes. For every instant
completed by a frame (the frames the node's own ``node_added_ms`` is measured on), after the warm-up:

* ``queue``: the completing frame's arrival stamp (zenoh callback) -> taken off the queue by the loop (waiting
  behind the frames before it, or for the loop to wake);
* ``decode + group``: ``receive`` start -> ``_fuse`` start (decode, checks, ``FrameGrouper.push``);
* ``fuse`` (wall and the loop thread's CPU): the fusion step plus encoding;
* ``to publish``: ``_fuse`` end -> ``_publish`` start;
* ``put``: ``_publish`` (``publisher.put``, then the pose-fit monitor; the node's ``node_added_ms`` stops right
  after ``put``);
* ``total``: arrival -> ``_publish`` end.

Then the slowest 2% of those instants (at least 3), one by one: their stages and what overlapped them (gc passes
by generation, status publishes, other zenoh deliveries), to tell where the tail comes from.

``--node-src`` runs the node from another checkout's ``src`` (e.g. the starting revision) under the same probe.
On a shared machine the wall-clock stages include waits for a core; the CPU column does not.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from skelfuse.bench.latency import measure

PROBE_ENV = "SKELFUSE_NODE_PROBE_OUT"

_SITECUSTOMIZE = f"""
import os
if os.environ.get({PROBE_ENV!r}):
    import importlib.util
    _spec = importlib.util.spec_from_file_location("_node_probe", {str(Path(__file__).resolve())!r})
    _module = importlib.util.module_from_spec(_spec)
    _spec.loader.exec_module(_module)
    _module.install(os.environ[{PROBE_ENV!r}])
"""


def install(out_path: str) -> None:
    """Wrap the node's stages (in the node process); the records are written to ``out_path`` at exit."""
    import atexit
    import gc
    import time

    from skelfuse.service import node as node_module
    from skelfuse.service import zenoh_io

    rec: dict[str, list] = {"recv": [], "fuse": [], "put": [], "get": [], "cb": [], "gc": [], "status": []}
    now, cpu = time.monotonic_ns, time.thread_time_ns

    def wrap(owner: object, name: str, record: object) -> None:
        original = getattr(owner, name)

        def wrapped(*args: object, **kwargs: object) -> object:
            start, start_cpu = now(), cpu()
            result = original(*args, **kwargs)
            record(args, result, start, now(), cpu() - start_cpu)  # type: ignore[operator]
            return result

        setattr(owner, name, wrapped)

    wrap(
        node_module.FusionCore,
        "receive",
        lambda a, r, s, e, c: rec["recv"].append((a[3], s, e, c, len(r))),
    )
    wrap(node_module.FusionCore, "_fuse", lambda a, r, s, e, c: rec["fuse"].append((a[2], s, e, c)))
    wrap(
        node_module.FusionNode,
        "_publish",
        lambda a, r, s, e, c: a[1] and rec["put"].append(([o.trigger_arrival_ns for o in a[1]], s, e)),
    )
    wrap(node_module.FusionNode, "_publish_status", lambda a, r, s, e, c: rec["status"].append((s, e, c)))
    wrap(zenoh_io.SampleQueue, "get", lambda a, r, s, e, c: r is not None and rec["get"].append((r.arrival_ns, e)))
    wrap(
        zenoh_io.SampleQueue, "get_nowait", lambda a, r, s, e, c: r is not None and rec["get"].append((r.arrival_ns, e))
    )
    wrap(zenoh_io.SampleQueue, "__call__", lambda a, r, s, e, c: rec["cb"].append((s, e, c)))
    gc_start: list[int] = [0]

    def on_gc(phase: str, info: dict) -> None:
        if phase == "start":
            gc_start[0] = now()
        else:
            rec["gc"].append((info["generation"], gc_start[0], now()))

    gc.callbacks.append(on_gc)
    atexit.register(lambda: Path(out_path).write_text(json.dumps(rec)))


def breakdown(rec: dict[str, list], skip: int = 30) -> dict[str, dict[str, float]]:
    """Per completed instant (after ``skip`` instants): each stage's p50 / p90 / p99 / max, ms."""
    taken = {arrival: t for arrival, t in rec["get"]}
    received = {a: (s, e) for a, s, e, _, _ in rec["recv"]}
    fused = {t: (s, e, c) for t, s, e, c in rec["fuse"] if t is not None}
    published = {t: (s, e) for triggers, s, e in rec["put"] for t in triggers if t is not None}
    rows = []
    spans = []  # (arrival, publish end) of each row: what else ran in between (outliers below)
    for t in sorted(fused)[skip:]:
        if t not in taken or t not in received or t not in published:
            continue
        fs, fe, fc = fused[t]
        ps, pe = published[t]
        spans.append((t, pe))
        rows.append(
            {
                "queue": taken[t] - t,
                "decode + group": fs - received[t][0],
                "fuse (wall)": fe - fs,
                "fuse (CPU)": fc,
                "to publish": ps - fe,
                "put": pe - ps,
                "total": pe - t,
            }
        )
    out: dict[str, dict[str, float]] = {}
    for stage in rows[0] if rows else []:
        values = np.array([r[stage] for r in rows]) / 1e6
        out[stage] = {q: round(float(np.percentile(values, v)), 3) for q, v in (("p50", 50), ("p90", 90), ("p99", 99))}
        out[stage]["max"] = round(float(values.max()), 3)
    others = [(e - s, c) for a, s, e, c, n in rec["recv"] if n == 0]
    if others:
        out["receive of a non-completing frame"] = {
            "wall p50": round(float(np.median([w for w, _ in others])) / 1e6, 3),
            "CPU p50": round(float(np.median([c for _, c in others])) / 1e6, 3),
        }
    if rec["gc"]:
        gc_ms = np.array([e - s for _, s, e in rec["gc"]]) / 1e6
        out["gc passes"] = {
            "n": len(gc_ms),
            "p50": round(float(np.median(gc_ms)), 3),
            "max": round(float(gc_ms.max()), 3),
        }
    if rec["status"]:
        st = np.array([e - s for s, e, _ in rec["status"]]) / 1e6
        out["status publish"] = {"n": len(st), "p50": round(float(np.median(st)), 3), "max": round(float(st.max()), 3)}
    out["instants"] = {"n": len(rows)}
    out.update(_outliers(rec, rows, spans))
    return out


def _outliers(rec: dict[str, list], rows: list[dict[str, int]], spans: list[tuple[int, int]]) -> dict[str, dict]:
    """The slowest 2% of instants (at least 3): each one's stages, ms, and what overlapped it between the frame's
    arrival and the end of the put: gc passes (generation: ms), status publishes (ms), zenoh deliveries."""
    out: dict[str, dict] = {}
    order = sorted(range(len(rows)), key=lambda i: rows[i]["total"], reverse=True)
    for rank, i in enumerate(order[: max(3, len(rows) // 50)]):
        start, end = spans[i]
        item: dict = {stage: round(v / 1e6, 3) for stage, v in rows[i].items()}
        item["gc"] = [f"gen{g}: {(e - s) / 1e6:.3f}" for g, s, e in rec["gc"] if s < end and e > start]
        item["status"] = [round((e - s) / 1e6, 3) for s, e, _ in rec["status"] if s < end and e > start]
        item["deliveries"] = sum(1 for s, e, _ in rec["cb"] if start < s < end)
        out[f"slowest #{rank + 1}"] = item
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sensors", type=int, nargs="+", default=[4, 16])
    parser.add_argument("--people", type=int, default=1)
    parser.add_argument("--duration", type=float, default=4.0)
    parser.add_argument("--node-src", type=Path, default=Path(__file__).resolve().parents[1] / "src")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    results = {}
    with tempfile.TemporaryDirectory(prefix="skelfuse-probe-") as tmp:
        probe_dir = Path(tmp) / "probe"
        probe_dir.mkdir()
        (probe_dir / "sitecustomize.py").write_text(_SITECUSTOMIZE)
        for n in args.sensors:
            out = Path(tmp) / f"probe-{n}.json"
            os.environ[PROBE_ENV] = str(out)
            print(f"node latency breakdown: {n} sensors x {args.people} people ...", file=sys.stderr, flush=True)
            case = measure(
                n,
                args.duration,
                workdir=Path(tmp),
                n_people=args.people,
                node_src=Path(f"{probe_dir}{os.pathsep}{args.node_src}"),
            )
            stages = breakdown(json.loads(out.read_text())) if out.exists() else {}
            results[f"{n}x{args.people}"] = {
                "node_added_p50_ms": case.node_added_p50_ms,
                "node_added_p99_ms": case.node_added_p99_ms,
                "load": [case.load_before[0], case.load_after[0]],
                "stages": stages,
            }
    if args.json:
        print(json.dumps(results, indent=1))
        return 0
    for name, result in results.items():
        print(
            f"\n{name}: node added p50 {result['node_added_p50_ms']} ms, p99 {result['node_added_p99_ms']} ms, "
            f"load {result['load'][0]:.2f}-{result['load'][1]:.2f}"
        )
        for stage, figures in result["stages"].items():
            print(f"  {stage:36s} " + "  ".join(f"{k} {v}" for k, v in figures.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
