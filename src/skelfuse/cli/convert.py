"""``skelfuse convert IN... -o OUT.mcap``: any recorded skeleton format to one time-matched skelfuse MCAP."""

from __future__ import annotations

import argparse
import sys

from skelfuse.cli.commands import COMMAND_HELP
from skelfuse.cli.common import EXIT_OK, OUTPUT_FILE, add_json_option, add_output_option, print_json
from skelfuse.cli.inputs import INPUT_HELP, add_input_options, open_take
from skelfuse.recording.inputs import write_mcap
from skelfuse.schema.errors import ConfigError
from skelfuse.wire.keys import validate_name


def _cmd_convert(args: argparse.Namespace) -> int:
    if args.output.suffix.lower() != ".mcap":
        raise ConfigError(f"-o {args.output}: convert writes a skelfuse MCAP; name it OUT.mcap")
    try:
        validate_name(args.rig, "rig")
    except ValueError as exc:
        raise ConfigError(f"--rig: {exc}") from None
    take = open_take(args, args.inputs, quiet=args.json)
    if not args.json:
        print(f"writing {args.output} ...", file=sys.stderr)
    n = write_mcap(take, args.output, rig=args.rig)
    summary = {
        "output": str(args.output),
        "frames": n,
        "sensors": list(take.sensor_ids),
        "time_matching": take.clock,
        "time_offsets_us": take.offsets_us,
        "confidence_assumed": {k: v for k, v in take.confidence_assumed.items() if v is not None},
        "notes": take.notes,
    }
    if args.json:
        print_json(summary)
    else:
        print(f"Converted {len(take.sensor_ids)} sensor(s), {n} frames -> {args.output}", file=sys.stderr)
    return EXIT_OK


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``convert``."""
    convert = commands.add_parser(
        "convert",
        help=COMMAND_HELP["convert"],
        description="Read one or more recordings (offline_processor JSON, azure-kinect-mkv-extractor CSV, "
        "andyj1 CSV, long CSV, .mkv through the SDK, or MCAP), match their frames in time (device clock, "
        "estimated offsets, or index where files hold no timestamps: the output says which) and write every "
        "sensor frame to one MCAP that fuse, replay, calibrate and eval read. The metadata keeps the sources, "
        "the matching and the assumed confidence.",
    )
    convert.add_argument("inputs", nargs="+", metavar="[ID=]PATH", help=INPUT_HELP)
    add_output_option(convert, type=OUTPUT_FILE, required=True, metavar="OUT.mcap", help="the MCAP to write")
    convert.add_argument(
        "--rig", default="converted", metavar="NAME", help="rig name of the channel topics (default: %(default)s)"
    )
    add_input_options(convert, by=False)
    add_json_option(convert, "a summary")
    convert.set_defaults(func=_cmd_convert)
