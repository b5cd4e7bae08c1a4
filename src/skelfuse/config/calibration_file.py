"""The rig's calibration file (versioned TOML) and the result types every calibration method returns.

Cycle::

    calibrate_from_sphere / calibrate_world_from_marker / (skeleton) -> CalibrationResult
    reanchor(result, world_from_master)      put a sensor-to-sensor result into the marker's world
    write_calibration(path, result)          -> TOML (version 1)
    read_calibration(path)                   -> CalibrationResult (poses validated as rigid)
    skelfuse.config.load_calibration(path)   -> {sensor id: (4, 4)} (reads the same file, ignores metadata)

File format, version 1 (``docs/configuration.md``, "[calibration]")::

    version = 1
    method = "sphere"                        # how the file was last made (the methods of the sensors may differ)
    date = "2025-01-31T10:22:03+00:00"       # ISO 8601
    master = "000123412512"                  # the sensor the others were fitted to (absent: none)
    notes = "..."
    [sensors."000123412512"]
    world_from_sensor = [[...4...], [...], [...], [0.0, 0.0, 0.0, 1.0]]   # sensor -> world, mm
    method = "sphere"                        # "sphere" | "marker" | "skeleton" | "manual" | "refine"
    date = "2025-01-31T10:22:03+00:00"
    residual_mm = 1.8                        # RMS of the fit, mm (absent: not measured)
    n_points = 412                           # correspondences the fit used (absent: none)
    notes = "..."

Only ``world_from_sensor`` is required by :func:`load_calibration`; the rest is metadata.
Absent values are written by leaving the key out (TOML has no null), as everywhere in skelfuse.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.config.checks import describe, rigid_4x4
from skelfuse.fusion.transform import invert_transform
from skelfuse.schema.errors import CalibrationError, ConfigError

FORMAT_VERSION = 1
METHODS: tuple[str, ...] = ("sphere", "marker", "skeleton", "manual", "refine")


def now_iso() -> str:
    """The current time as ISO 8601 with the UTC offset, to the second."""
    return _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat()


CALIBRATE_HINT = (
    "fusion needs a pose for every sensor: either set sensors[i].world_from_sensor, or point "
    "[calibration] file at a calibration made with `skelfuse calibrate ...`"
)


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
        raise ConfigError(f"cannot read calibration {path}: {exc}; {CALIBRATE_HINT}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"calibration {path} is not valid TOML: {exc}") from None
    sensors = data.get("sensors")
    if not isinstance(sensors, dict) or not sensors:
        raise ConfigError(
            f"{path}: key sensors: expected a table [sensors.<id>] with world_from_sensor per "
            f"sensor, found {describe(sensors)}"
        )
    poses = {}
    for sensor_id, table in sensors.items():
        where = f"sensors.{sensor_id}"
        if not isinstance(table, dict) or "world_from_sensor" not in table:
            raise ConfigError(
                f"{path}: key {where}: expected a table with world_from_sensor (4x4), found {describe(table)}"
            )
        poses[sensor_id] = np.array(rigid_4x4(table["world_from_sensor"], f"{where}.world_from_sensor", str(path)))
    return poses


@dataclass(frozen=True)
class SensorCalibration:
    """One sensor's measured pose and how good it is.

    Attributes
    ----------
    world_from_sensor : (4, 4) float64
        Sensor frame (x right, y down, z forward, mm) → world (z up, mm).
    method : {"sphere", "marker", "skeleton", "manual", "refine"}
    residual_mm : float or None
        RMS distance between the corresponding points after the fit, mm (None: not measured, e.g. the
        master of a sensor-to-sensor fit, or a manual pose).
    n_points : int or None
        Correspondences the fit used.
    date : str
        ISO 8601 time of the calibration.
    notes : str
    """

    world_from_sensor: np.ndarray
    method: str
    residual_mm: float | None = None
    n_points: int | None = None
    date: str = field(default_factory=now_iso)
    notes: str = ""

    def __post_init__(self) -> None:
        pose = np.array(self.world_from_sensor, dtype=np.float64)
        if pose.shape != (4, 4):
            raise ValueError(f"world_from_sensor must be 4x4, got {pose.shape}")
        object.__setattr__(self, "world_from_sensor", pose)
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")


@dataclass(frozen=True)
class CalibrationResult:
    """A calibration of a whole rig (or part of it).

    Attributes
    ----------
    sensors : dict sensor id -> SensorCalibration
    method : str
        The method that made it ("sphere", "marker", ...).
    master : str or None
        The sensor the others were fitted to; its frame is the world until a marker calibration re-anchors it.
    date : str
        ISO 8601.
    notes : str
    points_by_sensor : dict sensor id -> (N, 3) float64, mm, sensor frame
        The corresponding points the fit used (sphere centres), row i of every sensor the same instant.
        For inspection and :func:`skelfuse.calibration.view.log_calibration`; not written to the file.
    """

    sensors: dict[str, SensorCalibration]
    method: str
    master: str | None = None
    date: str = field(default_factory=now_iso)
    notes: str = ""
    points_by_sensor: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def world_from_sensor(self) -> dict[str, np.ndarray]:
        """(4, 4) pose per sensor id (what :meth:`skelfuse.config.RigConfig.poses` reads from the file)."""
        return {sensor_id: s.world_from_sensor for sensor_id, s in self.sensors.items()}


def reanchor(result: CalibrationResult, world_from_master: np.ndarray, *, note: str = "") -> CalibrationResult:
    """Move a whole calibration so that its master gets the pose ``world_from_master``.

    Every sensor keeps its pose relative to the master:
    ``world_from_sensor' = world_from_master @ inv(world_from_sensor[master]) @ world_from_sensor``.
    This is the paper's last step (sensor-to-marker after sensor-to-sensor). Residuals stay as they are
    (they measure the sensor-to-sensor fit, which a rigid change of world does not alter).

    Raises
    ------
    CalibrationError
        The result has no master, or the master is not among its sensors.
    """

    if result.master is None or result.master not in result.sensors:
        raise CalibrationError(
            f"cannot re-anchor a calibration without its master (master = {result.master!r}, "
            f"sensors: {', '.join(result.sensors)}); calibrate sensor to sensor first"
        )
    correction = np.asarray(world_from_master, dtype=np.float64) @ invert_transform(
        result.sensors[result.master].world_from_sensor
    )
    sensors = {
        sid: replace(
            s,
            world_from_sensor=correction @ s.world_from_sensor,
            notes=(s.notes + ("; " if s.notes and note else "") + note),
        )
        for sid, s in result.sensors.items()
    }
    return replace(result, sensors=sensors)


# ----------------------------------------------------------------------------------------------------------
# TOML
# ----------------------------------------------------------------------------------------------------------


def _toml_str(value: str) -> str:
    # JSON string escapes (\", \\, \n, \uXXXX) are valid TOML basic-string escapes.
    return json.dumps(value, ensure_ascii=True)


def _toml_float(value: float) -> str:
    if not math.isfinite(value):
        raise CalibrationError(f"cannot write a non-finite number ({value}) to a calibration file")
    return repr(float(value))  # shortest repr round-trips exactly


def write_calibration(path: str | Path, result: CalibrationResult) -> Path:
    """Write ``result`` as a version-1 calibration TOML file (see the module docstring), atomically.

    Poses are written with full float precision (``repr``), so reading back gives the same matrices bit
    for bit. Returns the path written.
    """
    path = Path(path)
    lines = [
        "# skelfuse rig calibration (written by `skelfuse calibrate`). Sensor frame: x right, y down,",
        "# z forward (k4abt depth camera); world: right-handed, z up; mm. p_world = world_from_sensor @ p.",
        f"version = {FORMAT_VERSION}",
        f"method = {_toml_str(result.method)}",
        f"date = {_toml_str(result.date)}",
    ]
    if result.master is not None:
        lines.append(f"master = {_toml_str(result.master)}")
    if result.notes:
        lines.append(f"notes = {_toml_str(result.notes)}")
    for sensor_id, sensor in result.sensors.items():
        pose = sensor.world_from_sensor
        rows = ", ".join("[" + ", ".join(_toml_float(v) for v in row) + "]" for row in pose)
        lines += [
            "",
            f"[sensors.{_toml_str(sensor_id)}]",
            f"world_from_sensor = [{rows}]",
            f"method = {_toml_str(sensor.method)}",
            f"date = {_toml_str(sensor.date)}",
        ]
        if sensor.residual_mm is not None:
            lines.append(f"residual_mm = {_toml_float(sensor.residual_mm)}")
        if sensor.n_points is not None:
            lines.append(f"n_points = {int(sensor.n_points)}")
        if sensor.notes:
            lines.append(f"notes = {_toml_str(sensor.notes)}")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    tmp.replace(path)
    return path


def read_calibration(path: str | Path) -> CalibrationResult:
    """Read a calibration file with its metadata.

    The poses are read and validated by :func:`load_calibration` (one parser for both), so
    whatever fusion accepts, this accepts. Files without ``version`` (hand-written) read as version 1;
    metadata that is absent gets defaults (method "manual" per sensor unless the file's top-level method
    says otherwise).

    Raises
    ------
    CalibrationError
        Unreadable, not TOML, a newer format version, a malformed pose or metadata value.
    """

    path = Path(path)
    try:
        poses = load_calibration(path)
    except ConfigError as exc:
        raise CalibrationError(str(exc)) from None
    with path.open("rb") as handle:
        data = tomllib.load(handle)
    version = data.get("version", FORMAT_VERSION)
    if not isinstance(version, int) or isinstance(version, bool) or version > FORMAT_VERSION or version < 1:
        raise CalibrationError(
            f"{path}: key version: expected an integer 1..{FORMAT_VERSION}, found {version!r}; "
            f"a newer skelfuse wrote this file, upgrade to read it"
        )
    top_method = _meta(data, "method", str, path, "")
    default_method = top_method if top_method in METHODS else "manual"
    sensors = {}
    for sensor_id, pose in poses.items():
        table: Mapping[str, Any] = data["sensors"][sensor_id]
        where = f"sensors.{sensor_id}"
        method = _meta(table, "method", str, path, default_method, where)
        if method not in METHODS:
            raise CalibrationError(
                f"{path}: key {where}.method: expected one of {', '.join(METHODS)}, found {method!r}"
            )
        residual = _meta(table, "residual_mm", float, path, None, where)
        sensors[sensor_id] = SensorCalibration(
            world_from_sensor=pose,
            method=method,
            residual_mm=None if residual is None else float(residual),
            n_points=_meta(table, "n_points", int, path, None, where),
            date=_meta(table, "date", str, path, _meta(data, "date", str, path, "")),
            notes=_meta(table, "notes", str, path, ""),
        )
    return CalibrationResult(
        sensors=sensors,
        method=top_method or default_method,
        master=_meta(data, "master", str, path, None),
        date=_meta(data, "date", str, path, ""),
        notes=_meta(data, "notes", str, path, ""),
    )


def _meta(table: Mapping[str, Any], key: str, kind: type, path: Path, default: Any, where: str = "") -> Any:
    if key not in table:
        return default
    value = table[key]
    if isinstance(value, _dt.datetime | _dt.date):  # an unquoted TOML date-time
        value = value.isoformat()
    ok = isinstance(value, kind) and not isinstance(value, bool)
    if kind is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
    if not ok:
        name = f"{where}.{key}" if where else key
        raise CalibrationError(f"{path}: key {name}: expected {kind.__name__}, found {value!r}")
    return value
