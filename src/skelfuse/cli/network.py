"""Several PCs: ``skelfuse router`` (the rig's zenoh router) and ``skelfuse certs`` (its CA and certificates)."""

from __future__ import annotations

import argparse
import json
import logging
import socket
from pathlib import Path
from typing import Any

from skelfuse.cli.commands import COMMAND_HELP
from skelfuse.cli.common import (
    COUNT,
    EXIT_OK,
    add_output_option,
    add_run_limits,
    add_zenoh_arguments,
    print_json,
    rig_config,
    run_limits,
    zenoh_conf,
)
from skelfuse.config import RigConfig
from skelfuse.config.access import ROUTER, access_control, common_name, rig_identities
from skelfuse.service.certs import make_rig_certificates
from skelfuse.service.lifecycle import Lifecycle
from skelfuse.service.router import run_router

log = logging.getLogger("skelfuse.cli")


DEFAULT_ROUTER_LISTEN = ("tcp/[::]:7447",)
"""zenoh's own default for a router, named where the router compares its endpoints."""


def router_config(args: argparse.Namespace, cfg: RigConfig) -> Any:
    """The router's session config: the rig's [zenoh] and the flags, in router mode whatever [zenoh] mode
    says (the rig's clients share the file), so its access control applies. The shared file's connect
    endpoints name this router for its clients: the router leaves out those that are its own."""
    args.zenoh_mode = "router"
    connect = args.zenoh_connect if args.zenoh_connect is not None else list(cfg.zenoh.connect)
    listen = args.zenoh_listen or list(cfg.zenoh.listen) or list(DEFAULT_ROUTER_LISTEN)
    own = [endpoint for endpoint in connect if is_own_endpoint(endpoint, listen)]
    if own:
        log.info("router: not connecting to %s: this router listens there (the rig's clients connect)", own)
        args.zenoh_connect = [endpoint for endpoint in connect if endpoint not in own]
    return zenoh_conf(args, cfg, identity=ROUTER)


def _host_port(endpoint: str) -> tuple[str, int] | None:
    """``tcp/10.0.0.2:7447#iface=eth0`` -> ("10.0.0.2", 7447); None for what has no host and port."""
    _, _, address = endpoint.partition("/")
    address = address.split("#")[0].split("?")[0]
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        return None
    return host.strip("[]"), int(port)


def is_own_endpoint(endpoint: str, listen: list[str]) -> bool:
    """True when ``endpoint`` reaches one of the ``listen`` endpoints of this host: same protocol and port,
    and an address of this machine (one a socket can bind to: loopback, any interface's address, a name
    that resolves to one)."""
    target = _host_port(endpoint)
    if target is None:
        return False
    protocol = endpoint.partition("/")[0]
    host, port = target
    ports = {hp[1] for e in listen if e.partition("/")[0] == protocol and (hp := _host_port(e)) is not None}
    if port not in ports:
        return False
    try:
        addresses = {str(info[4][0]) for info in socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)}
    except OSError:
        return False  # a name this host cannot resolve is not this host
    for address in addresses:
        family = socket.AF_INET6 if ":" in address else socket.AF_INET
        with socket.socket(family, socket.SOCK_STREAM) as probe:
            try:
                probe.bind((address, 0))
            except OSError:
                continue
            return True
    return False


def _cmd_router(args: argparse.Namespace) -> int:
    cfg = rig_config(args)
    if args.print_access_control:
        print(json.dumps(access_control(cfg), indent=2))
        return EXIT_OK
    conf = router_config(args, cfg)
    return run_router(
        conf,
        lifecycle=Lifecycle("router"),
        limits=run_limits(args),
        rig=cfg.name,
        rig_common_names=[common_name(cfg.name, identity) for identity in rig_identities(cfg)],
        status_period_s=cfg.node.status_period_s,
    )


def _cmd_certs(args: argparse.Namespace) -> int:
    cfg = rig_config(args)
    identities = rig_identities(cfg, tuple(args.app))
    if args.only:
        identities = [i for i in identities if i in set(args.only)] + [i for i in args.only if i not in identities]
    print(f"skelfuse certs: rig {cfg.name}: CA and {len(identities)} certificates in {args.output}", flush=True)
    issued = make_rig_certificates(Path(args.output), cfg.name, identities, sans=tuple(args.san), days=args.days)
    rows = [
        {
            "identity": c.identity,
            "common_name": c.common_name,
            "certificate": str(c.certificate),
            "key": str(c.private_key),
        }
        for c in issued
    ]
    if args.json:
        print_json({"directory": str(args.output), "certificates": rows})
    else:
        for row in rows:
            print(f"  {row['identity']:<24} CN {row['common_name']:<40} {row['certificate']}")
        print(f"  copy ca.pem and each PC's own <identity>.pem/.key to it; keep ca.key off the rig ({args.output})")
    return EXIT_OK


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``router`` and ``certs``."""
    router = commands.add_parser(
        "router",
        help=COMMAND_HELP["router"],
        description="Run zenoh's router from the Python package, with the rig's [zenoh] settings: listen "
        "endpoints ([zenoh] listen or --zenoh-listen; default tcp/[::]:7447), mutual TLS ([zenoh.tls], "
        "certificate 'router') and the access control generated from the rig ([zenoh] access_control = true). "
        "It counts what zenoh refuses (certificates of another CA, messages the access control denies: only "
        "zenoh's log reports them, which the router reads) and publishes the counts in its status on "
        "skelfuse/<rig>/status/router every [node] status_period_s (skelfuse status prints them). "
        "See docs/multi-pc.md.",
    )
    router.add_argument("--config", required=True, type=Path, metavar="RIG.toml", help="the rig config")
    router.add_argument(
        "--print-access-control",
        action="store_true",
        help="print the access control generated from the rig (zenoh's JSON) and exit",
    )
    add_run_limits(router, None)
    add_zenoh_arguments(router)
    router.set_defaults(func=_cmd_router)

    certs = commands.add_parser(
        "certs",
        help=COMMAND_HELP["certs"],
        description="Make (or reuse) the rig's CA in OUTPUT and issue one certificate per identity: router, "
        "fusion, capture-<host> for every capture PC of the rig ([[sensors]] host, default the sensor id) and "
        "app-<name> per --app. Point [zenoh.tls] directory at OUTPUT. See docs/multi-pc.md.",
    )
    certs.add_argument("--config", required=True, type=Path, metavar="RIG.toml", help="the rig config")
    add_output_option(certs, required=True, type=Path, metavar="DIR", help="directory of the certificates")
    certs.add_argument("--app", action="append", default=[], metavar="NAME", help="an app certificate (repeatable)")
    certs.add_argument(
        "--only", action="append", default=[], metavar="IDENTITY", help="issue only these identities (repeatable)"
    )
    certs.add_argument(
        "--san",
        action="append",
        default=[],
        metavar="NAME_OR_IP",
        help="extra DNS name or IP address in every certificate (for [zenoh.tls] verify_name; repeatable)",
    )
    certs.add_argument("--days", type=COUNT, default=825, help="validity in days (default: %(default)s)")
    certs.add_argument("--json", action="store_true", help="a JSON summary on stdout")
    certs.set_defaults(func=_cmd_certs)
