"""``skelfuse calibrate ...``: capture RGB-D frames, run a calibration method, write the file.

Sub-commands (``docs/calibration.md`` is the user's procedure)::

    calibrate capture  --config RIG.toml --out DIR --frames N    live Azure Kinects (pyk4a) -> RGB-D folder
    calibrate sphere   DIR [--config RIG.toml] [--output FILE]   sensor to sensor (paper 2.1.1) -> file
    calibrate marker   DIR [--config RIG.toml] [--output FILE]   master to world (paper 2.1.2), re-anchors the file
    calibrate skeleton (--recording REC.mcap | --take ID=FILE ...)   sensor to sensor from a walk -> file
    calibrate check    (--recording REC.mcap | --take ID=FILE ...)   has a sensor moved since? exit 3 if so
    calibrate refine   --recording REC.mcap --config RIG.toml | --sim  ICP on person clouds of a walk -> file

The RGB-D folder they read and write: :mod:`skelfuse.calibration.rgbd_folder`.

    DIR/<sensor_id>/intrinsics.json     {"fx", "fy", "cx", "cy", "width", "height"} of the depth camera, px
    DIR/<sensor_id>/color_000000.png    BGR colour registered to depth (same pixels as the depth image)
    DIR/<sensor_id>/depth_000000.png    uint16 depth, mm, 0 = invalid
    ...                                 the same number in every sensor's folder = the same instant

Exit codes: 0 done; 3 (:data:`EXIT_ATTENTION`) the calibration needs attention (a "bad" skeleton verdict,
a moved sensor); typed errors (:mod:`skelfuse.schema.errors`) are raised and turned into exit codes by
:mod:`skelfuse.cli`.
Progress goes to stderr, results to stdout.

"""

from __future__ import annotations

import argparse
from pathlib import Path

from skelfuse.cli.calibrate_run import (
    DEFAULT_OUTPUT,
    cmd_capture,
    cmd_check,
    cmd_marker,
    cmd_refine,
    cmd_skeleton,
    cmd_sphere,
)
from skelfuse.cli.commands import COMMAND_HELP
from skelfuse.cli.common import (
    COUNT,
    EXISTING_DIR,
    EXISTING_FILE,
    INDEX,
    OUTPUT_FILE,
    POSITIVE,
    SEED,
    Number,
    add_output_option,
)
from skelfuse.cli.inputs import add_input_options

# ----------------------------------------------------------------------------------------------------------
# parser
# ----------------------------------------------------------------------------------------------------------


def _add_output(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        type=EXISTING_FILE,
        default=None,
        metavar="RIG.toml",
        help="the rig config: its sensors are checked, its sync master is the default master and "
        "its [calibration] file the default output",
    )
    add_output_option(
        parser,
        metavar="FILE",
        help=f"calibration TOML to write (default: the rig config's [calibration] file, else {DEFAULT_OUTPUT})",
    )


def _add_take(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--recording",
        type=EXISTING_FILE,
        default=None,
        metavar="REC",
        help="a recording of one person walking holding every sensor (a `skelfuse record` MCAP, a long CSV); "
        "frames grouped by time, first body per sensor",
    )
    parser.add_argument(
        "--take",
        action="append",
        default=[],
        metavar="[ID=]PATH",
        help="one recording per sensor, any format of docs/recordings.md (offline_processor .json, extractor "
        "folder, andyj1 .csv, long .csv, .mkv, MCAP); frames matched by device time where the files have it, "
        "by index where not (the output says which); repeat per sensor",
    )
    add_input_options(parser)
    parser.add_argument(
        "--master",
        default=None,
        metavar="ID",
        help="sensor whose pose anchors the others (default: the stored calibration's master, else "
        "the rig's sync master, else the first sensor)",
    )
    parser.add_argument(
        "--max-frames",
        type=COUNT,
        default=None,
        metavar="N",
        help="use only the first N frames of the take (default: all)",
    )
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``calibrate`` with its sub-commands (capture, sphere, marker, skeleton, check) to ``commands``."""
    calibrate = commands.add_parser(
        "calibrate",
        help=COMMAND_HELP["calibrate"],
        description="Calibrate the rig: sensor to sensor from a red ball (sphere) or from a person walking "
        "(skeleton), then sensor to world from an ArUco plate on the floor (marker); check a stored "
        "calibration against a new walk (check). Procedure: docs/calibration.md. Exit code 3: the calibration "
        "needs attention (bad verdict, moved sensor).",
    )
    sub = calibrate.add_subparsers(dest="calibrate_command", metavar="METHOD", required=True)

    _add_capture(sub)
    _add_sphere(sub)
    _add_marker(sub)
    _add_skeleton(sub)
    _add_check(sub)
    _add_refine(sub)


def _add_capture(sub: argparse._SubParsersAction) -> None:
    capture = sub.add_parser(
        "capture",
        help="grab colour (registered to depth) + depth frames from the rig's Azure Kinects into an RGB-D folder",
        description="Open every kinect sensor of the rig (pyk4a, the 'kinect' extra), subordinates first, and "
        "write N synchronized frames per sensor: <out>/<sensor_id>/intrinsics.json, color_%06d.png "
        "(capture.transformed_color: colour warped into the depth camera), depth_%06d.png (uint16 mm). Carry "
        "the ball through the space while it runs, or show the marker plate to the master.",
    )
    capture.add_argument("--config", type=EXISTING_FILE, required=True, metavar="RIG.toml", help="the rig config")
    add_output_option(
        capture, type=Path, required=True, dest="out", aliases=("--out",), metavar="DIR", help="RGB-D folder to write"
    )
    capture.add_argument(
        "--frames",
        type=COUNT,
        default=300,
        metavar="N",
        help="frames to write per sensor (default: %(default)s; the paper used 1000 ball positions)",
    )
    capture.add_argument(
        "--every",
        type=COUNT,
        default=3,
        metavar="K",
        help="keep every K-th synchronized capture, so the ball moves between frames "
        "(default: %(default)s: 10 frames/s at 30 fps)",
    )
    capture.add_argument(
        "--sensors",
        nargs="+",
        default=None,
        metavar="ID",
        help="only these sensors (default: every kinect sensor of the rig)",
    )
    capture.add_argument(
        "--color-resolution",
        default="720P",
        choices=["720P", "1080P", "1440P", "1536P", "2160P", "3072P"],
        help="colour camera mode where the rig config leaves colour off (default: %(default)s)",
    )
    capture.add_argument(
        "--warmup",
        type=INDEX,
        default=30,
        metavar="N",
        help="captures dropped first while auto exposure settles (default: %(default)s)",
    )
    capture.add_argument(
        "--timeout-s",
        type=POSITIVE,
        default=2.0,
        metavar="SECONDS",
        help="longest wait for one capture (default: %(default)s)",
    )
    capture.add_argument(
        "--tolerance-ms",
        type=POSITIVE,
        default=5.0,
        metavar="MS",
        help="device times of one synchronized frame may differ by this much (default: %(default)s)",
    )
    capture.set_defaults(func=cmd_capture)


def _add_sphere(sub: argparse._SubParsersAction) -> None:
    sphere = sub.add_parser(
        "sphere",
        help="sensor-to-sensor calibration from a coloured ball carried through the space (paper 2.1.1)",
        description="Find the ball (hue/saturation histogram, RANSAC sphere of known radius) in every frame of "
        "every sensor of an RGB-D folder, fit each sensor's ball trajectory to the master's and write the "
        "calibration (world = the master's frame until `calibrate marker` puts it on the floor). Prints the "
        "residual per sensor (RMS distance of the fitted trajectories, mm).",
    )
    sphere.add_argument(
        "folder",
        type=EXISTING_DIR,
        metavar="DIR",
        help="RGB-D folder: DIR/<sensor_id>/intrinsics.json, color_%%06d.png, depth_%%06d.png",
    )
    _add_output(sphere)
    sphere.add_argument(
        "--master",
        default=None,
        metavar="ID",
        help="reference sensor (default: the rig's sync master, else its first sensor, else the first folder)",
    )
    sphere.add_argument(
        "--radius-mm",
        type=POSITIVE,
        default=240.0,
        metavar="MM",
        help="the ball's radius, mm (default: %(default)s, the paper's red ball)",
    )
    sphere.add_argument(
        "--ball-sample",
        type=EXISTING_FILE,
        default=None,
        metavar="IMAGE",
        help="a crop showing only the ball, to learn its colour (default: a red ball model)",
    )
    sphere.add_argument(
        "--ransac-threshold-mm",
        type=POSITIVE,
        default=30.0,
        metavar="MM",
        help="ball centres farther than this from the fit are dropped as wrong detections (default: %(default)s)",
    )
    sphere.add_argument(
        "--min-frames",
        type=COUNT,
        default=10,
        metavar="N",
        help="fewest frames in which every sensor found the ball (default: %(default)s)",
    )
    sphere.add_argument(
        "--max-frames",
        type=COUNT,
        default=None,
        metavar="N",
        help="use only the first N frames (default: all)",
    )
    sphere.add_argument(
        "--rrd",
        type=OUTPUT_FILE,
        default=None,
        metavar="FILE",
        help="also save the poses and ball centres as a Rerun .rrd to look at",
    )
    sphere.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    sphere.set_defaults(func=cmd_sphere)


def _add_marker(sub: argparse._SubParsersAction) -> None:
    marker = sub.add_parser(
        "marker",
        help="sensor-to-world calibration from a plate of 4 ArUco markers on the floor, seen by the master "
        "(paper 2.1.2)",
        description="Detect the plate's markers in one colour frame of the master, take their 3D centres from "
        "depth and build the world: origin at marker 1, x from marker 2 to 1, y from marker 0 to 1, z up. An "
        "existing sensor-to-sensor calibration (by default the output file, if it exists) is re-anchored so every "
        "sensor moves into that world.",
    )
    marker.add_argument(
        "folder",
        type=EXISTING_DIR,
        metavar="DIR",
        help="RGB-D folder holding the master's view of the plate (DIR/<master>/...)",
    )
    _add_output(marker)
    marker.add_argument(
        "--calibration",
        type=EXISTING_FILE,
        default=None,
        metavar="FILE",
        help="sensor-to-sensor calibration to re-anchor (default: the output file when it exists)",
    )
    marker.add_argument(
        "--fresh", action="store_true", help="ignore any existing calibration: write the master's pose alone"
    )
    marker.add_argument(
        "--master",
        default=None,
        metavar="ID",
        help="sensor that sees the plate (default: the calibration's master, else the rig's sync "
        "master, else the first folder)",
    )
    marker.add_argument(
        "--frame",
        type=INDEX,
        default=None,
        metavar="N",
        help="frame number to use (default: the first one of the master's folder)",
    )
    marker.add_argument(
        "--ids",
        type=INDEX,
        nargs=4,
        default=[0, 1, 2, 3],
        metavar=("ID0", "ID1", "ID2", "ID3"),
        help="ArUco ids playing the paper's markers 0, 1 (origin), 2, 3 (default: 0 1 2 3)",
    )
    marker.add_argument(
        "--dictionary",
        default="DICT_4X4_50",
        help="OpenCV ArUco dictionary of the printed markers (default: %(default)s)",
    )
    marker.add_argument(
        "--marker-mm",
        type=POSITIVE,
        default=None,
        metavar="MM",
        help="printed marker side, mm: enables the PnP cross-check of the depth centres",
    )
    marker.add_argument(
        "--centre-method",
        choices=["plane", "mean"],
        default="plane",
        help="marker centre from depth: plane fit ∩ centre ray (unbiased) or the paper's pixel mean "
        "(default: %(default)s)",
    )
    marker.add_argument(
        "--rrd", type=OUTPUT_FILE, default=None, metavar="FILE", help="also save the poses as a Rerun .rrd to look at"
    )
    marker.set_defaults(func=cmd_marker)


def _add_skeleton(sub: argparse._SubParsersAction) -> None:
    skeleton = sub.add_parser(
        "skeleton",
        help="sensor-to-sensor (and floor) calibration from one person walking ~30 s through the shared space",
        description="Fit every sensor's pose from the torso joints the sensors see at the same time (robust, "
        "mirrored views left out), put z up from the floor under the feet (or the master's pose from --anchor), "
        "print the quality report (residual, half-take agreement, verdict good / check / bad per sensor) and "
        "write the calibration. Exit 3 when a verdict is bad (the file is then not written unless --force).",
    )
    _add_take(skeleton)
    _add_output(skeleton)
    skeleton.add_argument(
        "--anchor",
        type=EXISTING_FILE,
        default=None,
        metavar="FILE",
        help="a calibration (e.g. from `calibrate marker`) whose master pose defines the world instead of the floor",
    )
    skeleton.add_argument("--force", action="store_true", help="write the file even when a verdict is bad")
    skeleton.set_defaults(func=cmd_skeleton)


def _add_check(sub: argparse._SubParsersAction) -> None:
    check = sub.add_parser(
        "check",
        help="has a sensor moved since calibration? compare the stored calibration with a new walk",
        description="Fit the rig afresh on a new walking take (~30 s), with the master held at its stored pose, "
        "and compare every sensor with the stored calibration: the correction a fresh fit would apply "
        "(rotation, translation at the subject) and the residual. Exit 3 when a sensor moved.",
    )
    _add_take(check)
    check.add_argument(
        "--config",
        type=EXISTING_FILE,
        default=None,
        metavar="RIG.toml",
        help="the rig config (its [calibration] file is the default --calibration)",
    )
    check.add_argument(
        "--calibration",
        type=EXISTING_FILE,
        default=None,
        metavar="FILE",
        help="the stored calibration (default: the rig config's [calibration] file)",
    )
    check.add_argument(
        "--max-rotation-deg",
        type=POSITIVE,
        default=2.0,
        metavar="DEG",
        help="a sensor whose correction rotates more than this moved (default: %(default)s)",
    )
    check.add_argument(
        "--max-translation-mm",
        type=POSITIVE,
        default=30.0,
        metavar="MM",
        help="... or shifts the subject by more than this (default: %(default)s)",
    )
    check.add_argument(
        "--max-residual-growth-mm",
        type=POSITIVE,
        default=15.0,
        metavar="MM",
        help="warn when a residual grew by more than this since a skeleton calibration (default: %(default)s)",
    )
    check.set_defaults(func=cmd_check)


def _add_refine(sub: argparse._SubParsersAction) -> None:
    refine_parser = sub.add_parser(
        "refine",
        help="refine every sensor's pose by ICP on the person clouds of one person walking through (depth mode)",
        description="The second paper's calibration refinement: the person clouds of a walk-through (recorded by "
        '`skelfuse record` from a rig in [fusion] mode = "depth" or "hybrid") are registered sensor to '
        "sensor by point-to-plane ICP, starting from the rig's calibration; the reference sensor stays put. "
        "Prints the quality table (correction, ICP residual, pairs, the held-out gap: each fold's refined pose "
        "scored on the other fold's instants, agreement of the two folds' poses, verdict) and writes the "
        "calibration (not when a verdict is bad, unless --force; exit 3). A sensor whose held-out gap does not "
        "fall is rated 'no improvement' and keeps its pose. "
        "--sim prints the table of a simulated walk with perturbed poses, scored against the truth "
        "(docs/depth-fusion.md). Progress on stderr.",
    )
    refine_parser.add_argument(
        "--recording", type=EXISTING_FILE, default=None, metavar="REC.mcap", help="the recorded walk-through"
    )
    _add_output(refine_parser)
    refine_parser.add_argument(
        "--reference", default=None, metavar="ID", help="the sensor that stays put (default: the rig's sync master)"
    )
    refine_parser.add_argument(
        "--frames", type=COUNT, default=12, metavar="N", help="instants used, evenly spread over the walk (default 12)"
    )
    refine_parser.add_argument("--passes", type=COUNT, default=3, metavar="N", help="ICP rounds over the sensors (3)")
    refine_parser.add_argument("--force", action="store_true", help="write the file even when a verdict is bad")
    refine_parser.add_argument("--sim", action="store_true", help="a simulated walk instead of a recording")
    refine_parser.add_argument(
        "--perturb-deg",
        type=Number(float, ge=0, le=30),
        default=2.0,
        metavar="DEG",
        help="--sim: rotation error given to each sensor (2)",
    )
    refine_parser.add_argument(
        "--perturb-mm",
        type=Number(float, ge=0, le=1000),
        default=40.0,
        metavar="MM",
        help="--sim: position error given to each sensor (40)",
    )
    refine_parser.add_argument("--seed", type=SEED, default=0, help="--sim: seed of the walk and of the errors (0)")
    refine_parser.set_defaults(func=cmd_refine)
