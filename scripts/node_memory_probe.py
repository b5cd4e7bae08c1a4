"""Run ``skelfuse ARGS...`` with a thread that writes where its memory is, cheaply, every ``--period`` seconds.

    python scripts/node_memory_probe.py OUT.jsonl [--period 10] [--trim-every 0] -- fuse --config rig.toml ...

Used by ``scripts/soak_hostile.py --memory-probe`` to attribute the fusion node's RSS growth without tracemalloc
(which slows the node too much to fuse the soak's rig in real time). Per line of OUT.jsonl:

- ``rss_mb``, and ``smaps`` (resident MB by kind of mapping: heap = glibc's main arena, anon = anonymous
  mappings: glibc's per-thread arenas, mmapped pymalloc arenas, large buffers; file; stack);
- ``malloc``: glibc ``mallinfo2()`` (via ctypes): ``arena_mb`` (bytes obtained with brk/sbrk plus the
  per-thread arenas' heaps), ``mmap_mb`` (large blocks mmapped on their own), ``in_use_mb`` (``uordblks``:
  allocated by malloc and not freed), ``free_held_mb`` (``fordblks``: freed, kept by glibc, not given back),
  ``top_pad_mb`` (``keepcost``: releasable at the top of the main heap);
- ``py_blocks``: ``sys.getallocatedblocks()`` (Python's small-object allocator: blocks in use);
- ``gc_objects`` and, every 6th sample, the 12 commonest types (``gc.get_objects()``, a few ms);
- ``threads``: live threads of the process (``/proc/self/task``), each with its own glibc arena and stack.

``--trim-every N`` calls glibc's ``malloc_trim(0)`` every N seconds (0: never), to measure what giving freed
memory back to the system does (the line then has ``trimmed_mb``: RSS before minus after the trim).
"""

from __future__ import annotations

import argparse
import collections
import ctypes
import gc
import json
import os
import sys
import threading
import time
from pathlib import Path


class _Mallinfo2(ctypes.Structure):
    _fields_ = [
        (name, ctypes.c_size_t)
        for name in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks")
    ] + [("keepcost", ctypes.c_size_t)]


def _libc() -> ctypes.CDLL | None:
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.mallinfo2.restype = _Mallinfo2
        return libc
    except (OSError, AttributeError):  # not glibc, or glibc < 2.33
        return None


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


def smaps_mb() -> dict[str, float]:
    kinds: dict[str, float] = collections.defaultdict(float)
    kind = "anon"
    for line in Path("/proc/self/smaps").read_text().splitlines():
        first = line.split(maxsplit=1)[0]
        if not first.endswith(":") or "-" in first:  # a mapping's header: "start-end perms offset dev inode [path]"
            parts = line.split()
            path = parts[5] if len(parts) > 5 else ""
            kind = "heap" if path == "[heap]" else "stack" if path.startswith("[stack") else "file" if path else "anon"
        elif first == "Rss:":
            kinds[kind] += int(line.split()[1]) / 1024
    return {k: round(v, 2) for k, v in sorted(kinds.items())}


def sample(libc: ctypes.CDLL | None, n: int, trim: bool) -> dict:
    out: dict = {"t_s": None, "rss_mb": round(rss_mb(), 2), "smaps": smaps_mb()}
    if libc is not None:
        info = libc.mallinfo2()
        out["malloc"] = {
            "arena_mb": round(info.arena / 2**20, 2),
            "mmap_mb": round(info.hblkhd / 2**20, 2),
            "in_use_mb": round(info.uordblks / 2**20, 2),
            "free_held_mb": round(info.fordblks / 2**20, 2),
            "top_pad_mb": round(info.keepcost / 2**20, 2),
        }
        if trim:
            before = rss_mb()
            libc.malloc_trim(0)
            out["trimmed_mb"] = round(before - rss_mb(), 2)
    out["py_blocks"] = sys.getallocatedblocks()
    objects = gc.get_objects()
    out["gc_objects"] = len(objects)
    if n % 6 == 0:
        counts = collections.Counter(type(o).__name__ for o in objects)
        out["gc_types"] = dict(counts.most_common(12))
    del objects
    out["threads"] = len(os.listdir("/proc/self/task"))
    return out


def main() -> int:
    argv = sys.argv[1:]
    if "--" not in argv:
        print(__doc__, file=sys.stderr)
        return 2
    split = argv.index("--")
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--period", type=float, default=10.0)
    parser.add_argument("--trim-every", type=float, default=0.0)
    args = parser.parse_args(argv[:split])
    libc = _libc()
    start = time.monotonic()

    def probe() -> None:
        n, next_trim = 0, start + args.trim_every
        with args.out.open("a") as out:
            while True:
                time.sleep(args.period)
                trim = args.trim_every > 0 and time.monotonic() >= next_trim
                if trim:
                    next_trim += args.trim_every
                line = sample(libc, n, trim)
                line["t_s"] = round(time.monotonic() - start, 1)
                out.write(json.dumps(line) + "\n")
                out.flush()
                n += 1

    threading.Thread(target=probe, name="memory-probe", daemon=True).start()
    from skelfuse.cli import entrypoint

    sys.argv = [sys.argv[0], *argv[split + 1 :]]
    entrypoint()  # exits
    return 0


if __name__ == "__main__":
    sys.exit(main())
