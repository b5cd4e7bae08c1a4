"""Each sensor's clock against the node's arrival clock: the offset, drift and jitter of its frame times, its
off-clock frames and the clocks they agree on (pure: times are passed in). :class:`skelfuse.rig.grouping.FrameGrouper`
keeps one :class:`SensorClock` per sensor; the rules are in that module's docstring ("Sensor clocks").
"""

from __future__ import annotations

import collections
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from skelfuse.schema.frames import SensorFrame

if TYPE_CHECKING:  # pragma: no cover - typing only
    pass

DEFAULT_RESYNC_AFTER = 8
"""Consecutive out-of-window frames that make the grouper start a new clock epoch (two frames of four sensors)."""
DEFAULT_MAX_AHEAD_US = 100_000
"""How far (µs) a frame's time may lie ahead of its sensor's learned clock (a frame cannot arrive before it
is stamped: only the latency's spread is legitimate here)."""
DEFAULT_MAX_BEHIND_US = 1_000_000
"""How far (µs) a frame's time may lie behind its sensor's learned clock (a stalled tracker, a queue)."""
CEILING_DECAY_US_PER_S = 1000.0
"""How fast a sensor's fastest-delivery reference forgets (1 ms per s, far above any clock drift)."""
CLOCK_WINDOW = 31
"""Frames in each sensor's running offset and phase estimates (about 1 s at 30 fps)."""
MAX_CANDIDATE_CLOCKS = 4
"""Candidate clocks (groups of agreeing off-clock frames) each sensor keeps; the weakest is dropped first."""


@dataclass(frozen=True)
class ClockEstimate:
    """One sensor's clock as the grouper sees it (for the node's status).

    Attributes
    ----------
    offset_ms : float or None
        Median of ``frame time - arrival`` over the sensor's recent frames, ms (its clock's offset from the
        node's arrival clock plus its latency); None before the first frame.
    relative_offset_ms : float or None
        ``offset_ms`` minus the median over the rig's sensors: how far this sensor's clock is off the rig's
        majority (what an operator compares across PCs).
    drift_ppm : float or None
        Slope of the residual over the arrival time, µs per s (ppm); None with too few frames.
    jitter_ms : float or None
        Median absolute deviation of the residual, ms.
    relearns : int
        Times the clock stepped and was re-learned.
    """

    offset_ms: float | None
    relative_offset_ms: float | None
    drift_ppm: float | None
    jitter_ms: float | None
    relearns: int

    def to_dict(self) -> dict[str, float | int | None]:
        # A literal, not dataclasses.asdict (a deep copy): the node builds one per sensor in every status.
        return {
            "offset_ms": self.offset_ms,
            "relative_offset_ms": self.relative_offset_ms,
            "drift_ppm": self.drift_ppm,
            "jitter_ms": self.jitter_ms,
            "relearns": self.relearns,
        }


def median_of(values: Iterable[float]) -> float:
    """``float(np.median(values))`` of a short window, bit for bit (float64 halves of the two middle values),
    without numpy's per-call cost: it runs on every frame."""
    ordered = sorted(values)
    n = len(ordered)
    middle = n // 2
    if n % 2:
        return float(ordered[middle])
    return (float(ordered[middle - 1]) + float(ordered[middle])) / 2.0


def _paced(times_us: Sequence[int], period_us: float) -> bool:
    """Whether frames' times (arrivals, or their own stamps) advance no faster than twice the frame rate, as a
    sensor's own stream does (give or take network bunching), not a forger's loop."""
    return times_us[-1] - times_us[0] >= 0.5 * (len(times_us) - 1) * period_us


@dataclass
class _Candidate:
    """Off-clock frames of one sensor key that agree with each other: a clock the sensor may have moved to."""

    frames: collections.deque[tuple[SensorFrame, int, int]]  # (frame, time_us, arrival_ns), oldest first
    newest_residual_us: int


class SensorClock:
    """One sensor's clock against the node's arrival clock: offset, drift, off-clock frames, phase.

    Pure: times are passed in. The residual of a frame is ``time_us - arrival_us``; its running median is the
    offset. See the module docstring ("Sensor clocks") for the rules.

    Parameters
    ----------
    period_us : float
        Nominal frame period (1e6 / fps).
    max_ahead_us, max_behind_us : int
        A residual further ahead of / behind the offset is off clock.
    relearn_after : int
        Off-clock frames of one candidate clock (agreeing with each other, paced like the sensor) that can
        re-learn the clock.
    window : int
        Frames in the running estimates; also the most frames a candidate clock keeps. Off-clock frames are
        held ``2 * relearn_after`` periods.
    """

    def __init__(
        self,
        *,
        period_us: float,
        max_ahead_us: int = DEFAULT_MAX_AHEAD_US,
        max_behind_us: int = DEFAULT_MAX_BEHIND_US,
        relearn_after: int = DEFAULT_RESYNC_AFTER,
        window: int = CLOCK_WINDOW,
    ) -> None:
        self.period_us = float(period_us)
        self.max_ahead_us = int(max_ahead_us)
        self.max_behind_us = int(max_behind_us)
        self.relearn_after = int(relearn_after)
        self.window = int(window)
        self.hold_us = 2 * self.relearn_after * self.period_us
        self.relearns = 0
        self._residuals: collections.deque[int] = collections.deque(maxlen=self.window)
        self._arrivals: collections.deque[int] = collections.deque(maxlen=self.window)
        self._offset_us: int | None = None
        self._ceiling_us: float | None = None  # the largest recent residual (the fastest path), slowly decaying
        self._last_arrival_us: int | None = None
        self._stamps: collections.deque[int] = collections.deque(maxlen=3)  # the last learned frames' times
        self._phases: collections.deque[float] = collections.deque(maxlen=self.window)
        self._far = 0
        self._candidates: list[_Candidate] = []

    @property
    def offset_us(self) -> int | None:
        """The sensor's current offset (median residual), µs; None before its first frame."""
        return self._offset_us

    @property
    def n_held(self) -> int:
        """Off-clock frames held (not yet replayed nor counted off clock)."""
        return sum(len(c.frames) for c in self._candidates)

    def on_clock(self, time_us: int, arrival_us: int) -> bool:
        """Whether a frame's time agrees with this sensor's learned clock (always True before the first)."""
        if self._offset_us is None or self._ceiling_us is None:
            return True
        residual = time_us - arrival_us
        # Ahead: against the fastest delivery seen lately (a frame cannot beat its path's shortest latency), so
        # on-time frames after a backlog are not mistaken for the future. Behind: against the median, and a
        # sensor's stamps never go back by more than their spread (its frames come in order): a second stream
        # on the key that lags the learned one is not this clock (the median of the last three learned stamps:
        # one stray frame that slipped in is no reference).
        stamps = sorted(self._stamps)
        return (
            residual - self._ceiling_us <= self.max_ahead_us
            and residual - self._offset_us >= -self.max_behind_us
            and time_us >= stamps[len(stamps) // 2] - self.max_ahead_us
        )

    def learn(self, time_us: int, arrival_us: int) -> None:
        """Add an on-clock frame to the running estimates."""
        residual = int(time_us) - int(arrival_us)
        self._residuals.append(residual)
        self._arrivals.append(int(arrival_us))
        if self._ceiling_us is None or self._last_arrival_us is None:
            self._ceiling_us = float(residual)
        else:
            elapsed_s = max(int(arrival_us) - self._last_arrival_us, 0) / 1e6
            self._ceiling_us = max(float(residual), self._ceiling_us - CEILING_DECAY_US_PER_S * elapsed_s)
        self._last_arrival_us = int(arrival_us)
        self._stamps.append(int(time_us))
        self._offset_us = int(median_of(self._residuals)) if len(self._residuals) > 2 else self._residuals[0]

    def expire(self, arrival_us: int) -> int:
        """Forget held frames older than the hold time (``2 * relearn_after`` periods); returns how many (off clock)."""
        if not self._candidates:
            return 0
        oldest_kept = arrival_us - self.hold_us
        expired = 0
        for candidate in self._candidates:
            frames = candidate.frames
            while frames and frames[0][2] // 1000 < oldest_kept:
                frames.popleft()
                expired += 1
        if expired:
            self._candidates = [c for c in self._candidates if c.frames]
        return expired

    def hold(
        self,
        frame: SensorFrame,
        time_us: int,
        arrival_ns: int,
        rig_offset_us: float | None = None,
        rig_arrival_us: int | None = None,
    ) -> tuple[list[tuple[SensorFrame, int, int]], int]:
        """Keep an off-clock frame with the candidate clock it agrees with; re-learn when a candidate wins.

        ``rig_offset_us``: the median offset of the rig's *other* sensors when they share this sensor's clock
        (device mode), else None. ``rig_arrival_us``: the latest arrival of any frame of the rig's other
        sensors (None in a one-sensor rig or before any arrived): whether the rest of the rig kept arriving
        while this sensor's stream was quiet. Returns the frames to replay when the clock re-learned (else []),
        and how many held frames were discarded (to be counted off clock).
        """
        arrival_us = int(arrival_ns) // 1000
        residual = int(time_us) - arrival_us
        discarded = self.expire(arrival_us)
        candidate = None
        for c in self._candidates:
            if abs(residual - c.newest_residual_us) <= self.max_ahead_us and (
                candidate is None or abs(residual - c.newest_residual_us) < abs(residual - candidate.newest_residual_us)
            ):
                candidate = c
        if candidate is None:
            if len(self._candidates) >= MAX_CANDIDATE_CLOCKS:  # keep the best-supported candidates
                weakest = min(self._candidates, key=lambda c: (len(c.frames), c.frames[-1][2]))
                self._candidates.remove(weakest)
                discarded += len(weakest.frames)
            candidate = _Candidate(collections.deque(), residual)
            self._candidates.append(candidate)
        if len(candidate.frames) >= self.window:
            candidate.frames.popleft()
            discarded += 1
        candidate.frames.append((frame, int(time_us), int(arrival_ns)))
        candidate.newest_residual_us = residual
        if not self._wins(candidate, rig_offset_us, rig_arrival_us):
            return [], discarded
        self._candidates.remove(candidate)
        self._residuals.clear()
        self._arrivals.clear()
        self._phases.clear()
        self._offset_us = None
        self._ceiling_us = None
        self._last_arrival_us = None
        self._stamps.clear()
        self.relearns += 1
        return list(candidate.frames), discarded

    def _wins(self, candidate: _Candidate, rig_offset_us: float | None, rig_arrival_us: int | None = None) -> bool:
        """Whether a candidate clock replaces the learned one (see "Sensor clocks" in the module docstring)."""
        frames = candidate.frames
        if len(frames) < self.relearn_after:
            return False
        arrivals = [a // 1000 for _, _, a in frames]
        stamps = [t for _, t, _ in frames]
        if not (_paced(arrivals, self.period_us) and _paced(stamps, self.period_us)):
            return False  # a forger's loop, not a sensor: frames too fast, or stamps not a frame period apart
        run_began_us = arrivals[-self.relearn_after]
        last_us = self._last_arrival_us
        if last_us is None or last_us < run_began_us:
            # The learned stream went quiet. With the rest of the rig arriving meanwhile, the clock stepped (or
            # the sensor restarted). Quiet together with the whole rig is a starved node or a stalled link, not
            # a step: the candidate's frames are merely the only ones getting through. The rig is a reference
            # only if it was still arriving when this stream went quiet: sensors silent since long before are
            # dead and must not keep a lone live sensor on a stepped clock.
            if rig_arrival_us is None or last_us is None or rig_arrival_us < last_us - self.hold_us:
                return True
            if rig_arrival_us >= run_began_us:
                return True
        learned = list(self._arrivals)
        learned_over_rate = len(learned) >= self.relearn_after and not _paced(learned, self.period_us)
        if rig_offset_us is None:
            return learned_over_rate
        distance_learned = abs(self._offset_us - rig_offset_us) if self._offset_us is not None else float("inf")
        distance_candidate = abs(median_of(t - a // 1000 for _, t, a in frames) - rig_offset_us)
        if learned_over_rate:
            return distance_candidate <= distance_learned + self.max_ahead_us
        return distance_candidate + self.max_ahead_us < distance_learned

    def drop_held(self) -> int:
        """Forget every held frame; returns how many (off clock)."""
        n = self.n_held
        self._candidates.clear()
        return n

    def smoothed_us(self, sequence: int, corrected_us: int) -> int:
        """A corrected host time with the stamp jitter removed, using the sequence number's frame grid.

        ``corrected_us`` is this frame's stamp moved onto the rig's clock; the phase ``corrected - sequence *
        period`` is steady for a sensor whose sequence counts its frames, so its running median times out the
        jitter. A phase more than three frame periods from the median is not learned; two in a row restart
        it (a restarted sequence, a sequence that does not count frames); then the corrected stamp itself is
        used until three frames agree again.
        """
        grid_us = sequence * self.period_us
        phase = corrected_us - grid_us
        if self._phases and abs(phase - median_of(self._phases)) > 3 * self.period_us:
            self._far += 1
            if self._far < 2:
                return int(corrected_us)  # one outlier: not learned
            self._phases.clear()  # two in a row: a restarted sequence (or one that does not count frames)
        self._far = 0
        self._phases.append(phase)
        if len(self._phases) < 3:
            return int(corrected_us)
        return round(grid_us + median_of(self._phases))

    def estimate(self, rig_offset_us: float | None) -> ClockEstimate:
        if self._offset_us is None:
            return ClockEstimate(None, None, None, None, self.relearns)
        residuals = np.asarray(self._residuals, dtype=np.float64)
        arrivals = np.asarray(self._arrivals, dtype=np.float64)
        drift = None
        if residuals.size >= 8 and np.ptp(arrivals) > 0:
            x = (arrivals - arrivals.mean()) / 1e6
            drift = round(float(np.dot(x, residuals - residuals.mean()) / np.dot(x, x)), 3)
        jitter = median_of(np.abs(residuals - self._offset_us).tolist()) / 1000
        relative = None if rig_offset_us is None else round((self._offset_us - rig_offset_us) / 1000, 3)
        return ClockEstimate(round(self._offset_us / 1000, 3), relative, drift, round(jitter, 3), self.relearns)
