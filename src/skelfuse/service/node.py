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
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from skelfuse.config import RigConfig
from skelfuse.fusion import kernels
from skelfuse.service.fusion_core import (
    BAD_KEY,
    FUSION_ERROR,
    IDLE_WAIT_S,
    KEY_MISMATCH,
    LATENCY_WINDOW,
    OUT_OF_VOLUME,
    OVERSIZED,
    TOO_MANY_BODIES,
    TRACK_ID_EPOCH_S,
    UNKNOWN_SENSOR,
    FusedOutput,
    FusionCore,
    calibration_document,
    time_based_first_track_id,
)
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
from skelfuse.wire.codec import NodeStatus, encode_status

if TYPE_CHECKING:  # pragma: no cover - typing only
    import zenoh

    from skelfuse.service.depth_stage import DepthStage

log = logging.getLogger("skelfuse.service.node")


def prepare_kernels(name: str) -> None:
    """Compile the fusion kernels now, or load them from the user cache; a first start says it is compiling."""
    started = time.monotonic()
    if kernels.is_cached():
        kernels.warm_up()
        log.debug("fusion node %s: fusion kernels loaded in %.2f s", name, time.monotonic() - started)
        return
    log.info(
        "fusion node %s: compiling the fusion kernels (first start; cached in %s for the next ones) ...",
        name,
        kernels.cache_dir(),
    )
    kernels.warm_up()
    log.info("fusion node %s: fusion kernels compiled in %.1f s", name, time.monotonic() - started)


# The core lives in skelfuse.service.fusion_core; its names are re-exported here for the node's users.
__all__ = [
    "BAD_KEY",
    "FUSION_ERROR",
    "IDLE_WAIT_S",
    "KEY_MISMATCH",
    "LATENCY_WINDOW",
    "OUT_OF_VOLUME",
    "OVERSIZED",
    "TOO_MANY_BODIES",
    "TRACK_ID_EPOCH_S",
    "UNKNOWN_SENSOR",
    "FusedOutput",
    "FusionCore",
    "FusionNode",
    "NodeOptions",
    "NodeReport",
    "calibration_document",
    "run_fusion_node",
    "time_based_first_track_id",
]


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


@dataclass(frozen=True)
class _Declared:
    """The zenoh entities a running fusion node holds (undeclared at its stop)."""

    publisher: FusedPublisher
    status_pub: Any
    queryable: Any
    token: Any
    subscriber: Any
    clouds: Any  # the person-cloud subscriber (depth / hybrid mode), else None


def fixed_lag_line(lag_frames: int, fps: float) -> str:
    """What the node says at start about ``[fusion] fixed_lag_frames``: the latency it adds."""
    return (
        f"fixed-lag smoothing over {lag_frames} frames adds {1000.0 * lag_frames / fps:.1f} ms of latency "
        f"({lag_frames} frames at {fps:g} fps): each fused frame is published {lag_frames} instants later, smoothed"
    )


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
        self.depth = _depth_stage(cfg)  # [fusion] mode depth / hybrid; its tracker opens here or raises
        self.core = FusionCore(cfg, first_track_id=time_based_first_track_id(time.time_ns()), depth=self.depth)
        self.core.shedder.what = f"fusion node {self.name}"
        prepare_kernels(self.name)  # before the first instant: a first start compiles them (seconds)
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
        samples = self._samples = self._sample_queue()
        try:
            declared = self._declare(session, samples)
            self._log_start()
            self.ready.set()
            self._loop(samples, declared.publisher, declared.status_pub, view)
            self.lifecycle.request_exit()  # the stop begins (arms the stop watchdog after a run limit too)
            budget = StopBudget.start(self.options.drain_timeout_s)
            self._drain_and_undeclare(budget, samples, declared, view)
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

    def _sample_queue(self) -> SampleQueue:
        """The intake queue of sensor payloads, bounded by ``[intake]``, fair per sensor."""
        rig, intake = self.cfg.name, self.cfg.intake
        return SampleQueue(
            max_items=intake.max_queue,
            max_payload_bytes=intake.max_payload_bytes,
            max_items_per_key=intake.max_queue_per_key,
            max_bytes=intake.max_queue_bytes,
            labels={keys.sensor_skeletons(rig, sid): sid for sid in self.cfg.sensor_ids},  # fair per sensor
        )

    def _declare(self, session: Any, samples: SampleQueue) -> _Declared:
        """The node's zenoh entities: fused publisher, status, calibration queryable, liveliness, subscribers."""
        rig, z = self.cfg.name, self.cfg.zenoh
        publisher = self._fused_publisher = FusedPublisher(
            session,
            keys.fused_skeletons(rig),
            congestion_control=z.fused_congestion_control,
            bound_ms=z.wait_before_drop_ms if z.fused_congestion_control == "drop" else z.wait_before_close_ms,
        )
        status_pub = session.declare_publisher(keys.status(rig, self.name))
        calibration = json.dumps(calibration_document(self.cfg, self.core.poses)).encode()
        calibration_key = keys.calibration(rig)
        queryable = session.declare_queryable(calibration_key, lambda query: query.reply(calibration_key, calibration))
        token = session.liveliness().declare_token(keys.alive(rig, self.name))
        subscriber = session.declare_subscriber(keys.all_sensor_skeletons(rig), samples)
        clouds = (
            None if self.depth is None else session.declare_subscriber(keys.all_sensor_clouds(rig), self.depth.clouds)
        )
        return _Declared(publisher, status_pub, queryable, token, subscriber, clouds)

    def _log_start(self) -> None:
        rig = self.cfg.name
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
        if self.core.fixed_lag_frames:
            log.info("fusion node %s: %s", self.name, fixed_lag_line(self.core.fixed_lag_frames, self.cfg.sync.fps))
        if self.depth is not None:
            log.info("fusion node %s: depth-level fusion, %s", self.name, self.depth.describe())

    def _drain_and_undeclare(
        self, budget: StopBudget, samples: SampleQueue, declared: _Declared, view: RerunView | None
    ) -> None:
        """The stop, within the drain timeout: stop taking input, fuse what is queued until the budget leaves
        only the close's share, flush open instants, say "stopped", undeclare."""
        publisher, status_pub = declared.publisher, declared.status_pub
        declared.subscriber.undeclare()
        if declared.clouds is not None:
            declared.clouds.undeclare()
        drained = 0
        while not self.lifecycle.force_exit and time.monotonic() < budget.drain_until:
            item = samples.get_nowait()
            if item is None:
                break
            self._publish(
                self.core.receive(item.key, item.payload, item.arrival_ns, time.monotonic_ns()), publisher, view
            )
            drained += 1
        drained_s = time.monotonic() - budget.began
        self._publish(self.core.flush(time.monotonic_ns()), publisher, view)
        self._publish_status(status_pub, "stopped", time.monotonic_ns())
        declared.token.undeclare()
        declared.queryable.undeclare()
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
                # published none for over 10 s.
                outputs = self.core.receive(item.key, item.payload, item.arrival_ns, time.monotonic_ns())
                self._publish(outputs, publisher, view)
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
            for change in self.pose_fit.update(out.sensors_world, *out.fit_inputs()):
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
                    agreement_mm=out.frame.agreement_mm,
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
        on the fusion loop, so a frame arriving meanwhile waits for it (``scripts/node_latency_breakdown.py``
        measures how long), and published at a quiet moment of the loop."""
        core = self.core
        pose_fit = self.pose_fit.report()
        state = state or self._state(now_ns, pose_fit)
        window_s = window_s or 1.0
        sensors = core.sensor_report(now_ns, window_s)
        self._rates = {sid: s["rate_hz"] for sid, s in sensors.items() if s["rate_hz"] is not None}
        queue = {} if self._samples is None else self._samples.counts()  # the intake queue, per sensor key
        no_drops = {"queued": 0, "dropped": 0, "oversized": 0}
        shedder = core.shedder
        for sid, report in sensors.items():
            report["queue"] = queue.get(sid, no_drops)
            report["shed"] = shedder.frames_by_sensor[sid]
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
            "groups_incomplete": stats.groups - stats.complete_groups,
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
            "instants_shed": shedder.total,
        } | {f"rejects.{reason}": n for reason, n in sorted(reject_totals.items())}
        counters |= {f"shed.{reason}": n for reason, n in sorted(shedder.by_reason.items())}
        info = {
            "rig": self.cfg.name,
            "preset": self.cfg.fusion.preset,
            "sync_by": self.cfg.sync.by,
            "max_lag_s": shedder.max_lag_s,
            "shed_episodes": shedder.episodes,
            "window_s": round(window_s, 4),
            "fused_rate_hz": round(len(self._window_fusion) / window_s, 3),
            "fixed_lag_ms": round(1000.0 * core.fixed_lag_frames / self.cfg.sync.fps, 3),
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


def _depth_stage(cfg: RigConfig) -> DepthStage | None:
    """The depth stage of a depth or hybrid rig; its module (scipy's spatial and ndimage) is imported only
    there, so a skeleton rig's node opens its session sooner."""
    if cfg.fusion.mode == "skeleton":
        return None
    from skelfuse.service.depth_stage import depth_stage_for

    return depth_stage_for(cfg)


def run_fusion_node(
    cfg: RigConfig, zenoh_conf: zenoh.Config, *, options: NodeOptions, lifecycle: Lifecycle
) -> NodeReport:
    """``skelfuse fuse --config RIG.toml``: run the node in this thread (signals via ``lifecycle``)."""
    node = FusionNode(cfg, zenoh_conf, options=options, lifecycle=lifecycle)
    with lifecycle.capture_signals():
        return node.run()
