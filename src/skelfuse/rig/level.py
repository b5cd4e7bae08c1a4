"""Level a world that no calibration defined, from the skeletons themselves (pure: arrays in, arrays out).

A take fused with identity poses (``--registered``, one view, or a sensor-to-sensor calibration) keeps the
master camera's frame: y down, z forward, the floor wherever the camera's tilt puts it. People stand on a
floor, so their skeletons carry what is missing:

* **gravity** from the floor contacts: the positions where a foot stands still lie on the floor plane; where
  they cover an area (the person moved about) the plane's normal is "up". Where they do not (standing on the
  spot), the **standing trunk** gives it: the median direction from between the ankles to the neck over the
  frames whose legs are straight (a person bends; a standing body is near vertical);
* **the floor height** from the same contacts: the still feet's median height along "up", less the foot
  joint's height above the sole (:data:`FOOT_ABOVE_FLOOR_MM`, an anatomical approximation).

The result maps the input frame to a world with z up (floor to ceiling), the floor at z = 0, x the input's x
axis laid on the floor (for a camera: its "right"), y = z x x, and the origin on the floor below the input's
origin. :func:`level_from_skeletons` says which evidence it used, so the command line can report it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skelfuse.schema.skeleton import J

FOOT_ABOVE_FLOOR_MM = 30.0
"""Height of k4abt's FOOT joints above the floor when the foot stands flat (toes/ball of the foot: an
anatomical approximation; the floor height inherits its uncertainty)."""
STILL_MM_PER_FRAME = 5.0
"""A foot moving less than this a frame (0.15 m/s at 30 Hz) is taken as standing on the floor."""
STILL_WINDOW = 4
"""Frames over which a foot's movement is measured."""
STANDING_LEG = 0.98
"""A frame is standing where the mean leg (hip to ankle) is at least this fraction of its long length."""
MIN_SPREAD_MM = 400.0
"""Contacts must spread at least this far along two directions for their plane to give gravity."""
MAX_PLANE_TO_TRUNK_DEG = 25.0
"""The contacts' plane is trusted where its normal is within this of the trunk's up (a sloped path is not)."""
AXES = {"x": 0, "y": 1, "z": 2}


@dataclass(frozen=True)
class Levelling:
    """How the world was levelled, to apply and to report.

    Attributes
    ----------
    world_from_input : (4, 4) float64
        Rigid transform from the input frame to the levelled world (z up, floor at z = 0), mm.
    up_in_input : (3,) unit vector: "up" in the input frame.
    source : str
        What gave "up": "floor contacts", "standing trunk" or "--up" (given).
    tilt_deg : float
        Angle between the found up and the input frame's own nearest axis (the camera's tilt).
    floor_mm : float
        Height of the input frame's origin above the floor (a camera's mounting height), mm.
    contacts, trunk_frames : int
        Still-foot samples and straight-leg frames that were used.
    """

    world_from_input: np.ndarray
    up_in_input: np.ndarray
    source: str
    tilt_deg: float
    floor_mm: float
    contacts: int
    trunk_frames: int

    def describe(self) -> str:
        return (
            f"levelled the world from the skeletons: up from the {self.source} (tilt {self.tilt_deg:.1f} deg from "
            f"the input's nearest axis), floor {self.floor_mm:.0f} mm below the input's origin ({self.contacts} "
            f"still-foot samples, {self.trunk_frames} standing frames); --up AXIS or --no-level to override"
        )


def parse_axis(text: str) -> np.ndarray:
    """``"-y"`` -> (0, -1, 0): an axis of the input frame, for ``--up``."""
    sign = -1.0 if text.startswith("-") else 1.0
    name = text.lstrip("+-").lower()
    if name not in AXES or len(text) > 2:
        raise ValueError(f"expected an axis such as z, -y or +x; got {text!r}")
    axis = np.zeros(3)
    axis[AXES[name]] = sign
    return axis


def level_from_skeletons(positions: np.ndarray, *, up: np.ndarray | None = None) -> Levelling:
    """Level the frame of ``positions`` (F, B, 32, 3) mm (NaN where absent), one body slot per tracked person.

    ``up`` (a unit vector in the input frame) skips the gravity estimate; the floor is still found.

    Raises
    ------
    ValueError
        Too little evidence: no standing frame and no still foot (the message says what was missing).
    """
    positions = np.asarray(positions, dtype=np.float64)
    trunk_up, trunk_frames = _trunk_up(positions)
    contacts = _still_feet(positions)
    source = "--up"
    if up is None:
        if trunk_up is None:
            raise ValueError("no standing frame with a pelvis, neck, hips and ankles: cannot find up; pass --up")
        up, source = trunk_up, "standing trunk"
        plane_up = _plane_normal(contacts, trunk_up)
        if plane_up is not None:
            up, source = plane_up, "floor contacts"
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    if len(contacts) == 0:
        raise ValueError("no foot stands still in the take: cannot find the floor; pass --no-level")
    heights = contacts @ up
    floor = float(np.median(heights)) - FOOT_ABOVE_FLOOR_MM  # still feet stand on the floor; noise averages out
    tilt = float(np.degrees(np.arccos(np.clip(np.abs(up).max(), -1.0, 1.0))))
    return Levelling(
        world_from_input=_world_from_input(up, floor),
        up_in_input=up,
        source=source,
        tilt_deg=tilt,
        floor_mm=-floor,
        contacts=len(contacts),
        trunk_frames=trunk_frames,
    )


def _trunk_up(positions: np.ndarray) -> tuple[np.ndarray | None, int]:
    """Median unit vector from between the ankles to the neck over the frames whose legs are straight
    (within :data:`STANDING_LEG` of their long length): a standing body, whatever the arms and head do."""
    ankles = 0.5 * (positions[..., J["ANKLE_LEFT"], :] + positions[..., J["ANKLE_RIGHT"], :])
    body = positions[..., J["NECK"], :] - ankles
    leg = 0.5 * (
        np.linalg.norm(positions[..., J["HIP_LEFT"], :] - positions[..., J["ANKLE_LEFT"], :], axis=-1)
        + np.linalg.norm(positions[..., J["HIP_RIGHT"], :] - positions[..., J["ANKLE_RIGHT"], :], axis=-1)
    )
    ok = np.isfinite(body).all(axis=-1) & np.isfinite(leg)
    if not ok.any():
        return None, 0
    standing = ok & (leg >= STANDING_LEG * np.percentile(leg[ok], 90))
    unit = body[standing] / np.linalg.norm(body[standing], axis=-1, keepdims=True)
    median = np.median(unit, axis=0)
    return median / np.linalg.norm(median), int(standing.sum())


def _still_feet(positions: np.ndarray) -> np.ndarray:
    """(N, 3) positions of FOOT joints that moved less than :data:`STILL_MM_PER_FRAME` a frame on average
    over :data:`STILL_WINDOW` frames (the window averages the tracker's jitter out)."""
    feet = positions[:, :, [J["FOOT_LEFT"], J["FOOT_RIGHT"]], :]  # (F, B, 2, 3)
    if feet.shape[0] <= STILL_WINDOW:
        return np.empty((0, 3))
    moved = np.linalg.norm(feet[STILL_WINDOW:] - feet[:-STILL_WINDOW], axis=-1)
    still = np.isfinite(moved) & (moved < STILL_MM_PER_FRAME * STILL_WINDOW)
    middle = STILL_WINDOW // 2
    return feet[middle : middle + len(moved)][still]


def _plane_normal(contacts: np.ndarray, trunk_up: np.ndarray) -> np.ndarray | None:
    """The floor plane's normal through the contacts (towards ``trunk_up``), where they span an area and the
    plane agrees with the trunk; else None."""
    if len(contacts) < 10:
        return None
    centred = contacts - np.median(contacts, axis=0)
    _, spread, axes = np.linalg.svd(centred, full_matrices=False)
    spread_mm = 2.0 * spread / np.sqrt(len(contacts))  # about two standard deviations per axis
    if spread_mm[1] < MIN_SPREAD_MM:
        return None
    normal = axes[2] if axes[2] @ trunk_up > 0 else -axes[2]
    if np.degrees(np.arccos(np.clip(normal @ trunk_up, -1.0, 1.0))) > MAX_PLANE_TO_TRUNK_DEG:
        return None
    return normal


def _world_from_input(up: np.ndarray, floor: float) -> np.ndarray:
    """z = up; x = the input's x laid on the floor (its z if x is vertical); origin below the input's."""
    x = np.array([1.0, 0.0, 0.0])
    if abs(x @ up) > 0.9:
        x = np.array([0.0, 0.0, 1.0])
    x = x - (x @ up) * up
    x /= np.linalg.norm(x)
    y = np.cross(up, x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, y, up])  # rows: world axes in input coordinates
    pose[2, 3] = -floor  # the floor (height `floor` along up in the input) goes to z = 0
    return pose
