"""The offline demo (``skelfuse demo --offline``): the live node's per-frame cycle in one loop, no zenoh.

Cycle: simulate the take once (:func:`_simulate_run`: the looping take's frames for the whole run), open the
view, fuse and draw frame by frame (:func:`_fuse_and_draw`, paced at 30 Hz when a viewer watches), score the
run against the simulator's ground truth (:func:`_offline_summary`).
"""

from __future__ import annotations

import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.apps.demo import DEFAULT_RRD, DEMO_TAKE_S
from skelfuse.apps.demo.summary import DemoSummary, group_errors, per_pass_errors, progress_line, scoring_window
from skelfuse.config import DEFAULT_PRESET
from skelfuse.fusion.pipeline import Fuser
from skelfuse.fusion.presets import FusionParams, preset
from skelfuse.fusion.transform import apply_transform
from skelfuse.schema.skeleton import EVAL_JOINTS
from skelfuse.service.viewer import FLUSH_TIMEOUT_S, ViewOptions, has_display, open_recording, release_recording
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.rig import paper_rig
from skelfuse.sinks.rerun_sink import RerunSink, default_blueprint

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class _OfflineRun:
    """The run's frames: take frame ``take_frame[i]`` at run frame i, its views in world mm and the truth."""

    world: np.ndarray  # (T, S, 32, 3) each sensor's skeleton in the world (simulated calibration), mm
    truth: np.ndarray  # (T, 32, 3)
    confidences: np.ndarray  # (T, S, 32)
    take_frame: np.ndarray  # (T,)
    take_frames: int
    fps: float
    sensor_ids: tuple[str, ...]
    world_from_sensor: np.ndarray  # (S, 4, 4) the simulated calibration fusion uses


def _simulate_run(duration_s: float, gesture: str, seed: int, take_duration_s: float) -> _OfflineRun:
    """The take (it loops, see DEMO_TAKE_S) seen by the paper's 4 sensors, laid out over the run's frames."""
    motion = make_gesture(gesture, duration_s=take_duration_s, seed=seed)
    observations = simulate(motion, paper_rig(4), load_profile(), seed=seed)
    poses = observations.world_from_sensor_calibrated
    take_world = apply_transform(poses, observations.positions.astype(np.float64))
    n_frames = max(1, round(duration_s * motion.fps))
    take_frame = np.arange(n_frames) % take_world.shape[0]  # frame i of the run shows take frame i mod T
    return _OfflineRun(
        world=take_world[take_frame],
        truth=observations.truth[take_frame],
        confidences=observations.confidence[take_frame],
        take_frame=take_frame,
        take_frames=take_world.shape[0],
        fps=motion.fps,
        sensor_ids=observations.sensor_ids,
        world_from_sensor=poses,
    )


def _fuse_and_draw(
    run: _OfflineRun, params: FusionParams, sink: RerunSink, *, realtime: bool, progress: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Fuse and draw every frame; returns the fused skeletons (T, 32, 3) and each frame's fusion time, ns."""
    n_frames = len(run.take_frame)
    fused = np.full((n_frames, 32, 3), np.nan)
    fusion_ns = np.zeros(n_frames, dtype=np.int64)
    period_s = 1.0 / run.fps
    started = time.perf_counter()
    track_ids = np.array([1])
    for frame in range(n_frames):
        if run.take_frame[frame] == 0:  # the person jumps back to the take's start: a new track, as live
            fuser = Fuser(params, n_bodies=1, sensor_positions=run.world_from_sensor[:, :3, 3])
        tick = time.perf_counter_ns()
        result = fuser.step(run.world[frame][None], run.confidences[frame][None], period_s)  # (B=1, S, 32, 3)
        fusion_ns[frame] = time.perf_counter_ns() - tick
        fused[frame] = result.positions[0]
        _draw_frame(sink, run, frame, result.positions, track_ids, fusion_ns[frame])
        if progress and frame % (30 if sys.stderr.isatty() else 300) == 0:
            progress_line(f"skelfuse demo: frame {frame + 1}/{n_frames}")
        if realtime:
            lag = started + (frame + 1) * period_s - time.perf_counter()
            if lag > 0:
                time.sleep(lag)
    if progress:
        progress_line(f"skelfuse demo: fused {n_frames} frames.", final=True)
    return fused, fusion_ns


def _draw_frame(
    sink: RerunSink, run: _OfflineRun, frame: int, positions: np.ndarray, track_ids: np.ndarray, fusion_ns: int
) -> None:
    """One frame in the view: the sensors' skeletons, the fused one and its error against the truth."""
    sink.set_time(float(frame / run.fps))
    sink.log_sensor_skeletons(run.world[frame][:, None])
    sink.log_fused(positions, track_ids)
    error = np.linalg.norm(positions[0, EVAL_JOINTS] - run.truth[frame, EVAL_JOINTS], axis=-1)
    sink.log_metrics(
        fusion_ms=fusion_ns / 1e6,
        error_mm=float(np.nanmean(error)) if np.isfinite(error).any() else None,
    )


def _offline_summary(
    run: _OfflineRun, fused: np.ndarray, fusion_ns: np.ndarray, *, gesture: str, preset_name: str, rrd: Any
) -> DemoSummary:
    """The run scored against the truth over :func:`scoring_window`, beside the best single sensor."""
    n_frames = len(run.take_frame)
    pass_index = scoring_window(np.arange(n_frames), 0, run.take_frames, n_frames, run.fps)
    scored = pass_index >= 0
    single = {
        sensor_id: group_errors(run.world[scored, index], run.truth[scored])
        for index, sensor_id in enumerate(run.sensor_ids)
    }
    best_sensor = min(single, key=lambda sensor_id: single[sensor_id]["all16"])
    return DemoSummary(
        frames_fused=n_frames,
        duration_s=n_frames / run.fps,
        gesture=gesture,
        preset=preset_name,
        n_sensors=len(run.sensor_ids),
        error_fused_mm=group_errors(fused[scored], run.truth[scored]),
        error_best_single_sensor_mm=single[best_sensor] | {"sensor": best_sensor},
        fusion_p50_ms=float(np.percentile(fusion_ns, 50)) / 1e6,
        fusion_p99_ms=float(np.percentile(fusion_ns, 99)) / 1e6,
        recording=str(rrd) if rrd is not None else None,
        frames_scored=int(scored.sum()),
        take_s=run.take_frames / run.fps,
        passes_scored=int(pass_index.max()) + 1 if scored.any() else 0,
        partial_pass=n_frames < run.take_frames,
        error_fused_per_pass_mm=per_pass_errors(fused[scored], run.truth[scored], pass_index[scored]),
    )


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
    run = _simulate_run(duration_s, gesture, seed, take_duration_s)
    if spawn is None:
        spawn = rrd_path is None and has_display()
    if rrd_path is None and not spawn:
        rrd_path = DEFAULT_RRD
    if realtime is None:
        realtime = bool(spawn)

    recording, _ = open_recording(
        ViewOptions(mode="spawn" if spawn else "save", file=rrd_path or DEFAULT_RRD, application_id="skelfuse_demo")
    )
    sink = RerunSink(recording, run.sensor_ids)
    sink.log_rig(run.world_from_sensor)
    recording.send_blueprint(default_blueprint(run.world_from_sensor))
    fused, fusion_ns = _fuse_and_draw(run, params, sink, realtime=realtime, progress=progress)
    try:
        recording.flush(timeout_sec=FLUSH_TIMEOUT_S)
    except Exception as exc:  # a viewer that went away: its last frames are lost, the summary is not
        log.warning("rerun: the view could not be flushed within %.1f s (%s)", FLUSH_TIMEOUT_S, exc)
    release_recording(recording)
    return _offline_summary(run, fused, fusion_ns, gesture=gesture, preset_name=preset_name, rrd=rrd_path)
