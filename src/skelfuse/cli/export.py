"""``skelfuse export FUSED --format csv|c3d|trc|bvh|fbx``: fused skeletons to the files other tools read.

The input is a fused table (CSV/Parquet), a recording with its fused stream, or a recording of sensor frames
fused on the way (:mod:`skelfuse.export.source`). CSV keeps every person in one table; the per-person formats
(C3D, TRC, BVH, FBX) write one file per track id on the take's uniform time grid (:mod:`skelfuse.export.tracks`).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.cli.commands import COMMAND_HELP
from skelfuse.cli.common import (
    COUNT,
    EXIT_OK,
    INDEX,
    OFFLINE_SMOOTHERS,
    POSITIVE,
    add_json_option,
    add_output_option,
    add_preset_option,
    print_json,
    rig_config,
)
from skelfuse.cli.inputs import add_level_options, world_poses
from skelfuse.config import DEFAULT_PRESET, RigConfig
from skelfuse.export.bvh import write_bvh_arrays
from skelfuse.export.c3d import write_c3d
from skelfuse.export.csv import FUSED_FORMATS, write_fused
from skelfuse.export.fbx import write_fbx_arrays
from skelfuse.export.source import INPUT_FORMATS, FusedSource, fuses_sensor_frames, open_fused
from skelfuse.export.tracks import PersonTrack, TakeTracks, take_tracks
from skelfuse.export.trc import write_trc
from skelfuse.progress import Progress, note
from skelfuse.recording.inputs import open_inputs
from skelfuse.schema.errors import ConfigError, DataError
from skelfuse.schema.frames import FusedFrame

PersonWriter = Callable[[PersonTrack, TakeTracks, Path, argparse.Namespace], Path]


def _c3d(person: PersonTrack, take: TakeTracks, path: Path, args: argparse.Namespace) -> Path:
    return write_c3d(person, take, path, source=str(args.input))


def _person_times_s(person: PersonTrack, take: TakeTracks) -> np.ndarray:
    """Seconds after the take's first instant of each of the person's grid frames."""
    return (person.first_frame + np.arange(person.n_frames)) / take.rate_hz


def _note_retargeting(kind: str, path: Path, error: dict[str, dict[str, float]], args: argparse.Namespace) -> None:
    """The armature's fit to the fused positions (fixed bone lengths cannot follow them exactly)."""
    if not args.json:
        body = error.get("body", {})
        note(
            f"{kind} {path.name}: retargeting error on the 16 body joints median {body.get('median', float('nan')):.1f}"
            f" mm, p90 {body.get('p90', float('nan')):.1f} mm (docs/animation.md)"
        )


def _armature_writer(write: Callable[..., Any], kind: str) -> PersonWriter:
    """A per-person writer for a format written from the fitted armature (BVH, FBX): it prints the retargeting
    error of each file it writes."""

    def writer(person: PersonTrack, take: TakeTracks, path: Path, args: argparse.Namespace) -> Path:
        written = write(
            path,
            _person_times_s(person, take),
            person.positions,
            orientations=person.orientations,
            fps=take.rate_hz,
            track_id=person.track_id,
        )
        _note_retargeting(kind, written.path, written.retargeting_error(), args)
        return written.path

    return writer


def _trc(person: PersonTrack, take: TakeTracks, path: Path, args: argparse.Namespace) -> Path:
    return write_trc(person, take, path, opensim_axes=not args.world_axes)


PER_PERSON_FORMATS: dict[str, tuple[str, PersonWriter]] = {
    "c3d": (".c3d", _c3d),
    "trc": (".trc", _trc),
    "bvh": (".bvh", _armature_writer(write_bvh_arrays, "BVH")),
    "fbx": (".fbx", _armature_writer(write_fbx_arrays, "FBX")),
}
"""Formats written one file per person: extension and writer."""
FORMATS = ("csv", *PER_PERSON_FORMATS)


def _select(frames: Iterator[FusedFrame], person: int | None, bar: Progress | None) -> Iterator[FusedFrame]:
    """The frames, advancing the progress bar, reduced to one track id when ``person`` is given."""
    for frame in frames:
        if bar is not None:
            bar.update()
        if person is None:
            yield frame
            continue
        keep = np.asarray(frame.track_ids) == person
        if not keep.any():
            continue
        fields: dict[str, Any] = {
            "track_ids": frame.track_ids[keep],
            "positions": frame.positions[keep],
            "n_agree": frame.n_agree[keep],
            "confidence": frame.confidence[keep],
            "contributors": frame.contributors[keep],
        }
        for optional in ("orientations", "position_std", "agreement_mm"):
            if getattr(frame, optional, None) is not None:
                fields[optional] = getattr(frame, optional)[keep]
        yield type(frame)(time_us=frame.time_us, sensor_ids=frame.sensor_ids, **fields)


def _output(args: argparse.Namespace, suffix: str) -> Path:
    out = args.output if args.output is not None else args.input.with_suffix(suffix)
    if out.resolve() == args.input.resolve():
        raise ConfigError(f"the output {out} is the input file; pass -o OTHER{suffix}")
    return out  # --output's folder was checked when parsed; the default's is the input's


def _person_path(out: Path, track_id: int, several: bool) -> Path:
    return out.with_name(f"{out.stem}_track{track_id}{out.suffix}") if several else out


def _fusion_poses(args: argparse.Namespace, cfg: RigConfig | None) -> dict[str, np.ndarray] | None:
    """Where the export fuses a recording's sensor frames: the poses ``fuse --input`` would use, levelled from
    the skeletons where no calibration defines the world (:func:`world_poses`); None: the config's or the
    recording's own."""
    if not fuses_sensor_frames(args.input, refuse=args.fuse):
        if args.up is not None or args.no_level or args.registered:
            raise ConfigError(
                "--up, --no-level and --registered apply where the export fuses a recording's sensor frames (a "
                "recording without a fused stream, or --fuse); this input is already fused"
            )
        return None
    take = open_inputs([str(args.input)], registered=args.registered, by=cfg.sync.by if cfg is not None else "device")
    return world_poses(args, take, cfg)


def _cmd_export(args: argparse.Namespace) -> int:
    if args.rate is not None and args.format == "csv":
        raise ConfigError("--rate applies to the per-person formats (c3d, trc): a CSV keeps the fused timestamps")
    if args.world_axes and args.format != "trc":
        raise ConfigError("--world-axes applies to --format trc only")
    if args.min_frames < 1:
        raise ConfigError(f"--min-frames must be at least 1, got {args.min_frames}")
    cfg = rig_config(args) if args.config is not None else None
    quiet = bool(args.json)
    source: FusedSource = open_fused(
        args.input,
        rig_config=cfg,
        preset_name=args.preset,
        refuse=args.fuse,
        progress=not quiet,
        world_from_sensor=_fusion_poses(args, cfg),
        smoother=args.smoother,
    )
    if not quiet:
        note(f"export: reading {args.input} ({source.kind})")
    # Offline fusion draws its own bar; a table or a recorded fused stream gets one here.
    bar = None
    if source.kind != "fused from the sensor frames":
        bar = Progress(source.total or 0, "read", enabled=False if quiet or not source.total else None)
    # Per-person formats pick the person after the grid is laid over the whole take, so the files of one
    # take line up whichever people are exported.
    frames = _select(source.frames, args.person if args.format == "csv" else None, bar)
    try:
        if args.format == "csv":
            summary = _export_table(args, frames)
        else:
            summary = _export_per_person(args, frames)
    except ModuleNotFoundError as exc:
        raise ConfigError(str(exc)) from None
    finally:
        if bar is not None:
            bar.close()
    summary = {"input": args.input, "source": source.kind, "format": args.format, **summary}
    if args.json:
        print_json(summary)
    return EXIT_OK


def _export_table(args: argparse.Namespace, frames: Iterator[FusedFrame]) -> dict[str, Any]:
    out = _output(args, ".csv")
    if out.suffix.lower() not in FUSED_FORMATS:
        raise ConfigError(f"--format csv writes {' or '.join(FUSED_FORMATS)}; got --output {out}")
    try:
        rows = write_fused(frames, out)
    except BaseException:
        out.unlink(missing_ok=True)  # no half-written table left behind a bad input
        raise
    if rows == 0 and args.person is not None:
        out.unlink(missing_ok=True)
        raise DataError(f"track id {args.person} does not appear in {args.input}")
    if not args.json:
        note(f"export: {rows} rows -> {out}")
    return {"files": [out], "rows": rows}


def _export_per_person(args: argparse.Namespace, frames: Iterator[FusedFrame]) -> dict[str, Any]:
    suffix, writer = PER_PERSON_FORMATS[args.format]
    take = take_tracks(frames, rate_hz=args.rate)
    if args.person is not None:
        persons = [take.person(args.person)]
    else:
        persons = [p for p in take.persons if p.n_frames >= args.min_frames]
        if not persons:
            raise DataError(
                f"no person is tracked for {args.min_frames} frames or more in {args.input} "
                f"(longest: {max(p.n_frames for p in take.persons)} frames); lower --min-frames"
            )
    out = _output(args, suffix)
    if out.suffix.lower() != suffix:
        raise ConfigError(f"--format {args.format} writes {suffix} files; got --output {out}")
    if not args.json:
        note(
            f"export: {take.instants} instants at {take.rate_hz:.3f} Hz, {len(take.persons)} person(s); "
            f"writing {len(persons)} {args.format.upper()} file(s)"
        )
    files = []
    with Progress(len(persons), f"write {args.format}", enabled=False if args.json else None) as bar:
        for person in persons:
            path = writer(person, take, _person_path(out, person.track_id, len(persons) > 1), args)
            files.append(path)
            gaps = float(person.gaps.mean())
            if not args.json:
                note(f"export: track {person.track_id}: {person.n_frames} frames, {gaps:.1%} gaps -> {path}")
            bar.update()
    return {
        "files": files,
        "rate_hz": take.rate_hz,
        "instants": take.instants,
        "collisions": take.collisions,
        "persons": [
            {"track_id": p.track_id, "first_frame": p.first_frame, "frames": p.n_frames, "gap_fraction": p.gaps.mean()}
            for p in persons
        ],
    }


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``export``."""
    export = commands.add_parser(
        "export",
        help=COMMAND_HELP["export"],
        description="Read fused skeletons from a fused table (.csv/.parquet), a recording's fused stream, or a "
        "recording of sensor frames (fused on the way, with --config's poses and [fusion] or the recording's "
        "calibration), and write them for other tools: csv = the fused table (docs/export.md); c3d = one C3D "
        "per person (joints as points, mm, gaps as invalid residuals); trc = one OpenSim marker file per "
        "person (joints as markers, mm, OpenSim's y-up axes, gaps blank); bvh = one BVH per person (an armature "
        "fitted to the joints, its rotations per frame, y up as Blender and MotionBuilder import it); fbx = the "
        "same armature as a binary FBX, written by Blender's own exporter (install it once with `skelfuse setup "
        "blender`). Per-person files are named OUT_track<ID>.<ext> when several people are written "
        "(docs/export.md, docs/animation.md).",
    )
    export.add_argument(
        "input", type=Path, metavar="FUSED", help=f"the input: {', '.join(INPUT_FORMATS)} (see the description)"
    )
    export.add_argument("--format", required=True, choices=FORMATS, help="what to write")
    add_output_option(
        export,
        metavar="OUT",
        help="output file (default: the input's name with the format's extension; csv: .csv or .parquet)",
    )
    export.add_argument("--person", type=INDEX, default=None, metavar="TRACK_ID", help="only this track id")
    export.add_argument(
        "--min-frames",
        type=COUNT,
        default=1,
        metavar="N",
        help="per-person formats: skip tracks shorter than N frames (default: %(default)s, every track)",
    )
    export.add_argument(
        "--rate",
        type=POSITIVE,
        default=None,
        metavar="HZ",
        help="per-person formats: the file's frame rate (default: from the timestamps, docs/export.md)",
    )
    export.add_argument(
        "--world-axes",
        action="store_true",
        help="trc: keep skelfuse's world axes (z up) instead of OpenSim's (y up)",
    )
    export.add_argument(
        "--config",
        type=Path,
        default=None,
        metavar="RIG.toml",
        help="recording of sensor frames: the rig's poses, [sync] and [fusion] (default: the recording's calibration)",
    )
    add_preset_option(
        export, default=None, what="recording of sensor frames: fusion preset", default_text=DEFAULT_PRESET
    )
    export.add_argument(
        "--smoother",
        choices=OFFLINE_SMOOTHERS,
        default=None,
        help="recording of sensor frames: zero-lag smoothing of the fused take (rts) or the live filter's output "
        "(none); default rts with the skelfuse preset",
    )
    export.add_argument(
        "--fuse", action="store_true", help="recording: fuse its sensor frames even if it holds a fused stream"
    )
    export.add_argument(
        "--registered",
        action="store_true",
        help="recording of sensor frames: its sensors' skeletons are already in one frame (identity poses, "
        "a world levelled from the skeletons as below); recorded identity poses are read so without it",
    )
    add_level_options(export)
    add_json_option(export, "a summary", "no progress output")
    export.set_defaults(func=_cmd_export)
