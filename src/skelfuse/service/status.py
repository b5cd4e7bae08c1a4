"""``skelfuse status``: print the status documents the rig's nodes publish on ``skelfuse/<rig>/status/*``."""

from __future__ import annotations

import json
import logging
import time
from typing import TYPE_CHECKING, Any, TextIO

from skelfuse.config import RigConfig
from skelfuse.service.lifecycle import Lifecycle, RunLimits
from skelfuse.service.zenoh_io import SampleQueue, close_session, open_session
from skelfuse.wire import keys
from skelfuse.wire.codec import DecodeError, NodeStatus, decode_status

if TYPE_CHECKING:  # pragma: no cover - typing only
    import zenoh

log = logging.getLogger("skelfuse.service.status")


def format_status(status: NodeStatus) -> str:
    """One human line per status: node, state, the main counters, per-sensor rates, latency."""
    c, info = status.counters, status.info
    parts = [f"{status.node} [{status.role}] {status.state}"]
    if status.role == "fusion":
        parts.append(
            f"in {c.get('frames_in', 0)} out {c.get('frames_out', 0)} "
            f"({info.get('fused_rate_hz', 0):.1f} Hz) late {c.get('late', 0)} dropped {c.get('dropped', 0)} "
            f"invalid {c.get('invalid', 0)}"
        )
        added = info.get("node_added_ms") or {}
        if added.get("p50") is not None:
            parts.append(f"node latency p50 {added['p50']:.3f} p99 {added['p99']:.3f} ms")
        sensors = info.get("sensors") or {}
        rates = []
        for sid, s in sensors.items():
            seen = s.get("last_seen_s")
            rates.append(
                f"{sid} {s.get('rate_hz') or 0:.1f} Hz"
                + (" (never seen)" if seen is None else f" ({seen:.2f} s ago)" if seen > 1 else "")
            )
        if rates:
            parts.append("sensors: " + ", ".join(rates))
        clocks = [format_clock(sid, s) for sid, s in sensors.items() if s.get("clock")]
        if clocks:
            parts.append("clocks (offset from the rig's median / jitter): " + ", ".join(clocks))
        flooded = [
            f"{sid} {s['queue']['dropped']}" for sid, s in sensors.items() if (s.get("queue") or {}).get("dropped")
        ]
        if flooded:
            parts.append("intake queue dropped: " + ", ".join(flooded))
        if c.get("instants_shed"):
            parts.append(
                f"BEHIND: {c['instants_shed']} instants shed (older than max_lag_s {info.get('max_lag_s')} s when "
                "their turn came)"
            )
        moved = [
            f"{sid} ({fit.get('median_mm')} mm off)"
            for sid, fit in (info.get("pose_fit") or {}).items()
            if fit.get("fits") is False
        ]
        if moved:
            parts.append("POSE NO LONGER FITS: " + ", ".join(moved))
    elif status.role == "router":
        parts.append(f"refused: {c.get('refused_tls', 0)} TLS connections, {c.get('refused_messages', 0)} messages")
        top = [f"{r['who']} {r['action']} on {r['key']} x{r['messages']}" for r in (info.get("refused") or [])[:3]]
        if top:
            parts.append("most refused: " + "; ".join(top))
    else:
        parts.append(f"out {c.get('frames_out', 0)} ({info.get('rate_hz', 0) or 0:.1f} Hz)")
        if info.get("last_error"):
            parts.append(f"last error: {info['last_error']}")
    return " | ".join(parts)


def format_clock(sensor_id: str, sensor: dict[str, Any]) -> str:
    """A sensor's clock as the node estimates it (status ``sensors.<id>.clock``, see docs/service.md), in words.

    ``capture_1 +100.2 ms / 20.1 ms`` (offset from the rig's median clock / jitter), then the drift, the clock
    steps the node re-learned and the frames held off clock, where there are any; ``learning`` before the
    node has enough frames of that sensor.
    """
    clock = sensor.get("clock") or {}
    offset, jitter = clock.get("relative_offset_ms"), clock.get("jitter_ms")
    if offset is None:
        return f"{sensor_id} learning"
    text = f"{sensor_id} {offset:+.1f} ms"
    if jitter is not None:
        text += f" / {jitter:.1f} ms"
    extra = []
    if clock.get("drift_ppm") is not None:
        extra.append(f"drift {clock['drift_ppm']:+.0f} ppm")
    if clock.get("relearns"):
        extra.append(f"re-learned {clock['relearns']}x")
    if sensor.get("off_clock"):
        extra.append(f"{sensor['off_clock']} off clock")
    return text + (f" ({', '.join(extra)})" if extra else "")


def watch_status(
    cfg: RigConfig, zenoh_conf: zenoh.Config, *, limits: RunLimits, lifecycle: Lifecycle, as_json: bool, out: TextIO
) -> int:
    """Print status messages until a signal or the limits (``max_frames``: messages); returns how many."""
    count = 0
    with lifecycle.capture_signals():
        start = time.monotonic()
        session = open_session(zenoh_conf, lifecycle=lifecycle, what="status", deadline=limits.deadline(start))
        if session is None:
            return 0
        samples = SampleQueue()
        try:
            session.declare_subscriber(keys.all_status(cfg.name), samples)
            while not lifecycle.should_exit and not limits.reached(count, start):
                item = samples.get(timeout=0.1)
                if item is None:
                    continue
                try:
                    status = decode_status(item.payload)
                except DecodeError as exc:
                    log.warning("status: rejected a payload on %s (%s): %s", item.key, exc.reason, exc)
                    continue
                count += 1
                if as_json:
                    doc: dict[str, Any] = {
                        "node": status.node,
                        "role": status.role,
                        "state": status.state,
                        "time_ns": status.time_ns,
                        "counters": status.counters,
                        "info": status.info,
                    }
                    out.write(json.dumps(doc) + "\n")
                else:
                    out.write(format_status(status) + "\n")
                out.flush()
        finally:
            lifecycle.request_exit()
            close_session(session, what="status")
    return count
