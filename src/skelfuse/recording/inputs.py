"""One door for every recording: open ``[ID=]PATH`` inputs of any known format and match their frames in time.

Every command that accepts a recording (``fuse --input``, ``replay``, ``[[sensors]] source = "replay"``,
``calibrate skeleton``, ``eval real``, ``convert``) goes through :func:`open_inputs`. Cycle::

    take = open_inputs(["master=m.json", "sub=s.json"], assume_confidence="medium")
    for note in take.notes: print(note)              # what was assumed, how frames were matched
    for group in take.groups(sync): ...              # one FrameGroup per instant (rig.grouping.FrameGrouper)

Formats (:mod:`skelfuse.sources.formats`): skelfuse MCAP (read here, with its host times, sequence numbers
and calibration metadata), Azure Kinect ``.mkv`` (through the SDK), offline_processor JSON,
azure-kinect-mkv-extractor CSV folders, andyj1 CSV and the long CSV (one file, several sensors).

Time matching (docs/recordings.md):

* **Device clock, shared** (one hardware sync chain; the default when the files' time ranges overlap):
  frames are matched on their device timestamps by :class:`~skelfuse.rig.grouping.FrameGrouper` within the
  ``[sync]`` tolerance (10 ms by default, which covers the subordinates' depth delays of up to ~1 ms),
  whatever frame each file starts at.
* **Device clocks differ** (ranges that do not overlap, or ``clock="independent"``): each sensor's offset
  to the first sensor is estimated from the person's motion (:mod:`skelfuse.rig.motion_sync`), reported
  with its score and ambiguity, and applied; ``time_offsets_ms`` overrides it per sensor.
* **Host clock** (``by="host"``): the recorded host receive time (MCAP only; other formats have none and
  use their device time).
* **Index** (a file without timestamps, e.g. andyj1 CSV): frame k of every file is one instant; the notes
  say so.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.config import SyncConfig
from skelfuse.recording.mcap_io import RecordedFrame, RecordingReader, RecordingWriter
from skelfuse.rig.grouping import FrameGroup, FrameGrouper
from skelfuse.rig.motion_sync import LagEstimate, band_pass, estimate_lag, grid_features, motion_features
from skelfuse.schema.errors import DataError
from skelfuse.schema.frames import SensorFrame
from skelfuse.schema.skeleton import N_JOINTS
from skelfuse.sources.formats import FORMATS, InputSpec, detect_format, load_sensor_file
from skelfuse.sources.recorded import FRAME_PERIOD_US, Recording, _pad_bodies, assumed_confidence_level
from skelfuse.wire import keys
from skelfuse.wire.codec import encode_sensor_frame

CLOCK_MODES = ("auto", "shared", "independent")
"""How the device clocks of the inputs relate: decide from the time ranges, one sync chain, or unrelated."""


@dataclass(frozen=True)
class OffsetEstimate:
    """A sensor's clock offset to the reference sensor, estimated from the motion.

    ``offset_us`` is added to the sensor's times. ``estimate`` holds the score and the candidate shifts.
    """

    sensor_id: str
    reference: str
    offset_us: int
    estimate: LagEstimate

    def describe(self) -> str:
        e = self.estimate
        if not e.found:
            return (
                f"{self.sensor_id}: no clock offset could be estimated from the motion against {self.reference} "
                "(too little common motion); pass --time-offset"
            )
        text = (
            f"{self.sensor_id}: clock offset {self.offset_us / 1000:+.1f} ms to {self.reference}, estimated from "
            f"the motion (correlation {e.correlation:.2f} over {e.overlap} frames)"
        )
        if e.ambiguous:
            text += (
                f"; AMBIGUOUS: other shifts score almost as well ({', '.join(f'{p:+d}' for p in e.peaks[1:])} "
                "frames, periodic motion): check it, or pass --time-offset"
            )
        return text


@dataclass
class InputTake:
    """The opened inputs: one :class:`Recording` per sensor, and how their frames are matched in time.

    Attributes
    ----------
    recordings : one per sensor, in input order, times as recorded.
    clock : "device", "host" or "index": the time frames are matched on.
    offsets_us : per sensor, added to its times before matching (0 where none).
    estimates : per sensor, the motion-based offset estimate where one was made.
    notes : what the user must hear (assumed confidence, how frames were matched, estimates).
    poses : world_from_sensor per sensor where known (an MCAP's calibration metadata, or identity for
        ``registered`` inputs), else empty.
    registered : the poses are already in one frame (e.g. the andyj1 subordinates).
    formats : per sensor, the format it was read as.
    period_us : the nominal frame interval used for index matching and motion grids.
    """

    recordings: tuple[Recording, ...]
    clock: str
    offsets_us: dict[str, int]
    estimates: dict[str, OffsetEstimate] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    poses: dict[str, np.ndarray] = field(default_factory=dict)
    registered: bool = False
    formats: dict[str, str] = field(default_factory=dict)
    period_us: float = float(FRAME_PERIOD_US)

    @property
    def sensor_ids(self) -> tuple[str, ...]:
        return tuple(r.sensor_id for r in self.recordings)

    @property
    def confidence_assumed(self) -> dict[str, str | None]:
        """Per sensor: None where the file stores confidence, else what was assumed."""
        return {r.sensor_id: r.confidence_assumed for r in self.recordings}

    @property
    def confidence_unknown(self) -> bool:
        """True when some sensor's confidence is not from its file: MEDIUM-based metrics mean little."""
        return any(r.confidence_assumed is not None for r in self.recordings)

    def match_times_us(self, recording: Recording) -> np.ndarray:
        """(T,) the times ``recording``'s frames are matched on, offset applied."""
        if self.clock == "index":
            times = np.arange(recording.n_frames, dtype=np.int64) * round(self.period_us)
        elif self.clock == "host" and recording.host_time_ns is not None:
            times = recording.host_time_ns // 1000
        else:
            times = recording.frame_times_us(round(self.period_us))
        return times + int(self.offsets_us.get(recording.sensor_id, 0))

    def frames(self) -> Iterator[SensorFrame]:
        """Every frame of every sensor in matching-time order, its device (and host) time on the matched clock.

        Device times are replaced by the matching time (offset applied; the frame index times the period
        for index matching), so that any consumer groups them correctly. A recorded host time (MCAP) is kept
        (shifted by the sensor's offset); files without one get the matching time.
        """
        streams = []
        for order, recording in enumerate(self.recordings):
            times = self.match_times_us(recording)
            streams.append((times, order, recording))
        keyed = [(int(t), order, k) for times, order, _ in streams for k, t in enumerate(times)]
        keyed.sort()
        cache: dict[int, list[SensorFrame]] = {}
        for t, order, k in keyed:
            recording = streams[order][2]
            if order not in cache:
                cache[order] = list(recording.frames(round(self.period_us)))
            frame = cache[order][k]
            offset = int(self.offsets_us.get(recording.sensor_id, 0))
            if self.clock == "host":
                yield replace(
                    frame,
                    device_time_us=frame.device_time_us + offset,
                    host_time_ns=int(frame.host_time_ns) + offset * 1000,
                )
                continue
            # a recorded host time (MCAP) is kept, shifted with the offset; files without one get the match time
            host_ns = t * 1000 if recording.host_time_ns is None else int(frame.host_time_ns) + offset * 1000
            yield replace(frame, device_time_us=t, host_time_ns=host_ns)

    def records(self, rig: str) -> Iterator[RecordedFrame]:
        """The frames as :class:`RecordedFrame` envelopes for a replay: the sensor key of ``rig`` as topic,
        the matching time as log time, the encoded wire payload (docs/wire-format.md)."""
        for frame in self.frames():
            log_ns = int(frame.host_time_ns) if self.clock == "host" else int(frame.device_time_us) * 1000
            yield RecordedFrame(
                topic=keys.sensor_skeletons(rig, frame.sensor_id),
                sensor_id=frame.sensor_id,
                log_time_ns=log_ns,
                publish_time_ns=int(frame.device_time_us) * 1000,
                payload=encode_sensor_frame(frame),
                frame=frame,
            )

    def grouper(
        self, sync: SyncConfig | None = None, *, tolerance_us: int | None = None, deadline_us: int | None = None
    ) -> FrameGrouper:
        """A :class:`FrameGrouper` over the take's sensors on its matching clock (``[sync]`` tolerances)."""
        sync = sync if sync is not None else SyncConfig()
        return FrameGrouper.from_sync(
            self.sensor_ids,
            sync,
            by="host" if self.clock == "host" else "device",
            tolerance_us=tolerance_us,
            deadline_us=deadline_us,
        )

    def groups(self, sync: SyncConfig | None = None, *, tolerance_us: int | None = None) -> Iterator[FrameGroup]:
        """One :class:`FrameGroup` per instant, frames matched by :meth:`grouper` (the matching time is
        the arrival clock: files are read in time order, so every group completes or is passed)."""
        grouper = self.grouper(sync, tolerance_us=tolerance_us)
        for frame in self.frames():
            now_ns = int(frame.host_time_ns) if self.clock == "host" else int(frame.device_time_us) * 1000
            yield from grouper.push(frame, now_ns)
        yield from grouper.flush()

    def describe(self) -> str:
        """A few lines for stderr: the sensors, their formats and frame counts, and every note."""
        lines = [
            f"inputs: {len(self.recordings)} sensor(s): "
            + ", ".join(
                f"{r.sensor_id} ({self.formats.get(r.sensor_id, r.file_format)}, {r.n_frames} frames)"
                for r in self.recordings
            )
        ]
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)


# ------------------------------------------------------------------------------------------------ reading


def read_mcap(path: Path, *, sensor_id: str | None = None) -> tuple[list[Recording], dict[str, np.ndarray]]:
    """A skelfuse MCAP as one :class:`Recording` per sensor (host times and sequences kept) and its poses."""
    reader = RecordingReader(path)
    reader.require_sensors("record one with `skelfuse record`")
    if sensor_id is not None and len(reader.sensors) > 1:
        raise DataError(
            f"{path}: holds sensors {', '.join(reader.sensors)}; an ID=PATH spec renames a one-sensor file only"
        )
    per: dict[str, list[SensorFrame]] = {s: [] for s in reader.sensors}
    for frame in reader.frames():
        per[frame.sensor_id].append(frame)
    meta = reader.metadata
    assumed = {}
    try:
        assumed = json.loads(meta.get("confidence_assumed", "{}"))
    except json.JSONDecodeError:
        assumed = {}
    out = []
    for sid, frames in per.items():
        frames.sort(key=lambda f: (f.device_time_us, f.sequence))
        bodies = [
            [(int(b), f.positions[i], f.orientations[i], f.confidence[i]) for i, b in enumerate(f.body_ids)]
            for f in frames
        ]
        positions, orientations, confidence, body_ids = _pad_bodies(bodies)
        name = sensor_id or sid
        out.append(
            Recording(
                sensor_id=name,
                positions=positions,
                orientations=orientations,
                confidence=confidence,
                body_ids=body_ids,
                device_time_us=np.asarray([f.device_time_us for f in frames], dtype=np.int64),
                source=str(path),
                host_time_ns=np.asarray([f.host_time_ns for f in frames], dtype=np.int64),
                sequences=np.asarray([f.sequence for f in frames], dtype=np.int64),
                confidence_assumed=assumed.get(sid) if isinstance(assumed, dict) else None,
                file_format="mcap",
                notes=(f"{sum(reader.rejects.values())} unreadable messages skipped",) if reader.rejects else (),
            )
        )
    poses = {}
    if reader.calibration:
        poses = {(sensor_id or s): np.asarray(p) for s, p in reader.calibration.items() if s in per}
    if meta.get("time_matching") == "index":
        out = [replace(r, device_time_us=None) for r in out]
    return out, poses


def _overlap_fraction(a: np.ndarray, b: np.ndarray) -> float:
    """Fraction of the shorter time range that the two ranges share (0 when disjoint)."""
    lo, hi = max(a.min(), b.min()), min(a.max(), b.max())
    shorter = min(a.max() - a.min(), b.max() - b.min())
    if hi < lo:
        return 0.0
    return float((hi - lo) / shorter) if shorter > 0 else 1.0


def _first_body_features(recording: Recording, times_us: np.ndarray, period_us: float) -> np.ndarray:
    pos = (
        recording.positions[:, 0].astype(np.float64)
        if recording.max_bodies
        else np.full((recording.n_frames, N_JOINTS, 3), np.nan)
    )
    return band_pass(grid_features(times_us, motion_features(pos), period_us).values)


def estimate_offset(
    reference: Recording, other: Recording, *, period_us: float = FRAME_PERIOD_US, max_lag: int | None = None
) -> OffsetEstimate:
    """``other``'s clock offset to ``reference`` (µs, to add to ``other``'s times) from the motion (first body)."""
    ta, tb = reference.frame_times_us(round(period_us)), other.frame_times_us(round(period_us))
    a = _first_body_features(reference, ta, period_us)
    b = _first_body_features(other, tb, period_us)
    est = estimate_lag(a, b, max_lag=max_lag)
    offset = int(ta.min() - tb.min() - round(est.lag * period_us)) if est.found else 0
    return OffsetEstimate(other.sensor_id, reference.sensor_id, offset, est)


def parse_time_offsets(items: Iterable[str]) -> dict[str, float]:
    """``ID=MS`` strings (``--time-offset``) -> {sensor id: milliseconds}; DataError naming a bad one."""
    out: dict[str, float] = {}
    for item in items:
        sensor_id, sep, value = item.partition("=")
        try:
            if not sep or not sensor_id:
                raise ValueError
            out[sensor_id] = float(value)
        except ValueError:
            raise DataError(
                f"--time-offset {item!r}: expected ID=MILLISECONDS (added to that sensor's times), e.g. sub=-1900"
            ) from None
    return out


def single_recorded_mcap(specs: Sequence[str]) -> bool:
    """True when ``specs`` is one plain path to a skelfuse MCAP (no ``ID=``): such a recording is fused on its
    recorded host arrival times, exactly as live, rather than opened as a take."""
    if len(specs) != 1:
        return False
    spec = InputSpec.parse(specs[0])
    return spec.sensor_id is None and spec.path.is_file() and detect_format(spec.path) == "mcap"


def open_inputs(
    specs: Sequence[str | InputSpec],
    *,
    fmt: str | None = None,
    assume_confidence: str = "medium",
    by: str = "device",
    clock: str = "auto",
    time_offsets_ms: Mapping[str, float] | None = None,
    registered: bool = False,
    fps: float = 30.0,
) -> InputTake:
    """Open every input and decide how their frames are matched in time (see the module docstring).

    Parameters
    ----------
    specs : ``PATH`` or ``ID=PATH`` strings (or :class:`InputSpec`); one path may hold several sensors
        (MCAP, long CSV).
    fmt : force a format (:data:`FORMATS`); None detects each file's.
    assume_confidence : "medium", "low" or "unknown", for files that store no confidence.
    by : "device" or "host" (host needs MCAP inputs).
    clock : "auto", "shared" or "independent" (:data:`CLOCK_MODES`).
    time_offsets_ms : per sensor, milliseconds added to its times (overrides any estimate).
    registered : every input's poses are already in one frame: identity poses.
    fps : nominal frame rate (index matching, motion grids).

    Raises
    ------
    DataError
        A missing or malformed file (naming the file, line or frame and the fix), an unknown format, a
        sensor given twice, an offset for an unknown sensor, no input.
    """
    if not specs:
        raise DataError("no input given; pass one recording (MCAP, long CSV) or one file per sensor")
    _check_options(fmt=fmt, clock=clock, by=by, assume_confidence=assume_confidence)
    period_us = 1e6 / fps
    recordings, formats, poses = _read_recordings(specs, fmt=fmt, assume_confidence=assume_confidence)
    notes = _recording_notes(recordings)
    ids = [r.sensor_id for r in recordings]
    offsets_ms = dict(time_offsets_ms or {})
    unknown = sorted(set(offsets_ms) - set(ids))
    if unknown:
        raise DataError(f"--time-offset for unknown sensor(s) {', '.join(unknown)}; the inputs hold {', '.join(ids)}")
    offsets_us = {sid: round(ms * 1000) for sid, ms in offsets_ms.items()}
    take = InputTake(
        tuple(recordings),
        "device",
        offsets_us,
        notes=notes,
        poses=poses,
        registered=registered,
        formats=formats,
        period_us=period_us,
    )
    if registered:
        take.poses = {sid: np.eye(4) for sid in ids}
        notes.append("poses given as already in one frame (--registered): identity world_from_sensor for every sensor")

    without = [r.sensor_id for r in recordings if not r.has_timestamps]
    if without:
        take.clock = "index"
        why = "their files hold no timestamps" if len(without) == len(ids) else f"{', '.join(without)} hold(s) none"
        notes.append(
            f"frames matched by INDEX (frame k of every file is one instant): {why}; if the files do not start at "
            "the same instant, pass --time-offset ID=MS (multiples of one frame)"
        )
        return take
    if by == "host":
        no_host = [r.sensor_id for r in recordings if r.host_time_ns is None]
        if no_host:
            notes.append(f"{', '.join(no_host)}: no host times in the file(s); their device times are used instead")
        take.clock = "host"
        notes.append("frames matched by host receive time (by = host)")
        return take

    _match_device_clocks(take, clock=clock, explicit_ms=offsets_ms)
    return take


def _check_options(*, fmt: str | None, clock: str, by: str, assume_confidence: str) -> None:
    """Refuse an unknown format, clock mode, matching clock or confidence level before any file is read."""
    if fmt is not None and fmt not in FORMATS:
        raise DataError(f"unknown format {fmt!r}; known: {', '.join(FORMATS)}")
    if clock not in CLOCK_MODES:
        raise DataError(f"unknown clock mode {clock!r}; known: {', '.join(CLOCK_MODES)}")
    if by not in ("device", "host"):
        raise DataError(f"unknown matching clock {by!r}; use device or host")
    assumed_confidence_level(assume_confidence)  # validates


def _read_recordings(
    specs: Sequence[str | InputSpec], *, fmt: str | None, assume_confidence: str
) -> tuple[list[Recording], dict[str, str], dict[str, np.ndarray]]:
    """Every sensor's recording in the inputs, with its file's format and the poses the files store."""
    recordings: list[Recording] = []
    formats: dict[str, str] = {}
    poses: dict[str, np.ndarray] = {}
    for raw in specs:
        spec = raw if isinstance(raw, InputSpec) else InputSpec.parse(str(raw))
        kind = fmt or detect_format(spec.path)
        if kind == "mcap":
            got, mcap_poses = read_mcap(spec.path, sensor_id=spec.sensor_id)
            poses.update(mcap_poses)
        else:
            got = load_sensor_file(spec, fmt=kind, assume_confidence=assume_confidence)
        for recording in got:
            if recording.sensor_id in formats:
                raise DataError(
                    f"sensor {recording.sensor_id!r} comes twice (again from {spec.path}); give each sensor once, "
                    "naming files with ID=PATH where their names clash"
                )
            formats[recording.sensor_id] = kind
            recordings.append(recording)
    return recordings, formats, poses


def _recording_notes(recordings: Sequence[Recording]) -> list[str]:
    """The loaders' notes and the confidence assumed where files store none; refuses a sensor with no frames."""
    notes: list[str] = []
    for r in recordings:
        notes += [f"{r.sensor_id}: {n}" for n in r.notes]
        if r.n_frames == 0:
            raise DataError(f"{r.source}: sensor {r.sensor_id!r} holds no frames")
    assumed = {r.sensor_id: r.confidence_assumed for r in recordings if r.confidence_assumed is not None}
    if assumed:
        levels = sorted(set(assumed.values()))
        notes.append(
            f"no confidence in the file(s) of {', '.join(assumed)}: assumed {' / '.join(levels)} for every joint "
            "(--assume-confidence); metrics that rely on MEDIUM confidence are "
            + ("meaningless for them" if "unknown" in levels or "low" in levels else "only as good as that guess")
        )
    return notes


def _match_device_clocks(take: InputTake, *, clock: str, explicit_ms: Mapping[str, float]) -> None:
    """Matching by device time: per sensor after the first, share its clock or estimate the offset; ``take``'s
    offsets, estimates and notes are updated in place (``explicit_ms``: the offsets the user gave)."""
    recordings, notes, offsets_us = take.recordings, take.notes, take.offsets_us
    ids = [r.sensor_id for r in recordings]
    if len(recordings) < 2:
        return
    reference = recordings[0]
    ref_times = reference.frame_times_us()
    for other in recordings[1:]:
        sid = other.sensor_id
        if sid in offsets_us:
            notes.append(f"{sid}: times shifted by {offsets_us[sid] / 1000:+.1f} ms (--time-offset)")
            continue
        times = other.frame_times_us()
        shares = _overlap_fraction(ref_times, times) > 0.0
        if clock == "shared" or (clock == "auto" and shares):
            continue
        estimate = estimate_offset(reference, other, period_us=take.period_us)
        take.estimates[sid] = estimate
        offsets_us[sid] = estimate.offset_us
        notes.append(estimate.describe())
    matched = [s for s in ids[1:] if s not in take.estimates and s not in explicit_ms]
    if matched:
        notes.append(
            f"frames matched by device timestamp ({', '.join([ids[0], *matched])} share one clock"
            + (", their time ranges overlap" if clock == "auto" else "")
            + "), whatever frame each file starts at"
        )


# ------------------------------------------------------------------------------------------------ writing


def write_mcap(
    take: InputTake,
    output: str | Path,
    *,
    rig: str = "converted",
    world_from_sensor: Mapping[str, Any] | None = None,
    extra_metadata: Mapping[str, str] | None = None,
) -> int:
    """Write the take's frames (times as matched: offsets applied) to a skelfuse MCAP. Returns frames written.

    Metadata records the sources, formats, the matching clock and offsets, and the assumed confidence per
    sensor (read back by :func:`read_mcap`).
    """
    for sid in take.sensor_ids:
        try:
            keys.validate_name(sid, "sensor")
        except ValueError as exc:
            raise DataError(f"sensor id {sid!r} cannot name an MCAP channel ({exc}); rename it with ID=PATH") from None
    poses = dict(world_from_sensor) if world_from_sensor is not None else dict(take.poses)
    metadata = {
        "sources": json.dumps({r.sensor_id: r.source for r in take.recordings}),
        "formats": json.dumps(take.formats),
        "time_matching": take.clock,
        "time_offsets_us": json.dumps(take.offsets_us),
        "confidence_assumed": json.dumps({k: v for k, v in take.confidence_assumed.items() if v is not None}),
        **dict(extra_metadata or {}),
    }
    n = 0
    with RecordingWriter(
        output,
        rig=rig,
        sensor_ids=take.sensor_ids,
        metadata=metadata,
        world_from_sensor=poses or None,
        flush_interval_s=None,
    ) as writer:
        for frame in take.frames():
            writer.write(frame)
            n += 1
    return n
