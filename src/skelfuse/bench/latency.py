"""``skelfuse bench latency``: publish -> fused-receive latency of the live service over loopback zenoh.

Setup per sensor count N: a rig config with N simulated sensors on a circle (written to a temporary
folder), the fusion node as a subprocess (``python -m skelfuse fuse``, peer mode on ``tcp/127.0.0.1``,
multicast off, no view), and this process as the N sensors and the subscriber: one thread publishes the N
sensors' frames of each instant at 30 Hz (one seeded walking take seen from N poses), a zenoh callback
stamps each fused frame on arrival.

Measured (``time.monotonic_ns``, one process, so no cross-process clock error):

* ``e2e``: publish of the last sensor frame of an instant -> its fused frame received: what an app sees;
* ``node_added``: the node's own share, from its status documents of the measured window (each carries its
  window's values, so the percentiles are over every measured instant): arrival of the frame that completed an
  instant (zenoh callback in the node) -> fused frame handed to zenoh;
* ``fusion``: the fusion step plus encoding, from the same statuses;
* ``floor``: the harness's own floor: publish of the last sensor frame of an instant -> that frame received by a
  second zenoh session of this process (one hop; e2e takes two, harness -> node -> harness). Its publishers,
  subscriber and the node share the machine's cores, so on a small machine this floor is not zero;
* ``rate``: fused frames received per second of publishing (30 Hz sustained: every instant fused), and the
  instants the node shed because it fell more than ``[node] max_lag_s`` behind (its last status).

Shaped like zenoh-python's ``z_ping``: warm-up (1 s, not counted), then every instant of the measured
window, and the distribution (p50 / p99 / max), never a mean. A sweep doubles N from 16 to 64 (the wire
format's cap) and reports the largest N the machine *sustains*: at least 95% of the instants fused, 95% of
them complete, and e2e p99 under one frame period. The publisher is one Python thread, so the sweep
measures this whole machine (publisher included), not the node alone.
"""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.schema.frames import SensorFrame
from skelfuse.schema.skeleton import N_JOINTS
from skelfuse.service.zenoh_io import close_session, free_port, loopback_args, loopback_config
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.rig import paper_rig
from skelfuse.wire import keys
from skelfuse.wire.codec import (
    DecodeError,
    decode_fused_frame,
    decode_sensor_frame,
    decode_status,
    encode_sensor_frame,
)

FPS = 30.0
WARMUP_S = 1.0
TARGET_NODE_ADDED_P99_MS = 1.0
TARGET_E2E_P99_MS = 5.0
TARGET_E2E_SENSORS = 5
SWEEP = (16, 32, 64)


@dataclass(frozen=True)
class LatencyCase:
    """One sensor count. Times in ms; None where nothing was measured."""

    n_sensors: int
    instants_sent: int
    fused_received: int
    complete_fraction: float
    e2e_p50_ms: float | None
    e2e_p99_ms: float | None
    e2e_max_ms: float | None
    node_added_p50_ms: float | None
    node_added_p99_ms: float | None
    node_added_max_ms: float | None
    fusion_p50_ms: float | None
    fusion_p99_ms: float | None
    sustained: bool
    load_before: tuple[float, float, float] = (0.0, 0.0, 0.0)
    load_after: tuple[float, float, float] = (0.0, 0.0, 0.0)
    n_people: int = 1
    node_src: str | None = None
    fused_rate_hz: float | None = None
    instants_shed: int | None = None
    floor_p50_ms: float | None = None
    floor_p99_ms: float | None = None
    publish_late_p99_ms: float | None = None


@dataclass
class LatencyResult:
    cases: list[LatencyCase] = field(default_factory=list)
    sweep: list[LatencyCase] = field(default_factory=list)
    max_sustained_sensors: int | None = None
    duration_s: float = 0.0
    cpus: int | None = field(default_factory=os.cpu_count)
    """The measuring machine's CPU count, which the table names (it may be rendered on another machine)."""

    def to_dict(self) -> dict[str, Any]:
        out = {
            "fps": FPS,
            "duration_s": self.duration_s,
            "cpus": self.cpus,
            "cases": [asdict(c) for c in self.cases],
            "sweep": [asdict(c) for c in self.sweep],
            "max_sustained_sensors": self.max_sustained_sensors,
            "targets": {
                "node_added_p99_ms": TARGET_NODE_ADDED_P99_MS,
                "e2e_p99_ms": TARGET_E2E_P99_MS,
                "e2e_sensors": TARGET_E2E_SENSORS,
            },
        }
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LatencyResult:
        """Read back what :meth:`to_dict` wrote (docs/evidence.md is rendered from the stored JSON)."""

        def case(fields: dict[str, Any]) -> LatencyCase:
            tuples: dict[str, Any] = {k: tuple(fields[k]) for k in ("load_before", "load_after") if k in fields}
            return LatencyCase(**{**fields, **tuples})

        return cls(
            cases=[case(c) for c in data["cases"]],
            sweep=[case(c) for c in data["sweep"]],
            max_sustained_sensors=data["max_sustained_sensors"],
            duration_s=data["duration_s"],
            cpus=data.get("cpus"),
        )


def _rig_toml(directory: Path, n_sensors: int) -> Path:

    lines = [
        "[rig]",
        'name = "bench"',
        "",
        "[sync]",
        'by = "device"',
        f"fps = {FPS}",
        "tolerance_ms = 10.0",
        "deadline_ms = 17.0",
        "",
        "[zenoh]",
        "multicast_scouting = false",
        "",
    ]
    for sensor in paper_rig(n_sensors):
        rows = ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in sensor.world_from_sensor)
        lines += ["[[sensors]]", f'id = "{sensor.sensor_id}"', 'source = "sim"', f"world_from_sensor = [{rows}]", ""]
    path = directory / f"bench-{n_sensors}.toml"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def synthetic_frames(n_sensors: int, n_instants: int, seed: int = 0, n_people: int = 1) -> list[list[Any]]:
    """Per instant, the N sensors' SensorFrames (device time filled in at publish); ``n_people`` bodies each
    (walkers on a grid 900 mm apart, every sensor sees everyone)."""

    times = np.arange(n_instants) / FPS
    walkers = [
        make_gesture("walking", duration_s=n_instants / FPS, seed=seed + p).at_times(times) for p in range(n_people)
    ]
    for p in range(1, n_people):  # the first walker stays where one walker always was
        walkers[p] = walkers[p] + np.array([900.0 * (p % 4 - 1.5) + 450.0, 900.0 * (p // 4) - 450.0, 0.0])
    truth = np.stack(walkers, axis=1)  # (T, P, 32, 3)
    rng = np.random.default_rng(seed)
    out: list[list[Any]] = []
    sensors = paper_rig(n_sensors)
    views = [s.to_sensor(truth) + rng.normal(0.0, 10.0, truth.shape) for s in sensors]  # (T, P, 32, 3) each
    orientations = np.zeros((n_people, N_JOINTS, 4), np.float32)
    orientations[..., 0] = 1.0
    confidence = np.full((n_people, N_JOINTS), 2, np.uint8)
    body_ids = np.arange(1, n_people + 1, dtype=np.uint32)
    for t in range(n_instants):
        out.append(
            [
                SensorFrame(s.sensor_id, 0, 0, 0, body_ids, views[i][t].astype(np.float32), orientations, confidence)
                for i, s in enumerate(sensors)
            ]
        )
    return out


def _percentile(values: Sequence[float], q: float) -> float | None:
    return round(float(np.percentile(values, q)), 4) if len(values) else None


def _merge_windows(windows: list[dict[str, Any]], name: str) -> dict[str, float | None]:
    """p50 / p99 / max of the status field ``name`` (e.g. ``node_added_ms``) over several status windows.

    Exact over every instant of the windows when they carry ``<name>_samples`` (this version's node does). A node
    without them (an older ``--node-src``) gives only each window's percentiles, which do not merge: then p50 is
    the median of the windows' p50 and p99 / max the largest window's (a 0.5 s window holds 15 instants, so its
    p99 is about its max: the largest window p99 is about the run's max, not its p99).
    """
    if any(f"{name}_samples" in w for w in windows):
        samples = [v for w in windows for v in w.get(f"{name}_samples") or ()]
        return {"p50": _percentile(samples, 50), "p99": _percentile(samples, 99), "max": max(samples, default=None)}
    parts = [w[name] for w in windows if (w.get(name) or {}).get("n")]
    if not parts:
        return {"p50": None, "p99": None, "max": None}
    return {
        "p50": round(float(np.median([p["p50"] for p in parts])), 4),
        "p99": max(p["p99"] for p in parts),
        "max": max(p["max"] for p in parts),
    }


def measure(
    n_sensors: int, duration_s: float, *, workdir: Path, n_people: int = 1, node_src: Path | None = None
) -> LatencyCase:
    """One sensor count: start a node, publish for WARMUP_S + duration_s, collect, stop the node.

    ``node_src``: run the node from that source tree (``PYTHONPATH``), e.g. an older checkout, with this
    harness; default: this one."""

    import zenoh

    load_before = os.getloadavg()  # the machine's load (1, 5, 15 min), recorded with every case
    port = free_port()
    node = _start_node(_rig_toml(workdir, n_sensors), port, workdir / f"node-{n_sensors}.log", node_src)
    n_instants = int((WARMUP_S + duration_s) * FPS)
    frames = synthetic_frames(n_sensors, min(n_instants, 300), n_people=n_people)
    collector = _Collector()
    try:
        session = zenoh.open(loopback_config(connect_ports=[port]))
        probe = zenoh.open(loopback_config(connect_ports=[port]))  # the harness's floor: one hop to a 2nd session
        try:
            session.declare_subscriber(keys.fused_skeletons("bench"), collector.on_fused)
            session.declare_subscriber(keys.status("bench", "fusion"), collector.on_status)
            probe.declare_subscriber(keys.sensor_skeletons("bench", frames[0][-1].sensor_id), collector.on_probe)
            if not collector.ready.wait(60.0):
                log = (workdir / f"node-{n_sensors}.log").read_text(errors="replace")[-2000:]
                raise RuntimeError(f"the fusion node did not come up within 60 s:\n{log}")
            run = _publish_instants(session, frames, n_instants)
            time.sleep(0.6)  # one more status window
            _stop_node(node, workdir / f"node-{n_sensors}.log")
        finally:
            close_session(probe, what="bench latency probe")
            close_session(session, what="bench latency")
    finally:
        if node.poll() is None:
            os.killpg(node.pid, signal.SIGKILL)
            node.wait(5.0)
    published = run.published
    with collector.lock:
        e2e = [(collector.received[t] - p) / 1e6 for t, p in published.items() if t in collector.received]
        floor = [(collector.probed[t] - p) / 1e6 for t, p in published.items() if t in collector.probed]
        n_complete = sum(1 for t in published if t in collector.complete)
        # Status windows (0.5 s) that lie inside the measured window: the node's own latency after warm-up, over
        # every instant of those windows (_merge_windows).
        windows = [
            st.info
            for t, st in collector.statuses
            if run.measure_from <= t <= run.measured_until + 600_000_000 and st.state != "stopped"
        ]
        last = collector.statuses[-1][1] if collector.statuses else None
    case = _case(n_sensors, len(published), e2e, n_complete, windows, load_before, n_people, node_src)
    span_s = (max(published.values()) - min(published.values())) / 1e9 + 1 / FPS if published else 0.0
    return dataclasses.replace(
        case,
        fused_rate_hz=round(len(e2e) / span_s, 2) if span_s else None,
        instants_shed=None if last is None else last.counters.get("instants_shed"),
        floor_p50_ms=_percentile(floor, 50),
        floor_p99_ms=_percentile(floor, 99),
        publish_late_p99_ms=_percentile(run.late_ms, 99),
    )


def _start_node(config: Path, port: int, log_path: Path, node_src: Path | None) -> subprocess.Popen[bytes]:
    """The fusion node under test, in a process group of its own, its log in ``log_path``."""
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "skelfuse",
            "fuse",
            "--config",
            str(config),
            "--no-view",
            "--status-period",
            "0.5",
            *loopback_args(listen_port=port),
        ],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=open(log_path, "wb"),
        start_new_session=True,
        env=None if node_src is None else dict(os.environ, PYTHONPATH=str(node_src)),
    )


def _stop_node(node: subprocess.Popen[bytes], log_path: Path) -> None:
    """SIGTERM to the node's group; say so on stderr when it has not stopped 15 s later (it is killed then)."""
    os.killpg(node.pid, signal.SIGTERM)
    try:
        node.wait(15.0)
    except subprocess.TimeoutExpired:
        print(
            f"bench latency: the node did not stop within 15 s of SIGTERM; killing it (log: {log_path})",
            file=sys.stderr,
        )


class _Collector:
    """What the harness's zenoh callbacks receive: the monotonic arrival time of each fused instant, which
    instants fused every sensor, and the node's statuses."""

    def __init__(self) -> None:
        self.received: dict[int, int] = {}
        self.complete: set[int] = set()
        self.statuses: list[Any] = []
        self.probed: dict[int, int] = {}  # device time -> the harness's second session received the frame
        self.lock = threading.Lock()
        self.ready = threading.Event()  # the node's first status: it is up and subscribed

    def on_fused(self, sample: Any) -> None:
        now = time.monotonic_ns()
        try:
            frame = decode_fused_frame(sample.payload.to_bytes())
        except DecodeError:
            return
        with self.lock:
            self.received[int(frame.time_us)] = now
            if frame.contributors.size and frame.contributors[0].all():
                self.complete.add(int(frame.time_us))

    def on_probe(self, sample: Any) -> None:
        now = time.monotonic_ns()
        try:
            frame = decode_sensor_frame(sample.payload.to_bytes())
        except DecodeError:
            return
        with self.lock:
            self.probed[int(frame.device_time_us)] = now

    def on_status(self, sample: Any) -> None:
        try:
            status = decode_status(sample.payload.to_bytes())
        except DecodeError:
            return
        with self.lock:
            self.statuses.append((time.monotonic_ns(), status))
        self.ready.set()


@dataclass(frozen=True)
class _Published:
    """What :func:`_publish_instants` sent: the monotonic time each measured instant's last frame went out (by
    device time, after the warm-up), when the first whole status window after the warm-up starts, when
    publishing ended, and how late each measured instant's first put was against its schedule (ms)."""

    published: dict[int, int]
    measure_from: int
    measured_until: int
    late_ms: list[float]


def _publish_instants(session: Any, frames: list[list[SensorFrame]], n_instants: int) -> _Published:
    """Publish ``n_instants`` instants at FPS, every sensor's frame stamped now."""
    period_ns = int(1e9 / FPS)
    published: dict[int, int] = {}
    late_ms: list[float] = []
    measure_from = 0
    publishers = [
        session.declare_publisher(keys.sensor_skeletons("bench", f.sensor_id), express=True) for f in frames[0]
    ]
    time.sleep(0.3)  # let the node's subscriber see the publishers
    start = time.monotonic_ns() + period_ns
    base_us = time.time_ns() // 1000
    for k in range(n_instants):
        due = start + k * period_ns
        delay = due - time.monotonic_ns()
        if delay > 0:
            time.sleep(delay / 1e9)
        device_us = base_us + round(k * 1e6 / FPS)
        began = time.monotonic_ns()
        batch = [
            encode_sensor_frame(
                dataclasses.replace(f, sequence=k, device_time_us=device_us, host_time_ns=time.time_ns())
            )
            for f in frames[k % len(frames)]
        ]
        for publisher, payload in zip(publishers[:-1], batch[:-1], strict=True):
            publisher.put(payload)
        last = time.monotonic_ns()
        publishers[-1].put(batch[-1])
        if k >= WARMUP_S * FPS:
            if not published:
                measure_from = time.monotonic_ns() + 500_000_000  # first whole status window
            published[device_us] = last
            late_ms.append((began - due) / 1e6)
    return _Published(published, measure_from, time.monotonic_ns(), late_ms)


def _case(
    n_sensors: int,
    sent: int,
    e2e: list[float],
    n_complete: int,
    windows: list[Any],
    load_before: tuple[float, float, float],
    n_people: int,
    node_src: Path | None,
) -> LatencyCase:
    """The figures of one sensor count from what was sent and received."""
    added = _merge_windows(windows, "node_added_ms")
    fusion = _merge_windows(windows, "fusion_ms")
    complete_fraction = n_complete / sent if sent else 0.0
    p99 = _percentile(e2e, 99)
    sustained = bool(
        sent and len(e2e) >= 0.95 * sent and complete_fraction >= 0.95 and p99 is not None and p99 < 1e3 / FPS
    )
    return LatencyCase(
        n_sensors=n_sensors,
        instants_sent=sent,
        fused_received=len(e2e),
        complete_fraction=round(complete_fraction, 4),
        e2e_p50_ms=_percentile(e2e, 50),
        e2e_p99_ms=p99,
        e2e_max_ms=round(max(e2e), 4) if e2e else None,
        node_added_p50_ms=added.get("p50"),
        node_added_p99_ms=added.get("p99"),
        node_added_max_ms=added.get("max"),
        fusion_p50_ms=fusion.get("p50"),
        fusion_p99_ms=fusion.get("p99"),
        sustained=sustained,
        load_before=_rounded(load_before),
        load_after=_rounded(os.getloadavg()),
        n_people=n_people,
        node_src=None if node_src is None else str(node_src),
    )


def _rounded(load: tuple[float, float, float]) -> tuple[float, float, float]:
    return (round(load[0], 2), round(load[1], 2), round(load[2], 2))


def run_latency_bench(
    *,
    sensor_counts: Sequence[int] = (4, 5, 8),
    duration_s: float = 5.0,
    sweep: bool = True,
    progress: bool = True,
    n_people: int = 1,
    node_src: Path | None = None,
    cases: Sequence[tuple[int, int]] = (),
) -> LatencyResult:
    """Measure every sensor count (each with ``n_people``), then every (sensors, people) of ``cases``, then
    (``sweep``) the largest count sustained at 30 Hz."""
    for n in [*sensor_counts, *(c[0] for c in cases)]:
        if not 1 <= n <= 64:
            raise ValueError(f"--sensors: each count must be in 1..64 (the wire format's cap), got {n}")
    result = LatencyResult(duration_s=duration_s)
    with tempfile.TemporaryDirectory(prefix="skelfuse-bench-") as tmp:
        workdir = Path(tmp)
        for n, people in [*((n, n_people) for n in sensor_counts), *cases]:
            if progress:
                print(
                    f"bench latency: {n} sensors x {people} people x {FPS:g} Hz for {duration_s:g} s ...",
                    file=sys.stderr,
                    flush=True,
                )
            result.cases.append(measure(n, duration_s, workdir=workdir, n_people=people, node_src=node_src))
        sustained = [c.n_sensors for c in result.cases if c.sustained and c.n_people == n_people]
        if sweep:
            for n in SWEEP:
                if n <= max(sensor_counts, default=0):
                    continue
                if progress:
                    print(f"bench latency: sweep, {n} sensors ...", file=sys.stderr, flush=True)
                case = measure(n, min(duration_s, 3.0), workdir=workdir, n_people=n_people, node_src=node_src)
                result.sweep.append(case)
                if not case.sustained:
                    break
                sustained.append(n)
        result.max_sustained_sensors = max(sustained) if sustained else None
    return result


def format_table(result: LatencyResult) -> str:
    def f(value: float | None, digits: int = 2) -> str:
        return "-" if value is None else f"{value:.{digits}f}"

    lines = [
        f"Latency over zenoh on loopback, {FPS:g} Hz, {result.duration_s:g} s per case (ms):",
        "",
        "| sensors x people | instants | fused | rate Hz | shed | complete | e2e p50 | e2e p99 | e2e max | node p50 "
        "| node p99 | node max | fusion p50 | fusion p99 | floor p50 | floor p99 | sustained | load 1 min |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|:---:|---:|",
    ]
    for c in [*result.cases, *result.sweep]:
        lines.append(
            f"| {c.n_sensors} x {c.n_people} | {c.instants_sent} | {c.fused_received} | {f(c.fused_rate_hz, 1)} "
            f"| {'-' if c.instants_shed is None else c.instants_shed} | {c.complete_fraction:.1%} "
            f"| {f(c.e2e_p50_ms)} | {f(c.e2e_p99_ms)} | {f(c.e2e_max_ms)} | {f(c.node_added_p50_ms, 3)} "
            f"| {f(c.node_added_p99_ms, 3)} | {f(c.node_added_max_ms, 3)} | {f(c.fusion_p50_ms, 3)} "
            f"| {f(c.fusion_p99_ms, 3)} | {f(c.floor_p50_ms)} | {f(c.floor_p99_ms)} | {'yes' if c.sustained else 'no'} "
            f"| {c.load_before[0]:.2f}-{c.load_after[0]:.2f} |"
        )
    lines += [
        "",
        "e2e: last sensor frame of an instant published -> fused frame received (same process clock).",
        "node: the fusion node's own added latency (completing frame in -> fused frame out), over every measured "
        "instant (from the node's status windows).",
        "rate: fused frames received per second of publishing; shed: instants the node shed, more than "
        "[node] max_lag_s behind (its last status).",
        "floor: the harness's own floor, the last sensor frame published -> received by a second session of the "
        "harness (one hop; e2e takes two); the harness shares the machine with the node.",
        f"load 1 min: os.getloadavg() before-after each case, on {result.cpus or os.cpu_count()} CPUs (a shared "
        "machine inflates every figure).",
        f"Largest sensor count sustained at {FPS:g} Hz: {result.max_sustained_sensors or 'none measured'}.",
        f"Targets: node adds <= {TARGET_NODE_ADDED_P99_MS:g} ms p99; e2e p99 <= {TARGET_E2E_P99_MS:g} ms "
        f"for {TARGET_E2E_SENSORS} sensors.",
    ]
    return "\n".join(lines)
