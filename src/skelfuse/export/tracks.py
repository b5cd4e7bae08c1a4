"""Fused frames regrouped per person on a uniform time grid: what the per-person file formats need.

C3D and TRC hold one subject's markers at a constant frame rate. The fused stream holds every person of each
instant, at the rate the sensors ran, with the odd dropped instant. :func:`take_tracks` estimates the rate
from the timestamps (the median step between instants finds the grid, the take's span over its grid steps
refines it), puts every instant on the grid
``round((time_us - first) / period)``, and cuts one :class:`PersonTrack` per track id from its first to its
last frame. A frame where the person was not fused, a grid slot no instant fell on, and a joint without an
estimate are all gaps (NaN): each format marks them as it allows.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from skelfuse.schema.errors import DataError
from skelfuse.schema.frames import FusedFrame
from skelfuse.schema.skeleton import N_JOINTS

MAX_GRID_FACTOR = 50
"""A take whose grid would hold more than this many frames per fused instant is refused (mixed clock epochs,
or a wrong --rate), instead of writing a file that is almost all gap."""


@dataclass(frozen=True)
class PersonTrack:
    """One person's fused joints on the take's grid, frames ``first_frame .. first_frame + n_frames - 1``.

    Attributes
    ----------
    track_id : int
    first_frame : int
        0-based index of the first frame on the take's grid (time ``first_frame / rate_hz`` after the take's
        first instant).
    positions : (T, 32, 3) float64, mm, world frame; NaN = gap
    n_agree : (T, 32) int16; 0 in gaps
    orientations : (T, 32, 4) float64 w,x,y,z or None (the fused frames carried none)
    position_std : (T, 32) float64 mm or None
    """

    track_id: int
    first_frame: int
    positions: np.ndarray
    n_agree: np.ndarray
    orientations: np.ndarray | None = None
    position_std: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def gaps(self) -> np.ndarray:
        """(T, 32) bool: the joint has no position in that frame."""
        return np.isnan(self.positions).any(axis=-1)


@dataclass(frozen=True)
class TakeTracks:
    """Every person of a take on one grid.

    Attributes
    ----------
    rate_hz : float
    start_time_us : int
        ``time_us`` of grid frame 0 (the take's first instant).
    n_frames : int
        Frames of the whole take's grid.
    persons : tuple[PersonTrack, ...]
        By ascending track id.
    instants : int
        Fused instants read (with or without persons).
    collisions : int
        Instants that fell on a grid slot another instant already held (kept: the first).
    """

    rate_hz: float
    start_time_us: int
    n_frames: int
    persons: tuple[PersonTrack, ...]
    instants: int
    collisions: int = 0

    def person(self, track_id: int) -> PersonTrack:
        for p in self.persons:
            if p.track_id == track_id:
                return p
        ids = ", ".join(str(p.track_id) for p in self.persons) or "none"
        raise DataError(f"track id {track_id} is not in the take; its track ids: {ids}")


def estimate_rate_hz(times_us: np.ndarray) -> float:
    """The frame rate of sorted unique instant times: 1e6 / the median step (robust to drops)."""
    steps = np.diff(np.unique(np.asarray(times_us, np.int64)))
    if steps.size == 0:
        raise DataError(
            "the take holds a single instant: its frame rate cannot be read from the timestamps; pass --rate"
        )
    return 1e6 / float(np.median(steps))


NOMINAL_RATES_HZ = (5.0, 10.0, 15.0, 24.0, 25.0, 30.0, 48.0, 50.0, 60.0, 90.0, 100.0, 120.0, 240.0)
"""Frame rates of cameras and motion-capture systems a measured rate is snapped to (Azure Kinect: 5, 15, 30)."""


def nominal_rate_hz(rate_hz: float, span_s: float) -> float:
    """``rate_hz``, or the nominal rate it measures where the difference drifts less than a tenth of a frame
    over ``span_s`` (a device clock's 33333/33334 µs steps read as 30.0003 Hz; files then say 30)."""
    for nominal in NOMINAL_RATES_HZ:
        drift_frames = abs(span_s * (rate_hz - nominal))
        if drift_frames < 0.1:
            return nominal
    return rate_hz


def take_tracks(frames: Iterable[FusedFrame], *, rate_hz: float | None = None) -> TakeTracks:
    """Regroup fused frames per person on a uniform grid (see the module docstring).

    Parameters
    ----------
    frames : iterable of FusedFrame
    rate_hz : float, optional
        The grid's rate; default: estimated from the timestamps.

    Raises
    ------
    DataError
        No instant, no person in the whole take, a single instant without ``rate_hz``, or timestamps that
        would make a grid mostly of gaps (:data:`MAX_GRID_FACTOR`).
    """
    frames = list(frames)
    if not frames:
        raise DataError("the input holds no fused instant: nothing to export")
    times = np.array([int(f.time_us) for f in frames], np.int64)
    start = int(times.min())
    if rate_hz is None:
        # The median step finds the grid; the take's span over its number of grid steps then gives the rate
        # to well under a microsecond per frame (a 30 fps device clock steps 33333 and 33334 us).
        period_us = 1e6 / estimate_rate_hz(times)
        steps = int(np.rint((times.max() - start) / period_us))
        if steps > 0:
            period_us = (times.max() - start) / steps
        rate_hz = nominal_rate_hz(1e6 / period_us, (times.max() - start) / 1e6)
    elif not (np.isfinite(rate_hz) and rate_hz > 0):
        raise DataError(f"frame rate must be a positive number of Hz, got {rate_hz!r}")
    period_us = 1e6 / rate_hz
    index = np.rint((times - start) / period_us).astype(np.int64)
    n_frames = int(index.max()) + 1
    if n_frames > MAX_GRID_FACTOR * len(frames) + 1000:
        raise DataError(
            f"the {len(frames)} instants span {(times.max() - start) / 1e6:.1f} s, {n_frames} frames at "
            f"{rate_hz:g} Hz: the timestamps jump (several clock epochs in one take?) or the rate is wrong; "
            f"export a part of the take or pass --rate"
        )
    order = np.argsort(index, kind="stable")
    taken = np.zeros(n_frames, bool)
    collisions = 0
    per_person: dict[int, list[tuple[int, FusedFrame, int]]] = {}
    for k in order:
        slot = int(index[k])
        if taken[slot]:
            collisions += 1
            continue
        taken[slot] = True
        frame = frames[k]
        for p, track_id in enumerate(np.asarray(frame.track_ids).tolist()):
            per_person.setdefault(int(track_id), []).append((slot, frame, p))
    if not per_person:
        raise DataError(f"no person in any of the {len(frames)} fused instants: nothing to export")
    persons = tuple(_person(track_id, rows) for track_id, rows in sorted(per_person.items()))
    return TakeTracks(
        rate_hz=float(rate_hz),
        start_time_us=start,
        n_frames=n_frames,
        persons=persons,
        instants=len(frames),
        collisions=collisions,
    )


def _person(track_id: int, rows: list[tuple[int, FusedFrame, int]]) -> PersonTrack:
    slots = np.array([slot for slot, _, _ in rows])
    first = int(slots.min())
    t = int(slots.max()) - first + 1
    at = slots - first
    positions = np.full((t, N_JOINTS, 3), np.nan)
    positions[at] = np.stack([np.asarray(f.positions[p], np.float64) for _, f, p in rows])
    n_agree = np.zeros((t, N_JOINTS), np.int16)
    n_agree[at] = np.stack([np.asarray(f.n_agree[p]) for _, f, p in rows])
    orientations = position_std = None
    if any(getattr(f, "orientations", None) is not None for _, f, _ in rows):
        orientations = np.full((t, N_JOINTS, 4), np.nan)
        for i, (_, f, p) in zip(at, rows, strict=True):
            if (quats := getattr(f, "orientations", None)) is not None:
                orientations[i] = quats[p]
    if any(getattr(f, "position_std", None) is not None for _, f, _ in rows):
        position_std = np.full((t, N_JOINTS), np.nan)
        for i, (_, f, p) in zip(at, rows, strict=True):
            if (std := getattr(f, "position_std", None)) is not None:
                position_std[i] = std[p]
    return PersonTrack(track_id, first, positions, n_agree, orientations, position_std)
