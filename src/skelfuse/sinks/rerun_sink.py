"""Rerun sink: draws the rig, each sensor's raw skeleton and the fused skeletons, frame by frame.

The recording stream is injected (``rr.RecordingStream``), never a global, so the demo, the fusion node and
the tests each own theirs. Entities mirror the scene:

- ``world``: static axes and a 1 m floor grid (world frame, z up; everything is drawn in metres);
- ``world/sensors/{id}/pose``: the sensor's pose and (``.../pose/frustum``) its NFOV frustum (static);
  ``world/sensors/{id}/skeleton``: every body it reports, already in the world frame (own colour). The
  skeleton is a sibling of the pose, not its child: a Rerun transform applies to the entity's whole
  subtree, so world-frame points under the posed entity would be transformed twice. Hide one sensor by
  hiding ``world/sensors/{id}``;
- ``world/fused``: every fused person in one entity (joints + bones), one colour per track id, drawn thick
  and opaque in colours no sensor uses (sensors are thin and half transparent), ``world/fused/labels``: the
  track id above each head; ``world/sensors/{id}/label``: the sensor's name at its position (static);
  ``world/fused/clouds/{track_id}``: a person's merged depth cloud (depth-level fusion), coloured by sensor;
- ``metrics/...``: time series of fusion time and per-sensor rate.

Each frame costs one log call per kind (joints, bones) per sensor and for the fused persons, so logging
stays well under a millisecond.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from skelfuse.fusion.depth.cloud import MergedCloud
from skelfuse.schema.skeleton import BONES, JOINT_NAMES

MM_TO_M = 1e-3
TIMELINE = "device_time"
"""Rerun timeline carrying the sensors' device timestamps (seconds since the start of the take)."""

SENSOR_COLORS = np.array(
    [
        [230, 159, 0],
        [86, 180, 233],
        [0, 158, 115],
        [240, 228, 66],
        [0, 114, 178],
        [213, 94, 0],
        [204, 121, 167],
        [153, 153, 153],
    ],
    dtype=np.uint8,
)
"""Okabe-Ito palette, readable by colour-blind users; sensors cycle through it."""
TRACK_COLORS = np.array(
    [[255, 255, 255], [255, 0, 255], [255, 40, 40], [140, 255, 0], [255, 150, 200], [0, 255, 255]],
    dtype=np.uint8,
)
"""Fused people: white, magenta, red, lime, pink, cyan: saturated or white, each far from every sensor colour
(``tests/unit/test_rerun_sink.py`` checks the distance)."""
SENSOR_ALPHA = 140
"""Sensors' skeletons are half transparent: the fused one, opaque and thicker, stands out in front of them."""
FUSED_JOINT_RADIUS_M, FUSED_BONE_RADIUS_M = 0.03, 0.02
SENSOR_JOINT_RADIUS_M, SENSOR_BONE_RADIUS_M = 0.01, 0.004
LABEL_ABOVE_HEAD_M = 0.3
HEAD = JOINT_NAMES.index("HEAD")


def _bone_segments(skeletons_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K, 32, 3) skeletons -> (N, 2, 3) bone segments with both ends finite, and (N,) the skeleton of each."""
    segments = np.stack([skeletons_m[:, BONES[:, 0]], skeletons_m[:, BONES[:, 1]]], axis=-2)  # (K, 31, 2, 3)
    drawable = np.isfinite(segments).all(axis=(-2, -1))
    return segments[drawable], np.nonzero(drawable)[0]


def _person_labels(track_ids: np.ndarray, agreement_mm: np.ndarray | None) -> np.ndarray:
    """ "person 7", or with the agreement figure "person 7 · views ±12 mm" ("· one view" where it is NaN)."""
    labels = [f"person {int(t)}" for t in track_ids]
    if agreement_mm is not None:
        labels = [
            f"{label} · views ±{figure:.0f} mm" if np.isfinite(figure) else f"{label} · one view"
            for label, figure in zip(labels, np.asarray(agreement_mm, dtype=np.float64).tolist(), strict=True)
        ]
    return np.array(labels, dtype=object)


def rig_eye(world_from_sensor: np.ndarray | None) -> rrb.EyeControls3D:
    """A camera that frames the people: it looks at the middle of the sensors at chest height from a corner,
    above and outside the rig (the sensors look inwards, so that is where people walk)."""
    if world_from_sensor is None or len(world_from_sensor) == 0:
        centre, radius = np.array([0.0, 0.0]), 2.5
    else:
        positions = np.asarray(world_from_sensor)[:, :2, 3] * MM_TO_M
        centre = positions.mean(axis=0)
        radius = max(float(np.linalg.norm(positions - centre, axis=1).max()), 1.0)
    target = [float(centre[0]), float(centre[1]), 0.9]
    offset = np.array([1.0, -1.0]) / np.sqrt(2.0) * radius * 1.6
    position = [float(centre[0] + offset[0]), float(centre[1] + offset[1]), 0.9 + radius * 0.8]
    return rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=position, look_target=target, eye_up=[0.0, 0.0, 1.0])


def default_blueprint(world_from_sensor: np.ndarray | None = None) -> rrb.Blueprint:
    """A 3D view of the world, its camera on the people (:func:`rig_eye`), beside the latency and rate plots."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="Rig", eye_controls=rig_eye(world_from_sensor)),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="metrics/fusion_ms", name="Fusion time (ms)"),
                rrb.TimeSeriesView(origin="metrics/rate_hz", name="Sensor rate (Hz)"),
                rrb.TimeSeriesView(origin="metrics/error_mm", name="Error vs ground truth (mm)"),
            ),
            column_shares=[3, 1],
        ),
        rrb.TimePanel(timeline=TIMELINE, expanded=False),  # the sensors' clock, not log time
        collapse_panels=True,
    )


class RerunSink:
    """Logs a rig and its skeletons to an injected Rerun recording stream.

    Parameters
    ----------
    recording : rr.RecordingStream
        Where to log; the caller decides whether it spawns a viewer, serves, or saves a .rrd file.
    sensor_ids : sequence of str
        The rig's sensors, in the order of every per-sensor array passed later.
    """

    def __init__(self, recording: rr.RecordingStream, sensor_ids: Sequence[str]) -> None:
        self.recording = recording
        self.sensor_ids = tuple(sensor_ids)

    def log_rig(
        self,
        world_from_sensor: np.ndarray,
        *,
        fov_v_deg: float = 65.0,
        aspect: float = 75.0 / 65.0,
        floor_half_size_m: int = 4,
    ) -> None:
        """Static scene: world axes, floor grid, and each sensor's pose and frustum.

        ``world_from_sensor`` is (S, 4, 4) in millimetres.
        """
        rec = self.recording
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log(
            "world/axes",
            rr.Arrows3D(
                vectors=np.eye(3) * 0.5,
                colors=[[255, 0, 0], [0, 255, 0], [0, 0, 255]],
                labels=["x", "y", "z"],
            ),
            static=True,
        )
        ticks = np.arange(-floor_half_size_m, floor_half_size_m + 1, dtype=np.float64)
        ends = np.full_like(ticks, float(floor_half_size_m))
        zeros = np.zeros_like(ticks)
        lines_x = np.stack([np.stack([-ends, ticks, zeros], 1), np.stack([ends, ticks, zeros], 1)], axis=1)
        lines_y = np.stack([np.stack([ticks, -ends, zeros], 1), np.stack([ticks, ends, zeros], 1)], axis=1)
        rec.log(
            "world/floor",
            rr.LineStrips3D(np.concatenate([lines_x, lines_y]), colors=[[90, 90, 90]], radii=0.003),
            static=True,
        )
        rec.log(
            "world",
            rr.AnnotationContext(
                [rr.ClassDescription(info=(0, "joint"), keypoint_annotations=list(enumerate(JOINT_NAMES)))]
            ),
            static=True,
        )
        for index, sensor_id in enumerate(self.sensor_ids):
            pose = np.asarray(world_from_sensor[index], dtype=np.float64)
            rec.log(
                f"world/sensors/{sensor_id}/pose",
                rr.Transform3D(translation=pose[:3, 3] * MM_TO_M, mat3x3=pose[:3, :3]),
                static=True,
            )
            rec.log(
                f"world/sensors/{sensor_id}/pose/frustum",
                rr.Pinhole(
                    fov_y=np.deg2rad(fov_v_deg),
                    aspect_ratio=aspect,
                    camera_xyz=rr.ViewCoordinates.RDF,  # k4abt depth frame: x right, y down, z forward
                    image_plane_distance=0.25,
                    color=SENSOR_COLORS[index % len(SENSOR_COLORS)],
                ),
                static=True,
            )
            rec.log(
                f"world/sensors/{sensor_id}/label",
                rr.Points3D(
                    pose[:3, 3] * MM_TO_M,
                    labels=sensor_id,
                    colors=SENSOR_COLORS[index % len(SENSOR_COLORS)],
                    radii=0.04,
                    show_labels=True,
                ),
                static=True,
            )

    def set_time(self, time_s: float) -> None:
        """Put what follows on the device-time timeline."""
        self.recording.set_time(TIMELINE, duration=time_s)

    def log_sensor_skeletons(self, world_positions_mm: np.ndarray) -> None:
        """Each sensor's raw skeletons in the world frame: (S, B, 32, 3) mm, NaN where missing."""
        for index, sensor_id in enumerate(self.sensor_ids):
            skeletons = world_positions_mm[index] * MM_TO_M
            color = np.append(SENSOR_COLORS[index % len(SENSOR_COLORS)], SENSOR_ALPHA).astype(np.uint8)
            finite = np.isfinite(skeletons).all(axis=-1)
            path = f"world/sensors/{sensor_id}/skeleton"
            self.recording.log(
                f"{path}/joints",
                rr.Points3D(
                    skeletons[finite],
                    keypoint_ids=np.nonzero(finite)[-1],
                    class_ids=0,
                    colors=color,
                    radii=SENSOR_JOINT_RADIUS_M,
                ),
            )
            bones, _ = _bone_segments(skeletons)
            self.recording.log(f"{path}/bones", rr.LineStrips3D(bones, colors=color, radii=SENSOR_BONE_RADIUS_M))

    def log_fused(
        self, positions_mm: np.ndarray, track_ids: np.ndarray, agreement_mm: np.ndarray | None = None
    ) -> None:
        """All fused persons in one entity: (P, 32, 3) mm world, one colour per track id; the label above each
        head names the track and, given the (P,) agreement figures, how far the views lie from it."""
        skeletons = positions_mm * MM_TO_M
        colors = TRACK_COLORS[np.asarray(track_ids, dtype=np.int64) % len(TRACK_COLORS)]
        finite = np.isfinite(skeletons).all(axis=-1)
        person = np.nonzero(finite)[0]
        self.recording.log(
            "world/fused/joints",
            rr.Points3D(
                skeletons[finite],
                keypoint_ids=np.nonzero(finite)[1],
                class_ids=0,
                colors=colors[person],
                radii=FUSED_JOINT_RADIUS_M,
            ),
        )
        segments, owner = _bone_segments(skeletons)
        self.recording.log(
            "world/fused/bones", rr.LineStrips3D(segments, colors=colors[owner], radii=FUSED_BONE_RADIUS_M)
        )
        heads = skeletons[:, HEAD]
        labelled = np.isfinite(heads).all(axis=-1)
        self.recording.log(
            "world/fused/labels",
            rr.Points3D(
                heads[labelled] + [0.0, 0.0, LABEL_ABOVE_HEAD_M],
                labels=_person_labels(np.asarray(track_ids), agreement_mm)[labelled].tolist(),
                colors=colors[labelled],
                radii=0.001,
                show_labels=True,
            ),
        )

    def log_person_clouds(self, clouds: Sequence[MergedCloud], track_ids: Sequence[int]) -> None:
        """Each person's merged depth cloud (depth-level fusion), coloured by the sensor each point came from
        (the sensors' skeleton colours): ``world/fused/clouds/{track_id}``, world frame, mm in, metres drawn."""
        for cloud, track_id in zip(clouds, track_ids, strict=True):
            colors = SENSOR_COLORS[np.asarray(cloud.sensor_index, dtype=np.int64) % len(SENSOR_COLORS)]
            self.recording.log(
                f"world/fused/clouds/{int(track_id)}",
                rr.Points3D(np.asarray(cloud.points) * MM_TO_M, colors=colors, radii=0.004),
            )

    def log_metrics(
        self,
        *,
        fusion_ms: float | None = None,
        rate_hz: dict[str, float] | None = None,
        error_mm: float | None = None,
    ) -> None:
        """Time series: fusion time, per-sensor rate, and (simulator only) error against ground truth."""
        if fusion_ms is not None:
            self.recording.log("metrics/fusion_ms", rr.Scalars(fusion_ms))
        for sensor_id, rate in (rate_hz or {}).items():
            self.recording.log(f"metrics/rate_hz/{sensor_id}", rr.Scalars(rate))
        if error_mm is not None and np.isfinite(error_mm):
            self.recording.log("metrics/error_mm", rr.Scalars(error_mm))
