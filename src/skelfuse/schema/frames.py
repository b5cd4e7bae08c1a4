"""Frames as they travel through skelfuse: what one sensor saw, and what fusion made of all of them.

Both are thin records around numpy arrays, vectorized over bodies and joints. Units are millimetres.
Positions of a :class:`SensorFrame` are in that sensor's depth-camera frame (x right, y down, z forward);
positions of a :class:`FusedFrame` are in the world frame (right-handed, z up). A missing joint is NaN.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from skelfuse.schema.skeleton import N_JOINTS


@dataclass(frozen=True, slots=True)
class SensorFrame:
    """One body-tracker result of one sensor.

    Attributes
    ----------
    sensor_id : str
        Device serial (or a simulator name).
    sequence : int
        Frame counter of that sensor, increasing by one per captured frame (gaps are drops).
    device_time_us : int
        Device timestamp of the depth frame, microseconds. Hardware-synced sensors agree on it up to
        their configured depth delay.
    host_time_ns : int
        Host clock when the frame was received, nanoseconds (for rigs without sync cables).
    body_ids : (B,) uint32
        The tracker's body ids. They change when the tracker loses a body, including on a left/right flip.
    positions : (B, 32, 3) float32, mm, sensor frame
    orientations : (B, 32, 4) float32, quaternions w, x, y, z
    confidence : (B, 32) uint8, :class:`skelfuse.schema.skeleton.Confidence` values
    """

    sensor_id: str
    sequence: int
    device_time_us: int
    host_time_ns: int
    body_ids: np.ndarray
    positions: np.ndarray
    orientations: np.ndarray
    confidence: np.ndarray

    @property
    def n_bodies(self) -> int:
        return int(self.body_ids.shape[0])

    def validate(self) -> None:
        """Raise ValueError naming the first inconsistency (shapes, dtypes ranges, non-finite values)."""
        n = self.n_bodies
        expected = {
            "positions": (n, N_JOINTS, 3),
            "orientations": (n, N_JOINTS, 4),
            "confidence": (n, N_JOINTS),
        }
        for name, shape in expected.items():
            got = getattr(self, name).shape
            if got != shape:
                raise ValueError(f"SensorFrame.{name} of sensor {self.sensor_id!r} has shape {got}, expected {shape}")
        if not np.isfinite(self.positions).all():
            raise ValueError(f"SensorFrame.positions of sensor {self.sensor_id!r} holds NaN or Inf values")
        if (self.confidence > 3).any():
            raise ValueError(f"SensorFrame.confidence of sensor {self.sensor_id!r} holds values above 3 (HIGH)")


@dataclass(frozen=True, slots=True)
class FusedFrame:
    """The fused skeletons of one instant.

    Attributes
    ----------
    time_us : int
        Device time of the sensor frames that were fused, microseconds.
    track_ids : (P,) int64
        Stable person ids.
    positions : (P, 32, 3) float64, mm, world frame. NaN where no estimate exists.
    n_agree : (P, 32) int16
        How many sensors' candidates formed the winning cluster of each joint (0 = coasted / predicted).
    confidence : (P, 32) uint8
        Highest tracker confidence among the candidates that were merged.
    contributors : (P, S) bool
        Which of the rig's S sensors contributed at least one joint to each person.
    sensor_ids : tuple[str, ...]
        The rig's sensors, in the column order of ``contributors``.
    orientations : (P, 32, 4) float64 or None
        Fused joint orientations, quaternions w, x, y, z in the world frame, k4abt joint-axis convention
        (docs/orientations.md); NaN where unknown. None: the producer does not compute them.
    position_std : (P, 32) float64 or None
        One-sigma position uncertainty per joint and axis, mm, from the data (docs/orientations.md); NaN where
        no estimate. None: the producer does not compute it.
    agreement_mm : (P,) float64 or None
        How far the views merged into each person lie from the fused torso, mm (docs/plausibility.md); NaN where
        fewer than two views carry the person. None: the producer does not compute it.
    """

    time_us: int
    track_ids: np.ndarray
    positions: np.ndarray
    n_agree: np.ndarray
    confidence: np.ndarray
    contributors: np.ndarray
    sensor_ids: tuple[str, ...] = field(default=())
    orientations: np.ndarray | None = None
    position_std: np.ndarray | None = None
    agreement_mm: np.ndarray | None = None

    @property
    def n_persons(self) -> int:
        return int(self.track_ids.shape[0])
