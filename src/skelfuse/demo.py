"""``skelfuse demo``: a simulated 4-sensor rig fused frame by frame and drawn in Rerun.

The first thing a new user runs. It needs no sensor and no data: the simulator plays a person walking
through a rig of four virtual Azure Kinects (rear views mirror left and right, occluded joints are guessed,
everything trembles), the fusion core merges the views frame by frame, and Rerun shows the raw and fused
skeletons live. Where there is no screen the recording is saved to a .rrd file instead.

The loop runs in one process for now; it is the same per-frame cycle the fusion node runs on live
sensor frames.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.skeleton import EVAL_JOINTS, JOINT_GROUPS

log = logging.getLogger(__name__)

DEFAULT_RRD = Path("skelfuse-demo.rrd")


@dataclass(frozen=True)
class DemoSummary:
    """What the demo prints at the end. Errors are mean Euclidean distances to ground truth, mm."""

    frames_fused: int
    duration_s: float
    gesture: str
    preset: str
    n_sensors: int
    error_fused_mm: dict[str, float]
    error_best_single_sensor_mm: dict[str, float]
    fusion_p50_ms: float
    fusion_p99_ms: float
    recording: str | None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def has_display() -> bool:
    """Whether a viewer window can open here (a desktop session, or macOS / Windows)."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


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


def run_demo(
    *,
    duration_s: float = 20.0,
    gesture: str = "walking",
    preset_name: str = "A5",
    seed: int = 0,
    rrd_path: Path | None = None,
    spawn: bool | None = None,
    realtime: bool | None = None,
    progress: bool = True,
) -> DemoSummary:
    """Simulate, fuse and draw; returns the summary.

    Parameters
    ----------
    rrd_path : save the recording here instead of spawning a viewer.
    spawn : spawn the Rerun viewer; default: when there is a display and no ``rrd_path``. Without either,
        the recording goes to ``skelfuse-demo.rrd``.
    realtime : pace frames at the sensors' 30 Hz; default: only when a live viewer is watching.
    """
    import rerun as rr

    from skelfuse.fusion.pipeline import Fuser
    from skelfuse.fusion.presets import preset
    from skelfuse.fusion.transform import apply_transform
    from skelfuse.sim.gestures import make_gesture
    from skelfuse.sim.observe import load_profile, simulate
    from skelfuse.sim.rig import paper_rig
    from skelfuse.sinks.rerun_sink import RerunSink, default_blueprint

    if duration_s <= 0:
        raise ValueError(f"--duration must be positive, got {duration_s}")
    params = preset(preset_name)
    sensors = paper_rig(4)
    motion = make_gesture(gesture, duration_s=duration_s, seed=seed)
    observations = simulate(motion, sensors, load_profile(), seed=seed)
    world = apply_transform(observations.world_from_sensor_calibrated, observations.positions.astype(np.float64))
    n_frames = world.shape[0]

    if spawn is None:
        spawn = rrd_path is None and has_display()
    if rrd_path is None and not spawn:
        rrd_path = DEFAULT_RRD
    if realtime is None:
        realtime = bool(spawn)

    recording = rr.RecordingStream("skelfuse_demo")
    if spawn:
        recording.spawn(default_blueprint=default_blueprint())
    else:
        assert rrd_path is not None
        recording.save(rrd_path, default_blueprint=default_blueprint())
    sink = RerunSink(recording, observations.sensor_ids)
    sink.log_rig(observations.world_from_sensor_calibrated)

    fuser = Fuser(params, n_bodies=1)
    fused = np.full((n_frames, 32, 3), np.nan)
    fusion_ns = np.zeros(n_frames, dtype=np.int64)
    times_s = (observations.device_time_us[:, 0] - observations.device_time_us[0, 0]) / 1e6
    period_s = 1.0 / motion.fps
    started = time.perf_counter()
    track_ids = np.array([1])
    for frame in range(n_frames):
        candidates = world[frame][None]  # (B=1, S, 32, 3)
        confidence = observations.confidence[frame][None]
        tick = time.perf_counter_ns()
        result = fuser.step(candidates, confidence, period_s)
        fusion_ns[frame] = time.perf_counter_ns() - tick
        fused[frame] = result.positions[0]

        sink.set_time(float(times_s[frame]))
        sink.log_sensor_skeletons(world[frame][:, None])
        sink.log_fused(result.positions, track_ids)
        error = np.linalg.norm(result.positions[0, EVAL_JOINTS] - observations.truth[frame, EVAL_JOINTS], axis=-1)
        sink.log_metrics(
            fusion_ms=fusion_ns[frame] / 1e6,
            error_mm=float(np.nanmean(error)) if np.isfinite(error).any() else None,
        )
        if progress and frame % 30 == 0:
            print(f"\rskelfuse demo: frame {frame + 1}/{n_frames}", end="", file=sys.stderr, flush=True)
        if realtime:
            lag = started + (frame + 1) * period_s - time.perf_counter()
            if lag > 0:
                time.sleep(lag)
    if progress:
        print(f"\rskelfuse demo: fused {n_frames} frames.        ", file=sys.stderr)
    recording.flush()
    if rrd_path is not None:
        recording.disconnect()

    single = {
        sensor_id: _group_errors(world[:, index], observations.truth)
        for index, sensor_id in enumerate(observations.sensor_ids)
    }
    best_sensor = min(single, key=lambda sensor_id: single[sensor_id]["all16"])
    return DemoSummary(
        frames_fused=n_frames,
        duration_s=float(motion.duration_s),
        gesture=gesture,
        preset=preset_name,
        n_sensors=len(sensors),
        error_fused_mm=_group_errors(fused, observations.truth),
        error_best_single_sensor_mm=single[best_sensor] | {"sensor": best_sensor},  # type: ignore[dict-item]
        fusion_p50_ms=float(np.percentile(fusion_ns, 50)) / 1e6,
        fusion_p99_ms=float(np.percentile(fusion_ns, 99)) / 1e6,
        recording=str(rrd_path) if rrd_path is not None else None,
    )


def format_summary(summary: DemoSummary) -> str:
    best = summary.error_best_single_sensor_mm
    lines = [
        f"Fused {summary.frames_fused} frames ({summary.duration_s:.1f} s of '{summary.gesture}') from "
        f"{summary.n_sensors} simulated sensors with preset {summary.preset}.",
        "",
        "Mean error against the simulator's ground truth (mm):",
        "| | torso | upper limb | lower limb | all 16 |",
        "|---|---:|---:|---:|---:|",
    ]
    for label, errors in (("fused", summary.error_fused_mm), (f"best single sensor ({best['sensor']})", best)):
        lines.append(
            f"| {label} | {errors['torso']:.1f} | {errors['upper_limb']:.1f} | {errors['lower_limb']:.1f} "
            f"| {errors['all16']:.1f} |"
        )
    lines += ["", f"Fusion time per frame: p50 {summary.fusion_p50_ms:.3f} ms, p99 {summary.fusion_p99_ms:.3f} ms."]
    if summary.recording:
        lines.append(f"Recording saved to {summary.recording}; open it with:  rerun {summary.recording}")
    return "\n".join(lines)
