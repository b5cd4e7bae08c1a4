"""The commands of ``skelfuse``: name, the module that builds and runs it, and the line ``skelfuse --help``
shows. Light on purpose: ``skelfuse CMD`` imports only CMD's module, ``skelfuse --help`` none of them."""

from __future__ import annotations

COMMANDS: dict[str, tuple[str, str]] = {
    "demo": (
        "skelfuse.cli.demo",
        "a simulated 4-sensor rig fused live over zenoh and shown in Rerun (a .rrd where there is no screen)",
    ),
    "eval": ("skelfuse.cli.evaluate", "reproduce the paper's experiments / evaluate on real data"),
    "sim": ("skelfuse.cli.sim", "the simulator: how close it is to real recordings"),
    "bench": ("skelfuse.cli.bench", "measure speed"),
    "capture": (
        "skelfuse.cli.service",
        "capture worker: publish one sensor's frames on skelfuse/<rig>/sensors/<id>/skeletons",
    ),
    "fuse": (
        "skelfuse.cli.service",
        "fusion node (live, over zenoh) or offline fusion of a recording (--input FILE --output OUT)",
    ),
    "record": (
        "skelfuse.cli.service",
        "record every raw sensor frame of the rig (and its fused stream) to an MCAP file",
    ),
    "replay": ("skelfuse.cli.service", "republish a recording's sensor frames over zenoh (original or maximum speed)"),
    "status": ("skelfuse.cli.service", "print the status messages of the rig's nodes"),
    "router": (
        "skelfuse.cli.network",
        "run the rig's zenoh router (several PCs: capture PCs, fusion node and apps connect to it)",
    ),
    "certs": (
        "skelfuse.cli.network",
        "make the rig's certificate authority and one certificate per capture PC, fusion node, router, app",
    ),
    "convert": (
        "skelfuse.cli.convert",
        "convert recordings of any supported format into one time-matched skelfuse MCAP",
    ),
    "devices": (
        "skelfuse.cli.devices",
        "list connected Azure Kinect / Femto Bolt sensors (serial, firmware, sync jacks)",
    ),
    "calibrate": (
        "skelfuse.cli.calibrate",
        "measure where each sensor stands (sphere, marker plate, or skeletons) and write the calibration file",
    ),
    "export": (
        "skelfuse.cli.export",
        "write fused skeletons as CSV/Parquet, C3D, OpenSim TRC, BVH or FBX (one file per person)",
    ),
    "stream": (
        "skelfuse.cli.stream",
        "stream daemon: re-send the fused skeletons live as OSC, VMC (UDP) or a Lab Streaming Layer stream",
    ),
    "setup": ("skelfuse.cli.setup", "install an optional component on request (blender: what FBX export needs)"),
}
"""Command name -> (module, help), in the order ``skelfuse --help`` lists them."""
COMMAND_HELP = {name: help_text for name, (_, help_text) in COMMANDS.items()}
