"""The ``skelfuse`` command line: parses arguments, calls the library, turns typed errors into exit codes.

Subcommands import their modules lazily so ``skelfuse --help`` stays fast and a missing optional
dependency only affects the command that needs it.
"""

from __future__ import annotations

import argparse
import contextlib
import faulthandler
import json
import logging
import signal
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from skelfuse import __version__
from skelfuse.errors import ConfigError, DataError, SkelfuseError

EXIT_OK = 0
EXIT_ERROR = 1
EXIT_USAGE = 2

log = logging.getLogger("skelfuse")


def _print_json(payload: dict[str, Any]) -> None:
    json.dump(payload, sys.stdout, indent=2, allow_nan=False, default=_json_default)
    sys.stdout.write("\n")


def _json_default(value: Any) -> Any:
    """numpy scalars and arrays, Paths: the types results may carry."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot serialize {type(value).__name__} to JSON")


def _cmd_eval_paper(args: argparse.Namespace) -> int:
    from skelfuse.eval import paper

    result = paper.run_paper_eval(
        out_dir=None if args.no_files else args.out,
        quick=args.quick,
        seed=args.seed,
        duration_s=args.duration,
        profile_path=args.profile,
        progress=not args.quiet,
        workers=args.workers,
    )
    if args.json:
        _print_json(result.to_dict())
    else:
        print(paper.format_markdown(result))
        if not args.no_files:
            print(f"\nTables, CSV and figures written to {args.out}/", file=sys.stderr)
    return EXIT_OK


def _cmd_eval_real(args: argparse.Namespace) -> int:
    from skelfuse.eval import real

    result = real.run_real_eval(args.data, eps_mm=args.eps)
    if args.json:
        _print_json(result.to_dict())
    else:
        text = real.format_markdown(result)
        print(text)
        if args.out is not None:
            args.out.mkdir(parents=True, exist_ok=True)
            (args.out / "report.md").write_text(text + "\n", encoding="utf-8")
            print(f"\nReport written to {args.out / 'report.md'}", file=sys.stderr)
    return EXIT_OK


def _cmd_bench_fusion(args: argparse.Namespace) -> int:
    from skelfuse.bench import fusion as bench_fusion

    result = bench_fusion.run_fusion_bench(
        sensor_counts=args.sensors,
        body_counts=args.bodies,
        preset_name=args.preset,
        n_frames=args.frames,
        quick=args.quick,
        progress=not args.quiet and not args.json,
    )
    if args.json:
        _print_json(result.to_dict())
    else:
        print(bench_fusion.format_table(result))
    return EXIT_OK if result.outputs_match else EXIT_ERROR


def _cmd_bench_people(args: argparse.Namespace) -> int:
    from skelfuse.bench.people import bench_people, format_people_bench

    result = bench_people(args.sensors, args.people, args.frames, preset_name=args.preset)
    if args.json:
        _print_json(result)
    else:
        print(format_people_bench(result))
    return EXIT_OK


def _cmd_eval_tracking(args: argparse.Namespace) -> int:
    from skelfuse.eval.tracking import run_tracking_eval

    result = run_tracking_eval(quick=args.quick, seed=args.seed, preset_name=args.preset)
    if args.json:
        _print_json(result.to_dict())
    else:
        print(result.format_markdown())
    return EXIT_OK


def _cmd_devices(args: argparse.Namespace) -> int:
    from skelfuse.sources.devices import describe_environment, format_devices, list_devices
    from skelfuse.sources.kinect import KinectUnavailable

    try:
        devices = list_devices()
    except KinectUnavailable:
        print(describe_environment())
        return EXIT_ERROR
    print(format_devices(devices))
    return EXIT_OK


def _cmd_demo(args: argparse.Namespace) -> int:
    from skelfuse import demo

    if args.offline:
        summary = demo.run_demo_offline(
            duration_s=args.duration,
            gesture=args.gesture,
            preset_name=args.preset,
            seed=args.seed,
            rrd_path=args.rrd,
            spawn=False if args.rrd is not None else None,
            realtime=args.realtime,
            progress=not args.json,
        )
    else:
        summary = demo.run_demo(
            duration_s=args.duration,
            gesture=args.gesture,
            preset_name=args.preset,
            seed=args.seed,
            rrd_path=args.rrd,
            spawn=False if args.rrd is not None or args.serve else None,
            serve=args.serve,
            progress=not args.json,
        )
    if args.json:
        _print_json(summary.to_dict())
    else:
        print(demo.format_summary(summary))
    return EXIT_OK


# -- service commands --------------------------------------------------------------------------------------


def _rig(args: argparse.Namespace) -> Any:
    from skelfuse.config import load_rig_config

    return load_rig_config(args.config)


def _zenoh_conf(args: argparse.Namespace, cfg: Any | None) -> Any:
    from skelfuse.config import RigConfig, zenoh_config, zenoh_flags

    if cfg is None:  # commands that may run without a rig config: zenoh defaults + flags
        cfg = RigConfig(name="skelfuse", sensors=(), source="<command line>")
    return zenoh_config(cfg, **zenoh_flags(args))


def _limits(args: argparse.Namespace) -> Any:
    from skelfuse.service.lifecycle import RunLimits

    try:
        return RunLimits(duration_s=args.duration, max_frames=getattr(args, "max_frames", None))
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def _cmd_capture(args: argparse.Namespace) -> int:
    from skelfuse.service.lifecycle import Lifecycle
    from skelfuse.service.worker import WorkerOptions, run_capture_worker

    cfg = _rig(args)
    options = WorkerOptions(
        gesture=args.gesture,
        take_duration_s=args.take_duration,
        seed=args.seed,
        loop=args.loop,
        speed=None if args.fast else args.speed,
        node_name=args.node,
        limits=_limits(args),
    )
    report = run_capture_worker(
        cfg, args.sensor, _zenoh_conf(args, cfg), options=options, lifecycle=Lifecycle(f"capture-{args.sensor}")
    )
    if args.json:
        _print_json({"frames_out": report.frames_out, "restarts": report.restarts})
    return EXIT_OK


def _view_options(args: argparse.Namespace, cfg: Any) -> Any:
    from skelfuse.service.viewer import ViewOptions

    r = cfg.rerun
    if args.no_view:
        return ViewOptions(mode="off")
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
    if args.spawn:
        return ViewOptions(mode="spawn", grpc_port=args.grpc_port or r.grpc_port, log_sensors=r.log_sensors)
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
    from skelfuse.service.lifecycle import Lifecycle
    from skelfuse.service.node import NodeOptions, run_fusion_node

    cfg = _rig(args)
    options = NodeOptions(
        node_name=args.node, status_period_s=args.status_period, limits=_limits(args), view=_view_options(args, cfg)
    )
    report = run_fusion_node(cfg, _zenoh_conf(args, cfg), options=options, lifecycle=Lifecycle("fusion"))
    if args.json:
        _print_json({"frames_in": report.frames_in, "frames_out": report.frames_out, "status": report.status})
    return EXIT_OK


def _fuse_offline(args: argparse.Namespace) -> int:
    from skelfuse.recording import fuse_recording, write_fused

    if args.output is None:
        raise ConfigError("skelfuse fuse --input FILE needs --output OUT.csv or OUT.parquet")
    cfg = _rig(args) if args.config is not None else None
    frames = fuse_recording(args.input, rig_config=cfg, preset_name=args.preset, progress=not args.json)
    try:
        rows = write_fused(frames, args.output)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    if args.json:
        _print_json({"input": args.input, "output": args.output, "rows": rows})
    else:
        print(f"Fused {args.input} -> {args.output} ({rows} rows)", file=sys.stderr)
    return EXIT_OK


def _cmd_record(args: argparse.Namespace) -> int:
    from skelfuse.service.lifecycle import Lifecycle
    from skelfuse.service.recorder import run_recorder

    cfg = _rig(args)
    report = run_recorder(
        cfg, _zenoh_conf(args, cfg), output=args.output, limits=_limits(args), lifecycle=Lifecycle("recorder")
    )
    summary = {"path": report.path, "frames_written": report.frames_written, "rejects": dict(report.rejects)}
    if args.json:
        _print_json(summary)
    else:
        print(f"Recorded {report.frames_written} frames to {report.path}", file=sys.stderr)
    return EXIT_OK


def _cmd_replay(args: argparse.Namespace) -> int:
    from skelfuse.service.lifecycle import Lifecycle
    from skelfuse.service.recorder import run_replay

    if args.rig is not None:
        from skelfuse.wire.keys import validate_name

        try:
            validate_name(args.rig, "rig")
        except ValueError as exc:
            raise ConfigError(f"--rig: {exc}") from None
    cfg = _rig(args) if args.config is not None else None
    report = run_replay(
        args.file,
        _zenoh_conf(args, cfg),
        speed=None if args.fast else args.speed,
        rig=args.rig,
        limits=_limits(args),
        lifecycle=Lifecycle("replay"),
    )
    if args.json:
        _print_json({"frames_out": report.frames_out, "topics": sorted(report.topics)})
    return EXIT_OK


def _cmd_status(args: argparse.Namespace) -> int:
    from skelfuse.service.lifecycle import Lifecycle
    from skelfuse.service.status import watch_status

    cfg = _rig(args)
    watch_status(
        cfg,
        _zenoh_conf(args, cfg),
        limits=_limits(args),
        lifecycle=Lifecycle("status"),
        as_json=args.json,
        out=sys.stdout,
    )
    return EXIT_OK


def _cmd_bench_latency(args: argparse.Namespace) -> int:
    from skelfuse.bench import latency

    result = latency.run_latency_bench(
        sensor_counts=args.sensors, duration_s=args.duration, sweep=not args.no_sweep, progress=not args.json
    )
    if args.json:
        _print_json(result.to_dict())
    else:
        print(latency.format_table(result))
    return EXIT_OK


def _default_data_dir() -> Path:
    """``../shared/data`` beside the working directory's project, where the team's real recordings live."""
    return Path.cwd().parent / "shared" / "data" / "azure-kinect-andyj1" / "saved_data_2_3dev"


def build_parser() -> argparse.ArgumentParser:
    from skelfuse.config import DEFAULT_PRESET

    parser = argparse.ArgumentParser(
        prog="skelfuse",
        description="Fuse the skeletons of several Azure Kinect body trackers into one accurate, smooth skeleton.",
    )
    parser.add_argument("--version", action="version", version=f"skelfuse {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages on stderr")
    parser.add_argument(
        "--log-format",
        choices=["text", "json"],
        default="text",
        help="logs on stderr as text lines or as one JSON object per line (default: %(default)s)",
    )
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    # demo -----------------------------------------------------------------------------------------
    demo = commands.add_parser(
        "demo",
        help="a simulated 4-sensor rig fused live over zenoh and shown in Rerun (a .rrd where there is no screen)",
        description="Start a simulated rig of four virtual Azure Kinects: four capture workers (subprocesses) "
        "publish over zenoh on loopback (peer mode, no router, no multicast), the fusion node fuses them live "
        "and draws raw and fused skeletons in the Rerun viewer. Without a display (or with --rrd) the view is "
        "saved to a .rrd file. Runs for --duration seconds of fused output or until Ctrl-C, then prints "
        "frames fused, accuracy against the simulator's ground truth and latency p50/p99.",
    )
    demo.add_argument(
        "--duration",
        type=float,
        default=20.0,
        metavar="SECONDS",
        help="how long to run, seconds of fused output (default: %(default)s); with --offline: the take's length",
    )
    demo.add_argument(
        "--gesture",
        default="walking",
        choices=["hands_up_down", "jump", "squat", "lunge", "walking", "random"],
        help="what the simulated person does (default: %(default)s)",
    )
    demo.add_argument(
        "--preset", default=DEFAULT_PRESET, help="fusion preset: skelfuse, or the paper's A1..A5 (default: %(default)s)"
    )
    demo.add_argument("--seed", type=int, default=0, help="simulation seed (default: %(default)s)")
    demo.add_argument(
        "--rrd", type=Path, default=None, metavar="FILE", help="save the recording to FILE instead of spawning a viewer"
    )
    demo.add_argument(
        "--serve",
        action="store_true",
        help="serve the view to Rerun viewers (gRPC on 127.0.0.1:9876) instead of spawning one",
    )
    demo.add_argument(
        "--offline",
        action="store_true",
        help="the old single-process demo: simulate and fuse in one loop, without zenoh or workers",
    )
    demo.add_argument(
        "--realtime",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="with --offline: pace frames at 30 Hz (default: only when a live viewer is open)",
    )
    demo.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    demo.set_defaults(func=_cmd_demo)

    # eval -----------------------------------------------------------------------------------------
    evaluate = commands.add_parser("eval", help="reproduce the paper's experiments / evaluate on real data")
    eval_commands = evaluate.add_subparsers(dest="eval_command", metavar="WHAT", required=True)

    paper = eval_commands.add_parser(
        "paper",
        help="the paper's three experiments on simulated data with exact ground truth",
        description="Reproduce experiments 1-3 of Lee et al. 2022 (ablations A1-A5, DBSCAN eps sweep, number "
        "of sensors) on a simulated 4-sensor rig, against exact ground truth and against the paper's "
        "best-view reference. Writes markdown, CSV and PNG charts to --out.",
    )
    paper.add_argument("--quick", action="store_true", help="a small subset that runs in well under a minute")
    paper.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    paper.add_argument("--out", type=Path, default=Path("eval_out/paper"), help="output folder (default: %(default)s)")
    paper.add_argument("--no-files", action="store_true", help="write no output folder, only print")
    paper.add_argument("--seed", type=int, default=0, help="simulation seed (default: %(default)s)")
    paper.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="SECONDS",
        help="length of each simulated take (default: the paper's ~33 s, or short with --quick)",
    )
    paper.add_argument(
        "--profile",
        type=Path,
        default=None,
        help="simulator noise profile TOML (default: the packaged Azure Kinect profile)",
    )
    paper.add_argument("--workers", type=int, default=2, help="worker processes (default: %(default)s)")
    paper.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    paper.set_defaults(func=_cmd_eval_paper)

    real = eval_commands.add_parser(
        "real",
        help="fuse the real 3-sensor Azure Kinect take and report agreement, jitter and leave-one-out error",
    )
    real.add_argument(
        "--data",
        type=Path,
        default=_default_data_dir(),
        help="folder with joints_gen_{master,sub1,sub2,sync}.csv (default: %(default)s)",
    )
    real.add_argument(
        "--eps", type=float, default=None, help="DBSCAN radius in mm for every preset (default: each preset's own)"
    )
    real.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    real.add_argument("--out", type=Path, default=None, help="also write report.md into this folder")
    real.set_defaults(func=_cmd_eval_real)

    tracking = eval_commands.add_parser(
        "tracking",
        help="several people: association, stable ids and per-person accuracy on simulated crowds",
        description="Simulate people crossing, a bystander seen by one sensor, people entering and leaving, and "
        "a crowd; fuse them with per-person tracking and report CLEAR-MOT figures (MOTA, MOTP, IDF1, id switches, "
        "fragmentation) and per-person accuracy against ground truth.",
    )
    tracking.add_argument("--quick", action="store_true", help="shorter takes, for CI")
    tracking.add_argument("--seed", type=int, default=0, help="simulation seed (default: %(default)s)")
    tracking.add_argument("--preset", default="skelfuse", help="fusion preset (default: %(default)s)")
    tracking.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    tracking.set_defaults(func=_cmd_eval_tracking)

    # bench ----------------------------------------------------------------------------------------
    bench = commands.add_parser("bench", help="measure speed")
    bench_commands = bench.add_subparsers(dest="bench_command", metavar="WHAT", required=True)
    fusion = bench_commands.add_parser(
        "fusion",
        help="time per fused frame against a scikit-learn + filterpy reference on the same inputs",
    )
    fusion.add_argument(
        "--sensors",
        type=int,
        nargs="+",
        default=[1, 2, 4, 5, 8, 16],
        metavar="N",
        help="sensor counts (default: %(default)s)",
    )
    fusion.add_argument(
        "--bodies", type=int, nargs="+", default=[1, 3, 6], metavar="N", help="body counts (default: %(default)s)"
    )
    fusion.add_argument("--preset", default="A5", help="fusion preset to time (default: %(default)s)")
    fusion.add_argument("--frames", type=int, default=300, help="timed frames per case (default: %(default)s)")
    fusion.add_argument("--quick", action="store_true", help="fewer frames and a few cases, for CI")
    fusion.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    fusion.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    fusion.set_defaults(func=_cmd_bench_fusion)

    people = bench_commands.add_parser(
        "people",
        help="time per frame of multi-person fusion (association + tracks + fusion) on a simulated crowd",
    )
    people.add_argument("--sensors", type=int, default=8, help="sensors in the rig (default: %(default)s)")
    people.add_argument("--people", type=int, default=6, help="people in the crowd (default: %(default)s)")
    people.add_argument("--frames", type=int, default=300, help="timed frames (default: %(default)s)")
    people.add_argument("--preset", default="skelfuse", help="fusion preset (default: %(default)s)")
    people.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    people.set_defaults(func=_cmd_bench_people)

    latency = bench_commands.add_parser(
        "latency",
        help="publish -> fused-receive latency over zenoh on loopback, the node's own latency, max sensors",
        description="Start a fusion node (subprocess) on loopback zenoh, publish N simulated sensors at 30 Hz "
        "from this process and time every fused frame: publish -> fused receive p50/p99/max, the node's own "
        "added latency (from its status), and a sweep for the largest sensor count this machine sustains at "
        "30 Hz. Prints absolute figures; targets: node adds <= 1 ms p99, publish -> subscriber <= 5 ms p99 "
        "for 5 sensors.",
    )
    latency.add_argument(
        "--sensors",
        type=int,
        nargs="+",
        default=[4, 5, 8],
        metavar="N",
        help="sensor counts to measure (default: %(default)s)",
    )
    latency.add_argument(
        "--duration",
        type=float,
        default=5.0,
        metavar="SECONDS",
        help="measured seconds per sensor count (default: %(default)s)",
    )
    latency.add_argument("--no-sweep", action="store_true", help="skip the search for the largest sensor count")
    latency.add_argument("--json", action="store_true", help="print the results as JSON on stdout")
    latency.set_defaults(func=_cmd_bench_latency)

    _add_service_commands(commands)
    return parser


def _add_run_limits(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="SECONDS",
        help="stop cleanly after this many seconds (default: run until SIGINT/SIGTERM)",
    )
    parser.add_argument(
        "--max-frames", type=int, default=None, metavar="N", help=f"stop cleanly after {what} (default: no limit)"
    )


def _add_service_commands(commands: Any) -> None:
    from skelfuse.config import DEFAULT_PRESET, add_zenoh_arguments

    # capture ----------------------------------------------------------------------------------------
    capture = commands.add_parser(
        "capture",
        help="capture worker: publish one sensor's frames on skelfuse/<rig>/sensors/<id>/skeletons",
        description="Run the capture worker of one sensor of the rig: read its frames from its source (sim, "
        "replay; kinect is a separate issue) and publish them over zenoh. Retries with backoff when the zenoh "
        "session cannot open or the source fails. SIGINT/SIGTERM stop it cleanly.",
    )
    capture.add_argument("--config", type=Path, required=True, metavar="RIG.toml", help="the rig config")
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
        type=float,
        default=20.0,
        metavar="SECONDS",
        help="sim: length of the simulated take before it loops (default: %(default)s)",
    )
    capture.add_argument(
        "--seed",
        type=int,
        default=0,
        help="sim: seed of the motion and (unless sensors[i].sim.seed) of the observations (default: %(default)s)",
    )
    capture.add_argument(
        "--loop",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="start the take / recording over at its end (default: sim loops, replay follows sensors[i].replay.loop)",
    )
    capture.add_argument("--speed", type=float, default=1.0, help="replay: playback speed (default: %(default)s)")
    capture.add_argument("--fast", action="store_true", help="replay: as fast as possible")
    capture.add_argument("--json", action="store_true", help="print a JSON summary on stdout at exit")
    _add_run_limits(capture, "publishing N frames")
    add_zenoh_arguments(capture)
    capture.set_defaults(func=_cmd_capture)

    # fuse -------------------------------------------------------------------------------------------
    fuse = commands.add_parser(
        "fuse",
        help="fusion node (live, over zenoh) or offline fusion of a recording (--input FILE --output OUT)",
        description="Live: subscribe to every sensor of the rig, group the frames of one instant (device or "
        "host time, [sync]), fuse them as soon as all sensors arrived or the deadline passed, and publish on "
        "skelfuse/<rig>/fused/skeletons; status every [node] status_period_s on skelfuse/<rig>/status/<node>; "
        "answers `get skelfuse/<rig>/calibration`. Offline (--input): fuse a recording without zenoh and write "
        "CSV or Parquet.",
    )
    fuse.add_argument(
        "--config",
        type=Path,
        default=None,
        metavar="RIG.toml",
        help="the rig config (required live; offline: poses, [sync] and [fusion] of the rig)",
    )
    fuse.add_argument("--input", type=Path, default=None, metavar="FILE", help="offline: an MCAP recording")
    fuse.add_argument(
        "--output", type=Path, default=None, metavar="OUT", help="offline: fused frames to OUT.csv or OUT.parquet"
    )
    fuse.add_argument(
        "--preset",
        default=None,
        help=f"offline: fusion preset, {DEFAULT_PRESET} or the paper's A1..A5 "
        f"(default: the config's [fusion] preset, else {DEFAULT_PRESET})",
    )
    fuse.add_argument(
        "--node",
        default=None,
        metavar="NAME",
        help="node name for status/liveliness keys (default: [node] name, else fusion)",
    )
    fuse.add_argument(
        "--status-period",
        type=float,
        default=None,
        metavar="SECONDS",
        help="status period (default: [node] status_period_s)",
    )
    view = fuse.add_argument_group("live view (default: the config's [rerun])")
    view.add_argument("--rrd", type=Path, default=None, metavar="FILE", help="save the live view to FILE")
    view.add_argument("--spawn", action="store_true", help="spawn a local Rerun viewer")
    view.add_argument(
        "--serve",
        action="store_true",
        help="serve the view over gRPC (and the web viewer with --web-port) for remote viewers",
    )
    view.add_argument(
        "--bind", default=None, metavar="ADDR", help="address to serve on (default: [rerun] bind, 127.0.0.1)"
    )
    view.add_argument(
        "--grpc-port", type=int, default=None, metavar="PORT", help="gRPC port (default: [rerun] grpc_port, 9876)"
    )
    view.add_argument(
        "--web-port",
        type=int,
        default=None,
        metavar="PORT",
        help="with --serve: also serve the web viewer on this port",
    )
    view.add_argument("--no-view", action="store_true", help="no live view, whatever the config says")
    fuse.add_argument("--json", action="store_true", help="print a JSON summary on stdout at exit")
    _add_run_limits(fuse, "publishing N fused frames")
    add_zenoh_arguments(fuse)
    fuse.set_defaults(func=_cmd_fuse)

    # record -----------------------------------------------------------------------------------------
    record = commands.add_parser(
        "record",
        help="record every raw sensor frame of the rig to an MCAP file",
        description="Subscribe to skelfuse/<rig>/sensors/*/skeletons and write every payload with both "
        "timestamps to an MCAP file (docs/recording.md). Flushed every [record] flush_period_s: a killed "
        "recorder leaves a file readable up to its last flush; SIGINT/SIGTERM close it with its index.",
    )
    record.add_argument("--config", type=Path, required=True, metavar="RIG.toml", help="the rig config")
    record.add_argument(
        "--output",
        type=Path,
        default=None,
        metavar="FILE",
        help="the .mcap file (default: <[record] directory or .>/<rig>-<UTC time>.mcap)",
    )
    record.add_argument("--json", action="store_true", help="print a JSON summary on stdout at exit")
    _add_run_limits(record, "writing N frames")
    add_zenoh_arguments(record)
    record.set_defaults(func=_cmd_record)

    # replay -----------------------------------------------------------------------------------------
    replay = commands.add_parser(
        "replay",
        help="republish a recording's sensor frames over zenoh (original or maximum speed)",
        description="Publish the sensor frames of an MCAP recording on their recorded keys, byte for byte, "
        "paced by their recorded host time, so a session can be fused again live with other settings.",
    )
    replay.add_argument("file", type=Path, metavar="FILE", help="an MCAP recording made by skelfuse record")
    replay.add_argument("--speed", type=float, default=1.0, help="playback speed (default: %(default)s)")
    replay.add_argument("--fast", action="store_true", help="as fast as possible")
    replay.add_argument(
        "--rig", default=None, metavar="NAME", help="publish under skelfuse/NAME/... instead of the recorded rig"
    )
    replay.add_argument(
        "--config",
        type=Path,
        default=None,
        metavar="RIG.toml",
        help="take the zenoh settings from this rig config (default: zenoh defaults + flags)",
    )
    replay.add_argument("--json", action="store_true", help="print a JSON summary on stdout at exit")
    _add_run_limits(replay, "publishing N frames")
    add_zenoh_arguments(replay)
    replay.set_defaults(func=_cmd_replay)

    # status -----------------------------------------------------------------------------------------
    status = commands.add_parser(
        "status",
        help="print the status messages of the rig's nodes",
        description="Subscribe to skelfuse/<rig>/status/* and print one line per status message (rates, "
        "counts, latency), or the documents as JSON lines with --json.",
    )
    status.add_argument("--config", type=Path, required=True, metavar="RIG.toml", help="the rig config")
    status.add_argument("--json", action="store_true", help="print each status document as one JSON line")
    _add_run_limits(status, "N status messages")
    add_zenoh_arguments(status)
    status.set_defaults(func=_cmd_status)

    # devices and calibration ------------------------------------------------------------------------
    devices = commands.add_parser(
        "devices",
        help="list connected Azure Kinect / Femto Bolt sensors (serial, firmware, sync jacks)",
        description="List connected sensors through pyk4a / libk4a. Where the SDK or the kinect extra is missing, "
        "says what is missing and how to install it.",
    )
    devices.set_defaults(func=_cmd_devices)

    from skelfuse.calibration.commands import add_calibrate_parser

    add_calibrate_parser(commands)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    from skelfuse.service.lifecycle import configure_logging

    configure_logging(verbose=args.verbose, fmt=args.log_format)
    try:
        return int(args.func(args))
    except (ConfigError, DataError) as exc:
        print(f"skelfuse: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except SkelfuseError as exc:
        print(f"skelfuse: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print("skelfuse: interrupted", file=sys.stderr)
        return 130


def entrypoint() -> None:
    """Console-script entry point (``[project.scripts]``, ``python -m skelfuse``)."""
    if hasattr(signal, "SIGUSR1"):
        with contextlib.suppress(OSError, ValueError, AttributeError):  # no real stderr: skip it
            faulthandler.register(signal.SIGUSR1, all_threads=True)  # `kill -USR1 PID` dumps a stuck node's stacks
    sys.exit(main())
