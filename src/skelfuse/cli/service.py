"""The daemons' commands: ``capture``, ``fuse`` (live, or offline with --input), ``record``, ``replay``, ``status``."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from skelfuse.cli.commands import COMMAND_HELP
from skelfuse.cli.common import (
    EXISTING_FILE,
    EXIT_OK,
    NON_NEGATIVE,
    OFFLINE_SMOOTHERS,
    OUTPUT_FILE,
    PORT,
    POSITIVE,
    SEED,
    Number,
    add_json_option,
    add_output_option,
    add_preset_option,
    add_run_limits,
    add_zenoh_arguments,
    print_json,
    rig_config,
    run_limits,
    zenoh_conf,
)
from skelfuse.cli.inputs import (
    INPUT_HELP,
    add_input_options,
    add_level_options,
    open_take,
    single_recorded_mcap,
    world_poses,
)
from skelfuse.config import DEFAULT_PRESET, RigConfig
from skelfuse.config.access import FUSION, capture_identity
from skelfuse.export.csv import write_fused
from skelfuse.recording.offline import fuse_recording
from skelfuse.schema.errors import ConfigError
from skelfuse.service import worker
from skelfuse.service.lifecycle import Lifecycle
from skelfuse.service.node import NodeOptions, run_fusion_node
from skelfuse.service.recorder import run_recorder, run_replay
from skelfuse.service.status import watch_status
from skelfuse.service.viewer import ViewOptions
from skelfuse.wire.keys import validate_name

if TYPE_CHECKING:
    from skelfuse.recording.inputs import InputTake
log = logging.getLogger("skelfuse.cli")


def _cmd_capture(args: argparse.Namespace) -> int:

    cfg = rig_config(args)
    options = worker.WorkerOptions(
        gesture=args.gesture,
        take_duration_s=args.take_duration,
        seed=args.seed,
        loop=args.loop,
        speed=None if args.fast else args.speed,
        node_name=args.node,
        limits=run_limits(args),
        take_origin_ns=round(args.take_origin * 1e9),
        stall_timeout_s=cfg.capture.stall_timeout_s if args.stall_timeout is None else args.stall_timeout,
        open_timeout_s=cfg.capture.open_timeout_s if args.open_timeout is None else args.open_timeout,
    )
    report = worker.run_capture_worker(
        cfg,
        args.sensor,
        zenoh_conf(args, cfg, identity=capture_identity(cfg.sensor(args.sensor).capture_host)),
        options=options,
        lifecycle=Lifecycle(f"capture-{args.sensor}"),
    )
    if args.json:
        print_json({"frames_out": report.frames_out, "restarts": report.restarts, "stalls": report.stalls})
    return EXIT_OK


def _view_options(args: argparse.Namespace, cfg: RigConfig) -> ViewOptions:
    r = cfg.rerun
    if args.no_view:
        return ViewOptions(mode="off")
    if args.spawn and not args.serve:  # with --rrd FILE: a viewer where one can open, else the view saved to FILE
        return ViewOptions(
            mode="spawn", file=args.rrd, grpc_port=args.grpc_port or r.grpc_port, log_sensors=r.log_sensors
        )
    if args.rrd is not None:
        return ViewOptions(mode="save", file=args.rrd, log_sensors=r.log_sensors)
    if args.serve:
        return ViewOptions(
            mode="serve",
            bind=args.bind or r.bind,
            grpc_port=args.grpc_port or r.grpc_port,
            web_port=args.web_port if args.web_port is not None else r.web_port,
            log_sensors=r.log_sensors,
        )
    return ViewOptions(
        mode=r.mode, file=r.file, bind=r.bind, grpc_port=r.grpc_port, web_port=r.web_port, log_sensors=r.log_sensors
    )


def _cmd_fuse(args: argparse.Namespace) -> int:
    if args.input is not None:
        return _fuse_offline(args)
    if args.output is not None:
        raise ConfigError(
            "--output needs --input FILE (offline fusion of a recording); the live node publishes "
            "on zenoh, record it with `skelfuse record`"
        )
    if args.config is None:
        raise ConfigError("skelfuse fuse needs --config RIG.toml (live) or --input FILE --output OUT (offline)")

    cfg = rig_config(args)
    if args.preset is not None and args.preset != cfg.fusion.preset:
        log.info("fusion preset %s (--preset) instead of the config's %s", args.preset, cfg.fusion.preset)
        cfg = dataclasses.replace(cfg, fusion=dataclasses.replace(cfg.fusion, preset=args.preset))
        cfg.fusion.fusion_params()  # the config's [fusion.params] overrides must suit the new preset
    options = NodeOptions(
        node_name=args.node, status_period_s=args.status_period, limits=run_limits(args), view=_view_options(args, cfg)
    )
    report = run_fusion_node(
        cfg, zenoh_conf(args, cfg, identity=FUSION), options=options, lifecycle=Lifecycle("fusion")
    )
    if args.json:
        print_json({"frames_in": report.frames_in, "frames_out": report.frames_out, "status": report.status})
    return EXIT_OK


def _fuse_offline(args: argparse.Namespace) -> int:
    if args.output is None:
        raise ConfigError("skelfuse fuse --input FILE needs --output OUT.csv or OUT.parquet")
    cfg = rig_config(args) if args.config is not None else None
    take = open_take(args, args.input, cfg, quiet=args.json)
    source: Path | InputTake = take
    if single_recorded_mcap(args.input) and not (args.time_offset or args.registered or args.by):
        # a skelfuse recording as it is: grouped on its recorded host arrival times, exactly as live
        source = Path(args.input[0])
    poses = world_poses(args, take, cfg)
    frames = fuse_recording(
        source,
        rig_config=cfg,
        world_from_sensor=poses,
        preset_name=args.preset,
        progress=not args.json,
        smoother=args.smoother,
    )
    try:
        rows = write_fused(frames, args.output)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    if args.json:
        print_json({"input": [str(i) for i in args.input], "output": args.output, "rows": rows, "notes": take.notes})
    else:
        print(f"Fused {', '.join(args.input)} -> {args.output} ({rows} rows)", file=sys.stderr)
    return EXIT_OK


def _cmd_record(args: argparse.Namespace) -> int:
    cfg = rig_config(args)
    report = run_recorder(
        cfg, zenoh_conf(args, cfg), output=args.output, limits=run_limits(args), lifecycle=Lifecycle("recorder")
    )
    summary = {
        "path": report.path,
        "frames_written": report.frames_written,
        "fused_frames_written": report.fused_frames_written,
        "rejects": dict(report.rejects),
    }
    if args.json:
        print_json(summary)
    else:
        print(
            f"Recorded {report.frames_written} sensor frames and {report.fused_frames_written} fused frames "
            f"to {report.path}",
            file=sys.stderr,
        )
    return EXIT_OK


def _cmd_replay(args: argparse.Namespace) -> int:
    if args.rig is not None:
        try:
            validate_name(args.rig, "rig")
        except ValueError as exc:
            raise ConfigError(f"--rig: {exc}") from None
    cfg = rig_config(args) if args.config is not None else None
    source: Path | InputTake
    if single_recorded_mcap(args.file) and not (args.time_offset or args.registered):
        source = Path(args.file[0])  # byte for byte, on the recorded keys
    else:
        source = open_take(args, args.file, cfg, quiet=args.json)
    report = run_replay(
        source,
        zenoh_conf(args, cfg),
        speed=None if args.fast else args.speed,
        rig=args.rig or (cfg.name if cfg is not None and not isinstance(source, Path) else None),
        limits=run_limits(args),
        lifecycle=Lifecycle("replay"),
    )
    if args.json:
        print_json({"frames_out": report.frames_out, "topics": sorted(report.topics)})
    return EXIT_OK


def _cmd_status(args: argparse.Namespace) -> int:
    cfg = rig_config(args)
    watch_status(
        cfg,
        zenoh_conf(args, cfg),
        limits=run_limits(args),
        lifecycle=Lifecycle("status"),
        as_json=args.json,
        out=sys.stdout,
    )
    return EXIT_OK


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``capture``, ``fuse``, ``record``, ``replay`` and ``status``."""
    _add_capture(commands)
    _add_fuse(commands)
    _add_record(commands)
    _add_replay(commands)
    _add_status(commands)


def _add_capture(commands: argparse._SubParsersAction) -> None:
    capture = commands.add_parser(
        "capture",
        help=COMMAND_HELP["capture"],
        description="Run the capture worker of one sensor of the rig: read its frames from its source (sim, "
        "replay or kinect, as its [[sensors]] source says; docs/service.md, docs/kinect.md) and publish them over "
        "zenoh. Retries with backoff when the zenoh session cannot open or the source fails; a kinect source "
        "without pyk4a / the SDKs stops it with exit status 1. SIGINT/SIGTERM stop it cleanly.",
    )
    capture.add_argument("--config", type=EXISTING_FILE, required=True, metavar="RIG.toml", help="the rig config")
    capture.add_argument("--sensor", required=True, metavar="ID", help="which [[sensors]] id to publish")
    capture.add_argument(
        "--node", default=None, metavar="NAME", help="node name for status/liveliness keys (default: capture-<ID>)"
    )
    capture.add_argument(
        "--gesture",
        default="walking",
        choices=["hands_up_down", "jump", "squat", "lunge", "walking", "random"],
        help="sim: what the simulated person does; every worker of a rig must agree (default: %(default)s)",
    )
    capture.add_argument(
        "--take-duration",
        type=POSITIVE,
        default=20.0,
        metavar="SECONDS",
        help="sim: length of the simulated take before it loops (default: %(default)s)",
    )
    capture.add_argument(
        "--seed",
        type=SEED,
        default=0,
        help="sim: seed of the motion and (unless sensors[i].sim.seed) of the observations (default: %(default)s)",
    )
    capture.add_argument(
        "--take-origin",
        type=NON_NEGATIVE,
        default=0.0,
        metavar="UNIX_SECONDS",
        help="sim: Unix time at which the take's first frame plays; every worker of a rig must agree "
        "(default: %(default)s, the take aligned on the Unix epoch)",
    )
    capture.add_argument(
        "--loop",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="start the take / recording over at its end (default: sim loops, replay follows sensors[i].replay.loop)",
    )
    capture.add_argument("--speed", type=POSITIVE, default=1.0, help="replay: playback speed (default: %(default)s)")
    capture.add_argument("--fast", action="store_true", help="replay: as fast as possible")
    capture.add_argument(
        "--stall-timeout",
        type=Number(float, gt=0, le=3600),
        default=None,
        metavar="SECONDS",
        help="watchdog: restart a started source that delivers no frame for this long, a read that never returns "
        "included (default: [capture] stall_timeout_s, 10)",
    )
    capture.add_argument(
        "--open-timeout",
        type=Number(float, gt=0, le=3600),
        default=None,
        metavar="SECONDS",
        help="watchdog before the first answer: restart a source that has not opened (device open, tracker create, "
        "a master's wait for its subordinates) within this long (default: [capture] open_timeout_s, 120)",
    )
    add_json_option(capture, "a summary at exit")
    add_run_limits(capture, "publishing N frames")
    add_zenoh_arguments(capture)
    capture.set_defaults(func=_cmd_capture)


def _add_fuse(commands: argparse._SubParsersAction) -> None:
    fuse = commands.add_parser(
        "fuse",
        help=COMMAND_HELP["fuse"],
        description="Live: subscribe to every sensor of the rig, group the frames of one instant (device or "
        "host time, [sync]), fuse them as soon as all sensors arrived or the deadline passed, and publish on "
        "skelfuse/<rig>/fused/skeletons; status every [node] status_period_s on skelfuse/<rig>/status/<node>; "
        "answers `get skelfuse/<rig>/calibration`. Offline (--input): fuse a recording without zenoh and write "
        "CSV or Parquet.",
    )
    fuse.add_argument(
        "--config",
        type=EXISTING_FILE,
        default=None,
        metavar="RIG.toml",
        help="the rig config (required live; offline: poses, [sync] and [fusion] of the rig)",
    )
    fuse.add_argument(
        "--input", nargs="+", default=None, metavar="[ID=]PATH", help=f"offline: the recording(s). {INPUT_HELP}"
    )
    add_output_option(fuse, metavar="OUT", help="offline: fused frames to OUT.csv or OUT.parquet")
    fuse.add_argument(
        "--calibration",
        type=EXISTING_FILE,
        default=None,
        metavar="FILE",
        help="offline: the sensors' poses from this calibration file (what `skelfuse calibrate skeleton` "
        "writes); overrides the config's and the recording's",
    )
    add_level_options(fuse)
    fuse.add_argument(
        "--smoother",
        choices=OFFLINE_SMOOTHERS,
        default=None,
        help="offline: zero-lag smoothing of the whole take (rts) or the live filter's output, frame by frame (none); "
        "default rts with the skelfuse preset",
    )
    add_preset_option(
        fuse,
        default=None,
        what="fusion preset, live or offline",
        default_text=f"the config's [fusion] preset, else {DEFAULT_PRESET}",
    )
    fuse.add_argument(
        "--node",
        default=None,
        metavar="NAME",
        help="node name for status/liveliness keys (default: [node] name, else fusion)",
    )
    fuse.add_argument(
        "--status-period",
        type=Number(float, gt=0, le=3600),
        default=None,
        metavar="SECONDS",
        help="status period (default: [node] status_period_s)",
    )
    _add_live_view_options(fuse)
    add_json_option(fuse, "a summary at exit")
    add_input_options(fuse)
    add_run_limits(fuse, "publishing N fused frames")
    add_zenoh_arguments(fuse)
    fuse.set_defaults(func=_cmd_fuse)


def _add_live_view_options(parser: argparse.ArgumentParser) -> None:
    """The fusion node's live Rerun view: save, spawn, serve or none (each defaults to the config's [rerun])."""
    view = parser.add_argument_group("live view (default: the config's [rerun])")
    view.add_argument(
        "--rrd",
        type=OUTPUT_FILE,
        default=None,
        metavar="FILE",
        help="save the live view to FILE; with --spawn: where the view goes when no viewer can open here",
    )
    view.add_argument(
        "--spawn",
        action="store_true",
        help="spawn a local Rerun viewer (where none can open, e.g. no DISPLAY: one warning, then no view, or "
        "--rrd FILE)",
    )
    view.add_argument(
        "--serve",
        action="store_true",
        help="serve the view over gRPC (and the web viewer with --web-port) for remote viewers",
    )
    view.add_argument(
        "--bind", default=None, metavar="ADDR", help="address to serve on (default: [rerun] bind, 127.0.0.1)"
    )
    view.add_argument(
        "--grpc-port", type=PORT, default=None, metavar="PORT", help="gRPC port (default: [rerun] grpc_port, 9876)"
    )
    view.add_argument(
        "--web-port",
        type=PORT,
        default=None,
        metavar="PORT",
        help="with --serve: also serve the web viewer on this port",
    )
    view.add_argument("--no-view", action="store_true", help="no live view, whatever the config says")


def _add_record(commands: argparse._SubParsersAction) -> None:
    record = commands.add_parser(
        "record",
        help=COMMAND_HELP["record"],
        description="Subscribe to skelfuse/<rig>/sensors/*/skeletons (and, with [record] fused = true, the "
        "default, to skelfuse/<rig>/fused/skeletons) and write every payload with its timestamps to an MCAP "
        "file (docs/recording.md). Flushed every [record] flush_period_s: a killed "
        "recorder leaves a file readable up to its last flush; SIGINT/SIGTERM close it with its index.",
    )
    record.add_argument("--config", type=EXISTING_FILE, required=True, metavar="RIG.toml", help="the rig config")
    add_output_option(
        record,
        metavar="FILE",
        help="the .mcap file (default: <[record] directory or .>/<rig>-<UTC time>.mcap)",
    )
    add_json_option(record, "a summary at exit")
    add_run_limits(record, "writing N frames")
    add_zenoh_arguments(record)
    record.set_defaults(func=_cmd_record)


def _add_replay(commands: argparse._SubParsersAction) -> None:
    replay = commands.add_parser(
        "replay",
        help=COMMAND_HELP["replay"],
        description="Publish the sensor frames of an MCAP recording on their recorded keys, byte for byte, "
        "paced by their recorded host time, so a session can be fused again live with other settings. Other "
        "formats (one file per sensor, or a long CSV) are matched in time and published on "
        "skelfuse/<--rig, the config's rig, else replay>/sensors/<id>/skeletons, paced by their matched times.",
    )
    replay.add_argument("file", nargs="+", metavar="[ID=]PATH", help=INPUT_HELP)
    replay.add_argument("--speed", type=POSITIVE, default=1.0, help="playback speed (default: %(default)s)")
    replay.add_argument("--fast", action="store_true", help="as fast as possible")
    replay.add_argument(
        "--rig", default=None, metavar="NAME", help="publish under skelfuse/NAME/... instead of the recorded rig"
    )
    replay.add_argument(
        "--config",
        type=EXISTING_FILE,
        default=None,
        metavar="RIG.toml",
        help="take the zenoh settings from this rig config (default: zenoh defaults + flags)",
    )
    add_json_option(replay, "a summary at exit")
    add_input_options(replay)
    add_run_limits(replay, "publishing N frames")
    add_zenoh_arguments(replay)
    replay.set_defaults(func=_cmd_replay)


def _add_status(commands: argparse._SubParsersAction) -> None:
    status = commands.add_parser(
        "status",
        help=COMMAND_HELP["status"],
        description="Subscribe to skelfuse/<rig>/status/* and print one line per status message (rates, "
        "counts, latency), or the documents as JSON lines with --json.",
    )
    status.add_argument("--config", type=EXISTING_FILE, required=True, metavar="RIG.toml", help="the rig config")
    status.add_argument("--json", action="store_true", help="print each status document as one JSON line")
    add_run_limits(status, "printing N status messages")
    add_zenoh_arguments(status)
    status.set_defaults(func=_cmd_status)
