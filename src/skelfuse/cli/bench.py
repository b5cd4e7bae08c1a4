"""``skelfuse bench fusion|people|instant|latency|depth``: speed against a reference measured in the same run."""

from __future__ import annotations

import argparse
from pathlib import Path

from skelfuse.cli.commands import COMMAND_HELP
from skelfuse.cli.common import (
    COUNT,
    EXIT_ERROR,
    EXIT_OK,
    POSITIVE,
    add_json_option,
    add_preset_option,
    add_seed_option,
    print_json,
)


def _cmd_bench_fusion(args: argparse.Namespace) -> int:
    from skelfuse.bench import fusion as bench_fusion  # each command imports what it runs (start-up)

    result = bench_fusion.run_fusion_bench(
        sensor_counts=args.sensors,
        body_counts=args.bodies,
        preset_name=args.preset,
        n_frames=args.frames,
        quick=args.quick,
        progress=not args.quiet and not args.json,
    )
    if args.json:
        print_json(result.to_dict())
    else:
        print(bench_fusion.format_table(result))
    return EXIT_OK if result.outputs_match else EXIT_ERROR


def _cmd_bench_people(args: argparse.Namespace) -> int:
    from skelfuse.bench.people import bench_people, format_people_bench

    result = bench_people(args.sensors, args.people, args.frames, preset_name=args.preset)
    if args.json:
        print_json(result)
    else:
        print(format_people_bench(result))
    return EXIT_OK


def _cmd_bench_instant(args: argparse.Namespace) -> int:
    from skelfuse.bench.instant import format_instant_bench, run_instant_bench

    result = run_instant_bench(
        args.cases,
        n_frames=args.frames,
        rounds=args.rounds,
        baseline=args.baseline,
        reference=args.reference,
        paced=args.paced,
        positions_only=args.positions_only,
        progress=not args.json,
    )
    if args.json:
        print_json(result, args)
    else:
        print(format_instant_bench(result))
    return EXIT_OK


def _cmd_bench_latency(args: argparse.Namespace) -> int:
    from skelfuse.bench import latency

    result = latency.run_latency_bench(
        sensor_counts=args.sensors,
        duration_s=args.duration,
        sweep=not args.no_sweep,
        progress=not args.json,
        n_people=args.people,
        node_src=args.node_src,
        cases=args.cases,
    )
    if args.json:
        print_json(result.to_dict(), args)
    else:
        print(latency.format_table(result))
    return EXIT_OK


def _cmd_bench_depth(args: argparse.Namespace) -> int:
    from skelfuse.bench.depth import format_depth_bench, run_depth_bench

    result = run_depth_bench(
        tuple(args.people),
        n_sensors=args.sensors,
        n_frames=args.frames,
        voxel_mm=args.voxel,
        icp=not args.no_icp,
        seed=args.seed,
        progress=not args.json,
    )
    if args.json:
        print_json(result, args)  # stamped: docs/evidence.md quotes it
    else:
        print(format_depth_bench(result))
    return EXIT_OK


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``bench`` with its sub-commands."""
    bench = commands.add_parser("bench", help=COMMAND_HELP["bench"])
    bench_commands = bench.add_subparsers(dest="bench_command", metavar="WHAT", required=True)
    _add_fusion(bench_commands)
    _add_people(bench_commands)
    _add_instant(bench_commands)
    _add_latency(bench_commands)
    _add_depth(bench_commands)


def _add_fusion(bench_commands: argparse._SubParsersAction) -> None:
    fusion = bench_commands.add_parser(
        "fusion",
        help="time per fused frame against a scikit-learn + filterpy reference on the same inputs",
    )
    fusion.add_argument(
        "--sensors",
        type=COUNT,
        nargs="+",
        default=[1, 2, 4, 5, 8, 16],
        metavar="N",
        help="sensor counts (default: %(default)s)",
    )
    fusion.add_argument(
        "--bodies", type=COUNT, nargs="+", default=[1, 3, 6], metavar="N", help="body counts (default: %(default)s)"
    )
    add_preset_option(fusion, default="A5", what="fusion preset to time")
    fusion.add_argument("--frames", type=COUNT, default=300, help="timed frames per case (default: %(default)s)")
    fusion.add_argument("--quick", action="store_true", help="fewer frames and a few cases, for CI")
    add_json_option(fusion)
    fusion.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    fusion.set_defaults(func=_cmd_bench_fusion)


def _add_people(bench_commands: argparse._SubParsersAction) -> None:
    people = bench_commands.add_parser(
        "people",
        help="time per frame of multi-person fusion (association + tracks + fusion) on a simulated crowd",
    )
    people.add_argument("--sensors", type=COUNT, default=8, help="sensors in the rig (default: %(default)s)")
    people.add_argument("--people", type=COUNT, default=6, help="people in the crowd (default: %(default)s)")
    people.add_argument("--frames", type=COUNT, default=300, help="timed frames (default: %(default)s)")
    add_preset_option(people, default="skelfuse")
    add_json_option(people)
    people.set_defaults(func=_cmd_bench_people)


def _add_instant(bench_commands: argparse._SubParsersAction) -> None:
    instant = bench_commands.add_parser(
        "instant",
        help="time per instant of the whole per-instant path (group, associate, tracks, fuse, encode), "
        "optionally against another source tree in the same run",
        description="Time the node's per-instant path (GroupFuser.step + encode_fused_frame, preset skelfuse with "
        "orientations and position_std) on a simulated crowd, every run in a fresh subprocess with the machine's "
        "load recorded. With --baseline SRC (the src/ folder of another checkout, e.g. a worktree at the starting "
        "revision) the same runs alternate between SRC and this tree and the ratio baseline / current is "
        "reported per case; with --reference the baseline is this tree running the numpy references of its "
        "compiled stages.",
    )
    instant.add_argument(
        "--cases",
        type=_sensors_by_people,
        nargs="+",
        default=[(4, 1), (16, 6)],
        metavar="SxP",
        help="sensors x people, e.g. 4x1 16x6 (default: 4x1 16x6)",
    )
    instant.add_argument("--frames", type=COUNT, default=300, help="timed instants per run (default: %(default)s)")
    instant.add_argument("--rounds", type=COUNT, default=3, help="runs per case and tree (default: %(default)s)")
    baseline = instant.add_mutually_exclusive_group()
    baseline.add_argument(
        "--baseline", type=Path, default=None, metavar="SRC", help="src/ folder of the checkout to compare against"
    )
    baseline.add_argument(
        "--reference",
        action="store_true",
        help="compare against this tree with the numpy references in place of the compiled kernels (the kernels' "
        "speed-up, measured in the same run)",
    )
    instant.add_argument(
        "--paced",
        action="store_true",
        help="one instant every 1/30 s, idle in between, as a live node gets them (default: back to back, which "
        "keeps the caches warm and times the path at its fastest; paced took about twice the CPU here)",
    )
    instant.add_argument(
        "--positions-only",
        action="store_true",
        help="the preset's orientation and uncertainty stages off, as in a rig with [fusion.params] orientations = "
        "false, position_std = false (the fused positions are the same)",
    )
    add_json_option(instant)
    instant.set_defaults(func=_cmd_bench_instant)


def _sensors_by_people(text: str) -> tuple[int, int]:
    """``"16x6"`` -> (16, 6)."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.isdigit() and int(p) > 0 for p in parts):
        raise argparse.ArgumentTypeError(f"expected SENSORSxPEOPLE with positive counts, e.g. 16x6; got {text!r}")
    return int(parts[0]), int(parts[1])


def _add_latency(bench_commands: argparse._SubParsersAction) -> None:
    latency = bench_commands.add_parser(
        "latency",
        help="publish -> fused-receive latency over zenoh on loopback, the node's own latency, max sensors",
        description="Start a fusion node (subprocess) on loopback zenoh, publish N simulated sensors at 30 Hz "
        "from this process and time every fused frame: publish -> fused receive p50/p99/max, the node's own "
        "added latency (from its status), and a sweep for the largest sensor count this machine sustains at "
        "30 Hz. Prints absolute figures; targets: node adds <= 1 ms p99, publish -> subscriber <= 5 ms p99 "
        "for 5 sensors.",
    )
    latency.add_argument(
        "--sensors",
        type=COUNT,
        nargs="+",
        default=[4, 5, 8],
        metavar="N",
        help="sensor counts to measure (default: %(default)s)",
    )
    latency.add_argument(
        "--duration",
        type=POSITIVE,
        default=5.0,
        metavar="SECONDS",
        help="measured seconds per sensor count (default: %(default)s)",
    )
    latency.add_argument("--people", type=COUNT, default=1, help="people every sensor sees (default: %(default)s)")
    latency.add_argument(
        "--cases",
        type=_sensors_by_people,
        nargs="+",
        default=[],
        metavar="SxP",
        help="more cases, sensors x people each, after --sensors, e.g. 8x16 64x6 (a crowd, the largest rig)",
    )
    latency.add_argument(
        "--node-src",
        type=Path,
        default=None,
        metavar="SRC",
        help="run the fusion node from this src/ folder (e.g. a worktree at an older revision) with this harness, "
        "to compare the two in the same session",
    )
    latency.add_argument("--no-sweep", action="store_true", help="skip the search for the largest sensor count")
    add_json_option(latency)
    latency.set_defaults(func=_cmd_bench_latency)


def _add_depth(bench_commands: argparse._SubParsersAction) -> None:
    depth = bench_commands.add_parser(
        "depth",
        help="depth-level fusion: person-cloud bytes on the wire, capture and fusion time per person (simulated)",
        description="Simulate 1-3 people in front of a 4-sensor rig (depth + body-index images per sensor), time "
        "the capture side (mask, lift, voxelize, encode the person clouds) per sensor-frame and the fusion node "
        "(decode, to world, merge, optional ICP, frontalize, render the virtual depth image with hole filling) "
        "per person-frame, and count the payload bytes per frame and per second at 30 fps. The body tracker on "
        "the virtual image is not included (it needs the SDK and a GPU).",
    )
    depth.add_argument(
        "--people", type=COUNT, nargs="+", default=[1, 2, 3], metavar="N", help="people counts (default: %(default)s)"
    )
    depth.add_argument("--sensors", type=COUNT, default=4, help="sensors in the rig (default: %(default)s)")
    depth.add_argument("--frames", type=COUNT, default=30, help="frames per people count (default: %(default)s)")
    depth.add_argument("--voxel", type=POSITIVE, default=15.0, help="voxel edge, mm (default: %(default)s)")
    depth.add_argument("--no-icp", action="store_true", help="skip the variant with ICP refinement (the slow one)")
    add_seed_option(depth, default=0)
    add_json_option(depth)
    depth.set_defaults(func=_cmd_bench_depth)
