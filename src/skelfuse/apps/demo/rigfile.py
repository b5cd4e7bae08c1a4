"""The demo's rig on disk: its config (the paper's ring of simulated sensors) and its simulated calibration.

:func:`sim_sensor_tables` is shared: the service tests and the soak script write their sensors with it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from skelfuse.apps.demo import DEMO_RIG
from skelfuse.sim.rig import paper_rig


def sim_sensor_tables(n_sensors: int, extra: Mapping[int, Sequence[str]] | None = None) -> list[str]:
    """Rig TOML lines for the paper's ring of ``n_sensors`` simulated sensors: one wired sync chain (the first
    sensor the master, subordinates 160 µs apart) and the true poses; ``extra[i]`` adds lines to sensor i's table.
    The demo's rig, the service tests and the soak script all write their sensors with it."""
    lines: list[str] = []
    for index, sensor in enumerate(paper_rig(n_sensors)):
        sync = '{ role = "master" }' if index == 0 else f'{{ role = "subordinate", delay_us = {160 * index} }}'
        rows = ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in sensor.world_from_sensor)
        lines += [
            "[[sensors]]",
            f'id = "{sensor.sensor_id}"',
            'source = "sim"',
            f"sync = {sync}",
            f"world_from_sensor = [{rows}]",
            *(extra or {}).get(index, ()),
            "",
        ]
    return lines


def write_demo_rig(directory: Path, *, preset_name: str, n_sensors: int = 4, port: int | None = None) -> Path:
    """Write the demo's rig config (the paper's 4-sensor layout, wired sync emulated) into ``directory``.

    The sensors' inline ``world_from_sensor`` are the true poses the simulator observes from; fusion uses
    ``calibration.toml`` beside it (the simulated calibration, with its error), written by the demo. With
    ``port``, ``[zenoh] connect`` names the demo's loopback endpoint, so any app given the file attaches.
    """

    lines = [
        "# skelfuse demo rig, written by `skelfuse demo` (the paper's 4-sensor layout, simulated).",
        "[rig]",
        f'name = "{DEMO_RIG}"',
        "",
        "[sync]",
        'by = "device"',
        "fps = 30.0",
        "tolerance_ms = 10.0",
        "deadline_ms = 17.0",
        "",
        "[calibration]",
        'file = "calibration.toml"',
        "",
        "[fusion]",
        f'preset = "{preset_name}"',
        "",
        "[zenoh]",
        'mode = "peer"',
        "multicast_scouting = false",
        *([f'connect = ["tcp/127.0.0.1:{port}"]'] if port is not None else []),
        "",
    ]
    lines += sim_sensor_tables(n_sensors)
    path = directory / "rig.toml"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def write_calibration(path: Path, sensor_ids: tuple[str, ...], poses: np.ndarray) -> None:
    lines = ['method = "simulated"  # the simulator\'s calibration error model', ""]
    for sensor_id, pose in zip(sensor_ids, poses, strict=True):
        rows = ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in pose)
        lines += [f'[sensors."{sensor_id}"]', f"world_from_sensor = [{rows}]", ""]
    path.write_text("\n".join(lines), encoding="utf-8")
