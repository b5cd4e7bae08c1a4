"""``skelfuse record`` and ``skelfuse replay``: the zenoh ends of :mod:`skelfuse.recording`.

Recorder cycle: subscribe to ``skelfuse/<rig>/sensors/*/skeletons`` (:class:`SampleQueue`, one writer
thread) -> ``RecordingWriter.write_payload`` (the bytes as received; a payload that fails to decode is
counted per reason and not written) -> ``flush()`` every ``[record] flush_period_s`` even when idle, so a
killed recorder leaves a file readable up to its last flush -> ``close()`` on SIGINT/SIGTERM or the run
limits (index and footer written).

Replay cycle: ``replay_frames(reader, speed=...)`` paces the recorded frames by their host time; each
payload is published unchanged on its recorded topic (or on the same sensor's key of another rig with
``--rig``).
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

from skelfuse.config import RigConfig
from skelfuse.recording import RecordingReader, RecordingWriter, replay_frames
from skelfuse.schema.errors import ConfigError
from skelfuse.service.lifecycle import Lifecycle, RunLimits
from skelfuse.service.zenoh_io import SampleQueue, open_session
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
    rejects: Counter[str] = field(default_factory=Counter)


def run_recorder(
    cfg: RigConfig, zenoh_conf: zenoh.Config, *, output: Path | None, limits: RunLimits, lifecycle: Lifecycle
) -> RecordReport:
    """Record every raw sensor frame of the rig to MCAP until a signal or the run limits."""

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
        writer = RecordingWriter(
            path,
            rig=cfg.name,
            sensor_ids=cfg.sensor_ids,
            world_from_sensor=cfg.poses(required=False) or None,
            flush_interval_s=flush_s,
            metadata={"recorder": "skelfuse record"},
        )
        try:
            # [record] sensors: the raw sensor frames (what `fuse --input` and `replay` read back)
            subscriber = (
                session.declare_subscriber(keys.all_sensor_skeletons(cfg.name), samples) if cfg.record.sensors else None
            )
            token = session.liveliness().declare_token(keys.alive(cfg.name, "recorder"))
            streams = ["sensor frames" if cfg.record.sensors else "no sensor frames ([record] sensors = false)"]
            log.info(
                "recorder: writing rig %s's %s to %s (flush every %.1f s)", cfg.name, ", ".join(streams), path, flush_s
            )
            next_flush = start + flush_s
            while not lifecycle.should_exit and not limits.reached(writer.frames_written, start):
                item = samples.get(timeout=0.05)
                while item is not None:
                    try:
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
            lifecycle.request_exit()  # the stop begins (bounded by the stop watchdog)
            if subscriber is not None:
                subscriber.undeclare()
            token.undeclare()
        finally:
            lifecycle.request_exit()
            writer.close()
            session.close()
    report.frames_written = writer.frames_written
    log.info(
        "recorder: %d frames written to %s (%d rejected)", report.frames_written, path, sum(report.rejects.values())
    )
    return report


@dataclass
class ReplayReport:
    frames_out: int = 0
    topics: set[str] = field(default_factory=set)


def run_replay(
    path: Path,
    zenoh_conf: zenoh.Config,
    *,
    speed: float | None,
    rig: str | None,
    limits: RunLimits,
    lifecycle: Lifecycle,
) -> ReplayReport:
    """Publish a recording's sensor frames at ``speed`` (None: as fast as possible)."""

    reader = RecordingReader(path)
    report = ReplayReport()
    with lifecycle.capture_signals():
        start = time.monotonic()
        session = open_session(zenoh_conf, lifecycle=lifecycle, what="replay", deadline=limits.deadline(start))
        if session is None:
            return report
        publishers: dict[str, object] = {}
        try:
            log.info(
                "replay: %s (%s) at %s",
                path,
                ", ".join(reader.sensors),
                "maximum speed" if speed is None else f"{speed:g}x",
            )
            for _, record in replay_frames(reader, speed=speed, sleep=lifecycle.wait):
                if lifecycle.should_exit or limits.reached(report.frames_out, start):
                    break
                topic = record.topic if rig is None else keys.sensor_skeletons(rig, record.sensor_id)
                publisher = publishers.get(topic)
                if publisher is None:
                    publisher = publishers[topic] = session.declare_publisher(topic, express=True)
                publisher.put(record.payload)  # type: ignore[attr-defined]
                report.frames_out += 1
                report.topics.add(topic)
        finally:
            lifecycle.request_exit()
            session.close()
    log.info("replay: %d frames published on %d topics", report.frames_out, len(report.topics))
    return report
