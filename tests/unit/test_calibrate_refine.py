"""``skelfuse calibrate refine``: person clouds recorded, read back, grouped into a walk, refined by ICP.

The algorithm itself (``refine_poses_from_walk``) is checked against the truth in tests/unit/test_depth_fusion.py;
here: the recorder writes the clouds of a depth-mode rig, the reader gives them back, the grouping of a
recording's clouds into instants, the pose error measure on hand-made poses, and the command end to end on a
recorded simulated walk with a miscalibrated rig (the refined file is closer to the truth).
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from recorder_progress import RecorderProgress

from skelfuse.calibration.refine import CAPTURE_CENTRE_MM, pose_errors, simulated_walk, walk_frames
from skelfuse.cli import main
from skelfuse.config import parse_rig_config
from skelfuse.config.calibration_file import read_calibration
from skelfuse.recording import RecordingReader, RecordingWriter
from skelfuse.service.lifecycle import Lifecycle, RunLimits
from skelfuse.service.recorder import run_recorder
from skelfuse.service.zenoh_io import free_port, loopback_config
from skelfuse.wire import keys
from skelfuse.wire.clouds import PersonCloudsFrame, encode_person_clouds
from waiting import wait_for_subscriber

RIG = "walk"


def _clouds(sensor_id: str, time_us: int, *sizes: int, ids: tuple[int, ...] = ()) -> PersonCloudsFrame:
    rng = np.random.default_rng(time_us)
    clouds = tuple(rng.uniform(500.0, 1500.0, (n, 3)) for n in sizes)
    body_ids = np.array(ids or range(len(sizes)), np.uint32)
    return PersonCloudsFrame(sensor_id, time_us // 33_333, time_us, 10**18 + time_us * 1000, 15.0, body_ids, clouds)


def test_walk_frames_group_by_device_time_keep_two_views_and_the_biggest_body() -> None:
    clouds = [
        _clouds("a", 1_000_000, 300),
        _clouds("b", 1_000_160, 250, 400, ids=(4, 5)),  # same instant (160 µs later), two bodies: the bigger
        _clouds("a", 1_033_333, 300),  # seen by a only: dropped
        _clouds("a", 1_066_667, 300),
        _clouds("b", 1_066_827, 100),  # b too small to count: dropped
        _clouds("c", 1_100_000, 500),  # a sensor the rig does not have: ignored
    ]
    frames = walk_frames(clouds, ("a", "b"), tolerance_us=10_000, max_frames=10)
    assert len(frames) == 1
    assert [len(c) for c in frames[0]] == [300, 400]
    np.testing.assert_array_equal(frames[0][1], clouds[1].clouds[1])
    many = [_clouds(s, 1_000_000 + k * 33_333, 300) for k in range(9) for s in ("a", "b")]
    spread = walk_frames(many, ("a", "b"), tolerance_us=10_000, max_frames=3)  # first, middle, last
    assert [f[0].tolist() for f in spread] == [many[2 * k].clouds[0].tolist() for k in (0, 4, 8)]


def test_pose_errors_by_hand() -> None:
    truth = np.stack([np.eye(4), np.eye(4)])
    turned = truth.copy()
    turned[1, :3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]  # 90° about z through the origin
    turned[1, :3, 3] = [0.0, 0.0, 50.0]
    degrees, centre_mm = pose_errors(turned, truth)
    assert degrees == pytest.approx([0.0, 90.0])
    # the centre (0, 0, 1000) lies on the z axis: the turn leaves it, the 50 mm lift moves it
    assert centre_mm == pytest.approx([0.0, 50.0]) and CAPTURE_CENTRE_MM[2] == 1000.0


@pytest.mark.live
def test_the_recorder_writes_the_person_clouds_of_a_depth_rig(
    tmp_path: Path, recorder_progress: RecorderProgress
) -> None:
    import zenoh

    pose = [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]
    cfg = parse_rig_config(
        {
            "rig": {"name": RIG},
            "sensors": [{"id": "s0", "source": "sim", "world_from_sensor": pose}],
            "fusion": {"mode": "depth"},
            "depth": {"tracker": "simulated"},
        }
    )
    port, lifecycle, result = free_port(), Lifecycle("recorder"), {}
    output = tmp_path / "walk.mcap"
    recorder = threading.Thread(
        target=lambda: result.update(
            report=run_recorder(
                cfg,
                loopback_config(listen_port=port),
                output=output,
                limits=RunLimits(duration_s=20),
                lifecycle=lifecycle,
            )
        ),
        daemon=True,
    )
    recorder.start()
    sent = [_clouds("s0", 1_000_000 + k * 33_333, 50 + k) for k in range(5)]
    with zenoh.open(loopback_config(connect_ports=[port])) as session:
        clouds = session.declare_publisher(keys.sensor_clouds(RIG, "s0"))
        end = session.declare_publisher(keys.fused_skeletons(RIG))
        wait_for_subscriber(clouds, "the recorder's subscription")
        for frame in sent:
            clouds.put(encode_person_clouds(frame))
        clouds.put(b"SKLF")  # truncated: counted, not written
        end.put(recorder_progress.end_marker())
        recorder_progress.wait_for_end_marker()
    lifecycle.request_exit()
    recorder.join(10.0)
    report: Any = result["report"]
    assert report.clouds_written == 5 and report.rejects["truncated"] == 1
    reader = RecordingReader(output)
    back = list(reader.person_clouds())
    assert [f.device_timestamp_us for f in back] == [f.device_timestamp_us for f in sent]
    for got, want in zip(back, sent, strict=True):
        np.testing.assert_allclose(got.clouds[0], want.clouds[0], atol=0.5)  # the wire's 1 mm quantum
    assert list(reader.frames()) == []  # the cloud channel is not read as skeletons


def test_calibrate_refine_brings_a_miscalibrated_rig_closer_to_the_truth(tmp_path: Path, capsys) -> None:
    """A recorded simulated walk (5 instants), the rig's poses off by 2° / 40 mm: the written calibration
    misplaces the capture area's centre less than the rig's did, for every refined sensor."""
    walk = simulated_walk(n_frames=5, perturb_deg=2.0, perturb_mm=40.0, seed=1)
    recording = tmp_path / "walk.mcap"
    with RecordingWriter(recording, rig=RIG, sensor_ids=walk.sensor_ids) as writer:
        for t, frame in enumerate(walk.frames):
            for s, cloud in enumerate(frame):
                if len(cloud):
                    payload = PersonCloudsFrame(
                        walk.sensor_ids[s],
                        t,
                        1_000_000 + t * 500_000 + 160 * s,
                        10**18,
                        15.0,
                        np.array([1], np.uint32),
                        (cloud,),
                    )
                    writer.write_clouds_payload(encode_person_clouds(payload))
    config = tmp_path / "rig.toml"
    lines = ["[rig]", f'name = "{RIG}"', "", "[fusion]", 'mode = "depth"', "", "[depth]", 'tracker = "simulated"', ""]
    for s, sensor_id in enumerate(walk.sensor_ids):  # the rig's (miscalibrated) poses: what is refined
        rows = ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in walk.perturbed_poses[s])
        role = '{ role = "master" }' if s == 0 else f'{{ role = "subordinate", delay_us = {160 * s} }}'
        lines += ["[[sensors]]", f'id = "{sensor_id}"', 'source = "sim"', f"sync = {role}"]
        lines += [f"world_from_sensor = [{rows}]", ""]
    config.write_text("\n".join(lines), encoding="utf-8")
    output = tmp_path / "refined.toml"
    code = main(
        ["calibrate", "refine", "--recording", str(recording), "--config", str(config), "--output", str(output)]
    )
    printed = capsys.readouterr().out
    assert code in (0, 3), printed
    assert "| capture_1 |" in printed and "reference" in printed
    refined = read_calibration(output)
    assert refined.method == "refine" and refined.master == walk.sensor_ids[0]
    after = np.stack([refined.sensors[sid].world_from_sensor for sid in walk.sensor_ids])
    _, before_mm = pose_errors(walk.perturbed_poses, walk.true_poses)
    _, after_mm = pose_errors(after, walk.true_poses)
    assert after_mm[0] == pytest.approx(0.0, abs=1e-6)  # the reference stays put
    assert (after_mm[1:] < before_mm[1:]).all(), (before_mm, after_mm)


# Seeds whose walks, between them, draw every verdict of a refined sensor ("improved" and "bad" on seed 3,
# "check" and "improved" on seed 4); seeds 0-2 draw no other verdict and take the same branches of the test.
@pytest.mark.parametrize("seed", [3, 4])
def test_refine_rates_by_held_out_evidence_and_keeps_exact_poses(seed: int) -> None:
    """Two simulated walks (8 instants). From exact poses the ICP still moves every sensor (it fits noise):
    the held-out gap does not fall, so each sensor is rated "no improvement" and keeps its exact pose. From
    poses off by 2° / 40 mm, every sensor not rated "no improvement" has a smaller true rotation error after,
    and its held-out gap fell (the verdict's own evidence, recomputed here from the poses it reports)."""
    from skelfuse.calibration.refine import NO_IMPROVEMENT, heldout_gap_mm, refine, refine_report

    walk = simulated_walk(n_frames=8, perturb_deg=2.0, perturb_mm=40.0, seed=seed)
    exact = refine(walk.frames, walk.true_poses, walk.sensor_ids, reference=0)
    _, verdicts = refine_report(exact, walk.true_poses)
    assert [verdicts[sid] for sid in walk.sensor_ids[1:]] == [NO_IMPROVEMENT] * 3
    np.testing.assert_array_equal(exact.after, walk.true_poses)
    moved = refine(walk.frames, walk.perturbed_poses, walk.sensor_ids, reference=0)
    _, verdicts = refine_report(moved, walk.true_poses)
    before_deg, _ = pose_errors(walk.perturbed_poses, walk.true_poses)
    after_deg, _ = pose_errors(moved.after, walk.true_poses)
    folds = (walk.frames[0::2], walk.frames[1::2])
    for s, sid in enumerate(walk.sensor_ids[1:], start=1):
        if verdicts[sid] == NO_IMPROVEMENT:
            np.testing.assert_array_equal(moved.after[s], walk.perturbed_poses[s])
            continue
        assert after_deg[s] < before_deg[s], (sid, verdicts[sid], before_deg[s], after_deg[s])
        held_before = np.mean([heldout_gap_mm(folds[1 - k], walk.perturbed_poses, s) for k in range(2)])
        held_after = np.mean([heldout_gap_mm(folds[1 - k], moved.halves[k], s) for k in range(2)])
        assert held_after < 0.95 * held_before
    assert sum(verdicts[sid] != NO_IMPROVEMENT for sid in walk.sensor_ids[1:]) >= 2  # 2° off: most are pinned down
