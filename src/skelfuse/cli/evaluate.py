"""``skelfuse eval paper|real|tracking|depth``: the paper's experiments, the real take, several people, the
depth-level fusion's tracker."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from skelfuse.cli.commands import COMMAND_HELP
from skelfuse.cli.common import (
    COUNT,
    EXISTING_DIR,
    EXISTING_FILE,
    EXIT_OK,
    POSITIVE,
    SEED,
    add_json_option,
    add_output_option,
    add_preset_option,
    add_seed_option,
    print_json,
)
from skelfuse.cli.inputs import INPUT_HELP, add_input_options, open_take
from skelfuse.cli.robustness import add_robustness_parser
from skelfuse.config import load_calibration, load_rig_config
from skelfuse.fusion.presets import COMPARED_PRESETS
from skelfuse.progress import note
from skelfuse.schema.errors import ConfigError
from skelfuse.sources.k4abt import TrackerSettings


def _cmd_eval_paper(args: argparse.Namespace) -> int:
    from skelfuse.eval import paper, report  # each command imports what it runs (start-up)

    result = paper.run_paper_eval(
        quick=args.quick,
        seed=args.seed,
        duration_s=args.duration,
        profile_path=args.profile,
        progress=not args.quiet,
        workers=args.workers,
    )
    if not args.no_files:
        report.write_suite(result, args.out)
    if args.json:
        print_json(result.to_dict())
    else:
        print(report.format_markdown(result))
        if not args.no_files:
            print(f"\nTables, CSV and figures written to {args.out}/", file=sys.stderr)
    return EXIT_OK


def _cmd_eval_real(args: argparse.Namespace) -> int:
    from skelfuse.eval import real, rig, rig_report

    specs = list(args.inputs)
    if not specs:  # the andyj1 3-sensor take: one input among others, its subordinates already registered
        specs = [f"{name}={args.data / file}" for name, file in real.VIEW_FILES.items()]
        args.registered = True
    if args.calibration is not None and args.auto_calibrate:
        raise ConfigError("give --calibration FILE or --auto-calibrate, not both")
    take = open_take(args, specs, quiet=args.json)
    calibration = load_calibration(args.calibration) if args.calibration is not None else None
    result = rig.run_rig_eval(
        take,
        calibration=calibration,
        auto_calibrate=args.auto_calibrate,
        presets=args.preset or rig.DEFAULT_PRESETS,
        eps_mm=args.eps,
        out_dir=args.out,
        progress=not args.json,
    )
    text = rig_report.format_markdown(result)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "report.md").write_text(text + "\n", encoding="utf-8")
    if args.json:
        print_json(result.to_dict())
    else:
        print(text)
        if args.out is not None:
            print(f"\nReport and plots written to {args.out}/", file=sys.stderr)
    return EXIT_OK


def _cmd_eval_tracking(args: argparse.Namespace) -> int:
    from skelfuse.eval.tracking import run_tracking_eval

    result = run_tracking_eval(quick=args.quick, seed=args.seed, preset_name=args.preset)
    if args.json:
        print_json(result.to_dict())
    else:
        print(result.format_markdown())
    return EXIT_OK


def _cmd_eval_depth(args: argparse.Namespace) -> int:
    from skelfuse.eval import depth
    from skelfuse.service.depth_stage import K4abtDepthTracker

    if args.sim_take not in depth.SIM_TAKES:
        raise ConfigError(f"--sim-take {args.sim_take}: expected one of {', '.join(sorted(depth.SIM_TAKES))}")
    if args.sim:
        note(f"eval depth: simulated {args.sim_take} take, {args.duration:g} s, seed {args.seed} (stand-in tracker)")
        instants, obs = depth.simulated_instants(args.sim_take, args.duration, args.seed)
        result = depth.evaluate_depth(
            instants,
            obs.sensor_ids,
            obs.world_from_sensor_calibrated,
            depth.sim_tracker,
            progress=not args.quiet,
            control=True,
        )
        print(result.table())
        print("\n(simulated input and the simulated stand-in tracker: a check of the evaluation, not of the SDK)")
        return EXIT_OK
    if args.config is None or not args.take:
        raise ConfigError("give the rig as --config RIG.toml and one --take ID=PATH.mkv per sensor (or --sim)")
    cfg = load_rig_config(args.config)
    takes = depth.mkv_takes(args.take, cfg)
    depth.require_sdk()  # before any reading: names pyk4a / libk4a / libk4abt, whichever is missing
    instants = depth.mkv_instants(takes, cfg, voxel_mm=cfg.depth.voxel_mm, max_frames=args.max_frames)
    by_id = cfg.poses()
    ids = tuple(takes)
    kinect = next((s.kinect for s in cfg.sensors if s.kinect is not None), None)
    settings = TrackerSettings.from_config(kinect.tracker) if kinect is not None else TrackerSettings()
    result = depth.evaluate_depth(
        instants,
        ids,
        np.stack([by_id[sid] for sid in ids]),
        lambda _: K4abtDepthTracker(settings, wait_ms=max(cfg.depth.tracker_wait_ms, 1000)),
        preset=cfg.fusion.preset,
        voxel_mm=cfg.depth.voxel_mm,
        progress=not args.quiet,
    )
    print(result.table())
    return EXIT_OK


def _default_data_dir() -> Path:
    """``../shared/data`` beside the working directory's project, where the team's real recordings live."""
    return Path.cwd().parent / "shared" / "data" / "azure-kinect-andyj1" / "saved_data_2_3dev"


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``eval`` with its sub-commands."""
    evaluate = commands.add_parser("eval", help=COMMAND_HELP["eval"])
    eval_commands = evaluate.add_subparsers(dest="eval_command", metavar="WHAT", required=True)

    _add_paper(eval_commands)
    _add_real(eval_commands)
    _add_tracking(eval_commands)
    _add_depth(eval_commands)
    add_robustness_parser(eval_commands)


def _add_paper(eval_commands: argparse._SubParsersAction) -> None:
    paper = eval_commands.add_parser(
        "paper",
        help="the paper's three experiments on simulated data with exact ground truth",
        description="Reproduce experiments 1-3 of Lee et al. 2022 (ablations A1-A5, DBSCAN eps sweep, number "
        "of sensors) on a simulated 4-sensor rig, against exact ground truth and against the paper's "
        "best-view reference. Writes markdown, CSV and PNG charts to --out.",
    )
    paper.add_argument("--quick", action="store_true", help="a small subset that runs in well under a minute")
    add_json_option(paper)
    add_output_option(
        paper,
        type=Path,
        default=Path("eval_out/paper"),
        dest="out",
        aliases=("--out",),
        metavar="DIR",
        help="output folder (default: %(default)s)",
    )
    paper.add_argument("--no-files", action="store_true", help="write no output folder, only print")
    add_seed_option(paper, default=0)
    paper.add_argument(
        "--duration",
        type=POSITIVE,
        default=None,
        metavar="SECONDS",
        help="length of each simulated take (default: the paper's ~33 s, or short with --quick)",
    )
    paper.add_argument(
        "--profile",
        type=EXISTING_FILE,
        default=None,
        help="simulator noise profile TOML (default: the packaged Azure Kinect profile)",
    )
    paper.add_argument("--workers", type=COUNT, default=2, help="worker processes (default: %(default)s)")
    paper.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    paper.set_defaults(func=_cmd_eval_paper)


def _add_real(eval_commands: argparse._SubParsersAction) -> None:
    real = eval_commands.add_parser(
        "real",
        help="report on any real recording of 2+ sensors: jitter, lag, agreement, gross errors, leave-one-out",
        description="Fuse a real recording with each preset and compare, per joint group (torso, arms, hands, "
        "legs, head), every preset with every single view: jitter, lag, agreement with each view where it is "
        "MEDIUM, gross errors, mirrored frames, dropouts, track ids, and leave-one-out error with 3+ sensors "
        "(docs/evaluation.md: what each metric can and cannot show). Without inputs: the andyj1 3-sensor take.",
    )
    real.add_argument("inputs", nargs="*", metavar="[ID=]PATH", help=INPUT_HELP)
    real.add_argument(
        "--data",
        type=EXISTING_DIR,
        default=_default_data_dir(),
        help="without inputs: the folder with joints_gen_{master,sub1,sub2}.csv (default: %(default)s)",
    )
    poses = real.add_mutually_exclusive_group()
    poses.add_argument("--calibration", type=Path, default=None, metavar="FILE", help="the rig's calibration TOML")
    poses.add_argument(
        "--auto-calibrate",
        action="store_true",
        help="skeleton calibration on the first half of the take, metrics on the second half",
    )
    real.add_argument(
        "--preset",
        action="append",
        default=[],
        help=f"fusion preset to evaluate; repeatable (default: {', '.join(COMPARED_PRESETS)})",
    )
    real.add_argument(
        "--eps", type=POSITIVE, default=None, help="DBSCAN radius in mm for every preset (default: each preset's own)"
    )
    add_json_option(real)
    add_output_option(
        real, type=Path, dest="out", aliases=("--out",), metavar="DIR", help="write report.md and the plots into DIR"
    )
    add_input_options(real)
    real.set_defaults(func=_cmd_eval_real)


def _add_tracking(eval_commands: argparse._SubParsersAction) -> None:
    tracking = eval_commands.add_parser(
        "tracking",
        help="several people: association, stable ids and per-person accuracy on simulated crowds",
        description="Simulate people crossing, a bystander seen by one sensor, people entering and leaving, and "
        "a crowd; fuse them with per-person tracking and report CLEAR-MOT figures (MOTA, MOTP, IDF1, id switches, "
        "fragmentation) and per-person accuracy against ground truth.",
    )
    tracking.add_argument("--quick", action="store_true", help="shorter takes, for CI")
    add_seed_option(tracking, default=0)
    add_preset_option(tracking, default="skelfuse")
    add_json_option(tracking)
    tracking.set_defaults(func=_cmd_eval_tracking)


def _add_depth(eval_commands: argparse._SubParsersAction) -> None:
    parser = eval_commands.add_parser(
        "depth",
        help="the depth-level fusion on recorded .mkv takes (needs the Body Tracking SDK): agreement with "
        "skeleton fusion",
        description="Replay one k4arecorder .mkv per sensor through the Body Tracking SDK (skeletons and person "
        "clouds from its body-index map), group them into instants, and run skeleton fusion, the depth mode and "
        "the hybrid mode over the same instants (the node's depth stage, the SDK as the tracker on each person's "
        "virtual image). Prints per mode: persons out per instant, agreement with skeleton fusion (mm over the "
        "evaluation joints; no ground truth on real takes) and the tracker's time per virtual image. Needs pyk4a "
        "(the `kinect` extra), the Azure Kinect Sensor SDK and the Body Tracking SDK on this machine; without them "
        "it stops at once naming what is missing. --sim runs the same evaluation on a simulated take with the "
        "simulated stand-in tracker, scored against the truth. Progress on stderr.",
    )
    parser.add_argument("--config", type=EXISTING_FILE, default=None, metavar="RIG.toml", help="the rig (poses, sync)")
    parser.add_argument(
        "--take", action="append", default=[], metavar="ID=PATH.mkv", help="one sensor's recording; repeat per sensor"
    )
    parser.add_argument(
        "--max-frames", type=COUNT, default=None, metavar="N", help="read at most N body frames per take"
    )
    parser.add_argument("--sim", action="store_true", help="a simulated take and the stand-in tracker instead")
    parser.add_argument(
        "--sim-take", default="crossing", metavar="NAME", help="--sim: the take, crossing or bystander (crossing)"
    )
    parser.add_argument("--duration", type=POSITIVE, default=4.0, metavar="S", help="--sim: seconds (4)")
    parser.add_argument("--seed", type=SEED, default=3, help="--sim: seed (3)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    parser.set_defaults(func=_cmd_eval_depth)
