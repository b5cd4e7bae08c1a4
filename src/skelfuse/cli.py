"""The ``skelfuse`` command line: parses arguments, calls the library, turns typed errors into exit codes.

Subcommands import their modules lazily so ``skelfuse --help`` stays fast and a missing optional
dependency only affects the command that needs it.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from skelfuse import __version__
from skelfuse.errors import ConfigError, DataError, SkelfuseError

EXIT_OK = 0
EXIT_ERROR = 1
EXIT_USAGE = 2

log = logging.getLogger("skelfuse")


def _print_json(payload: dict[str, Any]) -> None:
    json.dump(payload, sys.stdout, indent=2, allow_nan=False, default=_json_default)
    sys.stdout.write("\n")


def _json_default(value: Any) -> Any:
    """numpy scalars and arrays, Paths: the types results may carry."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot serialize {type(value).__name__} to JSON")


def _cmd_eval_paper(args: argparse.Namespace) -> int:
    from skelfuse.eval import paper

    result = paper.run_paper_eval(
        out_dir=None if args.no_files else args.out,
        quick=args.quick,
        seed=args.seed,
        duration_s=args.duration,
        profile_path=args.profile,
        progress=not args.quiet,
        workers=args.workers,
    )
    if args.json:
        _print_json(result.to_dict())
    else:
        print(paper.format_markdown(result))
        if not args.no_files:
            print(f"\nTables, CSV and figures written to {args.out}/", file=sys.stderr)
    return EXIT_OK


def _cmd_eval_real(args: argparse.Namespace) -> int:
    from skelfuse.eval import real

    result = real.run_real_eval(args.data, eps_mm=args.eps)
    if args.json:
        _print_json(result.to_dict())
    else:
        text = real.format_markdown(result)
        print(text)
        if args.out is not None:
            args.out.mkdir(parents=True, exist_ok=True)
            (args.out / "report.md").write_text(text + "\n", encoding="utf-8")
            print(f"\nReport written to {args.out / 'report.md'}", file=sys.stderr)
    return EXIT_OK


def _cmd_bench_fusion(args: argparse.Namespace) -> int:
    from skelfuse.bench import fusion as bench_fusion

    result = bench_fusion.run_fusion_bench(
        sensor_counts=args.sensors,
        body_counts=args.bodies,
        preset_name=args.preset,
        n_frames=args.frames,
        quick=args.quick,
        progress=not args.quiet and not args.json,
    )
    if args.json:
        _print_json(result.to_dict())
    else:
        print(bench_fusion.format_table(result))
    return EXIT_OK if result.outputs_match else EXIT_ERROR


def _cmd_demo(args: argparse.Namespace) -> int:
    from skelfuse import demo

    summary = demo.run_demo(
        duration_s=args.duration,
        gesture=args.gesture,
        preset_name=args.preset,
        seed=args.seed,
        rrd_path=args.rrd,
        spawn=False if args.rrd is not None else None,
        realtime=args.realtime,
        progress=not args.json,
    )
    if args.json:
        _print_json(summary.to_dict())
    else:
        print(demo.format_summary(summary))
    return EXIT_OK


def _default_data_dir() -> Path:
    """``../shared/data`` beside the working directory's project, where the team's real recordings live."""
    return Path.cwd().parent / "shared" / "data" / "azure-kinect-andyj1" / "saved_data_2_3dev"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="skelfuse",
        description="Fuse the skeletons of several Azure Kinect body trackers into one accurate, smooth skeleton.",
    )
    parser.add_argument("--version", action="version", version=f"skelfuse {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages on stderr")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    # demo -----------------------------------------------------------------------------------------
    demo = commands.add_parser(
        "demo",
        help="a simulated 4-sensor rig fused live and shown in Rerun (saved to a .rrd where there is no screen)",
        description="Simulate a person in front of four virtual Azure Kinects, fuse the views frame by frame and "
        "show raw and fused skeletons in the Rerun viewer. Without a display (or with --rrd) the recording is "
        "saved to a file. Prints accuracy against the simulator's ground truth and the fusion time.",
    )
    demo.add_argument(
        "--duration",
        type=float,
        default=20.0,
        metavar="SECONDS",
        help="length of the simulated take (default: %(default)s)",
    )
    demo.add_argument(
        "--gesture",
        default="walking",
        choices=["hands_up_down", "jump", "squat", "lunge", "walking", "random"],
        help="what the simulated person does (default: %(default)s)",
    )
    demo.add_argument("--preset", default="A5", help="fusion preset (default: %(default)s)")
    demo.add_argument("--seed", type=int, default=0, help="simulation seed (default: %(default)s)")
    demo.add_argument(
        "--rrd", type=Path, default=None, metavar="FILE", help="save the recording to FILE instead of spawning a viewer"
    )
    demo.add_argument(
        "--realtime",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="pace frames at 30 Hz (default: only when a live viewer is open)",
    )
    demo.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    demo.set_defaults(func=_cmd_demo)

    # eval -----------------------------------------------------------------------------------------
    evaluate = commands.add_parser("eval", help="reproduce the paper's experiments / evaluate on real data")
    eval_commands = evaluate.add_subparsers(dest="eval_command", metavar="WHAT", required=True)

    paper = eval_commands.add_parser(
        "paper",
        help="the paper's three experiments on simulated data with exact ground truth",
        description="Reproduce experiments 1-3 of Lee et al. 2022 (ablations A1-A5, DBSCAN eps sweep, number "
        "of sensors) on a simulated 4-sensor rig, against exact ground truth and against the paper's "
        "best-view reference. Writes markdown, CSV and PNG charts to --out.",
    )
    paper.add_argument("--quick", action="store_true", help="a small subset that runs in well under a minute")
    paper.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    paper.add_argument("--out", type=Path, default=Path("eval_out/paper"), help="output folder (default: %(default)s)")
    paper.add_argument("--no-files", action="store_true", help="write no output folder, only print")
    paper.add_argument("--seed", type=int, default=0, help="simulation seed (default: %(default)s)")
    paper.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="SECONDS",
        help="length of each simulated take (default: the paper's ~33 s, or short with --quick)",
    )
    paper.add_argument(
        "--profile",
        type=Path,
        default=None,
        help="simulator noise profile TOML (default: the packaged Azure Kinect profile)",
    )
    paper.add_argument("--workers", type=int, default=2, help="worker processes (default: %(default)s)")
    paper.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    paper.set_defaults(func=_cmd_eval_paper)

    real = eval_commands.add_parser(
        "real",
        help="fuse the real 3-sensor Azure Kinect take and report agreement, jitter and leave-one-out error",
    )
    real.add_argument(
        "--data",
        type=Path,
        default=_default_data_dir(),
        help="folder with joints_gen_{master,sub1,sub2,sync}.csv (default: %(default)s)",
    )
    real.add_argument("--eps", type=float, default=100.0, help="DBSCAN radius in mm (default: %(default)s)")
    real.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    real.add_argument("--out", type=Path, default=None, help="also write report.md into this folder")
    real.set_defaults(func=_cmd_eval_real)

    # bench ----------------------------------------------------------------------------------------
    bench = commands.add_parser("bench", help="measure speed")
    bench_commands = bench.add_subparsers(dest="bench_command", metavar="WHAT", required=True)
    fusion = bench_commands.add_parser(
        "fusion",
        help="time per fused frame against a scikit-learn + filterpy reference on the same inputs",
    )
    fusion.add_argument(
        "--sensors",
        type=int,
        nargs="+",
        default=[1, 2, 4, 5, 8, 16],
        metavar="N",
        help="sensor counts (default: %(default)s)",
    )
    fusion.add_argument(
        "--bodies", type=int, nargs="+", default=[1, 3, 6], metavar="N", help="body counts (default: %(default)s)"
    )
    fusion.add_argument("--preset", default="A5", help="fusion preset to time (default: %(default)s)")
    fusion.add_argument("--frames", type=int, default=300, help="timed frames per case (default: %(default)s)")
    fusion.add_argument("--quick", action="store_true", help="fewer frames and a few cases, for CI")
    fusion.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    fusion.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    fusion.set_defaults(func=_cmd_bench_fusion)

    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        return int(args.func(args))
    except (ConfigError, DataError) as exc:
        print(f"skelfuse: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except SkelfuseError as exc:
        print(f"skelfuse: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print("skelfuse: interrupted", file=sys.stderr)
        return 130


def entrypoint() -> None:
    """Console-script entry point (``[project.scripts]``)."""
    sys.exit(main())
