"""The ``skelfuse`` command line: parses arguments, calls the library, turns typed errors into exit codes.

Each command group builds its own parser next to the code that runs it (``cli/service.py``,
``cli/calibrate.py``, ...); this module assembles them and maps errors to exit codes
(``docs/service.md``, "Exit codes").
"""

from __future__ import annotations

import argparse
import contextlib
import faulthandler
import importlib
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Sequence

from skelfuse.cli.commands import COMMANDS
from skelfuse.cli.exits import EXIT_ERROR, EXIT_OK, EXIT_USAGE
from skelfuse.cli.stamp import RunStamp
from skelfuse.schema.errors import ConfigError, DataError, SkelfuseError
from skelfuse.service.lifecycle import configure_logging
from skelfuse.service.zenoh_io import sessions_left_behind
from skelfuse.version import __version__

__all__ = ["EXIT_ERROR", "EXIT_OK", "EXIT_USAGE", "build_parser", "entrypoint", "main"]

log = logging.getLogger("skelfuse")


def build_parser(only: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The whole command line; with ``only``, just those commands' modules are imported and built, the others
    stand as their one-line help (what ``skelfuse --help`` shows), so that each command starts at once."""
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
    wanted = set(COMMANDS) if only is None else set(only)
    for module in dict.fromkeys(module for name, (module, _) in COMMANDS.items() if name in wanted):
        importlib.import_module(module).add_parser(commands)
    for name, (_, help_text) in COMMANDS.items():
        if name not in commands.choices:
            commands.add_parser(name, help=help_text, add_help=False)  # stands for the command in the listing
    return _in_listed_order(parser, commands)


def _in_listed_order(
    parser: argparse.ArgumentParser,
    commands: argparse._SubParsersAction,
) -> argparse.ArgumentParser:
    """Commands listed in :data:`COMMANDS`' order whichever were built first."""
    order = list(COMMANDS)
    commands._choices_actions.sort(key=lambda action: order.index(action.dest))
    return parser


def _command_in(argv: Sequence[str]) -> str | None:
    """The command named in ``argv`` (after the global options), if any."""
    scout = argparse.ArgumentParser(add_help=False)
    scout.add_argument("-v", "--verbose", action="store_true")
    scout.add_argument("--log-format")
    scout.add_argument("--version", action="store_true")
    scout.add_argument("-h", "--help", action="store_true")
    scout.add_argument("command", nargs="?")
    known, _ = scout.parse_known_args(argv)
    return known.command if known.command in COMMANDS else None


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the process exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    command = _command_in(argv)
    parser = build_parser([command] if command is not None else [])
    args = parser.parse_args(argv)
    # what --json results record of their making (only there: asking git costs start-up time)
    args.stamp = RunStamp.begin(argv) if getattr(args, "json", False) else None
    configure_logging(verbose=args.verbose, fmt=args.log_format)
    try:
        return int(args.func(args))
    except (ConfigError, DataError) as exc:
        print(f"skelfuse: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except SkelfuseError as exc:
        print(f"skelfuse: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except OSError as exc:  # the system refused an operation, typically a file written (full disk, permissions)
        logging.getLogger("skelfuse.cli").debug("the command failed", exc_info=True)
        where = f": {exc.filename}" if exc.filename else ""
        print(
            f"skelfuse: error: {exc.strerror or exc}{where} (the operating system refused an operation; for an "
            "output file: free disk space, check its folder's permissions, or write somewhere else; -v logs details)",
            file=sys.stderr,
        )
        return EXIT_ERROR
    except KeyboardInterrupt:
        print("skelfuse: interrupted", file=sys.stderr)
        return 130


EXIT_GRACE_S = 5.0
"""Longest the interpreter's exit handlers may run once a command returned (the Rerun SDK's at-exit flush
waits for a viewer that may never answer); past it the process ends with the command's exit status."""


def _bound_exit(code: int, grace_s: float = EXIT_GRACE_S) -> None:
    """End the process with ``code`` if the exit handlers still run ``grace_s`` seconds from now."""

    def end() -> None:
        time.sleep(grace_s)
        with contextlib.suppress(Exception):
            sys.stderr.write(f"skelfuse: exit handlers still running after {grace_s:.0f} s (a viewer?); exiting\n")
            sys.stderr.flush()
            sys.stdout.flush()
        os._exit(code)

    threading.Thread(target=end, name="skelfuse-exit-bound", daemon=True).start()


def entrypoint() -> None:
    """Console-script entry point (``[project.scripts]``, ``python -m skelfuse``)."""
    if hasattr(signal, "SIGUSR1"):
        with contextlib.suppress(OSError, ValueError, AttributeError):  # no real stderr: skip it
            faulthandler.register(signal.SIGUSR1, all_threads=True)  # `kill -USR1 PID` dumps a stuck node's stacks
    code = main()
    left_behind = sessions_left_behind()
    if left_behind:  # a zenoh close still running would abort the interpreter's exit (service/zenoh_io.py)
        with contextlib.suppress(Exception):
            logging.shutdown()
            sys.stdout.flush()
            sys.stderr.flush()
        os._exit(code)
    _bound_exit(code)
    sys.exit(code)
