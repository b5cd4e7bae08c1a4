"""``skelfuse record`` and ``skelfuse replay``: the zenoh ends of :mod:`skelfuse.recording`.

Recorder cycle: subscribe to ``skelfuse/<rig>/sensors/*/skeletons`` and, with ``[record] fused`` (the
default), to ``skelfuse/<rig>/fused/skeletons`` (one :class:`SampleQueue`, one writer thread) ->
``RecordingWriter.write_payload`` / ``write_fused_payload`` (the bytes as received, a fused frame stamped
with the host time it arrived; a payload that fails to decode is counted per reason and not written) ->
``flush()`` every ``[record] flush_period_s`` even when idle, so a killed recorder leaves a file readable up
to its last flush -> ``close()`` on SIGINT/SIGTERM or the run limits (index and footer written).

Replay cycle: ``replay_frames(reader, speed=...)`` paces the recorded frames by their host time; each
payload is published unchanged on its recorded topic (or on the same sensor's key of another rig with
``--rig``).
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from skelfuse.config import RigConfig
from skelfuse.recording import RecordedFrame, RecordingReader, RecordingWriter, replay_frames
from skelfuse.recording.inputs import InputTake
from skelfuse.schema.errors import ConfigError, ServiceError
from skelfuse.service.lifecycle import Lifecycle, RunLimits
from skelfuse.service.zenoh_io import SampleQueue, close_session, open_session
from skelfuse.wire import keys
from skelfuse.wire.codec import DecodeError

if TYPE_CHECKING:  # pragma: no cover - typing only
    import zenoh

log = logging.getLogger("skelfuse.service.recorder")


def default_recording_path(cfg: RigConfig) -> Path:
    """``<[record] directory or .>/<rig>-<UTC time>.mcap``."""
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    directory = cfg.record.directory if cfg.record.directory is not None else Path(".")
    return directory / f"{cfg.name}-{stamp}.mcap"


@dataclass
class RecordReport:
    path: Path
    frames_written: int = 0
    fused_frames_written: int = 0
    clouds_written: int = 0
    rejects: Counter[str] = field(default_factory=Counter)


def run_recorder(
    cfg: RigConfig, zenoh_conf: zenoh.Config, *, output: Path | None, limits: RunLimits, lifecycle: Lifecycle
) -> RecordReport:
    """Record every raw sensor frame of the rig (and its fused stream, ``[record] fused``) to MCAP until a signal
    or the run limits."""

    if not cfg.record.sensors and not cfg.record.fused:
        raise ConfigError(f"{cfg.source}: [record] sensors and fused are both false: nothing to record")
    path = Path(output) if output is not None else default_recording_path(cfg)
    if (
        output is None
    ):  # [record] directory is the operator's choice: create it; an explicit --output's folder must exist
        path.parent.mkdir(parents=True, exist_ok=True)
    report = RecordReport(path)
    flush_s = cfg.record.flush_period_s
    with lifecycle.capture_signals():
        start = time.monotonic()
        session = open_session(zenoh_conf, lifecycle=lifecycle, what="recorder", deadline=limits.deadline(start))
        if session is None:
            return report
        samples = SampleQueue()
        try:
            writer = RecordingWriter(
                path,
                rig=cfg.name,
                sensor_ids=cfg.sensor_ids,
                world_from_sensor=cfg.poses(required=False) or None,
                flush_interval_s=flush_s,
                metadata={"recorder": "skelfuse record"},
            )
        except OSError as exc:  # a full disk, a read-only folder: the recorder cannot do its work
            lifecycle.request_exit()
            close_session(session, what="recorder")
            raise _write_failed(path, exc, None) from None
        failure: OSError | None = None
        try:
            subscribers, token = _subscribe(session, cfg, samples, path)
            _record(writer, samples, report, lifecycle, limits, start, flush_s, keys.fused_skeletons(cfg.name))
            lifecycle.request_exit()  # the stop begins (bounded by the stop watchdog)
            for subscriber in subscribers:
                subscriber.undeclare()
            token.undeclare()
        except OSError as exc:  # the file cannot take more: stop, keep what was flushed
            failure = exc
        finally:
            lifecycle.request_exit()
            try:
                writer.close()
            except OSError as exc:
                failure = failure or exc
            close_session(session, what="recorder")
    report.frames_written = writer.frames_written
    report.fused_frames_written = writer.fused_frames_written
    report.clouds_written = writer.clouds_written
    if failure is not None:
        raise _write_failed(path, failure, report)
    log.info(
        "recorder: %d sensor frames and %d fused frames written to %s (%d rejected)",
        report.frames_written,
        report.fused_frames_written,
        path,
        sum(report.rejects.values()),
    )
    return report


def _subscribe(session: Any, cfg: RigConfig, samples: SampleQueue, path: Path) -> tuple[list[Any], Any]:
    """The recorder's subscribers (per ``[record]`` and the fusion mode) and its liveliness token."""
    subscribers = []
    # [record] sensors: the raw sensor frames (what `fuse --input` and `replay` read back)
    if cfg.record.sensors:
        subscribers.append(session.declare_subscriber(keys.all_sensor_skeletons(cfg.name), samples))
    # [record] fused: the fused stream's payloads as received, on the fused key's channel
    if cfg.record.fused:
        subscribers.append(session.declare_subscriber(keys.fused_skeletons(cfg.name), samples))
    # depth / hybrid mode: the workers' person clouds too (what `skelfuse calibrate refine` reads)
    clouds = cfg.fusion.mode != "skeleton"
    if clouds:
        subscribers.append(session.declare_subscriber(keys.all_sensor_clouds(cfg.name), samples))
    token = session.liveliness().declare_token(keys.alive(cfg.name, "recorder"))
    streams = ["sensor frames" if cfg.record.sensors else "no sensor frames ([record] sensors = false)"]
    if cfg.record.fused:
        streams.append("fused frames")
    if clouds:
        streams.append(f"person clouds ([fusion] mode = {cfg.fusion.mode!r})")
    log.info(
        "recorder: writing rig %s's %s to %s (flush every %.1f s)",
        cfg.name,
        ", ".join(streams),
        path,
        cfg.record.flush_period_s,
    )
    return subscribers, token


def _record(
    writer: RecordingWriter,
    samples: SampleQueue,
    report: RecordReport,
    lifecycle: Lifecycle,
    limits: RunLimits,
    start: float,
    flush_s: float,
    fused_key: str,
) -> None:
    """Write what arrives until a signal or the run limits, flushing every ``flush_s``; bad payloads counted."""
    next_flush = start + flush_s
    while not lifecycle.should_exit and not limits.reached(writer.frames_written, start):
        item = samples.get(timeout=0.05)
        while item is not None:
            try:
                if item.key == fused_key:
                    writer.write_fused_payload(item.payload, log_time_ns=_wall_time_ns(item.arrival_ns))
                elif item.key.endswith("/clouds"):
                    writer.write_clouds_payload(item.payload)
                else:
                    writer.write_payload(item.payload)
            except DecodeError as exc:
                report.rejects[exc.reason] += 1
                if report.rejects[exc.reason] == 1:
                    log.warning("recorder: rejected a payload on %s (%s): %s", item.key, exc.reason, exc)
            if limits.max_frames is not None and writer.frames_written >= limits.max_frames:
                break
            item = samples.get_nowait()
        if time.monotonic() >= next_flush:
            writer.flush()
            next_flush = time.monotonic() + flush_s


def _write_failed(path: Path, exc: OSError, report: RecordReport | None) -> ServiceError:
    """The recorder's error for a file it cannot write (what failed, what was kept, what to do)."""
    kept = (
        ""
        if report is None
        else f"; of the {report.frames_written} sensor frames and {report.fused_frames_written} fused frames "
        "received, the file holds those up to its last flush (`fuse --input` reads it and says where it ends)"
    )
    return ServiceError(
        f"recorder: cannot write the recording {path} ({exc.strerror or exc}){kept}; free disk space or record "
        "to another --output / [record] directory"
    )


def _wall_time_ns(arrival_monotonic_ns: int) -> int:
    """The wall-clock time (ns since the Unix epoch) of a sample stamped with ``time.monotonic_ns()`` on arrival."""
    return time.time_ns() - (time.monotonic_ns() - arrival_monotonic_ns)


@dataclass
class ReplayReport:
    frames_out: int = 0
    topics: set[str] = field(default_factory=set)


def run_replay(
    path: Path | InputTake,
    zenoh_conf: zenoh.Config,
    *,
    speed: float | None,
    rig: str | None,
    limits: RunLimits,
    lifecycle: Lifecycle,
) -> ReplayReport:
    """Publish a recording's sensor frames at ``speed`` (None: as fast as possible).

    ``path``: a skelfuse MCAP (payloads republished byte for byte on their recorded keys, paced by the
    recorded host time) or a take of any format opened by :func:`skelfuse.recording.inputs.open_inputs`
    (frames encoded and published under ``rig`` (default ``replay``), paced by their matched times).
    """

    if isinstance(path, InputTake):
        take = path
        reader: RecordingReader | Iterable[RecordedFrame] = take.records(rig or "replay")
        sensors = ", ".join(take.sensor_ids)
        rig = None  # the records' topics already name the rig
        path = Path(take.recordings[0].source)
    else:
        recording = RecordingReader(path)
        sensors = ", ".join(recording.sensors)
        reader = recording
    report = ReplayReport()
    with lifecycle.capture_signals():
        start = time.monotonic()
        session = open_session(zenoh_conf, lifecycle=lifecycle, what="replay", deadline=limits.deadline(start))
        if session is None:
            return report
        publishers: dict[str, zenoh.Publisher] = {}
        try:
            log.info(
                "replay: %s (%s) at %s",
                path,
                sensors,
                "maximum speed" if speed is None else f"{speed:g}x",
            )
            for _, record in replay_frames(reader, speed=speed, sleep=lifecycle.wait):
                if lifecycle.should_exit or limits.reached(report.frames_out, start):
                    break
                topic = record.topic if rig is None else keys.sensor_skeletons(rig, record.sensor_id)
                publisher = publishers.get(topic)
                if publisher is None:
                    publisher = publishers[topic] = session.declare_publisher(topic, express=True)
                publisher.put(record.payload)
                report.frames_out += 1
                report.topics.add(topic)
        finally:
            lifecycle.request_exit()
            close_session(session, what="replay")
    log.info("replay: %d frames published on %d topics", report.frames_out, len(report.topics))
    return report
