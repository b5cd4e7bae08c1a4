"""The live "sensor moved" alarm: a sensor whose pose no longer fits is named, the others are not.

Truth: the simulator observes the person from the rig's true poses; the fusion core is given the same poses
except for one sensor, displaced as if it had been knocked after calibration. The frames go through the
node's real path (wire payloads, FusionCore: grouping, fusion), as they do live.
"""

from __future__ import annotations

import copy
import logging
from pathlib import Path

import numpy as np
import pytest

from skelfuse.config import load_rig_config
from skelfuse.service.node import FusionCore
from skelfuse.service.pose_fit import PoseFitMonitor
from skelfuse.service.worker import SimSource
from skelfuse.wire import keys
from skelfuse.wire.codec import encode_sensor_frame

SIM_RIG = Path(__file__).resolve().parents[2] / "config" / "rig-sim-4.toml"


@pytest.fixture(scope="module")
def rig() -> tuple[object, list[SimSource]]:
    cfg = load_rig_config(SIM_RIG)
    first = SimSource(cfg, cfg.sensor_ids[0], take_duration_s=8.0, clock_ns=lambda: 10**18)
    sources = []
    for column, sensor_id in enumerate(first.observations.sensor_ids):
        source = copy.copy(first)  # one simulation of the whole rig, one column per sensor
        source.sensor_id, source.column = sensor_id, column
        sources.append(source)
    return cfg, sources


def _run(cfg: object, sources: list[SimSource], poses: np.ndarray, monitor: PoseFitMonitor) -> list[object]:
    core = FusionCore(cfg, poses=poses)  # type: ignore[arg-type]
    changes = []
    period_ns = 1e9 / 30.0
    for n in range(150):
        outputs = []
        for source in sources:
            frame = source.frame_at(n)
            if frame is not None:
                key = keys.sensor_skeletons(cfg.name, source.sensor_id)  # type: ignore[attr-defined]
                outputs += core.receive(key, encode_sensor_frame(frame), int(n * period_ns) + 1000)
        for out in outputs:
            changes += monitor.update(out.sensors_world, *out.fit_inputs())  # as the node does
    return changes


def test_a_displaced_sensor_raises_the_alarm_and_only_it(rig: tuple[object, list[SimSource]]) -> None:
    cfg, sources = rig
    true = np.stack([cfg.poses()[s] for s in cfg.sensor_ids])  # type: ignore[attr-defined]
    knocked = true.copy()
    knocked[2, :3, 3] += [250.0, 0.0, 0.0]  # capture_2 pushed 25 cm sideways after calibration
    monitor = PoseFitMonitor(cfg.sensor_ids, window=100, min_frames=60)  # type: ignore[attr-defined]
    changes = _run(cfg, sources, knocked, monitor)
    report = monitor.report()
    assert [(c.sensor_id, c.fits) for c in changes] == [("capture_2", False)], changes
    assert report["capture_2"]["fits"] is False
    assert 150.0 < report["capture_2"]["median_mm"] < 350.0  # about the displacement
    for sensor_id in ("capture_0", "capture_1", "capture_3"):
        assert report[sensor_id]["fits"] is True and report[sensor_id]["median_mm"] < 60.0, report


def test_a_rig_whose_poses_fit_raises_nothing(rig: tuple[object, list[SimSource]]) -> None:
    cfg, sources = rig
    true = np.stack([cfg.poses()[s] for s in cfg.sensor_ids])  # type: ignore[attr-defined]
    monitor = PoseFitMonitor(cfg.sensor_ids, window=100, min_frames=60)  # type: ignore[attr-defined]
    assert _run(cfg, sources, true, monitor) == []
    assert all(fit["fits"] is True for fit in monitor.report().values())


def test_no_verdict_before_enough_instants_saw_the_sensor() -> None:
    monitor = PoseFitMonitor(("a", "b"), window=10, min_frames=5, check_every=1)
    far = np.zeros((2, 1, 32, 3))
    far[0] += 1000.0  # sensor a's body 1.7 m from the fused person
    fused = np.zeros((1, 32, 3))
    for _ in range(4):
        assert monitor.update(far, fused) == []
    assert monitor.report()["a"]["fits"] is None
    (change,) = monitor.update(far, fused)
    assert change.sensor_id == "a" and not change.fits and change.median_mm == pytest.approx(np.sqrt(3) * 1000)
    nobody = np.full((2, 0, 32, 3), np.nan)
    assert monitor.update(nobody, fused) == []  # an empty instant changes nothing


def test_the_medians_are_numpys_nanmedian_and_nan_for_a_sensor_nobody_saw() -> None:
    # The monitor's medians (its own fast path) against numpy's own nanmedian, odd and even counts.
    rng = np.random.default_rng(3)
    monitor = PoseFitMonitor(("a", "b", "c", "d"), window=40, min_frames=5, check_every=1000)
    for t in range(57):  # wraps the 40-instant window
        world = rng.normal(0.0, 80.0, (4, 1, 32, 3))
        world[1, :, :, :] = np.nan if t % 3 == 0 else world[1]  # b: a joint set missing in some instants
        world[3] = np.nan  # d: never sees anyone
        monitor.update(world, np.zeros((1, 32, 3)))
    report = monitor.report()
    window = monitor._distances
    for i, sid in enumerate(("a", "b", "c")):
        assert report[sid]["median_mm"] == round(float(np.nanmedian(window[:, i])), 1)
        assert report[sid]["frames"] == int(np.isfinite(window[:, i]).sum())
    assert report["b"]["frames"] % 2 == 0 or report["a"]["frames"] % 2 == 0  # an even count is covered
    assert report["d"] == {"median_mm": None, "frames": 0, "fits": None}


def test_the_node_logs_and_reports_the_alarm(caplog: pytest.LogCaptureFixture) -> None:
    from skelfuse.service.node import FusionNode
    from skelfuse.service.pose_fit import FitChange

    node = FusionNode(load_rig_config(SIM_RIG), None)
    with caplog.at_level(logging.WARNING, logger="skelfuse.service.node"):
        node._log_fit(FitChange("capture_2", False, 251.0, 150))
    assert "sensor capture_2's pose no longer fits" in caplog.text and "calibrate check" in caplog.text


# -- a crowd: people pass and occlude each other, association is ambiguous where they stand close -----------

CROWD_SENSORS, CROWD_PEOPLE, CROWD_FRAMES = 6, 10, 120


@pytest.fixture(scope="module")
def crowd() -> object:
    from skelfuse.sim.crowd import crowd_scenario, simulate_scenario
    from skelfuse.sim.observe import load_profile

    scenario = crowd_scenario(n_people=CROWD_PEOPLE, n_sensors=CROWD_SENSORS, duration_s=CROWD_FRAMES / 30.0, seed=1)
    return simulate_scenario(scenario, load_profile(), seed=1)


def _fuse_crowd(observations: object, shift_mm: np.ndarray | None, moved: int) -> PoseFitMonitor:
    """The crowd through the fusion core, as the node fuses it; sensor ``moved``'s bodies land ``shift_mm`` off
    (its pose moved after calibration: the rig still maps its bodies with the old one)."""
    from skelfuse.fusion.people import PeopleFuser
    from skelfuse.fusion.presets import preset

    world = observations.positions_world(calibrated=True).copy()  # type: ignore[attr-defined]
    if shift_mm is not None:
        world[:, moved] += shift_mm
    fuser = PeopleFuser(preset("skelfuse"))
    monitor = PoseFitMonitor(observations.sensor_ids, window=90, min_frames=30, check_every=10)  # type: ignore[attr-defined]
    for t in range(world.shape[0]):
        result = fuser.step(world[t], observations.confidence[t], observations.valid[t], observations.times_s[t])  # type: ignore[attr-defined]
        monitor.update(world[t], result.positions, result.contributors, result.held_out)
    return monitor


def test_a_crowd_raises_no_sensor_moved_alarm(crowd: object) -> None:
    report = _fuse_crowd(crowd, None, 0).report()
    assert all(fit["fits"] is True for fit in report.values()), report  # every sensor judged, none moved
    assert all(fit["median_mm"] < 60.0 for fit in report.values()), report


def test_a_moved_sensor_in_a_crowd_still_raises_the_alarm(crowd: object) -> None:
    report = _fuse_crowd(crowd, np.array([250.0, 0.0, 0.0]), 2).report()
    moved = crowd.sensor_ids[2]  # type: ignore[attr-defined]
    assert report[moved]["fits"] is False and 150.0 < report[moved]["median_mm"] < 350.0, report
    assert all(fit["fits"] is True for sid, fit in report.items() if sid != moved), report


def test_only_confidently_associated_persons_count() -> None:
    # Hand-made instants, two sensors a and b plus c: each rule leaves a person out on its own.
    monitor = PoseFitMonitor(("a", "b", "c"), isolation_mm=500.0, min_other_sensors=2)
    person = np.zeros((32, 3))
    far = person + np.array([0.0, 3000.0, 0.0])
    fused = np.stack([person, far])  # two people 3 m apart
    bodies = np.full((3, 2, 32, 3), np.nan)
    bodies[:, 0] = person
    bodies[:, 1] = far
    bodies[0, 0] += [200.0, 0.0, 0.0]  # sensor a's view of the first person lies 200 mm off
    everyone = np.ones((2, 3), dtype=bool)
    assert monitor.instant_distances(bodies, fused, everyone)[0] == pytest.approx(100.0)  # median of 200 and 0
    # Seen by a and one other sensor only: the person could follow a; it is left out (the other person stays).
    assert monitor.instant_distances(bodies, fused, np.array([[1, 1, 0], [1, 1, 1]], bool))[0] == 0.0
    # a's view held out as upside down: a bad skeleton, not a moved sensor; held out for jumping away: kept.
    held = np.zeros((2, 3), np.uint8)
    held[0, 0] = 2
    assert monitor.instant_distances(bodies, fused, everyone, held)[0] == 0.0
    held[0, 0] = 1
    assert monitor.instant_distances(bodies, fused, everyone, held)[0] == pytest.approx(100.0)
    # A second person 400 mm from the first: whose body is whose is in doubt, both are left out.
    crowded = np.stack([person, person + np.array([400.0, 0.0, 0.0])])
    crowd_bodies = np.stack([crowded, crowded, crowded])
    crowd_bodies[0, 0] += [200.0, 0.0, 0.0]
    assert np.isnan(monitor.instant_distances(crowd_bodies, crowded, everyone)[0])
