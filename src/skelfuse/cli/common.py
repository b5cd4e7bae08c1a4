"""What every command shares: exit codes, JSON output, run limits, the rig config and zenoh options."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from skelfuse.cli.exits import (  # noqa: F401 - the commands read them here, beside the other shared parts
    EXIT_ATTENTION,
    EXIT_ERROR,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_STOP_TIMEOUT,
    EXIT_USAGE,
)
from skelfuse.config import ZENOH_MODES, RigConfig, load_rig_config, zenoh_config
from skelfuse.config.checks import did_you_mean
from skelfuse.fusion.presets import ALL_PRESETS
from skelfuse.schema.errors import ConfigError
from skelfuse.service.lifecycle import RunLimits

# -- argument types: every value is checked where it enters, argparse turns a failure into a usage error -----


class Number:
    """An argparse ``type`` for a number in a range: ``Number(float, gt=0)``, ``Number(int, ge=1, le=65535)``.

    Rejects what is not a finite number of ``kind`` or lies outside the range with a message that says what
    was expected; tests read ``kind`` and the bounds to feed each option the values it must refuse.
    """

    def __init__(
        self, kind: type, *, gt: float | None = None, ge: float | None = None, le: float | None = None
    ) -> None:
        self.kind, self.gt, self.ge, self.le = kind, gt, ge, le
        self.__name__ = kind.__name__  # argparse names the type in "invalid <name> value" messages

    def describe(self) -> str:
        what = "an integer" if self.kind is int else "a number"
        bounds = [f"> {self.gt:g}" if self.gt is not None else "", f">= {self.ge:g}" if self.ge is not None else ""]
        bounds.append(f"<= {self.le:g}" if self.le is not None else "")
        return " ".join([what, " and ".join(b for b in bounds if b)]).strip()

    def __call__(self, text: str) -> Any:
        try:
            value = self.kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {self.describe()}, got {text!r}") from None
        if (
            not math.isfinite(value)
            or (self.gt is not None and not value > self.gt)
            or (self.ge is not None and not value >= self.ge)
            or (self.le is not None and not value <= self.le)
        ):
            raise argparse.ArgumentTypeError(f"expected {self.describe()}, got {text!r}")
        return value

    def __repr__(self) -> str:
        return f"Number({self.describe()})"


POSITIVE = Number(float, gt=0)
"""Seconds, speeds, sizes: a finite number > 0."""
NON_NEGATIVE = Number(float, ge=0)
COUNT = Number(int, ge=1)
"""Frames, sensors, workers: an integer >= 1."""
INDEX = Number(int, ge=0)
SEED = Number(int)
"""Any integer."""
PORT = Number(int, ge=1, le=65535)


class PathArg:
    """An argparse ``type`` for a path that must exist (``file`` / ``dir``) or whose folder must (``output``)."""

    def __init__(self, must: str) -> None:
        if must not in ("file", "dir", "output", "any"):
            raise ValueError(f"PathArg: unknown requirement {must!r}")
        self.must = must
        self.__name__ = "path"

    def __call__(self, text: str) -> Path:
        path = Path(text)
        if self.must == "file" and not path.is_file():
            problem = "is a folder, not a file" if path.is_dir() else "no such file"
            raise argparse.ArgumentTypeError(f"{problem}: {text}")
        if self.must == "dir" and not path.is_dir():
            problem = "is a file, not a folder" if path.exists() else "no such folder"
            raise argparse.ArgumentTypeError(f"{problem}: {text}")
        if self.must == "output":
            parent = path.parent if str(path.parent) else Path(".")
            if not parent.is_dir():
                raise argparse.ArgumentTypeError(f"the folder {parent} of {text} does not exist; create it first")
            if path.is_dir():
                raise argparse.ArgumentTypeError(f"{text} is a folder; give a file name")
        return path

    def __repr__(self) -> str:
        return f"PathArg({self.must})"


OFFLINE_SMOOTHERS = ("rts", "none")
"""``--smoother`` choices: the names of :data:`skelfuse.fusion.smoother.SMOOTHERS` (tests/unit/test_smoother.py checks
they agree), here so that parsing imports no fusion code."""

EXISTING_FILE = PathArg("file")
EXISTING_DIR = PathArg("dir")
OUTPUT_FILE = PathArg("output")
"""A file to write: its folder must exist (it is never created behind the user's back)."""


def add_output_option(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    *,
    metavar: str,
    help: str,
    type: Any = OUTPUT_FILE,
    default: Any = None,
    required: bool = False,
    dest: str = "output",
    aliases: tuple[str, ...] = (),
) -> None:
    """``-o/--output`` (and any older spelling in ``aliases``): the one spelling of "where this command
    writes", as in git, ffmpeg and Blender's command line."""
    parser.add_argument(
        "-o", "--output", *aliases, dest=dest, type=type, default=default, required=required, metavar=metavar, help=help
    )


def add_json_option(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup, what: str = "the results", note: str = ""
) -> None:
    """``--json``: ``what`` as JSON on stdout instead of text (progress and logs stay on stderr)."""
    parser.add_argument(
        "--json", action="store_true", help=f"print {what} as JSON on stdout" + (f" ({note})" if note else "")
    )


def add_seed_option(parser: argparse.ArgumentParser, *, default: int = 0, what: str = "simulation seed") -> None:
    """``--seed``: the seed everything random in a simulated run derives from."""
    parser.add_argument("--seed", type=SEED, default=default, help=f"{what} (default: %(default)s)")


def add_preset_option(
    parser: argparse.ArgumentParser,
    *,
    default: str | None,
    what: str = "fusion preset",
    default_text: str = "%(default)s",
) -> None:
    """``--preset``: one of the fusion presets, checked when parsed (one spelling, one check for every command)."""
    parser.add_argument(
        "--preset",
        type=preset_name,
        default=default,
        help=f"{what}: skelfuse or the paper's A1..A5 (default: {default_text})",
    )


def preset_name(text: str) -> str:
    """argparse ``type`` of ``--preset``: one of the fusion presets."""
    if text not in ALL_PRESETS:
        raise argparse.ArgumentTypeError(
            f"unknown fusion preset {text!r}{did_you_mean(text, ALL_PRESETS)}; expected one of {', '.join(ALL_PRESETS)}"
        )
    return text


def print_json(payload: dict[str, Any], args: argparse.Namespace | None = None) -> None:
    """``payload`` as JSON on stdout; with the command's ``args``, stamped with where it came from
    (``"stamp"``: command line, revision, machine, load; cli/stamp.py), for results that docs quote."""
    stamp = getattr(args, "stamp", None)
    if stamp is not None:
        payload = {**payload, "stamp": stamp.finished()}
    json.dump(payload, sys.stdout, indent=2, allow_nan=False, default=_json_default)
    sys.stdout.write("\n")


def _json_default(value: Any) -> Any:
    """numpy scalars and arrays, Paths: the types results may carry."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot serialize {type(value).__name__} to JSON")


def add_run_limits(parser: argparse.ArgumentParser, what: str | None) -> None:
    """``--duration``, and ``--max-frames`` (``--max-messages``) counting ``what``; None: a command that
    counts nothing (the router) gets ``--duration`` only."""
    parser.add_argument(
        "--duration",
        type=POSITIVE,
        default=None,
        metavar="SECONDS",
        help="stop cleanly after this many seconds of work; a zenoh session that cannot open is given up after as "
        "long (default: run until SIGINT/SIGTERM)",
    )
    if what is None:
        return
    flags = ("--max-messages", "--max-frames") if what.endswith("messages") else ("--max-frames",)
    parser.add_argument(
        *flags,
        dest="max_frames",
        type=COUNT,
        default=None,
        metavar="N",
        help=f"stop cleanly after {what} (default: no limit)",
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
