"""The router started from the shared rig config leaves out the connect endpoints that are its own."""

from __future__ import annotations

import argparse
import json
import socket
import tomllib

import pytest

from skelfuse.cli import build_parser
from skelfuse.cli.network import is_own_endpoint, router_config
from skelfuse.config import parse_rig_config


def _local_address() -> str | None:
    """A non-loopback address of this host (the one a UDP socket would leave from), if it has one."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))  # TEST-NET-1: nothing is sent, only the route is looked up
        except OSError:
            return None
        address = s.getsockname()[0]
    return None if address.startswith("127.") else address


@pytest.mark.parametrize(
    ("endpoint", "own"),
    [
        ("tcp/127.0.0.1:7447", True),
        ("tcp/localhost:7447", True),
        ("tcp/[::1]:7447", True),
        ("tcp/127.0.0.1:7448", False),  # another port: another process
        ("udp/127.0.0.1:7447", False),  # another protocol
        ("tcp/192.0.2.7:7447", False),  # TEST-NET-1: no host has it
        ("tcp/no-such-host.invalid:7447", False),
    ],
)
def test_own_endpoints(endpoint: str, own: bool) -> None:
    assert is_own_endpoint(endpoint, ["tcp/[::]:7447"]) is own


def test_an_interface_address_is_own() -> None:
    address = _local_address()
    if address is None:
        pytest.skip("this host has no non-loopback IPv4 address")
    assert is_own_endpoint(f"tcp/{address}:7447", ["tcp/0.0.0.0:7447"])


def test_the_router_does_not_dial_itself_from_the_shared_config() -> None:
    cfg = parse_rig_config(
        tomllib.loads(
            """
        [rig]
        name = "r"
        [zenoh]
        mode = "client"
        connect = ["tcp/127.0.0.1:7447", "tcp/192.0.2.7:7447"]
        listen = ["tcp/0.0.0.0:7447"]
        [[sensors]]
        id = "a"
        source = "sim"
        """
        )
    )
    args = build_parser().parse_args(["router", "--config", "rig.toml"])
    conf = json.loads(str(router_config(args, cfg)))
    assert conf["connect"]["endpoints"] == ["tcp/192.0.2.7:7447"]  # the other router stays


def test_router_help_says_what_its_limits_count(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        build_parser().parse_args(["router", "--help"])
    text = capsys.readouterr().out
    assert "never" not in text and "--max-frames" not in text and "--duration" in text
    assert isinstance(build_parser().parse_args(["router", "--config", "x"]), argparse.Namespace)
