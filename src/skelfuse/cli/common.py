"""What every command shares: exit codes, JSON output, run limits, the rig config and zenoh options."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from skelfuse.config import ZENOH_MODES, RigConfig, load_rig_config, zenoh_config
from skelfuse.schema.errors import ConfigError
from skelfuse.service.lifecycle import RunLimits

EXIT_OK = 0
EXIT_ERROR = 1
EXIT_USAGE = 2
EXIT_ATTENTION = 3  # the result needs a person's attention: a "bad" calibration verdict, a moved sensor


def print_json(payload: dict[str, Any]) -> None:
    json.dump(payload, sys.stdout, indent=2, allow_nan=False, default=_json_default)
    sys.stdout.write("\n")


def _json_default(value: Any) -> Any:
    """numpy scalars and arrays, Paths: the types results may carry."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot serialize {type(value).__name__} to JSON")


def add_run_limits(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="SECONDS",
        help="stop cleanly after this many seconds (default: run until SIGINT/SIGTERM)",
    )
    parser.add_argument(
        "--max-frames", type=int, default=None, metavar="N", help=f"stop cleanly after {what} (default: no limit)"
    )


def rig_config(args: argparse.Namespace) -> RigConfig:
    return load_rig_config(args.config)


def zenoh_conf(args: argparse.Namespace, cfg: RigConfig | None, *, identity: str | None = None) -> Any:
    """The session config: the rig's ``[zenoh]``, then the flags; ``identity`` (the command's own: ``fusion``,
    ``capture-<host>``, ``router``) picks the certificate of ``[zenoh.tls]`` unless ``--zenoh-identity`` does."""
    if cfg is None:  # commands that may run without a rig config: zenoh defaults + flags
        cfg = RigConfig(name="skelfuse", sensors=(), source="<command line>")
    flags = zenoh_flags(args)
    flags["identity"] = getattr(args, "zenoh_identity", None) or identity
    return zenoh_config(cfg, **flags)


def run_limits(args: argparse.Namespace) -> RunLimits:
    try:
        return RunLimits(duration_s=args.duration, max_frames=getattr(args, "max_frames", None))
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the zenoh flags every long-running command shares (read back by :func:`zenoh_flags`)."""
    group = parser.add_argument_group("zenoh (override the config file's [zenoh])")
    group.add_argument("--zenoh-mode", choices=ZENOH_MODES, default=None, help="session mode")
    group.add_argument(
        "--zenoh-connect",
        metavar="ENDPOINT",
        action="append",
        default=None,
        help="endpoint to connect to (repeatable), e.g. tcp/10.0.0.2:7447",
    )
    group.add_argument(
        "--zenoh-listen", metavar="ENDPOINT", action="append", default=None, help="endpoint to listen on (repeatable)"
    )
    group.add_argument(
        "--no-multicast-scouting",
        action="store_true",
        default=False,
        help="disable multicast scouting (recommended with explicit endpoints)",
    )
    group.add_argument(
        "--zenoh-identity",
        metavar="NAME",
        default=None,
        help="whose certificate of [zenoh.tls] directory to use: fusion, router, capture-HOST, app-NAME "
        "(default: the command's own role; apps need one)",
    )
    group.add_argument(
        "--zenoh-cfg",
        metavar="KEY:VALUE",
        action="append",
        default=[],
        help="raw zenoh config change, VALUE in JSON5, e.g. 'transport/unicast/max_links:2' (applied last)",
    )


def zenoh_flags(args: argparse.Namespace) -> dict[str, Any]:
    """Keyword arguments of :func:`zenoh_config` from flags added by :func:`add_zenoh_arguments`."""
    return {
        "overrides": tuple(args.zenoh_cfg or ()),
        "mode": args.zenoh_mode,
        "connect": args.zenoh_connect,
        "listen": args.zenoh_listen,
        "multicast_scouting": False if args.no_multicast_scouting else None,
    }
