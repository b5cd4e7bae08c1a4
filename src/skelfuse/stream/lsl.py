"""The fused skeletons as a Lab Streaming Layer stream, so labs record them in sync with EEG, EMG, eye trackers.

One LSL stream (type ``Mocap``, float32, nominal rate = the rig's ``[sync] fps``) with a fixed number of
person *slots* (``[stream] lsl_max_persons``): an LSL stream has a fixed channel count, a scene does not. Per
slot: ``track_id`` (-1 when the slot is empty), then per k4abt joint ``x y z`` (mm, world frame, z up),
``qw qx qy qz`` (fused orientation, NaN where unknown or not carried) and ``confidence`` (0..3): 1 + 32 x 8
channels. A person keeps its slot while it is tracked; a new person takes the lowest free slot; people beyond
the slots are left out and counted. A missing joint, an empty slot's joints: NaN. Each sample is stamped with
LSL's clock at the moment it is pushed (``pylsl.local_clock()``); LSL's own time sync maps it onto every
recorder's clock. The channel metadata (``desc/channels``) follows the XDF meta-data conventions for motion
capture: ``label``, ``marker`` (the joint), ``type`` (``PositionX``, ``OrientationW``, ``Confidence``, ...),
``unit``; ``desc/skelfuse`` says the frame, units and joint order.

pylsl's wheels bundle liblsl on Linux x86_64, macOS and Windows; elsewhere liblsl must be installed
(``conda install -c conda-forge liblsl`` or the release packages of sccn/liblsl). :func:`load_pylsl` says so.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from skelfuse.schema.errors import ConfigError
from skelfuse.schema.frames import FusedFrame
from skelfuse.schema.skeleton import JOINT_NAMES, N_JOINTS

PER_JOINT = (
    ("x", "PositionX", "millimeters"),
    ("y", "PositionY", "millimeters"),
    ("z", "PositionZ", "millimeters"),
    ("qw", "OrientationW", "normalized"),
    ("qx", "OrientationX", "normalized"),
    ("qy", "OrientationY", "normalized"),
    ("qz", "OrientationZ", "normalized"),
    ("confidence", "Confidence", "level 0..3"),
)
"""Channels of each joint: suffix, XDF type, unit."""
CHANNELS_PER_PERSON = 1 + N_JOINTS * len(PER_JOINT)


def load_pylsl() -> Any:
    """Import pylsl, or raise ConfigError saying how to get it and its liblsl."""
    try:
        import pylsl
    except ImportError:
        raise ConfigError("streaming to LSL needs pylsl: pip install 'skelfuse[lsl]' (or pip install pylsl)") from None
    except (RuntimeError, OSError) as exc:  # pylsl is there but liblsl is not: it raises at import
        raise ConfigError(
            f"pylsl cannot load liblsl ({exc}); its wheels bundle liblsl on Linux x86_64, macOS and Windows, "
            f"elsewhere install liblsl (conda install -c conda-forge liblsl, or a release of sccn/liblsl)"
        ) from None
    return pylsl


def channel_labels(max_persons: int) -> list[str]:
    """Channel labels in stream order: ``p0_track_id``, ``p0_PELVIS_x`` ... ``p<n-1>_EAR_RIGHT_confidence``."""
    labels = []
    for slot in range(max_persons):
        labels.append(f"p{slot}_track_id")
        labels += [f"p{slot}_{joint}_{suffix}" for joint in JOINT_NAMES for suffix, _, _ in PER_JOINT]
    return labels


def frame_sample(frame: FusedFrame, slots: list[int | None]) -> np.ndarray:
    """The LSL sample of ``frame`` for the given slot occupancy (track id per slot, None = empty)."""
    sample = np.full((len(slots), CHANNELS_PER_PERSON), np.nan, np.float32)
    row_of = {int(t): p for p, t in enumerate(np.asarray(frame.track_ids).tolist())}
    orientations = getattr(frame, "orientations", None)
    for slot, track in enumerate(slots):
        if track is None or track not in row_of:
            sample[slot, 0] = -1.0
            continue
        p = row_of[track]
        joints = np.full((N_JOINTS, len(PER_JOINT)), np.nan)
        joints[:, 0:3] = frame.positions[p]
        if orientations is not None:
            joints[:, 3:7] = orientations[p]
        joints[:, 7] = frame.confidence[p]
        sample[slot, 0] = track
        sample[slot, 1:] = joints.reshape(-1)
    return sample.reshape(-1)


@dataclass
class LslStats:
    frames: int = 0
    persons_left_out: int = 0


class SlotMap:
    """Stable person -> slot assignment: a tracked person keeps its slot, a new one takes the lowest free."""

    def __init__(self, n_slots: int) -> None:
        self.slots: list[int | None] = [None] * n_slots

    def update(self, track_ids: list[int]) -> int:
        """Assign slots for the persons of one frame; returns how many did not get one."""
        present = set(track_ids)
        self.slots = [t if t in present else None for t in self.slots]
        held = {t for t in self.slots if t is not None}
        left_out = 0
        for track in sorted(present - held):
            try:
                self.slots[self.slots.index(None)] = track
            except ValueError:
                left_out += 1
        return left_out


class LslOutlet:
    """An LSL outlet that carries the fused skeletons (see the module docstring).

    Parameters
    ----------
    name : str
        LSL stream name (what LabRecorder lists).
    source_id : str
        Unique and stable per rig, so a recorder reconnects to the same stream after a restart.
    max_persons : int
        Person slots.
    rate_hz : float
        Nominal sampling rate (the rig's fps).
    rig : str
        Written into the stream's metadata.
    """

    def __init__(self, *, name: str, source_id: str, max_persons: int, rate_hz: float, rig: str = "") -> None:
        if max_persons < 1:
            raise ConfigError(f"LSL needs at least 1 person slot, got {max_persons}")
        pylsl = load_pylsl()
        self._pylsl = pylsl
        info = pylsl.StreamInfo(name, "Mocap", max_persons * CHANNELS_PER_PERSON, rate_hz, pylsl.cf_float32, source_id)
        desc = info.desc()
        desc.append_child_value("manufacturer", "skelfuse")
        meta = desc.append_child("skelfuse")
        meta.append_child_value("rig", rig)
        meta.append_child_value("frame", "world, right-handed, z up (origin and axes from calibration)")
        meta.append_child_value("units", "mm")
        meta.append_child_value("quaternion", "w x y z, k4abt joint-axis convention")
        meta.append_child_value("joints", " ".join(JOINT_NAMES))
        meta.append_child_value("persons", str(max_persons))
        channels = desc.append_child("channels")
        for slot in range(max_persons):
            channel = channels.append_child("channel")
            channel.append_child_value("label", f"p{slot}_track_id")
            channel.append_child_value("type", "TrackId")
            channel.append_child_value("unit", "id")
            for joint in JOINT_NAMES:
                for suffix, kind, unit in PER_JOINT:
                    channel = channels.append_child("channel")
                    channel.append_child_value("label", f"p{slot}_{joint}_{suffix}")
                    channel.append_child_value("marker", joint)
                    channel.append_child_value("type", kind)
                    channel.append_child_value("unit", unit)
        self._outlet = pylsl.StreamOutlet(info)
        self._slots = SlotMap(max_persons)
        self.name = name
        self.source_id = source_id
        self.stats = LslStats()

    def send(self, frame: FusedFrame) -> None:
        """Push one sample (LSL buffers it for its inlets; never blocks on a slow or absent recorder)."""
        self.stats.persons_left_out += self._slots.update([int(t) for t in np.asarray(frame.track_ids).tolist()])
        self._outlet.push_sample(frame_sample(frame, self._slots.slots).tolist(), self._pylsl.local_clock())
        self.stats.frames += 1

    def close(self) -> None:
        del self._outlet

    def describe(self) -> str:
        return f"LSL stream {self.name!r} (source_id {self.source_id})"
