"""The live "sensor moved" alarm: does each sensor's pose still fit the others while people walk through?

``skelfuse calibrate check`` answers it offline from a dedicated walk; the fusion node asks it continuously
of every fused instant. For each sensor, its bodies are put in the world with the sensor's pose (the node
already does that for fusion) and compared with the fused people: the distance, averaged over the torso
joints (pelvis, navel, chest, neck: the joints the tracker places best, and that mirroring leaves alone),
from its nearest body to the nearest fused person. A sensor that was knocked or re-mounted keeps reporting
its bodies where its old pose puts them, so that distance grows by about the displacement at the subject,
while the fused person follows the sensors that still agree (clustering leaves the outlier out).

A sensor "no longer fits" when the median of that distance over the last ``window`` instants in which it
saw someone exceeds ``threshold_mm`` (and it saw someone in at least ``min_frames`` of them): one bad frame
or a person half out of view does not raise it. The median of sensors that fit stays at the tracker's noise
plus the calibration error (a few tens of mm on the simulator's Azure Kinect profile).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skelfuse.fusion.association import nanmedian_axis
from skelfuse.schema.skeleton import TORSO_TRACKING_JOINTS

DEFAULT_THRESHOLD_MM = 100.0
DEFAULT_WINDOW = 300
"""Instants (10 s at 30 Hz) over which the median is taken."""
DEFAULT_MIN_FRAMES = 60
DEFAULT_CHECK_EVERY = 30
"""The verdicts (medians over the window) are recomputed every this many instants (1 s at 30 Hz): the per-instant
cost stays a few tens of microseconds on the node's loop."""


@dataclass(frozen=True)
class FitChange:
    """A sensor whose verdict changed with the last instant."""

    sensor_id: str
    fits: bool
    median_mm: float
    frames: int


class PoseFitMonitor:
    """Rolling per-sensor agreement with the fused people (see the module docstring).

    Parameters
    ----------
    sensor_ids : sequence of str
        The rig's sensors, in the order of the per-sensor axis of what :meth:`update` gets.
    threshold_mm, window, min_frames : see the module docstring.
    """

    def __init__(
        self,
        sensor_ids: tuple[str, ...],
        *,
        threshold_mm: float = DEFAULT_THRESHOLD_MM,
        window: int = DEFAULT_WINDOW,
        min_frames: int = DEFAULT_MIN_FRAMES,
        check_every: int = DEFAULT_CHECK_EVERY,
    ) -> None:
        if not (threshold_mm > 0 and window >= 1 and 1 <= min_frames <= window):
            raise ValueError("PoseFitMonitor needs threshold_mm > 0 and 1 <= min_frames <= window")
        self.sensor_ids = tuple(sensor_ids)
        self.threshold_mm = float(threshold_mm)
        self.min_frames = int(min_frames)
        self.check_every = max(1, int(check_every))
        self._distances = np.full((int(window), len(self.sensor_ids)), np.nan)
        self._next = 0
        self._fits = np.ones(len(self.sensor_ids), dtype=bool)

    def update(self, sensors_world: np.ndarray, fused: np.ndarray) -> list[FitChange]:
        """One instant: (S, B, 32, 3) every sensor's bodies in the world, (P, 32, 3) fused people (mm, NaN
        where missing). Returns the sensors whose verdict changed (judged every ``check_every`` instants)."""
        distance = np.full(len(self.sensor_ids), np.nan)
        if fused.shape[0] and sensors_world.shape[1]:
            bodies = sensors_world[:, :, TORSO_TRACKING_JOINTS]  # (S, B, J, 3)
            people = fused[:, TORSO_TRACKING_JOINTS]  # (P, J, 3)
            offsets = bodies[:, :, None] - people[None, None]  # (S, B, P, J, 3)
            gaps = np.sqrt((offsets * offsets).sum(axis=-1)).mean(axis=-1)  # (S, B, P); NaN: a joint missing
            gaps[np.isnan(gaps)] = np.inf
            nearest = gaps.min(axis=(1, 2))  # (S,) nearest body to the nearest person
            distance[np.isfinite(nearest)] = nearest[np.isfinite(nearest)]
        self._distances[self._next % len(self._distances)] = distance
        self._next += 1
        return self._verdicts() if self._next % self.check_every == 0 else []

    def _medians(self) -> tuple[np.ndarray, np.ndarray]:
        frames = np.isfinite(self._distances).sum(axis=0)
        # NaN where a sensor saw nobody in the window; not np.nanmedian, whose masked-array path costs about
        # a millisecond of the node's loop at 16 sensors, twice per status.
        return nanmedian_axis(self._distances, 0), frames

    def _verdicts(self) -> list[FitChange]:
        medians, frames = self._medians()
        judged = frames >= self.min_frames
        fits = np.where(judged, ~(medians > self.threshold_mm), self._fits)
        changes = [
            FitChange(sid, bool(fits[i]), float(medians[i]), int(frames[i]))
            for i, sid in enumerate(self.sensor_ids)
            if fits[i] != self._fits[i]
        ]
        self._fits = fits
        return changes

    def report(self) -> dict[str, dict[str, float | int | bool | None]]:
        """Per sensor: the median distance to the fused people (mm), the instants it rests on, and the verdict
        (``fits`` None until ``min_frames`` instants saw the sensor's bodies)."""
        medians, frames = self._medians()
        return {
            sid: {
                "median_mm": None if not np.isfinite(medians[i]) else round(float(medians[i]), 1),
                "frames": int(frames[i]),
                "fits": bool(self._fits[i]) if frames[i] >= self.min_frames else None,
            }
            for i, sid in enumerate(self.sensor_ids)
        }
