"""``skelfuse eval robustness``: every fusion preset in every simulated failure world (``eval/robustness.py``)."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from skelfuse.cli.common import COUNT, EXIT_ATTENTION, EXIT_OK, POSITIVE, print_json
from skelfuse.progress import note

QUICK: dict[str, Any] = {"sensors": [3], "seeds": 2, "duration": 3.0}


def _cmd_eval_robustness(args: argparse.Namespace) -> int:
    from skelfuse.eval import robustness  # each command imports what it runs (start-up)

    sensors = args.sensors or (QUICK["sensors"] if args.quick else [2, 3, 4])
    seeds = args.seeds or (QUICK["seeds"] if args.quick else 6)
    duration = args.duration or (QUICK["duration"] if args.quick else 10.0)
    families = args.families or list(robustness.FAMILY_NAMES)
    if args.bases or args.mirroring_sweep:
        return _cmd_mirroring(args, families, sensors, seeds, duration)
    if not args.quiet:
        note(
            f"eval robustness: {len(families)} families x {len(sensors)} rig sizes x {seeds} seeds, "
            f"{duration:g} s takes, {len(robustness.PRESETS)} presets"
        )
    try:
        result = robustness.run_robustness(
            families=families,
            sensors=sensors,
            n_seeds=seeds,
            duration_s=duration,
            workers=args.workers,
            progress=not args.quiet,
        )
    except ValueError as exc:
        print(f"skelfuse: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print_json(result.to_dict(), args)
    else:
        print(robustness.format_markdown(result), end="")
    if args.strict and (result.n_worse or result.n_live_worse):
        print(
            f"skelfuse: {result.n_worse} (cell, group) where skelfuse is significantly worse than A1, "
            f"{result.n_live_worse} where the live path is significantly worse than the offline one",
            file=sys.stderr,
        )
        return EXIT_ATTENTION
    return EXIT_OK


def _cmd_mirroring(
    args: argparse.Namespace, families: list[str], sensors: list[int], seeds: int, duration: float
) -> int:
    """``--bases`` / ``--mirroring-sweep`` (eval/mirroring.py): A1 and skelfuse only, printed in turn."""
    from skelfuse.eval import mirroring  # each command imports what it runs (start-up)

    common = {"sensors": sensors, "n_seeds": seeds, "duration_s": duration, "workers": args.workers}
    common["progress"] = not args.quiet
    out: dict[str, object] = {}
    try:
        if args.bases:
            out["bases"] = mirroring.run_bases(families=families, **common)
        if args.mirroring_sweep:
            out["sweep"] = mirroring.run_sweep(**common)
    except ValueError as exc:
        print(f"skelfuse: error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print_json(out, args)
        return EXIT_OK
    if "bases" in out:
        print(mirroring.format_bases(out["bases"]))  # type: ignore[arg-type]
    if "sweep" in out:
        print(mirroring.format_sweep(out["sweep"]))  # type: ignore[arg-type]
    return EXIT_OK


def add_robustness_parser(eval_commands: argparse._SubParsersAction) -> None:
    """Add ``eval robustness``."""
    parser = eval_commands.add_parser(
        "robustness",
        help="every fusion preset in every simulated failure world, skelfuse against A1 with paired intervals",
        description="Simulate takes in every failure family (skelfuse.sim.failures; docs/simulator.md) and their "
        "mixture with 2-4 sensors, fuse them with A1, A3, A4, A5, A5post (posterior output), skelfuse, and skelfuse "
        "through the live node's path (skelfuse_live: frame groups, association, tracks, the take looped as a "
        "capture worker plays it), and report the error against exact truth per joint group, swapped left/right "
        "pairs and lag, with the paired 95%% confidence intervals of skelfuse - A1 and skelfuse_live - skelfuse "
        "over seeds per cell; held-out worlds are marked.",
    )
    parser.add_argument("--quick", action="store_true", help="3 sensors, 2 seeds, 3 s takes (CI)")
    parser.add_argument(
        "--families", nargs="+", default=None, metavar="NAME", help="families to run (default: all and mixture)"
    )
    parser.add_argument("--sensors", nargs="+", type=COUNT, default=None, help="rig sizes (default: 2 3 4)")
    parser.add_argument("--seeds", type=COUNT, default=None, help="seeds per cell (default: 6; --quick 2)")
    parser.add_argument("--duration", type=POSITIVE, default=None, metavar="SECONDS", help="take length (default: 10)")
    parser.add_argument("--workers", type=COUNT, default=2, help="worker processes (default: %(default)s)")
    parser.add_argument("--json", action="store_true", help="print the matrix as JSON")
    parser.add_argument(
        "--strict",
        action="store_true",
        help="exit 3 when skelfuse is significantly worse than A1, or skelfuse_live than skelfuse, in any cell",
    )
    parser.add_argument(
        "--bases",
        action="store_true",
        help="instead of the matrix: every family on the mirroring base and on a base without rear-view "
        "mirroring, each cell as its effect beyond its base (A1 and skelfuse; docs/simulator.md)",
    )
    parser.add_argument(
        "--mirroring-sweep",
        action="store_true",
        help="instead of the matrix: the rear-view mirroring rate swept from 0 past the assumption, skelfuse - A1 "
        "per point and the break-even mirrored share per group and rig size",
    )
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    parser.set_defaults(func=_cmd_eval_robustness)
