"""The live "sensor moved" alarm: does each sensor's pose still fit the others while people walk through?

``skelfuse calibrate check`` answers it offline from a dedicated walk; the fusion node asks it continuously
of every fused instant. For each sensor, its bodies are put in the world with the sensor's pose (the node
already does that for fusion) and compared with the fused people: the distance, averaged over the torso
joints (pelvis, navel, chest, neck: the joints the tracker places best, and that mirroring leaves alone),
from its nearest body to the nearest fused person. A sensor that was knocked or re-mounted keeps reporting
its bodies where its old pose puts them, so that distance grows by about the displacement at the subject,
while the fused person follows the sensors that still agree (clustering leaves the outlier out).

Only confidently associated persons count, so a crowd raises no alarm: a fused person is compared with a
sensor's bodies only when (1) at least two other sensors contributed to it (``min_other_sensors``; one in a
two-sensor rig), so it does not follow the sensor being judged; (2) no other person (of those two or more
sensors saw) stands within ``isolation_mm`` of it (torso to torso), so whose body is whose is not in doubt;
(3) the sensor's view of it was not held out as upside down or of another size by the plausibility stage (a
bad skeleton, not a moved sensor; a view held out for jumping away still counts: a moved sensor's views do);
and (4) the sensor's body nearest to it is nearer to it than to any other such person. A sensor's distance in
an instant is the median over those persons; an instant without one leaves no value.

A sensor "no longer fits" when the median of that distance over the last ``window`` instants in which it
had a value exceeds ``threshold_mm`` (and it had one in at least ``min_frames`` of them): one bad frame
or a person half out of view does not raise it. The median of sensors that fit stays at the tracker's noise
plus the calibration error (a few tens of mm on the simulator's Azure Kinect profile).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skelfuse.fusion.association import nanmedian_axis
from skelfuse.fusion.plausibility import BONES, UPSIDE_DOWN
from skelfuse.schema.skeleton import TORSO_TRACKING_JOINTS

DEFAULT_THRESHOLD_MM = 100.0
DEFAULT_WINDOW = 300
"""Instants (10 s at 30 Hz) over which the median is taken."""
DEFAULT_MIN_FRAMES = 60
DEFAULT_ISOLATION_MM = 500.0
"""Torso to torso: closer than this (two people side by side), whose body is whose is in doubt."""
DEFAULT_MIN_OTHER_SENSORS = 2
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
    threshold_mm, window, min_frames, isolation_mm, min_other_sensors : see the module docstring.
    """

    def __init__(
        self,
        sensor_ids: tuple[str, ...],
        *,
        threshold_mm: float = DEFAULT_THRESHOLD_MM,
        window: int = DEFAULT_WINDOW,
        min_frames: int = DEFAULT_MIN_FRAMES,
        check_every: int = DEFAULT_CHECK_EVERY,
        isolation_mm: float = DEFAULT_ISOLATION_MM,
        min_other_sensors: int = DEFAULT_MIN_OTHER_SENSORS,
    ) -> None:
        if not (threshold_mm > 0 and window >= 1 and 1 <= min_frames <= window):
            raise ValueError("PoseFitMonitor needs threshold_mm > 0 and 1 <= min_frames <= window")
        self.sensor_ids = tuple(sensor_ids)
        self.threshold_mm = float(threshold_mm)
        self.min_frames = int(min_frames)
        self.check_every = max(1, int(check_every))
        self.isolation_mm = float(isolation_mm)
        self.min_other_sensors = max(1, min(int(min_other_sensors), len(self.sensor_ids) - 1))
        self._distances = np.full((int(window), len(self.sensor_ids)), np.nan)
        self._next = 0
        self._fits = np.ones(len(self.sensor_ids), dtype=bool)

    def update(
        self,
        sensors_world: np.ndarray,
        fused: np.ndarray,
        contributors: np.ndarray | None = None,
        held_out: np.ndarray | None = None,
    ) -> list[FitChange]:
        """One instant: (S, B, 32, 3) every sensor's bodies in the world, (P, 32, 3) fused people (mm, NaN where
        missing), (P, S) which sensors contributed to each person and (P, S) why a view was held out (0: not;
        :mod:`skelfuse.fusion.plausibility` codes). ``contributors`` None: every sensor counts as contributing
        to every person. Returns the sensors whose verdict changed (judged every ``check_every`` instants)."""
        self._distances[self._next % len(self._distances)] = self.instant_distances(
            sensors_world, fused, contributors, held_out
        )
        self._next += 1
        return self._verdicts() if self._next % self.check_every == 0 else []

    def instant_distances(
        self,
        sensors_world: np.ndarray,
        fused: np.ndarray,
        contributors: np.ndarray | None = None,
        held_out: np.ndarray | None = None,
    ) -> np.ndarray:
        """(S,) each sensor's median distance (mm) to the confidently associated people of one instant (NaN:
        none); arguments as :meth:`update`."""
        n_sensors, n_people = len(self.sensor_ids), fused.shape[0]
        distance = np.full(n_sensors, np.nan)
        if not n_people or not sensors_world.shape[1]:
            return distance
        if contributors is None or contributors.shape != (n_people, n_sensors):  # depth mode fuses other views
            contributors, held_out = np.ones((n_people, n_sensors), dtype=bool), None
        # The rules that need no geometry first: most instants of a small rig stop here or skip the rest.
        counts = contributors.sum(axis=1)  # (P,)
        supported = counts >= 2  # persons two sensors or more agree on
        usable = (counts[None, :] - contributors.T >= self.min_other_sensors) & supported[None, :]  # (S, P)
        if held_out is not None:
            held = held_out.T
            usable &= (held != UPSIDE_DOWN) & (held != BONES)
        if not usable.any():
            return distance
        people = fused[:, TORSO_TRACKING_JOINTS]  # (P, J, 3)
        gaps = _torso_gaps(sensors_world[:, :, TORSO_TRACKING_JOINTS], people)  # (S, B, P)
        if n_people == 1:  # alone: nobody to mistake them for
            gap = gaps.min(axis=1)  # (S, 1)
        else:
            nearest_body = gaps.argmin(axis=1)  # (S, P) each sensor's body nearest to each person
            gap = np.take_along_axis(gaps, nearest_body[:, None, :], axis=1)[:, 0, :]  # (S, P)
            usable &= _unambiguous(people, supported, gaps, nearest_body, self.isolation_mm)
        usable &= np.isfinite(gap)
        values = np.where(usable, gap, np.nan)
        seen = usable.any(axis=1)
        distance[seen] = values[seen, 0] if n_people == 1 else nanmedian_axis(values[seen], 1)
        return distance

    def _medians(self) -> tuple[np.ndarray, np.ndarray]:
        frames = np.isfinite(self._distances).sum(axis=0)
        # NaN where a sensor saw nobody in the window; not np.nanmedian, whose masked-array path took ~1 ms
        # of the node's loop at 16 sensors, twice per status.
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


def _torso_gaps(bodies: np.ndarray, people: np.ndarray) -> np.ndarray:
    """(S, B, P) mean distance over the torso joints between (S, B, J, 3) bodies and (P, J, 3) people, mm;
    inf where a joint is missing on either side."""
    offsets = bodies[:, :, None] - people[None, None]  # (S, B, P, J, 3)
    gaps = np.sqrt((offsets * offsets).sum(axis=-1)).mean(axis=-1)
    gaps[np.isnan(gaps)] = np.inf
    return gaps


def _unambiguous(
    people: np.ndarray, supported: np.ndarray, gaps: np.ndarray, nearest_body: np.ndarray, isolation_mm: float
) -> np.ndarray:
    """(S, P): the person stands ``isolation_mm`` or more from every other supported person, and the sensor's body
    nearest to them is nearer to them than to any other supported person (whose body is whose is not in doubt).
    ``people`` (P, J, 3) torso joints, ``supported`` (P,), ``gaps`` (S, B, P), ``nearest_body`` (S, P)."""
    between = _torso_gaps(people[None], people)[0]  # (P, P)
    np.fill_diagonal(between, np.inf)
    isolated = np.where(supported[None, :], between, np.inf).min(axis=1) >= isolation_mm  # (P,)
    body_owner = np.where(supported[None, None, :], gaps, np.inf).argmin(axis=2)  # (S, B)
    owner = np.take_along_axis(body_owner, nearest_body, axis=1)  # (S, P)
    return (owner == np.arange(people.shape[0])[None, :]) & isolated[None, :]
