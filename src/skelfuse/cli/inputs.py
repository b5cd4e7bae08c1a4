"""The options every command that reads recordings shares, and opening them (``recording.inputs``).

Not a command group: ``fuse --input``, ``replay``, ``calibrate skeleton|check``, ``eval real`` and
``convert`` add these options with :func:`add_input_options` and open the take with :func:`open_take`.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Mapping, Sequence

import numpy as np

from skelfuse.config import RigConfig
from skelfuse.config.calibration_file import read_calibration
from skelfuse.recording.inputs import CLOCK_MODES, InputTake, open_inputs, parse_time_offsets
from skelfuse.recording.inputs import (
    single_recorded_mcap as single_recorded_mcap,  # its home; the commands import it here
)
from skelfuse.recording.level import level_take
from skelfuse.rig.level import parse_axis
from skelfuse.schema.errors import ConfigError
from skelfuse.sources.formats import FORMATS
from skelfuse.sources.recorded import ASSUME_CONFIDENCE

INPUT_HELP = (
    "[ID=]PATH of a recording: a skelfuse MCAP, an Azure Kinect .mkv (needs the SDK), an offline_processor "
    ".json, an azure-kinect-mkv-extractor camera folder, an andyj1 .csv or a long .csv (docs/recordings.md); "
    "one per sensor, or one file holding several"
)


def add_input_options(parser: argparse.ArgumentParser, *, by: bool = True) -> None:
    """``--format``, ``--assume-confidence``, ``--clock``, ``--time-offset``, ``--registered`` [, ``--by``]."""
    group = parser.add_argument_group("reading recordings (docs/recordings.md)")
    group.add_argument(
        "--format", choices=FORMATS, default=None, help="read every input as this format (default: detect each)"
    )
    group.add_argument(
        "--assume-confidence",
        choices=tuple(ASSUME_CONFIDENCE),
        default="medium",
        help="confidence of every joint of a file that stores none (offline_processor JSON, a long CSV without "
        "the column): medium, low, or unknown = do not use confidence (default: %(default)s); said in the output",
    )
    group.add_argument(
        "--clock",
        choices=CLOCK_MODES,
        default="auto",
        help="the files' device clocks: one sync chain (shared), unrelated (independent: the offset is "
        "estimated from the motion and reported), or auto = shared where the time ranges overlap "
        "(default: %(default)s)",
    )
    group.add_argument(
        "--time-offset",
        action="append",
        default=[],
        metavar="ID=MS",
        help="add MS milliseconds to sensor ID's times before matching (overrides an estimate; repeatable)",
    )
    group.add_argument(
        "--registered",
        action="store_true",
        help="the files' poses are already in one frame (e.g. the andyj1 subordinates): identity poses",
    )
    if by:
        group.add_argument(
            "--by",
            choices=["device", "host"],
            default=None,
            help="match frames by device time or recorded host time (MCAP) (default: the config's [sync] by, "
            "else device)",
        )


def open_take(
    args: argparse.Namespace, specs: Sequence[str], cfg: RigConfig | None = None, *, quiet: bool = False
) -> InputTake:
    """Open ``specs`` with the shared options; print what was assumed and how frames are matched on stderr."""
    by = getattr(args, "by", None) or (cfg.sync.by if cfg is not None else "device")
    take = open_inputs(
        list(specs),
        fmt=args.format,
        assume_confidence=args.assume_confidence,
        by=by,
        clock=args.clock,
        time_offsets_ms=parse_time_offsets(args.time_offset),
        registered=args.registered,
        fps=cfg.sync.fps if cfg is not None else 30.0,
    )
    if not quiet:
        print(take.describe(), file=sys.stderr)
    return take


def add_level_options(parser: argparse.ArgumentParser) -> None:
    """``--up AXIS`` and ``--no-level``: the world levelled from the skeletons (:func:`world_poses`)."""
    group = parser.add_argument_group("levelling the world (where no calibration defines it)")
    group.add_argument(
        "--up",
        default=None,
        metavar="AXIS",
        help="the axis of the shared frame (the master camera's: x right, y down, z forward) that points up, "
        "e.g. -y; the floor is still found from the feet (default: found from the skeletons)",
    )
    group.add_argument(
        "--no-level",
        action="store_true",
        help="keep the shared frame as it is (a camera's: y down) instead of levelling it",
    )


def world_poses(args: argparse.Namespace, take: InputTake, cfg: RigConfig | None) -> dict[str, np.ndarray] | None:
    """The poses to fuse ``take`` with: ``--calibration``'s, else those of the inputs' shared frame; levelled
    from the skeletons (z up, floor at z = 0, reported on stderr) where no calibration defines the world:
    registered or single-view inputs (a recording whose poses are all identity, as ``convert --registered``
    writes it, included), or a sensor-to-sensor calibration. None: the config's or recording's. ``fuse
    --input`` and ``export`` (of a recording fused on the way) both call it."""
    poses: dict[str, np.ndarray] | None = None
    world_defined = True
    if getattr(args, "calibration", None) is not None:  # `export` takes no --calibration: its --config's poses
        calibration = read_calibration(args.calibration)
        missing = [sid for sid in take.sensor_ids if sid not in calibration.sensors]
        if missing:
            raise ConfigError(
                f"--calibration {args.calibration}: no pose for {', '.join(missing)} (it holds "
                f"{', '.join(calibration.sensors)}); name the inputs ID=PATH with the calibration's sensor ids"
            )
        poses = calibration.world_from_sensor
        world_defined = "marker" in {calibration.method, *(s.method for s in calibration.sensors.values())}
    elif take.registered or (cfg is None and _all_identity(take.poses)):  # as `convert --registered` wrote it
        poses, world_defined = dict(take.poses), False
    elif len(take.sensor_ids) == 1 and cfg is None and not take.poses:
        poses, world_defined = {take.sensor_ids[0]: np.eye(4)}, False  # one view: its camera's frame
    if poses is None or world_defined or args.no_level:
        if args.up is not None:
            raise ConfigError("--up applies where the world is levelled from the skeletons; this take's is defined")
        return poses
    try:
        up = parse_axis(args.up) if args.up is not None else None
    except ValueError as exc:
        raise ConfigError(f"--up: {exc}") from None
    levelled, levelling = level_take(take, poses, up=up)
    print(f"note: {levelling.describe()}", file=sys.stderr)
    return levelled


def _all_identity(poses: Mapping[str, np.ndarray]) -> bool:
    """Recorded poses all identity: inputs already in one frame (a camera's), no world defined."""
    return bool(poses) and all(np.allclose(pose, np.eye(4)) for pose in poses.values())
