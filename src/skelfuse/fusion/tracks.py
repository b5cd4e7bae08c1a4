"""Persons over time: a table of tracks with stable ids (pure: times are passed in, never read from a clock).

Per-track state lives in one row per track of :class:`TrackTable`'s arrays (ids, status, descriptor,
velocity, times, counters, and the track's own row of the pipeline's
:class:`~skelfuse.fusion.pipeline.FusionState`); rows are compacted when tracks die and appended at births,
so the previous merged position, the realignment anchor and the per-joint filters follow the person. Every
step is batched numpy over all tracks: no per-track Python objects on the hot path (:attr:`TrackTable.tracks`
gives :class:`TrackState` snapshots for inspection).

Cycle, once per frame (driven by :class:`skelfuse.fusion.people.PeopleFuser`):

1. :meth:`TrackTable.predict`: every track's torso descriptor (see :mod:`skelfuse.fusion.association`)
   extrapolated with the constant velocity of the torso to the frame time, its gate (wider while it
   coasts) and whether it is confirmed; oldest track first.
2. :func:`skelfuse.fusion.association.associate` matches bodies to these predictions.
3. :meth:`TrackTable.update`: a matched track takes the measured descriptor (median over its sensors) and
   updates its velocity; an unmatched one misses. New clusters become tentative tracks.

Life cycle and policies
-----------------------
- Birth: a new cluster of leftover bodies starts a *tentative* track. It is *confirmed* after
  ``birth_frames`` consecutive frames with a match; a tentative track that misses one frame is deleted
  (a ghost or a passer-by at the edge never gets a public identity). ``birth_frames = 1`` confirms at once.
- Coasting: a confirmed track no sensor sees keeps being predicted (constant velocity, at most
  ``max_predict_s`` ahead) with a gate that widens by ``gate_growth_mm_s`` per second unseen (capped at
  ``max_gate_mm``), so a person walking behind another is picked up again where they reappear.
- Death: a confirmed track unseen for more than ``timeout_s`` is deleted.
- Ids: allocated from a counter that only increases (starting at 1), at the creation of the tentative
  track; an id is never reused, so public ids can have gaps where tentative tracks died.
- Velocity: the mean displacement of the descriptor points both the prediction base and the measurement
  have, divided by the time since the last match, exponentially smoothed (``velocity_smoothing``) and
  clamped to ``max_speed_mm_s``; zero on the first match.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from skelfuse.fusion import kernels
from skelfuse.fusion.association import DEFAULT_GATE_MM, N_DESCRIPTOR, Association
from skelfuse.fusion.pipeline import FusionState

MAX_TRACKS = 64
"""Live tracks at most: the persons a fused frame may hold (``skelfuse.wire.codec.MAX_PERSONS``, checked by a
test; the core cannot import the wire layer)."""
TENTATIVE = "tentative"
CONFIRMED = "confirmed"


@dataclass(frozen=True)
class TrackParams:
    """Life-cycle parameters of :class:`TrackTable` (units in the names).

    Attributes
    ----------
    gate_mm : association gate for a track seen in the previous frame, mm.
    birth_frames : consecutive matched frames before a tentative track is confirmed (>= 1).
    timeout_s : a confirmed track unseen for longer than this dies, s.
    gate_growth_mm_s : how fast the gate widens while a track is unseen, mm per second unseen.
    max_gate_mm : cap of the widened gate, mm.
    max_predict_s : the constant-velocity prediction never runs further ahead than this, s.
    velocity_smoothing : weight of the new velocity measurement in (0, 1].
    max_speed_mm_s : clamp of the torso speed, mm/s (a sprint is ~ 7000; indoors people walk ~ 1000-1500).
    max_tracks : live tracks at most (tentative and confirmed); new persons beyond it are not tracked and are
        counted in :attr:`TrackTable.births_refused`. The default is the fused frame's cap (64 persons), so
        coasting tracks plus new bodies can never make a frame the wire format refuses.
    """

    gate_mm: float = DEFAULT_GATE_MM
    birth_frames: int = 3
    timeout_s: float = 1.0
    gate_growth_mm_s: float = 600.0
    max_gate_mm: float = 900.0
    max_predict_s: float = 0.5
    velocity_smoothing: float = 0.5
    max_speed_mm_s: float = 3000.0
    max_tracks: int = MAX_TRACKS

    def __post_init__(self) -> None:
        if not 1 <= int(self.max_tracks) <= MAX_TRACKS:
            raise ValueError(f"TrackParams.max_tracks must be in 1..{MAX_TRACKS}, got {self.max_tracks!r}")
        if int(self.birth_frames) < 1:
            raise ValueError(f"TrackParams.birth_frames must be >= 1, got {self.birth_frames!r}")
        for name in ("gate_mm", "timeout_s", "max_gate_mm", "max_speed_mm_s"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"TrackParams.{name} must be a finite number > 0, got {value!r}")
        for name in ("gate_growth_mm_s", "max_predict_s"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ValueError(f"TrackParams.{name} must be a finite number >= 0, got {value!r}")
        if not 0.0 < self.velocity_smoothing <= 1.0:
            raise ValueError(f"TrackParams.velocity_smoothing must be in (0, 1], got {self.velocity_smoothing!r}")
        if self.max_gate_mm < self.gate_mm:
            raise ValueError(f"TrackParams.max_gate_mm ({self.max_gate_mm}) must be >= gate_mm ({self.gate_mm})")


@dataclass
class TrackState:
    """One person's track.

    Attributes
    ----------
    track_id : int, stable id (never reused).
    status : "tentative" or "confirmed".
    descriptor : (D, 3) float64, torso descriptor at ``last_seen_s`` (world mm; NaN points unknown).
    velocity : (3,) float64, torso velocity, mm/s.
    born_s : time of creation, s.
    last_seen_s : time of the last match, s.
    hits : consecutive matched frames (reset by a miss).
    n_frames_seen : total matched frames.
    n_sensors_seen : sensors that saw the person in the last frame (0 while coasting).
    fusion : the track's own 1-row FusionState, or None until the track is first fused.
    """

    track_id: int
    status: str
    descriptor: np.ndarray
    velocity: np.ndarray
    born_s: float
    last_seen_s: float
    hits: int = 1
    n_frames_seen: int = 1
    n_sensors_seen: int = 0
    fusion: FusionState | None = None

    @property
    def confirmed(self) -> bool:
        return self.status == CONFIRMED

    def coasting(self, time_s: float) -> bool:
        """Unseen at ``time_s`` (no sensor matched the track in that frame)."""
        return self.last_seen_s < time_s


@dataclass(frozen=True)
class Prediction:
    """The tracks as :func:`~skelfuse.fusion.association.associate` wants them, oldest first.

    Attributes
    ----------
    track_ids : (K,) int64
    descriptors : (K, D, 3) float64, predicted torso descriptors, mm.
    confirmed : (K,) bool
    gate_mm : (K,) float64
    """

    track_ids: np.ndarray
    descriptors: np.ndarray
    confirmed: np.ndarray
    gate_mm: np.ndarray


class TrackTable:
    """Tracks, one row per live track, oldest (lowest id) first, as arrays (see the module docstring for the
    life cycle): :meth:`predict` and :meth:`update` are batched numpy over all tracks, no per-track objects.

    Parameters
    ----------
    params : TrackParams
    next_id : the id the next new track gets.
    births_refused : new persons not tracked because the table held ``params.max_tracks`` tracks.

    Attributes
    ----------
    ids : (K,) int64, track ids, ascending.
    confirmed : (K,) bool.
    descriptor : (K, D, 3) float64, torso descriptor at ``last_seen_s`` (world mm; NaN points unknown).
    velocity : (K, 3) float64, torso velocity, mm/s.
    born_s, last_seen_s : (K,) float64, s.
    hits : (K,) int64, consecutive matched frames (reset by a miss).
    n_frames_seen : (K,) int64, total matched frames.
    n_sensors_seen : (K,) int64, sensors that saw the person in the last frame (0 while coasting).
    fusion : FusionState with K rows (each track's own pipeline state), or None; kept row-aligned by
        :meth:`update` (births get rows from its ``init_fusion``).
    association_rows : (K,) int64, the association row each track had in the last :meth:`update`.
    """

    def __init__(self, params: TrackParams | None = None, *, next_id: int = 1, births_refused: int = 0) -> None:
        self.params = TrackParams() if params is None else params
        self.next_id = int(next_id)
        self.births_refused = int(births_refused)
        self.ids = np.zeros(0, dtype=np.int64)
        self.confirmed = np.zeros(0, dtype=bool)
        self.descriptor = np.zeros((0, N_DESCRIPTOR, 3))
        self.velocity = np.zeros((0, 3))
        self.born_s = np.zeros(0)
        self.last_seen_s = np.zeros(0)
        self.hits = np.zeros(0, dtype=np.int64)
        self.n_frames_seen = np.zeros(0, dtype=np.int64)
        self.n_sensors_seen = np.zeros(0, dtype=np.int64)
        self.fusion: FusionState | None = None
        self.association_rows = np.zeros(0, dtype=np.int64)

    @property
    def n_tracks(self) -> int:
        return int(self.ids.size)

    @property
    def tracks(self) -> dict[int, TrackState]:
        """A snapshot of the tracks as :class:`TrackState` records keyed by id, oldest first (for inspection;
        the table itself holds arrays)."""
        out = {}
        for row, track_id in enumerate(self.ids.tolist()):
            fusion = None if self.fusion is None else take_state(self.fusion, slice(row, row + 1))
            out[track_id] = TrackState(
                track_id=track_id,
                status=CONFIRMED if self.confirmed[row] else TENTATIVE,
                descriptor=self.descriptor[row].copy(),
                velocity=self.velocity[row].copy(),
                born_s=float(self.born_s[row]),
                last_seen_s=float(self.last_seen_s[row]),
                hits=int(self.hits[row]),
                n_frames_seen=int(self.n_frames_seen[row]),
                n_sensors_seen=int(self.n_sensors_seen[row]),
                fusion=fusion,
            )
        return out

    def predict(self, time_s: float) -> Prediction:
        """Every track's predicted descriptor and gate at ``time_s``."""
        p = self.params
        unseen = np.maximum(time_s - self.last_seen_s, 0.0)
        ahead = np.minimum(unseen, p.max_predict_s)
        descriptors = self.descriptor + (ahead[:, None] * self.velocity)[:, None, :]  # x~ = x + v dt
        # The gate widens only for the time beyond one ordinary frame interval without a match.
        gate = np.minimum(p.gate_mm + p.gate_growth_mm_s * np.maximum(unseen - 0.05, 0.0), p.max_gate_mm)
        return Prediction(track_ids=self.ids, descriptors=descriptors, confirmed=self.confirmed.copy(), gate_mm=gate)

    def update(
        self,
        prediction: Prediction,
        association: Association,
        time_s: float,
        init_fusion: Callable[[int], FusionState] | None = None,
    ) -> np.ndarray:
        """Apply one frame's association; returns the track id of every association row (-1: deleted).

        Rows ``0..K-1`` are the predicted tracks (same order), rows ``K..`` the new clusters, which become
        tentative tracks (confirmed at once when ``birth_frames == 1``). ``init_fusion(n)``, when given, makes
        the fusion-state rows of the n new tracks (their :attr:`fusion` rows before they are first fused).
        """
        p = self.params
        time_s = float(time_s)
        K = prediction.track_ids.size
        if association.n_tracks != K or K != self.n_tracks:
            raise ValueError(
                f"association was made for {association.n_tracks} tracks, the prediction holds {K}, "
                f"the table {self.n_tracks}"
            )
        n_seen = association.n_sensors_seen
        hit = n_seen[:K] > 0
        # A miss: the streak ends; a tentative track, or a confirmed one unseen past the timeout, dies.
        dead = ~hit & (~self.confirmed | (time_s - self.last_seen_s > p.timeout_s))
        row_ids = np.full(association.n_persons, -1, dtype=np.int64)
        row_ids[:K] = np.where(dead, -1, self.ids)
        every_hit = K > 0 and bool(hit.all())  # the usual frame: every track seen
        if every_hit or hit.any():
            self._hit(hit, prediction.descriptors, association.descriptors[:K], n_seen[:K], time_s)
        if not every_hit:
            self.hits[~hit] = 0
            self.n_sensors_seen[~hit] = 0
        kept = np.flatnonzero(~dead)
        if kept.size < K:
            self._take(kept)
        n_new = association.n_persons - K
        n_born = min(n_new, max(int(p.max_tracks) - kept.size, 0))
        self.births_refused += n_new - n_born  # row_ids of the refused rows stay -1: their bodies are not tracked
        self.association_rows = np.concatenate([kept, K + np.arange(n_born)]) if n_born else kept
        if n_born:
            born = np.arange(self.next_id, self.next_id + n_born, dtype=np.int64)
            self.next_id += n_born
            row_ids[K : K + n_born] = born
            new = slice(K, K + n_born)
            self._append(
                born,
                np.full(n_born, p.birth_frames <= 1),
                association.descriptors[new],
                np.full(n_born, time_s),
                n_seen[new].astype(np.int64),
                None if init_fusion is None else init_fusion(n_born),
            )
        return row_ids

    def _hit(
        self, hit: np.ndarray, predicted: np.ndarray, measured: np.ndarray, n_seen: np.ndarray, time_s: float
    ) -> None:
        """Update the tracks that were seen this frame (rows ``hit``): their motion (:func:`seen_motion`) and the
        counters that confirm a tentative track."""
        p = self.params
        self.descriptor, self.velocity = seen_motion(
            self.descriptor, self.velocity, self.last_seen_s, self.n_frames_seen, predicted, measured, hit, time_s, p
        )
        idx = np.flatnonzero(hit)
        self.last_seen_s[idx] = time_s
        self.hits[idx] += 1
        self.n_frames_seen[idx] += 1
        self.n_sensors_seen[idx] = n_seen[idx]
        self.confirmed[idx] |= self.hits[idx] >= p.birth_frames

    def _take(self, rows: np.ndarray) -> None:
        for name in _ROW_FIELDS:
            setattr(self, name, getattr(self, name)[rows])
        if self.fusion is not None:
            self.fusion = take_state(self.fusion, rows)

    def _append(
        self,
        ids: np.ndarray,
        confirmed: np.ndarray,
        descriptor: np.ndarray,
        time_s: np.ndarray,
        n_seen: np.ndarray,
        fusion: FusionState | None,
    ) -> None:
        n = ids.size
        ones = np.ones(n, dtype=np.int64)
        new = {
            "ids": ids,
            "confirmed": confirmed,
            "descriptor": descriptor.copy(),
            "velocity": np.zeros((n, 3)),
            "born_s": time_s,
            "last_seen_s": time_s.copy(),
            "hits": ones,
            "n_frames_seen": ones.copy(),
            "n_sensors_seen": n_seen,
        }
        for name in _ROW_FIELDS:
            setattr(self, name, np.concatenate([getattr(self, name), new[name]]))
        if fusion is not None:
            self.fusion = fusion if self.fusion is None else stack_states([self.fusion, fusion])


_ROW_FIELDS = (
    "ids",
    "confirmed",
    "descriptor",
    "velocity",
    "born_s",
    "last_seen_s",
    "hits",
    "n_frames_seen",
    "n_sensors_seen",
)


def seen_motion(
    descriptor: np.ndarray,
    velocity: np.ndarray,
    last_seen_s: np.ndarray,
    n_frames_seen: np.ndarray,
    predicted: np.ndarray,
    measured: np.ndarray,
    hit: np.ndarray,
    time_s: float,
    params: TrackParams,
) -> tuple[np.ndarray, np.ndarray]:
    """The K tracks' new descriptors (K, D, 3) and velocities (K, 3) after this frame's matches (new arrays).

    A track seen this frame (``hit``) takes as velocity the mean step of the descriptor points it shares with its
    measurement, divided by the time since its last match, smoothed (``velocity_smoothing``; the measured one on
    its first two matches) and capped at ``max_speed_mm_s`` (kept when no point is shared or no time passed); its
    descriptor becomes the measurement, a point the sensors miss keeping its prediction. Other rows are
    unchanged. Runs in a compiled kernel (:mod:`skelfuse.fusion.kernels.tracks`); the numpy form is the test
    reference (:mod:`skelfuse.fusion.reference.tracks`).

    Parameters
    ----------
    descriptor, predicted, measured : (K, D, 3) mm; velocity : (K, 3) mm/s; last_seen_s : (K,) s;
    n_frames_seen : (K,) int; hit : (K,) bool; time_s : this frame's time, s; params : TrackParams.
    """
    descriptor = np.ascontiguousarray(descriptor, dtype=np.float64)
    K = len(descriptor)
    shapes = {np.shape(a) for a in (descriptor, predicted, measured)}
    if len(shapes) != 1 or descriptor.shape[2:] != (3,) or np.shape(velocity) != (K, 3):
        raise ValueError(
            f"seen_motion needs descriptor, predicted, measured (K, D, 3) and velocity (K, 3), got {shapes} and "
            f"{np.shape(velocity)}"
        )
    if np.shape(last_seen_s) != (K,) or np.shape(n_frames_seen) != (K,) or np.shape(hit) != (K,):
        raise ValueError(f"seen_motion needs last_seen_s, n_frames_seen and hit of shape ({K},)")
    return kernels.load().tracks.seen_motion(
        descriptor,
        np.ascontiguousarray(velocity, dtype=np.float64),
        np.ascontiguousarray(last_seen_s, dtype=np.float64),
        np.ascontiguousarray(n_frames_seen, dtype=np.int64),
        np.ascontiguousarray(predicted, dtype=np.float64),
        np.ascontiguousarray(measured, dtype=np.float64),
        np.ascontiguousarray(hit, dtype=np.bool_),
        float(time_s),
        float(params.velocity_smoothing),
        float(params.max_speed_mm_s),
    )


def take_state(state: FusionState, rows: np.ndarray | slice) -> FusionState:
    """The rows ``rows`` of a FusionState (an index array: new arrays, in that order; a slice: views)."""
    values: dict[str, Any] = {
        f.name: None if getattr(state, f.name) is None else getattr(state, f.name)[rows]
        for f in dataclasses.fields(FusionState)
    }
    return FusionState(**values)


def put_state(state: FusionState, rows: np.ndarray, values: FusionState) -> None:
    """Write the rows of ``values`` into the rows ``rows`` of ``state`` (in place; both hold the same fields)."""
    for f in dataclasses.fields(FusionState):
        target = getattr(state, f.name)
        if target is not None:
            target[rows] = getattr(values, f.name)


def stack_states(states: list[FusionState]) -> FusionState:
    """Concatenate 1-row (or n-row) FusionStates into one state of all their rows, in order.

    Works field by field, so fields added to FusionState later are carried too; an optional field that is
    None in some states and an array in others is filled with zeros where None (FusionState reads None as 0).
    """
    if not states:
        raise ValueError("stack_states needs at least one state")
    values: dict[str, Any] = {}
    for f in dataclasses.fields(FusionState):
        parts = [getattr(s, f.name) for s in states]
        present = [v for v in parts if v is not None]
        if not present:
            values[f.name] = None
            continue
        like = present[0]
        filled = [
            v if v is not None else np.zeros((s.n_bodies, *like.shape[1:]), dtype=like.dtype)
            for v, s in zip(parts, states, strict=True)
        ]
        values[f.name] = np.concatenate(filled, axis=0)
    return FusionState(**values)


def split_state(state: FusionState) -> list[FusionState]:
    """The rows of a FusionState as 1-row states (copies), the inverse of :func:`stack_states`."""
    out = []
    for row in range(state.n_bodies):
        values: dict[str, Any] = {}
        for f in dataclasses.fields(FusionState):
            value = getattr(state, f.name)
            values[f.name] = None if value is None else value[row : row + 1].copy()
        out.append(FusionState(**values))
    return out
