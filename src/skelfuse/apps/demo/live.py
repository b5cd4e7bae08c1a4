"""The live demo (:func:`run_demo`): the real service on loopback zenoh, scored against the simulator's truth.

Cycle: write the rig (config and simulated calibration) into a working folder (:func:`_prepare_rig`); open
the view and the fusion node's session in this process; start one ``skelfuse capture`` worker per sensor;
wait for the first fused frame; run ``--duration`` seconds from a pass of the take; stop everything; score
(:func:`_live_summary`). What the demo is: :mod:`skelfuse.apps.demo`.
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
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from skelfuse.apps.demo import CONVERGE_S, DEFAULT_RRD, DEMO_TAKE_S
from skelfuse.apps.demo.rigfile import write_calibration, write_demo_rig
from skelfuse.apps.demo.scorer import LiveScorer
from skelfuse.apps.demo.summary import DemoSummary, progress_line
from skelfuse.config import DEFAULT_PRESET, RigConfig, load_rig_config
from skelfuse.schema.errors import ServiceError
from skelfuse.service.lifecycle import Lifecycle
from skelfuse.service.node import FusionNode, NodeOptions, NodeReport
from skelfuse.service.viewer import (
    ViewOptions,
    has_display,
    open_recording,
    release_recording,
    stop_server,
    web_viewer_url,
)
from skelfuse.service.worker import simulate_rig
from skelfuse.service.zenoh_io import close_session, free_port, loopback_args, loopback_config
from skelfuse.wire import keys

log = logging.getLogger(__name__)

RESULT_GRACE_S = 0.5
"""After ``--duration``, how long the demo still collects fused frames (they arrive milliseconds late)."""
TAKE_ORIGIN_DELAY_S = 8.0
"""The live demo's take starts this long after the demo (the workers' start-up fits in it on most PCs)."""
STARTUP_TIMEOUT_S = 90.0


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


@dataclass
class _LiveRig:
    """The demo's rig once written: its config, its endpoint, the take's origin and the scorer."""

    cfg: RigConfig
    rig_path: Path
    port: int
    take_origin: str  # wall-clock seconds, as the workers' --take-origin reads it
    origin_n: int  # the instant at which the workers play take frame 0
    scorer: LiveScorer


def _prepare_rig(workdir: Path, *, preset_name: str, gesture: str, take_duration_s: float, seed: int) -> _LiveRig:
    """Write the rig config and its simulated calibration into ``workdir``; set up the scorer."""
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
    scorer = LiveScorer(
        observations.truth, cfg.sync.fps, np.stack([poses[s] for s in cfg.sensor_ids]), cfg.sensor_ids, origin_n
    )
    return _LiveRig(cfg, rig_path, port, take_origin, origin_n, scorer)


def _start_workers(
    live: _LiveRig,
    workdir: Path,
    workers: list[subprocess.Popen[bytes]],
    logs: list[IO[bytes]],
    *,
    gesture: str,
    take_duration_s: float,
    seed: int,
) -> None:
    """One ``skelfuse capture`` per sensor, each in its own process group, its output in ``workdir``; the
    processes and log files go into ``workers`` and ``logs`` as they start (so that a failure stops them)."""
    for sensor_id in live.cfg.sensor_ids:
        log_file = open(workdir / f"capture-{sensor_id}.log", "wb")
        logs.append(log_file)
        command = [
            sys.executable,
            "-m",
            "skelfuse",
            "capture",
            "--config",
            str(live.rig_path),
            "--sensor",
            sensor_id,
            "--gesture",
            gesture,
            "--take-duration",
            str(take_duration_s),
            "--seed",
            str(seed),
            "--take-origin",
            live.take_origin,
            *loopback_args(connect_ports=[live.port]),
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


def _wait_first_fused(live: _LiveRig, workers: list[Any], workdir: Path, lifecycle: Any) -> None:
    """Until the first fused frame arrives (or a stop is asked); a worker that exits or a silent rig raises."""
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    while live.scorer.first_fused is None and not lifecycle.should_exit:
        _check_workers(workers, workdir)
        if time.monotonic() > deadline:
            raise ServiceError(f"no fused frame within {STARTUP_TIMEOUT_S:.0f} s{_log_tails(workdir)}")
        lifecycle.wait(0.1)


def _start_of_run(live: _LiveRig, *, duration_s: float, take_duration_s: float, lifecycle: Any) -> float:
    """Wait for the scored run's start and return it (monotonic seconds).

    The scored run starts with a pass of the take: at the take's origin, or, when the workers came up after
    it, at the start of the next pass (each pass is the same material, so the figures are too).
    """
    scorer = live.scorer
    origin_monotonic = time.monotonic() + float(live.take_origin) - time.time()
    first_fused = scorer.first_fused if scorer.first_fused is not None else time.monotonic()  # or stopped
    late_passes = max(0, math.ceil((first_fused - origin_monotonic) / take_duration_s))
    if late_passes:
        log.info(
            "the capture workers came up %.1f s after the take's start; the run starts with the next pass "
            "of the take, in %.1f s",
            first_fused - origin_monotonic,
            origin_monotonic + late_passes * take_duration_s - time.monotonic(),
        )
    scorer.start_n = live.origin_n + late_passes * round(take_duration_s * live.cfg.sync.fps)
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
    return started


def _play(
    live: _LiveRig, started: float, duration_s: float, workers: list[Any], workdir: Path, lifecycle: Any, progress: bool
) -> float:
    """Run ``duration_s`` seconds from ``started`` (watching the workers); returns when it ended (monotonic)."""
    end = started + duration_s
    while not lifecycle.should_exit and time.monotonic() < end:
        _check_workers(workers, workdir)
        lifecycle.wait(min(1.0, max(0.0, end - time.monotonic())))
        elapsed_s = time.monotonic() - started
        if progress and (sys.stderr.isatty() or int(elapsed_s) % 5 == 0 or elapsed_s >= duration_s):
            progress_line(f"skelfuse demo: {len(live.scorer.fused)} frames fused, {elapsed_s:.0f}/{duration_s:.0f} s")
    ended = time.monotonic()
    lifecycle.wait(RESULT_GRACE_S)  # the last instants' fused frames are still on their way
    if progress:
        progress_line("", final=True)
    return ended


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
    live = _prepare_rig(workdir, preset_name=preset_name, gesture=gesture, take_duration_s=take_duration_s, seed=seed)
    cfg, scorer = live.cfg, live.scorer

    import zenoh

    recording, server = open_recording(view)
    workers: list[subprocess.Popen[bytes]] = []
    logs: list[IO[bytes]] = []
    node_lifecycle = Lifecycle("fusion")
    session = zenoh.open(loopback_config(listen_port=live.port))
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
            _start_workers(live, workdir, workers, logs, gesture=gesture, take_duration_s=take_duration_s, seed=seed)
            print(_attach_text(cfg.name, live.port, live.rig_path, view), file=sys.stderr, flush=True)
            if progress:
                print("skelfuse demo: starting 4 capture workers and the fusion node ...", file=sys.stderr, flush=True)
            _wait_first_fused(live, workers, workdir, lifecycle)
            started = _start_of_run(live, duration_s=duration_s, take_duration_s=take_duration_s, lifecycle=lifecycle)
            ended = _play(live, started, duration_s, workers, workdir, lifecycle, progress)
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
    return _live_summary(
        live,
        node.report,
        elapsed,
        gesture=gesture,
        preset_name=preset_name,
        recording=str(rrd_path) if rrd_path is not None and not spawn else None,
        take_duration_s=take_duration_s,
        stopped=lifecycle.should_exit,
    )


def _live_summary(
    live: _LiveRig,
    report: NodeReport,
    elapsed: float,
    *,
    gesture: str,
    preset_name: str,
    recording: str | None,
    take_duration_s: float,
    stopped: bool,
) -> DemoSummary | None:
    """The scores of the ``elapsed`` seconds run; None when stopped before the first fused frame."""
    run_frames = round(elapsed * live.cfg.sync.fps)
    n_fused, n_before, n_scored, fused_errors, best, best_id, latency, per_pass = live.scorer.scores(run_frames)
    if n_fused + n_before == 0:
        if stopped:  # stopped (Ctrl-C, SIGTERM) while starting: a clean stop, nothing to say
            return None
        raise ServiceError("the demo stopped before the first fused frame; nothing to summarize")

    def pct(values: Sequence[float], q: float) -> float | None:
        return float(np.percentile(values, q)) if values else None

    fusion_ms = report.fusion_ms
    return DemoSummary(
        frames_fused=n_fused,
        frames_before_run=n_before,
        duration_s=round(elapsed, 3),
        gesture=gesture,
        preset=preset_name,
        n_sensors=len(live.cfg.sensors),
        error_fused_mm=fused_errors,
        error_best_single_sensor_mm=best | {"sensor": best_id},
        fusion_p50_ms=float(np.percentile(fusion_ms, 50)),
        fusion_p99_ms=float(np.percentile(fusion_ms, 99)),
        recording=recording,
        latency_p50_ms=pct(latency, 50),
        latency_p99_ms=pct(latency, 99),
        node_added_p50_ms=pct(report.added_ms, 50),
        node_added_p99_ms=pct(report.added_ms, 99),
        mode="live",
        frames_scored=n_scored,
        take_s=take_duration_s,
        passes_scored=len(per_pass),
        partial_pass=run_frames < round(take_duration_s * live.cfg.sync.fps),
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
