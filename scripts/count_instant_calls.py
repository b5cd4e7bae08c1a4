#!/usr/bin/env python3
"""How many operations the per-instant path issues: the floor under its time, whatever numpy does per element.

    python scripts/count_instant_calls.py [--cases 4x1 16x6] [--frames 30] [--top 25]
    PYTHONPATH=/path/to/other/checkout/src python scripts/count_instant_calls.py   # the same count for another tree

Runs ``skelfuse bench instant``'s simulated crowd through GroupFuser.step + encode_fused_frame (30 warm-up
instants first) under an opcode tracer and counts, per instant, every CALL, binary / comparison / unary operator
and subscript (read or write) executed in a frame of a skelfuse module (bench excluded): each is one numpy call
when its operands are arrays (a few act on Python scalars, which cost ~50 ns, not ~1 us). Also counted: the calls
made inside numpy's own Python-level functions (np.moveaxis, ndarray.mean's wrapper, dispatchers ...) entered from
there. The tracer makes the run ~100x slower; the counts do not depend on the machine or its load.
"""

from __future__ import annotations

import argparse
import collections
import dis
import sys
from pathlib import Path
from types import FrameType
from typing import Any

from skelfuse.wire.codec import encode_fused_frame

sys.path.insert(0, str(Path(__file__).resolve().parent))
from profile_instant import _bench_instant  # one loader of bench instant's take for both scripts

_KINDS = {
    dis.opmap["CALL"]: "call",
    dis.opmap["BINARY_OP"]: "operator",
    dis.opmap["COMPARE_OP"]: "operator",
    dis.opmap["UNARY_INVERT"]: "operator",
    dis.opmap["UNARY_NEGATIVE"]: "operator",
    dis.opmap["BINARY_SUBSCR"]: "subscript",
    dis.opmap["STORE_SUBSCR"]: "subscript",
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["4x1", "16x6"], metavar="SxP")
    parser.add_argument("--frames", type=int, default=30, help="traced instants per case (default: 30)")
    parser.add_argument("--top", type=int, default=25, help="functions listed per case (default: 25)")
    args = parser.parse_args()
    counts: collections.Counter[tuple[str, str]] = collections.Counter()
    by_function: collections.Counter[str] = collections.Counter()

    def tracer(frame: FrameType, event: str, arg: Any) -> Any:
        filename = frame.f_code.co_filename
        if "/skelfuse/" in filename and "/bench/" not in filename:
            where = "skelfuse"
        elif "/numpy/" in filename:
            where = "numpy"
        else:
            return None
        frame.f_trace_opcodes = True

        def local(frame: FrameType, event: str, arg: Any) -> Any:
            if event == "opcode":
                kind = _KINDS.get(frame.f_code.co_code[frame.f_lasti])
                if kind is not None and (where == "skelfuse" or kind == "call"):
                    counts[(where, kind)] += 1
                    if where == "skelfuse":
                        by_function[frame.f_code.co_qualname] += 1
            return local

        return local

    warmup = 30
    for case in args.cases:
        n_sensors, n_people = (int(v) for v in case.lower().split("x"))
        fuser, groups = _bench_instant().instant_take(n_sensors, n_people, warmup + args.frames)
        for group in groups[:warmup]:
            encode_fused_frame(fuser.step(group).frame)
        counts.clear()
        by_function.clear()
        sys.settrace(tracer)
        try:
            for group in groups[warmup:]:
                encode_fused_frame(fuser.step(group).frame)
        finally:
            sys.settrace(None)
        n = args.frames
        ours = {kind: v / n for (where, kind), v in counts.items() if where == "skelfuse"}
        print(
            f"\n{case}: {sum(ours.values()):.0f} operations per instant in skelfuse code ("
            + ", ".join(f"{kind} {v:.0f}" for kind, v in sorted(ours.items()))
            + f"); {counts[('numpy', 'call')] / n:.0f} calls inside numpy's Python-level functions"
        )
        print("| function | operations per instant |")
        print("|---|---:|")
        for name, v in by_function.most_common(args.top):
            print(f"| {name} | {v / n:.0f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
