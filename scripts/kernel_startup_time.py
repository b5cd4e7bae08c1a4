#!/usr/bin/env python3
"""What the fusion kernels add to a daemon's start: a first start (empty cache: numba compiles) and later ones.

Each run is a fresh interpreter that imports the fusion node's module and then prepares the kernels as the node
does at start-up (``skelfuse.service.node.prepare_kernels``: numba's import, the kernel modules, loading or
compiling every kernel); the time reported is that preparation alone, wall clock and CPU time (the process's and
that of the child processes a first start compiles in). The
first-start runs get an empty cache directory each (``NUMBA_CACHE_DIR``); the later-start runs share one that a
first run filled. The machine's load is printed before and after: on a shared machine the CPU time is the fairer
figure.

Usage::

    python scripts/kernel_startup_time.py [--runs 5]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

PROBE = """
import json, resource, time
import skelfuse.service.node as node
def children_cpu():
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime
wall, cpu, child = time.perf_counter(), time.process_time(), children_cpu()
node.prepare_kernels("probe")
cpu, child = time.process_time() - cpu, children_cpu() - child
print(json.dumps({"wall_s": time.perf_counter() - wall, "cpu_s": cpu + child, "children_cpu_s": child}))
"""


def prepare_time(cache_dir: str) -> dict[str, float]:
    done = subprocess.run(
        [sys.executable, "-c", PROBE],
        env={**os.environ, "NUMBA_CACHE_DIR": cache_dir},
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    print(f"load before: {os.getloadavg()}")
    with tempfile.TemporaryDirectory() as shared:
        first = []
        for _ in range(args.runs):
            with tempfile.TemporaryDirectory() as empty:
                first.append(prepare_time(empty))
        prepare_time(shared)  # fills the shared cache
        later = [prepare_time(shared) for _ in range(args.runs)]
    for label, runs in (("first start (compiles)", first), ("later start (cache)", later)):
        wall = statistics.median(r["wall_s"] for r in runs)
        cpu = statistics.median(r["cpu_s"] for r in runs)
        print(f"{label}: {wall:.2f} s wall, {cpu:.2f} s CPU (median of {len(runs)})")
    print(f"load after: {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
