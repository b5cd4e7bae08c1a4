"""``skelfuse sim check``: the simulator's realism, statistic by statistic, beside the real figures."""

from __future__ import annotations

import argparse
from pathlib import Path

from skelfuse.cli.commands import COMMAND_HELP
from skelfuse.cli.common import COUNT, EXIT_OK, POSITIVE, SEED, print_json


def _default_data_dir() -> Path:
    """``../shared/data`` beside the working directory's project, where the team's real recordings live."""
    return Path.cwd().parent / "shared" / "data"


def _cmd_sim_check(args: argparse.Namespace) -> int:
    from skelfuse.eval import realism  # each command imports what it runs (start-up)
    from skelfuse.sim.observe import load_profile

    profile = load_profile(args.profile)
    data_dir = None
    if not args.no_real:
        data_dir = args.data
        if args.data is None:
            default = _default_data_dir()
            data_dir = default if (default.joinpath(*realism.RECORDED_TAKE)).is_dir() else None
    result = realism.run_sim_check(
        profile,
        profile_name=str(args.profile) if args.profile else "azure_kinect (packaged)",
        seeds=tuple(range(args.seed, args.seed + args.seeds)),
        duration_s=args.duration,
        data_dir=data_dir,
        progress=not args.quiet,
    )
    if args.json:
        print_json(result.to_dict(), args)
    else:
        print(realism.format_markdown(result), end="")
    return EXIT_OK


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``sim`` with its sub-commands."""
    sim = commands.add_parser("sim", help=COMMAND_HELP["sim"])
    sim_commands = sim.add_subparsers(dest="sim_command", metavar="WHAT", required=True)
    check = sim_commands.add_parser(
        "check",
        help="measure simulated takes with the statistics measured on real recordings, beside the real ranges",
        description="Simulate two-view squat takes set up like the real recordings (sensors 45° apart, subject "
        "2.25 m away) and a three-view one, measure cross-view disagreement, constant offsets, AR(1) rho and "
        "white jitter, body-model scale, confidence rates, LOW episodes and jumps per joint group, and print "
        "them beside the real ranges (DESIGN.md 'Real noise'; the real take under --data is measured too). "
        "Markdown on stdout (the table in docs/simulator.md), or --json.",
    )
    check.add_argument("--profile", type=Path, default=None, help="simulator profile TOML (default: the packaged one)")
    check.add_argument("--seeds", type=COUNT, default=3, help="two-view takes, one per seed (default: %(default)s)")
    check.add_argument("--seed", type=SEED, default=0, help="first seed (default: %(default)s)")
    check.add_argument(
        "--duration", type=POSITIVE, default=20.0, metavar="SECONDS", help="length of each take (default: %(default)s)"
    )
    check.add_argument(
        "--data",
        type=Path,
        default=None,
        help="shared data folder holding azure-kinect-andyj1/ (default: ../shared/data when it is there)",
    )
    check.add_argument("--no-real", action="store_true", help="do not measure the real take")
    check.add_argument("--json", action="store_true", help="print the table as JSON")
    check.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    check.set_defaults(func=_cmd_sim_check)
