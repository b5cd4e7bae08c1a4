"""The rig configuration: one typed, frozen :class:`RigConfig`, validated when it is loaded.

A rig config is a TOML file (see ``docs/configuration.md`` for every option, and ``config/rig-*.toml`` for
examples). It describes one installation: its name, its sensors (where frames come from and where each
sensor stands), how frames of one instant are grouped, how they are fused, how nodes talk over zenoh, and
what the fusion node shows and records. Every node of the rig (capture workers, fusion node) reads the same
file, so they agree on names and keys.

Cycle::

    load_rig_config(path)          TOML -> dict (tomllib)
      RigConfig.from_dict(...)     dict -> frozen dataclasses; every key checked (type, range, unknown keys)
    cfg.poses()                    world_from_sensor per sensor (calibration file, else inline poses)
    cfg.fusion.params()            skelfuse.fusion.presets.FusionParams (preset + overrides)
    zenoh_config(cfg, overrides)   zenoh.Config: file < flags < ``--zenoh-cfg KEY:VALUE``

Conventions: units are in the names (``tolerance_ms``, ``delay_us``, ``eps_mm``); ``None`` means "off" or
"not set" and is written in TOML by leaving the key out (never ``-1``). Relative paths are resolved against
the directory of the config file. Every problem raises :class:`skelfuse.schema.errors.ConfigError` naming the
file, the key path (``sensors[2].sync.delay_us``), what was expected and what was found, with a "did you
mean" for a misspelt key.
"""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import json
import math
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from skelfuse.schema.errors import ConfigError
from skelfuse.wire.keys import validate_name

if TYPE_CHECKING:  # pragma: no cover - typing only
    import zenoh

    from skelfuse.fusion.presets import FusionParams

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
RERUN_MODES: tuple[str, ...] = ("off", "spawn", "serve", "save")
DEFAULT_PRESET = "skelfuse"
"""The fusion preset of a rig config without ``[fusion] preset``, and of the demo and offline fusion."""
FUSION_PRESETS: tuple[str, ...] = ("skelfuse", "A1", "A2", "A3", "A4", "A5")
"""Accepted ``[fusion] preset`` names (case-insensitive), as :func:`skelfuse.fusion.presets.preset` knows them."""

MIN_DELAY_SPACING_US = 160
"""Subordinate depth delays must be at least this far apart (and from the master's 0) to avoid IR interference."""

_CALIBRATE_HINT = (
    "fusion needs a pose for every sensor: either set sensors[i].world_from_sensor, or point "
    "[calibration] file at a calibration made with `skelfuse calibrate ...`"
)


# ----------------------------------------------------------------------------------------------------------
# Sections
# ----------------------------------------------------------------------------------------------------------


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
    """

    by: str = "device"
    fps: float = 30.0
    tolerance_ms: float = 10.0
    deadline_ms: float = 17.0
    resync_after_frames: int = 8
    resync_horizon_ms: float = 1000.0

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
    """

    id: str
    source: str
    world_from_sensor: tuple[tuple[float, ...], ...] | None = None
    sync: SensorSyncConfig = field(default_factory=SensorSyncConfig)
    kinect: KinectConfig | None = None
    replay: ReplayConfig | None = None
    sim: SimConfig | None = None

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

    def fusion_params(self) -> FusionParams:
        """The :class:`skelfuse.fusion.presets.FusionParams` this section describes.

        Raises
        ------
        ConfigError
            An override is rejected by FusionParams' own validation.
        """
        from skelfuse.fusion import presets

        try:
            base = presets.preset(self.preset, self.eps_mm)
            return dataclasses.replace(base, **dict(self.params))
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"[fusion]: {exc}") from None


@dataclass(frozen=True)
class ZenohSection:
    """``[zenoh]``: session settings for every node of the rig (see :func:`zenoh_config`)."""

    mode: str = "peer"
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    multicast_scouting: bool = True
    config: tuple[tuple[str, Any], ...] = ()


@dataclass(frozen=True)
class NodeConfig:
    """``[node]``: settings shared by the rig's long-running nodes."""

    status_period_s: float = 1.0
    name: str | None = None


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
    """``[record]``: recording of the streams by the fusion node (``directory`` None: off)."""

    directory: Path | None = None
    flush_period_s: float = 1.0
    sensors: bool = True
    fused: bool = True


@dataclass(frozen=True)
class RigConfig:
    """A whole rig configuration, validated. Build it with :func:`load_rig_config` or :meth:`from_dict`.

    Attributes
    ----------
    name : str
        ``[rig] name``: the rig's key chunk (``skelfuse/<name>/...``).
    sensors : tuple[SensorConfig, ...]
    sync, calibration, fusion, zenoh, node, rerun, record : the sections
    source : str
        Where this config came from (a file path, or "<dict>"), for messages.
    """

    name: str
    sensors: tuple[SensorConfig, ...]
    sync: SyncConfig = field(default_factory=SyncConfig)
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    zenoh: ZenohSection = field(default_factory=ZenohSection)
    node: NodeConfig = field(default_factory=NodeConfig)
    rerun: RerunConfig = field(default_factory=RerunConfig)
    record: RecordConfig = field(default_factory=RecordConfig)
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
            f"{_did_you_mean(sensor_id, self.sensor_ids)}; its sensors: {', '.join(self.sensor_ids)}"
        )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, source: str = "<dict>", base_dir: Path | None = None) -> RigConfig:
        """Validate a parsed TOML document.

        Parameters
        ----------
        data : mapping
            What ``tomllib.load`` returned.
        source : str
            Named in error messages (the file path).
        base_dir : Path, optional
            Relative paths are resolved against it; None leaves them as written.
        """
        return _parse_rig(data, source, base_dir)

    def poses(self, *, required: bool = True) -> dict[str, np.ndarray]:
        """``world_from_sensor`` (4x4 float64) per sensor id.

        A pose from the calibration file (when ``[calibration] file`` is set and exists) wins over the
        sensor's inline ``world_from_sensor`` (for sim sensors the inline pose is the true one; a
        calibration is a measurement of it).

        Raises
        ------
        ConfigError
            ``required`` and a sensor has no pose; or the calibration file is malformed.
        """
        calibrated: dict[str, np.ndarray] = {}
        calibration_note = ""
        if self.calibration.file is not None:
            if self.calibration.file.exists():
                calibrated = load_calibration(self.calibration.file)
            else:
                calibration_note = f" (calibration file {self.calibration.file} does not exist yet)"
        poses: dict[str, np.ndarray] = {}
        for s in self.sensors:
            pose = calibrated.get(s.id)
            if pose is None:
                pose = s.pose()
            if pose is not None:
                poses[s.id] = pose
        missing = [s for s in self.sensor_ids if s not in poses]
        if required and missing:
            raise ConfigError(
                f"{self.source}: no pose for sensor(s) {', '.join(missing)}{calibration_note}; {_CALIBRATE_HINT}"
            )
        return poses


# ----------------------------------------------------------------------------------------------------------
# Loading
# ----------------------------------------------------------------------------------------------------------


def load_rig_config(path: str | Path) -> RigConfig:
    """Read and validate a rig config TOML file (relative paths inside resolve against its directory).

    Raises
    ------
    ConfigError
        The file cannot be read, is not TOML, or any key is unknown, missing, mistyped or out of range.
    """
    path = Path(path)
    try:
        with path.open("rb") as handle:
            data = tomllib.load(handle)
    except FileNotFoundError:
        raise ConfigError(f"rig config {path} does not exist; see config/rig-sim-4.toml for an example") from None
    except OSError as exc:
        raise ConfigError(f"cannot read rig config {path}: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"rig config {path} is not valid TOML: {exc}") from None
    return RigConfig.from_dict(data, source=str(path), base_dir=path.parent)


def load_calibration(path: str | Path) -> dict[str, np.ndarray]:
    """Read a calibration TOML file: ``[sensors.<id>] world_from_sensor = [[4 x 4]]``.

    Other keys (at the top level, or beside ``world_from_sensor``) are metadata written by the calibration
    tool (method, residuals, date) and are ignored here.

    Raises
    ------
    ConfigError
        Unreadable, not TOML, no ``[sensors]`` table, or a pose that is not a rigid 4x4 transform.
    """
    path = Path(path)
    try:
        with path.open("rb") as handle:
            data = tomllib.load(handle)
    except OSError as exc:
        raise ConfigError(f"cannot read calibration {path}: {exc}; {_CALIBRATE_HINT}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"calibration {path} is not valid TOML: {exc}") from None
    sensors = data.get("sensors")
    if not isinstance(sensors, dict) or not sensors:
        raise ConfigError(
            f"{path}: key sensors: expected a table [sensors.<id>] with world_from_sensor per "
            f"sensor, found {_describe(sensors)}"
        )
    poses = {}
    for sensor_id, table in sensors.items():
        where = f"sensors.{sensor_id}"
        if not isinstance(table, dict) or "world_from_sensor" not in table:
            raise ConfigError(
                f"{path}: key {where}: expected a table with world_from_sensor (4x4), found {_describe(table)}"
            )
        poses[sensor_id] = np.array(_rigid_4x4(table["world_from_sensor"], f"{where}.world_from_sensor", str(path)))
    return poses


# ----------------------------------------------------------------------------------------------------------
# zenoh
# ----------------------------------------------------------------------------------------------------------

_ZENOH_DEDICATED = {
    "mode": "mode",
    "connect/endpoints": "connect",
    "listen/endpoints": "listen",
    "scouting/multicast/enabled": "multicast_scouting",
}


def zenoh_config(
    cfg: RigConfig,
    overrides: Sequence[str] = (),
    *,
    mode: str | None = None,
    connect: Sequence[str] | None = None,
    listen: Sequence[str] | None = None,
    multicast_scouting: bool | None = None,
) -> zenoh.Config:
    """The zenoh session config of a node: file < flags < ``--zenoh-cfg KEY:VALUE`` overrides.

    Order of application (later wins), as in zenoh-python's ``examples/common/common.py``:

    1. ``[zenoh.config]`` raw keys of the file, then ``[zenoh]`` mode / connect / listen /
       multicast_scouting (validation forbids a raw key that duplicates one of those);
    2. the keyword flags (None: not given on the command line);
    3. ``overrides``: ``"KEY:VALUE"`` strings, KEY a zenoh config path (``transport/unicast/max_links``),
       VALUE JSON5 (``2``, ``'"client"'``, ``'["tcp/10.0.0.2:7447"]'``). Split at the first ``:`` only, so
       endpoint values keep theirs.

    Raises
    ------
    ConfigError
        A malformed override or a key / value zenoh rejects (the message names which).
    """
    import zenoh

    conf = zenoh.Config()

    def insert(key: str, value_json5: str, origin: str) -> None:
        try:
            conf.insert_json5(key, value_json5)
        except Exception as exc:  # zenoh raises its own ZError
            raise ConfigError(
                f"{origin}: zenoh rejected {key} = {value_json5}: {exc}; check the key path and "
                f"value type against zenoh's DEFAULT_CONFIG.json5"
            ) from None

    for key, value in cfg.zenoh.config:
        insert(key, json.dumps(value), f'{cfg.source}: zenoh.config."{key}"')
    z = cfg.zenoh
    insert("mode", json.dumps(z.mode), f"{cfg.source}: zenoh.mode")
    if z.connect:
        insert("connect/endpoints", json.dumps(list(z.connect)), f"{cfg.source}: zenoh.connect")
    if z.listen:
        insert("listen/endpoints", json.dumps(list(z.listen)), f"{cfg.source}: zenoh.listen")
    insert("scouting/multicast/enabled", json.dumps(z.multicast_scouting), f"{cfg.source}: zenoh.multicast_scouting")

    if mode is not None:
        if mode not in ZENOH_MODES:
            raise ConfigError(f"--zenoh-mode: expected one of {', '.join(ZENOH_MODES)}, found {mode!r}")
        insert("mode", json.dumps(mode), "--zenoh-mode")
    if connect is not None:
        insert("connect/endpoints", json.dumps(list(connect)), "--zenoh-connect")
    if listen is not None:
        insert("listen/endpoints", json.dumps(list(listen)), "--zenoh-listen")
    if multicast_scouting is not None:
        insert("scouting/multicast/enabled", json.dumps(bool(multicast_scouting)), "--no-multicast-scouting")

    for item in overrides:
        key, sep, value = str(item).partition(":")
        if not sep or not key.strip() or not value.strip():
            raise ConfigError(f"--zenoh-cfg: expected KEY:VALUE (e.g. 'transport/unicast/max_links:2'), found {item!r}")
        insert(key.strip(), value.strip(), f"--zenoh-cfg {item!r}")
    return conf


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the zenoh flags every long-running command shares (read back by :func:`zenoh_flags`)."""
    group = parser.add_argument_group("zenoh (override the config file's [zenoh])")
    group.add_argument("--zenoh-mode", choices=ZENOH_MODES, default=None, help="session mode")
    group.add_argument(
        "--zenoh-connect",
        metavar="ENDPOINT",
        action="append",
        default=None,
        help="endpoint to connect to (repeatable), e.g. tcp/10.0.0.2:7447",
    )
    group.add_argument(
        "--zenoh-listen", metavar="ENDPOINT", action="append", default=None, help="endpoint to listen on (repeatable)"
    )
    group.add_argument(
        "--no-multicast-scouting",
        action="store_true",
        default=False,
        help="disable multicast scouting (recommended with explicit endpoints)",
    )
    group.add_argument(
        "--zenoh-cfg",
        metavar="KEY:VALUE",
        action="append",
        default=[],
        help="raw zenoh config change, VALUE in JSON5, e.g. 'transport/unicast/max_links:2' (applied last)",
    )


def zenoh_flags(args: argparse.Namespace) -> dict[str, Any]:
    """Keyword arguments of :func:`zenoh_config` from flags added by :func:`add_zenoh_arguments`."""
    return {
        "overrides": tuple(args.zenoh_cfg or ()),
        "mode": args.zenoh_mode,
        "connect": args.zenoh_connect,
        "listen": args.zenoh_listen,
        "multicast_scouting": False if args.no_multicast_scouting else None,
    }


# ----------------------------------------------------------------------------------------------------------
# Validation machinery
# ----------------------------------------------------------------------------------------------------------

_REQUIRED = object()


def _describe(value: Any) -> str:
    if value is None:
        return "nothing"
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{text} ({type(value).__name__})"


def _did_you_mean(word: str, candidates: Sequence[str]) -> str:
    by_lower = {c.lower(): c for c in candidates}
    close = difflib.get_close_matches(word.lower(), list(by_lower), n=1, cutoff=0.6)
    return f"; did you mean {by_lower[close[0]]!r}?" if close else ""


class _Table:
    """One TOML table being read: remembers which keys were consumed so leftovers are reported."""

    def __init__(self, data: Any, path: str, source: str, base_dir: Path | None) -> None:
        self.path, self.source, self.base_dir = path, source, base_dir
        if not isinstance(data, dict):
            raise self.error(path or "<top level>", "a table", data)
        self.data: dict[str, Any] = data
        self.used: set[str] = set()

    def key(self, name: str) -> str:
        return f"{self.path}.{name}" if self.path else name

    def error(self, key: str, expected: str, found: Any, hint: str = "") -> ConfigError:
        return ConfigError(f"{self.source}: key {key}: expected {expected}, found {_describe(found)}{hint}")

    def raw(self, name: str, default: Any, expected: str) -> Any:
        self.used.add(name)
        if name in self.data:
            return self.data[name]
        if default is _REQUIRED:
            raise ConfigError(f"{self.source}: key {self.key(name)} is required ({expected}) but missing")
        return default

    def string(
        self,
        name: str,
        default: Any = _REQUIRED,
        *,
        choices: Sequence[str] | None = None,
        check: Callable[[str], str] | None = None,
    ) -> Any:
        expected = f"one of {', '.join(repr(c) for c in choices)}" if choices else "a string"
        value = self.raw(name, default, expected)
        if value is default and name not in self.data:
            return value
        if not isinstance(value, str):
            raise self.error(self.key(name), expected, value)
        if choices is not None and value not in choices:
            raise self.error(self.key(name), expected, value, _did_you_mean(value, choices))
        if check is not None:
            try:
                check(value)
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"{self.source}: key {self.key(name)}: {exc}") from None
        return value

    def integer(
        self, name: str, default: Any = _REQUIRED, *, lo: int | None = None, hi: int | None = None, unit: str = ""
    ) -> Any:
        expected = _range_text("an integer", lo, hi, unit)
        value = self.raw(name, default, expected)
        if value is default and name not in self.data:
            return value
        if (
            isinstance(value, bool)
            or not isinstance(value, int)
            or (lo is not None and value < lo)
            or (hi is not None and value > hi)
        ):
            raise self.error(self.key(name), expected, value)
        return value

    def number(
        self,
        name: str,
        default: Any = _REQUIRED,
        *,
        lo: float | None = None,
        hi: float | None = None,
        lo_open: bool = False,
        unit: str = "",
    ) -> Any:
        expected = _range_text("a number", lo, hi, unit, lo_open=lo_open)
        value = self.raw(name, default, expected)
        if value is default and name not in self.data:
            return value
        ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
        if ok and lo is not None:
            ok = value > lo if lo_open else value >= lo
        if ok and hi is not None:
            ok = value <= hi
        if not ok:
            raise self.error(self.key(name), expected, value)
        return float(value)

    def boolean(self, name: str, default: Any = _REQUIRED) -> Any:
        value = self.raw(name, default, "true or false")
        if not isinstance(value, bool):
            raise self.error(self.key(name), "true or false", value)
        return value

    def strings(self, name: str, default: Any = _REQUIRED) -> Any:
        value = self.raw(name, default, "a list of strings")
        if value is default and name not in self.data:
            return value
        if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
            raise self.error(self.key(name), "a list of non-empty strings", value)
        return tuple(value)

    def path_value(self, name: str, default: Any = _REQUIRED) -> Any:
        value = self.string(name, default)
        if value is default and name not in self.data:
            return value
        if not value.strip():
            raise self.error(self.key(name), "a non-empty path", value)
        path = Path(value).expanduser()
        if not path.is_absolute() and self.base_dir is not None:
            path = self.base_dir / path
        return path

    def table(self, name: str, *, required: bool = False) -> _Table | None:
        self.used.add(name)
        if name not in self.data:
            if required:
                raise ConfigError(f"{self.source}: table [{self.key(name)}] is required but missing")
            return None
        return _Table(self.data[name], self.key(name), self.source, self.base_dir)

    def done(self) -> None:
        """Raise on the first key nobody asked for."""
        for name in self.data:
            if name not in self.used:
                known = sorted(self.used)
                where = f"[{self.path}]" if self.path else "the top level"
                raise ConfigError(
                    f"{self.source}: unknown key {self.key(name)}{_did_you_mean(name, known)}; "
                    f"keys allowed in {where}: {', '.join(known)}"
                )


def _range_text(what: str, lo: float | None, hi: float | None, unit: str, *, lo_open: bool = False) -> str:
    unit = f" {unit}" if unit else ""
    if lo is not None and hi is not None:
        return f"{what} in {'(' if lo_open else '['}{lo:g}, {hi:g}]{unit}"
    if lo is not None:
        return f"{what} {'>' if lo_open else '>='} {lo:g}{unit}"
    if hi is not None:
        return f"{what} <= {hi:g}{unit}"
    return what + unit


def _rigid_4x4(value: Any, key: str, source: str) -> tuple[tuple[float, ...], ...]:
    expected = "a 4x4 list of numbers (rigid transform: rotation, translation in mm, last row 0 0 0 1)"
    if not (
        isinstance(value, list)
        and len(value) == 4
        and all(isinstance(r, list) and len(r) == 4 for r in value)
        and all(isinstance(v, int | float) and not isinstance(v, bool) for r in value for v in r)
    ):
        raise ConfigError(f"{source}: key {key}: expected {expected}, found {_describe(value)}")
    matrix = np.array(value, dtype=np.float64)
    if not np.isfinite(matrix).all():
        raise ConfigError(f"{source}: key {key}: expected finite numbers, found NaN or inf")
    if not np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise ConfigError(f"{source}: key {key}: expected last row [0, 0, 0, 1], found {matrix[3].tolist()}")
    rotation = matrix[:3, :3]
    error = float(np.abs(rotation @ rotation.T - np.eye(3)).max())
    if error > 1e-4 or np.linalg.det(rotation) < 0:
        raise ConfigError(
            f"{source}: key {key}: expected a rotation in the upper-left 3x3 (orthonormal, det +1, "
            f"to 1e-4), found max |R R^T - I| = {error:.3g}, det = {np.linalg.det(rotation):.4f}; "
            f"write at least 6 decimals, or re-run `skelfuse calibrate ...`"
        )
    return tuple(tuple(float(v) for v in row) for row in value)


# ----------------------------------------------------------------------------------------------------------
# Sections
# ----------------------------------------------------------------------------------------------------------


def _parse_rig(data: Mapping[str, Any], source: str, base_dir: Path | None) -> RigConfig:
    top = _Table(dict(data), "", source, base_dir)

    rig = top.table("rig", required=True)
    assert rig is not None
    name = rig.string("name", check=lambda v: validate_name(v, "rig"))
    rig.done()

    sync = _parse_sync(top.table("sync"))
    sensors = _parse_sensors(top, source, base_dir)
    calibration = CalibrationConfig()
    if (t := top.table("calibration")) is not None:
        calibration = CalibrationConfig(file=t.path_value("file", None))
        t.done()
    fusion = _parse_fusion(top.table("fusion"))
    zenoh = _parse_zenoh(top.table("zenoh"))
    node = NodeConfig()
    if (t := top.table("node")) is not None:
        node = NodeConfig(
            status_period_s=t.number("status_period_s", 1.0, lo=0.0, lo_open=True, hi=3600.0, unit="s"),
            name=t.string("name", None, check=lambda v: validate_name(v, "node")),
        )
        t.done()
    rerun = _parse_rerun(top.table("rerun"))
    record = RecordConfig()
    if (t := top.table("record")) is not None:
        record = RecordConfig(
            directory=t.path_value("directory", None),
            flush_period_s=t.number("flush_period_s", 1.0, lo=0.0, lo_open=True, hi=3600.0, unit="s"),
            sensors=t.boolean("sensors", True),
            fused=t.boolean("fused", True),
        )
        t.done()
    top.done()

    _check_rig(sensors, sync, source)
    return RigConfig(
        name=name,
        sensors=sensors,
        sync=sync,
        calibration=calibration,
        fusion=fusion,
        zenoh=zenoh,
        node=node,
        rerun=rerun,
        record=record,
        source=source,
    )


def _parse_sync(t: _Table | None) -> SyncConfig:
    if t is None:
        return SyncConfig()
    fps = t.number("fps", 30.0, lo=0.0, lo_open=True, hi=1000.0, unit="Hz")
    half_period_ms = 500.0 / fps
    by = t.string("by", "device", choices=SYNC_BY)
    # Device clocks of a synced rig agree to the subordinate delays (< 1 ms): a third of a frame is plenty.
    # Host receive times carry per-sensor latency offsets and USB jitter of a few ms each: 0.4 of a frame.
    default_tolerance_ms = min(10.0, 0.3 * 2 * half_period_ms) if by == "device" else 0.4 * 2 * half_period_ms
    sync = SyncConfig(
        by=by,
        fps=fps,
        # Above half a frame period, consecutive instants would fall into one group.
        tolerance_ms=t.number(
            "tolerance_ms",
            default_tolerance_ms,
            lo=0.0,
            lo_open=True,
            hi=round(half_period_ms, 3) - 0.001,
            unit="ms (below half a frame period)",
        ),
        deadline_ms=t.number("deadline_ms", max(17.0, half_period_ms), lo=0.0, lo_open=True, hi=10_000.0, unit="ms"),
        resync_after_frames=t.integer("resync_after_frames", 8, lo=1, hi=10_000),
        resync_horizon_ms=t.number("resync_horizon_ms", 1000.0, lo=0.0, lo_open=True, hi=3_600_000.0, unit="ms"),
    )
    if sync.resync_horizon_ms <= sync.tolerance_ms:
        raise t.error(
            t.key("resync_horizon_ms"), f"a number > tolerance_ms ({sync.tolerance_ms:g})", sync.resync_horizon_ms
        )
    t.done()
    return sync


def _parse_sensors(top: _Table, source: str, base_dir: Path | None) -> tuple[SensorConfig, ...]:
    raw = top.raw("sensors", _REQUIRED, "an array of tables [[sensors]]")
    if not isinstance(raw, list) or not raw:
        raise top.error("sensors", "at least one [[sensors]] table", raw)
    sensors = []
    for idx, item in enumerate(raw):
        t = _Table(item, f"sensors[{idx}]", source, base_dir)
        sensor_id = t.string("id", check=lambda v: validate_name(v, "sensor"))
        kind = t.string("source", choices=SOURCE_KINDS)
        pose = None
        if "world_from_sensor" in t.data:
            pose = _rigid_4x4(t.raw("world_from_sensor", None, ""), t.key("world_from_sensor"), source)
        sync = SensorSyncConfig()
        if (s := t.table("sync")) is not None:
            role = s.string("role", "standalone", choices=SYNC_ROLES)
            if role == "subordinate":
                delay = s.integer("delay_us", lo=MIN_DELAY_SPACING_US, hi=1_000_000, unit="µs")
            else:
                delay = s.integer("delay_us", 0, lo=0, hi=0, unit=f"µs (only subordinates have a delay; {role})")
            sync = SensorSyncConfig(role=role, delay_us=delay)
            s.done()
        options: dict[str, Any] = {}
        for other in SOURCE_KINDS:
            if other != kind and other in t.data:
                raise ConfigError(
                    f"{source}: key {t.key(other)}: a [{t.key(other)}] table belongs to source = "
                    f"{other!r} sensors, but this sensor has source = {kind!r}"
                )
        if kind == "kinect":
            options["kinect"] = _parse_kinect(t.table("kinect"), t, sensor_id)
        elif kind == "replay":
            r = t.table("replay", required=True)
            assert r is not None
            options["replay"] = ReplayConfig(
                file=r.path_value("file"), sensor=r.string("sensor", None), loop=r.boolean("loop", False)
            )
            r.done()
        else:
            s_t = t.table("sim")
            sim = SimConfig()
            if s_t is not None:
                sim = SimConfig(profile=s_t.path_value("profile", None), seed=s_t.integer("seed", None, lo=0))
                s_t.done()
            options["sim"] = sim
        for name in ("tracker",):
            if name in t.data:
                raise ConfigError(
                    f"{source}: unknown key {t.key(name)}; did you mean {t.key('kinect.' + name)}? "
                    "(tracker settings live under [sensors.kinect.tracker])"
                )
        t.done()
        sensors.append(SensorConfig(id=sensor_id, source=kind, world_from_sensor=pose, sync=sync, **options))
    ids = [s.id for s in sensors]
    for idx, sensor_id in enumerate(ids):
        if sensor_id in ids[:idx]:
            raise ConfigError(
                f"{source}: key sensors[{idx}].id: expected a sensor id not used before, found "
                f"{sensor_id!r} again (also sensors[{ids.index(sensor_id)}].id)"
            )
    return tuple(sensors)


def _parse_kinect(t: _Table | None, sensor: _Table, sensor_id: str) -> KinectConfig:
    if t is None:
        return KinectConfig(serial=sensor_id)
    kinect = KinectConfig(
        serial=t.string("serial", sensor_id),
        depth_mode=t.string("depth_mode", "NFOV_UNBINNED", choices=DEPTH_MODES),
        color_resolution=t.string("color_resolution", None, choices=COLOR_RESOLUTIONS),
        tracker=_parse_tracker(t.table("tracker")),
    )
    t.done()
    return kinect


def _parse_tracker(t: _Table | None) -> TrackerConfig:
    if t is None:
        return TrackerConfig()
    tracker = TrackerConfig(
        processing_mode=t.string("processing_mode", "gpu", choices=PROCESSING_MODES),
        gpu_device_id=t.integer("gpu_device_id", 0, lo=0, hi=255),
        model_path=t.path_value("model_path", None),
        sensor_orientation=t.string("sensor_orientation", "default", choices=SENSOR_ORIENTATIONS),
        temporal_smoothing=t.number("temporal_smoothing", 0.0, lo=0.0, hi=1.0),
    )
    t.done()
    return tracker


def _check_rig(sensors: tuple[SensorConfig, ...], sync: SyncConfig, source: str) -> None:
    """Rules across sensors: one master, distinct delays >= 160 µs apart, fps and modes the devices support."""
    roles = [(i, s) for i, s in enumerate(sensors) if s.sync.role != "standalone"]
    masters = [i for i, s in roles if s.sync.role == "master"]
    subordinates = [(i, s) for i, s in roles if s.sync.role == "subordinate"]
    if len(masters) > 1:
        raise ConfigError(
            f"{source}: key sensors[{masters[1]}].sync.role: expected one master per sync chain, "
            f"found a second master (sensors[{masters[0]}] is one already)"
        )
    if subordinates and not masters:
        raise ConfigError(
            f"{source}: key sensors[{subordinates[0][0]}].sync.role: a subordinate needs a master "
            f'in the rig, found none; set sync.role = "master" on the sensor at the head of the chain'
        )
    taken: list[tuple[int, str]] = [(0, f"sensors[{masters[0]}] (master)")] if masters else []
    for i, s in subordinates:
        for delay, owner in taken:
            if abs(s.sync.delay_us - delay) < MIN_DELAY_SPACING_US:
                raise ConfigError(
                    f"{source}: key sensors[{i}].sync.delay_us: expected a delay at least {MIN_DELAY_SPACING_US} µs "
                    f"away from every other sensor's (IR interference), found {s.sync.delay_us} µs, "
                    f"{abs(s.sync.delay_us - delay)} µs from {owner} at {delay} µs"
                )
        taken.append((s.sync.delay_us, f"sensors[{i}]"))
    if sync.by == "device" and subordinates:
        spread = max(s.sync.delay_us for _, s in subordinates)
        if spread >= sync.tolerance_us:
            raise ConfigError(
                f"{source}: key sync.tolerance_ms: expected more than the largest subordinate delay "
                f"({spread} µs) so a master's and its subordinates' frames group together, found "
                f"{sync.tolerance_ms:g} ms"
            )
    kinects = [(i, s) for i, s in enumerate(sensors) if s.kinect is not None]
    if kinects and not any(abs(sync.fps - f) < 1e-9 for f in KINECT_FPS):
        raise ConfigError(
            f"{source}: key sync.fps: expected one of {KINECT_FPS} for an Azure Kinect rig, found {sync.fps:g}"
        )
    for i, s in kinects:
        assert s.kinect is not None
        if sync.fps > 15 and s.kinect.depth_mode == "WFOV_UNBINNED":
            raise ConfigError(
                f"{source}: key sensors[{i}].kinect.depth_mode: WFOV_UNBINNED runs at 15 fps at most, "
                f"found sync.fps = {sync.fps:g}; use WFOV_2X2BINNED or NFOV_UNBINNED, or fps 15"
            )
        if sync.fps > 15 and s.kinect.color_resolution == "3072P":
            raise ConfigError(
                f"{source}: key sensors[{i}].kinect.color_resolution: 3072P runs at 15 fps at most, "
                f"found sync.fps = {sync.fps:g}"
            )
    if sync.by == "device" and len(kinects) > 1:
        unsynced = [i for i, s in kinects if s.sync.role == "standalone"]
        if unsynced:
            raise ConfigError(
                f'{source}: key sensors[{unsynced[0]}].sync.role: [sync] by = "device" needs every kinect on one '
                f'wired sync chain (independent devices\' clocks do not share an epoch), found "standalone"; '
                f'set master/subordinate roles, or use [sync] by = "host"'
            )
    serials = [(i, s.kinect.serial) for i, s in kinects if s.kinect is not None]
    for n, (i, serial) in enumerate(serials):
        earlier = [j for j, other in serials[:n] if other == serial]
        if earlier:
            raise ConfigError(
                f"{source}: key sensors[{i}].kinect.serial: expected a serial not used before, "
                f"found {serial!r} again (also sensors[{earlier[0]}])"
            )


def _parse_fusion(t: _Table | None) -> FusionConfig:
    if t is None:
        return FusionConfig()
    preset = t.string("preset", DEFAULT_PRESET)
    try:
        from skelfuse.fusion import presets as presets_module
    except ImportError:  # the fusion core is optional at config time
        presets_module = None  # type: ignore[assignment]
    canonical = {name.upper(): name for name in FUSION_PRESETS}
    if preset.strip().upper() not in canonical:
        raise t.error(
            t.key("preset"),
            f"one of {', '.join(FUSION_PRESETS)}",
            preset,
            _did_you_mean(preset.strip(), FUSION_PRESETS),
        )
    preset = canonical[preset.strip().upper()]
    eps_mm = t.number("eps_mm", None, lo=0.0, lo_open=True, hi=10_000.0, unit="mm")
    params: dict[str, Any] = {}
    p = t.table("params")
    if p is not None:
        fields = {} if presets_module is None else {f.name: f for f in dataclasses.fields(presets_module.FusionParams)}
        for name, value in p.data.items():
            p.used.add(name)
            key = p.key(name)
            if name == "eps_mm":
                raise ConfigError(
                    f"{p.source}: key {key}: set the DBSCAN radius with fusion.eps_mm, not in [fusion.params]"
                )
            if fields and name not in fields:
                raise ConfigError(
                    f"{p.source}: unknown key {key}{_did_you_mean(name, list(fields))}; "
                    f"[fusion.params] takes FusionParams fields: {', '.join(sorted(fields))}"
                )
            params[name] = _fusion_value(value, fields.get(name), key, p.source)
        p.done()
    fusion = FusionConfig(preset=preset, eps_mm=eps_mm, params=tuple(sorted(params.items())))
    if presets_module is not None:
        try:  # FusionParams' own range checks, reported at load time
            dataclasses.replace(presets_module.preset(fusion.preset, eps_mm), **params)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{t.source}: key {t.key('params')}: {exc}") from None
    t.done()
    return fusion


def _fusion_value(value: Any, f: dataclasses.Field[Any] | None, key: str, source: str) -> Any:
    """Check a [fusion.params] value against the field's annotation; "off" means None for optional fields."""
    if f is None:
        return value
    annotation = str(f.type)
    optional = "None" in annotation
    if value == "off":
        if not optional:
            raise ConfigError(f"{source}: key {key}: this field cannot be switched off, found 'off'")
        return None
    if annotation.startswith("bool"):
        ok = isinstance(value, bool)
        expected = "true or false"
    elif annotation.startswith("int"):
        ok = isinstance(value, int) and not isinstance(value, bool)
        expected = "an integer"
    elif annotation.startswith("float"):
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        expected = "a number"
        value = float(value) if ok else value
    else:  # Literal aliases (RealignMode, FilterKind, ...): strings, checked by FusionParams itself
        ok = isinstance(value, str)
        expected = "a string"
    if optional:
        expected += ' or "off"'
    if not ok:
        raise ConfigError(f"{source}: key {key}: expected {expected}, found {_describe(value)}")
    return value


def _parse_zenoh(t: _Table | None) -> ZenohSection:
    if t is None:
        return ZenohSection()
    section = ZenohSection(
        mode=t.string("mode", "peer", choices=ZENOH_MODES),
        connect=t.strings("connect", ()),
        listen=t.strings("listen", ()),
        multicast_scouting=t.boolean("multicast_scouting", True),
    )
    raw: dict[str, Any] = {}
    c = t.table("config")
    if c is not None:
        for key, value in c.data.items():
            c.used.add(key)
            normalized = key.strip("/")
            if normalized in _ZENOH_DEDICATED:
                raise ConfigError(
                    f'{c.source}: key zenoh.config."{key}": set this with zenoh.'
                    f"{_ZENOH_DEDICATED[normalized]} instead of the raw passthrough"
                )
            if not normalized or " " in normalized:
                raise c.error(f'zenoh.config."{key}"', "a zenoh config path like 'transport/unicast/max_links'", key)
            raw[normalized] = value
    t.done()
    return dataclasses.replace(section, config=tuple(sorted(raw.items())))


def _parse_rerun(t: _Table | None) -> RerunConfig:
    if t is None:
        return RerunConfig()
    mode = t.string("mode", "off", choices=RERUN_MODES)
    rerun = RerunConfig(
        mode=mode,
        bind=t.string("bind", "127.0.0.1"),
        grpc_port=t.integer("grpc_port", 9876, lo=1, hi=65535),
        web_port=t.integer("web_port", None, lo=1, hi=65535),
        file=t.path_value("file", None),
        log_sensors=t.boolean("log_sensors", True),
    )
    if mode == "save" and rerun.file is None:
        raise ConfigError(f'{t.source}: key rerun.file is required when rerun.mode = "save" (an .rrd path)')
    if mode != "save" and rerun.file is not None:
        raise ConfigError(f'{t.source}: key rerun.file: only used with rerun.mode = "save", found mode {mode!r}')
    t.done()
    return rerun
