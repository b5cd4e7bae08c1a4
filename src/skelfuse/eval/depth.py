"""``skelfuse eval depth``: the depth-level fusion's tracker on real takes, next to skeleton fusion.

What only the Body Tracking SDK on a GPU can show (docs/depth-fusion.md): how well it tracks a person on the
fused *virtual* depth image. Input: one k4arecorder ``.mkv`` per sensor of the same take (wired sync), each
replayed through the SDK's tracker (:class:`skelfuse.sources.kinect.MkvSource`, which also makes each body's
person cloud from the tracker's body-index map), grouped into instants by device time as the fusion node
groups them. Every instant then goes through skeleton fusion, the depth mode and the hybrid mode (the node's
own :class:`~skelfuse.service.depth_stage.DepthStage`, tracker ``k4abt``), and the report says, per mode:
how often a person came out, how far each mode's skeleton lies from skeleton fusion's (no ground truth on real
takes: agreement, not accuracy), and the tracker's time per virtual image.

The same evaluation runs on simulated input (:func:`simulated_instants`, the simulated stand-in tracker) with
the truth, which is how its logic is tested here: the figures of that run are no statement about the SDK.
Beside the stand-in it runs the control (``control``: the depth mode with
:class:`~skelfuse.sim.depth_tracker.PriorEchoTracker`, which returns skeleton fusion's output unchanged): the
stand-in only slides that output along the virtual camera's rays with the simulator's own body radii, so what
depth mode adds is unmeasured until a real body tracker runs on the virtual image (the SDK on a GPU).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.config import RigConfig, parse_rig_config
from skelfuse.fusion.camera import Intrinsics
from skelfuse.progress import note
from skelfuse.rig.grouping import FrameGroup
from skelfuse.rig.instant import GroupFuser
from skelfuse.schema.errors import DataError
from skelfuse.schema.frames import SensorFrame
from skelfuse.schema.skeleton import EVAL_JOINTS, N_JOINTS
from skelfuse.service.depth_stage import CloudBuffer, DepthStage, DepthTracker
from skelfuse.service.sim_clouds import sensor_person_clouds
from skelfuse.sim import crowd
from skelfuse.sim.depth_tracker import PriorEchoTracker, SimulatedDepthTracker
from skelfuse.sim.observe import load_profile
from skelfuse.sim.rig import VirtualSensor
from skelfuse.sources.k4abt import K4abtLibrary, TrackerSettings, load_k4a
from skelfuse.sources.kinect import EndOfStream, MkvSource, import_pyk4a
from skelfuse.wire import keys
from skelfuse.wire.clouds import PersonCloudsFrame, encode_person_clouds

SIM_TAKES = {"crossing": crowd.crossing_scenario, "bystander": crowd.bystander_scenario}
"""Simulated takes :func:`simulated_instants` knows."""


@dataclass
class Instant:
    """One instant of a take: the sensors' frames and each sensor's person clouds (by sensor id)."""

    group: FrameGroup
    clouds: dict[str, PersonCloudsFrame]
    truth: np.ndarray | None = None  # (P, 32, 3) world mm, simulated input only


def simulated_instants(
    take: str, duration_s: float, seed: int, *, max_instants: int | None = None
) -> tuple[list[Instant], crowd.CrowdObservations]:
    """A simulated multi-person take as instants: the crowd simulator's skeletons per sensor, each sensor's
    person clouds ray-cast from the true bodies (NFOV 2x2 binned, mutual occlusion), body ids matched; the
    first ``max_instants`` only when given."""
    obs = crowd.simulate_scenario(SIM_TAKES[take](duration_s=duration_s), load_profile(), seed=seed)
    sensors = [VirtualSensor(sid, obs.world_from_sensor[s]) for s, sid in enumerate(obs.sensor_ids)]
    binned = Intrinsics.azure_kinect_nfov(binned=True)
    out = []
    for t in range(obs.n_frames if max_instants is None else min(max_instants, obs.n_frames)):
        time_us = round(float(obs.times_s[t]) * 1e6) + 1_000_000
        frames, clouds = {}, {}
        people = np.flatnonzero(obs.present[t])
        for s, sid in enumerate(obs.sensor_ids):
            slots = np.flatnonzero(obs.valid[t, s])
            frames[sid] = SensorFrame(
                sensor_id=sid,
                sequence=t,
                device_time_us=time_us,
                host_time_ns=0,
                body_ids=obs.body_ids[t, s, slots].astype(np.uint32),
                positions=obs.positions[t, s, slots].astype(np.float32),
                orientations=np.tile(np.array([1.0, 0, 0, 0], np.float32), (slots.size, N_JOINTS, 1)),
                confidence=obs.confidence[t, s, slots],
            )
            by_person = sensor_person_clouds(
                sensors[s], obs.truth[t, people], voxel_mm=15.0, intrinsics=binned, rng=np.random.default_rng([s, t])
            )
            ids, points = [], []
            for slot in slots:
                index = np.flatnonzero(people == obs.person_of_body[t, s, slot])
                if index.size and int(index[0]) in by_person:
                    ids.append(int(obs.body_ids[t, s, slot]))
                    points.append(by_person[int(index[0])])
            clouds[sid] = PersonCloudsFrame(sid, t, time_us, 0, 15.0, np.array(ids, np.uint32), tuple(points))
        out.append(Instant(FrameGroup(time_us, frames, (), True), clouds, obs.truth[t][obs.present[t]]))
    return out, obs


def mkv_instants(
    takes: Mapping[str, Path],
    cfg: RigConfig,
    *,
    voxel_mm: float,
    max_frames: int | None = None,
    pyk4a: Any = None,
    k4abt: Any = None,
) -> list[Instant]:
    """Each sensor's ``.mkv`` replayed through the Body Tracking SDK (one after the other: the SDK allows one
    tracker per process), its frames and person clouds grouped into instants by device time within the rig's
    ``[sync]`` tolerance. Raises KinectUnavailable (pyk4a / the SDKs missing) before reading anything.
    ``pyk4a`` / ``k4abt``: injected by tests (the fake stack), else the installed ones."""
    per_sensor: dict[str, list[tuple[SensorFrame, PersonCloudsFrame | None]]] = {}
    for sensor_id, path in takes.items():
        sensor = cfg.sensor(sensor_id)
        settings = (
            TrackerSettings.from_config(sensor.kinect.tracker) if sensor.kinect is not None else TrackerSettings()
        )
        source = MkvSource(
            path,
            settings,
            sensor_id=sensor_id,
            fps=cfg.sync.fps,
            clouds_voxel_mm=voxel_mm,
            pyk4a=pyk4a,
            k4abt=k4abt,
        )
        source.open()
        frames: list[tuple[SensorFrame, PersonCloudsFrame | None]] = []
        try:
            while max_frames is None or len(frames) < max_frames:
                try:
                    frame = source.read(1.0)
                except EndOfStream:
                    break
                if frame is not None:
                    frames.append((frame, source.clouds_at(frame)))
        finally:
            source.close()
        note(f"eval depth: {path}: {len(frames)} body frames tracked")
        per_sensor[sensor_id] = frames
    stamped = sorted((f.device_time_us, sid, f, c) for sid, items in per_sensor.items() for f, c in items)
    instants: list[Instant] = []
    tolerance = cfg.sync.tolerance_us
    for time_us, sid, frame, clouds in stamped:
        if not instants or time_us - instants[-1].group.time_us > tolerance or sid in instants[-1].group.frames:
            instants.append(Instant(FrameGroup(time_us, {}, (), False), {}))
        instants[-1].group.frames[sid] = frame
        if clouds is not None:
            instants[-1].clouds[sid] = clouds
    for instant in instants:
        instant.group = FrameGroup(
            instant.group.time_us,
            instant.group.frames,
            tuple(s for s in cfg.sensor_ids if s not in instant.group.frames),
            len(instant.group.frames) == len(cfg.sensor_ids),
        )
    if not instants:
        raise DataError(f"no body frames in {', '.join(map(str, takes.values()))}: nothing to evaluate")
    return instants


@dataclass
class ModeFigures:
    """One mode's figures over a take."""

    persons: int = 0
    agreement_mm: list[float] = field(default_factory=list)  # to skeleton fusion's person, per fused person
    error_mm: list[float] = field(default_factory=list)  # to the nearest true person (simulated input)


CONTROL_NOTE = (
    "\nThe stand-in tracker slides skeleton fusion's output along the virtual camera's rays onto the simulator's "
    "own body surface; the control returns that output unchanged. Where the stand-in does not beat the control, "
    "its figure shows the image path working, not depth helping: the benefit of depth mode is unmeasured until "
    "a real body tracker runs on the virtual image (the Body Tracking SDK on a GPU)."
)


@dataclass
class DepthEvaluation:
    instants: int
    figures: dict[str, ModeFigures]
    tracker_ms: list[float]
    tracker: str

    def table(self) -> str:
        def stat(values: list[float]) -> str:
            return "—" if not values else f"{np.median(values):.1f} / {np.percentile(values, 90):.1f}"

        lines = [
            "| mode | persons out (per instant) | agreement with skeleton fusion, mm p50 / p90 | "
            "error vs truth, mm p50 / p90 |",
            "|---|---:|---|---|",
        ]
        names = {"control": "control: depth mode, tracker returns skeleton fusion's output unchanged"}
        for mode, f in self.figures.items():
            lines.append(
                f"| {names.get(mode, mode)} | {f.persons / max(self.instants, 1):.2f} | "
                f"{'—' if mode == 'skeleton' else stat(f.agreement_mm)} | {stat(f.error_mm)} |"
            )
        ms = self.tracker_ms
        timing = f"{np.median(ms):.1f} / {np.percentile(ms, 99):.1f}" if ms else "—"
        lines.append(f"\ntracker ({self.tracker}) per virtual image, ms p50 / p99: {timing}; {self.instants} instants")
        if "control" in self.figures:
            lines.append(CONTROL_NOTE)
        return "\n".join(lines)


def _eval_joints_distance(a: np.ndarray, b: np.ndarray) -> float:
    with np.errstate(invalid="ignore"):
        return float(np.nanmean(np.linalg.norm(a[EVAL_JOINTS] - b[EVAL_JOINTS], axis=-1)))


class _TimedTracker:
    """Wraps a tracker to time its calls (the figure the SDK's GPU decides)."""

    def __init__(self, inner: DepthTracker, times_ms: list[float]) -> None:
        self.inner, self.times_ms = inner, times_ms
        self.name, self.description = inner.name, inner.description

    def track(self, person, view, prior_world):
        tick = time.perf_counter_ns()
        try:
            return self.inner.track(person, view, prior_world)
        finally:
            self.times_ms.append((time.perf_counter_ns() - tick) / 1e6)

    def retire(self, active: set[int]) -> None:
        self.inner.retire(active)

    def close(self) -> None:
        self.inner.close()


def evaluate_depth(
    instants: Sequence[Instant],
    sensor_ids: Sequence[str],
    world_from_sensor: np.ndarray,
    make_tracker: Callable[[RigConfig], DepthTracker],
    *,
    preset: str = "skelfuse",
    voxel_mm: float = 15.0,
    progress: bool = True,
    control: bool = False,
) -> DepthEvaluation:
    """Skeleton fusion, the depth mode and the hybrid mode over the same instants (see the module docstring);
    with ``control``, also the depth mode with :class:`PriorEchoTracker` (row ``control``, untimed)."""
    eye = [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]
    times_ms: list[float] = []
    runs = {}
    for mode in ("skeleton", "depth", "hybrid", "control") if control else ("skeleton", "depth", "hybrid"):
        cfg = parse_rig_config(
            {
                "rig": {"name": "eval"},
                "sensors": [{"id": sid, "source": "sim", "world_from_sensor": eye} for sid in sensor_ids],
                "fusion": {"mode": "depth" if mode == "control" else mode, "preset": preset},
                "depth": {"tracker": "simulated", "voxel_mm": voxel_mm},
            }
        )
        stage = None
        if mode == "control":
            stage = DepthStage(cfg, PriorEchoTracker(), clouds=CloudBuffer("eval", cfg.sensor_ids))
        elif mode != "skeleton":
            stage = DepthStage(
                cfg, _TimedTracker(make_tracker(cfg), times_ms), clouds=CloudBuffer("eval", cfg.sensor_ids)
            )
        ids, poses = (cfg.sensor_ids, world_from_sensor) if stage is None else stage.fuser_sensors(world_from_sensor)
        runs[mode] = (stage, GroupFuser(ids, poses, cfg.fusion.fusion_params()))
    figures = {mode: ModeFigures() for mode in runs}
    try:
        for index, instant in enumerate(instants):
            outputs = {}
            for mode, (stage, fuser) in runs.items():
                if stage is not None:
                    for sid, clouds in instant.clouds.items():
                        stage.clouds.put(keys.sensor_clouds("eval", sid), encode_person_clouds(clouds))
                frame = (fuser.step(instant.group) if stage is None else stage.step(fuser, instant.group)).frame
                outputs[mode] = frame
                figures[mode].persons += frame.n_persons
                if instant.truth is not None and len(instant.truth):
                    for person in frame.positions:
                        figures[mode].error_mm.append(min(_eval_joints_distance(person, t) for t in instant.truth))
            skeleton = outputs["skeleton"]
            for mode in [m for m in outputs if m != "skeleton"]:
                for track_id, person in zip(outputs[mode].track_ids, outputs[mode].positions, strict=True):
                    if mode != "hybrid":  # the same tracks as skeleton fusion's: compare like for like
                        match = np.flatnonzero(skeleton.track_ids == track_id)
                        candidates = skeleton.positions[match]
                    else:  # hybrid runs its own tracks: the nearest skeleton-fusion person
                        candidates = skeleton.positions
                    if len(candidates):
                        figures[mode].agreement_mm.append(min(_eval_joints_distance(person, c) for c in candidates))
            if progress and index % 30 == 0:
                note(f"eval depth: instant {index + 1} of {len(instants)}")
    finally:
        for stage, _ in runs.values():
            if stage is not None:
                stage.close()
    tracker = runs["depth"][0].tracker.name  # type: ignore[union-attr]
    return DepthEvaluation(len(instants), figures, times_ms, tracker)


def sim_tracker(_: RigConfig) -> DepthTracker:
    """The simulated stand-in (simulated input only)."""
    return SimulatedDepthTracker()


def require_sdk() -> None:
    """Raise, naming what is missing, unless pyk4a, libk4a and the Body Tracking SDK all load here."""
    import_pyk4a()  # KinectUnavailable: names the `kinect` extra and the Sensor SDK
    load_k4a()  # K4ABTLibraryError: names the Sensor SDK and SKELFUSE_K4A_LIBRARY
    K4abtLibrary.load()  # K4ABTLibraryError: names the Body Tracking SDK and SKELFUSE_K4ABT_LIBRARY


def mkv_takes(specs: Iterable[str], cfg: RigConfig) -> dict[str, Path]:
    """``ID=PATH.mkv`` specs -> {sensor id: path}; every id a sensor of the rig, every path a file."""
    takes: dict[str, Path] = {}
    for spec in specs:
        sensor_id, sep, path = spec.partition("=")
        if not sep or not sensor_id or not path:
            raise DataError(f"--take {spec!r}: write ID=PATH.mkv (a sensor id of the rig, then its recording)")
        cfg.sensor(sensor_id)  # ConfigError naming the rig's sensors
        if not Path(path).is_file():
            raise DataError(f"--take {spec!r}: {path} does not exist")
        takes[sensor_id] = Path(path)
    if len(takes) < 2:
        raise DataError(f"{len(takes)} take(s): depth-level fusion needs the .mkv of two sensors or more")
    return takes
