"""The capture worker's sources: what ``skelfuse capture`` publishes from (``sim``, ``replay``, ``kinect``).

:func:`make_source` builds the one a sensor's config names; each yields ``(due monotonic ns, frame)`` pairs
(:class:`FrameSource`) that :mod:`skelfuse.service.worker` publishes. The sources, their clocks and their
failure modes are described in that module's docstring.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
import zlib
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from skelfuse.config import RigConfig, SensorConfig
from skelfuse.fusion.camera import Intrinsics
from skelfuse.recording import RecordedFrame, RecordingReader
from skelfuse.recording.inputs import open_inputs
from skelfuse.schema.errors import ConfigError, DataError
from skelfuse.schema.frames import SensorFrame
from skelfuse.schema.skeleton import N_JOINTS
from skelfuse.service.lifecycle import RunLimits
from skelfuse.sources.formats import detect_format
from skelfuse.sources.kinect import KinectSource
from skelfuse.wire import keys
from skelfuse.wire.clouds import PersonCloudsFrame

if TYPE_CHECKING:  # pragma: no cover - typing only
    from skelfuse.sim.rig import VirtualSensor

    pass

log = logging.getLogger("skelfuse.service.worker")  # one logger for the worker and its sources

DEFAULT_GESTURE = "walking"
DEFAULT_TAKE_S = 10.0
"""A simulated take's length before it loops (`capture --take-duration`, `demo --take-duration`)."""
DEFAULT_STALL_TIMEOUT_S = 10.0
"""The watchdog's default (``WorkerOptions.stall_timeout_s``; the config parser has its own copy)."""
DEFAULT_OPEN_TIMEOUT_S = 120.0
"""The watchdog's default before a source's first answer (``WorkerOptions.open_timeout_s``): generous, since a
master waits up to ``subordinate_wait_s`` (30 s) for its subordinates and a body tracker loads its model."""


class FrameSource(Protocol):
    """What a capture worker publishes from."""

    sensor_id: str

    def frames(self) -> Iterator[tuple[int, SensorFrame | None]]:
        """(due monotonic ns, frame) in publish order; ``host_time_ns`` is stamped by the worker. A None frame:
        nothing came this time (a live sensor's read timeout), so the worker's loop stays responsive."""
        ...


@dataclass(frozen=True)
class WorkerOptions:
    """How a capture worker runs.

    Attributes
    ----------
    gesture, take_duration_s, seed : the sim source's take (every worker of a rig must use the same).
    loop : bool or None
        Start the take / recording over at its end (default: sim loops, replay follows ``replay.loop``).
    speed : float or None
        Replay speed (1.0 real time; None as fast as possible).
    node_name : str or None
        Default ``capture-<sensor id>``.
    limits : RunLimits
        ``max_frames`` counts published frames.
    subordinate_wait_s : float
        Kinect master only: how long to wait for every subordinate's camera token
        (:func:`wait_for_subordinates`) before starting the master's camera anyway.
    """

    gesture: str = DEFAULT_GESTURE
    take_duration_s: float = DEFAULT_TAKE_S
    seed: int = 0
    loop: bool | None = None
    speed: float | None = 1.0
    node_name: str | None = None
    status_period_s: float | None = None
    limits: RunLimits = field(default_factory=RunLimits)
    subordinate_wait_s: float = 30.0
    take_origin_ns: int = 0
    stall_timeout_s: float | None = DEFAULT_STALL_TIMEOUT_S
    """Watchdog (``[capture] stall_timeout_s``, ``--stall-timeout``): a source that, once started, delivers no
    frame for this long is treated as stalled and restarted like a source that failed, counted in the status
    as ``stalls``: a body tracker that keeps answering with nothing, and a read that never returns (a hung SDK
    call: the source is read on a thread of its own, :class:`SourceReader`). A Kinect source gets the same
    timeout for its own diagnosis (no capture / no tracker result); the watchdog waits 0.5 s longer
    (``service.worker.DIAGNOSIS_GRACE_S``) so that diagnosis names the cause first. None: off."""
    open_timeout_s: float | None = DEFAULT_OPEN_TIMEOUT_S
    """Watchdog before the source's first answer (``[capture] open_timeout_s``, ``--open-timeout``): a source
    whose start (device open, tracker create, a master's wait for its subordinates) has not answered within this
    long is restarted like a stalled one (an SDK call that hangs while opening). None: off."""


# ----------------------------------------------------------------------------------------------------------
# Sources


def sim_rig_order(cfg: RigConfig) -> list[SensorConfig]:
    """The rig's sim sensors in simulation order: the master first, then the others in config order."""
    sims = [s for s in cfg.sensors if s.source == "sim"]
    return sorted(sims, key=lambda s: s.sync.role != "master")


def simulate_rig(
    cfg: RigConfig, *, gesture: str, take_duration_s: float, seed: int, observation_seed: int | None = None
) -> Any:
    """Simulate the rig's sim sensors (:func:`sim_rig_order`) for one take: ``skelfuse.sim`` Observations."""
    from skelfuse.sim.gestures import make_gesture  # the simulator: imported by the sources that simulate
    from skelfuse.sim.observe import load_profile, simulate
    from skelfuse.sim.rig import VirtualSensor

    sensors = sim_rig_order(cfg)
    if not sensors:
        raise ConfigError(f'{cfg.source}: rig {cfg.name!r} has no sensor with source = "sim"')
    virtual = []
    for s in sensors:
        pose = s.pose()
        if pose is None:
            raise ConfigError(
                f"{cfg.source}: sim sensor {s.id!r} needs sensors[i].world_from_sensor: the "
                "simulator observes the person from that (true) pose"
            )
        u, _, vt = np.linalg.svd(pose[:3, :3])  # TOML poses carry ~6 decimals: re-orthonormalize
        pose = pose.copy()
        pose[:3, :3] = u @ vt
        virtual.append(VirtualSensor(s.id, pose))
    profile_paths = {s.sim.profile for s in sensors if s.sim is not None and s.sim.profile is not None}
    if len(profile_paths) > 1:
        raise ConfigError(
            f"{cfg.source}: sim sensors use different profiles ({', '.join(map(str, profile_paths))}); "
            "one simulation covers the whole rig, so give them one profile"
        )
    profile = load_profile(next(iter(profile_paths)) if profile_paths else None)
    motion = make_gesture(gesture, duration_s=take_duration_s, seed=seed)
    return simulate(motion, virtual, profile, seed=seed if observation_seed is None else observation_seed)


class SimSource:
    """One sensor of a simulated rig, emulating wired sync on the host clock (see the module docstring).

    Parameters
    ----------
    cfg : RigConfig
    sensor_id : str
    gesture, take_duration_s, seed : the take; the observation seed is ``sensors[i].sim.seed`` if set.
    loop : bool
    clock_ns : callable
        Host clock (Unix ns) used to align instants across workers; injected by tests.
    take_origin_ns : int
        Unix ns at which take frame 0 plays (instant ``n`` shows take frame ``(n - n0) mod T``); every
        worker of a rig must get the same. Default 0: the take is aligned on the Unix epoch.

    ``sensors[i].sim.clock_offset_ms`` / ``clock_jitter_ms`` emulate a capture PC whose wall clock is off
    (and jittery): :meth:`host_time_ns` adds them to the host time the worker stamps.
    """

    def __init__(
        self,
        cfg: RigConfig,
        sensor_id: str,
        *,
        gesture: str = DEFAULT_GESTURE,
        take_duration_s: float = DEFAULT_TAKE_S,
        seed: int = 0,
        loop: bool = True,
        clock_ns: Any = time.time_ns,
        take_origin_ns: int = 0,
    ) -> None:
        from skelfuse.sim.orientation import observe_orientations, truth_orientations

        sensor = cfg.sensor(sensor_id)
        if sensor.source != "sim":
            raise ConfigError(f"{cfg.source}: sensor {sensor_id!r} has source {sensor.source!r}, not 'sim'")
        observation_seed = sensor.sim.seed if sensor.sim is not None else None
        self.sensor_id = sensor_id
        self.observations = simulate_rig(
            cfg, gesture=gesture, take_duration_s=take_duration_s, seed=seed, observation_seed=observation_seed
        )
        self.column = list(self.observations.sensor_ids).index(sensor_id)
        self.fps = float(cfg.sync.fps)
        # the views' joint orientations (tracker-like noise around the true ones; NaN where nothing is tracked)
        orientation_seed = seed if observation_seed is None else observation_seed
        truth = truth_orientations(self.observations.truth, self.fps, seed=orientation_seed)
        self.orientations = observe_orientations(self.observations, truth, seed=orientation_seed)[:, self.column]
        self.loop = loop
        self.clock_ns = clock_ns
        self.origin_n = math.ceil(take_origin_ns / (1e9 / self.fps))
        sim = sensor.sim
        self.clock_offset_ns = round((sim.clock_offset_ms if sim is not None else 0.0) * 1e6)
        self.clock_jitter_ns = (sim.clock_jitter_ms if sim is not None else 0.0) * 1e6
        self._clock_rng = np.random.default_rng(zlib.crc32(sensor_id.encode()))
        self.seed = seed if observation_seed is None else observation_seed
        self.voxel_mm = cfg.depth.voxel_mm
        self._clouds: dict[int, dict[int, np.ndarray]] = {}  # take frame -> person index -> cloud (the take loops)
        if cfg.fusion.mode != "skeleton":  # render the take's clouds now: publishing must keep the frame rate
            tick = time.monotonic()
            for f in range(self.observations.n_frames):
                self._render_clouds(f)
            log.info(
                "sim sensor %s: %d depth frames rendered in %.1f s (depth mode: person clouds)",
                sensor_id,
                self.observations.n_frames,
                time.monotonic() - tick,
            )

    def clouds_at(self, frame: SensorFrame) -> PersonCloudsFrame:
        """Depth mode: the person cloud of ``frame``'s body (``sim/depth.py``: capsule bodies ray-cast in this
        sensor's NFOV 2x2-binned depth image, its noise seeded by (seed, sensor, take frame)), with the
        skeleton's body id; no cloud where the simulated tracker lost the body. The take is rendered once, when
        the source is built in depth or hybrid mode."""
        clouds = self._render_clouds((frame.sequence - self.origin_n) % self.observations.n_frames)
        ids, points = (frame.body_ids[:1], (clouds[0],)) if len(frame.body_ids) and 0 in clouds else ([], ())
        return PersonCloudsFrame(
            sensor_id=self.sensor_id,
            sequence=frame.sequence,
            device_timestamp_us=frame.device_time_us,
            host_timestamp_ns=frame.host_time_ns,
            voxel_mm=self.voxel_mm,
            body_ids=np.asarray(ids, dtype=np.uint32),
            clouds=points,
        )

    def _render_clouds(self, f: int) -> dict[int, np.ndarray]:
        from skelfuse.service.sim_clouds import sensor_person_clouds

        if f not in self._clouds:
            rng = np.random.default_rng([self.seed, self.column, f])
            self._clouds[f] = sensor_person_clouds(
                self.depth_sensor,
                self.observations.truth[f][None],
                voxel_mm=self.voxel_mm,
                intrinsics=Intrinsics.azure_kinect_nfov(binned=True),
                rng=rng,
            )
        return self._clouds[f]

    @property
    def depth_sensor(self) -> VirtualSensor:
        """This sensor's true pose, as the simulation observes from it."""
        from skelfuse.sim.rig import VirtualSensor

        return VirtualSensor(self.sensor_id, self.observations.world_from_sensor[self.column])

    def host_time_ns(self) -> int:
        """This emulated capture PC's wall clock: the host's, plus its configured offset and jitter."""
        jitter = round(self._clock_rng.normal(0.0, self.clock_jitter_ns)) if self.clock_jitter_ns > 0 else 0
        return self.clock_ns() + self.clock_offset_ns + jitter

    def frame_at(self, n: int) -> SensorFrame | None:
        """The frame of instant ``n`` (take frame ``n mod T``); None where the simulated sensor dropped it."""
        obs, s = self.observations, self.column
        f = (n - self.origin_n) % obs.n_frames
        if obs.dropped[f, s]:
            return None
        period_us = 1e6 / self.fps
        master = obs.device_time_us[f, 0]
        delay_us = int(obs.device_time_us[f, s] - master) if master >= 0 else 0
        device_time_us = round(n * period_us) + delay_us
        positions = obs.positions[f, s]
        if obs.tracked[f, s] and np.isfinite(positions).all():
            body_ids = np.array([max(int(obs.body_ids[f, s]), 0)], dtype=np.uint32)
            positions = positions[None].astype(np.float32)
            confidence = obs.confidence[f, s][None]
        else:  # the tracker lost the body: a frame without bodies (never NaN on the wire)
            body_ids = np.zeros(0, dtype=np.uint32)
            positions = np.zeros((0, N_JOINTS, 3), dtype=np.float32)
            confidence = np.zeros((0, N_JOINTS), dtype=np.uint8)
        orientations = np.zeros((len(body_ids), N_JOINTS, 4), dtype=np.float32)
        orientations[..., 0] = 1.0  # identity where the simulated tracker gives none (never NaN on the wire)
        if len(body_ids):
            seen = np.isfinite(self.orientations[f]).all(axis=-1)
            orientations[0, seen] = self.orientations[f, seen]
        return SensorFrame(
            sensor_id=self.sensor_id,
            sequence=n,
            device_time_us=device_time_us,
            host_time_ns=0,
            body_ids=body_ids,
            positions=positions,
            orientations=orientations,
            confidence=np.ascontiguousarray(confidence, dtype=np.uint8),
        )

    def frames(self) -> Iterator[tuple[int, SensorFrame]]:
        period_ns = 1e9 / self.fps
        offset_ns = time.monotonic_ns() - self.clock_ns()  # host (Unix) ns -> monotonic ns
        n = math.ceil(self.clock_ns() / period_ns)
        first = n
        n_frames = self.observations.n_frames
        while True:
            if not self.loop and n > first and (n - self.origin_n) % n_frames == 0:
                return  # end of the take
            frame = self.frame_at(n)
            if frame is not None:
                yield round(n * period_ns) + offset_ns, frame
            n += 1


class ReplaySource:
    """One sensor's frames of a recording, paced by recorded time (see the module docstring).

    An MCAP is paced by its recorded host time. Any other format (:mod:`skelfuse.recording.inputs`) is paced
    by its device time, from ``anchor_us`` (the earliest first frame of the rig's replay files, so that
    workers started together publish the instants of a shared device clock together) when given.
    """

    def __init__(
        self,
        path: Path,
        sensor_id: str,
        *,
        recorded_sensor: str | None = None,
        loop: bool = False,
        speed: float | None = 1.0,
        anchor_us: int | None = None,
    ) -> None:

        self.sensor_id = sensor_id
        self.recorded_sensor = recorded_sensor or sensor_id
        self.anchor_ns = None if anchor_us is None else int(anchor_us) * 1000
        if detect_format(path) == "mcap":
            reader = RecordingReader(path)
            held = reader.sensors
            self._records: Callable[[], Iterable[RecordedFrame]] = lambda: reader.records(
                sensors=[self.recorded_sensor]
            )
            self.anchor_ns = None
        else:
            take = open_inputs([str(path)])
            held = take.sensor_ids
            if self.recorded_sensor not in held and recorded_sensor is None and len(held) == 1:
                self.recorded_sensor = held[0]  # a one-sensor file replays as this sensor, whatever its name
            self._records = lambda: (r for r in take.records("replay") if r.sensor_id == self.recorded_sensor)
        if self.recorded_sensor not in held:
            raise DataError(
                f"recording {path} has no sensor {self.recorded_sensor!r}; it holds "
                f"{', '.join(held) or 'no sensors'} (set sensors[i].replay.sensor)"
            )
        self.loop = loop
        self.speed = speed

    def frames(self) -> Iterator[tuple[int, SensorFrame]]:
        pass_index = 0
        start_ns = time.monotonic_ns()
        shift_us = 0
        pass_offset_ns = 0
        while True:
            first_log: int | None = None
            last_log = 0
            first_dev: int | None = None
            last_dev = 0
            for record in self._records():
                frame = record.frame
                if first_log is None:
                    first_log = record.log_time_ns
                    first_dev = frame.device_time_us
                last_log, last_dev = record.log_time_ns, frame.device_time_us
                anchor = self.anchor_ns if (pass_index == 0 and self.anchor_ns is not None) else first_log
                offset = max(record.log_time_ns - anchor, 0)
                due = start_ns + pass_offset_ns + (0 if self.speed is None else int(offset / self.speed))
                yield (
                    due,
                    dataclasses.replace(
                        frame, sensor_id=self.sensor_id, device_time_us=frame.device_time_us + shift_us
                    ),
                )
            if first_log is None or not self.loop:
                return
            pass_index += 1
            span_us = last_dev - (first_dev or 0) + 33_333
            shift_us += span_us
            pass_offset_ns += 0 if self.speed is None else int((last_log - first_log + 33_333_333) / self.speed)


def camera_node(sensor_id: str) -> str:
    """``camera-<sensor id>``: the liveliness node name a subordinate Kinect worker declares once its camera runs."""
    return keys.validate_name(f"camera-{sensor_id}", "node")


def wait_for_subordinates(
    session: Any,
    rig: str,
    subordinate_ids: Sequence[str],
    *,
    timeout_s: float,
    should_exit: Callable[[], bool] = lambda: False,
    poll_s: float = 0.1,
    log_every_s: float = 5.0,
) -> list[str]:
    """Wait until the camera token (``keys.alive(rig, camera_node(id))``) of every subordinate exists.

    A liveliness subscriber with history sees the tokens already declared and those declared later.
    Returns the ids still missing: ``[]`` once all are up, the missing ones on timeout or when
    ``should_exit()`` turns true (checked every ``poll_s``). Logs the ones still awaited every
    ``log_every_s`` seconds.
    """
    wanted = {camera_node(sid): sid for sid in subordinate_ids}
    if not wanted:
        return []
    present: set[str] = set()
    lock = threading.Lock()
    changed = threading.Event()

    def on_sample(sample: Any) -> None:
        try:
            node = keys.parse_alive_key(sample.key_expr, rig)
        except ValueError:
            return
        if node not in wanted:
            return
        with lock:
            if str(sample.kind).endswith("DELETE"):
                present.discard(node)
            else:
                present.add(node)
        changed.set()

    def missing() -> list[str]:
        with lock:
            return [sid for node, sid in wanted.items() if node not in present]

    subscriber = session.liveliness().declare_subscriber(keys.all_alive(rig), on_sample, history=True)
    try:
        start = time.monotonic()
        next_log = start + log_every_s
        while True:
            left = missing()
            if not left or should_exit():
                return left
            now = time.monotonic()
            if now - start >= timeout_s:
                return left
            if now >= next_log:
                log.info(
                    "kinect master of rig %s: waiting for subordinate camera(s) %s (%.0f s of %.0f s)",
                    rig,
                    ", ".join(left),
                    now - start,
                    timeout_s,
                )
                next_log = now + log_every_s
            changed.wait(min(poll_s, max(timeout_s - (now - start), 0.0)))
            changed.clear()
    finally:
        subscriber.undeclare()


class KinectFrameSource:
    """An Azure Kinect / Femto Bolt (``skelfuse.sources.kinect.KinectSource``) as a worker source.

    Frames are due when the tracker delivers them (no pacing) and keep the host time the source stamped on
    receipt. ``frames()`` also yields ``(now, None)`` once the device is open and then every read timeout
    while the device is silent (the worker's watchdog counts silence from the first of them). Device
    failures (unplugged, tracker stalled) raise out of ``frames()`` and the worker restarts the source with
    backoff; pyk4a or the SDKs missing raise ``KinectUnavailable`` (a ServiceError), which stops the worker
    with a message naming the ``kinect`` extra.

    Start order across processes (wired sync needs the subordinates' cameras running before the master's):
    with a zenoh session (constructor or :meth:`attach`), a subordinate declares the liveliness token
    ``skelfuse/<rig>/alive/camera-<sensor id>`` once its camera is open (undeclared when it closes), and a
    master waits for the tokens of every subordinate of the rig (:func:`wait_for_subordinates`) before
    opening its camera. After ``subordinate_wait_s`` the master logs an error naming the missing
    subordinates and starts anyway: a master that never starts would stall the whole rig, while a late
    subordinate only loses sync until it is restarted. Standalone sensors, and sources without a session,
    do not wait.
    """

    stamps_host_time = True

    def __init__(
        self,
        cfg: RigConfig,
        sensor_id: str,
        *,
        read_timeout_s: float = 0.1,
        session: Any = None,
        subordinate_wait_s: float = 30.0,
        should_exit: Callable[[], bool] = lambda: False,
        stall_timeout_s: float | None = None,
    ) -> None:
        self.cfg = cfg
        self.sensor_id = sensor_id
        self.read_timeout_s = read_timeout_s
        self.session = session
        self.subordinate_wait_s = subordinate_wait_s
        self.should_exit = should_exit
        self.stall_timeout_s = stall_timeout_s

    def attach(self, session: Any, *, should_exit: Callable[[], bool] | None = None) -> None:
        """Give the source the worker's zenoh session (and exit flag) for the start-order handshake."""
        self.session = session
        if should_exit is not None:
            self.should_exit = should_exit

    @property
    def role(self) -> str:
        return self.cfg.sensor(self.sensor_id).sync.role

    def subordinate_ids(self) -> list[str]:
        """The rig's kinect subordinates (other than this sensor)."""
        return [
            s.id
            for s in self.cfg.sensors
            if s.source == "kinect" and s.sync.role == "subordinate" and s.id != self.sensor_id
        ]

    def _wait_for_subordinates(self) -> None:
        subs = self.subordinate_ids()
        if self.session is None or self.role != "master" or not subs:
            return
        log.info(
            "kinect master %s: waiting for subordinate camera(s) %s before starting (up to %.0f s)",
            self.sensor_id,
            ", ".join(subs),
            self.subordinate_wait_s,
        )
        missing = wait_for_subordinates(
            self.session, self.cfg.name, subs, timeout_s=self.subordinate_wait_s, should_exit=self.should_exit
        )
        if missing and not self.should_exit():
            log.error(
                "kinect master %s: subordinate camera(s) %s not started after %.0f s; starting the master "
                "anyway (those subordinates stay unsynchronised until restarted)",
                self.sensor_id,
                ", ".join(missing),
                self.subordinate_wait_s,
            )
        elif not missing:
            log.info("kinect master %s: every subordinate camera is running; starting", self.sensor_id)

    def clouds_at(self, frame: SensorFrame) -> PersonCloudsFrame | None:
        """Depth / hybrid mode: the person clouds of ``frame`` (from the body tracker's body-index map)."""
        source = getattr(self, "_source", None)
        return None if source is None else source.clouds_at(frame)

    def frames(self) -> Iterator[tuple[int, SensorFrame | None]]:
        options: dict[str, Any] = {} if self.stall_timeout_s is None else {"stall_timeout_s": self.stall_timeout_s}
        if self.cfg.fusion.mode != "skeleton":
            options["clouds_voxel_mm"] = self.cfg.depth.voxel_mm
        source = self._source = KinectSource.from_config(self.cfg, self.sensor_id, **options)
        source.ensure_available()  # missing pyk4a / SDKs: say so now, not after waiting for subordinates
        self._wait_for_subordinates()
        if self.should_exit():
            return
        source.open()
        token = None
        try:
            if self.session is not None and self.role == "subordinate":
                token = self.session.liveliness().declare_token(keys.alive(self.cfg.name, camera_node(self.sensor_id)))
            yield time.monotonic_ns(), None  # the device is open: the worker's watchdog watches every read from here
            while True:
                yield time.monotonic_ns(), source.read(self.read_timeout_s)
        finally:
            if token is not None:
                token.undeclare()
            source.close()


def check_source(cfg: RigConfig, sensor_id: str) -> None:
    """The cheap checks of :func:`make_source`, done before anything opens (same errors)."""
    sensor = cfg.sensor(sensor_id)
    if sensor.source == "sim" and sensor.pose() is None:
        raise ConfigError(
            f"{cfg.source}: sim sensor {sensor_id!r} needs sensors[i].world_from_sensor: the "
            "simulator observes the person from that (true) pose"
        )
    if sensor.source == "replay" and sensor.replay is not None:
        if not Path(sensor.replay.file).exists():
            raise DataError(f"{cfg.source}: sensors[{sensor_id!r}].replay.file {sensor.replay.file} does not exist")
        detect_format(sensor.replay.file)  # an unknown format fails here, naming the known ones


def replay_anchor_us(cfg: RigConfig) -> int | None:
    """The earliest first device time over the rig's non-MCAP replay files (None when there are none).

    Every replay worker paces its file from this instant, so files of one sync chain that start at different
    frames are published in step (workers started together stay within their start-up jitter).
    """
    files = {s.replay.file for s in cfg.sensors if s.source == "replay" and s.replay is not None}
    firsts = []
    for file in sorted(files):
        if Path(file).exists() and detect_format(file) != "mcap":
            take = open_inputs([str(file)])
            firsts += [int(take.match_times_us(r).min()) for r in take.recordings if r.n_frames]
    return min(firsts) if firsts else None


def make_source(cfg: RigConfig, sensor_id: str, options: WorkerOptions) -> FrameSource:
    """The source of ``sensor_id`` as its ``[[sensors]]`` entry says.

    Raises
    ------
    ConfigError
        Unknown sensor, or a sim sensor without a pose.
    ServiceError
        (from ``frames()``) ``source = "kinect"`` without pyk4a or the Azure Kinect SDKs.
    DataError
        A replay recording that is missing or lacks the sensor.
    """
    sensor = cfg.sensor(sensor_id)
    if sensor.source == "sim":
        return SimSource(
            cfg,
            sensor_id,
            gesture=options.gesture,
            take_duration_s=options.take_duration_s,
            seed=options.seed,
            loop=True if options.loop is None else options.loop,
            take_origin_ns=options.take_origin_ns,
        )
    if sensor.source == "replay":
        assert sensor.replay is not None
        loop = sensor.replay.loop if options.loop is None else options.loop
        return ReplaySource(
            sensor.replay.file,
            sensor_id,
            recorded_sensor=sensor.replay.sensor,
            loop=loop,
            speed=options.speed,
            anchor_us=replay_anchor_us(cfg),
        )
    if sensor.source == "kinect":
        return KinectFrameSource(
            cfg, sensor_id, subordinate_wait_s=options.subordinate_wait_s, stall_timeout_s=options.stall_timeout_s
        )
    raise ConfigError(f"{cfg.source}: sensor {sensor_id!r} has unknown source {sensor.source!r}")  # pragma: no cover
