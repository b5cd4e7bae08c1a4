"""Several PCs: the [zenoh] keys, `skelfuse certs`, and the router's access control with real zenoh sessions.

The access control is checked against zenoh itself (a router, clients over mutual TLS on loopback): what
arrives at a subscriber is the truth, not our generated JSON.
"""

from __future__ import annotations

import dataclasses
import stat
import threading
from pathlib import Path

import pytest

from skelfuse.cli import main
from skelfuse.config import RigConfig, load_rig_config, parse_rig_config, zenoh_config
from skelfuse.config.access import access_control, capture_hosts, common_name, rig_identities
from skelfuse.config.model import ZenohTls
from skelfuse.schema.errors import ConfigError
from skelfuse.service.certs import make_rig_certificates
from skelfuse.service.zenoh_io import free_port
from waiting import wait_until

RIG_SIM_4 = Path(__file__).resolve().parents[2] / "config" / "rig-sim-4.toml"


def two_pc_rig() -> RigConfig:
    """Four sensors on two capture PCs (pc-a: capture_0, capture_1; pc-b: capture_2, capture_3)."""
    cfg = load_rig_config(RIG_SIM_4)
    sensors = tuple(dataclasses.replace(s, host="pc-a" if i < 2 else "pc-b") for i, s in enumerate(cfg.sensors))
    return dataclasses.replace(cfg, sensors=sensors)


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("certs")
    make_rig_certificates(directory, "sim4", rig_identities(two_pc_rig(), ("viewer",)))
    return directory


def test_zenoh_keys_parse_with_defaults_for_production() -> None:
    data = {"rig": {"name": "r"}, "sensors": [{"id": "s0", "source": "sim", "host": "pc-a"}]}
    cfg = parse_rig_config(data)
    assert cfg.zenoh.multicast_scouting is False  # explicit endpoints unless a config (the demo's) says so
    assert (cfg.zenoh.reconnect_init_ms, cfg.zenoh.reconnect_max_ms) == (100, 1000)
    assert cfg.sensors[0].capture_host == "pc-a"
    with pytest.raises(ConfigError, match=r"\[zenoh\.tls\]"):
        parse_rig_config(data | {"zenoh": {"config": {"transport/link/tls/root_ca_certificate": "ca.pem"}}})
    with pytest.raises(ConfigError, match="access_control needs"):
        parse_rig_config(data | {"zenoh": {"access_control": True}})


def test_session_config_carries_tls_retry_and_size_limits(certs: Path) -> None:
    import json

    cfg = two_pc_rig()
    cfg = dataclasses.replace(cfg, zenoh=dataclasses.replace(cfg.zenoh, tls=ZenohTls(directory=certs)))
    conf = json.loads(str(zenoh_config(cfg, mode="client", identity="capture-pc-a")))
    tls = conf["transport"]["link"]["tls"]
    assert tls["root_ca_certificate"] == str(certs / "ca.pem")
    assert tls["connect_certificate"] == str(certs / "capture-pc-a.pem")
    assert tls["enable_mtls"] is True
    assert conf["connect"]["retry"]["period_init_ms"] == 100
    assert conf["transport"]["link"]["rx"]["max_message_size"] == 1_048_576
    with pytest.raises(ConfigError, match="skelfuse certs"):
        zenoh_config(cfg, mode="client", identity="capture-pc-z")  # no such certificate


@pytest.mark.live
def test_congestion_keys_reach_the_session_config_and_the_fused_publisher() -> None:
    """[zenoh] wait_before_drop_ms / wait_before_close_ms (ms) become zenoh's microseconds; the fused
    publisher is declared with the chosen congestion control, express, on DATA_HIGH (read back from zenoh)."""
    import json

    import zenoh

    from skelfuse.service.zenoh_io import FusedPublisher

    data = {"rig": {"name": "r"}, "sensors": [{"id": "s0", "source": "sim"}]}
    congestion = json.loads(str(zenoh_config(parse_rig_config(data))))["transport"]["link"]["tx"]["queue"]
    assert congestion["congestion_control"]["drop"]["wait_before_drop"] == 250_000  # zenoh's own: 1000 (1 ms)
    assert congestion["congestion_control"]["block"]["wait_before_close"] == 1_000_000  # zenoh's own: 5 s
    cfg = parse_rig_config(
        data | {"zenoh": {"fused_congestion_control": "block", "wait_before_drop_ms": 40, "wait_before_close_ms": 300}}
    )
    conf = zenoh_config(cfg, mode="peer", listen=[f"tcp/127.0.0.1:{free_port()}"], multicast_scouting=False)
    congestion = json.loads(str(conf))["transport"]["link"]["tx"]["queue"]["congestion_control"]
    assert (congestion["drop"]["wait_before_drop"], congestion["block"]["wait_before_close"]) == (40_000, 300_000)
    session = zenoh.open(conf)
    try:
        for control, expected in (("block", zenoh.CongestionControl.BLOCK), ("drop", zenoh.CongestionControl.DROP)):
            publisher = FusedPublisher(session, "r/fused", congestion_control=control, bound_ms=300)
            assert publisher._publisher.congestion_control == expected
            assert publisher._publisher.priority == zenoh.Priority.DATA_HIGH
            publisher.put(b"frame")
            assert publisher.report()["puts"] == 1
            publisher.undeclare()
    finally:
        session.close()
    with pytest.raises(ConfigError, match="fused_congestion_control"):
        parse_rig_config(data | {"zenoh": {"fused_congestion_control": "block_first"}})
    with pytest.raises(ConfigError, match="wait_before_drop_ms"):
        parse_rig_config(data | {"zenoh": {"wait_before_drop_ms": -1}})
    with pytest.raises(ConfigError, match="wait_before_drop_ms / wait_before_close_ms"):
        raw = {"transport/link/tx/queue/congestion_control/drop/wait_before_drop": 5}
        parse_rig_config(data | {"zenoh": {"config": raw}})


def test_certs_are_signed_by_the_rig_ca_with_the_identity_common_name(certs: Path) -> None:
    from cryptography import x509
    from cryptography.hazmat.primitives.asymmetric import ec

    ca = x509.load_pem_x509_certificate((certs / "ca.pem").read_bytes())
    leaf = x509.load_pem_x509_certificate((certs / "capture-pc-b.pem").read_bytes())
    ca.public_key().verify(leaf.signature, leaf.tbs_certificate_bytes, ec.ECDSA(leaf.signature_hash_algorithm))
    assert leaf.subject.rfc4514_string() == f"CN={common_name('sim4', 'capture-pc-b')}"
    assert stat.S_IMODE((certs / "capture-pc-b.key").stat().st_mode) == 0o600
    before = (certs / "ca.pem").read_bytes()
    make_rig_certificates(certs, "sim4", ["app-late"])  # the CA is reused: certificates can be added later
    assert (certs / "ca.pem").read_bytes() == before and (certs / "app-late.pem").exists()


def test_certs_command_makes_every_identity(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["certs", "--config", str(RIG_SIM_4), "--output", str(tmp_path), "--app", "viewer", "--json"]) == 0
    names = sorted(p.stem for p in tmp_path.glob("*.pem"))
    assert names == sorted(["ca", "router", "fusion", "app-viewer", *(f"capture-capture_{i}" for i in range(4))])


def test_access_control_is_generated_from_the_rig() -> None:
    cfg = two_pc_rig()
    assert capture_hosts(cfg) == {"pc-a": ("capture_0", "capture_1"), "pc-b": ("capture_2", "capture_3")}
    acl = access_control(cfg)
    rules = {rule["id"]: rule for rule in acl["rules"]}
    assert rules["capture-pc-a-publishes"]["key_exprs"] == [
        "skelfuse/sim4/sensors/capture_0/skeletons",
        "skelfuse/sim4/sensors/capture_1/skeletons",
        "skelfuse/sim4/status/capture-capture_0",
        "skelfuse/sim4/status/capture-capture_1",
    ]
    assert rules["fusion-publishes"]["key_exprs"] == ["skelfuse/sim4/fused/skeletons", "skelfuse/sim4/status/fusion"]
    assert acl["default_permission"] == "deny"


def _secured(cfg: RigConfig, tls: ZenohTls) -> RigConfig:
    z = dataclasses.replace(cfg.zenoh, tls=tls, access_control=True, connect_timeout_ms=500)
    return dataclasses.replace(cfg, zenoh=z)


@pytest.mark.live
def test_router_enforces_mutual_tls_and_per_key_access(certs: Path, tmp_path: Path) -> None:
    import zenoh

    cfg = _secured(two_pc_rig(), ZenohTls(directory=certs))
    port = free_port()
    endpoint = [f"tls/127.0.0.1:{port}"]
    router = zenoh.open(zenoh_config(cfg, mode="router", listen=endpoint, identity="router"))
    sessions = [router]
    received: list[tuple[str, bytes]] = []
    lock = threading.Lock()

    def client(c: RigConfig, identity: str | None) -> zenoh.Session:
        session = zenoh.open(zenoh_config(c, mode="client", connect=endpoint, identity=identity))
        sessions.append(session)
        return session

    try:
        app = client(cfg, "app-viewer")

        def on_sample(sample: zenoh.Sample) -> None:
            with lock:
                received.append((str(sample.key_expr), sample.payload.to_bytes()))

        app.declare_subscriber("skelfuse/sim4/**", on_sample)
        pc_a, fusion = client(cfg, "capture-pc-a"), client(cfg, "fusion")
        own_key, fused_key = "skelfuse/sim4/sensors/capture_0/skeletons", "skelfuse/sim4/fused/skeletons"

        def arrived(key: str, payload: bytes) -> bool:
            with lock:
                return (key, payload) in received

        # Each client's allowed key reaches the viewer before the check starts (routes are in place).
        for session, key in ((pc_a, own_key), (fusion, fused_key)):
            wait_until(lambda s=session, k=key: s.put(k, b"ready") or arrived(k, b"ready"), f"{key} to route")
        pc_a.put(own_key, b"own sensor")
        pc_a.put("skelfuse/sim4/sensors/capture_2/skeletons", b"pc-b's sensor, forged")
        pc_a.put(fused_key, b"fused, forged by a capture PC")
        fusion.put(fused_key, b"fused")
        fusion.put("skelfuse/sim4/sensors/capture_3/skeletons", b"sensor, forged by the fusion node")
        # One session's messages keep their order on its link: once each client's last message has arrived,
        # a forged one sent before it would have arrived too.
        pc_a.put(own_key, b"end")
        fusion.put(fused_key, b"end")
        wait_until(lambda: arrived(own_key, b"end") and arrived(fused_key, b"end"), "both clients' last messages")
        with lock:
            got = sorted(sample for sample in received if sample[1] not in (b"ready", b"end"))
        assert got == [
            ("skelfuse/sim4/fused/skeletons", b"fused"),
            ("skelfuse/sim4/sensors/capture_0/skeletons", b"own sensor"),
        ]

        # A stranger without a certificate, and a certificate of another CA, cannot even connect.
        stranger = _secured(two_pc_rig(), ZenohTls(ca=certs / "ca.pem"))
        with pytest.raises(Exception, match="Unable to connect"):
            client(stranger, None)
        other_ca = tmp_path / "other"
        make_rig_certificates(other_ca, "sim4", ["capture-pc-a"])
        impostor = _secured(two_pc_rig(), ZenohTls(ca=certs / "ca.pem", directory=other_ca))
        with pytest.raises(Exception, match="Unable to connect"):
            client(impostor, "capture-pc-a")
    finally:
        for session in reversed(sessions):
            session.close()


def test_the_router_command_enforces_the_access_control_whatever_the_files_mode(certs: Path, tmp_path: Path) -> None:
    import json

    from skelfuse.cli import build_parser
    from skelfuse.cli.network import router_config

    cfg = _secured(two_pc_rig(), ZenohTls(directory=certs))
    assert cfg.zenoh.mode == "peer"  # the rig's file says peer (or client, for its clients)
    args = build_parser().parse_args(["router", "--config", str(RIG_SIM_4)])
    conf = json.loads(str(router_config(args, cfg)))
    assert conf["mode"] == "router" and conf["access_control"]["enabled"] is True
    assert conf["transport"]["link"]["tls"]["listen_certificate"] == str(certs / "router.pem")
