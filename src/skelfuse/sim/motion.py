"""Ground-truth human motion: 32 k4abt joints over time, in the world frame.

A :class:`Motion` is what the simulator treats as the truth. It comes from a real BVH recording
(:mod:`skelfuse.sim.bvh`) or from the procedural gesture generator (:mod:`skelfuse.sim.gestures`), and
:mod:`skelfuse.sim.observe` turns it into what each virtual Azure Kinect body tracker would report.

World frame: right-handed, z up, floor at z = 0, millimetres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skelfuse.schema.errors import DataError
from skelfuse.schema.skeleton import N_JOINTS, J

__all__ = ["Motion", "axis_rotation", "facing_deg", "root_facing"]


@dataclass(frozen=True)
class Motion:
    """A take of one person's true joint positions.

    Attributes
    ----------
    name : str
        What the take is (gesture name or BVH file stem).
    fps : float
        Frame rate of ``positions``, Hz.
    positions : (T, 32, 3) float64
        Joint positions in the world frame, mm (right-handed, z up, floor at z = 0), k4abt joint order.
    """

    name: str
    fps: float
    positions: np.ndarray

    def __post_init__(self) -> None:
        positions = np.asarray(self.positions, dtype=np.float64)
        if positions.ndim != 3 or positions.shape[1:] != (N_JOINTS, 3) or positions.shape[0] < 1:
            raise DataError(
                f"Motion {self.name!r}: positions must have shape (T, {N_JOINTS}, 3) with T >= 1, got {positions.shape}"
            )
        if not np.isfinite(positions).all():
            raise DataError(f"Motion {self.name!r}: positions hold NaN or Inf values")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise DataError(f"Motion {self.name!r}: fps must be a positive number, got {self.fps!r}")
        object.__setattr__(self, "positions", positions)

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def duration_s(self) -> float:
        """Length of the take in seconds: number of frames / fps."""
        return self.n_frames / self.fps

    @property
    def times_s(self) -> np.ndarray:
        """(T,) time of each frame from the start of the take, seconds."""
        return np.arange(self.n_frames) / self.fps

    def at_times(self, times_s: np.ndarray) -> np.ndarray:
        """Joint positions at arbitrary times by linear interpolation (clamped to the take).

        Parameters
        ----------
        times_s : (N,) float
            Times from the start of the take, seconds.

        Returns
        -------
        (N, 32, 3) float64, world mm. Times that fall on a frame (within 1e-9 frame) return it exactly.
        """
        frame = np.clip(np.asarray(times_s, dtype=np.float64) * self.fps, 0.0, self.n_frames - 1)
        nearest = np.rint(frame)
        frame = np.where(np.abs(frame - nearest) < 1e-6, nearest, frame)
        lo = np.floor(frame).astype(np.int64)
        hi = np.minimum(lo + 1, self.n_frames - 1)
        w = (frame - lo)[:, None, None]
        return (1.0 - w) * self.positions[lo] + w * self.positions[hi]

    def resampled(self, fps: float) -> Motion:
        """The same take at another frame rate (linear interpolation of positions).

        The new frames sit at ``k / fps`` seconds for every ``k`` that does not run past the last frame,
        so resampling 120 Hz to 30 Hz picks every 4th frame exactly.
        """
        if not (np.isfinite(fps) and fps > 0):
            raise DataError(f"Motion.resampled: fps must be a positive number, got {fps!r}")
        last_s = (self.n_frames - 1) / self.fps
        n_new = int(np.floor(last_s * fps + 1e-6)) + 1
        return Motion(self.name, float(fps), self.at_times(np.arange(n_new) / fps))


def root_facing(positions: np.ndarray) -> np.ndarray:
    """Horizontal unit vector the motion's root (pelvis segment) faces: the simulator's truth of "facing".

    Both motion sources hang the hips rigidly on the root segment (the gestures' forward kinematics and a BVH
    file's hips segment), so the true hip line is the root's lateral axis and its horizontal normal is where
    the root faces. This is the simulator's own definition, on the truth: the product decides facing from
    noisy views with its own rule (hips and shoulders), and the two must not share code, or an error of that
    rule would also decide which views the simulator mirrors and go unseen.

    Parameters
    ----------
    positions : (..., 32, 3) true world mm (z up).

    Returns
    -------
    (..., 3) unit vectors with zero z: forward = left x up, left pointing from the right hip to the left one.
    """
    left = positions[..., J["HIP_LEFT"], :] - positions[..., J["HIP_RIGHT"], :]
    forward = np.stack([left[..., 1], -left[..., 0], np.zeros_like(left[..., 0])], axis=-1)
    return forward / np.maximum(np.linalg.norm(forward, axis=-1, keepdims=True), 1e-9)


def facing_deg(positions: np.ndarray) -> np.ndarray:
    """Facing angle of the motion's root, degrees counter-clockwise from world +x (see :func:`root_facing`)."""
    forward = root_facing(positions)
    return np.degrees(np.arctan2(forward[..., 1], forward[..., 0]))


def axis_rotation(axis: str, angle_rad: np.ndarray | float) -> np.ndarray:
    """Rotation matrices about a coordinate axis, vectorized over angles.

    Parameters
    ----------
    axis : "x", "y" or "z"
    angle_rad : (...) angles, radians (right-hand rule)

    Returns
    -------
    (..., 3, 3) float64
    """
    angle = np.asarray(angle_rad, dtype=np.float64)
    c, s = np.cos(angle), np.sin(angle)
    one, zero = np.ones_like(angle), np.zeros_like(angle)
    if axis == "x":
        rows = [[one, zero, zero], [zero, c, -s], [zero, s, c]]
    elif axis == "y":
        rows = [[c, zero, s], [zero, one, zero], [-s, zero, c]]
    elif axis == "z":
        rows = [[c, -s, zero], [s, c, zero], [zero, zero, one]]
    else:
        raise ValueError(f"axis must be 'x', 'y' or 'z', got {axis!r}")
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)
