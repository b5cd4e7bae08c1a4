"""The fusion node's depth and hybrid modes (``[fusion] mode``): person clouds in, one skeleton per person out.

The node calls this module and nothing else of the depth path (``docs/depth-fusion.md``):

- :class:`CloudBuffer` is the zenoh callback of ``skelfuse/<rig>/sensors/*/clouds``: it decodes each sensor's
  person clouds (:mod:`skelfuse.wire.clouds`) and keeps the latest few per sensor, by device timestamp. A
  capture worker publishes a capture's clouds before its skeletons, so they are there when the instant is fused.
- :class:`DepthStage` fuses one instant (a :class:`~skelfuse.rig.grouping.FrameGroup`). Per person: the clouds
  of the bodies associated with that person (the cloud's body id is the skeleton's) go through
  :func:`~skelfuse.fusion.depth.pipeline.fuse_person_depth` (to world, optional ICP, merge, frontalize, virtual
  depth image), then through a tracker, one per person (track id), and back to the world.

  ``depth``: skeleton fusion runs as usual (its tracks associate the bodies, its skeleton gives the facing and
  the simulated tracker's prior); the output is the tracker's skeleton, one per person, with the same track id.
  A person the tracker found nothing for is not output at that instant: never the skeleton fusion's result in
  its place.

  ``hybrid``: the tracker's skeleton enters skeleton fusion as one more, virtual, sensor (identity pose: it is
  already in the world), repeated ``[depth] virtual_weight`` times so that it counts as that many sensors in
  the merge's vote. The bodies are associated with the previous instant's people (every track its real bodies
  joined, tentative ones included; nearest, within :data:`ASSOCIATION_GATE_MM`), since this instant's
  association is what the fusion is about to do. Bodies of no known person (someone's first instant) are
  grouped among themselves by the same distance (:func:`group_new_bodies`) and get a virtual skeleton at once,
  their tracker stream keyed provisionally (negative) until the fusion says which track they joined. A
  person's prior (and the facing that places the virtual camera) is the realigned fused skeleton of the
  real sensors alone (a second skeleton fusion without the virtual sensor,
  :func:`~skelfuse.fusion.depth.hybrid.fused_priors`): never a median of the raw bodies, which carries
  mirrored rear views. That fusion's tracks are born at first sight, so a new person has a prior at once.

Trackers (``[depth] tracker``): :class:`K4abtDepthTracker` (the Body Tracking SDK through
:class:`skelfuse.sources.depth_tracker.VirtualCameraTracker`; or the fake library the suite compiles) or
:class:`skelfuse.sim.depth_tracker.SimulatedDepthTracker` (sim rigs only; not the SDK). The node's start-up
log says which runs. Nothing falls back silently: a tracker that cannot be created stops the node at start-up.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import threading
import time
from collections import Counter
from typing import Any, Protocol

import numpy as np

from skelfuse.config import RigConfig
from skelfuse.config.model import DEPTH_TRACKER_PROCESSES
from skelfuse.fusion.association import descriptor_distance, nanmedian_axis, torso_descriptor
from skelfuse.fusion.camera import Intrinsics
from skelfuse.fusion.depth.cloud import MergedCloud
from skelfuse.fusion.depth.frontal import body_facing
from skelfuse.fusion.depth.hybrid import VIRTUAL_SENSOR_POSE, fused_priors
from skelfuse.fusion.depth.pipeline import DepthFusionParams, PersonDepthView, fuse_person_depth
from skelfuse.rig.grouping import FrameGroup
from skelfuse.rig.instant import FusedInstant, GroupFuser, bodies_to_world, fused_frame, group_bodies
from skelfuse.schema.errors import ConfigError, SkelfuseError
from skelfuse.schema.frames import SensorFrame
from skelfuse.schema.skeleton import N_JOINTS
from skelfuse.sources.depth_tracker import VirtualCameraTracker
from skelfuse.sources.k4abt import K4ABTError, K4abtLibrary, TrackerCreateError, TrackerSettings, load_k4a
from skelfuse.sources.tracker_pool import TrackerPool, WorkerSpec
from skelfuse.wire import keys
from skelfuse.wire.clouds import PersonCloudsFrame, decode_person_clouds
from skelfuse.wire.codec import DecodeError

log = logging.getLogger("skelfuse.service.depth")

VIRTUAL_SENSOR_ID = "virtual"
"""Sensor id of the hybrid mode's virtual sensor (its copies: ``virtual_2``, ``virtual_3``, ...)."""
CLOUD_WAIT_S = 0.03
"""How long one instant's fusion waits, at most, for clouds that have not arrived with their skeletons (the two
keys' samples reach the node on different zenoh threads, and a cloud is larger and decoded on arrival)."""
CLOUD_FIRST_WAIT_S = 10.0
"""For this long after the node starts, a sensor that has sent no cloud yet is waited for too (its first cloud
may lose the race with its first skeletons); after it, a sensor that never sent one is not waited for."""
CLOUD_FRAMES_KEPT = 16
"""Cloud frames kept per sensor (about half a second at 30 fps): enough for a group's deadline."""
ASSOCIATION_GATE_MM = 400.0
"""Hybrid mode: a body joins the previous instant's nearest person (or a new person's first body) only within
this torso-descriptor distance (people move well under 100 mm between two frames)."""
VIRTUAL_INTRINSICS = Intrinsics.azure_kinect_nfov()
"""The virtual camera: NFOV unbinned nominal pinhole intrinsics (640 x 576; the paper's mode)."""


class DepthTracker(Protocol):
    """A body tracker on one person's virtual image (one temporal stream per ``person`` key)."""

    name: str
    description: str

    def track(
        self, person: int, view: PersonDepthView, prior_world: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """(32, 3) world joints (NaN where not found) and (32,) uint8 confidence; None when nothing was found."""
        ...

    def retire(self, active: set[int]) -> None:
        """Forget the streams of people not in ``active``."""
        ...

    def close(self) -> None: ...


TRACKER_PROCESS_MODES = DEPTH_TRACKER_PROCESSES
"""``[depth] tracker_processes``: where each person's SDK tracker runs (see :class:`K4abtDepthTracker`)."""
TrackResult = tuple[np.ndarray, np.ndarray] | Exception | None


def track_all(
    tracker: DepthTracker, requests: list[tuple[int, PersonDepthView, np.ndarray | None]]
) -> list[TrackResult]:
    """Every request's result (or its error): the tracker's own ``track_many`` where it has one (its people's
    trackers then work at the same time), else one :meth:`DepthTracker.track` after the other."""
    many = getattr(tracker, "track_many", None)
    if many is not None:
        return many(requests)
    results: list[TrackResult] = []
    for person, view, prior in requests:
        try:
            results.append(tracker.track(person, view, prior))
        except (K4ABTError, SkelfuseError) as exc:
            results.append(exc)
    return results


class K4abtDepthTracker:
    """The Body Tracking SDK on each person's virtual image: one :class:`VirtualCameraTracker` per track id.

    Each image is submitted and its result awaited (``wait_ms`` each way): the depth and hybrid modes wait for
    the tracker, so their latency includes its time (reported apart from the skeleton path's).

    Where the trackers run (``processes``, ``[depth] tracker_processes``):

    - ``"in_process"``: all in the node's process. An SDK version that allows one tracker per process then
      tracks one person; the next person's tracker fails to be created, counted as ``tracker_errors``.
    - ``"per_person"``: each person's tracker in its own worker process (:class:`TrackerPool`), started with
      the person's first image (its first instants have no result while the SDK loads).
    - ``"auto"`` (default): in process, until the SDK refuses a tracker while another lives in the process;
      from then on every new person gets a worker process (said once in the log). Costs nothing where the SDK
      allows several trackers per process, and never leaves a person untracked where it does not.
    """

    name = "k4abt"

    def __init__(
        self,
        settings: TrackerSettings,
        *,
        wait_ms: int,
        processes: str = "auto",
        intrinsics: Intrinsics = VIRTUAL_INTRINSICS,
        hung_after_s: float = 2.0,
    ) -> None:
        if processes not in TRACKER_PROCESS_MODES:
            raise ConfigError(
                f"[depth] tracker_processes: expected one of {', '.join(TRACKER_PROCESS_MODES)}, found {processes!r}"
            )
        self.k4a = load_k4a()
        self.library = K4abtLibrary.load()
        self.settings = settings
        self.wait_ms = int(wait_ms)
        self.intrinsics = intrinsics
        self.processes = processes
        self.hung_after_s = hung_after_s
        where = {
            "auto": "in this process, a worker process per person if the SDK allows one tracker per process",
            "in_process": "all in this process",
            "per_person": "a worker process per person",
        }[processes]
        self.description = (
            f"Body Tracking SDK ({self.library.path}, ABI {self.library.abi}), one tracker per person, {where}"
        )
        self._trackers: dict[int, VirtualCameraTracker] = {}
        self._pool: TrackerPool | None = None
        self._pooled = processes == "per_person"  # new people go to worker processes

    def pool(self) -> TrackerPool:
        if self._pool is None:
            spec = WorkerSpec(
                k4a_path=str(self.k4a._name),
                k4abt_path=str(self.library.path),
                abi=self.library.abi,
                intrinsics=self.intrinsics,
                settings=self.settings,
                wait_ms=self.wait_ms,
            )
            self._pool = TrackerPool(spec, hung_after_s=self.hung_after_s)
        return self._pool

    def track(
        self, person: int, view: PersonDepthView, prior_world: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray] | None:
        (result,) = self.track_many([(person, view, prior_world)])
        if isinstance(result, Exception):
            raise result
        return result

    def track_many(self, requests: list[tuple[int, PersonDepthView, np.ndarray | None]]) -> list[TrackResult]:
        results: list[TrackResult] = [None] * len(requests)
        pooled: list[int] = []
        for index, (person, view, _) in enumerate(requests):
            in_pool = self._pool is not None and person in self._pool.persons()
            if person not in self._trackers and (self._pooled or in_pool):
                pooled.append(index)
                continue
            try:
                results[index] = self._track_here(person, view)
            except TrackerCreateError as exc:
                if self.processes == "auto" and self._trackers:
                    self._pooled = True
                    log.warning(
                        "the Body Tracking SDK refused a second tracker in this process (%s); person %d and every "
                        'new person get a tracker process of their own ([depth] tracker_processes = "auto")',
                        exc,
                        person,
                    )
                    pooled.append(index)
                else:
                    results[index] = exc
            except (K4ABTError, SkelfuseError) as exc:
                results[index] = exc
        if pooled:
            answers = self.pool().track_many([(requests[i][0], requests[i][1]) for i in pooled])
            for index, answer in zip(pooled, answers, strict=True):
                results[index] = answer
        return results

    def _track_here(self, person: int, view: PersonDepthView) -> tuple[np.ndarray, np.ndarray] | None:
        tracker = self._trackers.get(person)
        if tracker is None:
            tracker = self._trackers[person] = VirtualCameraTracker(
                self.k4a, self.library, self.intrinsics, self.settings
            )
        if not tracker.submit(view, timeout_ms=self.wait_ms):
            return None
        skeleton = tracker.collect(timeout_ms=self.wait_ms)
        if skeleton is None:
            return None
        return skeleton.positions_world, skeleton.confidence

    def rename(self, old: int, new: int) -> None:
        """A new person's stream, first keyed provisionally, takes its track's id."""
        if old in self._trackers and new not in self._trackers:
            self._trackers[new] = self._trackers.pop(old)
        if self._pool is not None:
            self._pool.rename(old, new)

    def retire(self, active: set[int]) -> None:
        for person in [p for p in self._trackers if p not in active]:
            self._trackers.pop(person).close()
        if self._pool is not None:
            self._pool.retire(active)

    def report(self) -> dict[str, Any] | None:
        """The worker processes' counters (None while none was needed)."""
        return None if self._pool is None else self._pool.report()

    def close(self) -> None:
        self.retire(set())
        if self._pool is not None:
            self._pool.close()


def open_tracker(cfg: RigConfig) -> DepthTracker:
    """The tracker ``[depth] tracker`` names; raises (ConfigError / the SDK loader's error) when it cannot run."""
    depth = cfg.depth
    if depth.tracker == "simulated":
        if any(s.source != "sim" for s in cfg.sensors):  # the parser refuses it too; never run it on real data
            raise ConfigError(f'{cfg.source}: [depth] tracker = "simulated" runs on simulated rigs only')
        from skelfuse.sim.depth_tracker import SimulatedDepthTracker  # the simulator: on simulated rigs only

        return SimulatedDepthTracker()
    kinect = next((s.kinect for s in cfg.sensors if s.kinect is not None), None)
    settings = TrackerSettings.from_config(kinect.tracker) if kinect is not None else TrackerSettings()
    return K4abtDepthTracker(settings, wait_ms=depth.tracker_wait_ms, processes=depth.tracker_processes)


class CloudBuffer:
    """The latest person clouds of every sensor, by device timestamp; the zenoh callback of the clouds key.

    Thread-safe (the callback runs on a zenoh thread, :meth:`take` on the node's loop). Bad payloads are
    counted per reason (``rejects``), never raised.
    """

    def __init__(self, rig: str, sensor_ids: tuple[str, ...], *, max_payload_bytes: int | None = None) -> None:
        self.rig = rig
        self.max_payload_bytes = max_payload_bytes
        self._frames: dict[str, collections.OrderedDict[int, PersonCloudsFrame]] = {
            sid: collections.OrderedDict() for sid in sensor_ids
        }
        self._lock = threading.Lock()
        self._arrived = threading.Condition(self._lock)
        self.received = 0
        self.rejects: Counter[str] = Counter()
        self._first_wait_until = time.monotonic() + CLOUD_FIRST_WAIT_S

    def __call__(self, sample: Any) -> None:
        self.put(str(sample.key_expr), sample.payload.to_bytes())

    def put(self, key: str, payload: bytes) -> None:
        if self.max_payload_bytes is not None and len(payload) > self.max_payload_bytes:
            self._reject("oversized")
            return
        try:
            sensor_id = keys.parse_sensor_key(key.removesuffix("/clouds") + "/skeletons", self.rig)
            frame = decode_person_clouds(payload)
        except ValueError:
            self._reject("bad_key")
            return
        except DecodeError as exc:
            self._reject(exc.reason)
            return
        if frame.sensor_id != sensor_id or sensor_id not in self._frames:
            self._reject("key_mismatch" if sensor_id in self._frames else "unknown_sensor")
            return
        with self._lock:
            frames = self._frames[sensor_id]
            frames[frame.device_timestamp_us] = frame
            while len(frames) > CLOUD_FRAMES_KEPT:
                frames.popitem(last=False)
            self.received += 1
            self._arrived.notify_all()

    def _reject(self, reason: str) -> None:
        with self._lock:
            self.rejects[reason] += 1
            first = self.rejects[reason] == 1
        if first:
            log.warning("rejected a person-cloud payload (%s); counted in the status under depth.cloud_rejects", reason)

    def take(self, sensor_id: str, device_time_us: int, *, until: float | None = None) -> PersonCloudsFrame | None:
        """The clouds of ``sensor_id``'s capture at ``device_time_us``, waiting for them up to the monotonic
        time ``until`` (None: no wait); None when they did not arrive."""
        with self._arrived:
            frames = self._frames.get(sensor_id)
            if frames is None:
                return None
            # a sensor that never sent a cloud is not waited for, once the start-up's first race is over
            while (
                device_time_us not in frames
                and until is not None
                and (frames or time.monotonic() < self._first_wait_until)
            ):
                left = until - time.monotonic()
                if left <= 0 or not self._arrived.wait(left):
                    break
            return frames.get(device_time_us)


@dataclasses.dataclass
class DepthCounters:
    """What the depth stage did, for the node's status (``info.depth``)."""

    persons: int = 0
    tracked: int = 0
    no_clouds: int = 0
    clouds_missing: int = 0
    tracker_misses: int = 0
    tracker_errors: int = 0
    depth_ms: collections.deque[float] = dataclasses.field(default_factory=lambda: collections.deque(maxlen=1000))


class DepthStage:
    """One instant of the depth or hybrid mode (see the module docstring).

    Parameters
    ----------
    cfg : RigConfig
        ``[fusion] mode`` (depth / hybrid) and ``[depth]``.
    tracker : DepthTracker
    clouds : CloudBuffer, optional
        Default: a new one for the rig's sensors.
    """

    def __init__(self, cfg: RigConfig, tracker: DepthTracker, *, clouds: CloudBuffer | None = None) -> None:
        if cfg.fusion.mode not in ("depth", "hybrid"):
            raise ValueError(f"the depth stage runs in depth or hybrid mode, not {cfg.fusion.mode!r}")
        self.mode = cfg.fusion.mode
        self.tracker = tracker
        self.params = DepthFusionParams(voxel_mm=cfg.depth.voxel_mm, icp=cfg.depth.icp)
        self.copies = int(cfg.depth.virtual_weight) if self.mode == "hybrid" else 0
        self.sensor_ids: tuple[str, ...] = cfg.sensor_ids
        self.clouds = clouds or CloudBuffer(cfg.name, cfg.sensor_ids, max_payload_bytes=cfg.intake.max_payload_bytes)
        self.counters = DepthCounters()
        self.last_clouds: tuple[tuple[int, MergedCloud], ...] = ()
        self._poses = np.zeros((len(self.sensor_ids), 4, 4))
        self._previous: tuple[np.ndarray, np.ndarray] = (np.zeros(0, np.int64), np.zeros((0, N_JOINTS, 3)))
        self._next_new_key = -1
        self._skeleton: GroupFuser | None = None
        """Hybrid: tracker stream keys of new persons count down from -1 until their track is known."""

    def fuser_sensors(self, world_from_sensor: np.ndarray) -> tuple[tuple[str, ...], np.ndarray]:
        """The sensors (ids, poses) the node's GroupFuser fuses: the rig's, plus the virtual copies in hybrid."""
        self._poses = np.asarray(world_from_sensor, dtype=np.float64)
        self._skeleton = None  # rebuilt on the new poses
        virtual = tuple(VIRTUAL_SENSOR_ID if k == 0 else f"{VIRTUAL_SENSOR_ID}_{k + 1}" for k in range(self.copies))
        poses = np.concatenate([self._poses, np.repeat(VIRTUAL_SENSOR_POSE[None], self.copies, axis=0)])
        return self.sensor_ids + virtual, poses

    def describe(self) -> str:
        extra = f", virtual sensor weight {self.copies}" if self.mode == "hybrid" else ""
        return (
            f"mode {self.mode}: tracker {self.tracker.name} = {self.tracker.description}; voxel "
            f"{self.params.voxel_mm:g} mm, ICP {'on' if self.params.icp else 'off'}{extra}"
        )

    def step(self, fuser: GroupFuser, group: FrameGroup) -> FusedInstant:
        """Fuse one instant in this stage's mode (``fuser`` was built with :meth:`fuser_sensors`)."""
        tick = time.perf_counter_ns()
        instant = self._hybrid(fuser, group) if self.mode == "hybrid" else self._depth(fuser, group)
        self.counters.depth_ms.append((time.perf_counter_ns() - tick) / 1e6)
        return instant

    # -- the two modes --------------------------------------------------------------------------------------

    def _depth(self, fuser: GroupFuser, group: FrameGroup) -> FusedInstant:
        instant = fuser.step(group)
        people = instant.people
        rows = np.arange(people.n_persons)
        assignment = np.where(people.assignment >= 0, people.assignment, -1)
        virtual, confidence, used = self._virtual_skeletons(group, assignment, people.positions, people.track_ids, rows)
        finite = np.isfinite(virtual).all(axis=-1)
        out = dataclasses.replace(
            people,
            positions=virtual,
            confidence=confidence,
            n_agree=np.where(finite, used.sum(axis=1)[:, None], 0).astype(np.int16),
            contributors=used,
            orientations=None,
            position_std=None,
            agreement_mm=None,
        )
        self.tracker.retire({int(i) for i in people.track_ids})
        return dataclasses.replace(instant, frame=fused_frame(out, group.time_us, fuser.sensor_ids))

    def _hybrid(self, fuser: GroupFuser, group: FrameGroup) -> FusedInstant:
        n_real = len(self.sensor_ids)
        positions, _, valid = group_bodies(group.frames, self.sensor_ids)
        world = bodies_to_world(self._poses, positions)
        previous_keys, previous = self._previous
        assignment = associate_bodies(world, valid, previous)
        # bodies of no known person (a person's first instants): this instant's own grouping, new stream keys
        assignment, n_new = group_new_bodies(world, valid, assignment, first=previous_keys.shape[0])
        keys = np.concatenate([previous_keys, np.arange(self._next_new_key, self._next_new_key - n_new, -1)])
        self._next_new_key -= n_new
        skeleton = self._skeleton_fuser(fuser).step(group).people
        priors = fused_priors(assignment, skeleton.assignment, skeleton.positions, keys.shape[0])
        virtual, confidence, _ = self._virtual_skeletons(group, assignment, priors, keys, np.arange(len(keys)))
        found = np.isfinite(virtual).all(axis=-1).any(axis=-1)
        frames = dict(group.frames)
        if found.any():
            body = virtual[found]
            frame = SensorFrame(
                sensor_id=VIRTUAL_SENSOR_ID,
                sequence=0,
                device_time_us=group.time_us,
                host_time_ns=0,
                body_ids=(keys[found] % 2**32).astype(np.uint32),
                positions=body.astype(np.float32),  # NaN joints carry confidence NONE, as with_virtual_sensor's
                orientations=np.tile(np.array([1.0, 0, 0, 0], np.float32), (int(found.sum()), N_JOINTS, 1)),
                confidence=np.where(np.isfinite(body).all(axis=-1), confidence[found], 0).astype(np.uint8),
            )
            for sensor_id in fuser.sensor_ids[n_real:]:
                frames[sensor_id] = dataclasses.replace(frame, sensor_id=sensor_id)
        instant = fuser.step(FrameGroup(group.time_us, frames, group.missing, group.complete))
        self._follow_tracks(instant, keys, assignment, found, world, n_real)
        return dataclasses.replace(  # the node's per-sensor views (pose fit, Rerun) see the real sensors only
            instant, sensors_world=instant.sensors_world[:n_real], valid=instant.valid[:n_real]
        )

    def _skeleton_fuser(self, fuser: GroupFuser) -> GroupFuser:
        """Hybrid: the skeleton fusion of the real sensors alone (``fuser``'s parameters), whose realigned
        skeletons are the tracker's priors. Its tracks are born at first sight (``birth_frames`` 1), so that a
        new person has a prior at once; which tracks are output stays the main fusion's decision."""
        if self._skeleton is None:
            table = fuser.people.track_params
            self._skeleton = GroupFuser(
                self.sensor_ids,
                self._poses,
                fuser.params,
                gate_mm=table.gate_mm,
                birth_frames=1,
                timeout_s=table.timeout_s,
                duplicate_mm=fuser.people.duplicate_mm,
                reset_gap_s=fuser.reset_gap_s,
                max_persons=table.max_tracks,
            )
        return self._skeleton

    def _follow_tracks(
        self,
        instant: FusedInstant,
        keys: np.ndarray,
        assignment: np.ndarray,
        found: np.ndarray,
        world: np.ndarray,
        n_real: int,
    ) -> None:
        """After a hybrid instant: a new person's tracker stream takes the id of the track its bodies joined
        (the virtual body's track, else the most common of its real bodies'), tentative tracks included; the
        next instant's persons are every track this instant's real bodies joined (at the median of those
        bodies, or the fused skeleton where the track was output). Streams of anyone else are retired."""
        body_tracks = instant.people.body_track_ids
        real_tracks = body_tracks[:n_real, : world.shape[1]]
        virtual_slot = np.cumsum(found) - 1  # the virtual frame's body index of each person found
        rename = getattr(self.tracker, "rename", None)
        taken = {int(k) for k in keys if k >= 0}
        for person, key in enumerate(keys):
            if key >= 0:
                continue
            track = -1
            if found[person] and self.copies:
                track = int(body_tracks[n_real, virtual_slot[person]])
            if track < 0:
                joined = real_tracks[(assignment == person) & (real_tracks >= 0)]
                if joined.size:
                    values, counts = np.unique(joined, return_counts=True)
                    track = int(values[np.argmax(counts)])
            if track >= 0 and track not in taken:
                taken.add(track)
                if rename is not None:
                    rename(int(key), track)
        ids = np.unique(real_tracks[real_tracks >= 0])
        positions = np.stack([nanmedian_axis(world[real_tracks == i], axis=0) for i in ids]) if ids.size else None
        if positions is None:
            positions = np.zeros((0, N_JOINTS, 3))
        fused_rows = {int(t): r for r, t in enumerate(instant.frame.track_ids)}
        for row, track in enumerate(ids):
            if int(track) in fused_rows:
                positions[row] = instant.frame.positions[fused_rows[int(track)]]
        self._previous = (ids.astype(np.int64), positions)
        self.tracker.retire({int(i) for i in ids})

    # -- per person ---------------------------------------------------------------------------------------

    def _virtual_skeletons(
        self,
        group: FrameGroup,
        assignment: np.ndarray,
        priors: np.ndarray,
        person_keys: np.ndarray,
        rows: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For persons ``rows`` (indices into ``priors`` / ``person_keys``), the tracker's skeleton from the
        clouds of the bodies ``assignment`` (S, B) gives them: (P, 32, 3) world, (P, 32) confidence, (P, S)
        sensors whose clouds went in."""
        n_persons, n_sensors = len(rows), len(self.sensor_ids)
        virtual = np.full((n_persons, N_JOINTS, 3), np.nan)
        confidence = np.zeros((n_persons, N_JOINTS), np.uint8)
        used = np.zeros((n_persons, n_sensors), bool)
        per_person: list[list[list[np.ndarray]]] = [[[] for _ in range(n_sensors)] for _ in range(n_persons)]
        until = time.monotonic() + CLOUD_WAIT_S
        for s, sensor_id in enumerate(self.sensor_ids):
            frame = group.frames.get(sensor_id)
            if frame is None or frame.n_bodies == 0:
                continue
            clouds = self.clouds.take(sensor_id, frame.device_time_us, until=until)
            if clouds is None:  # not arrived in time: this sensor's bodies go without their clouds
                self.counters.clouds_missing += 1
                continue
            by_id = dict(zip((int(i) for i in clouds.body_ids), clouds.clouds, strict=True))
            for b, body_id in enumerate(frame.body_ids):
                person = int(assignment[s, b]) if b < assignment.shape[1] else -1
                cloud = by_id.get(int(body_id))
                if person >= 0 and cloud is not None and cloud.shape[0]:
                    per_person[person][s].append(cloud)
        merged = []
        requests: list[tuple[int, PersonDepthView, np.ndarray | None]] = []
        asked: list[int] = []
        for person in range(n_persons):
            self.counters.persons += 1
            sensor_clouds = [np.concatenate(c) if c else np.zeros((0, 3)) for c in per_person[person]]
            sizes = np.array([c.shape[0] for c in sensor_clouds])
            if sizes.sum() < 50:  # nothing worth a virtual image
                self.counters.no_clouds += 1
                continue
            prior = priors[rows[person]]
            facing = body_facing(prior)
            facing_deg = float(np.degrees(np.arctan2(facing[1], facing[0]))) if np.isfinite(facing).all() else None
            view = fuse_person_depth(
                sensor_clouds,
                self._poses,
                VIRTUAL_INTRINSICS,
                reference=int(np.argmax(sizes)),
                skeleton_facing_deg=facing_deg,
                params=self.params,
            )
            key = int(person_keys[rows[person]])
            merged.append((key, view.merged))
            used[person] = sizes > 0
            requests.append((key, view, prior if np.isfinite(prior).any() else None))
            asked.append(person)
        for person, (key, _, _), result in zip(asked, requests, track_all(self.tracker, requests), strict=True):
            if isinstance(result, Exception):
                self.counters.tracker_errors += 1
                if self.counters.tracker_errors == 1 or self.counters.tracker_errors % 1000 == 0:
                    log.error(
                        "depth tracker failed for person %d (%d so far): %s", key, self.counters.tracker_errors, result
                    )
                continue
            if result is None:
                self.counters.tracker_misses += 1
                continue
            virtual[person], confidence[person] = result
            self.counters.tracked += 1
        self.last_clouds = tuple(merged)
        return virtual, confidence, used

    def report(self) -> dict[str, Any]:
        """The status document's ``depth`` entry."""
        c = self.counters
        data = np.fromiter(c.depth_ms, dtype=np.float64)
        return {
            "mode": self.mode,
            "tracker": self.tracker.name,
            "clouds_received": self.clouds.received,
            "cloud_rejects": dict(self.clouds.rejects),
            "persons": c.persons,
            "tracked": c.tracked,
            "no_clouds": c.no_clouds,
            "clouds_missing": c.clouds_missing,
            "tracker_misses": c.tracker_misses,
            "tracker_errors": c.tracker_errors,
            "depth_ms_p50": round(float(np.percentile(data, 50)), 3) if data.size else None,
            "depth_ms_p99": round(float(np.percentile(data, 99)), 3) if data.size else None,
            "tracker_processes": getattr(self.tracker, "report", lambda: None)(),
        }

    def close(self) -> None:
        self.tracker.close()


def associate_bodies(world: np.ndarray, valid: np.ndarray, persons: np.ndarray) -> np.ndarray:
    """(S, B) index of the person in ``persons`` (P, 32, 3) each valid body of ``world`` (S, B, 32, 3) is
    nearest to, -1 beyond :data:`ASSOCIATION_GATE_MM` or with no person. The distance is the people path's own
    (:func:`descriptor_distance` of the mirror-invariant torso descriptors), so a mirrored rear view joins its
    person like any other view; padding slots are infinitely far."""
    out = np.full(valid.shape, -1, dtype=np.int64)
    if persons.shape[0] == 0 or world.shape[1] == 0:
        return out
    distance = descriptor_distance(torso_descriptor(world)[:, :, None], torso_descriptor(persons)[None, None])
    nearest = np.argmin(distance, axis=-1)
    close = np.take_along_axis(distance, nearest[..., None], axis=-1)[..., 0] <= ASSOCIATION_GATE_MM
    out[valid & close] = nearest[valid & close]
    return out


def group_new_bodies(
    world: np.ndarray, valid: np.ndarray, assignment: np.ndarray, *, first: int
) -> tuple[np.ndarray, int]:
    """The valid bodies ``assignment`` leaves without a person (-1), grouped into new persons numbered from
    ``first``: a body joins the new person whose first body is nearest by the people path's torso distance,
    within :data:`ASSOCIATION_GATE_MM` and at most one body per sensor, else starts one. Returns the completed
    assignment (S, B) and the number of new persons. (A handful of bodies per instant: a plain loop.)"""
    out = assignment.copy()
    descriptors = torso_descriptor(world)
    seeds: list[tuple[np.ndarray, set[int]]] = []
    for s, b in zip(*np.nonzero(valid & (assignment < 0)), strict=True):
        distances = [
            np.inf if s in sensors else float(descriptor_distance(descriptors[s, b], seed)) for seed, sensors in seeds
        ]
        nearest = int(np.argmin(distances)) if distances else -1
        if nearest < 0 or distances[nearest] > ASSOCIATION_GATE_MM:
            seeds.append((descriptors[s, b], set()))
            nearest = len(seeds) - 1
        seeds[nearest][1].add(int(s))
        out[s, b] = first + nearest
    return out, len(seeds)


def depth_stage_for(cfg: RigConfig) -> DepthStage | None:
    """The node's depth stage for ``[fusion] mode`` (None in skeleton mode); opens the tracker."""
    if cfg.fusion.mode == "skeleton":
        return None
    return DepthStage(cfg, open_tracker(cfg))
