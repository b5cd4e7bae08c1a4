"""The zenoh session config of a node, from the rig config and the command line's zenoh flags."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from skelfuse.config.access import access_control
from skelfuse.config.model import ZENOH_MODES, RigConfig, ZenohTls
from skelfuse.schema.errors import ConfigError

if TYPE_CHECKING:  # pragma: no cover - typing only
    import zenoh


SCOUTING_DELAY_MS = 0
"""How long ``zenoh.open`` waits for peers found by scouting before it returns (zenoh's ``scouting/delay``;
its own default is 500 ms, paid by every node with multicast scouting on or a connect endpoint not yet up,
which was most of a daemon's start). Our nodes stream continuously, so a peer that connects a moment after
the session opened loses nothing that matters; ``[zenoh.config] "scouting/delay"`` or ``--zenoh-cfg
scouting/delay:500`` restore the wait."""


def zenoh_config(
    cfg: RigConfig,
    overrides: Sequence[str] = (),
    *,
    mode: str | None = None,
    connect: Sequence[str] | None = None,
    listen: Sequence[str] | None = None,
    multicast_scouting: bool | None = None,
    identity: str | None = None,
) -> zenoh.Config:
    """The zenoh session config of a node: file < flags < ``--zenoh-cfg KEY:VALUE`` overrides.

    ``identity`` (``fusion``, ``router``, ``capture-<host>``, ``app-<name>``; :mod:`skelfuse.config.access`)
    picks this process's certificate from ``[zenoh.tls] directory``; a router with ``access_control = true``
    enforces the rig's generated access control.

    Order of application (later wins), as in zenoh-python's ``examples/common/common.py``:

    0. skelfuse's default: ``scouting/delay`` = :data:`SCOUTING_DELAY_MS` (the session opens at once);
    1. ``[zenoh.config]`` raw keys of the file, then ``[zenoh]`` mode / connect / listen /
       multicast_scouting (validation forbids a raw key that duplicates one of those);
    2. the keyword flags (None: not given on the command line);
    3. ``overrides``: ``"KEY:VALUE"`` strings, KEY a zenoh config path (``transport/unicast/max_links``),
       VALUE JSON5 (``2``, ``'"client"'``, ``'["tcp/10.0.0.2:7447"]'``). Split at the first ``:`` only, so
       endpoint values keep theirs.

    Raises
    ------
    ConfigError
        A malformed override or a key / value zenoh rejects (the message names which).
    """
    import zenoh

    conf = zenoh.Config()
    _insert(conf, "scouting/delay", str(SCOUTING_DELAY_MS), "skelfuse's default")
    _apply_file(conf, cfg, mode, identity)
    _apply_flags(conf, mode, connect, listen, multicast_scouting)
    for item in overrides:
        key, sep, value = str(item).partition(":")
        if not sep or not key.strip() or not value.strip():
            raise ConfigError(f"--zenoh-cfg: expected KEY:VALUE (e.g. 'transport/unicast/max_links:2'), found {item!r}")
        _insert(conf, key.strip(), value.strip(), f"--zenoh-cfg {item!r}")
    return conf


def _insert(conf: zenoh.Config, key: str, value_json5: str, origin: str) -> None:
    """``conf.insert_json5``, a refusal raised as a ConfigError that names where the value came from."""
    try:
        conf.insert_json5(key, value_json5)
    except Exception as exc:  # zenoh raises its own ZError
        raise ConfigError(
            f"{origin}: zenoh rejected {key} = {value_json5}: {exc}; check the key path and "
            f"value type against zenoh's DEFAULT_CONFIG.json5"
        ) from None


def _apply_file(conf: zenoh.Config, cfg: RigConfig, mode: str | None, identity: str | None) -> None:
    """The rig file's ``[zenoh.config]`` raw keys, then its ``[zenoh]`` settings (TLS and access control too)."""

    def insert(key: str, value_json5: str, origin: str) -> None:
        _insert(conf, key, value_json5, origin)

    for key, value in cfg.zenoh.config:
        insert(key, json.dumps(value), f'{cfg.source}: zenoh.config."{key}"')
    z = cfg.zenoh
    insert("mode", json.dumps(z.mode), f"{cfg.source}: zenoh.mode")
    if z.connect:
        insert("connect/endpoints", json.dumps(list(z.connect)), f"{cfg.source}: zenoh.connect")
    if z.listen:
        insert("listen/endpoints", json.dumps(list(z.listen)), f"{cfg.source}: zenoh.listen")
    insert("scouting/multicast/enabled", json.dumps(z.multicast_scouting), f"{cfg.source}: zenoh.multicast_scouting")
    retry = {"period_init_ms": z.reconnect_init_ms, "period_max_ms": z.reconnect_max_ms, "period_increase_factor": 2}
    insert("connect/retry", json.dumps(retry), f"{cfg.source}: zenoh.reconnect_init_ms / reconnect_max_ms")
    effective_mode = mode if mode is not None else z.mode
    if effective_mode == "client":  # peers and routers open without their connect endpoints and keep trying
        insert("connect/timeout_ms", json.dumps(z.connect_timeout_ms), f"{cfg.source}: zenoh.connect_timeout_ms")
    size = json.dumps(z.max_message_bytes)
    insert("transport/link/rx/max_message_size", size, f"{cfg.source}: zenoh.max_message_bytes")
    congestion = "transport/link/tx/queue/congestion_control"
    drop_us, close_us = json.dumps(z.wait_before_drop_ms * 1000), json.dumps(z.wait_before_close_ms * 1000)
    insert(f"{congestion}/drop/wait_before_drop", drop_us, f"{cfg.source}: zenoh.wait_before_drop_ms")
    insert(f"{congestion}/block/wait_before_close", close_us, f"{cfg.source}: zenoh.wait_before_close_ms")
    if z.tls is not None:
        for key, value in tls_settings(z.tls, identity).items():
            insert(f"transport/link/tls/{key}", json.dumps(value), f"{cfg.source}: [zenoh.tls]")
    if z.access_control and effective_mode == "router":
        insert("access_control", json.dumps(access_control(cfg)), f"{cfg.source}: zenoh.access_control")


def _apply_flags(
    conf: zenoh.Config,
    mode: str | None,
    connect: Sequence[str] | None,
    listen: Sequence[str] | None,
    multicast_scouting: bool | None,
) -> None:
    """The command line's zenoh flags (None: not given)."""
    if mode is not None:
        if mode not in ZENOH_MODES:
            raise ConfigError(f"--zenoh-mode: expected one of {', '.join(ZENOH_MODES)}, found {mode!r}")
        _insert(conf, "mode", json.dumps(mode), "--zenoh-mode")
    if connect is not None:
        _insert(conf, "connect/endpoints", json.dumps(list(connect)), "--zenoh-connect")
    if listen is not None:
        _insert(conf, "listen/endpoints", json.dumps(list(listen)), "--zenoh-listen")
    if multicast_scouting is not None:
        _insert(conf, "scouting/multicast/enabled", json.dumps(bool(multicast_scouting)), "--no-multicast-scouting")


def tls_files(tls: ZenohTls, identity: str | None) -> dict[str, str]:
    """The CA, certificate and key files of ``identity`` (explicit paths win over the directory's)."""
    files: dict[str, str] = {}
    ca = tls.ca or (tls.directory / "ca.pem" if tls.directory is not None else None)
    if ca is not None:
        files["ca"] = str(ca)
    certificate, key = tls.certificate, tls.private_key
    if certificate is None and tls.directory is not None and identity is not None:
        certificate, key = tls.directory / f"{identity}.pem", tls.directory / f"{identity}.key"
    if certificate is not None and key is not None:
        files["certificate"], files["private_key"] = str(certificate), str(key)
    for what, path in files.items():
        if not Path(path).is_file():
            raise ConfigError(
                f"[zenoh.tls] {what} {path} does not exist; make the rig's certificates with `skelfuse certs "
                f"--config RIG.toml --output DIR` (identity {identity or '?'})"
            )
    return files


def tls_settings(tls: ZenohTls, identity: str | None) -> dict[str, object]:
    """zenoh's ``transport/link/tls`` keys: the same certificate serves listening and connecting."""
    files = tls_files(tls, identity)
    settings: dict[str, object] = {
        "enable_mtls": tls.mutual,
        "verify_name_on_connect": tls.verify_name,
    }
    if "ca" in files:
        settings["root_ca_certificate"] = files["ca"]
    if "certificate" in files:
        settings["listen_certificate"] = files["certificate"]
        settings["listen_private_key"] = files["private_key"]
        settings["connect_certificate"] = files["certificate"]
        settings["connect_private_key"] = files["private_key"]
    return settings
