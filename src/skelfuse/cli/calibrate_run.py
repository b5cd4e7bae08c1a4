"""The ``skelfuse calibrate`` sub-commands' bodies: read the inputs, run the method, write the file.

The parser and the user's view of the commands (options, exit codes, folder layout): :mod:`skelfuse.cli.calibrate`.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.calibration.rgbd_folder import INTRINSICS_FILE, load_rgbd_folder, save_rgbd_frame, write_intrinsics
from skelfuse.calibration.skeleton import calibrate_from_skeletons, check_calibration, skeleton_calibration_result
from skelfuse.calibration.takes import load_recording_take, take_arrays
from skelfuse.cli.common import (
    EXIT_ATTENTION,
    EXIT_OK,
)
from skelfuse.cli.inputs import open_take, single_recorded_mcap
from skelfuse.config import load_rig_config
from skelfuse.config.calibration_file import (
    CalibrationResult,
    SensorCalibration,
    read_calibration,
    write_calibration,
)
from skelfuse.fusion.camera import Intrinsics
from skelfuse.progress import note
from skelfuse.recording.mcap_io import RecordingReader
from skelfuse.schema.errors import CalibrationError, ConfigError, DataError
from skelfuse.sources.kinect import DeviceSettings, _open_by_serial, import_pyk4a, kinect_start_order

DEFAULT_OUTPUT = Path("calibration.toml")


# ----------------------------------------------------------------------------------------------------------
# Shared helpers
# ----------------------------------------------------------------------------------------------------------


def _rig(args: argparse.Namespace) -> Any:
    if getattr(args, "config", None) is None:
        return None

    return load_rig_config(args.config)


def _output_path(args: argparse.Namespace, cfg: Any) -> Path:
    """--output, else the rig config's [calibration] file, else calibration.toml."""
    if args.output is not None:
        return Path(args.output)
    if cfg is not None and cfg.calibration.file is not None:
        return Path(cfg.calibration.file)
    if cfg is not None:
        note(
            f"note: {cfg.source} has no [calibration] file; writing {DEFAULT_OUTPUT} (set [calibration] "
            f'file = "{DEFAULT_OUTPUT}" so that fusion uses it)'
        )
    return DEFAULT_OUTPUT


def _stored_calibration_path(args: argparse.Namespace, cfg: Any, what: str) -> Path:
    if args.calibration is not None:
        return Path(args.calibration)
    if cfg is not None and cfg.calibration.file is not None:
        return Path(cfg.calibration.file)
    raise ConfigError(
        f"{what} needs the stored calibration: --calibration FILE, or --config RIG.toml with a [calibration] file"
    )


def _default_master(candidates: Sequence[str], cfg: Any, stored_master: str | None = None) -> str:
    """The stored calibration's master, else the rig's sync master, else the rig's first sensor, else the
    first candidate; only among ``candidates``."""
    if not candidates:
        raise DataError("no sensors to calibrate")
    if stored_master is not None and stored_master in candidates:
        return stored_master
    if cfg is not None:
        for s in cfg.sensors:
            if s.sync.role == "master" and s.id in candidates:
                return s.id
        for s in cfg.sensors:
            if s.id in candidates:
                return s.id
    return candidates[0]


def _check_master(master: str, candidates: Sequence[str], where: str) -> str:
    if master not in candidates:
        raise ConfigError(f"--master {master!r} is not among the sensors of {where}: {', '.join(candidates)}")
    return master


def _check_known_sensors(ids: Sequence[str], cfg: Any, where: str) -> None:
    if cfg is None:
        return
    unknown = [s for s in ids if s not in cfg.sensor_ids]
    if unknown:
        raise ConfigError(
            f"{where} holds sensor(s) {', '.join(unknown)} that rig {cfg.name!r} ({cfg.source}) does "
            f"not have (its sensors: {', '.join(cfg.sensor_ids)}); check the serials"
        )
    absent = [s for s in cfg.sensor_ids if s not in ids]
    if absent:
        note(f"note: {where} has no data of sensor(s) {', '.join(absent)}: they will not be calibrated")


def _print_result(result: CalibrationResult, path: Path) -> None:
    print(f"{result.method} calibration, master {result.master}, written to {path}")
    print(f"{'sensor':<20} {'method':<9} {'residual':>10} {'points':>7}  position (world, mm)")
    for sensor_id, s in result.sensors.items():
        residual = "master" if s.residual_mm is None else f"{s.residual_mm:.1f} mm"
        points = "-" if s.n_points is None else str(s.n_points)
        x, y, z = s.world_from_sensor[:3, 3]
        print(f"{sensor_id:<20} {s.method:<9} {residual:>10} {points:>7}  ({x:.0f}, {y:.0f}, {z:.0f})")
    if result.notes:
        print(f"notes: {result.notes}")


def _save_rrd(path: Path, result: CalibrationResult) -> None:
    import rerun as rr

    from skelfuse.calibration.view import log_calibration  # rerun: imported by the command that uses it

    recording = rr.RecordingStream("skelfuse_calibration")
    recording.save(path)
    log_calibration(recording, result)
    recording.flush()
    recording.disconnect()
    note(f"calibration view saved to {path} (open it with `rerun {path}`)")


# ----------------------------------------------------------------------------------------------------------
# capture
# ----------------------------------------------------------------------------------------------------------


def cmd_capture(args: argparse.Namespace) -> int:
    cfg = _rig(args)
    kinects = kinect_start_order(cfg.sensors)
    if args.sensors:
        unknown = [s for s in args.sensors if s not in cfg.sensor_ids]
        if unknown:
            raise ConfigError(f"--sensors {', '.join(unknown)}: not in rig {cfg.name!r} ({', '.join(cfg.sensor_ids)})")
        kinects = [s for s in kinects if s.id in args.sensors]
    if not kinects:
        raise ConfigError(
            f'{cfg.source}: no sensor with source = "kinect" to capture from (sensors: '
            f"{', '.join(f'{s.id} ({s.source})' for s in cfg.sensors)})"
        )
    pyk4a = import_pyk4a()  # KinectUnavailable names the extra and the SDK
    out = Path(args.out)
    devices: list[tuple[str, Any]] = []
    try:
        for sensor in kinects:  # subordinates first, the master last
            settings = DeviceSettings.from_sensor(sensor, cfg.sync.fps)
            if settings.color_resolution is None:
                settings = dataclasses.replace(settings, color_resolution=args.color_resolution)
            device = _open_by_serial(pyk4a, settings)
            devices.append((sensor.id, device))
            device.start()
            note(f"started {sensor.id} ({settings.depth_mode}, colour {settings.color_resolution}, {sensor.sync.role})")
        _capture_frames(pyk4a, devices, out, args)
    finally:
        for _, device in reversed(devices):
            try:
                device.stop()
            except Exception as exc:
                note(f"note: stopping a device failed: {exc}")
    note(f"wrote {args.frames} frames of {len(devices)} sensor(s) to {out}")
    print(out)
    return EXIT_OK


def _grab(pyk4a: Any, sensor_id: str, device: Any, timeout_ms: int) -> tuple[Any, int]:
    try:
        capture = device.get_capture(timeout=timeout_ms)
    except pyk4a.K4AException as exc:
        raise DataError(
            f"sensor {sensor_id}: no capture within {timeout_ms} ms ({exc}); check its cable, power "
            "and, on a synced rig, the sync cables (subordinates wait for the master)"
        ) from None
    return capture, int(capture.depth_timestamp_usec)


def _capture_frames(pyk4a: Any, devices: Sequence[tuple[str, Any]], out: Path, args: argparse.Namespace) -> None:
    """Grab ``args.frames`` synchronized rounds (every ``args.every``-th) and write them to ``out``."""
    timeout_ms = round(args.timeout_s * 1000)
    tolerance_us = round(args.tolerance_ms * 1000)
    for sensor_id, device in devices:
        matrix = np.asarray(device.calibration.get_camera_matrix(pyk4a.CalibrationType.DEPTH), dtype=np.float64)
        capture, _ = _grab(pyk4a, sensor_id, device, timeout_ms)
        height, width = np.asarray(capture.depth).shape[:2]
        write_intrinsics(
            out / sensor_id, Intrinsics(matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2], int(width), int(height))
        )
    for _ in range(args.warmup):  # auto exposure settles
        for sensor_id, device in devices:
            _grab(pyk4a, sensor_id, device, timeout_ms)
    written = rounds = 0
    started = time.monotonic()
    while written < args.frames:
        grabbed = {sid: _grab(pyk4a, sid, dev, timeout_ms) for sid, dev in devices}
        for _ in range(10 * len(devices)):  # catch up the sensors that lag behind the newest one
            newest = max(t for _, t in grabbed.values())
            late = [sid for sid, (_, t) in grabbed.items() if newest - t > tolerance_us]
            if not late:
                break
            for sid, dev in devices:
                if sid in late:
                    grabbed[sid] = _grab(pyk4a, sid, dev, timeout_ms)
        else:
            times = {sid: t for sid, (_, t) in grabbed.items()}
            raise DataError(
                f"the sensors' device times never came within {args.tolerance_ms:g} ms of each other "
                f"({times}); wired sync is needed for sphere calibration (check the sync cables)"
            )
        rounds += 1
        if (rounds - 1) % args.every:
            continue
        for sid, (capture, _) in grabbed.items():
            color = capture.transformed_color
            if color is None:
                raise DataError(
                    f"sensor {sid}: the capture has no colour image; enable the colour camera "
                    "(--color-resolution or sensors.kinect.color_resolution)"
                )
            save_rgbd_frame(out / sid, written, np.asarray(color)[..., :3], np.asarray(capture.depth, dtype=np.uint16))
        written += 1
        if written % 10 == 0 or written == args.frames:
            note(f"captured {written}/{args.frames} frames ({time.monotonic() - started:.0f} s)")


# ----------------------------------------------------------------------------------------------------------
# sphere
# ----------------------------------------------------------------------------------------------------------


def cmd_sphere(args: argparse.Namespace) -> int:
    from skelfuse.calibration.sphere import calibrate_from_sphere, red_histogram, sphere_histogram

    cfg = _rig(args)
    frames, intrinsics = load_rgbd_folder(args.folder)
    ids = list(frames)
    _check_known_sensors(ids, cfg, str(args.folder))
    if len(ids) < 2:
        raise DataError(f"{args.folder}: sphere calibration needs at least two sensors, found {', '.join(ids)}")
    master = _check_master(args.master, ids, str(args.folder)) if args.master else _default_master(ids, cfg)
    if args.max_frames is not None:
        frames = {s: f[: args.max_frames] for s, f in frames.items()}
    if args.ball_sample is not None:
        import cv2

        sample = cv2.imread(str(args.ball_sample), cv2.IMREAD_COLOR)
        if sample is None:
            raise DataError(
                f"cannot read --ball-sample {args.ball_sample} as an image; give a crop showing only the ball"
            )
        hist = sphere_histogram(sample)
    else:
        hist = red_histogram()
    n_frames = len(next(iter(frames.values())))
    note(f"sphere calibration: {len(ids)} sensors, {n_frames} frames, master {master}, radius {args.radius_mm:g} mm")
    result = calibrate_from_sphere(
        frames,
        intrinsics,
        args.radius_mm,
        master,
        hist=hist,
        threshold_mm=args.ransac_threshold_mm,
        min_points=args.min_frames,
        progress=not args.quiet,
    )
    path = write_calibration(_output_path(args, cfg), result)
    _print_result(result, path)
    print("next: put the marker plate on the floor in the master's view and run `skelfuse calibrate marker`")
    if args.rrd is not None:
        _save_rrd(Path(args.rrd), result)
    return EXIT_OK


# ----------------------------------------------------------------------------------------------------------
# marker
# ----------------------------------------------------------------------------------------------------------


def cmd_marker(args: argparse.Namespace) -> int:
    from skelfuse.calibration.marker import calibrate_world_from_marker

    cfg = _rig(args)
    output = _output_path(args, cfg)
    stored: CalibrationResult | None = None
    stored_path = Path(args.calibration) if args.calibration is not None else output
    if not args.fresh and stored_path.exists():
        stored = read_calibration(stored_path)
        note(
            f"re-anchoring the {stored.method} calibration in {stored_path} ({len(stored.sensors)} sensors, "
            f"master {stored.master})"
        )
    elif args.calibration is not None and not args.fresh:
        raise DataError(
            f"--calibration {stored_path} not found; run `skelfuse calibrate sphere` (or skeleton) "
            "first, or leave it out to calibrate the master alone"
        )
    folder = Path(args.folder)
    if not folder.is_dir():
        load_rgbd_folder(folder)  # raises the folder's DataError
    available = sorted(p.name for p in folder.iterdir() if (p / INTRINSICS_FILE).is_file())
    if args.master:
        master = args.master
    else:
        master = _default_master(available, cfg, stored.master if stored is not None else None)
    if stored is not None and stored.master != master:
        raise CalibrationError(
            f"the stored calibration {stored_path} was fitted to master {stored.master!r} but the "
            f"plate is read from {master!r}; use {stored.master!r}'s view of the plate "
            "(--master), or --fresh to calibrate the master alone"
        )
    frames, intrinsics = load_rgbd_folder(folder, sensors=[master], frames=None if args.frame is None else [args.frame])
    sequence = frames[master]
    number = sequence.numbers[0]
    color, depth = sequence.read(number)
    note(f"marker calibration: master {master}, frame {number} of {folder / master}")
    result, observations = calibrate_world_from_marker(
        color,
        depth,
        intrinsics[master],
        master,
        calibration=stored,
        ids=tuple(args.ids),
        dictionary=args.dictionary,
        marker_mm=args.marker_mm,
        centre_method=args.centre_method,
    )
    path = write_calibration(output, result)
    for marker_id, obs in sorted(observations.items()):
        x, y, z = obs.center
        pnp = "" if obs.pnp_discrepancy_mm is None else f", {obs.pnp_discrepancy_mm:.1f} mm from the PnP centre"
        print(
            f"marker {marker_id}: centre ({x:.0f}, {y:.0f}, {z:.0f}) mm in {master}'s frame, "
            f"{obs.n_pixels} depth pixels{pnp}"
        )
    _print_result(result, path)
    if args.rrd is not None:
        _save_rrd(Path(args.rrd), result)
    return EXIT_OK


def _load_take(args: argparse.Namespace, cfg: Any) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    specs = ([str(args.recording)] if args.recording is not None else []) + list(args.take)
    if not specs:
        raise ConfigError(
            "give the walking take as --recording REC.mcap (from `skelfuse record`) or as --take [ID=]PATH per "
            "sensor (any format of docs/recordings.md)"
        )
    if (
        args.recording is not None
        and not args.take
        and not (args.time_offset or args.registered)
        and single_recorded_mcap(specs)
    ):
        sync = cfg.sync if cfg is not None else None
        by = args.by or (sync.by if sync is not None else "device")
        positions, confidence, ids = load_recording_take(
            args.recording, by=by, sync=sync, max_frames=args.max_frames, progress=not args.quiet
        )
    else:
        take = open_take(args, specs, cfg)  # what was assumed and how frames were matched: always said
        positions, confidence, ids = take_arrays(
            take, sync=cfg.sync if cfg is not None else None, max_frames=args.max_frames, progress=not args.quiet
        )
    if len(ids) < 2:
        raise DataError(f"the take holds {len(ids)} sensor ({', '.join(ids)}); a calibration needs at least two")
    _check_known_sensors(ids, cfg, "the take")
    return positions, confidence, ids


# ----------------------------------------------------------------------------------------------------------
# skeleton
# ----------------------------------------------------------------------------------------------------------


def cmd_skeleton(args: argparse.Namespace) -> int:

    cfg = _rig(args)
    positions, confidence, ids = _load_take(args, cfg)
    anchor_pose = None
    anchor: CalibrationResult | None = None
    if args.anchor is not None:
        anchor = read_calibration(args.anchor)
    master_default = anchor.master if anchor is not None else None
    master = _check_master(args.master, ids, "the take") if args.master else _default_master(ids, cfg, master_default)
    if anchor is not None:
        if master not in anchor.sensors:
            raise CalibrationError(
                f"--anchor {args.anchor} has no pose for the master {master!r} (it has "
                f"{', '.join(anchor.sensors)}); give --master one of those"
            )
        anchor_pose = anchor.sensors[master].world_from_sensor
    note(f"skeleton calibration: {len(ids)} sensors, {len(positions)} frames, master {master}")
    cal = calibrate_from_skeletons(
        positions, confidence, ids, master, master_world_from_sensor=anchor_pose, progress=not args.quiet
    )
    print(cal.report())
    bad = [s for s in cal.sensor_ids if cal.quality[s].verdict == "bad"]
    result = skeleton_calibration_result(cal)
    output = _output_path(args, cfg)
    if bad and not args.force:
        print(
            f"\nnot written: sensor(s) {', '.join(bad)} are 'bad' ({output} is left as it was; --force writes "
            "it anyway)"
        )
    else:
        write_calibration(output, result)
        print(f"\nwritten to {output}" + (" (with bad sensors: do not fuse with them)" if bad else ""))
    if bad:
        print(
            "hint: record a longer walk (~30 s or more) that crosses the space every pair of sensors shares, one "
            "person only, feet visible; a bad sensor with few points did not see the person often enough"
        )
        return EXIT_ATTENTION
    if any(cal.quality[s].verdict == "check" for s in cal.sensor_ids):
        print("hint: 'check' verdicts are usable but not stable; a longer walk through every shared view helps")
    return EXIT_OK


# ----------------------------------------------------------------------------------------------------------
# check
# ----------------------------------------------------------------------------------------------------------


def cmd_check(args: argparse.Namespace) -> int:

    cfg = _rig(args)
    path = _stored_calibration_path(args, cfg, "calibrate check")
    if not path.is_file():  # bad input, exit 2 (docs/calibration.md): a check needs a stored calibration
        raise ConfigError(
            f"calibration file {path} not found; make one first with `skelfuse calibrate skeleton` "
            "(or sphere, then marker)"
        )
    try:
        stored = read_calibration(path)
    except CalibrationError as exc:  # a malformed stored file is bad input too, not a failed computation
        raise ConfigError(str(exc)) from None
    positions, confidence, ids = _load_take(args, cfg)
    master = _check_master(args.master, ids, "the take") if args.master else _default_master(ids, cfg, stored.master)
    # Only residuals of a skeleton calibration measure the same thing as the check's (sphere centres do not).
    reference = {
        s: c.residual_mm for s, c in stored.sensors.items() if c.method == "skeleton" and c.residual_mm is not None
    }
    note(
        f"checking {path} ({stored.method}, {stored.date or 'undated'}) on a take of {len(positions)} frames, "
        f"master {master}"
    )
    result = check_calibration(
        stored.world_from_sensor,
        positions,
        confidence,
        ids,
        master,
        reference_residual_mm=reference or None,
        max_rotation_deg=args.max_rotation_deg,
        max_translation_mm=args.max_translation_mm,
        max_residual_growth_mm=args.max_residual_growth_mm,
        progress=not args.quiet,
    )
    print(result.report())
    if result.moved:
        print(
            f"hint: recalibrate ({', '.join(result.moved)} moved): `skelfuse calibrate skeleton` with a new walk, "
            "or sphere + marker"
        )
        return EXIT_ATTENTION
    return EXIT_OK


# ----------------------------------------------------------------------------------------------------------
# refine
# ----------------------------------------------------------------------------------------------------------


def cmd_refine(args: argparse.Namespace) -> int:
    from skelfuse.calibration.refine import refine, refine_report, simulated_walk, walk_frames

    if args.sim:
        note(
            f"refine: simulated walk, {args.frames} instants, every sensor but the reference off by "
            f"{args.perturb_deg:g}° / {args.perturb_mm:g} mm (seed {args.seed})"
        )
        walk = simulated_walk(
            n_frames=args.frames, perturb_deg=args.perturb_deg, perturb_mm=args.perturb_mm, seed=args.seed
        )
        note("refine: ICP on the walk (whole, then each half)")
        result = refine(
            walk.frames, walk.perturbed_poses, walk.sensor_ids, reference=walk.reference, passes=args.passes
        )
        table, _ = refine_report(result, walk.true_poses)
        print(table)
        print("\n(simulator: the error is against the true poses; nothing is written in --sim mode)")
        return EXIT_OK
    if args.recording is None:
        raise ConfigError(
            'give the walk as --recording REC.mcap (`skelfuse record` of the rig in [fusion] mode = "depth" or '
            '"hybrid", so that the person clouds are recorded), or --sim for the simulated quality table'
        )
    cfg = _rig(args)
    if cfg is None:
        raise ConfigError("--config RIG.toml is required with --recording: the rig's calibration is what is refined")
    ids = cfg.sensor_ids
    reference = args.reference or _default_master(ids, cfg)
    _check_master(reference, ids, "the rig")
    by_id = cfg.poses()
    poses = np.stack([by_id[sid] for sid in ids])
    note(f"refine: reading the person clouds of {args.recording}")
    frames = walk_frames(
        RecordingReader(args.recording).person_clouds(),
        ids,
        tolerance_us=cfg.sync.tolerance_us,
        max_frames=args.frames,
    )
    if len(frames) < 2:
        raise DataError(
            f"{args.recording} holds {len(frames)} instant(s) whose person clouds two sensors or more saw; record a "
            'walk-through with the rig in [fusion] mode = "depth" or "hybrid" (the workers then publish the '
            "clouds and `skelfuse record` writes them)"
        )
    note(f"refine: ICP on {len(frames)} instants (whole walk, then each half), reference {reference}")
    result = refine(frames, poses, ids, reference=ids.index(reference), passes=args.passes)
    table, verdicts = refine_report(result)
    print(table)
    bad = [sid for sid, v in verdicts.items() if v == "bad"]
    output = _output_path(args, cfg)
    if bad and not args.force:
        print(f"\nnot written: sensor(s) {', '.join(bad)} are 'bad' ({output} is left as it was; --force writes it)")
        return EXIT_ATTENTION
    source = f"{result.n_frames} instants of person clouds from {Path(args.recording).name}"
    sensors = {}
    for s, sid in enumerate(ids):
        icp = result.results[s]
        refined = icp is not None and bool(result.improved[s])
        sensors[sid] = SensorCalibration(
            result.after[s],
            "refine",
            residual_mm=float(icp.rmse_after_mm) if refined and icp is not None else None,
            n_points=int(icp.n_pairs) if refined and icp is not None else None,
            notes=f"ICP on {source}" if refined else f"pose kept (not refined: {verdicts[sid]}) after ICP on {source}",
        )
    write_calibration(output, CalibrationResult(sensors, "refine", master=reference))
    print(f"\nwritten to {output}")
    return EXIT_ATTENTION if bad else EXIT_OK
