"""One fused instant, shared by the live fusion node and offline fusion: FrameGroup -> PeopleFuser -> FusedFrame.

Both :class:`skelfuse.service.node.FusionCore` (live) and :func:`skelfuse.recording.offline.fuse_recording`
(offline) fuse every instant through one :class:`GroupFuser`, so "the live stream of a set of frames equals
the offline fusion of the same frames" holds by construction. Cycle of :meth:`GroupFuser.step`:

1. The group's frames (dict sensor id -> SensorFrame, some sensors missing) become ``(S, B, 32, 3)`` positions,
   NaN-padded to the most bodies any sensor reported, with ``(S, B, 32)`` confidence and ``(S, B)`` valid; rows
   in the rig's sensor order (as :func:`group_bodies` stacks them).
2. ... in the world frame: the stacking and the transform are one compiled pass
   (:func:`~skelfuse.fusion.transform.stack_views_to_world`; :func:`bodies_to_world` is the same transform alone).
3. Clock rule: a time step back (a new clock epoch, e.g. a restarted rig) or a gap over
   :data:`RESET_GAP_S` restarts the fusion state (:meth:`PeopleFuser.reset
   <skelfuse.fusion.people.PeopleFuser.reset>`: tracks forgotten, ids keep counting up, never reused).
4. :meth:`PeopleFuser.step <skelfuse.fusion.people.PeopleFuser.step>` at the group's time in seconds:
   association across sensors, stable track ids, per-track fusion.
   With ``params.orientations`` the bodies' joint quaternions go along, stacked and rotated to the world frame
   by the calibration in the same pass as the positions (as :func:`~skelfuse.fusion.orientation.views_to_world`).
5. A :class:`~skelfuse.schema.frames.FusedFrame`: one person per confirmed track that has an estimate (a track
   coasting past the filter's ``max_coast_frames`` has none and is left out), ascending track id.

Only numpy and the fusion core (its compiled kernels included): no zenoh, no clocks, no I/O.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from skelfuse.fusion.association import DEFAULT_DUPLICATE_MM, DEFAULT_GATE_MM
from skelfuse.fusion.orientation import calibration_quat_matrices
from skelfuse.fusion.people import PeopleFuser, PeopleResult
from skelfuse.fusion.presets import FusionParams
from skelfuse.fusion.tracks import MAX_TRACKS, TrackParams
from skelfuse.fusion.transform import StackedViews, apply_transform, stack_views_to_world
from skelfuse.rig.grouping import FrameGroup
from skelfuse.schema.frames import FusedFrame, SensorFrame
from skelfuse.schema.skeleton import N_JOINTS

RESET_GAP_S = 1.0
"""A gap longer than this between two instants restarts the fusion state (tracks, filters)."""


def group_bodies(
    frames: Mapping[str, SensorFrame], sensor_ids: Sequence[str]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stack the bodies of one instant, sensor by sensor, NaN-padded.

    Parameters
    ----------
    frames : mapping sensor id -> SensorFrame
        The frames of the instant (a sensor without a frame is simply absent).
    sensor_ids : sequence of str
        The rig's sensors: row order of the output. Frames of other sensors are ignored.

    Returns
    -------
    positions : (S, B, 32, 3) float64, mm, each sensor's own frame; NaN in empty slots.
        ``B`` is the largest number of bodies any sensor reported (0 when none did).
    confidence : (S, B, 32) uint8, 0 in empty slots.
    valid : (S, B) bool, the slot holds a body.
    """
    positions, confidence, valid, _ = _stack_group(frames, sensor_ids, orientations=False)
    return positions, confidence, valid


def group_orientations(frames: Mapping[str, SensorFrame], sensor_ids: Sequence[str], n_bodies: int) -> np.ndarray:
    """(S, B, 32, 4) float64 sensor-frame joint quaternions of one instant, stacked like :func:`group_bodies`
    (NaN in empty slots)."""
    *_, orientations = _stack_group(frames, sensor_ids, orientations=True, n_bodies=n_bodies)
    assert orientations is not None
    return orientations


def _stack_group(
    frames: Mapping[str, SensorFrame], sensor_ids: Sequence[str], *, orientations: bool, n_bodies: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`group_bodies` (and the orientations) with one concatenation and one scatter per array, whatever
    the number of sensors (no per-sensor numpy calls)."""
    S = len(sensor_ids)
    present = [(row, frames[sid]) for row, sid in enumerate(sensor_ids) if sid in frames]
    present = [(row, frame) for row, frame in present if frame.n_bodies]
    counts = [frame.n_bodies for _, frame in present]
    B = max(counts, default=0) if n_bodies is None else int(n_bodies)
    positions = np.full((S, B, N_JOINTS, 3), np.nan)
    confidence = np.zeros((S, B, N_JOINTS), dtype=np.uint8)
    valid = np.zeros((S, B), dtype=bool)
    quats = np.full((S, B, N_JOINTS, 4), np.nan) if orientations else None
    if present:
        rows = np.repeat([row for row, _ in present], counts)
        cols = np.concatenate([_ARANGE[:n] for n in counts]) if len(present) > 1 else _ARANGE[: counts[0]]
        positions[rows, cols] = np.concatenate([frame.positions for _, frame in present])
        confidence[rows, cols] = np.concatenate([frame.confidence for _, frame in present])
        valid[rows, cols] = True
        if quats is not None:
            quats[rows, cols] = np.concatenate([frame.orientations for _, frame in present])
    return positions, confidence, valid, quats


_ARANGE = np.arange(1024)  # body slot indices (a frame holds at most wire.codec.MAX_BODIES = 64)


def bodies_to_world(world_from_sensor: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """(S, B, 32, 3) sensor-frame bodies -> world frame, mm, with the (S, 4, 4) poses; NaN stays NaN."""
    # apply_transform wants the sensor axis third from the end: (B, S, 32, 3) in, swapped back out.
    return np.swapaxes(apply_transform(world_from_sensor, np.swapaxes(positions, 0, 1)), 0, 1)


def fused_frame(people: PeopleResult, time_us: int, sensor_ids: tuple[str, ...]) -> FusedFrame:
    """The wire record of a :class:`PeopleResult`: persons with at least one finite joint, ascending id."""
    keep = np.isfinite(people.positions).all(axis=-1).any(axis=-1)  # (P,)
    if keep.all():  # the usual case: every track has an estimate, no copies
        keep = slice(None)
    return FusedFrame(
        time_us=int(time_us),
        track_ids=people.track_ids[keep].astype(np.int64, copy=False),
        positions=people.positions[keep],
        n_agree=people.n_agree[keep].astype(np.int16, copy=False),
        confidence=people.confidence[keep].astype(np.uint8, copy=False),
        contributors=people.contributors[keep].astype(bool, copy=False),
        sensor_ids=sensor_ids,
        orientations=None if people.orientations is None else people.orientations[keep],
        position_std=None if people.position_std is None else people.position_std[keep],
        agreement_mm=None if people.agreement_mm is None else people.agreement_mm[keep],
    )


@dataclass(frozen=True)
class FusedInstant:
    """What :meth:`GroupFuser.step` made of one instant.

    Attributes
    ----------
    frame : FusedFrame
        One person per track with an estimate, ascending track id (what is published / written).
    sensors_world : (S, B, 32, 3) float64, mm
        Every body of every sensor in the world frame (NaN: no frame, no body in the slot).
    valid : (S, B) bool
        The slot holds a body.
    people : PeopleResult
        The core's full result (coasting tracks without an estimate included, association of the bodies).
    reset : bool
        The fusion state was restarted before this instant (first instant, step back, or long gap).
    """

    frame: FusedFrame
    sensors_world: np.ndarray
    valid: np.ndarray
    people: PeopleResult
    reset: bool


class GroupFuser:
    """Fuses frame groups of one rig into fused frames, one person per track (see the module docstring).

    Parameters
    ----------
    sensor_ids : sequence of str
        The rig's sensors, in the row order of ``world_from_sensor`` and of ``contributors``.
    world_from_sensor : (S, 4, 4) float, mm
        Sensor frame -> world.
    params : FusionParams
        The per-person pipeline's parameters.
    gate_mm, birth_frames, timeout_s, duplicate_mm
        Passed to :class:`~skelfuse.fusion.people.PeopleFuser`.
    reset_gap_s : float
        A longer gap between instants restarts the fusion state.
    max_persons : int
        Live tracks at most (bodies beyond are not tracked, counted in ``people.table.births_refused``).
    first_track_id : int
        The first track's id (the live node starts from a time-based epoch so ids continue across restarts).

    Attributes
    ----------
    people : PeopleFuser
        The multi-person state (tracks, per-track filters).
    last_time_us : int or None
        Time of the previous instant.
    """

    def __init__(
        self,
        sensor_ids: Sequence[str],
        world_from_sensor: np.ndarray,
        params: FusionParams,
        *,
        gate_mm: float = DEFAULT_GATE_MM,
        birth_frames: int = 3,
        timeout_s: float = 1.0,
        duplicate_mm: float | None = DEFAULT_DUPLICATE_MM,
        reset_gap_s: float = RESET_GAP_S,
        max_persons: int = MAX_TRACKS,
        first_track_id: int = 1,
    ) -> None:
        self.sensor_ids = tuple(sensor_ids)
        poses = np.asarray(world_from_sensor, dtype=np.float64)
        if poses.shape != (len(self.sensor_ids), 4, 4):
            raise ValueError(
                f"world_from_sensor must have shape ({len(self.sensor_ids)}, 4, 4) for sensors "
                f"{', '.join(self.sensor_ids)}; got {poses.shape}"
            )
        self.world_from_sensor = poses
        self._orientation_matrices = calibration_quat_matrices(poses)  # the poses' rotations, once
        self._rows = {sid: row for row, sid in enumerate(self.sensor_ids)}  # sensor id -> row
        self.params = params
        self.reset_gap_s = float(reset_gap_s)
        track_params = TrackParams(
            gate_mm=float(gate_mm), birth_frames=int(birth_frames), timeout_s=float(timeout_s), max_tracks=max_persons
        )
        self.people = PeopleFuser(params, duplicate_mm=duplicate_mm, track_params=track_params)
        self.people.sensor_positions = poses[:, :3, 3]  # the rear-view rule needs where each sensor stands
        self.people.table.next_id = int(first_track_id)
        self.last_time_us: int | None = None

    def reset(self) -> None:
        """Forget every track and filter (ids keep counting up)."""
        self.people.reset()
        self.last_time_us = None

    def step(self, group: FrameGroup) -> FusedInstant:
        """Fuse one instant (its ``time_us`` on the grouping clock)."""
        time_us = int(group.time_us)
        # Within one clock epoch the grouper's times strictly increase; a step back is a new epoch and a long
        # gap leaves nothing worth carrying: both restart the fusion state.
        reset = self.last_time_us is None or not 0 < (time_us - self.last_time_us) / 1e6 <= self.reset_gap_s
        if reset:
            self.people.reset()
        self.last_time_us = time_us
        views = self._stack_to_world(group.frames)
        people = self.people.step(
            views.world, views.confidence, views.valid, time_us / 1e6, world_orientations=views.orientations
        )
        return FusedInstant(fused_frame(people, time_us, self.sensor_ids), views.world, views.valid, people, reset)

    def _stack_to_world(self, frames: Mapping[str, SensorFrame]) -> StackedViews:
        """The instant's bodies as :func:`group_bodies` stacks them, in the world frame (with their orientations
        when the preset fuses them): one concatenation per array and one compiled pass."""
        rows: list[int] = []
        present: list[SensorFrame] = []
        for sid, frame in frames.items():
            row = self._rows.get(sid)
            if row is not None and frame.body_ids.shape[0]:
                rows.append(row)
                present.append(frame)
        counts = [frame.body_ids.shape[0] for frame in present]
        if present:
            positions = np.concatenate([frame.positions for frame in present], dtype=np.float64)
            confidence = np.concatenate([frame.confidence for frame in present])
        else:
            positions, confidence = _NO_POSITIONS, _NO_CONFIDENCE
        orientations = None
        if self.params.orientations:
            orientations = (
                np.concatenate([frame.orientations for frame in present], dtype=np.float64)
                if present
                else _NO_ORIENTATIONS
            )
        return stack_views_to_world(
            positions,
            confidence,
            orientations,
            np.array(rows, dtype=np.int64),
            np.array(counts, dtype=np.int64),
            max(counts, default=0),
            self.world_from_sensor,
            self._orientation_matrices,
        )


_NO_POSITIONS = np.zeros((0, N_JOINTS, 3))
_NO_CONFIDENCE = np.zeros((0, N_JOINTS), dtype=np.uint8)
_NO_ORIENTATIONS = np.zeros((0, N_JOINTS, 4))
