"""The per-instant adapter shared by the live node and offline fusion (service/fusion_step.py): stacking the
bodies of a frame group, several people fused offline and live with stable track ids, live equals offline."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skelfuse.config import RigConfig, SensorConfig
from skelfuse.fusion.presets import preset
from skelfuse.fusion.transform import apply_transform, make_transform
from skelfuse.recording import RecordingWriter, fuse_recording
from skelfuse.rig.grouping import FrameGroup
from skelfuse.rig.instant import GroupFuser, bodies_to_world, group_bodies
from skelfuse.schema.frames import FusedFrame, SensorFrame
from skelfuse.schema.skeleton import N_JOINTS, J
from skelfuse.service.node import FusionCore
from skelfuse.sim.crowd import CrowdObservations, bystander_scenario, crossing_scenario, simulate_scenario
from skelfuse.sim.observe import load_profile
from skelfuse.wire.codec import encode_sensor_frame

SEED = 20240613
RIG = "crowd"
TORSO = [J["PELVIS"], J["SPINE_NAVEL"], J["SPINE_CHEST"], J["NECK"]]
BIRTH_FRAMES = 3


def sensor_frame(sensor_id: str, n_bodies: int, rng: np.random.Generator, time_us: int = 1_000_000) -> SensorFrame:
    return SensorFrame(
        sensor_id=sensor_id,
        sequence=0,
        device_time_us=time_us,
        host_time_ns=time_us * 1000,
        body_ids=np.arange(n_bodies, dtype=np.uint32),
        positions=rng.normal(0.0, 800.0, (n_bodies, N_JOINTS, 3)).astype(np.float32),
        orientations=np.zeros((n_bodies, N_JOINTS, 4), np.float32),
        confidence=rng.integers(0, 4, (n_bodies, N_JOINTS)).astype(np.uint8),
    )


def test_group_bodies_pads_and_orders_by_rig_and_maps_every_block_to_the_world() -> None:
    rng = np.random.default_rng(SEED)
    sensor_ids = ("a", "b", "c", "d")
    frames = {"c": sensor_frame("c", 3, rng), "a": sensor_frame("a", 1, rng), "b": sensor_frame("b", 0, rng)}
    positions, confidence, valid = group_bodies(frames, sensor_ids)  # "d" delivered no frame
    assert positions.shape == (4, 3, N_JOINTS, 3) and confidence.shape == (4, 3, N_JOINTS)
    assert valid.tolist() == [[True, False, False], [False] * 3, [True] * 3, [False] * 3]
    np.testing.assert_array_equal(positions[2], frames["c"].positions)
    np.testing.assert_array_equal(confidence[0, 0], frames["a"].confidence[0])
    assert np.isnan(positions[~valid]).all() and (confidence[~valid] == 0).all()

    poses = np.stack(
        [make_transform(np.linalg.qr(rng.normal(size=(3, 3)))[0], rng.normal(0, 1000, 3)) for _ in sensor_ids]
    )
    world = bodies_to_world(poses, positions)
    for s in range(4):  # the vectorized transform equals one apply_transform per sensor
        expected = apply_transform(poses[s : s + 1], positions[s][:, None])[:, 0]
        np.testing.assert_allclose(world[s], expected, rtol=0, atol=1e-9, equal_nan=True)

    empty, _, none_valid = group_bodies({"b": sensor_frame("b", 0, rng)}, sensor_ids)
    assert empty.shape == (4, 0, N_JOINTS, 3) and none_valid.shape == (4, 0)


def test_a_step_back_in_time_restarts_the_tracks_with_new_ids() -> None:
    rng = np.random.default_rng(SEED)
    body = sensor_frame("a", 1, rng).positions
    fuser = GroupFuser(("a", "b"), np.tile(np.eye(4), (2, 1, 1)), preset("A4"))

    def group(time_us: int) -> FrameGroup:
        frames = {
            sid: SensorFrame(
                sid,
                0,
                time_us,
                time_us * 1000,
                np.zeros(1, np.uint32),
                body,
                np.zeros((1, N_JOINTS, 4), np.float32),
                np.full((1, N_JOINTS), 2, np.uint8),
            )
            for sid in ("a", "b")
        }
        return FrameGroup(time_us, frames, (), True)

    first = [fuser.step(group(t)) for t in (0, 33_333, 66_666, 100_000)]
    assert first[0].reset and not first[-1].reset
    assert [f.frame.track_ids.tolist() for f in first] == [[], [], [1], [1]]
    again = [fuser.step(group(t)) for t in (10, 33_343, 66_676)]  # a new clock epoch
    assert again[0].reset and again[-1].frame.track_ids.tolist() == [2]  # ids are never reused


# ---------------------------------------------------------------------------------------------------------
# Several people, offline and live


def crowd_frames(observations: CrowdObservations) -> list[SensorFrame]:
    """Every sensor's frames of the simulated crowd, in arrival (host time) order; a lost body is not listed."""
    rng = np.random.default_rng(SEED)
    frames = []
    for t in range(observations.n_frames):
        for s, sensor_id in enumerate(observations.sensor_ids):
            slots = observations.valid[t, s]
            n = int(slots.sum())
            device_time_us = int(observations.device_time_us[t, s])
            frames.append(
                SensorFrame(
                    sensor_id=sensor_id,
                    sequence=t,
                    device_time_us=device_time_us,
                    host_time_ns=device_time_us * 1000 + 2_000_000 + int(rng.integers(0, 3_000_000)),
                    body_ids=observations.body_ids[t, s][slots].astype(np.uint32),
                    positions=observations.positions[t, s][slots].astype(np.float32),
                    orientations=np.tile(np.array([1.0, 0, 0, 0], np.float32), (n, N_JOINTS, 1)),
                    confidence=observations.confidence[t, s][slots],
                )
            )
    return sorted(frames, key=lambda f: f.host_time_ns)


def crowd_rig(observations: CrowdObservations) -> RigConfig:
    return RigConfig(
        name=RIG,
        sensors=tuple(
            SensorConfig(id=sid, source="sim", world_from_sensor=tuple(map(tuple, pose.tolist())))
            for sid, pose in zip(observations.sensor_ids, observations.world_from_sensor_calibrated, strict=True)
        ),
    )


def assert_people_tracked(fused: list[FusedFrame], observations: CrowdObservations, tolerance_mm: float) -> None:
    """Two track ids, each stays with one person all along, and its torso is within ``tolerance_mm``."""
    assert len(fused) == observations.n_frames
    person_of_track: dict[int, int] = {}
    errors = []
    for t, frame in enumerate(fused):
        truth = observations.truth[t][:, TORSO]  # (P, 4, 3)
        if t >= BIRTH_FRAMES - 1:
            assert frame.n_persons == 2, (t, frame.track_ids)
        for p, track_id in enumerate(frame.track_ids.tolist()):
            distance = np.linalg.norm(frame.positions[p, TORSO] - truth, axis=-1).mean(axis=-1)  # (P,)
            person = int(np.argmin(distance))
            assert person_of_track.setdefault(track_id, person) == person, f"track {track_id} switched at {t}"
            errors.append(distance[person])
    assert sorted(person_of_track) == [1, 2] and sorted(person_of_track.values()) == [0, 1]
    errors = np.array(errors)
    assert np.median(errors) < 0.5 * tolerance_mm and np.percentile(errors, 95) < tolerance_mm, (
        np.median(errors),
        np.percentile(errors, 95),
        errors.max(),
    )


@pytest.fixture(scope="module")
def crossing() -> CrowdObservations:
    return simulate_scenario(crossing_scenario(duration_s=4.0), load_profile(), seed=0)


def test_two_people_crossing_fused_offline_keep_their_ids(tmp_path: Path, crossing: CrowdObservations) -> None:
    path = tmp_path / "crossing.mcap"
    with RecordingWriter(path, rig=RIG, sensor_ids=crossing.sensor_ids) as writer:
        for frame in crowd_frames(crossing):
            writer.write(frame)
    poses = dict(zip(crossing.sensor_ids, crossing.world_from_sensor_calibrated, strict=True))
    fused = list(fuse_recording(path, world_from_sensor=poses, progress=False))
    assert_people_tracked(fused, crossing, tolerance_mm=50.0)


def test_a_bystander_only_one_sensor_sees_is_a_person_of_its_own() -> None:
    observations = simulate_scenario(bystander_scenario(duration_s=3.0), load_profile(), seed=0)
    core = FusionCore(crowd_rig(observations))
    out = []
    for frame in crowd_frames(observations):
        out += core.receive(
            f"skelfuse/{RIG}/sensors/{frame.sensor_id}/skeletons", encode_sensor_frame(frame), frame.host_time_ns
        )
    out += core.flush()
    assert_people_tracked([o.frame for o in out], observations, tolerance_mm=50.0)


def test_node_core_publishes_every_person_and_equals_offline(tmp_path: Path, crossing: CrowdObservations) -> None:
    """The node's core, fed the crowd's payloads: P persons with distinct ids, the same frames as offline."""
    cfg = crowd_rig(crossing)
    frames = crowd_frames(crossing)
    core = FusionCore(cfg)
    out = []
    for frame in frames:
        out += core.receive(
            f"skelfuse/{RIG}/sensors/{frame.sensor_id}/skeletons", encode_sensor_frame(frame), frame.host_time_ns
        )
    out += core.flush()
    live = [o.frame for o in out]
    assert_people_tracked(live, crossing, tolerance_mm=50.0)
    # Every body of every sensor goes to the view, in the world frame.
    assert all(o.sensors_world.shape[0] == 4 and o.sensors_world.shape[1] >= 1 for o in out)
    assert max(int(np.isfinite(o.sensors_world).all(axis=(-2, -1)).sum()) for o in out) >= 6

    path = tmp_path / "published.mcap"
    with RecordingWriter(path, rig=RIG, sensor_ids=cfg.sensor_ids) as writer:
        for frame in frames:
            writer.write(frame)
    offline = list(fuse_recording(path, rig_config=cfg, progress=False, smoother="none"))  # live = causal
    assert [f.time_us for f in live] == [f.time_us for f in offline]
    for a, b in zip(live, offline, strict=True):
        np.testing.assert_array_equal(a.track_ids, b.track_ids)
        np.testing.assert_array_equal(a.positions, b.positions)
        np.testing.assert_array_equal(a.contributors, b.contributors)
        np.testing.assert_array_equal(a.n_agree, b.n_agree)
