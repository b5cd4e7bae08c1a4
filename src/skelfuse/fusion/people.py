"""Several people: association + tracks + the fusion pipeline, one fused skeleton per confirmed track.

:class:`PeopleFuser` is the stateful front of the multi-person core; every step is pure numpy apart from
the track table's row bookkeeping. Cycle of :meth:`PeopleFuser.step`:

1. :meth:`TrackTable.predict <skelfuse.fusion.tracks.TrackTable.predict>`: where every track should be now.
2. :func:`~skelfuse.fusion.association.associate`: sensor bodies -> person rows (gated Hungarian per
   sensor on the mirror-invariant torso descriptor; leftovers clustered across sensors into new persons).
3. :meth:`TrackTable.update <skelfuse.fusion.tracks.TrackTable.update>`: hits, misses, births, deaths.
4. Fusion: the candidates of every *confirmed* live track (seen or coasting) are stacked as rows B = P and
   fused by ONE :func:`~skelfuse.fusion.pipeline.fuse` call on the tracks' own FusionState rows (the table's
   whole state when every track is confirmed, else its confirmed rows, written back afterwards). A track
   is first fused in the frame it is confirmed (fresh state, made at its birth). A coasting track is fused
   with all-NaN candidates, so the pipeline's filter predicts it (for at most ``params.max_coast_frames``
   frames, NaN afterwards) while the track itself lives up to ``timeout_s``.

Only confirmed tracks appear in the output, in ascending track id order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skelfuse.fusion.association import DEFAULT_DUPLICATE_MM, DEFAULT_GATE_MM, associate
from skelfuse.fusion.pipeline import FusionState, fuse, init_state
from skelfuse.fusion.presets import FusionParams
from skelfuse.fusion.tracks import TrackParams, TrackTable, put_state, take_state
from skelfuse.schema.skeleton import N_JOINTS

DEFAULT_DT_S = 1.0 / 30.0


@dataclass(frozen=True)
class PeopleResult:
    """The fused people of one instant (P confirmed tracks, ascending id).

    Attributes
    ----------
    time_s : float, the frame time given to :meth:`PeopleFuser.step`.
    track_ids : (P,) int64, stable ids.
    positions : (P, J, 3) float64, mm, world; NaN = no estimate.
    n_agree : (P, J) int16, sensors in the winning cluster (0 = coasted / none).
    confidence : (P, J) uint8, best merged tracker confidence (0 = none).
    contributors : (P, S) bool, sensors merged into at least one joint of the person.
    coasting : (P,) bool, no sensor saw the person in this frame (positions are predictions or NaN).
    assignment : (S, B) int64, output row of each input body (-1: padding, a tentative track, a duplicate).
    body_track_ids : (S, B) int64, track id of each input body, tentative tracks included (-1: none).
    orientations : (P, J, 4) float64 or None, fused world quaternions w, x, y, z (``params.orientations``).
    position_std : (P, J) float64 or None, mm, one-sigma position uncertainty per axis (``params.position_std``).
    held_out : (P, S) uint8 or None, why each sensor's view of the person was held out of the merge (0 = used
        or absent; :data:`skelfuse.fusion.plausibility.HOLD_REASONS`), with ``params.plausibility_gate_mm``.
    agreement_mm : (P,) float64 or None, how far the used views lie from the fused torso (see
        :attr:`skelfuse.fusion.pipeline.FusionResult.agreement_mm`), with ``params.position_std``.
    merged : (P, J, 3) float64 or None, mm, the merge before the temporal filter (NaN = no measurement).
    restarted : (P,) bool or None, the person's filter restarted at the views (plausibility follow rule).
    """

    time_s: float
    track_ids: np.ndarray
    positions: np.ndarray
    n_agree: np.ndarray
    confidence: np.ndarray
    contributors: np.ndarray
    coasting: np.ndarray
    assignment: np.ndarray
    body_track_ids: np.ndarray
    orientations: np.ndarray | None = None
    position_std: np.ndarray | None = None
    held_out: np.ndarray | None = None
    agreement_mm: np.ndarray | None = None
    merged: np.ndarray | None = None
    restarted: np.ndarray | None = None

    @property
    def n_persons(self) -> int:
        return int(self.track_ids.size)


class PeopleFuser:
    """Stateful multi-person fusion (see the module docstring).

    Parameters
    ----------
    params : FusionParams of the per-person pipeline.
    gate_mm : association gate, mm (mean torso-descriptor distance).
    birth_frames : consecutive matched frames before a track is confirmed and output.
    timeout_s : a confirmed track unseen for longer than this dies, s.
    duplicate_mm : a second body of one sensor this close to a matched track is a duplicate (None: keep).
    track_params : full :class:`TrackParams` (overrides gate_mm, birth_frames and timeout_s when given).

    Attributes
    ----------
    table : TrackTable, the tracks and their per-track fusion state.
    last_time_s : time of the previous step, or None.
    """

    def __init__(
        self,
        params: FusionParams,
        *,
        gate_mm: float = DEFAULT_GATE_MM,
        birth_frames: int = 3,
        timeout_s: float = 1.0,
        duplicate_mm: float | None = DEFAULT_DUPLICATE_MM,
        track_params: TrackParams | None = None,
    ) -> None:
        if not isinstance(params, FusionParams):
            raise ValueError(f"params must be a FusionParams, got {type(params).__name__}")
        self.params = params
        if track_params is None:
            track_params = TrackParams(
                gate_mm=float(gate_mm), birth_frames=int(birth_frames), timeout_s=float(timeout_s)
            )
        self.track_params = track_params
        self.duplicate_mm = duplicate_mm
        self.table = TrackTable(track_params)
        self.last_time_s: float | None = None
        self.sensor_positions: np.ndarray | None = None  # (S, 3) world mm, for the realignment's rear-view rule

    def reset(self) -> None:
        """Forget every track (ids keep counting up: an id is never reused)."""
        self.table = TrackTable(self.track_params, next_id=self.table.next_id, births_refused=self.table.births_refused)
        self.last_time_s = None

    def step(
        self,
        world_positions: np.ndarray,
        confidence: np.ndarray,
        valid: np.ndarray,
        time_s: float,
        world_orientations: np.ndarray | None = None,
    ) -> PeopleResult:
        """Associate, track and fuse one frame.

        Parameters
        ----------
        world_positions : (S, B, J, 3) float, mm, world frame; the bodies of every sensor, NaN-padded.
        confidence : (S, B, J) uint8.
        valid : (S, B) bool, the slot holds a body.
        time_s : frame time, s; must increase from step to step.
        world_orientations : (S, B, J, 4) float or None, the bodies' joint quaternions in the world frame
            (w, x, y, z; NaN = none), used with ``params.orientations``.

        Returns
        -------
        PeopleResult

        Raises
        ------
        ValueError
            On bad shapes or a time that does not increase.
        """
        time_s = float(time_s)
        if not math.isfinite(time_s):
            raise ValueError(f"time_s must be finite, got {time_s!r}")
        if self.last_time_s is not None and time_s <= self.last_time_s:
            raise ValueError(f"time_s must increase: got {time_s} after {self.last_time_s}")
        dt_s = DEFAULT_DT_S if self.last_time_s is None else time_s - self.last_time_s
        self.last_time_s = time_s
        valid = np.asarray(valid, dtype=bool)

        table = self.table
        prediction = table.predict(time_s)
        association = associate(
            world_positions,
            confidence,
            valid,
            prediction.descriptors,
            prediction.confirmed,
            gate_mm=self.track_params.gate_mm,
            track_gate_mm=prediction.gate_mm,
            duplicate_mm=self.duplicate_mm,
        )
        row_ids = table.update(prediction, association, time_s, self._init_fusion)

        # Confirmed live tracks (table rows, ascending id) and their association rows.
        out_idx = np.flatnonzero(table.confirmed)
        every = out_idx.size == table.n_tracks
        rows = table.association_rows if every else table.association_rows[out_idx]
        S = valid.shape[0]
        P = out_idx.size
        out_row_of_assoc = np.full(association.n_persons + 1, -1, dtype=np.int64)  # last slot: "-1" lookups
        out_row_of_assoc[rows] = np.arange(P)
        assignment = out_row_of_assoc[association.person_of_body]
        body_track_ids = np.append(row_ids, -1)[association.person_of_body]

        if P == 0:
            return PeopleResult(
                orientations=np.zeros((0, N_JOINTS, 4)) if self.params.orientations else None,
                position_std=np.zeros((0, N_JOINTS)) if self.params.position_std else None,
                held_out=np.zeros((0, S), dtype=np.uint8) if self.params.plausibility_gate_mm is not None else None,
                agreement_mm=np.zeros(0) if self.params.position_std else None,
                merged=np.zeros((0, N_JOINTS, 3)),
                restarted=np.zeros(0, dtype=bool) if self.params.plausibility_gate_mm is not None else None,
                time_s=time_s,
                track_ids=np.zeros(0, dtype=np.int64),
                positions=np.zeros((0, N_JOINTS, 3)),
                n_agree=np.zeros((0, N_JOINTS), dtype=np.int16),
                confidence=np.zeros((0, N_JOINTS), dtype=np.uint8),
                contributors=np.zeros((0, S), dtype=bool),
                coasting=np.zeros(0, dtype=bool),
                assignment=assignment,
                body_track_ids=body_track_ids,
            )
        assert table.fusion is not None
        state = table.fusion if every else take_state(table.fusion, out_idx)
        orientations = None
        if world_orientations is not None and self.params.orientations:
            orientations = gather_orientations(world_orientations, assignment, P)
        # The rows are sorted and distinct: as many as the association's rows means all of them, in order
        # (the usual frame), and the candidates need no copy.
        whole = rows.size == association.n_persons
        result, new_state = fuse(
            association.candidates if whole else association.candidates[rows],
            association.confidence if whole else association.confidence[rows],
            state,
            self.params,
            dt_s,
            orientations,
            self.sensor_positions,
        )
        if every:
            table.fusion = new_state
        else:
            put_state(table.fusion, out_idx, new_state)
        return PeopleResult(
            time_s=time_s,
            track_ids=table.ids[out_idx],
            positions=result.positions,
            n_agree=result.n_agree,
            confidence=result.confidence,
            contributors=result.contributors,
            coasting=table.last_seen_s[out_idx] < time_s,
            assignment=assignment,
            body_track_ids=body_track_ids,
            orientations=result.orientations,
            position_std=result.position_std,
            held_out=result.held_out,
            agreement_mm=result.agreement_mm,
            merged=result.merged,
            restarted=result.restarted,
        )

    def _init_fusion(self, n_tracks: int) -> FusionState:
        """The fusion-state rows of new tracks (a track is fused from this state when it is confirmed)."""
        return init_state(n_tracks, self.params)


def gather_orientations(orientations: np.ndarray, assignment: np.ndarray, n_rows: int) -> np.ndarray:
    """(S, B, J, 4) per-body quaternions -> (n_rows, S, J, 4) by each body's output row ``assignment`` ((S, B),
    -1: none; NaN where a sensor does not see the row), the same gather as
    :func:`~skelfuse.fusion.association.gather_candidates` does for positions."""
    orientations = np.asarray(orientations, dtype=np.float64)
    if orientations.shape[:2] != assignment.shape or orientations.shape[2:] != (N_JOINTS, 4):
        raise ValueError(
            f"world_orientations must have shape {(*assignment.shape, N_JOINTS, 4)} (S, B, J, 4), "
            f"got {orientations.shape}"
        )
    out = np.full((int(n_rows), assignment.shape[0], N_JOINTS, 4), np.nan)
    sensor_idx, body_idx = np.nonzero(assignment >= 0)
    out[assignment[sensor_idx, body_idx], sensor_idx] = orientations[sensor_idx, body_idx]
    return out
