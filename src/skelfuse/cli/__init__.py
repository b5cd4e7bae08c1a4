"""The ``skelfuse`` command line: parses arguments, calls the library, turns typed errors into exit codes.

Each command group builds its own parser next to the code that runs it (``cli/service.py``,
``cli/calibrate.py``, ...); this module assembles them and maps errors to exit codes
(``docs/service.md``, "Exit codes").
"""

from __future__ import annotations

import argparse
import contextlib
import faulthandler
import logging
import signal
import sys
from collections.abc import Sequence

from skelfuse import __version__
from skelfuse.cli import bench, calibrate, demo, devices, evaluate, network, service
from skelfuse.cli.common import EXIT_ERROR, EXIT_OK, EXIT_USAGE
from skelfuse.schema.errors import ConfigError, DataError, SkelfuseError
from skelfuse.service.lifecycle import configure_logging

__all__ = ["EXIT_ERROR", "EXIT_OK", "EXIT_USAGE", "build_parser", "entrypoint", "main"]

log = logging.getLogger("skelfuse")

#: Command groups in the order ``skelfuse --help`` lists them.
COMMAND_GROUPS = (demo, evaluate, bench, service, network, devices, calibrate)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="skelfuse",
        description="Fuse the skeletons of several Azure Kinect body trackers into one accurate, smooth skeleton.",
    )
    parser.add_argument("--version", action="version", version=f"skelfuse {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages on stderr")
    parser.add_argument(
        "--log-format",
        choices=["text", "json"],
        default="text",
        help="logs on stderr as text lines or as one JSON object per line (default: %(default)s)",
    )
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    for group in COMMAND_GROUPS:
        group.add_parser(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    configure_logging(verbose=args.verbose, fmt=args.log_format)
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
    """Console-script entry point (``[project.scripts]``, ``python -m skelfuse``)."""
    if hasattr(signal, "SIGUSR1"):
        with contextlib.suppress(OSError, ValueError, AttributeError):  # no real stderr: skip it
            faulthandler.register(signal.SIGUSR1, all_threads=True)  # `kill -USR1 PID` dumps a stuck node's stacks
    sys.exit(main())
