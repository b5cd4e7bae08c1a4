"""When the fusion node cannot keep up: shed the oldest instants, so its output is never far behind real time.

An instant whose fusion takes longer than the sensors' frame period (a crowd in a big rig on a slow PC) makes
every later instant wait longer: without a bound the node drifts further and further behind, its output
useless live. :class:`LagShedder` holds the bound (``[node] max_lag_s``): when an instant's turn to be fused
comes, its age (now minus the arrival of its first frame, on the node's monotonic clock) is compared with
the bound; an instant older than that is shed, not fused. The check is on whole instants (all sensors'
frames of one instant go together: no instant is fused from a part of its frames because the rest was
shed), and it only ever sheds what is already too old: a node that keeps up, or falls behind for less than
the bound (a pause, a burst), loses nothing, and the newest instants are always the ones kept. Under
sustained overload the node fuses as many instants as it can and its output stays within the bound plus one
instant's fusion time of real time.

Shedding is counted per reason (:data:`SHED_BEHIND`) and per sensor (the frames of the shed instants), and
logged once per episode: a warning when shedding starts, a line with the count when it has stopped for
:data:`EPISODE_QUIET_S`; a new episode within :data:`LOG_EVERY_S` of the last warning is counted, not logged.

Pure logic: the clock is passed in.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Iterable

log = logging.getLogger("skelfuse.service.node")  # the node's logger

SHED_BEHIND = "behind"
"""Shed reason: the instant was older than ``[node] max_lag_s`` when its turn to be fused came."""
EPISODE_QUIET_S = 2.0
"""An episode of shedding ends after this long without a shed instant."""
LOG_EVERY_S = 30.0
"""At most one "shedding" warning this often (episodes in between are counted in the next one)."""


class LagShedder:
    """Decides which instants are too old to fuse, counts them, and logs the episodes (module docstring).

    Parameters
    ----------
    max_lag_s : float
        ``[node] max_lag_s``.
    what : str
        Who sheds, for the log lines (e.g. "fusion node fusion").

    Attributes
    ----------
    by_reason : Counter
        Instants shed per reason, since the start.
    frames_by_sensor : Counter
        Frames of the shed instants, per sensor id.
    episodes : int
        Episodes of shedding since the start.
    """

    def __init__(self, max_lag_s: float, what: str = "fusion node") -> None:
        if not max_lag_s > 0:
            raise ValueError(f"max_lag_s must be > 0, got {max_lag_s!r}")
        self.max_lag_s = float(max_lag_s)
        self.max_lag_ns = round(max_lag_s * 1e9)
        self.what = what
        self.by_reason: Counter[str] = Counter()
        self.frames_by_sensor: Counter[str] = Counter()
        self.episodes = 0
        self._episode_started_ns: int | None = None  # None: not shedding now
        self._episode_shed = 0
        self._last_shed_ns = 0
        self._last_warning_ns: int | None = None
        self._unlogged_episodes = 0
        self._unlogged_shed = 0
        self._logging_episode = False

    @property
    def total(self) -> int:
        """Instants shed since the start."""
        return sum(self.by_reason.values())

    def too_old(self, first_arrival_ns: int, now_ns: int) -> bool:
        """Whether an instant whose first frame arrived at ``first_arrival_ns`` is over the bound at ``now_ns``."""
        return now_ns - first_arrival_ns > self.max_lag_ns

    def shed(self, sensor_ids: Iterable[str], age_ns: int, now_ns: int, fusion_ms: float | None) -> None:
        """Count one shed instant (its frames' ``sensor_ids``, its ``age_ns``); warn if an episode starts.
        ``fusion_ms``: the last fused instant's fusion time, for the warning."""
        self.by_reason[SHED_BEHIND] += 1
        self.frames_by_sensor.update(sensor_ids)
        if self._episode_started_ns is None:
            self._start_episode(age_ns, now_ns, fusion_ms)
        self._episode_shed += 1
        self._last_shed_ns = now_ns

    def fused(self, now_ns: int) -> None:
        """An instant was fused at ``now_ns``: ends the episode once nothing was shed for EPISODE_QUIET_S."""
        started = self._episode_started_ns
        if started is None or now_ns - self._last_shed_ns < EPISODE_QUIET_S * 1e9:
            return
        if self._logging_episode:
            log.info(
                "%s caught up: %d instants shed over %.1f s (in all %d since the start)",
                self.what,
                self._episode_shed,
                (self._last_shed_ns - started) / 1e9,
                self.total,
            )
        else:
            self._unlogged_episodes += 1
            self._unlogged_shed += self._episode_shed
        self._episode_started_ns = None

    def _start_episode(self, age_ns: int, now_ns: int, fusion_ms: float | None) -> None:
        self.episodes += 1
        self._episode_started_ns = now_ns
        self._episode_shed = 0
        last = self._last_warning_ns
        self._logging_episode = last is None or now_ns - last >= LOG_EVERY_S * 1e9
        if not self._logging_episode:
            return
        self._last_warning_ns = now_ns
        since = (
            f"; {self._unlogged_episodes} shorter episodes since the last warning shed {self._unlogged_shed}"
            if self._unlogged_episodes
            else ""
        )
        took = "" if fusion_ms is None else f" (the last instant took {fusion_ms:.1f} ms to fuse)"
        log.warning(
            "%s cannot keep up: an instant waited %.2f s, over [node] max_lag_s = %g s; shedding the oldest "
            "instants until it catches up%s%s. Fewer sensors or people per node, or a faster PC, fix it",
            self.what,
            age_ns / 1e9,
            self.max_lag_s,
            took,
            since,
            extra={"alarm": "shedding"},
        )
        self._unlogged_episodes = 0
        self._unlogged_shed = 0
