"""Cost of the depth-level fusion: the capture side's person clouds on the wire, and the fusion node's
merge + ICP + frontalize + render per person per frame.

Input: the depth simulator (:mod:`skelfuse.sim.depth`): 1-3 people doing the paper's gestures in the capture
area of a 4-sensor rig (NFOV unbinned, 640 x 576), each sensor's depth and body-index images rendered per
frame (not timed). Per sensor and frame the capture side's work is timed (mask, lift, voxelize, encode) and
its payload's bytes counted; per person and frame the fusion node's work is timed (decode, to world,
optional ICP, merge, frontalize, render with hole filling). The body tracker on the virtual image is not
included: it needs the SDK and a GPU (``skelfuse eval depth``), and its time is its own.

Times are wall-clock (``perf_counter``) and, beside them, the CPU time of the timing thread
(``thread_time``), which a busy shared machine inflates less. The simulated bodies are capsules and the
depth noise an assumed model: point counts (hence bytes and times) are those of the simulated surface,
not measured on a real sensor.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from skelfuse.fusion.camera import Intrinsics
from skelfuse.fusion.depth.cloud import person_clouds
from skelfuse.fusion.depth.frontal import body_facing
from skelfuse.fusion.depth.pipeline import DepthFusionParams, fuse_person_depth
from skelfuse.progress import Progress
from skelfuse.sim.depth import DepthNoise, render_rig
from skelfuse.sim.gestures import GESTURES, make_gesture
from skelfuse.sim.rig import paper_rig
from skelfuse.wire.clouds import PersonCloudsFrame, decode_person_clouds, encode_person_clouds

FPS = 30.0
FRAME_BUDGET_MS = 1000.0 / FPS


def _people(n_people: int, n_frames: int, seed: int) -> np.ndarray:
    """(T, P, 32, 3) world truth: P people, 1.2 m apart on a circle around the centre, facing random ways."""
    rng = np.random.default_rng(seed)
    radius = 0.0 if n_people == 1 else 600.0
    takes = []
    for person in range(n_people):
        angle = 2 * np.pi * person / n_people
        gesture = GESTURES[(seed + person) % len(GESTURES)]
        if gesture == "walking":  # keep everyone in place: walking would leave the capture area
            gesture = "hands_up_down"
        motion = make_gesture(
            gesture,
            duration_s=(n_frames + 1) / FPS,
            fps=FPS,
            facing_deg=float(rng.uniform(-180, 180)),
            position_mm=(radius * np.cos(angle), radius * np.sin(angle)),
            seed=seed + person,
        )
        takes.append(motion.positions[:n_frames])
    return np.stack(takes, axis=1)


def _stats(values: Sequence[float]) -> dict[str, float]:
    v = np.asarray(values, dtype=np.float64)
    return {"p50": float(np.percentile(v, 50)), "p99": float(np.percentile(v, 99)), "max": float(v.max())}


def run_depth_bench(
    people_counts: tuple[int, ...] = (1, 2, 3),
    *,
    n_sensors: int = 4,
    n_frames: int = 30,
    voxel_mm: float = 15.0,
    icp: bool = True,
    seed: int = 0,
    progress: bool = True,
) -> dict[str, Any]:
    """Measure the capture side and the fusion node side for each people count (see the module docstring).

    Returns a JSON-ready dict: per people count, payload bytes per sensor-frame, per frame (all sensors) and
    per second at 30 fps; capture ms per sensor-frame; fusion ms per person-frame without and with ICP; the
    frontalization error against the true facing; and the 30 Hz frame budget. ``icp=False`` skips the
    variant with ICP (the slow one).
    """
    sensors = paper_rig(n_sensors)
    poses = np.stack([s.world_from_sensor for s in sensors])
    intrinsics = Intrinsics.azure_kinect_nfov()
    variants = {"no_icp": DepthFusionParams(voxel_mm=voxel_mm)}
    if icp:
        variants["icp"] = DepthFusionParams(voxel_mm=voxel_mm, icp=True)
    cases = []
    bar = Progress(len(people_counts) * n_frames, "bench depth", enabled=None if progress else False)
    for n_people in people_counts:
        truth = _people(n_people, n_frames, seed)
        tally = _DepthTally(variants)
        for t in range(n_frames):
            frames = render_rig(sensors, truth[t], noise=DepthNoise(), seed=seed * 100_000 + t)
            payloads = _capture(frames, t, intrinsics, voxel_mm, tally)
            facings = body_facing(truth[t])
            true_facing = np.degrees(np.arctan2(facings[:, 1], facings[:, 0]))
            _fuse_people(payloads, n_people, poses, intrinsics, true_facing, variants, tally)
            bar.update()
        cases.append(tally.case(n_people, n_sensors, n_frames))
    bar.close()
    return {"voxel_mm": voxel_mm, "fps": FPS, "frame_budget_ms": FRAME_BUDGET_MS, "cases": cases}


class _DepthTally:
    """The measurements of one people count, gathered frame by frame."""

    def __init__(self, variants: dict[str, DepthFusionParams]) -> None:
        self.sensor_bytes: list[int] = []
        self.frame_bytes: list[int] = []
        self.capture_ms: list[float] = []
        self.fuse_ms: dict[str, list[float]] = {name: [] for name in variants}
        self.fuse_cpu_ms: dict[str, list[float]] = {name: [] for name in variants}
        self.points_per_person: list[int] = []
        self.facing_error: list[float] = []

    def case(self, n_people: int, n_sensors: int, n_frames: int) -> dict[str, Any]:
        per_frame = np.asarray(self.frame_bytes, dtype=np.float64)
        return {
            "n_people": n_people,
            "n_sensors": n_sensors,
            "n_frames": n_frames,
            "bytes_per_sensor_frame": _stats(self.sensor_bytes),
            "bytes_per_frame": _stats(self.frame_bytes),
            "megabits_per_second_mean": float(per_frame.mean() * FPS * 8 / 1e6),
            "megabits_per_second_p99_frame": float(np.percentile(per_frame, 99) * FPS * 8 / 1e6),
            "capture_ms_per_sensor_frame": _stats(self.capture_ms),
            "fuse_ms_per_person_frame": {name: _stats(values) for name, values in self.fuse_ms.items()},
            "fuse_cpu_ms_per_person_frame": {name: _stats(values) for name, values in self.fuse_cpu_ms.items()},
            "merged_points_per_person": _stats(self.points_per_person),
            "facing_error_deg": _stats(self.facing_error),
        }


def _capture(
    frames: Sequence[Any], t: int, intrinsics: Intrinsics, voxel_mm: float, tally: _DepthTally
) -> list[tuple[int, bytes]]:
    """The capture side of one instant: each sensor's person clouds, encoded (timed per sensor-frame)."""
    payloads = []
    for index, frame in enumerate(frames):
        start = time.perf_counter_ns()
        clouds = person_clouds(frame.depth, frame.body_index, intrinsics, voxel_mm=voxel_mm)
        payload = encode_person_clouds(
            PersonCloudsFrame(
                frame.sensor_id,
                t,
                int(t * 1e6 / FPS),
                0,
                voxel_mm,
                np.array([c.body_index for c in clouds], dtype=np.uint32),
                tuple(c.points for c in clouds),
            )
        )
        tally.capture_ms.append((time.perf_counter_ns() - start) / 1e6)
        tally.sensor_bytes.append(len(payload))
        payloads.append((index, payload))
    tally.frame_bytes.append(sum(len(p) for _, p in payloads))
    return payloads


def _fuse_people(
    payloads: list[tuple[int, bytes]],
    n_people: int,
    poses: np.ndarray,
    intrinsics: Intrinsics,
    true_facing: np.ndarray,
    variants: dict[str, DepthFusionParams],
    tally: _DepthTally,
) -> None:
    """The node side of one instant: decode and fuse each person, per variant (timed per person-frame)."""
    for name, params in variants.items():
        for person in range(n_people):
            start, start_cpu = time.perf_counter_ns(), time.thread_time_ns()
            per_sensor = []
            for _, payload in payloads:
                decoded = decode_person_clouds(payload)
                found = np.nonzero(decoded.body_ids == person)[0]
                per_sensor.append(decoded.clouds[found[0]] if found.size else np.zeros((0, 3)))
            view = fuse_person_depth(
                per_sensor, poses, intrinsics, skeleton_facing_deg=float(true_facing[person]), params=params
            )
            tally.fuse_ms[name].append((time.perf_counter_ns() - start) / 1e6)
            tally.fuse_cpu_ms[name].append((time.thread_time_ns() - start_cpu) / 1e6)
            if name == "no_icp":
                tally.points_per_person.append(len(view.merged))
                gap = (view.frontal.facing_deg - true_facing[person] + 180.0) % 360.0 - 180.0
                tally.facing_error.append(abs(float(gap)))


def format_depth_bench(result: dict[str, Any]) -> str:
    """A plain-text table of :func:`run_depth_bench`'s result."""
    lines = [
        f"depth-level fusion, {result['voxel_mm']:g} mm voxels, {result['fps']:g} fps "
        f"(frame budget {result['frame_budget_ms']:.1f} ms); tracker time not included",
        f"{'people':>6} {'kB/sensor p50':>13} {'kB/frame p50':>12} {'Mbit/s':>7} {'capture ms p50/p99':>18} "
        f"{'fuse ms/person p50/p99 (cpu p50)':>32} {'+ICP p50/p99 (cpu p50)':>24} {'points':>7} "
        f"{'facing err p50/max':>18}",
    ]
    for case in result["cases"]:
        nan = {"p50": float("nan"), "p99": float("nan")}
        fuse, icp = case["fuse_ms_per_person_frame"]["no_icp"], case["fuse_ms_per_person_frame"].get("icp", nan)
        cpu = {"icp": nan, **case["fuse_cpu_ms_per_person_frame"]}
        lines.append(
            f"{case['n_people']:>6} {case['bytes_per_sensor_frame']['p50'] / 1e3:>13.1f} "
            f"{case['bytes_per_frame']['p50'] / 1e3:>12.1f} {case['megabits_per_second_mean']:>7.1f} "
            f"{case['capture_ms_per_sensor_frame']['p50']:>8.2f} / {case['capture_ms_per_sensor_frame']['p99']:<7.2f} "
            f"{fuse['p50']:>10.1f} / {fuse['p99']:<6.1f} ({cpu['no_icp']['p50']:5.1f}) "
            f"{icp['p50']:>7.1f} / {icp['p99']:<6.1f} ({cpu['icp']['p50']:5.1f}) "
            f"{case['merged_points_per_person']['p50']:>7.0f} "
            f"{case['facing_error_deg']['p50']:>8.1f} / {case['facing_error_deg']['max']:<6.1f}"
        )
    return "\n".join(lines)
