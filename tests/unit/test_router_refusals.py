"""Refusals counted from zenoh's log: the line parser on lines zenoh 1.10.2 wrote, and a real router process.

zenoh reports refused TLS connections and access-control denials only in its log (see
``skelfuse.service.zenoh_log``); the router reads its own log and publishes the counts in its status.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import zenoh

from skelfuse.config import load_rig_config
from skelfuse.config.access import rig_identities
from skelfuse.service.certs import make_rig_certificates
from skelfuse.service.status import format_status
from skelfuse.service.zenoh_io import free_port, wait_for_port
from skelfuse.service.zenoh_log import MAX_KINDS, OTHER_KINDS, RefusalCounter
from skelfuse.wire.codec import decode_status
from waiting import wait_for_subscriber, wait_until

PC_A = "capture-pc-a.sim4.skelfuse"
ACL = "zenoh::net::routing::interceptor::access_control"
SUBJECT = f"Interface(lo)+CertCommonName({PC_A})+Transport(Tls)+c852579ceb764e48e0b6f2bde70cca18"


def decision(verdict: str, action: str, key: str, zid: str = "c852579ceb764e48e0b6f2bde70cca18") -> str:
    """A decision line as zenoh 1.10.2 writes it at TRACE (copied from a router's output, colours included)."""
    return (
        "\x1b[2m2026-11-25T06:40:51.551124Z\x1b[0m \x1b[35mTRACE\x1b[0m  rx-1 ThreadId(10) "
        "\x1b[1mdemux\x1b[0m\x1b[1m{\x1b[0mzid=c06b8d27c522ea0e4981f3746acccc22 src=south:0:client/c852579c:1"
        f"\x1b[1m}}\x1b[0m\x1b[2m:\x1b[0m \x1b[2m{ACL}\x1b[0m\x1b[2m:\x1b[0m {zid} on "
        f"{SUBJECT.replace('c852579ceb764e48e0b6f2bde70cca18', zid)} is {verdict} to {action} on {key}"
    )


CACHED_ACTIONS = (
    "Query",
    "Reply",
    "Put",
    "Delete",
    "Declare/Undeclare Subscriber",
    "Declare/Undeclare Queryable",
    "Declare/Undeclare Liveliness Token",
    "Liveliness Query",
    "Declare Liveliness Subscriber",
)


def caching(key: str) -> str:
    return (
        "2026-11-25T06:49:07.231894Z TRACE  rx-1 ThreadId(10) demux{zid=c06b8d27c522ea0e4981f3746acccc22 "
        f"src=south:0:client/c852579c:1}}: {ACL}: ACL (ingress): caching permissions for `{key}` ..."
    )


def cached(verdict: str, action: str, key: str) -> str:
    return (
        "2026-11-25T06:49:07.525192Z TRACE  rx-1 ThreadId(10) demux{zid=c06b8d27c522ea0e4981f3746acccc22 "
        f"src=south:0:client/c852579c:1}}: {ACL}: Using cached result: c852579ceb764e48e0b6f2bde70cca18 is "
        f"{verdict} to {action} on {key}"
    )


def test_counter_reads_zenohs_decision_and_tls_lines() -> None:
    counter = RefusalCounter([PC_A])
    own, other, fused = (
        "skelfuse/sim4/sensors/capture_0/skeletons",
        "skelfuse/sim4/sensors/capture_2/skeletons",
        "skelfuse/sim4/fused/skeletons",
    )
    lines = []
    for _ in range(3):  # three refused puts on pc-b's key: two lines each (the 'rig' subject and pc-a's own)
        lines += [decision("unauthorized", "Put (ingress)", other)] * 2
    lines += [decision("unauthorized", "Put (ingress)", fused)] * 2  # one refused put on the fused key
    for _ in range(5):  # allowed puts, the 'rig' subject tried first: its "unauthorized" line is not a refusal
        lines += [decision("unauthorized", "Put (ingress)", own), decision("authorized", "Put (ingress)", own)]
    lines += [
        "\x1b[2m2026-11-25T06:42:09.914596Z\x1b[0m \x1b[33m WARN\x1b[0m acc-0 ThreadId(06) "
        "\x1b[2mzenoh_link_tls::unicast\x1b[0m\x1b[2m:\x1b[0m invalid peer certificate: BadSignature. "
        "Hint: increase the system open file limit.",
        "2026-11-25T06:40:50.903131Z  INFO ThreadId(01) zenoh::net::runtime::orchestrator: Zenoh can be reached at: "
        "tls/127.0.0.1:35111",
    ]
    # A publisher declared on capture_3's key: zenoh fills its permission cache (every action, allowed or not, for
    # each subject; no message is refused there), then logs one cached decision per message.
    declared = "skelfuse/sim4/sensors/capture_3/skeletons"
    cache_block = [caching(declared)]
    for action in CACHED_ACTIONS:
        cache_block += [decision("unauthorized", f"{action} (ingress)", declared)]
        if action in ("Query", "Declare/Undeclare Subscriber", "Liveliness Query", "Declare Liveliness Subscriber"):
            cache_block += [decision("authorized", f"{action} (ingress)", declared)]
        else:
            cache_block += [decision("unauthorized", f"{action} (ingress)", declared)]
    lines = cache_block + lines + [cached("unauthorized", "Put (ingress)", declared)] * 4
    kinds = [counter.feed(line) for line in lines]
    assert kinds[-6:-4] == ["tls", None]  # the INFO line is left for the log
    assert counter.refused_messages() == {
        (PC_A, "Put (ingress)", other): 3,
        (PC_A, "Put (ingress)", fused): 1,
        (PC_A, "Put (ingress)", declared): 4,
    }
    assert counter.counters() == {"refused_tls": 1, "refused_messages": 8}
    assert counter.info()["tls_refused"] == {"invalid peer certificate: BadSignature": 1}


def test_counter_stays_bounded_whatever_keys_peers_send() -> None:
    counter = RefusalCounter()
    for i in range(MAX_KINDS + 500):
        counter.feed(decision("unauthorized", "Put (ingress)", f"skelfuse/sim4/junk/{i}"))
    refused = counter.refused_messages()
    assert len(refused) == MAX_KINDS + 1
    assert refused[(OTHER_KINDS, "", OTHER_KINDS)] == 500


@pytest.mark.live
def test_the_router_counts_refused_certificates_and_messages_in_its_status(tmp_path: Path) -> None:
    base = load_rig_config(Path(__file__).resolve().parents[2] / "config" / "rig-sim-4.toml")
    certs = tmp_path / "certs"
    port = free_port()
    rig = tmp_path / "rig.toml"
    sensors = []
    for i, sensor in enumerate(base.sensors):
        sensors += [
            "[[sensors]]",
            f'id = "{sensor.id}"',
            'source = "sim"',
            f'host = "{"pc-a" if i < 2 else "pc-b"}"',
            f"world_from_sensor = {base.poses()[sensor.id].tolist()}",
        ]
    rig.write_text(
        "\n".join(
            [
                '[rig]\nname = "sim4"\n[node]\nstatus_period_s = 0.25',
                f'[zenoh]\nmode = "client"\nconnect = ["tls/127.0.0.1:{port}"]',
                "access_control = true\nconnect_timeout_ms = 500",
                f'[zenoh.tls]\ndirectory = "{certs}"',
                *sensors,
            ]
        )
    )
    cfg = load_rig_config(rig)
    make_rig_certificates(certs, "sim4", rig_identities(cfg, ("viewer",)))
    log_file = open(tmp_path / "router.log", "wb")
    router = subprocess.Popen(
        [sys.executable, "-m", "skelfuse", "router", "--config", str(rig), "--zenoh-listen", f"tls/127.0.0.1:{port}"],
        stdout=log_file,
        stderr=subprocess.STDOUT,
        start_new_session=True,
        env={k: v for k, v in os.environ.items() if k != "RUST_LOG"},
    )
    from skelfuse.config import zenoh_config

    sessions = []
    statuses, delivered = [], []
    lock = threading.Lock()

    def on_status(sample) -> None:
        status = decode_status(sample.payload.to_bytes())
        if status.role == "router":
            with lock:
                statuses.append(status)

    try:
        assert wait_for_port(port, timeout_s=60), (tmp_path / "router.log").read_text()
        app = zenoh.open(zenoh_config(cfg, identity="app-viewer"))
        sessions.append(app)
        app.declare_subscriber("skelfuse/sim4/status/router", on_status)
        app.declare_subscriber("skelfuse/sim4/sensors/*/skeletons", lambda s: delivered.append(str(s.key_expr)))
        pc_a = zenoh.open(zenoh_config(cfg, identity="capture-pc-a"))
        sessions.append(pc_a)
        own = pc_a.declare_publisher("skelfuse/sim4/sensors/capture_0/skeletons")
        forged_declared = pc_a.declare_publisher("skelfuse/sim4/sensors/capture_3/skeletons")
        # The viewer's subscription to sensors/*/skeletons has reached pc-a (through the router) for both keys.
        wait_for_subscriber(own, "the viewer's subscription", timeout_s=60)
        for _ in range(3):
            own.put(b"own sensor")
            pc_a.put("skelfuse/sim4/sensors/capture_2/skeletons", b"pc-b's sensor, forged")
            forged_declared.put(b"pc-b's other sensor, forged on a declared publisher")
        pc_a.put("skelfuse/sim4/fused/skeletons", b"fused, forged")
        other_ca = tmp_path / "other"
        make_rig_certificates(other_ca, "sim4", ["capture-pc-a"])
        impostor = cfg.zenoh.tls.__class__(ca=certs / "ca.pem", directory=other_ca)
        import dataclasses

        forged = dataclasses.replace(cfg, zenoh=dataclasses.replace(cfg.zenoh, tls=impostor))
        with pytest.raises(Exception, match="Unable to connect"):
            zenoh.open(zenoh_config(forged, identity="capture-pc-a"))
        # A client with no certificate at all (it trusts the rig's CA, so the router's certificate passes): the
        # router's TLS layer refuses it with "peer sent no certificates", once per connection attempt.
        bare = zenoh.Config()
        for key, value in {
            "mode": '"client"',
            "connect/endpoints": f'["tls/127.0.0.1:{port}"]',
            "connect/timeout_ms": "1000",
            "scouting/multicast/enabled": "false",
            "transport/link/tls/root_ca_certificate": f'"{certs / "ca.pem"}"',
            "transport/link/tls/verify_name_on_connect": "false",
        }.items():
            bare.insert_json5(key, value)
        with pytest.raises(Exception, match="Unable to connect"):
            zenoh.open(bare)

        def refusals_counted():  # the router's latest status, once it has counted all that was refused
            with lock:
                last = statuses[-1] if statuses else None
            if (
                last is not None
                and last.counters["refused_messages"] >= 7
                and "peer sent no certificates" in last.info["tls_refused"]
                and len(delivered) >= 3
            ):
                return last
            return None

        last = wait_until(
            refusals_counted,
            "the router's status counting 7 refused messages",
            60,
            lambda: f"{statuses[-1:]}\n{(tmp_path / 'router.log').read_text()[-3000:]}",
        )
    finally:
        for session in reversed(sessions):
            session.close()
        if router.poll() is None:
            os.killpg(router.pid, signal.SIGTERM)
            try:
                router.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(router.pid, signal.SIGKILL)
                router.wait(5)
        log_file.close()
    output = (tmp_path / "router.log").read_text()
    refused = {(r["who"], r["key"]): r["messages"] for r in last.info["refused"]}
    assert refused == {
        (PC_A, "skelfuse/sim4/sensors/capture_2/skeletons"): 3,
        (PC_A, "skelfuse/sim4/sensors/capture_3/skeletons"): 3,
        (PC_A, "skelfuse/sim4/fused/skeletons"): 1,
    }, output
    assert last.counters["refused_tls"] >= 2 and "BadSignature" in str(last.info["tls_refused"]), output
    assert last.info["tls_refused"]["peer sent no certificates"] >= 1, output
    assert delivered.count("skelfuse/sim4/sensors/capture_0/skeletons") == 3  # the access control still works
    assert "refused Put (ingress) from capture-pc-a.sim4.skelfuse on skelfuse/sim4/fused/skeletons" in output
    assert "is authorized" not in output  # the TRACE decision lines are consumed, not written to the log
    line = format_status(last)
    assert "refused: " in line and "messages" in line and f"{PC_A} Put (ingress) on skelfuse/sim4/" in line, line
