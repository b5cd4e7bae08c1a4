"""The world levelled from the skeletons: on simulated rigs with random camera tilts, "up" is found within 2 deg
and the floor within a few centimetres of the simulator's truth (its floor is z = 0)."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.rig.level import level_from_skeletons, parse_axis
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.rig import VirtualSensor, look_at


def _tilted_sensor(rng: np.random.Generator) -> VirtualSensor:
    """A camera 1.0-2.0 m high, 2.5 m from the person, pitched and rolled at random (up to 20 deg)."""
    angle = rng.uniform(0, 2 * np.pi)
    position = np.array([2500 * np.cos(angle), 2500 * np.sin(angle), rng.uniform(1000, 2000)])
    level = look_at("cam", position, np.array([0.0, 0.0, rng.uniform(600, 1200)])).world_from_sensor
    roll, pitch = np.radians(rng.uniform(-20, 20, size=2))
    rx = np.array([[1, 0, 0], [0, np.cos(pitch), -np.sin(pitch)], [0, np.sin(pitch), np.cos(pitch)]])
    rz = np.array([[np.cos(roll), -np.sin(roll), 0], [np.sin(roll), np.cos(roll), 0], [0, 0, 1]])
    pose = level.copy()
    pose[:3, :3] = level[:3, :3] @ rz @ rx  # extra roll about the optical axis, pitch about the camera's x
    return VirtualSensor("cam", pose)


HELD_OUT = [("walking", 10), ("walking", 11), ("squat", 12), ("random", 13), ("lunge", 14), ("jump", 15)]
"""The estimator's thresholds were chosen on seeds 0-3 of these gestures; these seeds were not looked at."""


@pytest.mark.parametrize(("gesture", "seed"), HELD_OUT)
def test_up_within_two_degrees_on_randomly_tilted_cameras(gesture: str, seed: int) -> None:
    rng = np.random.default_rng(seed)
    sensor = _tilted_sensor(rng)
    obs = simulate(make_gesture(gesture, duration_s=8.0, seed=seed), [sensor], load_profile(), seed=seed)
    camera = obs.positions[:, 0]  # (T, 32, 3) what the tracker reports, in the camera's frame
    result = level_from_skeletons(camera[:, None])
    true_up = sensor.world_from_sensor[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # world z in the camera's frame
    error = np.degrees(np.arccos(np.clip(result.up_in_input @ true_up, -1, 1)))
    assert error < 2.0, f"{gesture}: up off by {error:.2f} deg ({result.describe()})"
    true_height = sensor.world_from_sensor[2, 3]
    assert abs(result.floor_mm - true_height) < 50.0, result.describe()
    world = obs.positions[:, 0] @ result.world_from_input[:3, :3].T + result.world_from_input[:3, 3]
    head, pelvis = world[:, 26, 2], world[:, 0, 2]
    ok = np.isfinite(head) & np.isfinite(pelvis)
    assert (head[ok] > pelvis[ok]).mean() > 0.95  # the person stands up in the levelled world


def test_a_level_camera_reports_no_tilt_and_the_given_up_is_kept() -> None:
    sensor = look_at("cam", np.array([2500.0, 0.0, 1500.0]), np.array([0.0, 0.0, 1500.0]))  # horizontal axis
    obs = simulate(make_gesture("walking", duration_s=6.0, seed=0), [sensor], load_profile(), seed=0)
    result = level_from_skeletons(obs.positions[:, 0][:, None])
    assert result.tilt_deg < 2.0
    given = level_from_skeletons(obs.positions[:, 0][:, None], up=parse_axis("-y"))
    assert given.source == "--up" and np.allclose(given.up_in_input, [0, -1, 0])
    assert abs(given.floor_mm - 1500.0) < 50.0


def test_parse_axis_refuses_what_is_not_an_axis() -> None:
    assert np.allclose(parse_axis("+z"), [0, 0, 1])
    with pytest.raises(ValueError, match="expected an axis"):
        parse_axis("up")


def test_no_evidence_is_said() -> None:
    with pytest.raises(ValueError, match="cannot find up"):
        level_from_skeletons(np.full((5, 1, 32, 3), np.nan))
