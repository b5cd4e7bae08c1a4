"""The zenoh session config of a node, from the rig config and the command line's zenoh flags."""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import TYPE_CHECKING

from skelfuse.config.model import ZENOH_MODES, RigConfig
from skelfuse.schema.errors import ConfigError

if TYPE_CHECKING:  # pragma: no cover - typing only
    import zenoh


def zenoh_config(
    cfg: RigConfig,
    overrides: Sequence[str] = (),
    *,
    mode: str | None = None,
    connect: Sequence[str] | None = None,
    listen: Sequence[str] | None = None,
    multicast_scouting: bool | None = None,
) -> zenoh.Config:
    """The zenoh session config of a node: file < flags < ``--zenoh-cfg KEY:VALUE`` overrides.

    Order of application (later wins), as in zenoh-python's ``examples/common/common.py``:

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

    def insert(key: str, value_json5: str, origin: str) -> None:
        try:
            conf.insert_json5(key, value_json5)
        except Exception as exc:  # zenoh raises its own ZError
            raise ConfigError(
                f"{origin}: zenoh rejected {key} = {value_json5}: {exc}; check the key path and "
                f"value type against zenoh's DEFAULT_CONFIG.json5"
            ) from None

    for key, value in cfg.zenoh.config:
        insert(key, json.dumps(value), f'{cfg.source}: zenoh.config."{key}"')
    z = cfg.zenoh
    insert("mode", json.dumps(z.mode), f"{cfg.source}: zenoh.mode")
    if z.connect:
        insert("connect/endpoints", json.dumps(list(z.connect)), f"{cfg.source}: zenoh.connect")
    if z.listen:
        insert("listen/endpoints", json.dumps(list(z.listen)), f"{cfg.source}: zenoh.listen")
    insert("scouting/multicast/enabled", json.dumps(z.multicast_scouting), f"{cfg.source}: zenoh.multicast_scouting")

    if mode is not None:
        if mode not in ZENOH_MODES:
            raise ConfigError(f"--zenoh-mode: expected one of {', '.join(ZENOH_MODES)}, found {mode!r}")
        insert("mode", json.dumps(mode), "--zenoh-mode")
    if connect is not None:
        insert("connect/endpoints", json.dumps(list(connect)), "--zenoh-connect")
    if listen is not None:
        insert("listen/endpoints", json.dumps(list(listen)), "--zenoh-listen")
    if multicast_scouting is not None:
        insert("scouting/multicast/enabled", json.dumps(bool(multicast_scouting)), "--no-multicast-scouting")

    for item in overrides:
        key, sep, value = str(item).partition(":")
        if not sep or not key.strip() or not value.strip():
            raise ConfigError(f"--zenoh-cfg: expected KEY:VALUE (e.g. 'transport/unicast/max_links:2'), found {item!r}")
        insert(key.strip(), value.strip(), f"--zenoh-cfg {item!r}")
    return conf
