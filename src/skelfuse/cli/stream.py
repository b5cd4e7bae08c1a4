"""``skelfuse stream osc|vmc|lsl``: the stream daemon, a subscriber of the fused stream that re-sends it live."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from skelfuse.cli.commands import COMMAND_HELP
from skelfuse.cli.common import (
    EXISTING_FILE,
    EXIT_OK,
    INDEX,
    PORT,
    add_json_option,
    add_run_limits,
    add_zenoh_arguments,
    print_json,
    rig_config,
    run_limits,
    zenoh_conf,
)
from skelfuse.config import RigConfig
from skelfuse.schema.errors import ConfigError
from skelfuse.service.lifecycle import Lifecycle
from skelfuse.stream.daemon import FrameSender, run_stream
from skelfuse.stream.lsl import LslOutlet
from skelfuse.stream.osc import OscSender
from skelfuse.stream.vmc import VmcSender
from skelfuse.wire.keys import validate_name


def _osc(cfg: RigConfig, args: argparse.Namespace) -> FrameSender:
    s = cfg.stream
    try:
        return OscSender(args.host or s.host, args.port or s.osc_port, prefix=s.osc_prefix, units=s.osc_units)
    except OSError as exc:  # the host name does not resolve
        raise ConfigError(f"OSC receiver {args.host or s.host}:{args.port or s.osc_port}: {exc}") from None


def _lsl(cfg: RigConfig, args: argparse.Namespace) -> FrameSender:
    if args.host is not None or args.port is not None:
        raise ConfigError("--host/--port are for osc; an LSL stream is found by name on the network")
    s = cfg.stream
    return LslOutlet(
        name=s.lsl_name,
        source_id=f"skelfuse-{cfg.name}-fused",
        max_persons=s.lsl_max_persons,
        rate_hz=cfg.sync.fps,
        rig=cfg.name,
    )


def _vmc(cfg: RigConfig, args: argparse.Namespace) -> FrameSender:
    s = cfg.stream
    host, port = args.host or s.host, args.port or s.vmc_port
    try:
        return VmcSender(host, port, person=args.person)
    except OSError as exc:  # the host name does not resolve
        raise ConfigError(f"VMC receiver {host}:{port}: {exc}") from None


PROTOCOLS: dict[str, Callable[[RigConfig, argparse.Namespace], FrameSender]] = {
    "osc": _osc,
    "lsl": _lsl,
    "vmc": _vmc,
}
"""Protocols of ``skelfuse stream``: a factory of the sender per protocol."""


def _cmd_stream(args: argparse.Namespace) -> int:
    cfg = rig_config(args)
    node = args.node or f"stream-{args.protocol}"
    try:
        validate_name(node, "node")
    except ValueError as exc:
        raise ConfigError(f"--node: {exc}") from None
    if args.port is not None and not 1 <= args.port <= 65535:
        raise ConfigError(f"--port must be in 1..65535, got {args.port}")
    limits = run_limits(args)
    conf = zenoh_conf(args, cfg)
    sender = PROTOCOLS[args.protocol](cfg, args)
    report = run_stream(cfg, conf, sender, node=node, limits=limits, lifecycle=Lifecycle(node))
    summary = {
        "protocol": args.protocol,
        "frames_in": report.frames_in,
        "frames_out": report.frames_out,
        "dropped": report.dropped,
        "rejects": dict(report.rejects),
        "send_failures": report.send_failures,
        "sender": vars(sender.stats),
    }
    if args.json:
        print_json(summary)
    else:
        print(
            f"Streamed {report.frames_out} fused frames as {args.protocol} ({report.dropped} dropped, "
            f"{sum(report.rejects.values())} rejected)",
            file=sys.stderr,
        )
    return EXIT_OK


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``stream``."""
    stream = commands.add_parser(
        "stream",
        help=COMMAND_HELP["stream"],
        description="Subscribe to skelfuse/<rig>/fused/skeletons and re-send every fused frame: osc = one OSC "
        "bundle per frame to [stream] host:osc_port (address scheme in docs/streaming.md); vmc = one VMC bundle per "
        "frame (one person's root and "
        "humanoid bone local rotations, docs/animation.md) to [stream] host:vmc_port; lsl = an LSL stream "
        "of type Mocap named [stream] lsl_name (needs pylsl). Runs on any PC of the rig; a receiver that is gone "
        "never blocks fusion (UDP, a bounded queue that drops the oldest frame). SIGINT/SIGTERM: send what is "
        "queued (at most [stream] drain_timeout_s) and stop.",
    )
    stream.add_argument("protocol", choices=sorted(PROTOCOLS), help="what to send")
    stream.add_argument("--config", type=EXISTING_FILE, required=True, metavar="RIG.toml", help="the rig config")
    stream.add_argument("--host", default=None, help="osc, vmc: the receiver's host (default: [stream] host)")
    stream.add_argument(
        "--port",
        type=PORT,
        default=None,
        help="osc, vmc: the receiver's UDP port (default: [stream] osc_port or vmc_port)",
    )
    stream.add_argument(
        "--person",
        type=INDEX,
        default=None,
        metavar="TRACK_ID",
        help="vmc: the track id to drive the avatar with (default: the lowest track id in each frame)",
    )
    stream.add_argument(
        "--node", default=None, metavar="NAME", help="node name for the liveliness key (default: stream-<protocol>)"
    )
    add_json_option(stream, "a summary at exit")
    add_run_limits(stream, "sending N fused frames")
    add_zenoh_arguments(stream)
    stream.set_defaults(func=_cmd_stream)
