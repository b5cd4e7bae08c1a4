"""What every command shares: exit codes, JSON output, run limits, the rig config and zenoh options."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from skelfuse.config import RigConfig, load_rig_config, zenoh_config, zenoh_flags
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


def zenoh_conf(args: argparse.Namespace, cfg: RigConfig | None) -> Any:
    if cfg is None:  # commands that may run without a rig config: zenoh defaults + flags
        cfg = RigConfig(name="skelfuse", sensors=(), source="<command line>")
    return zenoh_config(cfg, **zenoh_flags(args))


def run_limits(args: argparse.Namespace) -> RunLimits:
    try:
        return RunLimits(duration_s=args.duration, max_frames=getattr(args, "max_frames", None))
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
