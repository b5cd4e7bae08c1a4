"""The fused skeletons as OSC over UDP (TouchDesigner, Max/MSP, Unity/Unreal OSC receivers), via python-osc.

Address scheme (``docs/streaming.md``), ``<prefix>`` = ``[stream] osc_prefix`` (default ``/skelfuse``), one OSC
bundle per fused frame (time tag "immediately")::

    <prefix>/frame                                  h time_us, i n_persons, i frame counter
    <prefix>/persons                                i track id of each person (no argument: nobody)
    <prefix>/person/<track_id>/<joint>/position     f x, f y, f z        world frame, z up, in [stream] units
    <prefix>/person/<track_id>/<joint>/orientation  f w, f x, f y, f z   only where the fused frame carries one
    <prefix>/person/<track_id>/<joint>/confidence   i confidence (0..3), i n_agree, f position_std (mm; -1: none)
    <prefix>/person/<track_id>/agreement            f agreement_mm (-1: one view)  where the fused frame carries it

``<joint>`` is the k4abt joint name in lower case (``pelvis``, ``wrist_left``, ... ``ear_right``). A joint
without an estimate sends no ``position`` (a receiver keeps its last value) but still its ``confidence``
(n_agree 0). A frame whose bundle would be longer than :data:`MAX_DATAGRAM_BYTES` (8 KiB: more than one
person) is sent as one bundle with ``frame`` and ``persons`` followed by one bundle per person, in that order.

Encoding: python-osc's string and time-tag encoders build each address + type tag once (cached per track and
joint); the numbers are packed with :mod:`struct` (big-endian, as OSC 1.0 specifies). Building the messages
with python-osc's ``OscMessageBuilder`` cost about 10 ms per person per frame on this (loaded) machine, too
slow for a 30 Hz stream of several people; the tests decode every datagram with python-osc's parser.

:class:`OscSender` sends from a non-blocking UDP socket: a receiver that is gone, slow or refusing costs a
counted drop, never a wait.
"""

from __future__ import annotations

import functools
import socket
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np
from pythonosc.osc_bundle_builder import IMMEDIATELY
from pythonosc.parsing import osc_types

from skelfuse.schema.frames import FusedFrame
from skelfuse.schema.skeleton import JOINT_NAMES

DEFAULT_PREFIX = "/skelfuse"
MAX_DATAGRAM_BYTES = 8192
"""Largest datagram sent: many OSC receivers read into an 8 KiB buffer (python-osc's UDP server, several
Unity and Max receivers) and silently cut longer datagrams. One person's bundle is about 4.2 KiB (6 KiB with
orientations)."""
UNIT_SCALE = {"mm": 1.0, "m": 1e-3}
"""Position units OSC can send: millimetres (skelfuse's unit) or metres (most 3D engines)."""

JOINT_ADDRESS_NAMES = tuple(name.lower() for name in JOINT_NAMES)


_BUNDLE_HEAD = b"#bundle\x00" + osc_types.write_date(IMMEDIATELY)
_HEAD_CACHE_MAX = 100_000
_TAGS = {"position": ",fff", "orientation": ",ffff", "confidence": ",iif"}
_ARGS = {"position": struct.Struct(">fff"), "orientation": struct.Struct(">ffff"), "confidence": struct.Struct(">iif")}
_FRAME_ARGS = struct.Struct(">qii")
_AGREEMENT_ARGS = struct.Struct(">f")
_SIZE = struct.Struct(">i")


class _Heads:
    """Encoded address + type tag of every joint message, built with python-osc's own string encoding once
    per (prefix, track, joint, kind) and reused: the per-frame work is then only packing the numbers."""

    def __init__(self) -> None:
        self._cache: dict[tuple[str, int, int, str], bytes] = {}

    def __call__(self, prefix: str, track: int, joint: int, kind: str) -> bytes:
        key = (prefix, track, joint, kind)
        head = self._cache.get(key)
        if head is None:
            if len(self._cache) >= _HEAD_CACHE_MAX:  # track ids are never reused: forget old ones
                self._cache.clear()
            address = f"{prefix}/person/{track}/{JOINT_ADDRESS_NAMES[joint]}/{kind}"
            head = self._cache[key] = osc_types.write_string(address) + osc_types.write_string(_TAGS[kind])
        return head


_heads = _Heads()


@functools.lru_cache(maxsize=4096)
def _agreement_head(prefix: str, track: int) -> bytes:
    """Encoded address + type tag of a person's agreement message (track ids are never reused: old ones age out)."""
    return osc_types.write_string(f"{prefix}/person/{track}/agreement") + osc_types.write_string(",f")


def _bundle(messages: list[bytes]) -> bytes:
    return _BUNDLE_HEAD + b"".join(_SIZE.pack(len(m)) + m for m in messages)


def person_messages(frame: FusedFrame, p: int, *, prefix: str = DEFAULT_PREFIX, units: str = "mm") -> list[bytes]:
    """The OSC messages of person ``p`` of ``frame`` (position, orientation, confidence per joint), encoded."""
    scale = UNIT_SCALE[units]
    track = int(frame.track_ids[p])
    positions = np.asarray(frame.positions[p], np.float64) * scale
    has_position: list[bool] = np.asarray(np.isfinite(positions).all(axis=1)).tolist()
    orientations = getattr(frame, "orientations", None)
    quats = None if orientations is None else np.asarray(orientations[p], np.float64)
    has_quat: list[bool] = (
        [False] * len(JOINT_ADDRESS_NAMES) if quats is None else np.asarray(np.isfinite(quats).all(axis=1)).tolist()
    )
    quat_rows: list[list[float]] = [] if quats is None else quats.tolist()
    std = getattr(frame, "position_std", None)
    sigma = np.full(len(JOINT_ADDRESS_NAMES), -1.0) if std is None else np.asarray(std[p], np.float64)
    sigma = np.where(np.isfinite(sigma), sigma, -1.0).tolist()
    confidence = np.asarray(frame.confidence[p]).tolist()
    n_agree = np.asarray(frame.n_agree[p]).tolist()
    xyz = positions.tolist()
    out = []
    agreement = getattr(frame, "agreement_mm", None)
    if agreement is not None:
        figure = float(agreement[p])
        out.append(_agreement_head(prefix, track) + _AGREEMENT_ARGS.pack(figure if np.isfinite(figure) else -1.0))
    for j in range(len(JOINT_ADDRESS_NAMES)):
        if has_position[j]:
            out.append(_heads(prefix, track, j, "position") + _ARGS["position"].pack(*xyz[j]))
        if has_quat[j]:
            out.append(_heads(prefix, track, j, "orientation") + _ARGS["orientation"].pack(*quat_rows[j]))
        out.append(
            _heads(prefix, track, j, "confidence") + _ARGS["confidence"].pack(confidence[j], n_agree[j], sigma[j])
        )
    return out


def frame_bundles(
    frame: FusedFrame, *, counter: int = 0, prefix: str = DEFAULT_PREFIX, units: str = "mm"
) -> list[bytes]:
    """The datagrams of one fused frame: one bundle, or (past :data:`MAX_DATAGRAM_BYTES`) a header bundle and
    one bundle per person."""
    if units not in UNIT_SCALE:
        raise ValueError(f"OSC units must be one of {', '.join(UNIT_SCALE)}, got {units!r}")
    tracks = np.asarray(frame.track_ids).tolist()
    head = [
        osc_types.write_string(f"{prefix}/frame")
        + osc_types.write_string(",hii")
        + _FRAME_ARGS.pack(int(frame.time_us), frame.n_persons, counter & 0x7FFFFFFF),
        osc_types.write_string(f"{prefix}/persons")
        + osc_types.write_string("," + "i" * len(tracks))
        + struct.pack(f">{len(tracks)}i", *tracks),
    ]
    persons = [person_messages(frame, p, prefix=prefix, units=units) for p in range(frame.n_persons)]
    whole = _bundle(head + [m for person in persons for m in person])
    if len(whole) <= MAX_DATAGRAM_BYTES:
        return [whole]
    return [_bundle(head), *(_bundle(person) for person in persons)]


@dataclass
class SendStats:
    frames: int = 0
    datagrams: int = 0
    bytes: int = 0
    send_errors: int = 0
    last_error: str = ""


class UdpOut:
    """A non-blocking UDP socket to one receiver that counts what it sends: a failed send (no receiver, a full
    buffer) is counted in ``stats``, never raised or waited for, so a receiver that is gone never blocks fusion.
    The OSC and VMC senders share it."""

    def __init__(self, host: str, port: int) -> None:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)  # resolved once, here
        family, _, _, _, sockaddr = infos[0]
        self.address: tuple[Any, ...] = sockaddr
        self._socket = socket.socket(family, socket.SOCK_DGRAM)
        self._socket.setblocking(False)
        self.stats = SendStats()

    def send(self, dgram: bytes) -> None:
        try:
            self._socket.sendto(dgram, self.address)
        except OSError as exc:  # BlockingIOError (buffer full), ConnectionRefusedError (ICMP from a gone port)
            self.stats.send_errors += 1
            self.stats.last_error = f"{type(exc).__name__}: {exc}"
            return
        self.stats.datagrams += 1
        self.stats.bytes += len(dgram)

    def close(self) -> None:
        self._socket.close()

    def url(self) -> str:
        return f"udp://{self.address[0]}:{self.address[1]}"


class OscSender:
    """Send each fused frame as OSC bundles to ``host:port`` over a non-blocking UDP socket.

    Parameters
    ----------
    host, port : the receiver (resolved once, here)
    prefix : str
        First part of every address; must start with ``/``.
    units : {"mm", "m"}
    """

    def __init__(self, host: str, port: int, *, prefix: str = DEFAULT_PREFIX, units: str = "mm") -> None:
        if not prefix.startswith("/") or prefix.endswith("/") or " " in prefix or "#" in prefix:
            raise ValueError(f"OSC prefix must start with '/', not end with '/', and hold no space or '#': {prefix!r}")
        if units not in UNIT_SCALE:
            raise ValueError(f"OSC units must be one of {', '.join(UNIT_SCALE)}, got {units!r}")
        self.prefix = prefix
        self.units = units
        self._out = UdpOut(host, port)
        self.stats = self._out.stats
        self.address = self._out.address

    def send(self, frame: FusedFrame) -> None:
        """Send one frame; a failed send (no receiver, full buffer) is counted, never raised or waited for."""
        for dgram in frame_bundles(frame, counter=self.stats.frames, prefix=self.prefix, units=self.units):
            self._out.send(dgram)
        self.stats.frames += 1

    def close(self) -> None:
        self._out.close()

    def describe(self) -> str:
        return f"OSC to {self._out.url()}{self.prefix} ({self.units})"
