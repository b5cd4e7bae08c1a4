"""The rig configuration as typed, frozen dataclasses: one :class:`RigConfig` and its sections.

Built by :func:`skelfuse.config.parse.parse_rig_config` (every key checked); read by every node of the rig.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.config.calibration_file import CALIBRATE_HINT, load_calibration
from skelfuse.config.checks import did_you_mean
from skelfuse.fusion import presets
from skelfuse.fusion.presets import FusionParams
from skelfuse.schema.errors import ConfigError

SOURCE_KINDS: tuple[str, ...] = ("sim", "replay", "kinect")
SYNC_BY: tuple[str, ...] = ("device", "host")
SYNC_ROLES: tuple[str, ...] = ("standalone", "master", "subordinate")
DEPTH_MODES: tuple[str, ...] = ("NFOV_UNBINNED", "NFOV_2X2BINNED", "WFOV_UNBINNED", "WFOV_2X2BINNED")
"""Depth modes body tracking can use (OFF and PASSIVE_IR give no depth)."""
COLOR_RESOLUTIONS: tuple[str, ...] = ("720P", "1080P", "1440P", "1536P", "2160P", "3072P")
KINECT_FPS: tuple[int, ...] = (5, 15, 30)
PROCESSING_MODES: tuple[str, ...] = ("gpu", "cpu", "cuda", "tensorrt", "directml")
"""k4abt_tracker_processing_mode_t, in SDK order (GPU=0, CPU=1, CUDA=2, TensorRT=3, DirectML=4)."""
SENSOR_ORIENTATIONS: tuple[str, ...] = ("default", "clockwise90", "counterclockwise90", "flip180")
"""k4abt_sensor_orientation_t, in SDK order."""
ZENOH_MODES: tuple[str, ...] = ("peer", "client", "router")
CONGESTION_CONTROLS: tuple[str, ...] = ("drop", "block")
"""``[zenoh] fused_congestion_control``: zenoh's ``CongestionControl.DROP`` / ``BLOCK`` by name."""
RERUN_MODES: tuple[str, ...] = ("off", "spawn", "serve", "save")
DEFAULT_PRESET = "skelfuse"
"""The fusion preset of a rig config without ``[fusion] preset``, and of the demo and offline fusion."""
FUSION_PRESETS: tuple[str, ...] = ("skelfuse", "A1", "A2", "A3", "A4", "A5")
"""Accepted ``[fusion] preset`` names (case-insensitive), as :func:`skelfuse.fusion.presets.preset` knows them."""
MIN_DELAY_SPACING_US = 160
"""Subordinate depth delays must be at least this far apart (and from the master's 0) to avoid IR interference."""


@dataclass(frozen=True)
class SyncConfig:
    """``[sync]``: how the fusion node groups the frames of one instant.

    Attributes
    ----------
    by : {"device", "host"}
        "device": group by device timestamp (needs wired hardware sync, so all devices share one clock);
        "host": group by the host receive time (rigs without sync cables).
    fps : float
        The rig's frame rate, Hz. Kinect sensors capture at it (5, 15 or 30).
    tolerance_ms : float
        Frames whose times lie within this of a group's first frame belong to that group, ms.
    deadline_ms : float
        A group is emitted at the latest this long after its first frame arrived, ms (complete or not).
    resync_after_frames : int
        Consecutive frames far outside the current time window after which the grouper restarts its
        clock (a replay looped, all sensors restarted).
    resync_horizon_ms : float
        How far from the newest frame time a frame may lie before it counts as outside the window, ms.
    max_ahead_ms, max_behind_ms : float
        How far a frame's time may lie ahead of (in the future of) / behind its own sensor's learned clock
        before it is rejected as off clock, ms (see :mod:`skelfuse.rig.grouping`, "Sensor clocks").
    """

    by: str = "device"
    fps: float = 30.0
    tolerance_ms: float = 10.0
    deadline_ms: float = 17.0
    resync_after_frames: int = 8
    resync_horizon_ms: float = 1000.0
    max_ahead_ms: float = 100.0
    max_behind_ms: float = 1000.0

    @property
    def max_ahead_us(self) -> int:
        return round(self.max_ahead_ms * 1000)

    @property
    def max_behind_us(self) -> int:
        return round(self.max_behind_ms * 1000)

    @property
    def frame_period_us(self) -> float:
        return 1e6 / self.fps

    @property
    def tolerance_us(self) -> int:
        return round(self.tolerance_ms * 1000)

    @property
    def deadline_us(self) -> int:
        return round(self.deadline_ms * 1000)

    @property
    def resync_horizon_us(self) -> int:
        return round(self.resync_horizon_ms * 1000)


@dataclass(frozen=True)
class SensorSyncConfig:
    """``sensors[i].sync``: the sensor's role in a wired sync chain (kinect; emulated by sim).

    Attributes
    ----------
    role : {"standalone", "master", "subordinate"}
    delay_us : int
        Subordinates only: depth capture delay after the master, µs (distinct, >= 160 µs apart). 0 otherwise.
    """

    role: str = "standalone"
    delay_us: int = 0


@dataclass(frozen=True)
class TrackerConfig:
    """``sensors[i].tracker``: Azure Kinect Body Tracking SDK settings (k4abt_tracker_configuration_t)."""

    processing_mode: str = "gpu"
    gpu_device_id: int = 0
    model_path: Path | None = None
    sensor_orientation: str = "default"
    temporal_smoothing: float = 0.0


@dataclass(frozen=True)
class KinectConfig:
    """``sensors[i].kinect``: device settings of an Azure Kinect DK / Femto Bolt (K4A mode)."""

    serial: str
    depth_mode: str = "NFOV_UNBINNED"
    color_resolution: str | None = None
    tracker: TrackerConfig = field(default_factory=TrackerConfig)


@dataclass(frozen=True)
class ReplayConfig:
    """``sensors[i].replay``: frames come from a recording."""

    file: Path
    sensor: str | None = None
    loop: bool = False


@dataclass(frozen=True)
class SimConfig:
    """``sensors[i].sim``: frames come from the simulator."""

    profile: Path | None = None
    seed: int | None = None
    clock_offset_ms: float = 0.0
    clock_jitter_ms: float = 0.0


@dataclass(frozen=True)
class SensorConfig:
    """One ``[[sensors]]`` entry.

    Attributes
    ----------
    id : str
        Sensor id: a zenoh key chunk (the device serial for kinect sensors, by convention).
    source : {"sim", "replay", "kinect"}
    world_from_sensor : 4x4 tuple of floats or None
        Inline pose (sensor frame -> world, mm). For sim sensors it is also the true pose.
    sync : SensorSyncConfig
    kinect, replay, sim : the options of the sensor's source kind (None for the other kinds)
    host : str or None
        The capture PC that runs this sensor's worker (a name; default: the sensor id). Its certificate
        (``skelfuse certs``) may publish only its own sensors' keys (the generated access control).
    """

    id: str
    source: str
    world_from_sensor: tuple[tuple[float, ...], ...] | None = None
    sync: SensorSyncConfig = field(default_factory=SensorSyncConfig)
    kinect: KinectConfig | None = None
    replay: ReplayConfig | None = None
    sim: SimConfig | None = None
    host: str | None = None

    @property
    def capture_host(self) -> str:
        """The capture PC's name (``host``, else the sensor id)."""
        return self.host or self.id

    def pose(self) -> np.ndarray | None:
        """(4, 4) float64 inline ``world_from_sensor``, or None."""
        return None if self.world_from_sensor is None else np.array(self.world_from_sensor, dtype=np.float64)


@dataclass(frozen=True)
class CalibrationConfig:
    """``[calibration]``: where the rig's measured poses live (a TOML file; may not exist yet)."""

    file: Path | None = None


@dataclass(frozen=True)
class FusionConfig:
    """``[fusion]``: a preset ("skelfuse" or the paper's A1-A5), its DBSCAN radius, and FusionParams overrides.

    ``eps_mm`` None keeps the preset's own radius (75 mm for "skelfuse", 100 mm for the paper's presets).
    ``params`` holds the ``[fusion.params]`` overrides as sorted ``(field, value)`` pairs, with "off"
    already turned into None.
    """

    preset: str = DEFAULT_PRESET
    eps_mm: float | None = None
    params: tuple[tuple[str, Any], ...] = ()
    mode: str = "skeleton"
    """What the node outputs: "skeleton" (skeleton fusion), "depth" (the skeleton a body tracker finds on each
    person's fused virtual depth image, ``docs/depth-fusion.md``) or "hybrid" (that skeleton enters skeleton
    fusion as one more, virtual, sensor). Settings of the depth path: ``[depth]`` (:class:`DepthConfig`)."""
    fixed_lag_frames: int = 0
    """Above 0, the live node publishes each instant this many frames later, smoothed by the fixed-lag smoother
    over the filter's motion model (``skelfuse.rig.smoothing.LiveFixedLag``); 0 publishes the live filter's
    output at once."""

    def fusion_params(self) -> FusionParams:
        """The :class:`skelfuse.fusion.presets.FusionParams` this section describes.

        Raises
        ------
        ConfigError
            An override is rejected by FusionParams' own validation.
        """

        try:
            base = presets.preset(self.preset, self.eps_mm)
            return dataclasses.replace(base, **dict(self.params))
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"[fusion]: {exc}") from None


FUSION_MODES = ("skeleton", "depth", "hybrid")
"""Accepted ``[fusion] mode`` values."""
DEPTH_TRACKERS = ("k4abt", "simulated")
DEPTH_TRACKER_PROCESSES = ("auto", "in_process", "per_person")
"""Accepted ``[depth] tracker`` values."""


@dataclass(frozen=True)
class DepthConfig:
    """``[depth]``: the depth-level fusion of ``[fusion] mode = "depth"`` / ``"hybrid"`` (docs/depth-fusion.md).

    Attributes
    ----------
    tracker : "k4abt" (the Body Tracking SDK on the virtual image) or "simulated" (sim rigs only: a stand-in
        that is not the SDK, :class:`skelfuse.sim.depth_tracker.SimulatedDepthTracker`).
    voxel_mm : voxel edge of the capture workers' person clouds and of the merged cloud.
    icp : refine each cloud against the others by point-to-plane ICP (costly; off by default).
    tracker_wait_ms : how long the node waits for the tracker's result of one person's image.
    virtual_weight : hybrid mode: the virtual sensor counts as this many sensors in the merge's vote (its
        skeleton enters as that many identical rows, ``virtual``, ``virtual_2``, ...).
    tracker_processes : "k4abt": where each person's tracker runs: "auto" (in the node's process until the SDK
        refuses a second tracker there, then a worker process per new person), "in_process", "per_person".
    """

    tracker: str = "k4abt"
    voxel_mm: float = 15.0
    icp: bool = False
    tracker_wait_ms: int = 100
    virtual_weight: int = 1
    tracker_processes: str = "auto"


@dataclass(frozen=True)
class ZenohSection:
    """``[zenoh]``: session settings for every node of the rig (see :func:`zenoh_config`).

    Attributes
    ----------
    mode, connect, listen, multicast_scouting : the session's mode, endpoints and UDP multicast scouting
        (off unless set: production rigs use explicit endpoints; the demo turns it on).
    reconnect_init_ms, reconnect_max_ms : connect retry period, first and longest (zenoh doubles it): how
        soon a client is back after its router or peer restarts.
    connect_timeout_ms : how long opening a session tries its connect endpoints before it fails (and the
        node retries with backoff, still answering SIGTERM): a TLS refusal otherwise blocks forever.
    max_message_bytes : larger messages are dropped by zenoh itself before they reach Python.
    fused_congestion_control : ``"drop"`` or ``"block"``: what the fusion node's fused-frame publisher does when
        the link to a subscriber (or to the router) is full (zenoh ``CongestionControl``).
    wait_before_drop_ms : a ``"drop"`` message waits at most this long for room before it is dropped (zenoh
        ``transport/link/tx/queue/congestion_control/drop/wait_before_drop``); after one such drop, later ones on
        that link and priority drop at once until the link takes a batch again. Every process of the rig.
    wait_before_close_ms : a ``"block"`` message waits at most this long, then zenoh closes the link
        (``.../block/wait_before_close``). Every process of the rig.
    tls : ZenohTls or None
        TLS / mutual TLS (``[zenoh.tls]``).
    access_control : bool
        The router enforces the access control generated from the rig (:mod:`skelfuse.config.access`).
    config : raw ``[zenoh.config]`` key paths and values, applied first.
    """

    mode: str = "peer"
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    multicast_scouting: bool = False
    reconnect_init_ms: int = 100
    reconnect_max_ms: int = 1000
    connect_timeout_ms: int = 2000
    max_message_bytes: int = 1_048_576
    fused_congestion_control: str = "drop"
    wait_before_drop_ms: int = 250
    wait_before_close_ms: int = 1000
    tls: ZenohTls | None = None
    access_control: bool = False
    config: tuple[tuple[str, Any], ...] = ()


@dataclass(frozen=True)
class ZenohTls:
    """``[zenoh.tls]``: the rig's CA and this process's certificate (``skelfuse certs`` makes them).

    Attributes
    ----------
    directory : Path or None
        Where ``skelfuse certs`` wrote ``ca.pem`` and ``<identity>.pem`` / ``<identity>.key``; each process
        picks its own identity (``fusion``, ``router``, ``capture-<host>``, ``app-<name>``).
    ca, certificate, private_key : Path or None
        Explicit files, overriding the directory's.
    mutual : bool
        Listeners require a client certificate signed by the CA (mutual TLS).
    verify_name : bool
        Clients check the listener's certificate name against the endpoint's host name.
    """

    directory: Path | None = None
    ca: Path | None = None
    certificate: Path | None = None
    private_key: Path | None = None
    mutual: bool = True
    verify_name: bool = False


@dataclass(frozen=True)
class NodeConfig:
    """``[node]``: settings shared by the rig's long-running nodes.

    Attributes
    ----------
    status_period_s : float
    name : str or None
    max_lag_s : float
        The fusion node's bound on how far it may fall behind: an instant whose first frame arrived longer ago
        than this when its turn to be fused comes is shed (counted ``shed.behind``), not fused, so a node that
        cannot keep up skips its oldest instants instead of drifting ever later.
    """

    status_period_s: float = 1.0
    name: str | None = None
    max_lag_s: float = 0.5


@dataclass(frozen=True)
class CaptureConfig:
    """``[capture]``: the capture workers (``skelfuse capture``).

    Attributes
    ----------
    stall_timeout_s : float
        The worker's watchdog: a started source that delivers no frame for this long (a tracker answering
        with nothing, a read that never returns) is restarted; a Kinect source uses it for its own
        no-capture / no-result diagnosis too.
    open_timeout_s : float
        The watchdog before the source's first answer: a source that has not opened (device open, tracker
        created; a master's wait for its subordinates included) within this long is restarted like a stalled one.
    """

    stall_timeout_s: float = 10.0
    open_timeout_s: float = 120.0


@dataclass(frozen=True)
class IntakeConfig:
    """``[intake]``: what the fusion node accepts from any peer (every cap is a counted reject, never a crash).

    Attributes
    ----------
    max_bodies_per_sensor : int
        A sensor frame with more bodies is rejected (reason ``too_many_bodies``).
    max_persons : int
        Live tracks at most (at most the fused frame's 64); bodies that would start more are not tracked
        (counted ``persons_refused``).
    max_range_mm : float
        A sensor frame with a joint farther than this from its sensor on any axis is rejected
        (``out_of_volume``): a Kinect sees about 5.5 m at most.
    max_payload_bytes : int
        Larger sensor payloads are dropped on arrival, before they are copied (``oversized``).
    max_queue : int
        Samples waiting for the node's loop at most, all keys together; beyond, the key with the most waiting
        drops its oldest (``samples_dropped``).
    max_queue_per_key : int
        Samples of one key (one sensor; every unknown key together counts as one) waiting at most; beyond,
        that key's oldest is dropped: a flooding or bursting key never pushes out another sensor's frames.
    max_queue_bytes : int
        Payload bytes waiting at most, all keys together; beyond, the key with the most bytes drops its oldest.
    """

    max_bodies_per_sensor: int = 16
    max_persons: int = 64
    max_range_mm: float = 10_000.0
    max_payload_bytes: int = 262_144
    max_queue: int = 4096
    max_queue_per_key: int = 1024
    max_queue_bytes: int = 64 * 1024 * 1024


@dataclass(frozen=True)
class RerunConfig:
    """``[rerun]``: the fusion node's live view."""

    mode: str = "off"
    bind: str = "127.0.0.1"
    grpc_port: int = 9876
    web_port: int | None = None
    file: Path | None = None
    log_sensors: bool = True


@dataclass(frozen=True)
class RecordConfig:
    """``[record]``: what ``skelfuse record`` records (``sensors``, ``fused``) and where (``directory`` None: the
    current folder). The fusion node itself never records."""

    directory: Path | None = None
    flush_period_s: float = 1.0
    sensors: bool = True
    fused: bool = True


OSC_UNITS = ("mm", "m")
"""Position units the OSC stream can send."""


@dataclass(frozen=True)
class StreamConfig:
    """``[stream]``: the stream daemon (``skelfuse stream osc|lsl|vmc``), a subscriber of the fused stream."""

    host: str = "127.0.0.1"
    osc_port: int = 9000
    osc_prefix: str = "/skelfuse"
    osc_units: str = "mm"
    vmc_port: int = 39539
    lsl_name: str = "skelfuse"
    lsl_max_persons: int = 2
    queue_size: int = 64
    drain_timeout_s: float = 1.0


@dataclass(frozen=True)
class RigConfig:
    """A whole rig configuration, validated. Build it with :func:`load_rig_config` or :meth:`from_dict`.

    Attributes
    ----------
    name : str
        ``[rig] name``: the rig's key chunk (``skelfuse/<name>/...``).
    sensors : tuple[SensorConfig, ...]
    sync, calibration, fusion, zenoh, node, capture, rerun, record, stream : the sections
    source : str
        Where this config came from (a file path, or "<dict>"), for messages.
    """

    name: str
    sensors: tuple[SensorConfig, ...]
    sync: SyncConfig = field(default_factory=SyncConfig)
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    depth: DepthConfig = field(default_factory=DepthConfig)
    zenoh: ZenohSection = field(default_factory=ZenohSection)
    node: NodeConfig = field(default_factory=NodeConfig)
    capture: CaptureConfig = field(default_factory=CaptureConfig)
    intake: IntakeConfig = field(default_factory=IntakeConfig)
    rerun: RerunConfig = field(default_factory=RerunConfig)
    record: RecordConfig = field(default_factory=RecordConfig)
    stream: StreamConfig = field(default_factory=StreamConfig)
    source: str = "<dict>"

    @property
    def sensor_ids(self) -> tuple[str, ...]:
        return tuple(s.id for s in self.sensors)

    def sensor(self, sensor_id: str) -> SensorConfig:
        """The sensor named ``sensor_id``; ConfigError (with a suggestion) if the rig has none."""
        for s in self.sensors:
            if s.id == sensor_id:
                return s
        raise ConfigError(
            f"{self.source}: rig {self.name!r} has no sensor {sensor_id!r}"
            f"{did_you_mean(sensor_id, self.sensor_ids)}; its sensors: {', '.join(self.sensor_ids)}"
        )

    def poses(self, *, required: bool = True) -> dict[str, np.ndarray]:
        """``world_from_sensor`` (4x4 float64) per sensor id.

        A pose from the calibration file (``[calibration] file``) wins over the sensor's inline
        ``world_from_sensor`` (for sim sensors the inline pose is the true one; a calibration is a
        measurement of it). :meth:`pose_sources` says which sensor's pose came from where.

        Parameters
        ----------
        required : bool
            Fusion needs a pose for every sensor from where the config says: then a ``[calibration] file``
            that does not exist is an error (never a silent fall back to the inline poses). Without
            ``required`` (a recorder, before the rig is calibrated) a missing file leaves the inline poses.

        Raises
        ------
        ConfigError
            ``required`` and a sensor has no pose or the calibration file does not exist; the calibration
            file is malformed or names none of the rig's sensors.
        """
        return {sid: pose for sid, (pose, _) in self._resolve_poses(required).items()}

    def pose_sources(self) -> dict[str, str]:
        """Where each sensor's pose comes from: ``"calibration file <path>"``, ``"inline world_from_sensor"``,
        or ``"none"`` (for start-up messages; never raises for a missing pose or file)."""
        resolved = self._resolve_poses(required=False)
        return {sid: resolved[sid][1] if sid in resolved else "none" for sid in self.sensor_ids}

    def describe_poses(self) -> str:
        """One line: which sensors take their pose from where (``pose_sources`` grouped)."""
        groups: dict[str, list[str]] = {}
        for sid, where in self.pose_sources().items():
            groups.setdefault(where, []).append(sid)
        return "; ".join(f"{where}: {', '.join(ids)}" for where, ids in groups.items())

    def _resolve_poses(self, required: bool) -> dict[str, tuple[np.ndarray, str]]:
        calibrated: dict[str, np.ndarray] = {}
        calibration_note = ""
        file = self.calibration.file
        if file is not None:
            if file.exists():
                calibrated = load_calibration(file)
                unknown = sorted(set(calibrated) - set(self.sensor_ids))
                if unknown and len(unknown) == len(calibrated):
                    raise ConfigError(
                        f"{self.source}: [calibration] file {file} holds poses of {', '.join(unknown)}, none of "
                        f"which is a sensor of rig {self.name!r} ({', '.join(self.sensor_ids)}); point [calibration] "
                        "file at this rig's calibration, or calibrate it with `skelfuse calibrate ...`"
                    )
            elif required:
                raise ConfigError(
                    f"{self.source}: [calibration] file {file} does not exist; calibrate the rig first "
                    "(`skelfuse calibrate skeleton ...` or `calibrate sphere` / `marker`, docs/calibration.md), "
                    "or remove the key to use the sensors' inline world_from_sensor"
                )
            else:
                calibration_note = f" (calibration file {file} does not exist yet)"
        poses: dict[str, tuple[np.ndarray, str]] = {}
        for s in self.sensors:
            pose = calibrated.get(s.id)
            if pose is not None:
                poses[s.id] = (pose, f"calibration file {file}")
            elif (inline := s.pose()) is not None:
                poses[s.id] = (inline, "inline world_from_sensor")
        missing = [s for s in self.sensor_ids if s not in poses]
        if required and missing:
            raise ConfigError(
                f"{self.source}: no pose for sensor(s) {', '.join(missing)}{calibration_note}; {CALIBRATE_HINT}"
            )
        return poses
