"""Smoothed fused frames, shared by offline fusion and the live node's fixed-lag option.

:mod:`skelfuse.fusion.smoother` smooths each track's positions (Rauch-Tung-Striebel over the live filter's
motion model). This module puts them back into the :class:`~skelfuse.schema.frames.FusedFrame` the live fusion
made of the instant: the same persons, the smoothed positions, the orientations swung onto the smoothed bones
(their twist kept); ``n_agree``, confidence, contributors, position_std and agreement_mm stay the instant's own.

:class:`LiveFixedLag` is the live node's ``[fusion] fixed_lag_frames``: each instant goes out ``lag`` instants
later, smoothed by the frames up to then, equal frame for frame to the offline fixed-lag smoother over the
same instants. Pure numpy, no clocks or I/O.
"""

from __future__ import annotations

from collections import deque
from dataclasses import replace
from typing import Generic, TypeVar

import numpy as np

from skelfuse.fusion.orientation import aim_directions, apply_derived, swing_onto_aims
from skelfuse.fusion.people import PeopleResult
from skelfuse.fusion.presets import FusionParams
from skelfuse.fusion.smoother import FixedLagSmoother
from skelfuse.rig.instant import FusedInstant
from skelfuse.schema.frames import FusedFrame

Item = TypeVar("Item")


def follow_bones(orientations: np.ndarray | None, positions: np.ndarray) -> np.ndarray | None:
    """The fused orientations swung onto the smoothed bones (their twist kept): every aimed joint's aim axis (X;
    the ankles' foot axis) lies on its bone of the smoothed positions, as the live fusion's lies on the live
    positions' (docs/orientations.md)."""
    if orientations is None:
        return None
    swung = apply_derived(swing_onto_aims(orientations, aim_directions(positions)))
    return np.where(np.isfinite(swung).all(axis=-1, keepdims=True), swung, orientations)


def smoothed_frame(frame: FusedFrame, people_ids: np.ndarray, positions: np.ndarray) -> FusedFrame:
    """``frame`` with its persons' smoothed ``positions`` ((P, J, 3) in the order of ``people_ids``, the
    instant's tracks, of which the frame holds a subset: both ascending)."""
    rows = np.searchsorted(people_ids, frame.track_ids)
    return replace(frame, positions=positions[rows], orientations=follow_bones(frame.orientations, positions[rows]))


def merged_or_nan(people: PeopleResult) -> np.ndarray:
    """The people's merge before the filter, the smoother's measurements (NaN: a path without one)."""
    return people.merged if people.merged is not None else np.full_like(people.positions, np.nan)


class LiveFixedLag(Generic[Item]):
    """Fixed-lag smoothing of the live fused stream: :meth:`push` each instant as it is fused, with whatever
    the caller publishes beside it (``item``); get back the instant ``lag`` instants earlier, smoothed.

    The added latency is ``lag`` frames. A new person appears ``lag`` instants after the live fusion saw them;
    a person who leaves has their last ``lag`` frames released with the instants they belong to, smoothed
    from what there is (the tail is flushed, not dropped); :meth:`flush` releases the instants still held at
    the end of the stream (the node's shutdown), the same way.
    """

    def __init__(self, params: FusionParams, lag: int) -> None:
        self.smoother = FixedLagSmoother(params, lag)
        self.lag = self.smoother.lag
        self._held: deque[tuple[FusedInstant, Item]] = deque()

    def push(self, instant: FusedInstant, item: Item) -> list[tuple[Item, FusedFrame]]:
        """Add one fused instant; return the instant now due (none during the first ``lag``)."""
        people = instant.people
        self._held.append((instant, item))
        positions = self.smoother.push(
            people.time_s, people.track_ids, merged_or_nan(people), people.n_agree, people.restarted
        )
        return [] if positions is None else [self._out(positions)]

    def flush(self) -> list[tuple[Item, FusedFrame]]:
        """Every instant still held, oldest first, smoothed from what there is."""
        return [self._out(positions) for positions in self.smoother.flush()]

    def _out(self, positions: np.ndarray) -> tuple[Item, FusedFrame]:
        instant, item = self._held.popleft()
        return item, smoothed_frame(instant.frame, instant.people.track_ids, positions)
