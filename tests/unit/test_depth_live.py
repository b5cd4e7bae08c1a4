"""The node's depth and hybrid modes in process: sim workers' frames and clouds -> FusionCore -> fused frames,
checked against the simulator's truth (the zenoh end-to-end test is tests/service/test_depth_service.py).

The tracker is the simulated stand-in (``[depth] tracker = "simulated"``), not the SDK: what is checked is
that every stage in front of it and the way back to the world do their work (an error near the skeleton
path's, not an arbitrary one), the track ids, the contributors, the counters, and the refusals.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from skelfuse.apps.demo import sim_sensor_tables
from skelfuse.config import load_rig_config, parse_rig_config
from skelfuse.fusion.depth.pipeline import fuse_person_depth
from skelfuse.schema.errors import ConfigError
from skelfuse.schema.skeleton import EVAL_JOINTS, Confidence
from skelfuse.service.depth_stage import (
    ASSOCIATION_GATE_MM,
    VIRTUAL_INTRINSICS,
    VIRTUAL_SENSOR_ID,
    CloudBuffer,
    associate_bodies,
    depth_stage_for,
)
from skelfuse.service.node import FusionCore
from skelfuse.service.sim_clouds import sensor_person_clouds
from skelfuse.service.worker import SimSource
from skelfuse.sim.depth import EXACT
from skelfuse.sim.depth_tracker import JOINT_RADIUS_MM, SimulatedDepthTracker
from skelfuse.sim.rig import paper_rig
from skelfuse.wire import keys
from skelfuse.wire.clouds import encode_person_clouds
from skelfuse.wire.codec import encode_sensor_frame
from waiting import wait_for_subscriber, wait_until

RIG = "dl"
FIRST = 1_020  # instant number of take frame 0 (1020 = 34 x 30): the window never wraps the 1 s take


def _rig(tmp_path: Path, mode: str, *, weight: int = 1) -> Path:
    lines = ["[rig]", f'name = "{RIG}"', "", "[sync]", 'by = "device"', "fps = 30.0", ""]
    lines += ["[fusion]", f'mode = "{mode}"', "", "[depth]", 'tracker = "simulated"', f"virtual_weight = {weight}", ""]
    path = tmp_path / f"rig-{mode}.toml"
    path.write_text("\n".join(lines + sim_sensor_tables(4)), encoding="utf-8")
    return path


def _run(config: Path, n_frames: int = 18) -> tuple[FusionCore, list, SimSource]:
    """Feed every sensor's frame (and clouds) of ``n_frames`` instants through a FusionCore, as the node does."""
    cfg = load_rig_config(config)
    sources = [SimSource(cfg, sid, gesture="walking", take_duration_s=1.0, seed=0) for sid in cfg.sensor_ids]
    core = FusionCore(cfg, depth=depth_stage_for(cfg))
    outputs = []
    for n in range(FIRST, FIRST + n_frames):
        for source in sources:
            frame = source.frame_at(n)
            if frame is None:
                continue
            if core.depth is not None:
                core.depth.clouds.put(
                    keys.sensor_clouds(RIG, source.sensor_id), encode_person_clouds(source.clouds_at(frame))
                )
            outputs += core.receive(
                keys.sensor_skeletons(RIG, source.sensor_id), encode_sensor_frame(frame), n * 33_333_333
            )
    outputs += core.flush()
    return core, outputs, sources[0]


def _errors(outputs: list, source: SimSource) -> np.ndarray:
    obs, errors = source.observations, []
    for out in outputs:
        frame = out.frame
        if frame.n_persons:
            n = round(frame.time_us / (1e6 / 30))
            truth = obs.truth[(n - source.origin_n) % obs.n_frames]
            errors.append(np.nanmean(np.linalg.norm(frame.positions[0, EVAL_JOINTS] - truth[EVAL_JOINTS], axis=-1)))
    return np.array(errors)


@pytest.fixture(scope="module")
def skeleton_errors(tmp_path_factory: pytest.TempPathFactory) -> np.ndarray:
    _, outputs, source = _run(_rig(tmp_path_factory.mktemp("s"), "skeleton"))
    return _errors(outputs, source)


def test_depth_mode_outputs_the_trackers_skeleton_of_each_person(tmp_path: Path, skeleton_errors: np.ndarray) -> None:
    core, outputs, source = _run(_rig(tmp_path, "depth"))
    errors = _errors(outputs, source)
    report = core.depth.report()
    assert report["tracker"] == "simulated" and report["tracker_misses"] == 0 and report["no_clouds"] == 0
    assert report["clouds_received"] == 4 * 18
    fused = [out.frame for out in outputs if out.frame.n_persons]
    assert len(errors) >= 14  # every instant after the skeleton track's birth
    assert len({int(f.track_ids[0]) for f in fused}) == 1  # the skeleton track's id, one person
    assert all(f.contributors[0].sum() >= 3 for f in fused)  # the clouds of (nearly) every sensor went in
    assert all(out.clouds and out.clouds[0][0] == out.frame.track_ids[0] for out in outputs if out.frame.n_persons)
    # Not the skeleton fusion's output: a different estimate, within a few cm of the truth (measured 19 mm
    # against the skeleton path's 11 mm on this take: the stand-in's capsule-radius model is coarse).
    assert not np.allclose(errors, skeleton_errors[: len(errors)])
    assert np.median(errors) < 35.0


def test_hybrid_mode_adds_one_virtual_sensor_per_weight(tmp_path: Path, skeleton_errors: np.ndarray) -> None:
    core, outputs, source = _run(_rig(tmp_path, "hybrid", weight=2))
    errors = _errors(outputs, source)
    fused = [out.frame for out in outputs if out.frame.n_persons]
    assert fused[-1].sensor_ids == (*source.observations.sensor_ids, VIRTUAL_SENSOR_ID, f"{VIRTUAL_SENSOR_ID}_2")
    assert all(out.sensors_world.shape[0] == 4 for out in outputs)  # the node's per-sensor views: real ones
    merged_virtual = np.mean([f.contributors[0, 4:].all() for f in fused[5:]])
    assert merged_virtual > 0.9  # the virtual rows are merged into the person from the second fused instant on
    assert core.depth.report()["tracked"] >= len(fused) - 2
    assert np.median(errors) < np.median(skeleton_errors) + 10.0  # measured: 12 vs 11 mm (weight 1)


def test_the_simulated_tracker_slides_a_prior_onto_the_virtual_image() -> None:
    """A prior 100 mm too far from the virtual camera comes back to the truth's depth; outside the body: NaN."""
    from skelfuse.sim.gestures import make_gesture

    truth = make_gesture("hands_up_down", duration_s=1.0, seed=0).positions[0]
    sensors = paper_rig(4)
    clouds = [
        sensor_person_clouds(s, truth[None], voxel_mm=10.0, noise=EXACT).get(0, np.zeros((0, 3))) for s in sensors
    ]
    poses = np.stack([s.world_from_sensor for s in sensors])
    view = fuse_person_depth(clouds, poses, VIRTUAL_INTRINSICS, skeleton_facing_deg=None)
    view = fuse_person_depth(clouds, poses, VIRTUAL_INTRINSICS, skeleton_facing_deg=view.frontal.facing_deg)
    camera_axis = view.frontal.world_from_camera[:3, 2]
    prior = truth + 100.0 * camera_axis  # every joint pushed 100 mm deeper along the virtual camera's axis
    positions, confidence = SimulatedDepthTracker().track(1, view, prior)
    own = np.isfinite(JOINT_RADIUS_MM) & (confidence == int(Confidence.MEDIUM))
    assert own[EVAL_JOINTS].mean() > 0.7  # most evaluated joints were seen and slid
    before = np.abs((prior - truth)[own] @ camera_axis)
    after = np.abs((positions - truth)[own] @ camera_axis)
    assert np.median(before) == pytest.approx(100.0) and np.median(after) < 25.0
    far = truth + np.array([0.0, 0.0, 3000.0])  # a prior above the person's head: nothing under it
    assert SimulatedDepthTracker().track(1, view, far) is None


def test_simulated_tracker_is_refused_on_a_rig_with_real_sensors() -> None:
    pose = [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]
    data = {
        "rig": {"name": "r"},
        "sensors": [
            {"id": "a", "source": "sim", "world_from_sensor": pose},
            {"id": "b", "source": "replay", "replay": {"file": "x.mcap"}},
        ],
        "fusion": {"mode": "depth"},
        "depth": {"tracker": "simulated"},
    }
    with pytest.raises(ConfigError, match="simulated rigs only"):
        parse_rig_config(data)
    assert parse_rig_config({**data, "fusion": {"mode": "skeleton"}}).depth.tracker == "simulated"  # unused: fine


def test_cloud_buffer_counts_bad_payloads_and_keeps_good_ones() -> None:
    cfg_ids = ("a", "b")
    buffer = CloudBuffer(RIG, cfg_ids, max_payload_bytes=10_000)
    from skelfuse.wire.clouds import PersonCloudsFrame

    good = PersonCloudsFrame("a", 1, 5_000, 0, 15.0, np.array([3], np.uint32), (np.ones((4, 3)) * 1000,))
    buffer.put(keys.sensor_clouds(RIG, "a"), encode_person_clouds(good))
    buffer.put(keys.sensor_clouds(RIG, "b"), encode_person_clouds(good))  # payload of a on b's key
    buffer.put(keys.sensor_clouds(RIG, "a"), b"SKLF\x01")  # truncated
    buffer.put("skelfuse/other/sensors/a/clouds", encode_person_clouds(good))  # another rig
    buffer.put(keys.sensor_clouds(RIG, "a"), b"x" * 10_001)
    assert buffer.received == 1
    assert dict(buffer.rejects) == {"key_mismatch": 1, "truncated": 1, "bad_key": 1, "oversized": 1}
    assert buffer.take("a", 5_000).body_ids.tolist() == [3] and buffer.take("a", 5_001) is None


def test_bodies_join_the_nearest_previous_person_within_the_gate() -> None:
    persons = np.zeros((2, 32, 3))
    persons[1] += [2000.0, 0, 0]
    world = np.full((2, 2, 32, 3), np.nan)
    world[0, 0] = persons[1] + 30.0  # near person 1
    world[0, 1] = persons[0] - 50.0  # near person 0
    world[1, 0] = persons[0] + [ASSOCIATION_GATE_MM + 1.0, 0, 0]  # beyond the gate
    valid = np.array([[True, True], [True, False]])
    assert associate_bodies(world, valid, persons).tolist() == [[1, 0], [-1, -1]]
    assert associate_bodies(world, valid, np.zeros((0, 32, 3))).tolist() == [[-1, -1], [-1, -1]]


@pytest.mark.live
def test_the_node_subscribes_to_the_clouds_and_fuses_them_over_zenoh(tmp_path: Path) -> None:
    """A FusionNode in depth mode on a loopback zenoh session: clouds and skeletons published on their keys
    (clouds first, as the capture worker does) come out as the tracker's skeletons, and the rejects of a bad
    cloud payload are counted in the status, not raised."""
    import threading

    import zenoh

    from skelfuse.service.lifecycle import Lifecycle, RunLimits
    from skelfuse.service.node import FusionNode, NodeOptions
    from skelfuse.service.zenoh_io import free_port, loopback_config, wait_for_port
    from skelfuse.wire.codec import decode_fused_frame

    cfg = load_rig_config(_rig(tmp_path, "depth"))
    sources = [SimSource(cfg, sid, gesture="walking", take_duration_s=1.0, seed=0) for sid in cfg.sensor_ids]
    # Instants go out as soon as the node has the last one's clouds, faster than a rig's 30 Hz while the depth
    # stage fuses slower: a lag bound above the run keeps every instant (shedding: test_node_shedding.py).
    cfg = dataclasses.replace(cfg, node=dataclasses.replace(cfg.node, max_lag_s=3600.0))
    port = free_port()
    node = FusionNode(
        cfg,
        loopback_config(listen_port=port),
        options=NodeOptions(limits=RunLimits(duration_s=30.0)),
        lifecycle=Lifecycle(),
    )
    thread = threading.Thread(target=node.run, daemon=True)
    thread.start()
    fused = []
    try:
        assert wait_for_port(port, timeout_s=20.0) and node.ready.wait(20.0)
        with zenoh.open(loopback_config(connect_ports=[port])) as session:
            session.declare_subscriber(
                keys.fused_skeletons(RIG), lambda s: fused.append(decode_fused_frame(s.payload.to_bytes()))
            )
            clouds = {sid: session.declare_publisher(keys.sensor_clouds(RIG, sid)) for sid in cfg.sensor_ids}
            skeletons = {sid: session.declare_publisher(keys.sensor_skeletons(RIG, sid)) for sid in cfg.sensor_ids}
            # Both ways: the node's subscriptions reach this session, this session's reaches the node's publisher.
            for publisher in [*clouds.values(), *skeletons.values()]:
                wait_for_subscriber(publisher, "the node's subscriptions")
            wait_for_subscriber(node._fused_publisher._publisher, "this test's fused subscription")
            clouds[cfg.sensor_ids[1]].put(b"SKLF\x01\x00\x04")  # truncated
            for k, n in enumerate(range(FIRST, FIRST + 12)):
                for source in sources:
                    frame = source.frame_at(n)
                    if frame is not None:
                        clouds[source.sensor_id].put(encode_person_clouds(source.clouds_at(frame)))
                        skeletons[source.sensor_id].put(encode_sensor_frame(frame))
                # one instant at a time, as a live rig sends them: the next once the node has this one's clouds
                wait_until(lambda k=k: node.depth.report()["clouds_received"] >= 4 * (k + 1), f"instant {k}'s clouds")
            wait_until(
                lambda: node.depth.report()["clouds_received"] == 4 * 12 and len(fused) >= node.core.frames_out >= 12,
                "12 instants fused and received here",
                details=lambda: str(node.depth.report()),
            )
    finally:
        node.lifecycle.request_exit()
        thread.join(20.0)
    assert not thread.is_alive()
    report = node.depth.report()
    assert report["clouds_received"] == 4 * 12 and report["cloud_rejects"] == {"truncated": 1}
    assert report["tracked"] >= 8 and report["clouds_missing"] == 0
    with_person = [f for f in fused if f.n_persons]
    assert len(with_person) >= 8 and all(f.contributors[0].sum() >= 3 for f in with_person)
    assert node.report.status["info"]["depth"]["mode"] == "depth"


class _KeyRecorder:
    """The simulated tracker, recording each call's stream key and result, and the stage's renames."""

    def __init__(self, inner: SimulatedDepthTracker) -> None:
        self.inner, self.name, self.description = inner, inner.name, inner.description
        self.calls: list[tuple[int, object]] = []
        self.renames: list[tuple[int, int]] = []

    def track(self, person, view, prior):
        result = self.inner.track(person, view, prior)
        self.calls.append((person, result))
        return result

    def rename(self, old: int, new: int) -> None:
        self.renames.append((old, new))

    def retire(self, active: set[int]) -> None:
        self.inner.retire(active)

    def close(self) -> None:
        self.inner.close()


def test_hybrid_gives_a_person_a_virtual_skeleton_from_the_first_instant(tmp_path: Path) -> None:
    """A person nobody has seen yet is grouped from this instant's own bodies: the tracker runs at once (its
    stream keyed provisionally, then renamed to the track the fusion made), the virtual skeleton is on the
    truth, and it is merged into the person's very first fused output."""
    cfg = load_rig_config(_rig(tmp_path, "hybrid"))
    # a 0.5 s take (15 frames: FIRST is its frame 0), rendered once per sensor: the rendering is the slow part
    sources = [SimSource(cfg, sid, gesture="walking", take_duration_s=0.5, seed=0) for sid in cfg.sensor_ids]
    stage = depth_stage_for(cfg)
    stage.tracker = recorder = _KeyRecorder(stage.tracker)
    core = FusionCore(cfg, depth=stage)
    obs = sources[0].observations
    first_fused = None
    for n in range(FIRST, FIRST + 6):
        calls_before = len(recorder.calls)
        outputs = []
        for source in sources:
            frame = source.frame_at(n)
            stage.clouds.put(keys.sensor_clouds(RIG, source.sensor_id), encode_person_clouds(source.clouds_at(frame)))
            outputs += core.receive(
                keys.sensor_skeletons(RIG, source.sensor_id), encode_sensor_frame(frame), n * 33_333_333
            )
        if n == FIRST:  # the very first instant: one new person, one provisional stream, found on the truth
            assert len(recorder.calls) == calls_before + 1
            key, (positions, _) = recorder.calls[-1]
            assert key < 0
            truth = obs.truth[(n - sources[0].origin_n) % obs.n_frames]
            error = np.linalg.norm(positions[EVAL_JOINTS] - truth[EVAL_JOINTS], axis=-1)
            # the stand-in tracker on the realigned fused prior; another person or place would
            # be hundreds of mm off
            assert np.nanmedian(error) < 60.0
        fused = [out.frame for out in outputs if out.frame.n_persons]
        if fused and first_fused is None:
            first_fused = fused[0]
    assert first_fused is not None
    assert first_fused.contributors[0, 4]  # the virtual sensor is merged into the first output
    track = int(first_fused.track_ids[0])
    assert recorder.renames == [(recorder.calls[0][0], track)]  # the stream took the track's id
    assert {key for key, _ in recorder.calls[1:]} == {track}
