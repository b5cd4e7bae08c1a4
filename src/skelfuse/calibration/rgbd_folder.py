"""The RGB-D folder that ``skelfuse calibrate capture`` writes and the sphere and marker methods read.

Layout::

    DIR/<sensor_id>/intrinsics.json     {"fx", "fy", "cx", "cy", "width", "height"} of the depth camera, px
    DIR/<sensor_id>/color_000000.png    BGR colour registered to depth (same pixels as the depth image)
    DIR/<sensor_id>/depth_000000.png    uint16 depth, mm, 0 = invalid
    ...                                 the same number in every sensor's folder = the same instant
"""

from __future__ import annotations

import dataclasses
import json
import re
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.fusion.camera import Intrinsics
from skelfuse.schema.errors import DataError

INTRINSICS_FILE = "intrinsics.json"
COLOR_NAME = "color_{:06d}.png"
DEPTH_NAME = "depth_{:06d}.png"
_FRAME_FILE = re.compile(r"^(color|depth)_(\d+)\.png$")


def write_intrinsics(sensor_dir: str | Path, intrinsics: Intrinsics) -> Path:
    """Write ``<sensor_dir>/intrinsics.json``; returns its path."""
    path = Path(sensor_dir) / INTRINSICS_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(dataclasses.asdict(intrinsics), indent=2) + "\n", encoding="utf-8")
    return path


def read_intrinsics(path: str | Path) -> Intrinsics:
    """Read an ``intrinsics.json`` ({fx, fy, cx, cy, width, height}); DataError naming the file if malformed."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DataError(
            f"{path} not found: every sensor folder needs {INTRINSICS_FILE} with the depth camera's "
            "fx, fy, cx, cy, width, height (px)"
        ) from None
    except (OSError, json.JSONDecodeError) as exc:
        raise DataError(f"cannot read {path}: {exc}") from None
    keys = ("fx", "fy", "cx", "cy", "width", "height")
    if not isinstance(data, dict) or any(k not in data for k in keys):
        raise DataError(f"{path}: expected a JSON object with keys {', '.join(keys)}, found {data!r:.200}")
    try:
        return Intrinsics(
            float(data["fx"]),
            float(data["fy"]),
            float(data["cx"]),
            float(data["cy"]),
            int(data["width"]),
            int(data["height"]),
        )
    except (TypeError, ValueError) as exc:
        raise DataError(f"{path}: {exc}") from None


def save_rgbd_frame(sensor_dir: str | Path, index: int, color_bgr: np.ndarray, depth_mm: np.ndarray) -> None:
    """Write one frame (``color_%06d.png`` BGR uint8, ``depth_%06d.png`` uint16 mm) into a sensor folder."""
    import cv2

    sensor_dir = Path(sensor_dir)
    sensor_dir.mkdir(parents=True, exist_ok=True)
    color = np.ascontiguousarray(color_bgr, dtype=np.uint8)
    depth = np.ascontiguousarray(depth_mm)
    if color.ndim != 3 or color.shape[2] != 3:
        raise ValueError(f"color_bgr must be (H, W, 3) BGR, got shape {color.shape}")
    if depth.dtype != np.uint16 or depth.shape != color.shape[:2]:
        raise ValueError(
            f"depth_mm must be uint16 (H, W) matching the colour image {color.shape[:2]}, "
            f"got {depth.dtype} {depth.shape}"
        )
    for name, image in ((COLOR_NAME.format(index), color), (DEPTH_NAME.format(index), depth)):
        if not cv2.imwrite(str(sensor_dir / name), image):
            raise DataError(f"cannot write {sensor_dir / name}; check the folder is writable")


def save_rgbd_folder(
    directory: str | Path,
    frames_by_sensor: Mapping[str, Sequence[tuple[np.ndarray, np.ndarray]]],
    intrinsics_by_sensor: Mapping[str, Intrinsics],
    *,
    start_index: int = 0,
) -> Path:
    """Write synchronized RGB-D frames in the folder layout of the module docstring.

    Parameters
    ----------
    directory : the folder (created).
    frames_by_sensor : sensor id -> sequence of ``(color_bgr (H, W, 3) uint8, depth_mm (H, W) uint16)``;
        frame i of every sensor is the same instant and is written as number ``start_index + i``.
    intrinsics_by_sensor : sensor id -> the depth camera's Intrinsics (colour registered to depth).
    """
    directory = Path(directory)
    for sensor_id, frames in frames_by_sensor.items():
        if sensor_id not in intrinsics_by_sensor:
            raise ValueError(f"no intrinsics for sensor {sensor_id!r}")
        sensor_dir = directory / sensor_id
        write_intrinsics(sensor_dir, intrinsics_by_sensor[sensor_id])
        for i, (color, depth) in enumerate(frames):
            save_rgbd_frame(sensor_dir, start_index + i, color, depth)
    return directory


class RgbdFrames(Sequence[tuple[np.ndarray, np.ndarray]]):
    """One sensor's frames of an RGB-D folder, read from disk on access (a take of 1000 frames does not fit
    in memory at once). Item i: ``(color_bgr (H, W, 3) uint8, depth_mm (H, W) uint16)``.

    Attributes
    ----------
    sensor_dir : Path
    numbers : tuple[int, ...], the frame numbers (file names), in order.
    intrinsics : Intrinsics
    """

    def __init__(self, sensor_dir: Path, numbers: Sequence[int], intrinsics: Intrinsics) -> None:
        self.sensor_dir = sensor_dir
        self.numbers = tuple(numbers)
        self.intrinsics = intrinsics

    def __len__(self) -> int:
        return len(self.numbers)

    def __getitem__(self, index: Any) -> Any:
        if isinstance(index, slice):
            return RgbdFrames(self.sensor_dir, self.numbers[index], self.intrinsics)
        return self.read(self.numbers[index])

    def __iter__(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for number in self.numbers:
            yield self.read(number)

    def read(self, number: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``number`` (the number in the file names)."""
        import cv2

        color_path = self.sensor_dir / COLOR_NAME.format(number)
        depth_path = self.sensor_dir / DEPTH_NAME.format(number)
        color = cv2.imread(str(color_path), cv2.IMREAD_COLOR)
        depth = cv2.imread(str(depth_path), cv2.IMREAD_UNCHANGED)
        if color is None:
            raise DataError(f"cannot read {color_path} as an image; check the file")
        if depth is None:
            raise DataError(f"cannot read {depth_path} as an image; check the file")
        size = (self.intrinsics.height, self.intrinsics.width)
        if depth.dtype != np.uint16 or depth.ndim != 2:
            raise DataError(
                f"{depth_path}: expected a 16-bit single-channel PNG (depth in mm), found "
                f"{depth.dtype} with shape {depth.shape}"
            )
        for path, image in ((color_path, color), (depth_path, depth)):
            if image.shape[:2] != size:
                raise DataError(
                    f"{path} is {image.shape[1]}x{image.shape[0]} (W x H), {INTRINSICS_FILE} says "
                    f"{self.intrinsics.width}x{self.intrinsics.height}; colour must be registered to "
                    "depth (pyk4a capture.transformed_color) and the intrinsics be the depth camera's"
                )
        return color, depth


def _frame_numbers(sensor_dir: Path) -> list[int]:
    """Numbers that have both a colour and a depth file."""
    found: dict[str, set[int]] = {"color": set(), "depth": set()}
    for entry in sensor_dir.iterdir():
        match = _FRAME_FILE.match(entry.name)
        if match:
            found[match.group(1)].add(int(match.group(2)))
    return sorted(found["color"] & found["depth"])


def load_rgbd_folder(
    directory: str | Path,
    *,
    sensors: Sequence[str] | None = None,
    frames: Sequence[int] | None = None,
) -> tuple[dict[str, RgbdFrames], dict[str, Intrinsics]]:
    """Open an RGB-D folder (layout in the module docstring) for :func:`calibrate_from_sphere` and the marker.

    Parameters
    ----------
    directory : the folder holding one sub-folder per sensor.
    sensors : only these sensor ids (default: every sub-folder with an ``intrinsics.json``).
    frames : only these frame numbers (default: every number that every selected sensor has).

    Returns
    -------
    (frames_by_sensor, intrinsics_by_sensor): sensor id -> :class:`RgbdFrames` (lazy; the frame numbers
    every selected sensor has, in order, so index i is the same instant everywhere), sensor id -> Intrinsics.

    Raises
    ------
    DataError
        No such folder, no sensor folder, a requested sensor or frame missing, no frame common to all
        sensors, a malformed ``intrinsics.json``.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise DataError(
            f"RGB-D folder {directory} not found; record one with `skelfuse calibrate capture` "
            "(layout: <dir>/<sensor_id>/intrinsics.json, color_%06d.png, depth_%06d.png)"
        )
    available = sorted(p.name for p in directory.iterdir() if (p / INTRINSICS_FILE).is_file())
    if sensors is None:
        selected = available
    else:
        selected = list(sensors)
        missing = [s for s in selected if s not in available]
        if missing:
            raise DataError(
                f"{directory}: no folder with {INTRINSICS_FILE} for sensor(s) {', '.join(missing)}; "
                f"found {', '.join(available) or 'none'}"
            )
    if not selected:
        raise DataError(
            f"{directory} holds no sensor folder (<sensor_id>/{INTRINSICS_FILE}); is it the RGB-D "
            "folder written by `skelfuse calibrate capture`?"
        )
    intrinsics = {s: read_intrinsics(directory / s / INTRINSICS_FILE) for s in selected}
    numbers = {s: _frame_numbers(directory / s) for s in selected}
    if frames is not None:
        wanted = [int(n) for n in frames]
        for s in selected:
            absent = sorted(set(wanted) - set(numbers[s]))
            if absent:
                have = numbers[s]
                span = f"{have[0]}..{have[-1]} ({len(have)} frames)" if have else "none"
                raise DataError(f"{directory / s}: frame(s) {absent[:10]} not found (colour and depth); it has {span}")
        common = wanted
    else:
        common_set = set.intersection(*(set(n) for n in numbers.values()))
        common = sorted(common_set)
        if not common:
            counts = ", ".join(f"{s}: {len(n)}" for s, n in numbers.items())
            raise DataError(
                f"{directory}: no frame number has colour and depth in every sensor folder (frames per "
                f"sensor: {counts}); frames with the same number must be the same instant"
            )
    return ({s: RgbdFrames(directory / s, common, intrinsics[s]) for s in selected}, intrinsics)
