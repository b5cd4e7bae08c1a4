"""The demo's runs: live (:func:`run_demo`, the real service on loopback) and offline (:func:`run_demo_offline`).

What the demo is and its settings: :mod:`skelfuse.apps.demo`.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import time as _time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.apps.demo import CONVERGE_S, DEFAULT_RRD, DEMO_RIG, DEMO_TAKE_S
from skelfuse.config import DEFAULT_PRESET, load_rig_config
from skelfuse.fusion.pipeline import Fuser
from skelfuse.fusion.presets import preset
from skelfuse.fusion.transform import apply_transform
from skelfuse.schema.errors import ServiceError
from skelfuse.schema.skeleton import EVAL_JOINTS, JOINT_GROUPS
from skelfuse.service.lifecycle import Lifecycle
from skelfuse.service.node import FusionNode, NodeOptions
from skelfuse.service.viewer import (
    FLUSH_TIMEOUT_S,
    ViewOptions,
    has_display,
    open_recording,
    release_recording,
    stop_server,
    web_viewer_url,
)
from skelfuse.service.worker import simulate_rig
from skelfuse.service.zenoh_io import close_session, free_port, loopback_args, loopback_config
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.rig import paper_rig
from skelfuse.sinks.rerun_sink import RerunSink, default_blueprint
from skelfuse.wire import keys
from skelfuse.wire.codec import DecodeError, decode_fused_frame, decode_sensor_frame

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DemoSummary:
    """What the demo prints at the end. Errors are mean Euclidean distances to ground truth, mm.

    ``latency_*``: publish of the last sensor frame of an instant -> its fused frame received by a zenoh
    subscriber (live demo only); ``node_added_*``: the fusion node's own share of it.
    """

    frames_fused: int
    duration_s: float
    gesture: str
    preset: str
    n_sensors: int
    error_fused_mm: dict[str, float]
    error_best_single_sensor_mm: dict[str, Any]  # the groups' errors (mm) and "sensor": which one
    fusion_p50_ms: float
    fusion_p99_ms: float
    recording: str | None
    latency_p50_ms: float | None = None
    latency_p99_ms: float | None = None
    node_added_p50_ms: float | None = None
    node_added_p99_ms: float | None = None
    mode: str = "offline"
    frames_scored: int | None = None
    """Fused frames the errors are computed over: the scoring window of every whole pass of the take."""
    frames_before_run: int = 0
    """Live: frames fused while the rig came up, before the run's ``duration_s`` began (not in ``frames_fused``)."""
    converge_s: float = CONVERGE_S
    take_s: float = DEMO_TAKE_S
    """Length of the looping take; each pass is scored over take time [converge_s, take_s)."""
    passes_scored: int = 1
    partial_pass: bool = False
    """The run was shorter than one pass: only its part of the window is scored (not comparable)."""
    error_fused_per_pass_mm: list[float] | None = None
    """The fused ``all16`` error of each scored pass (they agree: every pass is the same material)."""

    def to_dict(self) -> dict[str, Any]:
        """As JSON takes it: a figure that could not be computed (nothing scored) is None, not NaN."""

        def finite(value: Any) -> Any:
            if isinstance(value, float) and not math.isfinite(value):
                return None
            if isinstance(value, dict):
                return {k: finite(v) for k, v in value.items()}
            if isinstance(value, list):
                return [finite(v) for v in value]
            return value

        return finite(asdict(self))


def _progress(text: str, *, final: bool = False) -> None:
    """A progress line on stderr: redrawn in place on a terminal, one plain line each in a log file."""
    if sys.stderr.isatty():
        print(f"\r{text:<60}", end="\n" if final else "", file=sys.stderr, flush=True)
    elif text:
        print(text, file=sys.stderr, flush=True)


def _group_errors(estimate: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Mean distance per paper joint group over frames where the estimate exists; (T, 32, 3) inputs."""
    distance = np.linalg.norm(estimate - truth, axis=-1)
    out = {}
    for group, joints in JOINT_GROUPS.items():
        values = distance[:, joints]
        out[group] = float(np.mean(values[np.isfinite(values)])) if np.isfinite(values).any() else float("nan")
    values = distance[:, EVAL_JOINTS]
    out["all16"] = float(np.mean(values[np.isfinite(values)])) if np.isfinite(values).any() else float("nan")
    return out


def scoring_window(instants: np.ndarray, start_n: int, take_frames: int, run_frames: int, fps: float) -> np.ndarray:
    """Pass index of each instant in the demo's scoring window, -1 outside it.

    ``start_n`` is the instant at which a pass of the take begins (take frame 0) and the run's scored part
    starts; the window is take time [CONVERGE_S, take) of every whole pass of the ``run_frames`` from there
    (of the one, partial pass when the run is shorter than a pass).
    """
    offset = np.asarray(instants, dtype=np.int64) - start_n
    passes = max(1, run_frames // take_frames)
    pass_index = offset // take_frames
    inside = (offset >= 0) & (pass_index < passes) & (offset % take_frames >= round(CONVERGE_S * fps))
    return np.where(inside, pass_index, -1)


def _per_pass(estimate: np.ndarray, truth: np.ndarray, pass_index: np.ndarray) -> list[float]:
    """The ``all16`` error of each pass (``pass_index`` per frame, as :func:`scoring_window` gives it)."""
    passes = int(pass_index.max()) + 1 if len(pass_index) else 0
    return [_group_errors(estimate[pass_index == p], truth[pass_index == p])["all16"] for p in range(passes)]


def run_demo_offline(
    *,
    duration_s: float = 20.0,
    gesture: str = "walking",
    preset_name: str = DEFAULT_PRESET,
    seed: int = 0,
    rrd_path: Path | None = None,
    spawn: bool | None = None,
    realtime: bool | None = None,
    progress: bool = True,
    take_duration_s: float = DEMO_TAKE_S,
) -> DemoSummary:
    """Simulate, fuse and draw in one process, without zenoh (``skelfuse demo --offline``); returns the summary.

    Parameters
    ----------
    rrd_path : save the recording here instead of spawning a viewer.
    spawn : spawn the Rerun viewer; default: when there is a display and no ``rrd_path``. Without either,
        the recording goes to ``skelfuse-demo.rrd``.
    realtime : pace frames at the sensors' 30 Hz; default: only when a live viewer is watching.
    take_duration_s : the looping take (:data:`DEMO_TAKE_S`); each pass starts a new filter, as the live node
        starts a new track for the person who jumped back to the take's start.
    """

    if duration_s <= 0:
        raise ValueError(f"--duration must be positive, got {duration_s}")
    params = preset(preset_name)
    sensors = paper_rig(4)
    motion = make_gesture(gesture, duration_s=take_duration_s, seed=seed)  # the take; it loops (see DEMO_TAKE_S)
    observations = simulate(motion, sensors, load_profile(), seed=seed)
    take_world = apply_transform(observations.world_from_sensor_calibrated, observations.positions.astype(np.float64))
    take_frames = take_world.shape[0]
    n_frames = max(1, round(duration_s * motion.fps))
    take_frame = np.arange(n_frames) % take_frames  # frame i of the run shows take frame i mod T
    world = take_world[take_frame]
    truth = observations.truth[take_frame]
    confidences = observations.confidence[take_frame]

    if spawn is None:
        spawn = rrd_path is None and has_display()
    if rrd_path is None and not spawn:
        rrd_path = DEFAULT_RRD
    if realtime is None:
        realtime = bool(spawn)

    recording, _ = open_recording(
        ViewOptions(mode="spawn" if spawn else "save", file=rrd_path or DEFAULT_RRD, application_id="skelfuse_demo")
    )
    sink = RerunSink(recording, observations.sensor_ids)
    sink.log_rig(observations.world_from_sensor_calibrated)
    recording.send_blueprint(default_blueprint(observations.world_from_sensor_calibrated))

    fused = np.full((n_frames, 32, 3), np.nan)
    fusion_ns = np.zeros(n_frames, dtype=np.int64)
    times_s = np.arange(n_frames) / motion.fps
    period_s = 1.0 / motion.fps
    started = time.perf_counter()
    track_ids = np.array([1])
    for frame in range(n_frames):
        if take_frame[frame] == 0:  # the person jumps back to the take's start: a new track, as the live node makes
            fuser = Fuser(params, n_bodies=1, sensor_positions=observations.world_from_sensor_calibrated[:, :3, 3])
        candidates = world[frame][None]  # (B=1, S, 32, 3)
        confidence = confidences[frame][None]
        tick = time.perf_counter_ns()
        result = fuser.step(candidates, confidence, period_s)
        fusion_ns[frame] = time.perf_counter_ns() - tick
        fused[frame] = result.positions[0]

        sink.set_time(float(times_s[frame]))
        sink.log_sensor_skeletons(world[frame][:, None])
        sink.log_fused(result.positions, track_ids)
        error = np.linalg.norm(result.positions[0, EVAL_JOINTS] - truth[frame, EVAL_JOINTS], axis=-1)
        sink.log_metrics(
            fusion_ms=fusion_ns[frame] / 1e6,
            error_mm=float(np.nanmean(error)) if np.isfinite(error).any() else None,
        )
        if progress and frame % (30 if sys.stderr.isatty() else 300) == 0:
            _progress(f"skelfuse demo: frame {frame + 1}/{n_frames}")
        if realtime:
            lag = started + (frame + 1) * period_s - time.perf_counter()
            if lag > 0:
                time.sleep(lag)
    if progress:
        _progress(f"skelfuse demo: fused {n_frames} frames.", final=True)
    try:
        recording.flush(timeout_sec=FLUSH_TIMEOUT_S)
    except Exception as exc:  # a viewer that went away: its last frames are lost, the summary is not
        log.warning("rerun: the view could not be flushed within %.1f s (%s)", FLUSH_TIMEOUT_S, exc)
    release_recording(recording)

    pass_index = scoring_window(np.arange(n_frames), 0, take_frames, n_frames, motion.fps)
    scored = pass_index >= 0
    single = {
        sensor_id: _group_errors(world[scored, index], truth[scored])
        for index, sensor_id in enumerate(observations.sensor_ids)
    }
    best_sensor = min(single, key=lambda sensor_id: single[sensor_id]["all16"])
    return DemoSummary(
        frames_fused=n_frames,
        duration_s=n_frames / motion.fps,
        gesture=gesture,
        preset=preset_name,
        n_sensors=len(sensors),
        error_fused_mm=_group_errors(fused[scored], truth[scored]),
        error_best_single_sensor_mm=single[best_sensor] | {"sensor": best_sensor},
        fusion_p50_ms=float(np.percentile(fusion_ns, 50)) / 1e6,
        fusion_p99_ms=float(np.percentile(fusion_ns, 99)) / 1e6,
        recording=str(rrd_path) if rrd_path is not None else None,
        frames_scored=int(scored.sum()),
        take_s=take_frames / motion.fps,
        passes_scored=int(pass_index.max()) + 1 if scored.any() else 0,
        partial_pass=n_frames < take_frames,
        error_fused_per_pass_mm=_per_pass(fused[scored], truth[scored], pass_index[scored]),
    )


def format_summary(summary: DemoSummary) -> str:
    best = summary.error_best_single_sensor_mm
    lines = [
        f"Fused {summary.frames_fused} frames ({summary.duration_s:.1f} s of '{summary.gesture}') from "
        f"{summary.n_sensors} simulated sensors with preset {summary.preset}"
        + (f" ({summary.frames_before_run} more while the rig came up)." if summary.frames_before_run else "."),
        "",
    ]
    if not summary.frames_scored:
        lines.append(
            f"Accuracy not scored: the run stopped before {summary.converge_s:.1f} s of a pass of the take had played "
            f"(the scoring window is {_window_text(summary)})."
        )
    else:
        lines += [
            f"Mean error against the simulator's ground truth (mm), {summary.frames_scored} frames scored: "
            + _window_text(summary)
            + ":",
            "| | torso | upper limb | lower limb | all 16 |",
            "|---|---:|---:|---:|---:|",
        ]
        for label, errors in (("fused", summary.error_fused_mm), (f"best single sensor ({best['sensor']})", best)):
            lines.append(
                f"| {label} | {errors['torso']:.1f} | {errors['upper_limb']:.1f} | {errors['lower_limb']:.1f} "
                f"| {errors['all16']:.1f} |"
            )
    per_pass = summary.error_fused_per_pass_mm or []
    if len(per_pass) > 1:
        lines.append(f"Fused, all 16, pass by pass: {', '.join(f'{e:.1f}' for e in per_pass)} mm.")
    lines += ["", f"Fusion time per frame: p50 {summary.fusion_p50_ms:.3f} ms, p99 {summary.fusion_p99_ms:.3f} ms."]
    if summary.latency_p50_ms is not None and summary.latency_p99_ms is not None:
        lines.append(
            f"Latency, sensor publish -> fused frame received over zenoh: "
            f"p50 {summary.latency_p50_ms:.2f} ms, p99 {summary.latency_p99_ms:.2f} ms."
        )
    if summary.node_added_p50_ms is not None and summary.node_added_p99_ms is not None:
        lines.append(
            f"Added by the fusion node (last frame in -> fused frame out): p50 "
            f"{summary.node_added_p50_ms:.3f} ms, p99 {summary.node_added_p99_ms:.3f} ms."
        )
    if summary.recording:
        lines.append(f"Recording saved to {summary.recording}; open it with:  rerun {summary.recording}")
    return "\n".join(lines)


def _window_text(summary: DemoSummary) -> str:
    """What the figures cover, in words (the scoring window)."""
    window = f"take seconds {summary.converge_s:.1f}-{summary.take_s:.1f}"
    if summary.partial_pass:
        return (
            f"{window} of the {summary.take_s:.0f} s take, cut short by --duration: a run shorter than one pass "
            f"scores only part of the take; run at least {summary.take_s:.0f} s for the comparable figure"
        )
    return (
        f"{window} of each of {summary.passes_scored} whole pass(es) of the {summary.take_s:.0f} s take, which "
        f"loops (every pass is the same material: the same figure for any --duration >= {summary.take_s:.0f} s; "
        "the first seconds of a pass, while the fused track settles, are not scored)"
    )


# ----------------------------------------------------------------------------------------------------------
# Live demo: capture workers + fusion node over loopback zenoh

RESULT_GRACE_S = 0.5
"""After ``--duration``, how long the demo still collects fused frames (they arrive milliseconds late)."""
TAKE_ORIGIN_DELAY_S = 8.0
"""The live demo's take starts this long after the demo (the workers' start-up fits in it on most PCs)."""
STARTUP_TIMEOUT_S = 90.0


def sim_sensor_tables(n_sensors: int, extra: Mapping[int, Sequence[str]] | None = None) -> list[str]:
    """Rig TOML lines for the paper's ring of ``n_sensors`` simulated sensors: one wired sync chain (the first
    sensor the master, subordinates 160 µs apart) and the true poses; ``extra[i]`` adds lines to sensor i's table.
    The demo's rig, the service tests and the soak script all write their sensors with it."""
    lines: list[str] = []
    for index, sensor in enumerate(paper_rig(n_sensors)):
        sync = '{ role = "master" }' if index == 0 else f'{{ role = "subordinate", delay_us = {160 * index} }}'
        rows = ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in sensor.world_from_sensor)
        lines += [
            "[[sensors]]",
            f'id = "{sensor.sensor_id}"',
            'source = "sim"',
            f"sync = {sync}",
            f"world_from_sensor = [{rows}]",
            *(extra or {}).get(index, ()),
            "",
        ]
    return lines


def write_demo_rig(directory: Path, *, preset_name: str, n_sensors: int = 4, port: int | None = None) -> Path:
    """Write the demo's rig config (the paper's 4-sensor layout, wired sync emulated) into ``directory``.

    The sensors' inline ``world_from_sensor`` are the true poses the simulator observes from; fusion uses
    ``calibration.toml`` beside it (the simulated calibration, with its error), written by the demo. With
    ``port``, ``[zenoh] connect`` names the demo's loopback endpoint, so any app given the file attaches.
    """

    lines = [
        "# skelfuse demo rig, written by `skelfuse demo` (the paper's 4-sensor layout, simulated).",
        "[rig]",
        f'name = "{DEMO_RIG}"',
        "",
        "[sync]",
        'by = "device"',
        "fps = 30.0",
        "tolerance_ms = 10.0",
        "deadline_ms = 17.0",
        "",
        "[calibration]",
        'file = "calibration.toml"',
        "",
        "[fusion]",
        f'preset = "{preset_name}"',
        "",
        "[zenoh]",
        'mode = "peer"',
        "multicast_scouting = false",
        *([f'connect = ["tcp/127.0.0.1:{port}"]'] if port is not None else []),
        "",
    ]
    lines += sim_sensor_tables(n_sensors)
    path = directory / "rig.toml"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def write_calibration(path: Path, sensor_ids: tuple[str, ...], poses: np.ndarray) -> None:
    lines = ['method = "simulated"  # the simulator\'s calibration error model', ""]
    for sensor_id, pose in zip(sensor_ids, poses, strict=True):
        rows = ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in pose)
        lines += [f'[sensors."{sensor_id}"]', f"world_from_sensor = [{rows}]", ""]
    path.write_text("\n".join(lines), encoding="utf-8")


class _Scorer:
    """The demo's subscriber: fused frames against ground truth, latency from the workers' publish stamps.

    Zenoh callbacks (several threads) only decode and store under a lock; scores are computed at the end.
    """

    def __init__(
        self,
        truth: np.ndarray,
        fps: float,
        poses_calibrated: np.ndarray,
        sensor_ids: tuple[str, ...],
        origin_n: int = 0,
    ) -> None:

        self.truth = truth
        self.origin_n = origin_n  # the instant at which the workers play take frame 0
        self.period_us = 1e6 / fps
        self.poses = poses_calibrated
        self.column = {sid: i for i, sid in enumerate(sensor_ids)}
        self.lock = threading.Lock()
        self.published_ns: dict[int, int] = {}  # instant -> latest publish wall time among its sensor frames
        self.fused: list[tuple[int, np.ndarray, int]] = []  # (instant, (32, 3) world mm, receive wall ns)
        self.converged: list[bool] = []  # per fused entry: its track is at least CONVERGE_S old
        self.start_n = origin_n  # the pass the scored run starts with (run_demo moves it when workers come late)
        self.track_birth_us: dict[int, int] = {}
        self.single: list[list[tuple[int, np.ndarray]]] = [[] for _ in sensor_ids]
        self.first_fused: float | None = None
        self.on_error: Callable[[int, float], None] | None = None

    def instant(self, time_us: int) -> int:
        return round(time_us / self.period_us)

    def on_sensor(self, sample: Any) -> None:

        try:
            frame = decode_sensor_frame(sample.payload.to_bytes())
        except DecodeError:
            return
        n = self.instant(frame.device_time_us)
        column = self.column.get(frame.sensor_id)
        world = None
        if column is not None and frame.n_bodies:
            world = apply_transform(self.poses[column : column + 1], frame.positions[:1])[0]
        with self.lock:
            self.published_ns[n] = max(self.published_ns.get(n, 0), frame.host_time_ns)
            if world is not None and column is not None:
                self.single[column].append((n, world))

    def on_fused(self, sample: Any) -> None:

        received = _time.time_ns()
        try:
            frame = decode_fused_frame(sample.payload.to_bytes())
        except DecodeError:
            return
        # One simulated person; when the take loops it jumps back to its start and gets a new track id while
        # the old track coasts out, and a view the tracker got wrong can start a short-lived track of its own:
        # score the person most sensors measured in this instant (no ground truth in the choice).
        seen_by = frame.contributors.sum(axis=1)
        if not seen_by.any():
            return
        person = int(np.argmax(seen_by))
        positions = frame.positions[person]
        track = int(frame.track_ids[person])
        n = self.instant(frame.time_us)
        with self.lock:
            birth = self.track_birth_us.setdefault(track, frame.time_us)
            self.converged.append(frame.time_us - birth >= CONVERGE_S * 1e6)
            self.fused.append((n, positions, received))
            if self.first_fused is None:
                self.first_fused = _time.monotonic()
        if self.on_error is not None:
            error = np.linalg.norm(
                positions[EVAL_JOINTS] - self.truth[(n - self.origin_n) % len(self.truth), EVAL_JOINTS], axis=-1
            )
            if np.isfinite(error).any():
                self.on_error(frame.time_us, float(np.nanmean(error)))

    def scores(self, run_frames: int) -> tuple[Any, ...]:
        """Errors over the scoring window (:func:`scoring_window`) of the ``run_frames`` from ``start_n``."""
        with self.lock:
            everything = list(self.fused)
            converged = list(self.converged)
            single = [list(s) for s in self.single]
            published = dict(self.published_ns)
        T = len(self.truth)
        fps = 1e6 / self.period_us
        pass_of = scoring_window(
            np.array([n for n, _, _ in everything], dtype=np.int64), self.start_n, T, run_frames, fps
        )
        keep = [i for i, (p, ok) in enumerate(zip(pass_of, converged, strict=True)) if p >= 0 and ok]
        fused = [everything[i] for i in keep]
        per_pass: list[float] = []
        if fused:
            estimate = np.stack([p for _, p, _ in fused])
            truth = self.truth[[(n - self.origin_n) % T for n, _, _ in fused]]
            fused_errors = _group_errors(estimate, truth)
            per_pass = _per_pass(estimate, truth, pass_of[keep])
        else:
            fused_errors = {k: float("nan") for k in ("torso", "upper_limb", "lower_limb", "all16")}
        best_id, best = "", {k: float("nan") for k in fused_errors}
        fused_instants = {n for n, _, _ in fused}
        for sensor_id, column in self.column.items():
            rows = [(n, w) for n, w in single[column] if n in fused_instants]
            if not rows:
                continue
            errors = _group_errors(
                np.stack([w for _, w in rows]), self.truth[[(n - self.origin_n) % T for n, _ in rows]]
            )
            if not best_id or errors["all16"] < best["all16"]:
                best_id, best = sensor_id, errors
        latency = [(received - published[n]) / 1e6 for n, _, received in everything if n in published]
        in_run = sum(self.start_n <= n < self.start_n + run_frames for n, _, _ in everything)
        return in_run, len(everything) - in_run, len(fused), fused_errors, best, best_id, latency, per_pass


def _stop_processes(processes: list[Any], timeout_s: float = 5.0) -> None:
    """SIGTERM the process groups we started, all at once, then SIGKILL those left after ``timeout_s``."""
    running = [p for p in processes if p.poll() is None]
    for process in running:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGTERM)
    deadline = time.monotonic() + timeout_s
    for process in running:
        try:
            process.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
            process.wait(timeout=timeout_s)


def run_demo(
    *,
    duration_s: float = 20.0,
    gesture: str = "walking",
    preset_name: str = DEFAULT_PRESET,
    seed: int = 0,
    rrd_path: Path | None = None,
    spawn: bool | None = None,
    serve: bool = False,
    web_port: int | None = None,
    grpc_port: int | None = None,
    take_duration_s: float = DEMO_TAKE_S,
    progress: bool = True,
    lifecycle: Any = None,
) -> DemoSummary | None:
    """The live demo (see the module docstring): runs ``duration_s`` seconds of fused output or until Ctrl-C.

    Parameters
    ----------
    rrd_path : save the view here instead of spawning a viewer.
    spawn : spawn the Rerun viewer; default: when there is a display and neither ``rrd_path`` nor ``serve``.
        Without any of them the view goes to ``skelfuse-demo.rrd``.
    serve : serve the view over gRPC on 127.0.0.1 (``grpc_port``, default 9876) for viewers to connect.
    web_port : with ``serve``, also serve Rerun's web viewer on this port (its URL is printed).

    The demo is a rig like any other: it prints its rig name, its zenoh endpoint and the command lines that
    attach ``skelfuse status``, ``skelfuse stream`` and the example subscriber to it. Its working folder (the
    rig config those commands read, the workers' logs) is removed when it ends.

    Returns None when stopped (Ctrl-C, SIGTERM) before the first fused frame.

    Raises
    ------
    ServiceError
        A capture worker exits early, or no fused frame arrives within STARTUP_TIMEOUT_S.
    """

    if duration_s <= 0:
        raise ValueError(f"--duration must be positive, got {duration_s}")
    lifecycle = lifecycle or Lifecycle("demo")
    if spawn is None:
        spawn = rrd_path is None and not serve and has_display()
    if rrd_path is None and not spawn and not serve:
        rrd_path = DEFAULT_RRD

    workdir = Path(tempfile.mkdtemp(prefix="skelfuse-demo-"))
    try:
        return _run_live(
            workdir,
            duration_s=duration_s,
            gesture=gesture,
            preset_name=preset_name,
            seed=seed,
            rrd_path=rrd_path,
            spawn=spawn,
            view=_view_options(serve, web_port, grpc_port, spawn, rrd_path),
            take_duration_s=take_duration_s,
            progress=progress,
            lifecycle=lifecycle,
        )
    finally:
        shutil.rmtree(workdir, ignore_errors=True)  # the rig config and the workers' logs: no folder left behind


def _view_options(
    serve: bool, web_port: int | None, grpc_port: int | None, spawn: bool, rrd_path: Path | None
) -> ViewOptions:
    if serve:
        return ViewOptions(
            mode="serve",
            web_port=web_port,
            grpc_port=grpc_port or ViewOptions.grpc_port,
            application_id="skelfuse_demo",
        )
    return ViewOptions(mode="spawn" if spawn else "save", file=rrd_path or DEFAULT_RRD, application_id="skelfuse_demo")


def _attach_text(rig: str, port: int, rig_path: Path, view: ViewOptions) -> str:
    """What the demo prints so that other apps attach to it."""
    lines = [
        f'skelfuse demo: rig "{rig}", zenoh endpoint tcp/127.0.0.1:{port} (peer mode, no multicast); attach with:',
        f"  skelfuse status --config {rig_path}",
        f"  skelfuse stream osc --config {rig_path}        (or vmc, lsl)",
        f"  python scripts/example_subscriber.py --config {rig_path}",
        f"  (or any zenoh app: connect tcp/127.0.0.1:{port}, subscribe {keys.fused_skeletons(rig)})",
    ]
    if view.mode == "serve":
        grpc = f"rerun+http://127.0.0.1:{view.grpc_port}/proxy"
        lines.append(f"skelfuse demo: live view: rerun {grpc}")
        if view.web_port:
            lines.append(f"skelfuse demo: web viewer: {web_viewer_url('127.0.0.1', view.web_port, grpc)}")
    return "\n".join(lines)


def _run_live(
    workdir: Path,
    *,
    duration_s: float,
    gesture: str,
    preset_name: str,
    seed: int,
    rrd_path: Path | None,
    spawn: bool,
    view: ViewOptions,
    take_duration_s: float,
    progress: bool,
    lifecycle: Any,
) -> DemoSummary | None:
    port = free_port()
    rig_path = write_demo_rig(workdir, preset_name=preset_name, port=port)
    cfg = load_rig_config(rig_path)
    # The same simulation every worker runs: truth and the simulated calibration (what fusion uses).
    observations = simulate_rig(cfg, gesture=gesture, take_duration_s=take_duration_s, seed=seed)
    write_calibration(workdir / "calibration.toml", observations.sensor_ids, observations.world_from_sensor_calibrated)
    cfg = load_rig_config(rig_path)
    poses = cfg.poses()
    # Every run plays the take from its first frame at the same moment after the start (the workers take a
    # few seconds to come up), so a seed always scores the same stretch of the take.
    take_origin = repr(round(time.time() + TAKE_ORIGIN_DELAY_S, 3))
    origin_n = math.ceil(round(float(take_origin) * 1e9) / (1e9 / cfg.sync.fps))
    scorer = _Scorer(
        observations.truth, cfg.sync.fps, np.stack([poses[s] for s in cfg.sensor_ids]), cfg.sensor_ids, origin_n
    )

    import zenoh

    recording, server = open_recording(view)
    workers: list[subprocess.Popen[bytes]] = []
    logs = []
    node_lifecycle = Lifecycle("fusion")
    session = zenoh.open(loopback_config(listen_port=port))
    node = FusionNode(
        cfg,
        None,
        options=NodeOptions(node_name="fusion"),
        lifecycle=node_lifecycle,
        session=session,
        recording=recording,
    )
    scorer.on_error = lambda time_us, error: node.log_error(time_us, error)
    node_thread = threading.Thread(target=node.run, name="skelfuse-fusion-node", daemon=True)
    started = ended = None
    try:
        with lifecycle.capture_signals():
            session.declare_subscriber(keys.all_sensor_skeletons(cfg.name), scorer.on_sensor)
            session.declare_subscriber(keys.fused_skeletons(cfg.name), scorer.on_fused)
            node_thread.start()
            node.ready.wait(10.0)
            for sensor_id in cfg.sensor_ids:
                log_file = open(workdir / f"capture-{sensor_id}.log", "wb")
                logs.append(log_file)
                command = [
                    sys.executable,
                    "-m",
                    "skelfuse",
                    "capture",
                    "--config",
                    str(rig_path),
                    "--sensor",
                    sensor_id,
                    "--gesture",
                    gesture,
                    "--take-duration",
                    str(take_duration_s),
                    "--seed",
                    str(seed),
                    "--take-origin",
                    take_origin,
                    *loopback_args(connect_ports=[port]),
                ]
                workers.append(
                    subprocess.Popen(
                        command,
                        stdin=subprocess.DEVNULL,
                        stdout=log_file,
                        stderr=subprocess.STDOUT,
                        start_new_session=True,
                    )
                )
            print(_attach_text(cfg.name, port, rig_path, view), file=sys.stderr, flush=True)
            if progress:
                print("skelfuse demo: starting 4 capture workers and the fusion node ...", file=sys.stderr, flush=True)
            deadline = time.monotonic() + STARTUP_TIMEOUT_S
            while scorer.first_fused is None and not lifecycle.should_exit:
                _check_workers(workers, workdir)
                if time.monotonic() > deadline:
                    raise ServiceError(f"no fused frame within {STARTUP_TIMEOUT_S:.0f} s{_log_tails(workdir)}")
                lifecycle.wait(0.1)
            # The scored run starts with a pass of the take: at the take's origin, or, when the workers came up
            # after it, at the start of the next pass (each pass is the same material, so the figures are too).
            origin_monotonic = time.monotonic() + float(take_origin) - time.time()
            first_fused = scorer.first_fused if scorer.first_fused is not None else time.monotonic()  # or stopped
            late_passes = max(0, math.ceil((first_fused - origin_monotonic) / take_duration_s))
            if late_passes:
                log.info(
                    "the capture workers came up %.1f s after the take's start; the run starts with the next pass "
                    "of the take, in %.1f s",
                    first_fused - origin_monotonic,
                    origin_monotonic + late_passes * take_duration_s - time.monotonic(),
                )
            scorer.start_n = origin_n + late_passes * round(take_duration_s * cfg.sync.fps)
            started = origin_monotonic + late_passes * take_duration_s
            if not lifecycle.wait(max(0.0, started - time.monotonic())):
                log.info(
                    "the run starts: %.0f s of fused output from a pass of the %.0f s take (scored: take seconds "
                    "%.1f-%.0f of each whole pass)",
                    duration_s,
                    take_duration_s,
                    CONVERGE_S,
                    take_duration_s,
                )
            end = started + duration_s
            while not lifecycle.should_exit and time.monotonic() < end:
                _check_workers(workers, workdir)
                lifecycle.wait(min(1.0, max(0.0, end - time.monotonic())))
                elapsed_s = time.monotonic() - started
                if progress and (sys.stderr.isatty() or int(elapsed_s) % 5 == 0 or elapsed_s >= duration_s):
                    _progress(f"skelfuse demo: {len(scorer.fused)} frames fused, {elapsed_s:.0f}/{duration_s:.0f} s")
            ended = time.monotonic()
            lifecycle.wait(RESULT_GRACE_S)  # the last instants' fused frames are still on their way
            if progress:
                _progress("", final=True)
    finally:
        _stop_processes(workers)
        for log_file in logs:
            log_file.close()
        node_lifecycle.request_exit()
        node_thread.join(15.0)
        close_session(session, what="demo")
        if recording is not None:
            release_recording(recording)
        stop_server(server)
    elapsed = 0.0 if started is None else min(max(0.0, (ended or time.monotonic()) - started), duration_s)
    run_frames = round(elapsed * cfg.sync.fps)
    n_fused, n_before, n_scored, fused_errors, best, best_id, latency, per_pass = scorer.scores(run_frames)
    if n_fused + n_before == 0:
        if lifecycle.should_exit:  # stopped (Ctrl-C, SIGTERM) while starting: a clean stop, nothing to say
            return None
        raise ServiceError("the demo stopped before the first fused frame; nothing to summarize")
    report = node.report

    def pct(values: Sequence[float], q: float) -> float | None:
        return float(np.percentile(values, q)) if values else None

    fusion_ms = report.fusion_ms
    return DemoSummary(
        frames_fused=n_fused,
        frames_before_run=n_before,
        duration_s=round(elapsed, 3),
        gesture=gesture,
        preset=preset_name,
        n_sensors=len(cfg.sensors),
        error_fused_mm=fused_errors,
        error_best_single_sensor_mm=best | {"sensor": best_id},
        fusion_p50_ms=float(np.percentile(fusion_ms, 50)),
        fusion_p99_ms=float(np.percentile(fusion_ms, 99)),
        recording=str(rrd_path) if rrd_path is not None and not spawn else None,
        latency_p50_ms=pct(latency, 50),
        latency_p99_ms=pct(latency, 99),
        node_added_p50_ms=pct(report.added_ms, 50),
        node_added_p99_ms=pct(report.added_ms, 99),
        mode="live",
        frames_scored=n_scored,
        take_s=take_duration_s,
        passes_scored=len(per_pass),
        partial_pass=run_frames < round(take_duration_s * cfg.sync.fps),
        error_fused_per_pass_mm=per_pass,
    )


def _log_tails(workdir: Path) -> str:
    """The last lines of every worker's log (the folder is removed when the demo ends)."""
    tails = []
    for path in sorted(workdir.glob("capture-*.log")):
        lines = path.read_text(errors="replace").strip().splitlines()[-3:]
        tails.append(f"\n  {path.stem}: " + "\n    ".join(lines or ["(nothing logged)"]))
    return "; the workers' last log lines:" + "".join(tails) if tails else ""


def _check_workers(workers: list[Any], workdir: Path) -> None:

    for process in workers:
        if process.poll() is not None:
            log_path = workdir / f"capture-{process.args[process.args.index('--sensor') + 1]}.log"
            tail = log_path.read_text(errors="replace").strip().splitlines()[-5:] if log_path.exists() else []
            raise ServiceError(
                f"capture worker {' '.join(process.args[3:7])} exited with status {process.returncode}:"
                f"\n  " + "\n  ".join(tail)
            )
