"""Parsing and validating a rig config TOML into :class:`~skelfuse.config.model.RigConfig`, section by section."""

from __future__ import annotations

import dataclasses
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from skelfuse.config.checks import REQUIRED, Table, describe, did_you_mean, rigid_4x4
from skelfuse.config.model import (
    COLOR_RESOLUTIONS,
    CONGESTION_CONTROLS,
    DEFAULT_PRESET,
    DEPTH_MODES,
    DEPTH_TRACKER_PROCESSES,
    DEPTH_TRACKERS,
    FUSION_MODES,
    FUSION_PRESETS,
    KINECT_FPS,
    MIN_DELAY_SPACING_US,
    OSC_UNITS,
    PROCESSING_MODES,
    RERUN_MODES,
    SENSOR_ORIENTATIONS,
    SOURCE_KINDS,
    SYNC_BY,
    SYNC_ROLES,
    ZENOH_MODES,
    CalibrationConfig,
    CaptureConfig,
    DepthConfig,
    FusionConfig,
    IntakeConfig,
    KinectConfig,
    NodeConfig,
    RecordConfig,
    ReplayConfig,
    RerunConfig,
    RigConfig,
    SensorConfig,
    SensorSyncConfig,
    SimConfig,
    StreamConfig,
    SyncConfig,
    TrackerConfig,
    ZenohSection,
    ZenohTls,
)
from skelfuse.fusion import presets
from skelfuse.schema.errors import ConfigError
from skelfuse.wire.keys import validate_name

_ZENOH_DEDICATED = {
    "mode": "mode",
    "connect/endpoints": "connect",
    "listen/endpoints": "listen",
    "scouting/multicast/enabled": "multicast_scouting",
    "connect/retry": "reconnect_init_ms / reconnect_max_ms",
    "connect/timeout_ms": "connect_timeout_ms",
    "listen/retry": "reconnect_init_ms / reconnect_max_ms",
    "transport/link/rx/max_message_size": "max_message_bytes",
    "transport/link/tx/queue/congestion_control": "wait_before_drop_ms / wait_before_close_ms",
    "transport/link/tls": "[zenoh.tls]",
    "access_control": "access_control",
}


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
    return parse_rig_config(data, source=str(path), base_dir=path.parent)


def parse_rig_config(data: Mapping[str, Any], *, source: str = "<dict>", base_dir: Path | None = None) -> RigConfig:
    """Validate a parsed TOML document (what ``tomllib.load`` returned) into a :class:`RigConfig`.

    ``source`` is named in error messages (the file path); relative paths are resolved against ``base_dir``
    (None leaves them as written).
    """
    return _parse_rig(data, source, base_dir)


def _parse_rig(data: Mapping[str, Any], source: str, base_dir: Path | None) -> RigConfig:
    top = Table(dict(data), "", source, base_dir)

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
    depth = _parse_depth(top.table("depth"))
    zenoh = _parse_zenoh(top.table("zenoh"))
    node = NodeConfig()
    if (t := top.table("node")) is not None:
        node = NodeConfig(
            status_period_s=t.number("status_period_s", 1.0, lo=0.0, lo_open=True, hi=3600.0, unit="s"),
            name=t.string("name", None, check=lambda v: validate_name(v, "node")),
            max_lag_s=t.number("max_lag_s", 0.5, lo=0.0, lo_open=True, hi=3600.0, unit="s"),
        )
        t.done()
    capture = CaptureConfig()
    if (t := top.table("capture")) is not None:
        capture = CaptureConfig(
            stall_timeout_s=t.number("stall_timeout_s", 10.0, lo=0.0, lo_open=True, hi=3600.0, unit="s"),
            open_timeout_s=t.number("open_timeout_s", 120.0, lo=0.0, lo_open=True, hi=3600.0, unit="s"),
        )
        t.done()
    intake = _parse_intake(top.table("intake"))
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
    stream = _parse_stream(top.table("stream"))
    top.done()

    _check_rig(sensors, sync, source)
    _check_depth(fusion, depth, sensors, source)
    return RigConfig(
        name=name,
        sensors=sensors,
        sync=sync,
        calibration=calibration,
        fusion=fusion,
        depth=depth,
        zenoh=zenoh,
        node=node,
        capture=capture,
        intake=intake,
        rerun=rerun,
        record=record,
        stream=stream,
        source=source,
    )


def _parse_sync(t: Table | None) -> SyncConfig:
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
        max_ahead_ms=t.number("max_ahead_ms", 100.0, lo=0.0, lo_open=True, hi=3_600_000.0, unit="ms"),
        max_behind_ms=t.number("max_behind_ms", 1000.0, lo=0.0, lo_open=True, hi=3_600_000.0, unit="ms"),
    )
    if sync.resync_horizon_ms <= sync.tolerance_ms:
        raise t.error(
            t.key("resync_horizon_ms"), f"a number > tolerance_ms ({sync.tolerance_ms:g})", sync.resync_horizon_ms
        )
    t.done()
    return sync


def _parse_sensors(top: Table, source: str, base_dir: Path | None) -> tuple[SensorConfig, ...]:
    raw = top.raw("sensors", REQUIRED, "an array of tables [[sensors]]")
    if not isinstance(raw, list) or not raw:
        raise top.error("sensors", "at least one [[sensors]] table", raw)
    sensors = []
    for idx, item in enumerate(raw):
        t = Table(item, f"sensors[{idx}]", source, base_dir)
        sensor_id = t.string("id", check=lambda v: validate_name(v, "sensor"))
        kind = t.string("source", choices=SOURCE_KINDS)
        pose = None
        if "world_from_sensor" in t.data:
            pose = rigid_4x4(t.raw("world_from_sensor", None, ""), t.key("world_from_sensor"), source)
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
                sim = SimConfig(
                    profile=s_t.path_value("profile", None),
                    seed=s_t.integer("seed", None, lo=0),
                    clock_offset_ms=s_t.number("clock_offset_ms", 0.0, lo=-3_600_000.0, hi=3_600_000.0, unit="ms"),
                    clock_jitter_ms=s_t.number("clock_jitter_ms", 0.0, lo=0.0, hi=10_000.0, unit="ms"),
                )
                s_t.done()
            options["sim"] = sim
        for name in ("tracker",):
            if name in t.data:
                raise ConfigError(
                    f"{source}: unknown key {t.key(name)}; did you mean {t.key('kinect.' + name)}? "
                    "(tracker settings live under [sensors.kinect.tracker])"
                )
        host = t.string("host", None, check=lambda v: validate_name(v, "capture host"))
        t.done()
        sensors.append(SensorConfig(id=sensor_id, source=kind, world_from_sensor=pose, sync=sync, host=host, **options))
    ids = [s.id for s in sensors]
    for idx, sensor_id in enumerate(ids):
        if sensor_id in ids[:idx]:
            raise ConfigError(
                f"{source}: key sensors[{idx}].id: expected a sensor id not used before, found "
                f"{sensor_id!r} again (also sensors[{ids.index(sensor_id)}].id)"
            )
    return tuple(sensors)


def _parse_kinect(t: Table | None, sensor: Table, sensor_id: str) -> KinectConfig:
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


def _parse_tracker(t: Table | None) -> TrackerConfig:
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


MAX_FIXED_LAG_FRAMES = 30
"""The longest ``[fusion] fixed_lag_frames`` (1 s at 30 fps): past it, smooth the recording offline instead."""


def _parse_fusion(t: Table | None) -> FusionConfig:
    if t is None:
        return FusionConfig()
    preset = t.string("preset", DEFAULT_PRESET)
    canonical = {name.upper(): name for name in FUSION_PRESETS}
    if preset.strip().upper() not in canonical:
        raise t.error(
            t.key("preset"),
            f"one of {', '.join(FUSION_PRESETS)}",
            preset,
            did_you_mean(preset.strip(), FUSION_PRESETS),
        )
    preset = canonical[preset.strip().upper()]
    eps_mm = t.number("eps_mm", None, lo=0.0, lo_open=True, hi=10_000.0, unit="mm")
    mode = t.string("mode", "skeleton", choices=FUSION_MODES)
    fixed_lag_frames = t.integer("fixed_lag_frames", 0, lo=0, hi=MAX_FIXED_LAG_FRAMES, unit="frames")
    params: dict[str, Any] = {}
    p = t.table("params")
    if p is not None:
        fields = {f.name: f for f in dataclasses.fields(presets.FusionParams)}
        for name, value in p.data.items():
            p.used.add(name)
            key = p.key(name)
            if name == "eps_mm":
                raise ConfigError(
                    f"{p.source}: key {key}: set the DBSCAN radius with fusion.eps_mm, not in [fusion.params]"
                )
            if fields and name not in fields:
                raise ConfigError(
                    f"{p.source}: unknown key {key}{did_you_mean(name, list(fields))}; "
                    f"[fusion.params] takes FusionParams fields: {', '.join(sorted(fields))}"
                )
            params[name] = _fusion_value(value, fields.get(name), key, p.source)
        p.done()
    fusion = FusionConfig(
        preset=preset,
        eps_mm=eps_mm,
        params=tuple(sorted(params.items())),
        mode=mode,
        fixed_lag_frames=fixed_lag_frames,
    )
    try:  # FusionParams' own range checks, reported at load time
        fusion_params = dataclasses.replace(presets.preset(fusion.preset, eps_mm), **params)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{t.source}: key {t.key('params')}: {exc}") from None
    if fixed_lag_frames and (fusion_params.filter != "cv_kalman" or mode == "depth"):
        why = f"fusion mode {mode!r}" if mode == "depth" else f"the {fusion_params.filter!r} filter"
        raise ConfigError(
            f"{t.source}: key {t.key('fixed_lag_frames')}: the fixed-lag smoother needs the cv_kalman filter's "
            f"motion model over skeleton fusion (the skelfuse preset; mode skeleton or hybrid), not {why}"
        )
    t.done()
    return fusion


def _parse_depth(t: Table | None) -> DepthConfig:
    if t is None:
        return DepthConfig()
    depth = DepthConfig(
        tracker=t.string("tracker", "k4abt", choices=DEPTH_TRACKERS),
        voxel_mm=t.number("voxel_mm", 15.0, lo=1.0, hi=100.0, unit="mm"),
        icp=t.boolean("icp", False),
        tracker_wait_ms=t.integer("tracker_wait_ms", 100, lo=0, hi=10_000, unit="ms"),
        virtual_weight=t.integer("virtual_weight", 1, lo=1, hi=8),
        tracker_processes=t.string("tracker_processes", "auto", choices=DEPTH_TRACKER_PROCESSES),
    )
    t.done()
    return depth


def _check_depth(fusion: FusionConfig, depth: DepthConfig, sensors: tuple[SensorConfig, ...], source: str) -> None:
    """The simulated tracker is a stand-in for sim rigs: refused where a real sensor's data would meet it."""
    if fusion.mode == "skeleton" or depth.tracker != "simulated":
        return
    real = [s.id for s in sensors if s.source != "sim"]
    if real:
        raise ConfigError(
            f'{source}: key depth.tracker: "simulated" is a stand-in for simulated rigs only (it is not the Body '
            f'Tracking SDK), but sensor(s) {", ".join(real)} are not simulated; use tracker = "k4abt"'
        )


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
        raise ConfigError(f"{source}: key {key}: expected {expected}, found {describe(value)}")
    return value


def _parse_zenoh(t: Table | None) -> ZenohSection:
    if t is None:
        return ZenohSection()
    tls = None
    if (tls_t := t.table("tls")) is not None:
        tls = ZenohTls(
            directory=tls_t.path_value("directory", None),
            ca=tls_t.path_value("ca", None),
            certificate=tls_t.path_value("certificate", None),
            private_key=tls_t.path_value("private_key", None),
            mutual=tls_t.boolean("mutual", True),
            verify_name=tls_t.boolean("verify_name", False),
        )
        if tls.directory is None and tls.ca is None:
            raise ConfigError(f"{tls_t.source}: [zenoh.tls] needs directory (from `skelfuse certs`) or ca")
        if (tls.certificate is None) != (tls.private_key is None):
            raise ConfigError(f"{tls_t.source}: [zenoh.tls] certificate and private_key go together")
        tls_t.done()
    section = ZenohSection(
        mode=t.string("mode", "peer", choices=ZENOH_MODES),
        connect=t.strings("connect", ()),
        listen=t.strings("listen", ()),
        multicast_scouting=t.boolean("multicast_scouting", False),
        reconnect_init_ms=t.integer("reconnect_init_ms", 100, lo=10, hi=600_000, unit="ms"),
        reconnect_max_ms=t.integer("reconnect_max_ms", 1000, lo=10, hi=600_000, unit="ms"),
        connect_timeout_ms=t.integer("connect_timeout_ms", 2000, lo=100, hi=600_000, unit="ms"),
        max_message_bytes=t.integer("max_message_bytes", 1_048_576, lo=65_536, hi=1 << 30, unit="bytes"),
        fused_congestion_control=t.string("fused_congestion_control", "drop", choices=CONGESTION_CONTROLS),
        wait_before_drop_ms=t.integer("wait_before_drop_ms", 250, lo=0, hi=10_000, unit="ms"),
        wait_before_close_ms=t.integer("wait_before_close_ms", 1000, lo=10, hi=60_000, unit="ms"),
        tls=tls,
        access_control=t.boolean("access_control", False),
    )
    if section.reconnect_max_ms < section.reconnect_init_ms:
        raise t.error(
            t.key("reconnect_max_ms"),
            f"a number >= reconnect_init_ms ({section.reconnect_init_ms})",
            section.reconnect_max_ms,
        )
    if section.access_control and section.tls is None:
        raise ConfigError(
            f"{t.source}: zenoh.access_control needs [zenoh.tls]: the rules name certificates (`skelfuse certs`)"
        )
    raw: dict[str, Any] = {}
    c = t.table("config")
    if c is not None:
        for key, value in c.data.items():
            c.used.add(key)
            normalized = key.strip("/")
            dedicated = next((k for k in _ZENOH_DEDICATED if normalized == k or normalized.startswith(k + "/")), None)
            if dedicated is not None:
                raise ConfigError(
                    f'{c.source}: key zenoh.config."{key}": set this with [zenoh] '
                    f"{_ZENOH_DEDICATED[dedicated]} instead of the raw passthrough"
                )
            if not normalized or " " in normalized:
                raise c.error(f'zenoh.config."{key}"', "a zenoh config path like 'transport/unicast/max_links'", key)
            raw[normalized] = value
    t.done()
    return dataclasses.replace(section, config=tuple(sorted(raw.items())))


def _check_osc_prefix(value: str) -> str:
    if not value.startswith("/") or value.endswith("/") or any(c in value for c in " #*,?[]{}"):
        raise ValueError(
            f"{value!r} is not an OSC address prefix: it starts with '/', does not end with '/', and holds none "
            f'of \' #*,?[]{{}}\' (e.g. "/skelfuse" or "/lab/skeletons")'
        )
    return value


def _parse_stream(t: Table | None) -> StreamConfig:
    if t is None:
        return StreamConfig()
    stream = StreamConfig(
        host=t.string("host", "127.0.0.1", check=_nonempty),
        osc_port=t.integer("osc_port", 9000, lo=1, hi=65535),
        osc_prefix=t.string("osc_prefix", "/skelfuse", check=_check_osc_prefix),
        osc_units=t.string("osc_units", "mm", choices=OSC_UNITS),
        vmc_port=t.integer("vmc_port", 39539, lo=1, hi=65535),
        lsl_name=t.string("lsl_name", "skelfuse", check=_nonempty),
        lsl_max_persons=t.integer("lsl_max_persons", 2, lo=1, hi=64),
        queue_size=t.integer("queue_size", 64, lo=1, hi=100_000, unit="frames"),
        drain_timeout_s=t.number("drain_timeout_s", 1.0, lo=0.0, hi=60.0, unit="s"),
    )
    t.done()
    return stream


def _nonempty(value: str) -> str:
    if not value.strip():
        raise ValueError("must not be empty")
    return value


def _parse_intake(t: Table | None) -> IntakeConfig:
    if t is None:
        return IntakeConfig()
    intake = IntakeConfig(
        max_bodies_per_sensor=t.integer("max_bodies_per_sensor", 16, lo=1, hi=64),
        max_persons=t.integer("max_persons", 64, lo=1, hi=64),
        max_range_mm=t.number("max_range_mm", 10_000.0, lo=0.0, lo_open=True, hi=1e6, unit="mm"),
        max_payload_bytes=t.integer("max_payload_bytes", 262_144, lo=1024, hi=64 * 1024 * 1024),
        max_queue=t.integer("max_queue", 4096, lo=16, hi=1_000_000),
        max_queue_per_key=t.integer("max_queue_per_key", 1024, lo=16, hi=1_000_000),
        max_queue_bytes=t.integer("max_queue_bytes", 64 * 1024 * 1024, lo=1024, hi=4 * 1024**3),
    )
    if intake.max_queue_bytes < intake.max_payload_bytes:
        raise ConfigError(
            f"{t.source}: key {t.key('max_queue_bytes')}: expected at least max_payload_bytes "
            f"({intake.max_payload_bytes}) so one payload fits, found {intake.max_queue_bytes}"
        )
    t.done()
    return intake


def _parse_rerun(t: Table | None) -> RerunConfig:
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
