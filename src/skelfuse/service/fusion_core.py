"""The fusion node's pure-logic core: sensor payloads in, fused frames and status counters out.

:class:`FusionCore` decodes each payload (rejects counted per sensor and reason, never raised), groups frames
into instants (:class:`skelfuse.rig.grouping.FrameGrouper`) and fuses each instant
(:class:`skelfuse.rig.instant.GroupFuser`); it opens no session and starts no thread, so tests and tools drive
it directly. :mod:`skelfuse.service.node` is the zenoh shell around it (data flow in its docstring).
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from skelfuse.config import RigConfig
from skelfuse.fusion.people import PeopleResult
from skelfuse.fusion.plausibility import HOLD_REASONS
from skelfuse.fusion.presets import FusionParams
from skelfuse.rig.grouping import FrameGroup, FrameGrouper
from skelfuse.rig.instant import GroupFuser
from skelfuse.rig.smoothing import LiveFixedLag
from skelfuse.schema.frames import FusedFrame
from skelfuse.service.shedding import LagShedder
from skelfuse.wire import keys
from skelfuse.wire.codec import DecodeError, decode_sensor_frame, encode_fused_frame

if TYPE_CHECKING:  # pragma: no cover - typing only
    from skelfuse.service.depth_stage import DepthStage

log = logging.getLogger("skelfuse.service.node")  # one logger for the node and its core

KEY_MISMATCH = "key_mismatch"
"""Node-level reject reason: the payload's sensor id differs from the sensor id of the key it came on."""
BAD_KEY = "bad_key"
"""Node-level reject reason: a sample on the sensor wildcard whose key is not a valid sensor key."""
UNKNOWN_SENSOR = "?"
"""Sensor name under which rejects of unparseable keys are counted."""
LATENCY_WINDOW = 10_000
"""Latency samples kept for the "since start" percentiles (the most recent ones)."""
OVERSIZED = "oversized"
"""Node-level reject reason: a payload larger than ``[intake] max_payload_bytes`` (dropped unread)."""
TOO_MANY_BODIES = "too_many_bodies"
"""Node-level reject reason: more bodies than ``[intake] max_bodies_per_sensor``."""
OUT_OF_VOLUME = "out_of_volume"
"""Node-level reject reason: a joint farther than ``[intake] max_range_mm`` from its sensor."""
IDLE_WAIT_S = 0.02
"""The longest the node loop sleeps while no instant is open (no deadline can pass then); it wakes on arrival."""
FUSION_ERROR = "fusion_error"
"""Node-level reject reason: an instant the core could not fuse or encode (logged; the node goes on)."""


TRACK_ID_EPOCH_S = 1_767_225_600
"""2026-01-01T00:00:00Z: the live node's track ids count seconds from here (see time_based_first_track_id)."""


def time_based_first_track_id(unix_time_ns: int) -> int:
    """The first track id of a node started at ``unix_time_ns``: whole seconds since 2026-01-01 UTC.

    Track ids are never reused, across restarts too: a restarted node starts above every id the previous run
    could have given, unless that run started more tracks than seconds went by before the restart (a person
    walking in starts one track) or the clock stepped back. No state file is needed (a replaced PC continues the
    sequence). The ids stay below 2**31 until 2094, so every consumer can hold them in a 32-bit signed integer
    (OSC's ``i``, C3D parameters, LSL, most game engines).
    """
    return max(int(unix_time_ns) // 1_000_000_000 - TRACK_ID_EPOCH_S, 1)


def calibration_document(cfg: RigConfig, poses: np.ndarray) -> dict[str, Any]:
    """What the calibration queryable answers (JSON; see docs/service.md)."""
    return {
        "rig": cfg.name,
        "units": "mm",
        "convention": "world_from_sensor: p_world = R @ p_sensor + t; row-major 4x4; sensor frame x right, "
        "y down, z forward; world right-handed, z up",
        "sensor_ids": list(cfg.sensor_ids),
        "world_from_sensor": {sid: poses[i].tolist() for i, sid in enumerate(cfg.sensor_ids)},
    }


@dataclass(frozen=True)
class FusedOutput:
    """One fused instant, ready to publish.

    Attributes
    ----------
    frame : FusedFrame
    payload : bytes
        ``encode_fused_frame(frame)``.
    sensors_world : (S, B, 32, 3) float64
        Every body of every sensor in the world frame, mm, NaN-padded (NaN: no frame / no body in the slot).
    fusion_ns : int
        Time of the fusion step plus encoding, ns.
    trigger_arrival_ns : int or None
        Arrival (monotonic ns) of the frame that completed the group; None when a deadline or the final
        flush emitted it.
    complete : bool
        Every sensor of the rig delivered a frame for this instant.
    """

    frame: FusedFrame
    payload: bytes
    sensors_world: np.ndarray
    fusion_ns: int
    trigger_arrival_ns: int | None
    complete: bool
    clouds: tuple[Any, ...] = ()
    """Depth / hybrid mode: (track id, MergedCloud) of each person's fused cloud, for the view."""
    people: PeopleResult | None = None
    """The fusion core's whole result (association, contributors, held-out views), for the sensor-moved monitor."""

    def fit_inputs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """What the sensor-moved monitor (:meth:`skelfuse.service.pose_fit.PoseFitMonitor.update`) takes after
        ``sensors_world``: the people (coasting tracks too), who contributed to each, which views were held out."""
        people = self.people
        if people is None:
            return self.frame.positions, self.frame.contributors, None
        return people.positions, people.contributors, people.held_out


@dataclass(frozen=True)
class _Beside:
    """What is published beside a fused frame, held with it while a fixed lag delays it."""

    sensors_world: np.ndarray
    complete: bool
    clouds: tuple[Any, ...]
    people: PeopleResult | None = None


@dataclass
class _SensorWindow:
    received: int = 0
    last_seen_ns: int | None = None
    rejects: Counter[str] = field(default_factory=Counter)
    window_received: int = 0


class FusionCore:
    """Decode -> group -> fuse -> encode, single-threaded, no I/O: the clock is passed in.

    Parameters
    ----------
    cfg : RigConfig
        The rig: its sensors, ``[sync]`` (grouping), ``[fusion]`` and poses.
    params : FusionParams, optional
        Overrides ``cfg.fusion.fusion_params()``.
    poses : (S, 4, 4), optional
        Overrides ``cfg.poses()`` (rows in ``cfg.sensor_ids`` order).
    first_track_id : int
        The first track id (the live node passes :func:`time_based_first_track_id`).
    depth : DepthStage, optional
        ``[fusion] mode`` depth / hybrid: fuses each instant instead of the plain GroupFuser step.
    fixed_lag_frames : int, optional
        Overrides ``cfg.fusion.fixed_lag_frames``: above 0, each instant is published that many instants later,
        smoothed by the fixed-lag smoother (:class:`skelfuse.rig.smoothing.LiveFixedLag`).

    An instant is shed instead of fused when it is older than ``[node] max_lag_s`` at its turn
    (:class:`~skelfuse.service.shedding.LagShedder`); its age is measured from the clock the caller passes as
    ``now_ns`` (a caller that passes none, or only arrival times, never sheds).

    Attributes
    ----------
    grouper : FrameGrouper
    fuser : GroupFuser
        The per-instant adapter shared with offline fusion (its ``people`` holds the tracks).
    frames_in, frames_out : int
        Payloads received, fused frames produced.
    rejects : dict[str, Counter]
        Per sensor (from the key), rejects per reason (codec reasons, plus "key_mismatch", "bad_key").
    shedder : LagShedder
        Instants shed because the caller fell behind, per reason and per sensor.
    """

    def __init__(
        self,
        cfg: RigConfig,
        *,
        params: FusionParams | None = None,
        poses: np.ndarray | None = None,
        first_track_id: int = 1,
        depth: DepthStage | None = None,
        fixed_lag_frames: int | None = None,
    ) -> None:
        self.cfg = cfg
        self.sensor_ids = cfg.sensor_ids
        self.column = {sid: i for i, sid in enumerate(self.sensor_ids)}
        self._sensor_of_key = {keys.sensor_skeletons(cfg.name, sid): sid for sid in self.sensor_ids}
        if poses is None:
            by_id = cfg.poses()
            poses = np.stack([by_id[sid] for sid in self.sensor_ids])
        self.poses = np.asarray(poses, dtype=np.float64)
        self.params = params if params is not None else cfg.fusion.fusion_params()
        self.grouper = FrameGrouper.for_rig(cfg)
        self.intake = cfg.intake
        self.depth = depth
        fused_ids, fused_poses = (self.sensor_ids, self.poses) if depth is None else depth.fuser_sensors(self.poses)
        self.fuser = GroupFuser(
            fused_ids,
            fused_poses,
            self.params,
            max_persons=self.intake.max_persons,
            first_track_id=first_track_id,
        )
        lag = cfg.fusion.fixed_lag_frames if fixed_lag_frames is None else int(fixed_lag_frames)
        self.fixed_lag: LiveFixedLag[_Beside] | None = LiveFixedLag(self.params, lag) if lag > 0 else None
        self.frames_in = 0
        self.frames_out = 0
        self.groups_complete = 0
        self.groups_partial = 0
        self.deadline_emits = 0
        self.rejects: dict[str, Counter[str]] = {}
        self.held_out: dict[str, Counter[str]] = {}  # views the plausibility stage held out, per sensor and reason
        self._sensors = {sid: _SensorWindow() for sid in self.sensor_ids}
        self._logged_rejects: Counter[tuple[str, str]] = Counter()
        self.shedder = LagShedder(cfg.node.max_lag_s, what=f"fusion node {cfg.node.name or 'fusion'}")
        self._last_fusion_ms: float | None = None

    @property
    def fixed_lag_frames(self) -> int:
        """Instants each fused frame is held back for fixed-lag smoothing (0: published at once)."""
        return 0 if self.fixed_lag is None else self.fixed_lag.lag

    # -- input --------------------------------------------------------------------------------------------

    def receive(self, key: str, payload: bytes, arrival_ns: int, now_ns: int | None = None) -> list[FusedOutput]:
        """One sample from the sensor wildcard; returns the fused instants that became due.

        ``now_ns``: the time now on the clock of ``arrival_ns`` (the live node's monotonic clock): due instants older
        than ``[node] max_lag_s`` by then are shed. Deadlines run on arrivals, a rejected sample's too: a backlog's
        frames arrived in time, whatever the time now. Default ``arrival_ns`` (a sample taken as it arrives)."""
        now_ns = arrival_ns if now_ns is None else now_ns
        self.frames_in += 1
        key_sensor = self._sensor_of_key.get(key) if isinstance(key, str) else None  # the rig's keys, parsed once
        if key_sensor is None:
            try:
                key_sensor = keys.parse_sensor_key(key, self.cfg.name)
            except ValueError as exc:
                self._reject(UNKNOWN_SENSOR, BAD_KEY, str(exc))
                return self._due(arrival_ns, now_ns)
        intake = self.intake
        if len(payload) > intake.max_payload_bytes:
            self._reject(key_sensor, OVERSIZED, f"{len(payload)} bytes, at most {intake.max_payload_bytes} ([intake])")
            return self._due(arrival_ns, now_ns)
        try:
            frame = decode_sensor_frame(payload)
        except DecodeError as exc:
            self._reject(key_sensor, exc.reason, str(exc))
            return self._due(arrival_ns, now_ns)
        if frame.n_bodies > intake.max_bodies_per_sensor:
            self._reject(
                key_sensor,
                TOO_MANY_BODIES,
                f"{frame.n_bodies} bodies, at most {intake.max_bodies_per_sensor} ([intake] max_bodies_per_sensor)",
            )
            return self._due(arrival_ns, now_ns)
        if frame.n_bodies:
            reach = float(np.abs(frame.positions).max())  # finite: the codec rejects NaN and Inf
            if reach > intake.max_range_mm:
                self._reject(
                    key_sensor,
                    OUT_OF_VOLUME,
                    f"a joint {reach:.4g} mm from the sensor on one axis, at most {intake.max_range_mm:g} mm "
                    f"([intake] max_range_mm)",
                )
                return self._due(arrival_ns, now_ns)
        if frame.sensor_id != key_sensor:
            self._reject(
                key_sensor,
                KEY_MISMATCH,
                f"payload says sensor {frame.sensor_id!r} but came on the key of {key_sensor!r}",
            )
            return self._due(arrival_ns, now_ns)
        window = self._sensors.get(key_sensor)
        if window is not None:
            window.received += 1
            window.window_received += 1
            window.last_seen_ns = arrival_ns
        groups = self.grouper.push(frame, arrival_ns)
        return self._fuse_groups(groups, trigger_arrival_ns=arrival_ns, now_ns=now_ns)

    def poll(self, now_ns: int) -> list[FusedOutput]:
        """Instants whose deadline passed by ``now_ns``."""
        return self._due(now_ns, now_ns)

    def _due(self, by_ns: int, now_ns: int) -> list[FusedOutput]:
        """Instants whose deadline passed by ``by_ns`` (a rejected sample's arrival: a frame queued behind it in a
        backlog arrived in time, whatever the time now), those older than the bound at ``now_ns`` shed."""
        groups = self.grouper.poll(by_ns)
        self.deadline_emits += sum(1 for g in groups if not g.complete)
        return self._fuse_groups(groups, trigger_arrival_ns=None, now_ns=now_ns)

    def flush(self, now_ns: int | None = None) -> list[FusedOutput]:
        """Every open instant (shutdown; with ``now_ns``, those older than the bound are shed), then, with a fixed
        lag, every instant it still holds."""
        out = self._fuse_groups(self.grouper.flush(), trigger_arrival_ns=None, now_ns=now_ns)
        if self.fixed_lag is not None:
            tick = time.perf_counter_ns()
            out += [self._output(frame, beside, tick, None) for beside, frame in self.fixed_lag.flush()]
        return out

    def _reject(self, sensor_id: str, reason: str, message: str) -> None:
        self.rejects.setdefault(sensor_id, Counter())[reason] += 1
        if sensor_id in self._sensors:
            self._sensors[sensor_id].rejects[reason] += 1
        seen = self._logged_rejects[(sensor_id, reason)]
        self._logged_rejects[(sensor_id, reason)] += 1
        if seen == 0 or (seen + 1) % 1000 == 0:  # first of a kind, then every 1000th: no log floods
            log.warning(
                "rejected a payload of sensor %s (%s, %d so far): %s",
                sensor_id,
                reason,
                seen + 1,
                message,
                extra={"sensor": sensor_id, "reason": reason},
            )

    # -- fusion -------------------------------------------------------------------------------------------

    def _fuse_groups(
        self, groups: list[FrameGroup], trigger_arrival_ns: int | None, now_ns: int | None
    ) -> list[FusedOutput]:
        out: list[FusedOutput] = []
        for index, group in enumerate(groups):
            # Only the newest group of a push was completed by the pushed frame; older ones were pushed out.
            trigger = trigger_arrival_ns if index == len(groups) - 1 and group.complete else None
            first_arrival_ns = group.first_arrival_ns
            if now_ns is not None and first_arrival_ns is not None:
                now = now_ns + sum(o.fusion_ns for o in out)  # the groups fused before this one took that long
                if self.shedder.too_old(first_arrival_ns, now):
                    self.shedder.shed(list(group.frames), now - first_arrival_ns, now, self._last_fusion_ms)
                    continue
                self.shedder.fused(now)
            try:
                out += self._fuse(group, trigger)
            except Exception as exc:  # never expected (caps keep frames encodable): a daemon must not die of it
                self.fuser.reset()  # the tracks start afresh; the next instant is fused as usual
                if self.fixed_lag is not None:  # the instants it held are lost with the tracks
                    self.fixed_lag = LiveFixedLag(self.params, self.fixed_lag.lag)
                if not isinstance(exc, ValueError):  # a bug in the core: its trace once per kind, for the report
                    first = not any(FUSION_ERROR in counter for counter in self.rejects.values())
                    log.error("the fusion step raised %s: a bug, please report it", type(exc).__name__, exc_info=first)
                self._reject(
                    UNKNOWN_SENSOR,
                    FUSION_ERROR,
                    f"instant at {group.time_us} µs not fused: {type(exc).__name__}: {exc}",
                )
        return out

    def _fuse(self, group: FrameGroup, trigger_arrival_ns: int | None) -> list[FusedOutput]:
        """The instant's output; with a fixed lag, the one ``lag`` instants back instead (none at first)."""
        tick = time.perf_counter_ns()
        depth = self.depth
        instant = self.fuser.step(group) if depth is None else depth.step(self.fuser, group)
        if instant.people.held_out is not None:
            count_held_out(self.held_out, instant.people.held_out, instant.frame.sensor_ids)
        beside = _Beside(
            instant.sensors_world, group.complete, () if depth is None else depth.last_clouds, instant.people
        )
        if self.fixed_lag is None:
            out = [self._output(instant.frame, beside, tick, trigger_arrival_ns)]
        else:
            out = [self._output(f, b, tick, trigger_arrival_ns) for b, f in self.fixed_lag.push(instant, beside)]
        self._last_fusion_ms = (time.perf_counter_ns() - tick) / 1e6
        if group.complete:
            self.groups_complete += 1
        else:
            self.groups_partial += 1
        return out

    def _output(self, frame: FusedFrame, beside: _Beside, tick: int, trigger_arrival_ns: int | None) -> FusedOutput:
        payload = encode_fused_frame(frame)
        self.frames_out += 1
        elapsed = time.perf_counter_ns() - tick
        return FusedOutput(
            frame,
            payload,
            beside.sensors_world,
            elapsed,
            trigger_arrival_ns,
            beside.complete,
            beside.clouds,
            beside.people,
        )

    # -- status -------------------------------------------------------------------------------------------

    def sensor_report(self, now_ns: int, window_s: float) -> dict[str, dict[str, Any]]:
        """Per sensor: rate over the last window, last seen, grouper counters, rejects. Resets the window."""
        stats = self.grouper.stats
        clocks = self.grouper.clock_estimates()
        report = {}
        for sid, window in self._sensors.items():
            counters = stats.sensors[sid]
            report[sid] = {
                "rate_hz": round(window.window_received / window_s, 3) if window_s > 0 else None,
                "last_seen_s": None if window.last_seen_ns is None else round((now_ns - window.last_seen_ns) / 1e9, 4),
                "received": counters.received,
                "grouped": counters.grouped,
                "late": counters.late,
                "dropped": counters.dropped,
                "duplicate": counters.duplicate,
                "out_of_window": counters.out_of_window,
                "off_clock": counters.off_clock,
                "invalid": sum(window.rejects.values()),
                "rejects": dict(window.rejects),
                "held_out": dict(self.held_out.get(sid, {})),
                "clock": clocks[sid].to_dict(),
            }
            window.window_received = 0
        return report


def count_held_out(counts: dict[str, Counter[str]], held_out: np.ndarray, sensor_ids: Sequence[str]) -> None:
    """Add one instant's held-out views ((P, S) reason codes, columns in ``sensor_ids`` order) to ``counts``,
    per sensor and reason name (:data:`skelfuse.fusion.plausibility.HOLD_REASONS`)."""
    persons, sensors = np.nonzero(held_out)
    for person, sensor in zip(persons.tolist(), sensors.tolist(), strict=True):
        reason = HOLD_REASONS[int(held_out[person, sensor]) - 1]
        counts.setdefault(sensor_ids[sensor], Counter())[reason] += 1
