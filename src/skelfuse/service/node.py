"""The fusion node: ``skelfuse fuse --config RIG.toml``. A thin adapter around the pure fusion core.

Data flow of one sensor frame::

    zenoh callback (zenoh thread)        SampleQueue: stamp arrival (monotonic ns), copy bytes, enqueue
                                         (bounded and fair per sensor key: a flood drops its own oldest)
      -> node loop (one thread)          FusionCore.receive: decode (rejects counted per sensor and reason,
                                         never raised, never reach fusion state)
      -> FrameGrouper.push(frame, now)   groups of one instant (complete, or at their deadline)
      -> FusionCore._fuse                GroupFuser.step (service/fusion_step.py, shared with offline
                                         fusion): every body to the world with the rig's poses,
                                         PeopleFuser.step (association, tracks), FusedFrame; encode
      -> publisher.put                   skelfuse/<rig>/fused/skeletons
      -> RerunView.submit (optional)     drawn on the view's own thread

While an instant is open, a poll every ``poll_interval_s`` (2 ms) emits groups whose deadline passed, so a dead
or slow sensor never stalls the output (with none open the loop just waits for the next frame). Every
``status_period_s`` (at a moment when no instant is half received, at most one period late) the node publishes
its status on
``skelfuse/<rig>/status/<node>``; it answers ``get`` on ``skelfuse/<rig>/calibration`` with the rig's poses
and holds a liveliness token on ``skelfuse/<rig>/alive/<node>``.

Everyone the sensors see is fused, one skeleton per person with a stable track id
(:class:`skelfuse.fusion.people.PeopleFuser`). Each instant goes through the same
:class:`skelfuse.rig.instant.GroupFuser` as offline fusion (the same clock rule too: the state
restarts when the instants' time steps back or jumps by more than
:data:`skelfuse.rig.instant.RESET_GAP_S`), so the live stream of a recording equals
``skelfuse fuse --input`` of it by construction.
"""

from __future__ import annotations

import collections
import json
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from skelfuse.config import RigConfig
from skelfuse.fusion.plausibility import HOLD_REASONS
from skelfuse.fusion.presets import FusionParams
from skelfuse.rig.grouping import FrameGroup, FrameGrouper
from skelfuse.rig.instant import GroupFuser
from skelfuse.schema.frames import FusedFrame
from skelfuse.service.depth_stage import DepthStage, depth_stage_for
from skelfuse.service.lifecycle import Lifecycle, RunLimits
from skelfuse.service.pose_fit import FitChange, PoseFitMonitor
from skelfuse.service.viewer import RerunView, ViewOptions, open_recording, stop_server
from skelfuse.service.zenoh_io import (
    OTHER_KEYS,
    SESSION_CLOSE_TIMEOUT_S,
    FusedPublisher,
    SampleQueue,
    StopBudget,
    close_session,
    open_session,
)
from skelfuse.wire import keys
from skelfuse.wire.codec import DecodeError, NodeStatus, decode_sensor_frame, encode_fused_frame, encode_status

if TYPE_CHECKING:  # pragma: no cover - typing only
    import zenoh

log = logging.getLogger("skelfuse.service.node")

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

    Attributes
    ----------
    grouper : FrameGrouper
    fuser : GroupFuser
        The per-instant adapter shared with offline fusion (its ``people`` holds the tracks).
    frames_in, frames_out : int
        Payloads received, fused frames produced.
    rejects : dict[str, Counter]
        Per sensor (from the key), rejects per reason (codec reasons, plus "key_mismatch", "bad_key").
    """

    def __init__(
        self,
        cfg: RigConfig,
        *,
        params: FusionParams | None = None,
        poses: np.ndarray | None = None,
        first_track_id: int = 1,
        depth: DepthStage | None = None,
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
        self.frames_in = 0
        self.frames_out = 0
        self.groups_complete = 0
        self.groups_partial = 0
        self.deadline_emits = 0
        self.rejects: dict[str, Counter[str]] = {}
        self.held_out: dict[str, Counter[str]] = {}  # views the plausibility stage held out, per sensor and reason
        self._sensors = {sid: _SensorWindow() for sid in self.sensor_ids}
        self._logged_rejects: Counter[tuple[str, str]] = Counter()

    # -- input --------------------------------------------------------------------------------------------

    def receive(self, key: str, payload: bytes, arrival_ns: int) -> list[FusedOutput]:
        """One sample from the sensor wildcard; returns the fused instants that became due."""
        self.frames_in += 1
        key_sensor = self._sensor_of_key.get(key) if isinstance(key, str) else None  # the rig's keys, parsed once
        if key_sensor is None:
            try:
                key_sensor = keys.parse_sensor_key(key, self.cfg.name)
            except ValueError as exc:
                self._reject(UNKNOWN_SENSOR, BAD_KEY, str(exc))
                return self.poll(arrival_ns)
        intake = self.intake
        if len(payload) > intake.max_payload_bytes:
            self._reject(key_sensor, OVERSIZED, f"{len(payload)} bytes, at most {intake.max_payload_bytes} ([intake])")
            return self.poll(arrival_ns)
        try:
            frame = decode_sensor_frame(payload)
        except DecodeError as exc:
            self._reject(key_sensor, exc.reason, str(exc))
            return self.poll(arrival_ns)
        if frame.n_bodies > intake.max_bodies_per_sensor:
            self._reject(
                key_sensor,
                TOO_MANY_BODIES,
                f"{frame.n_bodies} bodies, at most {intake.max_bodies_per_sensor} ([intake] max_bodies_per_sensor)",
            )
            return self.poll(arrival_ns)
        if frame.n_bodies:
            reach = float(np.abs(frame.positions).max())  # finite: the codec rejects NaN and Inf
            if reach > intake.max_range_mm:
                self._reject(
                    key_sensor,
                    OUT_OF_VOLUME,
                    f"a joint {reach:.4g} mm from the sensor on one axis, at most {intake.max_range_mm:g} mm "
                    f"([intake] max_range_mm)",
                )
                return self.poll(arrival_ns)
        if frame.sensor_id != key_sensor:
            self._reject(
                key_sensor,
                KEY_MISMATCH,
                f"payload says sensor {frame.sensor_id!r} but came on the key of {key_sensor!r}",
            )
            return self.poll(arrival_ns)
        window = self._sensors.get(key_sensor)
        if window is not None:
            window.received += 1
            window.window_received += 1
            window.last_seen_ns = arrival_ns
        groups = self.grouper.push(frame, arrival_ns)
        return self._fuse_groups(groups, trigger_arrival_ns=arrival_ns)

    def poll(self, now_ns: int) -> list[FusedOutput]:
        """Instants whose deadline passed by ``now_ns``."""
        groups = self.grouper.poll(now_ns)
        self.deadline_emits += sum(1 for g in groups if not g.complete)
        return self._fuse_groups(groups, trigger_arrival_ns=None)

    def flush(self) -> list[FusedOutput]:
        """Every open instant (shutdown)."""
        return self._fuse_groups(self.grouper.flush(), trigger_arrival_ns=None)

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

    def _fuse_groups(self, groups: list[FrameGroup], trigger_arrival_ns: int | None) -> list[FusedOutput]:
        out = []
        for index, group in enumerate(groups):
            # Only the newest group of a push was completed by the pushed frame; older ones were pushed out.
            trigger = trigger_arrival_ns if index == len(groups) - 1 and group.complete else None
            try:
                out.append(self._fuse(group, trigger))
            except Exception as exc:  # never expected (caps keep frames encodable): a daemon must not die of it
                self.fuser.reset()  # the tracks start afresh; the next instant is fused as usual
                if not isinstance(exc, ValueError):  # a bug in the core: its trace once per kind, for the report
                    first = not any(FUSION_ERROR in counter for counter in self.rejects.values())
                    log.error("the fusion step raised %s: a bug, please report it", type(exc).__name__, exc_info=first)
                self._reject(
                    UNKNOWN_SENSOR,
                    FUSION_ERROR,
                    f"instant at {group.time_us} µs not fused: {type(exc).__name__}: {exc}",
                )
        return out

    def _fuse(self, group: FrameGroup, trigger_arrival_ns: int | None) -> FusedOutput:
        tick = time.perf_counter_ns()
        depth = self.depth
        instant = self.fuser.step(group) if depth is None else depth.step(self.fuser, group)
        fused = instant.frame
        if instant.people.held_out is not None:
            count_held_out(self.held_out, instant.people.held_out, fused.sensor_ids)
        payload = encode_fused_frame(fused)
        self.frames_out += 1
        if group.complete:
            self.groups_complete += 1
        else:
            self.groups_partial += 1
        return FusedOutput(
            fused,
            payload,
            instant.sensors_world,
            time.perf_counter_ns() - tick,
            trigger_arrival_ns,
            group.complete,
            () if depth is None else depth.last_clouds,
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


def _percentiles(values: Any) -> dict[str, float | int | None]:
    data = np.fromiter(values, dtype=np.float64)
    if data.size == 0:
        return {"p50": None, "p99": None, "max": None, "n": 0}
    p50, p99 = np.percentile(data, (50, 99)).tolist()  # one sort of up to LATENCY_WINDOW values, not two
    return {"p50": round(p50, 4), "p99": round(p99, 4), "max": round(float(data.max()), 4), "n": int(data.size)}


@dataclass(frozen=True)
class NodeOptions:
    """How the fusion node runs (the rig config says what it fuses).

    Attributes
    ----------
    node_name : str
        Key chunk of its status and liveliness keys (default ``[node] name``, else "fusion").
    status_period_s : float or None
        Default: the rig's ``[node] status_period_s``.
    poll_interval_s : float
        How often deadlines are checked when no frame arrives while an instant is open.
    drain_timeout_s : float
        The stop's budget after SIGTERM: queued samples are fused until the session close's share is left
        (``service.zenoh_io.StopBudget``), then open instants are flushed, "stopped" is said and the session
        closed with what is left.
    limits : RunLimits
        ``max_frames`` counts fused frames published.
    view : ViewOptions
        The live Rerun view (mode "off": none).
    """

    node_name: str | None = None
    status_period_s: float | None = None
    poll_interval_s: float = 0.002
    drain_timeout_s: float = 2.0
    limits: RunLimits = field(default_factory=RunLimits)
    view: ViewOptions = field(default_factory=ViewOptions)


@dataclass
class NodeReport:
    """What a fusion node run did (returned when it stops).

    Attributes
    ----------
    frames_in, frames_out : int
    fusion_ms : deque of float
        Time of each fusion step + encoding, ms (the latest :data:`LATENCY_WINDOW`: a daemon's record is
        bounded).
    added_ms : deque of float
        Arrival of the frame that completed an instant (zenoh callback) -> its fused frame handed to
        zenoh, ms: the latency the node adds (complete instants only; the latest :data:`LATENCY_WINDOW`).
    status : dict
        The last status document.
    """

    frames_in: int = 0
    frames_out: int = 0
    fusion_ms: collections.deque[float] = field(default_factory=lambda: collections.deque(maxlen=LATENCY_WINDOW))
    added_ms: collections.deque[float] = field(default_factory=lambda: collections.deque(maxlen=LATENCY_WINDOW))
    status: dict[str, Any] = field(default_factory=dict)


class FusionNode:
    """The fusion node's zenoh shell around :class:`FusionCore` (see the module docstring).

    Parameters
    ----------
    cfg : RigConfig
    zenoh_conf : zenoh.Config or None
        Used to open the session; ignored when ``session`` is given.
    options : NodeOptions
    lifecycle : Lifecycle
        Its ``should_exit`` stops the loop.
    session : zenoh.Session, optional
        A session owned by the caller (the demo shares one); not closed by the node.
    recording : rr.RecordingStream, optional
        An injected Rerun stream (the caller owns where it goes); overrides ``options.view.mode``.
    on_fused : callable, optional
        Called on the loop thread with every :class:`FusedOutput` after it is published.
    """

    def __init__(
        self,
        cfg: RigConfig,
        zenoh_conf: zenoh.Config | None,
        *,
        options: NodeOptions | None = None,
        lifecycle: Lifecycle | None = None,
        session: zenoh.Session | None = None,
        recording: Any = None,
        on_fused: Callable[[FusedOutput], None] | None = None,
    ) -> None:
        self.cfg = cfg
        self.options = options or NodeOptions()
        self.name = keys.validate_name(self.options.node_name or cfg.node.name or "fusion", "node")
        self.lifecycle = lifecycle or Lifecycle(self.name)
        self.depth = depth_stage_for(cfg)  # [fusion] mode depth / hybrid; its tracker opens here or raises
        self.core = FusionCore(cfg, first_track_id=time_based_first_track_id(time.time_ns()), depth=self.depth)
        self.pose_origin = cfg.describe_poses()
        self.pose_fit = PoseFitMonitor(cfg.sensor_ids)  # the live "sensor moved" alarm
        self.zenoh_conf = zenoh_conf
        self.session = session
        self.recording = recording
        self.on_fused = on_fused
        self.report = NodeReport()
        self.ready = threading.Event()
        self._window_added: list[float] = []
        self._window_fusion: list[float] = []
        self._first_time_us: int | None = None
        self._rates: dict[str, float] | None = None
        self.view: RerunView | None = None
        self._samples: SampleQueue | None = None
        self._fused_publisher: FusedPublisher | None = None

    def log_error(self, time_us: int, error_mm: float) -> None:
        """Draw an error against ground truth (simulated rigs) on the live view's time axis, if there is one."""
        view, first = self.view, self._first_time_us
        if view is not None and first is not None:
            view.log_error((time_us - first) / 1e6, error_mm)

    def run(self) -> NodeReport:
        """Open zenoh (retrying), serve until ``lifecycle.should_exit`` or the run limits, drain, close."""
        own_session = self.session is None
        session = self.session
        self._started = time.monotonic()  # an unreachable router cannot hold the node past --duration
        if session is None:
            assert self.zenoh_conf is not None
            session = open_session(
                self.zenoh_conf,
                lifecycle=self.lifecycle,
                what=f"fusion node {self.name}",
                deadline=self.options.limits.deadline(self._started),
            )
            if session is None:
                if self.depth is not None:
                    self.depth.close()  # the tracker(s) it opened
                return self.report
        view, server = self._open_view()
        self.view = view
        budget: StopBudget | None = None  # from the stop's start
        rig = self.cfg.name
        intake = self.cfg.intake
        samples = self._samples = SampleQueue(
            max_items=intake.max_queue,
            max_payload_bytes=intake.max_payload_bytes,
            max_items_per_key=intake.max_queue_per_key,
            max_bytes=intake.max_queue_bytes,
            labels={keys.sensor_skeletons(rig, sid): sid for sid in self.cfg.sensor_ids},  # fair per sensor
        )
        try:
            z = self.cfg.zenoh
            publisher = self._fused_publisher = FusedPublisher(
                session,
                keys.fused_skeletons(rig),
                congestion_control=z.fused_congestion_control,
                bound_ms=z.wait_before_drop_ms if z.fused_congestion_control == "drop" else z.wait_before_close_ms,
            )
            status_pub = session.declare_publisher(keys.status(rig, self.name))
            calibration = json.dumps(calibration_document(self.cfg, self.core.poses)).encode()
            calibration_key = keys.calibration(rig)
            queryable = session.declare_queryable(
                calibration_key, lambda query: query.reply(calibration_key, calibration)
            )
            token = session.liveliness().declare_token(keys.alive(rig, self.name))
            subscriber = session.declare_subscriber(keys.all_sensor_skeletons(rig), samples)
            clouds = (
                None
                if self.depth is None
                else session.declare_subscriber(keys.all_sensor_clouds(rig), self.depth.clouds)
            )
            log.info(
                "fusion node %s: rig %s, %d sensors (%s), grouping by %s time, tolerance %.1f ms, deadline "
                "%.1f ms, preset %s; publishing on %s",
                self.name,
                rig,
                len(self.cfg.sensors),
                ", ".join(self.cfg.sensor_ids),
                self.cfg.sync.by,
                self.cfg.sync.tolerance_ms,
                self.cfg.sync.deadline_ms,
                self.cfg.fusion.preset,
                keys.fused_skeletons(rig),
            )
            log.info("fusion node %s: poses: %s", self.name, self.pose_origin)
            if self.depth is not None:
                log.info("fusion node %s: depth-level fusion, %s", self.name, self.depth.describe())
            self.ready.set()
            self._loop(samples, publisher, status_pub, view)
            self.lifecycle.request_exit()  # the stop begins (arms the stop watchdog after a run limit too)
            # Shutdown, all within the drain timeout: stop taking input, fuse what is queued until the budget
            # leaves only the close's share, flush open instants, say "stopped", close with what is left.
            budget = StopBudget.start(self.options.drain_timeout_s)
            subscriber.undeclare()
            if clouds is not None:
                clouds.undeclare()
            drained = 0
            while not self.lifecycle.force_exit and time.monotonic() < budget.drain_until:
                item = samples.get_nowait()
                if item is None:
                    break
                self._publish(self.core.receive(item.key, item.payload, item.arrival_ns), publisher, view)
                drained += 1
            drained_s = time.monotonic() - budget.began
            self._publish(self.core.flush(), publisher, view)
            self._publish_status(status_pub, "stopped", time.monotonic_ns())
            token.undeclare()
            queryable.undeclare()
            publisher.undeclare()
            status_pub.undeclare()
            log.info(
                "fusion node %s: stopping: %d queued samples fused in %.3f s (%d left), flushed and said "
                "stopped at %.3f s of its %.1f s drain timeout",
                self.name,
                drained,
                drained_s,
                samples.qsize(),
                time.monotonic() - budget.began,
                self.options.drain_timeout_s,
            )
        finally:
            self.lifecycle.request_exit()
            self.ready.set()
            if view is not None:
                view.close(timeout_s=0.5 if self.lifecycle.force_exit else 5.0)
            stop_server(server)
            if self.depth is not None:
                self.depth.close()
            if own_session:
                close_session(
                    session,
                    what=f"fusion node {self.name}",
                    timeout_s=SESSION_CLOSE_TIMEOUT_S if budget is None else budget.close_timeout_s(),
                )
        self.report.frames_in = self.core.frames_in
        self.report.frames_out = self.core.frames_out
        log.info(
            "fusion node %s stopped: %d payloads in, %d fused frames out",
            self.name,
            self.core.frames_in,
            self.core.frames_out,
        )
        return self.report

    def _open_view(self) -> tuple[RerunView | None, Any]:
        view_options = self.options.view
        recording, server = self.recording, None
        if recording is None and view_options.mode != "off":
            recording, server = open_recording(view_options)
        if recording is None:
            return None, None
        return RerunView(recording, self.cfg.sensor_ids, self.core.poses, log_sensors=view_options.log_sensors), server

    def _loop(self, samples: SampleQueue, publisher: Any, status_pub: Any, view: RerunView | None) -> None:
        period_s = self.options.status_period_s or self.cfg.node.status_period_s
        period_ns = int(period_s * 1e9)
        start = time.monotonic()  # --duration of fusing; the wait for a session before is bounded by it too
        next_status = time.monotonic_ns()
        last_status = next_status
        limits = self.options.limits
        deadline = limits.deadline(start)
        poll_s = self.options.poll_interval_s
        while not self.lifecycle.should_exit:
            # Deadlines belong to open instants: with none open only a frame can make one due, so the loop
            # sleeps until a frame arrives (woken at once), the status is due, or IDLE_WAIT_S for the stop check.
            if self.core.grouper.n_open:
                wait_s = poll_s
            else:
                wait_s = min(IDLE_WAIT_S, max((next_status - time.monotonic_ns()) / 1e9, poll_s))
            item = samples.get(timeout=wait_s)
            emptied = True
            while item is not None:
                # Each instant goes out as soon as it is fused, not after the rest of a backlog is read. Deadlines
                # are looked at only once the queue is empty (a queued frame arrived in time, whatever the time
                # now), but a stop is seen between any two samples (a starved node's backlog never hides it),
                # and so is an overdue status: a node a little behind for long (its queue never quite empty)
                # published none for over 10 s (session 22).
                self._publish(self.core.receive(item.key, item.payload, item.arrival_ns), publisher, view)
                if self.lifecycle.should_exit:
                    break
                if time.monotonic_ns() >= next_status + period_ns:
                    emptied = False
                    break
                item = samples.get_nowait()
            now_ns = time.monotonic_ns()
            if emptied:
                self._publish(self.core.poll(now_ns), publisher, view)
            # The status waits for a quiet moment (no instant half received, so no frame of one queues behind
            # it), at most one period.
            quiet = not self.core.grouper.n_open or now_ns >= next_status + period_ns
            if now_ns >= next_status and quiet:
                window_s = (now_ns - last_status) / 1e9
                self._rates = None
                self._publish_status(status_pub, None, now_ns, window_s)
                last_status = now_ns
                next_status = now_ns + period_ns
            if limits.max_frames is not None and self.core.frames_out >= limits.max_frames:
                log.info("fusion node %s: --max-frames %d reached", self.name, limits.max_frames)
                break
            if time.monotonic() >= deadline:
                log.info("fusion node %s: --duration %.1f s reached", self.name, limits.duration_s)
                break

    def _publish(self, outputs: list[FusedOutput], publisher: Any, view: RerunView | None) -> None:
        for out in outputs:
            publisher.put(out.payload)
            done_ns = time.monotonic_ns()
            for change in self.pose_fit.update(out.sensors_world, out.frame.positions):
                self._log_fit(change)
            fusion_ms = out.fusion_ns / 1e6
            self._window_fusion.append(fusion_ms)
            self.report.fusion_ms.append(fusion_ms)
            added_ms = None
            if out.trigger_arrival_ns is not None:
                added_ms = (done_ns - out.trigger_arrival_ns) / 1e6
                self._window_added.append(added_ms)
                self.report.added_ms.append(added_ms)
            if view is not None:
                if self._first_time_us is None:
                    self._first_time_us = out.frame.time_us
                view.submit(
                    (out.frame.time_us - self._first_time_us) / 1e6,
                    out.sensors_world,
                    out.frame.positions,
                    out.frame.track_ids,
                    fusion_ms,
                    added_ms,
                    self._rates,
                )
                if out.clouds:
                    view.log_clouds((out.frame.time_us - self._first_time_us) / 1e6, out.clouds)
            if self.on_fused is not None:
                self.on_fused(out)

    def _log_fit(self, change: FitChange) -> None:
        if change.fits:
            log.info(
                "fusion node %s: sensor %s fits the others again (median %.0f mm from the fused people)",
                self.name,
                change.sensor_id,
                change.median_mm,
            )
            return
        log.warning(
            "fusion node %s: sensor %s's pose no longer fits the others: its bodies lie a median %.0f mm from the "
            "fused people over its last %d instants (alarm above %.0f mm). Was it moved or knocked? Check with "
            "`skelfuse calibrate check`, then recalibrate",
            self.name,
            change.sensor_id,
            change.median_mm,
            change.frames,
            self.pose_fit.threshold_mm,
            extra={"sensor": change.sensor_id, "alarm": "pose_moved"},
        )

    def _state(self, now_ns: int, pose_fit: dict[str, dict[str, Any]]) -> str:
        seen = [w.last_seen_ns for w in self.core._sensors.values()]
        if all(s is None for s in seen):
            return "starting"
        stale = any(s is None or now_ns - s > 1e9 for s in seen)
        moved = any(fit["fits"] is False for fit in pose_fit.values())
        return "degraded" if stale or moved else "running"

    def _publish_status(self, status_pub: Any, state: str | None, now_ns: int, window_s: float | None = None) -> None:
        """Build and put the status (``state`` None: judged from the sensors and the pose-fit monitor). It runs
        on the fusion loop, so a frame arriving meanwhile waits for it: 1.1-1.4 ms p50 at 4-8 sensors, about 2 ms at
        16 (``scripts/node_latency_breakdown.py``, 2026-11-28), and published at a quiet moment of the loop."""
        core = self.core
        pose_fit = self.pose_fit.report()
        state = state or self._state(now_ns, pose_fit)
        window_s = window_s or 1.0
        sensors = core.sensor_report(now_ns, window_s)
        self._rates = {sid: s["rate_hz"] for sid, s in sensors.items() if s["rate_hz"] is not None}
        queue = {} if self._samples is None else self._samples.counts()  # the intake queue, per sensor key
        no_drops = {"queued": 0, "dropped": 0, "oversized": 0}
        for sid, report in sensors.items():
            report["queue"] = queue.get(sid, no_drops)
        stats = core.grouper.stats
        totals = stats.totals
        reject_totals: Counter[str] = Counter()
        for counter in core.rejects.values():
            reject_totals.update(counter)
        counters = {
            "frames_in": core.frames_in,
            "frames_out": core.frames_out,
            "groups_complete": core.groups_complete,
            "groups_partial": core.groups_partial,
            "deadline_emits": core.deadline_emits,
            "late": totals.late,
            "dropped": totals.dropped,
            "duplicate": totals.duplicate,
            "out_of_window": totals.out_of_window,
            "unknown": stats.unknown,
            "resyncs": stats.resyncs,
            "off_clock": totals.off_clock,
            "persons_refused": core.fuser.people.table.births_refused,
            "samples_dropped": 0 if self._samples is None else self._samples.dropped,
            "samples_oversized": 0 if self._samples is None else self._samples.oversized,
            "invalid": sum(reject_totals.values()),
        } | {f"rejects.{reason}": n for reason, n in sorted(reject_totals.items())}
        info = {
            "rig": self.cfg.name,
            "preset": self.cfg.fusion.preset,
            "sync_by": self.cfg.sync.by,
            "window_s": round(window_s, 4),
            "fused_rate_hz": round(len(self._window_fusion) / window_s, 3),
            "sensors": sensors,
            "pose_fit": pose_fit,
            "unknown_ids": stats.unknown_ids,
            "rejects_unknown_sensor": dict(core.rejects.get(UNKNOWN_SENSOR, {})),
            "queue_unknown_keys": queue.get(OTHER_KEYS, no_drops),
            "fused_publish": None if self._fused_publisher is None else self._fused_publisher.report(),
            "fusion_ms": _percentiles(self._window_fusion),
            "node_added_ms": _percentiles(self._window_added),
            # The window's own values: percentiles of windows do not merge, samples do (bench latency, dashboards).
            "fusion_ms_samples": [round(v, 4) for v in self._window_fusion],
            "node_added_ms_samples": [round(v, 4) for v in self._window_added],
            "fusion_ms_total": _percentiles(self.report.fusion_ms),  # the latest LATENCY_WINDOW
            "node_added_ms_total": _percentiles(self.report.added_ms),
        }
        if self.depth is not None:
            info["depth"] = self.depth.report()
        self._window_fusion.clear()
        self._window_added.clear()
        status = NodeStatus(
            node=self.name, role="fusion", state=state, time_ns=time.time_ns(), counters=counters, info=info
        )
        self.report.status = {"state": state, "counters": counters, "info": info}
        try:
            status_pub.put(encode_status(status))
        except ValueError:
            log.exception("fusion node %s: status could not be encoded", self.name)


def run_fusion_node(
    cfg: RigConfig, zenoh_conf: zenoh.Config, *, options: NodeOptions, lifecycle: Lifecycle
) -> NodeReport:
    """``skelfuse fuse --config RIG.toml``: run the node in this thread (signals via ``lifecycle``)."""
    node = FusionNode(cfg, zenoh_conf, options=options, lifecycle=lifecycle)
    with lifecycle.capture_signals():
        return node.run()
