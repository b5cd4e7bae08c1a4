"""``skelfuse devices``: the connected sensors, or what is missing to see them."""

from __future__ import annotations

import argparse

from skelfuse.cli.commands import COMMAND_HELP
from skelfuse.cli.common import EXIT_ERROR, EXIT_OK
from skelfuse.sources.devices import describe_environment, format_devices, list_devices
from skelfuse.sources.kinect import KinectUnavailable


def _cmd_devices(args: argparse.Namespace) -> int:
    try:
        devices = list_devices()
    except KinectUnavailable:
        print(describe_environment())
        return EXIT_ERROR
    print(format_devices(devices))
    return EXIT_OK


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``devices``."""
    # devices and calibration ------------------------------------------------------------------------
    devices = commands.add_parser(
        "devices",
        help=COMMAND_HELP["devices"],
        description="List connected sensors through pyk4a / libk4a. Where the SDK or the kinect extra is missing, "
        "says what is missing and how to install it.",
    )
    devices.set_defaults(func=_cmd_devices)
