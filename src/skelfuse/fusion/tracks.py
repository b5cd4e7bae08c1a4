"""Persons over time: a table of tracks with stable ids (pure: times are passed in, never read from a clock).

Per-track state lives in one dict keyed by track id (:class:`TrackTable` -> :class:`TrackState` -> the
track's own row of the pipeline's :class:`~skelfuse.fusion.pipeline.FusionState`), so the previous merged
position, the realignment anchor and the per-joint filters follow the person, never a row index.

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
from dataclasses import dataclass, field

import numpy as np

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


@dataclass
class TrackTable:
    """Tracks keyed by id (see the module docstring for the life cycle).

    Attributes
    ----------
    params : TrackParams
    tracks : dict[int, TrackState], in creation order (oldest first).
    next_id : the id the next new track gets.
    births_refused : new persons not tracked because the table held ``params.max_tracks`` tracks.
    """

    params: TrackParams = field(default_factory=TrackParams)
    tracks: dict[int, TrackState] = field(default_factory=dict)
    next_id: int = 1
    births_refused: int = 0

    def predict(self, time_s: float) -> Prediction:
        """Every track's predicted descriptor and gate at ``time_s``."""
        p = self.params
        states = list(self.tracks.values())
        K = len(states)
        if K == 0:
            return Prediction(
                np.zeros(0, dtype=np.int64), np.zeros((0, N_DESCRIPTOR, 3)), np.zeros(0, bool), np.zeros(0)
            )
        unseen = np.array([max(time_s - t.last_seen_s, 0.0) for t in states])
        ahead = np.minimum(unseen, p.max_predict_s)
        base = np.stack([t.descriptor for t in states])  # (K, D, 3)
        velocity = np.stack([t.velocity for t in states])  # (K, 3)
        descriptors = base + (ahead[:, None] * velocity)[:, None, :]  # x~ = x + v dt
        # The gate widens only for the time beyond one ordinary frame interval without a match.
        gate = np.minimum(p.gate_mm + p.gate_growth_mm_s * np.maximum(unseen - 0.05, 0.0), p.max_gate_mm)
        return Prediction(
            track_ids=np.array([t.track_id for t in states], dtype=np.int64),
            descriptors=descriptors,
            confirmed=np.array([t.confirmed for t in states]),
            gate_mm=gate,
        )

    def update(self, prediction: Prediction, association: Association, time_s: float) -> np.ndarray:
        """Apply one frame's association; returns the track id of every association row (-1: deleted).

        Rows ``0..K-1`` are the predicted tracks (same order), rows ``K..`` the new clusters, which become
        tentative tracks (confirmed at once when ``birth_frames == 1``).
        """
        p = self.params
        K = prediction.track_ids.size
        if association.n_tracks != K:
            raise ValueError(f"association was made for {association.n_tracks} tracks, the prediction holds {K}")
        row_ids = np.full(association.n_persons, -1, dtype=np.int64)
        n_seen_rows = association.n_sensors_seen.tolist()
        hit_rows: list[int] = []
        hit_tracks: list[TrackState] = []
        for row, track_id in enumerate(prediction.track_ids.tolist()):  # bookkeeping over a handful of tracks
            track = self.tracks[track_id]
            n_seen = n_seen_rows[row]
            if n_seen > 0:
                hit_rows.append(row)
                hit_tracks.append(track)
                row_ids[row] = track_id
            else:
                track.hits = 0
                track.n_sensors_seen = 0
                if not track.confirmed or time_s - track.last_seen_s > p.timeout_s:
                    del self.tracks[track_id]
                else:
                    row_ids[row] = track_id
        if hit_tracks:
            self._hit_many(
                hit_tracks,
                prediction.descriptors[hit_rows],
                association.descriptors[hit_rows],
                [n_seen_rows[row] for row in hit_rows],
                time_s,
            )
        room = max(int(p.max_tracks) - len(self.tracks), 0)
        for row in range(K, association.n_persons):
            if room == 0:
                self.births_refused += 1  # row_ids[row] stays -1: its bodies are not tracked
                continue
            room -= 1
            track_id = self.next_id
            self.next_id += 1
            self.tracks[track_id] = TrackState(
                track_id=track_id,
                status=CONFIRMED if p.birth_frames <= 1 else TENTATIVE,
                descriptor=association.descriptors[row].copy(),
                velocity=np.zeros(3),
                born_s=float(time_s),
                last_seen_s=float(time_s),
                n_sensors_seen=int(association.n_sensors_seen[row]),
            )
            row_ids[row] = track_id
        return row_ids

    def _hit_many(
        self,
        tracks: list[TrackState],
        predicted: np.ndarray,
        measured: np.ndarray,
        n_seen: list[int],
        time_s: float,
    ) -> None:
        """Update the tracks that were seen this frame: velocity from the mean step of their common
        descriptor points (smoothed, capped at ``max_speed_mm_s``), the descriptor (a point the sensors
        miss keeps its prediction), and the counters that confirm a tentative track."""
        p = self.params
        time_s = float(time_s)
        dt = np.array([time_s - t.last_seen_s for t in tracks])  # (H,)
        step = measured - np.stack([t.descriptor for t in tracks])  # (H, D, 3)
        ok = np.isfinite(step).all(axis=-1)  # (H, D)
        count = ok.sum(axis=-1)
        moved = (dt > 0) & (count > 0)
        if moved.any():
            # Sum over the common points in point order (adding exact zeros elsewhere), then / count / dt,
            # as step[ok].mean(axis=0) / dt does.
            total = np.where(ok[..., None], step, 0.0).sum(axis=-2)  # (H, 3)
            v_meas = total / np.maximum(count, 1)[:, None] / np.where(moved, dt, 1.0)[:, None]
            old_v = np.stack([t.velocity for t in tracks])
            smoothed = p.velocity_smoothing * v_meas + (1.0 - p.velocity_smoothing) * old_v
            first = np.array([t.n_frames_seen < 2 for t in tracks])
            v = np.where(first[:, None], v_meas, smoothed)
            for i in np.nonzero(moved)[0].tolist():
                row = v[i]
                speed = math.sqrt(float(row.dot(row)))
                tracks[i].velocity = row * min(1.0, p.max_speed_mm_s / speed) if speed > 0 else row
        # A point the sensors miss this frame keeps its prediction.
        descriptors = np.where(np.isfinite(measured), measured, predicted)
        for i, track in enumerate(tracks):
            track.descriptor = descriptors[i]
            track.last_seen_s = time_s
            track.hits += 1
            track.n_frames_seen += 1
            track.n_sensors_seen = n_seen[i]
            if not track.confirmed and track.hits >= p.birth_frames:
                track.status = CONFIRMED


def stack_states(states: list[FusionState]) -> FusionState:
    """Concatenate 1-row (or n-row) FusionStates into one state of all their rows, in order.

    Works field by field, so fields added to FusionState later are carried too; an optional field that is
    None in some states and an array in others is filled with zeros where None (FusionState reads None as 0).
    """
    if not states:
        raise ValueError("stack_states needs at least one state")
    values = {}
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
        values = {}
        for f in dataclasses.fields(FusionState):
            value = getattr(state, f.name)
            values[f.name] = None if value is None else value[row : row + 1].copy()
        out.append(FusionState(**values))
    return out
