"""Every zenoh key expression skelfuse uses, built in one place under one rig prefix.

A *rig* is one installation (the sensors that look at one space, and the fusion node that merges them). All
its traffic lives under ``skelfuse/<rig>/``::

    skelfuse/<rig>/sensors/<serial>/skeletons   capture worker -> fusion node   (codec: sensor frame)
    skelfuse/<rig>/fused/skeletons              fusion node -> apps             (codec: fused frame)
    skelfuse/<rig>/status/<node>                every node, periodically        (codec: node status)
    skelfuse/<rig>/calibration                  queryable served by the fusion node
    skelfuse/<rig>/alive/<node>                 liveliness token of every running node

Names (rig, sensor serial, node) are single key chunks. :func:`validate_name` refuses anything zenoh would
reject or treat specially: an empty name, ``/`` (would add a level), ``*`` and ``$`` (wildcard syntax),
``?`` and ``#`` (forbidden by zenoh), a leading ``@`` (a zenoh "verbatim" chunk, which wildcards never
match, so ``skelfuse/*/fused/skeletons`` would miss the rig), and whitespace or control characters (legal
for zenoh but a trap in shells and config files).

Nothing here imports zenoh: keys are plain strings, and a received key (``sample.key_expr``) is parsed
after ``str()``.
"""

from __future__ import annotations

import re

PREFIX = "skelfuse"
"""First chunk of every skelfuse key."""

_FORBIDDEN_CHARS = frozenset("/*$?#")
_NAME_HINT = "use letters, digits, '-', '_' or '.', e.g. a device serial like '000123412512'"


def validate_name(name: object, what: str = "name") -> str:
    """Return ``name`` if it can be one chunk of a skelfuse key, else raise ValueError saying why.

    Parameters
    ----------
    name : str
        A rig name, sensor serial or node name.
    what : str
        What the name is ("rig", "sensor", "node"), used in the message.

    Raises
    ------
    ValueError
        Empty, holds one of ``/ * $ ? #``, starts with ``@``, or holds whitespace / control characters.
    TypeError
        ``name`` is not a str.
    """
    if not isinstance(name, str):
        raise TypeError(f"{what} name must be a str, got {type(name).__name__}: {name!r}")
    if not name:
        raise ValueError(f"{what} name is empty; {_NAME_HINT}")
    bad = sorted({ch for ch in name if ch in _FORBIDDEN_CHARS})
    if bad:
        raise ValueError(
            f"{what} name {name!r} holds {' '.join(repr(ch) for ch in bad)}, which zenoh key chunks "
            f"cannot carry ('/' separates levels, '*' and '$' are wildcards, '?' and '#' are forbidden); "
            f"{_NAME_HINT}"
        )
    if name.startswith("@"):
        raise ValueError(
            f"{what} name {name!r} starts with '@', which makes a zenoh verbatim chunk that wildcard "
            f"subscriptions never match; {_NAME_HINT}"
        )
    if any(ch.isspace() or not ch.isprintable() for ch in name):
        raise ValueError(f"{what} name {name!r} holds whitespace or control characters; {_NAME_HINT}")
    return name


def rig_prefix(rig: str) -> str:
    """``skelfuse/<rig>``: the prefix of every key of that rig."""
    return f"{PREFIX}/{validate_name(rig, 'rig')}"


def sensor_skeletons(rig: str, sensor_id: str) -> str:
    """``skelfuse/<rig>/sensors/<sensor_id>/skeletons``: where one capture worker publishes sensor frames."""
    return f"{rig_prefix(rig)}/sensors/{validate_name(sensor_id, 'sensor')}/skeletons"


def all_sensor_skeletons(rig: str) -> str:
    """``skelfuse/<rig>/sensors/*/skeletons``: what the fusion node subscribes to."""
    return f"{rig_prefix(rig)}/sensors/*/skeletons"


def sensor_clouds(rig: str, sensor_id: str) -> str:
    """``skelfuse/<rig>/sensors/<sensor_id>/clouds``: where a capture worker in depth mode publishes its
    person clouds (:mod:`skelfuse.wire.clouds`)."""
    return f"{rig_prefix(rig)}/sensors/{validate_name(sensor_id, 'sensor')}/clouds"


def all_sensor_clouds(rig: str) -> str:
    """``skelfuse/<rig>/sensors/*/clouds``: what a fusion node in depth or hybrid mode subscribes to."""
    return f"{rig_prefix(rig)}/sensors/*/clouds"


def fused_skeletons(rig: str) -> str:
    """``skelfuse/<rig>/fused/skeletons``: where the fusion node publishes fused frames."""
    return f"{rig_prefix(rig)}/fused/skeletons"


def status(rig: str, node: str) -> str:
    """``skelfuse/<rig>/status/<node>``: where a node publishes its status document."""
    return f"{rig_prefix(rig)}/status/{validate_name(node, 'node')}"


def all_status(rig: str) -> str:
    """``skelfuse/<rig>/status/*``: every node's status."""
    return f"{rig_prefix(rig)}/status/*"


def calibration(rig: str) -> str:
    """``skelfuse/<rig>/calibration``: the queryable that serves the rig's calibration."""
    return f"{rig_prefix(rig)}/calibration"


def alive(rig: str, node: str) -> str:
    """``skelfuse/<rig>/alive/<node>``: the liveliness token a running node declares."""
    return f"{rig_prefix(rig)}/alive/{validate_name(node, 'node')}"


def all_alive(rig: str) -> str:
    """``skelfuse/<rig>/alive/*``: liveliness of every node (for ``liveliness().get`` / subscribers)."""
    return f"{rig_prefix(rig)}/alive/*"


def _parse_one_chunk(key: object, pattern: re.Pattern[str], shape: str, rig: str | None, what: str) -> str:
    text = str(key)
    match = pattern.fullmatch(text)
    if match is None:
        raise ValueError(f"key {text!r} is not a skelfuse {what} key; expected {shape!r}")
    key_rig, name = match.group(1), match.group(2)
    validate_name(key_rig, "rig")
    validate_name(name, what)
    if rig is not None and key_rig != validate_name(rig, "rig"):
        raise ValueError(f"key {text!r} belongs to rig {key_rig!r}, expected rig {rig!r}")
    return name


_SENSOR_KEY = re.compile(rf"{PREFIX}/([^/]+)/sensors/([^/]+)/skeletons")
_STATUS_KEY = re.compile(rf"{PREFIX}/([^/]+)/status/([^/]+)")
_ALIVE_KEY = re.compile(rf"{PREFIX}/([^/]+)/alive/([^/]+)")


def parse_sensor_key(key: object, rig: str | None = None) -> str:
    """Sensor id of a received ``skelfuse/<rig>/sensors/<sensor_id>/skeletons`` key.

    Parameters
    ----------
    key : str or zenoh.KeyExpr
        The sample's key expression (anything whose ``str()`` is the key).
    rig : str, optional
        When given, the key must belong to this rig.

    Raises
    ------
    ValueError
        The key has another shape, a chunk is not a valid name (e.g. a wildcard), or the rig differs.
    """
    return _parse_one_chunk(key, _SENSOR_KEY, f"{PREFIX}/<rig>/sensors/<sensor>/skeletons", rig, "sensor")


def parse_status_key(key: object, rig: str | None = None) -> str:
    """Node name of a received ``skelfuse/<rig>/status/<node>`` key (errors as :func:`parse_sensor_key`)."""
    return _parse_one_chunk(key, _STATUS_KEY, f"{PREFIX}/<rig>/status/<node>", rig, "node")


def parse_alive_key(key: object, rig: str | None = None) -> str:
    """Node name of a ``skelfuse/<rig>/alive/<node>`` liveliness key (errors as :func:`parse_sensor_key`)."""
    return _parse_one_chunk(key, _ALIVE_KEY, f"{PREFIX}/<rig>/alive/<node>", rig, "node")
