"""Grouping sensor frames of one instant: pure logic, no clocks, no threads (time is passed in).

The fusion node receives the sensors' frames one by one, in whatever order the network delivers them, and
must hand the fusion core one set of frames per instant. :class:`FrameGrouper` does that. Cycle::

    for each received frame:   groups = grouper.push(frame, now_ns)      # may emit groups
    on a timer (e.g. 5 ms):    groups = grouper.poll(now_ns)             # emits groups whose deadline passed
    at shutdown:               groups = grouper.flush()                  # emits everything still open

Which clock groups frames (``by``):

* ``"device"``: the device timestamp ``device_time_us``. Only meaningful with wired hardware sync: synced
  Azure Kinects share the master's clock, and a subordinate's timestamp sits its configured depth delay
  (160 µs to ~1 ms) after the master's. Independent devices' clocks do not share an epoch.
* ``"host"``: the host receive time ``host_time_ns`` (rigs without sync cables). It carries USB and
  body-tracking latency jitter of a few ms, so the tolerance must cover that.

Rules
-----
Membership
    A frame joins the open group whose *anchor* (the time of the group's first frame) is nearest to the
    frame's time, if it lies within ``tolerance_us``; otherwise it opens a new group. With the tolerance
    below half a frame period (checked) consecutive instants never share a group.
Emission
    A group is *ready* when every expected sensor either has a frame in it or has already delivered a frame
    of a later instant (time beyond the group's window): frames of one sensor arrive in time order, so the
    missing frame can no longer come. A complete group is therefore emitted on its last frame, and a group
    whose sensor dropped that one frame is emitted as soon as the sensor's next frame arrives. Otherwise the
    group is emitted when its deadline passes: ``deadline_us`` after the arrival (``now_ns``) of its first
    frame, so a dead or slow sensor never stalls the output. Groups are emitted in time order, each once:
    when a later group is due, every older open group is emitted before it, as it is.
``FrameGroup.time_us``
    The earliest frame time in the group (in device mode the master's timestamp when the master is in it).
    Emitted ``time_us`` strictly increase within one clock epoch (see below).
Late frames
    A frame whose time is not after the last emitted group's window belongs to an instant already emitted:
    it is counted as ``late`` and dropped; it never re-opens an emitted instant.
Duplicates
    A second frame of one sensor for one group: the first is kept, the second counted as ``duplicate``.
Drops
    Sequence gaps per sensor (``sequence`` jumping by more than one) are counted as ``dropped``; a sequence
    going backwards (a restarted sensor or a looped replay), or jumping further than the resync horizon's
    worth of frames, restarts the count for that sensor (a forged sequence cannot inflate ``dropped``).
Unknown sensors
    Frames of a sensor not in ``expected_sensor_ids`` are counted in ``unknown`` and ignored.
Clock resets (resync rule)
    A frame whose time lies more than ``resync_horizon_us`` (default 1 s) from the newest frame time seen is
    *out of window*: a sensor restarted with a new clock epoch, a replay looped, a clock jumped. It is held
    back. If an in-window frame arrives next, the held-back frames are counted as ``out_of_window`` and
    dropped: one sensor on a foreign clock is ignored while the others go on (it shows as missing). If
    ``resync_after`` consecutive frames are out of window (from two sensors or more when the epoch knew
    two), the whole rig has moved to a new epoch: the
    grouper emits every open group, forgets its time state (a new epoch begins, ``resyncs`` counts it) and
    replays the held-back frames into the new epoch, so none is lost. ``time_us`` may jump backwards across
    a resync, never within an epoch.

Sensor clocks (:class:`SensorClock`, one per sensor)
    Every frame's time is compared with its arrival (``now_ns``, the node's clock): the residual ``time -
    arrival`` of one sensor is steady (its clock's offset from the node's plus a latency), so each sensor's
    offset (a running median) and drift (a slope) are estimated online, from that sensor's frames only. A frame
    whose residual lies more than ``max_ahead_us`` ahead of (in the future of) the largest recent residual of
    its sensor (its fastest delivery, forgotten at 1 ms/s: a frame cannot beat its path's shortest latency,
    while a backlog only makes frames late), or more than ``max_behind_us`` behind its offset, is *off clock*: a
    peer stamping frames in the future or the past, a clock that stepped. So is a frame stamped more than
    ``max_ahead_us`` before the sensor's previous learned frames (the median of the last three: a sensor's
    frames come in order, so a second stream that lags the learned one is not this clock). It is held back by
    its sensor's clock and never reaches the grouping windows or counters above. Held frames are sorted into
    *candidate clocks* (frames within ``max_ahead_us`` of a candidate's newest residual; at most four
    candidates, the weakest dropped) and counted ``off_clock`` when they are older than ``2 * resync_after``
    frame periods (or at flush). A candidate with at least ``resync_after`` frames, *paced* like the sensor
    (arriving no faster than twice the frame rate, and stamped at least half a frame period apart on average: a
    forger's 1 kHz or 125 Hz loop, or its stamps repeated while the sensor's stream pauses, never is), re-learns
    the clock and is replayed in order, so a genuine epoch change loses no frame, if (1) the learned stream went
    quiet (none of its frames since the candidate's last ``resync_after``: a clock step or restart) while the
    rig's other sensors kept arriving (a frame of any of them since then, on clock or not; a starved node or a
    stalled link silences the whole rig, and then a forger's frames are merely the only ones getting through,
    and re-learning then hands the forger the clock; other sensors silent since ``2 * resync_after``
    periods before the stream went quiet are dead, not a reference), or (2) the
    learned stream itself is not paced (a forger that spoke first holds the clock and outruns the sensor) and,
    in device mode, the candidate agrees with the rig's other sensors no worse than the learned clock (within
    ``max_ahead_us``), or (3) in device mode, the candidate agrees with the rig's other sensors better than the
    learned clock by more than ``max_ahead_us`` (a forger paced like the sensor that spoke first). Until the
    genuine stream wins, a forger that spoke first is grouped as the sensor (its lead in time can make the rig's
    frames late for that long). The rig's other sensors are a reference only in device mode, where wired sync
    gives them one clock; they are read, never moved. A forger paced like the sensor, agreeing with the rig and
    speaking first keeps the clock: timing cannot tell it from the sensor (the rig's access control can,
    docs/multi-pc.md).
Host time across PCs (``by = "host"``)
    Capture PCs' clocks may be offset by hundreds of ms and jitter by tens. In host mode frames are grouped
    on the *corrected* time ``stamp - offset(sensor) + reference``: each sensor's stamps are moved onto the
    node's arrival clock by that sensor's own offset, then shifted by one reference offset (the median of the
    sensors' offsets when the clock epoch began, frozen for the epoch), so fused times stay near the rig's
    majority clock. Stamp jitter is removed with the sequence numbers (frames of one sensor are one frame
    period apart): the corrected time is ``sequence * period + median(phase)`` over the sensor's recent
    frames, unless the sequence does not follow the period (then the corrected stamp itself is used). One
    sensor's clock therefore never moves another sensor's times or the grouping windows.
Accounting: every pushed frame of an expected sensor ends up in exactly one emitted group or in one of
``late``, ``duplicate``, ``out_of_window``, ``off_clock`` (after :meth:`FrameGrouper.flush`; before it, frames
may still be held in open groups, held back or held by a sensor clock, see :attr:`FrameGrouper.n_held`).
"""

from __future__ import annotations

import bisect
import dataclasses
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np

from skelfuse.rig.clocks import (
    DEFAULT_MAX_AHEAD_US,
    DEFAULT_MAX_BEHIND_US,
    DEFAULT_RESYNC_AFTER,
    ClockEstimate,
    SensorClock,
    median_of,
)
from skelfuse.schema.frames import SensorFrame

if TYPE_CHECKING:  # pragma: no cover - typing only
    from skelfuse.config import RigConfig, SyncConfig

GroupBy = Literal["device", "host"]

DEFAULT_RESYNC_HORIZON_US = 1_000_000
"""How far (µs) from the newest frame time a frame may lie before it counts as out of window."""
_MAX_UNKNOWN_IDS = 16


@dataclass(frozen=True)
class FrameGroup:
    """The frames of one instant.

    Attributes
    ----------
    time_us : int
        Earliest frame time in the group, µs, on the grouping clock (device time, or host time / 1000).
    frames : dict[str, SensorFrame]
        One frame per sensor that delivered one, in the order of the grouper's expected sensor ids.
    missing : tuple[str, ...]
        Expected sensors without a frame in this group, in expected order.
    complete : bool
        True when ``missing`` is empty.
    first_arrival_ns : int or None
        Arrival (the caller's ``now_ns``) of the group's first frame; None for groups not made by a grouper. The
        fusion node measures how far behind it is from it.
    """

    time_us: int
    frames: dict[str, SensorFrame]
    missing: tuple[str, ...]
    complete: bool
    first_arrival_ns: int | None = None


@dataclass
class SensorCounters:
    """Frame counters of one sensor (or the sum over sensors).

    Attributes
    ----------
    received : int
        Frames pushed.
    grouped : int
        Frames handed out in an emitted group.
    late : int
        Frames for an instant already emitted (dropped).
    dropped : int
        Frames the sensor never delivered, from gaps in its sequence numbers.
    duplicate : int
        Second frames of the sensor for one group (dropped).
    out_of_window : int
        Frames far outside the current time window that did not lead to a resync (dropped).
    """

    received: int = 0
    grouped: int = 0
    late: int = 0
    dropped: int = 0
    duplicate: int = 0
    out_of_window: int = 0
    off_clock: int = 0


@dataclass
class GrouperStats:
    """Counters of a :class:`FrameGrouper` (a snapshot when read through :attr:`FrameGrouper.stats`).

    Attributes
    ----------
    sensors : dict[str, SensorCounters]
        Per expected sensor.
    unknown : int
        Frames of sensors that are not expected (ignored).
    unknown_ids : list[str]
        The first few unknown sensor ids seen (at most 16), for a status message.
    groups, complete_groups : int
        Groups emitted, and how many of them were complete.
    resyncs : int
        Clock epochs started after out-of-window frames (see the module's resync rule).
    """

    sensors: dict[str, SensorCounters]
    unknown: int = 0
    unknown_ids: list[str] = field(default_factory=list)
    groups: int = 0
    complete_groups: int = 0
    resyncs: int = 0

    @property
    def totals(self) -> SensorCounters:
        """Counters summed over the expected sensors."""
        total = SensorCounters()
        for counters in self.sensors.values():
            for f in dataclasses.fields(SensorCounters):
                setattr(total, f.name, getattr(total, f.name) + getattr(counters, f.name))
        return total

    def to_dict(self) -> dict[str, object]:
        """Plain dict (JSON-ready) for a status document."""
        return {
            "sensors": {sid: dataclasses.asdict(c) for sid, c in self.sensors.items()},
            "totals": dataclasses.asdict(self.totals),
            "unknown": self.unknown,
            "unknown_ids": list(self.unknown_ids),
            "groups": self.groups,
            "complete_groups": self.complete_groups,
            "resyncs": self.resyncs,
        }


@dataclass
class _OpenGroup:
    anchor_us: int
    deadline_ns: int
    first_arrival_ns: int
    frames: dict[str, SensorFrame] = field(default_factory=dict)
    min_time_us: int = 0


class FrameGrouper:
    """Groups :class:`SensorFrame` objects of one instant (rules in the module docstring).

    Parameters
    ----------
    expected_sensor_ids : iterable of str
        The rig's sensors; groups are complete when all of them delivered.
    by : {"device", "host"}
        Grouping clock: ``device_time_us`` (wired sync) or ``host_time_ns`` (no sync cables).
    tolerance_us : int
        Maximum distance of a frame's time from its group's anchor, µs; below half a frame period.
    deadline_us : int
        A group is emitted at the latest this long after its first frame arrived (``now_ns``), µs.
    fps : float
        Nominal frame rate, Hz (bounds the tolerance).
    resync_after : int
        Consecutive out-of-window frames that start a new clock epoch.
    resync_horizon_us : int
        Distance from the newest frame time beyond which a frame is out of window, µs.
    max_ahead_us, max_behind_us : int
        How far a frame's time may lie ahead of / behind its sensor's learned clock (see "Sensor clocks").

    Not thread-safe: call it from one thread (the fusion node's loop).
    """

    _reference_us: int | None  # host mode: the rig's clock offset for this epoch (set by _reset_epoch)

    def __init__(
        self,
        expected_sensor_ids: Iterable[str],
        *,
        by: GroupBy = "device",
        tolerance_us: int,
        deadline_us: int,
        fps: float = 30.0,
        resync_after: int = DEFAULT_RESYNC_AFTER,
        resync_horizon_us: int = DEFAULT_RESYNC_HORIZON_US,
        max_ahead_us: int = DEFAULT_MAX_AHEAD_US,
        max_behind_us: int = DEFAULT_MAX_BEHIND_US,
    ) -> None:
        ids = tuple(expected_sensor_ids)
        if not ids or not all(isinstance(s, str) and s for s in ids):
            raise ValueError(f"FrameGrouper needs at least one sensor id (non-empty str), got {ids!r}")
        if len(set(ids)) != len(ids):
            raise ValueError(f"FrameGrouper expected_sensor_ids holds duplicates: {ids!r}")
        if by not in ("device", "host"):
            raise ValueError(f"FrameGrouper by must be 'device' or 'host', got {by!r}")
        if not fps > 0:
            raise ValueError(f"FrameGrouper fps must be > 0, got {fps!r}")
        half_period_us = 0.5e6 / fps
        if not 0 < tolerance_us < half_period_us:
            raise ValueError(
                f"FrameGrouper tolerance_us must be in (0, {half_period_us:.0f}) (half a frame period "
                f"at {fps:g} fps), got {tolerance_us!r}"
            )
        if not deadline_us > 0:
            raise ValueError(f"FrameGrouper deadline_us must be > 0, got {deadline_us!r}")
        if int(resync_after) < 1:
            raise ValueError(f"FrameGrouper resync_after must be >= 1, got {resync_after!r}")
        if not resync_horizon_us > tolerance_us:
            raise ValueError(
                f"FrameGrouper resync_horizon_us must exceed tolerance_us ({tolerance_us}), got {resync_horizon_us!r}"
            )
        if not (int(max_ahead_us) > 0 and int(max_behind_us) > 0):
            raise ValueError(
                f"FrameGrouper max_ahead_us and max_behind_us must be > 0, got {max_ahead_us!r}, {max_behind_us!r}"
            )
        self.expected_sensor_ids = ids
        self.by: GroupBy = by
        self.tolerance_us = int(tolerance_us)
        self.deadline_us = int(deadline_us)
        self.fps = float(fps)
        self.resync_after = int(resync_after)
        self.resync_horizon_us = int(resync_horizon_us)
        self._expected = frozenset(ids)
        self._stats = GrouperStats(sensors={sid: SensorCounters() for sid in ids})
        self._last_sequence: dict[str, int] = {}
        self._held_back: list[tuple[SensorFrame, int, int]] = []  # (frame, time_us, arrival_ns), out of window
        self._arrived_us: dict[str, int] = {}  # each expected sensor's latest frame arrival, on clock or not
        self._clocks = {
            sid: SensorClock(
                period_us=1e6 / self.fps,
                max_ahead_us=int(max_ahead_us),
                max_behind_us=int(max_behind_us),
                relearn_after=self.resync_after,
            )
            for sid in ids
        }
        # A sequence jump longer than the horizon's worth of frames is a restart, not drops.
        self._max_sequence_gap = int(self.resync_horizon_us * self.fps / 1e6) + 1
        self._reset_epoch()

    @classmethod
    def for_rig(cls, cfg: RigConfig) -> FrameGrouper:
        """A grouper for a rig: its sensors, and the ``[sync]`` section of its config."""
        return cls.from_sync(cfg.sensor_ids, cfg.sync)

    @classmethod
    def from_sync(
        cls,
        sensor_ids: Iterable[str],
        sync: SyncConfig,
        *,
        by: str | None = None,
        tolerance_us: int | None = None,
        deadline_us: int | None = None,
    ) -> FrameGrouper:
        """A grouper from a ``[sync]`` section; ``by`` and the two times override it where given."""
        return cls(
            sensor_ids,
            by=by if by is not None else sync.by,  # type: ignore[arg-type]  # config validation keeps [sync] by to "device" / "host"
            tolerance_us=int(tolerance_us) if tolerance_us is not None else sync.tolerance_us,
            deadline_us=int(deadline_us) if deadline_us is not None else sync.deadline_us,
            fps=sync.fps,
            resync_after=sync.resync_after_frames,
            resync_horizon_us=sync.resync_horizon_us,
            max_ahead_us=sync.max_ahead_us,
            max_behind_us=sync.max_behind_us,
        )

    # -- public -------------------------------------------------------------------------------------------

    def push(self, frame: SensorFrame, now_ns: int) -> list[FrameGroup]:
        """Add one received frame (``now_ns``: its arrival, on the caller's monotonic clock).

        Returns the groups that became due, oldest first (possibly none).
        """
        sensor_id = frame.sensor_id
        if sensor_id not in self._expected:
            self._stats.unknown += 1
            if sensor_id not in self._stats.unknown_ids and len(self._stats.unknown_ids) < _MAX_UNKNOWN_IDS:
                self._stats.unknown_ids.append(str(sensor_id))
            return self._emit_due(now_ns)
        counters = self._stats.sensors[sensor_id]
        counters.received += 1
        self._arrived_us[sensor_id] = int(now_ns) // 1000
        raw_us = self._time_of(frame)
        clock = self._clocks[sensor_id]
        emitted: list[FrameGroup] = []
        if clock.on_clock(raw_us, int(now_ns) // 1000):
            counters.off_clock += clock.expire(int(now_ns) // 1000)
            self._accept(frame, raw_us, int(now_ns), int(now_ns), emitted)
        else:
            replay, discarded = clock.hold(
                frame,
                raw_us,
                int(now_ns),
                rig_offset_us=self._rig_offset_without(sensor_id),
                rig_arrival_us=self._rig_arrival_without(sensor_id),
            )
            counters.off_clock += discarded
            # Replayed after a clock step: their deadlines run from now, so the other sensors' frames of the
            # same step (re-learned within a frame or two) still join their instants.
            for held_frame, held_us, held_arrival_ns in replay:
                self._accept(held_frame, held_us, held_arrival_ns, int(now_ns), emitted)
        emitted.extend(self._emit_due(now_ns))
        return emitted

    def clock_estimates(self) -> dict[str, ClockEstimate]:
        """Each expected sensor's clock: offset from the node's arrival clock, from the rig's median, drift."""
        offsets = [c.offset_us for c in self._clocks.values() if c.offset_us is not None]
        rig_offset = float(np.median(offsets)) if offsets else None
        return {sid: clock.estimate(rig_offset) for sid, clock in self._clocks.items()}

    def poll(self, now_ns: int) -> list[FrameGroup]:
        """Emit the groups whose deadline passed by ``now_ns`` (or that became ready), oldest first."""
        return self._emit_due(now_ns)

    def flush(self) -> list[FrameGroup]:
        """Emit every open group (end of stream, shutdown); held-back frames are counted out of window,
        frames held by a sensor clock off clock."""
        for sid, clock in self._clocks.items():
            self._stats.sensors[sid].off_clock += clock.drop_held()
        self._drop_held_back()
        emitted = [self._emit(group) for group in self._open]
        self._open.clear()
        return emitted

    @property
    def stats(self) -> GrouperStats:
        """A snapshot of the counters (safe to keep or serialize)."""
        return dataclasses.replace(
            self._stats,
            sensors={sid: dataclasses.replace(c) for sid, c in self._stats.sensors.items()},
            unknown_ids=list(self._stats.unknown_ids),
        )

    @property
    def n_open(self) -> int:
        """Groups waiting for frames or their deadline."""
        return len(self._open)

    @property
    def n_held(self) -> int:
        """Frames not yet accounted for: in open groups, or held back as out of window."""
        return (
            sum(len(g.frames) for g in self._open) + len(self._held_back) + sum(c.n_held for c in self._clocks.values())
        )

    # -- internals ----------------------------------------------------------------------------------------

    def _accept(
        self, frame: SensorFrame, raw_us: int, arrival_ns: int, place_ns: int, emitted: list[FrameGroup]
    ) -> None:
        """An on-clock frame: learn its sensor's clock (``arrival_ns``), count its sequence, place it (its
        group's deadline runs from ``place_ns``) or hold it back."""
        clock = self._clocks[frame.sensor_id]
        clock.learn(raw_us, arrival_ns // 1000)
        self._count_sequence(frame.sensor_id, int(frame.sequence))
        time_us = self._grouping_time(frame, raw_us, clock)
        if self._in_window(time_us):
            self._drop_held_back()
            self._place(frame, time_us, place_ns)
        else:
            self._held_back.append((frame, time_us, place_ns))
            # The whole rig moved only if more than one sensor did (when the epoch knew more than one): one
            # sensor's re-learned clock replays its frames in a row and must not drag the others along.
            movers = {f.sensor_id for f, _, _ in self._held_back}
            if len(self._held_back) >= self.resync_after and len(movers) >= min(2, len(self._latest_by_sensor)):
                emitted.extend(self._resync())

    def _rig_offset_without(self, sensor_id: str) -> float | None:
        """The median offset of the other sensors' clocks: a reference for ``sensor_id``'s clock only where
        the sensors share one clock (device mode: wired sync); None in host mode, where PCs' clocks differ."""
        if self.by != "device":
            return None
        offsets = [c.offset_us for sid, c in self._clocks.items() if sid != sensor_id and c.offset_us is not None]
        return median_of(offsets) if offsets else None

    def _rig_arrival_without(self, sensor_id: str) -> int | None:
        """When the latest frame of any other expected sensor arrived (µs; None if none has): the rig arriving.

        The latest, not a median: dead sensors must not keep a live one from re-learning its stepped clock."""
        latest = [us for sid, us in self._arrived_us.items() if sid != sensor_id]
        return max(latest) if latest else None

    def _grouping_time(self, frame: SensorFrame, raw_us: int, clock: SensorClock) -> int:
        """Device mode: the device time. Host mode: the stamp on the rig's clock, jitter removed."""
        if self.by == "device":
            return raw_us
        assert clock.offset_us is not None  # learned just before
        if self._reference_us is None:
            offsets = [c.offset_us for c in self._clocks.values() if c.offset_us is not None]
            self._reference_us = int(np.median(offsets))
        corrected = raw_us - clock.offset_us + self._reference_us
        return clock.smoothed_us(int(frame.sequence), corrected)

    def _reset_epoch(self) -> None:
        self._open: list[_OpenGroup] = []  # sorted by anchor
        self._emitted_until_us: int | None = None  # anchor of the newest emitted group
        self._newest_us: int | None = None  # newest in-window frame time
        self._latest_by_sensor: dict[str, int] = {}
        self._reference_us = None

    def _time_of(self, frame: SensorFrame) -> int:
        return int(frame.device_time_us) if self.by == "device" else int(frame.host_time_ns) // 1000

    def _count_sequence(self, sensor_id: str, sequence: int) -> None:
        last = self._last_sequence.get(sensor_id)
        if last is not None and last + 1 < sequence <= last + self._max_sequence_gap:
            self._stats.sensors[sensor_id].dropped += sequence - last - 1
        if last is None or sequence != last:
            # Forward: the new last. Backwards: a restarted sensor or looped replay, count from here.
            self._last_sequence[sensor_id] = sequence

    def _in_window(self, time_us: int) -> bool:
        return self._newest_us is None or abs(time_us - self._newest_us) <= self.resync_horizon_us

    def _drop_held_back(self) -> None:
        for frame, _, _ in self._held_back:
            self._stats.sensors[frame.sensor_id].out_of_window += 1
        self._held_back.clear()

    def _resync(self) -> list[FrameGroup]:
        """Start a new clock epoch: emit what is open, forget the time state, replay the held-back frames."""
        emitted = [self._emit(group) for group in self._open]
        held, self._held_back = self._held_back, []
        self._reset_epoch()
        self._stats.resyncs += 1
        for frame, time_us, arrival_ns in held:
            if self._in_window(time_us):
                self._place(frame, time_us, arrival_ns)
            else:  # the held-back frames do not even agree with each other
                self._stats.sensors[frame.sensor_id].out_of_window += 1
        return emitted

    def _place(self, frame: SensorFrame, time_us: int, arrival_ns: int) -> None:
        sensor_id = frame.sensor_id
        counters = self._stats.sensors[sensor_id]
        self._newest_us = time_us if self._newest_us is None else max(self._newest_us, time_us)
        self._latest_by_sensor[sensor_id] = max(self._latest_by_sensor.get(sensor_id, time_us), time_us)
        if self._emitted_until_us is not None and time_us <= self._emitted_until_us + self.tolerance_us:
            counters.late += 1
            return
        group = self._nearest_open(time_us)
        if group is None:
            group = _OpenGroup(
                anchor_us=time_us,
                deadline_ns=int(arrival_ns) + self.deadline_us * 1000,
                first_arrival_ns=int(arrival_ns),
                min_time_us=time_us,
            )
            anchors = [g.anchor_us for g in self._open]
            self._open.insert(bisect.bisect_right(anchors, time_us), group)
        elif sensor_id in group.frames:
            counters.duplicate += 1
            return
        group.frames[sensor_id] = frame
        group.min_time_us = min(group.min_time_us, time_us)

    def _nearest_open(self, time_us: int) -> _OpenGroup | None:
        best, best_distance = None, None
        for group in self._open:
            distance = abs(time_us - group.anchor_us)
            if distance <= self.tolerance_us and (best_distance is None or distance < best_distance):
                best, best_distance = group, distance
        return best

    def _ready(self, group: _OpenGroup) -> bool:
        if len(group.frames) == len(self.expected_sensor_ids):  # complete (frames hold expected sensors only)
            return True
        window_end = group.anchor_us + self.tolerance_us
        latest = self._latest_by_sensor
        # Only the missing sensors can hold the group open (a set difference, not a pass over every sensor).
        return all(latest.get(sid, window_end) > window_end for sid in self._expected.difference(group.frames))

    def _emit_due(self, now_ns: int) -> list[FrameGroup]:
        last_due = -1
        for idx, group in enumerate(self._open):
            if now_ns >= group.deadline_ns or self._ready(group):
                last_due = idx
        if last_due < 0:
            return []
        due, self._open = self._open[: last_due + 1], self._open[last_due + 1 :]
        return [self._emit(group) for group in due]

    def _emit(self, group: _OpenGroup) -> FrameGroup:
        frames = {sid: group.frames[sid] for sid in self.expected_sensor_ids if sid in group.frames}
        missing = tuple(sid for sid in self.expected_sensor_ids if sid not in group.frames)
        for sid in frames:
            self._stats.sensors[sid].grouped += 1
        self._stats.groups += 1
        if not missing:
            self._stats.complete_groups += 1
        if self._emitted_until_us is None or group.anchor_us > self._emitted_until_us:
            self._emitted_until_us = group.anchor_us
        return FrameGroup(
            time_us=group.min_time_us,
            frames=frames,
            missing=missing,
            complete=not missing,
            first_arrival_ns=group.first_arrival_ns,
        )
