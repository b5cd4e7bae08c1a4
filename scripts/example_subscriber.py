#!/usr/bin/env python3
"""Subscribe to a skelfuse rig's fused skeletons and print each person's pelvis, without skelfuse.

This is the reference for writing a decoder in another language (C#, C++, Unity...): it uses only zenoh and
the Python standard library (``struct``), no skelfuse and no numpy, and follows docs/wire-format.md
section by section. ``decode_fused`` is the part to port.

Usage::

    pip install eclipse-zenoh
    python scripts/example_subscriber.py --config config/rig-sim-4.toml     # rig name and [zenoh] from the config
    python scripts/example_subscriber.py --rig lab --max-messages 100
    python scripts/example_subscriber.py --rig lab --connect tcp/192.168.1.10:7447 --no-scouting

It says which key it listens on and warns when nothing arrived after a few seconds (a wrong rig name is the
usual cause: every rig publishes under its own ``skelfuse/<rig>/...``).
"""

from __future__ import annotations

import argparse
import json
import math
import struct
import sys
import threading
import time
import tomllib
from collections.abc import Sequence
from typing import Any

MAGIC = b"SKLF"
SUPPORTED_MAJOR = 1
KNOWN_MINOR = 2  # 1.1 adds optional orientations and position_std after the sensor id table, 1.2 agreement_mm
SECTION_ORIENTATIONS = 1  # bits of the header's `sections` field (version 1.1; `reserved` in 1.0)
SECTION_POSITION_STD = 2
SECTION_AGREEMENT = 4  # version 1.2
KIND_FUSED_FRAME = 2
N_JOINTS = 32
PELVIS = 0

# Fused-frame header, 32 bytes little-endian: magic, major, minor, kind, flags, header_size, n_joints,
# n_persons, n_sensors, time_us, sensor_table_size, sections (1.1; reserved in 1.0).
FUSED_HEADER = struct.Struct("<4sBBBBHHHHqII")


class PayloadError(ValueError):
    """The payload is not a fused frame this decoder understands."""


def decode_fused(payload: bytes) -> dict[str, Any]:
    """Decode a fused-frame payload (docs/wire-format.md, message kind 2) into plain Python values.

    Returns
    -------
    dict
        ``version`` (major, minor), ``time_us`` int, ``sensor_ids`` list of str, and ``persons``: one dict
        per person with ``track_id`` int, ``positions`` (32 [x, y, z] lists, mm, world frame, NaN = no
        estimate), ``n_agree`` (32 ints), ``confidence`` (32 ints 0..3), ``contributors`` (list of the
        sensor ids that contributed), and from a 1.1 payload that carries them ``orientations`` (32 [w, x, y, z]
        lists, world frame, k4abt joint axes, NaN = unknown) and ``position_std`` (32 floats, mm, one sigma per
        axis, NaN = no estimate), and from a 1.2 payload ``agreement_mm`` (float, mm, how far the views lie from
        the fused torso, NaN = fewer than two views); absent keys mean the sender did not compute them.
    """
    if len(payload) < FUSED_HEADER.size:
        raise PayloadError(f"{len(payload)} bytes, shorter than the {FUSED_HEADER.size}-byte header")
    (magic, major, minor, kind, _flags, header_size, n_joints, n_persons, n_sensors, time_us, table_size, sections) = (
        FUSED_HEADER.unpack_from(payload, 0)
    )
    if magic != MAGIC:
        raise PayloadError(f"magic {magic!r}, expected {MAGIC!r}")
    if major != SUPPORTED_MAJOR:
        raise PayloadError(f"schema version {major}.{minor}; this decoder reads major {SUPPORTED_MAJOR}")
    if kind != KIND_FUSED_FRAME:
        raise PayloadError(f"message kind {kind}, expected {KIND_FUSED_FRAME} (fused frame)")
    if header_size < FUSED_HEADER.size or n_joints != N_JOINTS:
        raise PayloadError(f"header size {header_size} / joint count {n_joints} not as documented")

    # Sections follow the header in this order; a newer minor may add bytes after them (ignored here).
    per_person = n_joints
    offset = header_size  # a newer minor may grow the header: always start at header_size
    track_ids_at = offset
    positions_at = track_ids_at + 8 * n_persons
    n_agree_at = positions_at + 8 * 3 * per_person * n_persons
    confidence_at = n_agree_at + 2 * per_person * n_persons
    contributors_at = confidence_at + per_person * n_persons
    table_at = contributors_at + n_sensors * n_persons
    table_end = table_at + table_size
    # Version 1.1: the `sections` bits name optional sections after the table, in bit order (1.0: ignore);
    # 1.2 adds bit 2. Bits of a newer minor name sections after these: skip them.
    sections = 0 if minor < 1 else sections & (SECTION_ORIENTATIONS | SECTION_POSITION_STD | SECTION_AGREEMENT)
    orientations_at = table_end
    std_at = orientations_at + (8 * 4 * per_person * n_persons if sections & SECTION_ORIENTATIONS else 0)
    agreement_at = std_at + (8 * per_person * n_persons if sections & SECTION_POSITION_STD else 0)
    end = agreement_at + (8 * n_persons if sections & SECTION_AGREEMENT else 0)
    if len(payload) < end or (minor <= KNOWN_MINOR and len(payload) != end):
        raise PayloadError(f"{len(payload)} bytes, the header's counts need {end}")

    sensor_ids = []
    at = table_at
    for _ in range(n_sensors):
        (size,) = struct.unpack_from("<H", payload, at)
        sensor_ids.append(payload[at + 2 : at + 2 + size].decode("utf-8"))
        at += 2 + size
    if at != table_end:
        raise PayloadError("sensor id table does not match its declared size")

    track_ids = struct.unpack_from(f"<{n_persons}q", payload, track_ids_at)
    coords = struct.unpack_from(f"<{3 * per_person * n_persons}d", payload, positions_at)
    n_agree = struct.unpack_from(f"<{per_person * n_persons}h", payload, n_agree_at)
    confidence = payload[confidence_at:contributors_at]
    contributors = payload[contributors_at:table_at]
    quats = (
        struct.unpack_from(f"<{4 * per_person * n_persons}d", payload, orientations_at)
        if sections & SECTION_ORIENTATIONS
        else ()
    )
    std = struct.unpack_from(f"<{per_person * n_persons}d", payload, std_at) if sections & SECTION_POSITION_STD else ()
    agreement = struct.unpack_from(f"<{n_persons}d", payload, agreement_at) if sections & SECTION_AGREEMENT else ()

    persons = []
    for p in range(n_persons):
        first = p * per_person
        person = {
            "track_id": track_ids[p],
            "positions": [list(coords[3 * (first + j) : 3 * (first + j) + 3]) for j in range(per_person)],
            "n_agree": list(n_agree[first : first + per_person]),
            "confidence": list(confidence[first : first + per_person]),
            "contributors": [sensor_ids[s] for s in range(n_sensors) if contributors[p * n_sensors + s]],
        }
        if quats:
            person["orientations"] = [list(quats[4 * (first + j) : 4 * (first + j) + 4]) for j in range(per_person)]
        if std:
            person["position_std"] = list(std[first : first + per_person])
        if agreement:
            person["agreement_mm"] = agreement[p]
        persons.append(person)
    return {"version": (major, minor), "time_us": time_us, "sensor_ids": sensor_ids, "persons": persons}


def describe(frame: dict[str, Any]) -> str:
    """One line per frame: time, then each person's track id and pelvis position (mm)."""
    parts = [f"t={frame['time_us'] / 1e6:.3f}s persons={len(frame['persons'])}"]
    for person in frame["persons"]:
        x, y, z = person["positions"][PELVIS]
        pelvis = "no estimate" if math.isnan(x) else f"({x:.0f}, {y:.0f}, {z:.0f}) mm"
        parts.append(f"track {person['track_id']}: pelvis {pelvis}")
    return " | ".join(parts)


SILENCE_WARNING_S = 5.0
"""Warn when no fused frame arrived this long after subscribing."""


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--rig", default=None, help="subscribes to skelfuse/<rig>/fused/skeletons (or take it from --config)"
    )
    parser.add_argument(
        "--config",
        default=None,
        metavar="RIG.toml",
        help="a skelfuse rig config: its [rig] name, and its [zenoh] mode / connect / listen / multicast_scouting "
        "unless given here",
    )
    parser.add_argument("--mode", choices=("peer", "client"), default=None, help="zenoh session mode (default: peer)")
    parser.add_argument("--connect", action="append", default=[], help="zenoh endpoint to connect to")
    parser.add_argument("--listen", action="append", default=[], help="zenoh endpoint to listen on")
    parser.add_argument("--no-scouting", action="store_true", help="disable multicast scouting")
    parser.add_argument("--max-messages", type=int, default=None, help="stop after this many frames")
    parser.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    args = parser.parse_args(argv)
    if args.config is not None:
        try:
            with open(args.config, "rb") as handle:
                rig = tomllib.load(handle)
        except (OSError, tomllib.TOMLDecodeError) as exc:
            parser.error(f"--config {args.config}: {exc}")
        name = rig.get("rig", {}).get("name")
        if args.rig is not None and name is not None and args.rig != name:
            parser.error(f"--rig {args.rig} but {args.config} is rig {name!r}; give one of them")
        args.rig = args.rig or name
        section = rig.get("zenoh", {})
        args.mode = args.mode or section.get("mode")
        args.connect = args.connect or list(section.get("connect", []))
        args.listen = args.listen or list(section.get("listen", []))
        args.no_scouting = args.no_scouting or section.get("multicast_scouting") is False
    if args.rig is None:
        parser.error("say which rig to listen to: --rig NAME (the [rig] name of its config) or --config RIG.toml")
    args.mode = args.mode or "peer"
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    import zenoh  # lazy: decode_fused must be importable (and testable) without zenoh installed

    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(args.mode))
    if args.connect:
        config.insert_json5("connect/endpoints", json.dumps(args.connect))
    if args.listen:
        config.insert_json5("listen/endpoints", json.dumps(args.listen))
    if args.no_scouting:
        config.insert_json5("scouting/multicast/enabled", "false")

    key = f"skelfuse/{args.rig}/fused/skeletons"
    received = 0
    done = threading.Event()

    def on_sample(sample: Any) -> None:
        nonlocal received
        try:
            frame = decode_fused(sample.payload.to_bytes())
        except (PayloadError, struct.error, UnicodeDecodeError, IndexError) as exc:
            print(f"rejected payload on {sample.key_expr}: {exc}", file=sys.stderr)
            return
        print(describe(frame), flush=True)
        received += 1
        if args.max_messages is not None and received >= args.max_messages:
            done.set()

    with zenoh.open(config) as session:
        session.declare_subscriber(key, on_sample)
        endpoints = "; ".join(
            f"{what} {', '.join(points)}"
            for what, points in (("connect", args.connect), ("listen", args.listen))
            if points
        )
        print(
            f"listening on {key} (zenoh {args.mode}, {endpoints or 'default endpoints'}, multicast scouting "
            f"{'off' if args.no_scouting else 'on'})",
            file=sys.stderr,
        )
        started = time.monotonic()
        deadline = None if args.duration is None else started + args.duration
        warned = False
        try:
            while not done.is_set():
                if not warned and received == 0 and time.monotonic() - started > SILENCE_WARNING_S:
                    warned = True
                    print(
                        f"nothing received on {key} after {SILENCE_WARNING_S:.0f} s: is the fusion node running, "
                        f"and is its rig {args.rig!r}? (`skelfuse status --config RIG.toml` shows what is up)",
                        file=sys.stderr,
                    )
                timeout = 0.2 if deadline is None else min(0.2, deadline - time.monotonic())
                if timeout <= 0:
                    break
                done.wait(timeout)
        except KeyboardInterrupt:
            pass
    print(f"received {received} fused frames", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
