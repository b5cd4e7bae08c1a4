"""``skelfuse demo``: a simulated four-sensor rig fused live (or offline), with its summary."""

from __future__ import annotations

import argparse
import sys

from skelfuse.apps import demo
from skelfuse.apps.demo import CONVERGE_S, DEMO_TAKE_S
from skelfuse.cli.commands import COMMAND_HELP
from skelfuse.cli.common import (
    EXIT_OK,
    OUTPUT_FILE,
    PORT,
    POSITIVE,
    Number,
    add_json_option,
    add_preset_option,
    add_seed_option,
    print_json,
)
from skelfuse.config import DEFAULT_PRESET


def _cmd_demo(args: argparse.Namespace) -> int:
    summary: demo.DemoSummary | None
    if args.offline:
        summary = demo.run_demo_offline(
            duration_s=args.duration,
            gesture=args.gesture,
            preset_name=args.preset,
            seed=args.seed,
            rrd_path=args.rrd,
            spawn=False if args.rrd is not None else None,
            realtime=args.realtime,
            progress=not args.json,
            take_duration_s=args.take,
        )
    else:
        summary = demo.run_demo(
            duration_s=args.duration,
            gesture=args.gesture,
            preset_name=args.preset,
            seed=args.seed,
            rrd_path=args.rrd,
            spawn=False if args.rrd is not None or args.serve or args.web else None,
            serve=args.serve or args.web,
            web_port=args.web_port if args.web else None,
            grpc_port=args.grpc_port,
            progress=not args.json,
            take_duration_s=args.take,
        )
    if summary is None:
        print("skelfuse demo: stopped before the first fused frame; nothing to summarize", file=sys.stderr)
        return EXIT_OK
    if args.json:
        print_json(summary.to_dict(), args)
    else:
        print(demo.format_summary(summary))
    return EXIT_OK


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``demo``."""
    # demo -----------------------------------------------------------------------------------------
    demo = commands.add_parser(
        "demo",
        help=COMMAND_HELP["demo"],
        description="Start a simulated rig of four virtual Azure Kinects: four capture workers (subprocesses) "
        "publish over zenoh on loopback (peer mode, no router, no multicast), the fusion node fuses them live "
        "(it prints its rig name, its endpoint and how `skelfuse status`, `skelfuse stream` and other apps attach) "
        "and draws raw and fused skeletons in the Rerun viewer. Without a display (or with --rrd) the view is "
        "saved to a .rrd file. Runs for --duration seconds of fused output or until Ctrl-C, then prints "
        "frames fused, accuracy against the simulator's ground truth and latency p50/p99.",
    )
    demo.add_argument(
        "--duration",
        type=POSITIVE,
        default=20.0,
        metavar="SECONDS",
        help="how long to run, seconds of fused output (default: %(default)s); the take loops through it",
    )
    demo.add_argument(
        "--take-duration",
        "--take",
        dest="take",
        type=Number(float, ge=2 * CONVERGE_S, le=600),
        default=DEMO_TAKE_S,
        metavar="SECONDS",
        help="length of the simulated take, played in a loop (as capture's --take-duration); the accuracy is "
        "scored over take seconds "
        f"{CONVERGE_S}-SECONDS of each whole pass, so any --duration of at least one pass gives the "
        "same figure (default: %(default)s)",
    )
    demo.add_argument(
        "--gesture",
        default="walking",
        choices=["hands_up_down", "jump", "squat", "lunge", "walking", "random"],
        help="what the simulated person does (default: %(default)s)",
    )
    add_preset_option(demo, default=DEFAULT_PRESET)
    add_seed_option(demo, default=0)
    _add_view_options(demo)
    add_json_option(demo, "the summary")
    demo.set_defaults(func=_cmd_demo)


def _add_view_options(demo: argparse.ArgumentParser) -> None:
    """Where the view goes (a viewer spawned, a .rrd, served to viewers and browsers) and the offline mode."""
    demo.add_argument(
        "--rrd",
        type=OUTPUT_FILE,
        default=None,
        metavar="FILE",
        help="save the recording to FILE instead of spawning a viewer",
    )
    demo.add_argument(
        "--serve",
        action="store_true",
        help="serve the view to Rerun viewers (gRPC on 127.0.0.1, --grpc-port) instead of spawning one",
    )
    demo.add_argument(
        "--web",
        action="store_true",
        help="serve the view and Rerun's web viewer (--web-port) and print the URL to open in a browser",
    )
    demo.add_argument(
        "--grpc-port", type=PORT, default=None, metavar="PORT", help="with --serve/--web: gRPC port (default: 9876)"
    )
    demo.add_argument(
        "--web-port", type=PORT, default=9090, metavar="PORT", help="with --web: the web viewer's port (default: 9090)"
    )
    demo.add_argument(
        "--offline",
        action="store_true",
        help="the old single-process demo: simulate and fuse in one loop, without zenoh or workers",
    )
    demo.add_argument(
        "--realtime",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="with --offline: pace frames at 30 Hz (default: only when a live viewer is open)",
    )
