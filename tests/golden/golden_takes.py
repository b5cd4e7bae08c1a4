"""Inputs and runners of the golden-output test (tests/golden/test_golden_outputs.py).

The takes are built here from the crowd's motions alone (:func:`skelfuse.sim.crowd.crowd_scenario`'s walkers
seen through :func:`skelfuse.sim.rig.paper_rig`'s poses) with this module's own seeded noise, label flips,
dropped joints, shuffled body order, absences and duplicates, so that the simulator's tracker model (profile,
``sim/observe.py``) can change without changing these inputs. What is pinned is the per-instant path's output
for these inputs, not its accuracy.

The golden file holds the inputs themselves beside the outputs, and the test fuses the stored inputs: building
the take runs the crowd's forward kinematics through numpy's sin and cos, whose last bits differ between
processors (an AMD EPYC VM built inputs whose SHA-256 differed from the ones an earlier machine had stored), and
a one-ulp change of a float32 joint moves the fused positions by far more than the outputs' 1e-9 mm tolerance.
:func:`builder_drift` tells whether this module still builds the stored inputs, to within such rounding.

Regenerate the golden file after a change that is meant to change the outputs (and say so in the commit)::

    python scripts/make_golden_outputs.py
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skelfuse.config import RigConfig, SensorConfig
from skelfuse.fusion.orientation import apply_derived, body_hint_frames, quat_from_rotvec, quat_multiply
from skelfuse.fusion.presets import preset
from skelfuse.rig.grouping import FrameGroup
from skelfuse.rig.instant import GroupFuser
from skelfuse.schema.frames import FusedFrame, SensorFrame
from skelfuse.schema.skeleton import MIRROR, N_JOINTS
from skelfuse.service.node import FusionCore
from skelfuse.sim.crowd import crowd_scenario
from skelfuse.sim.rig import paper_rig
from skelfuse.wire.codec import decode_fused_frame, encode_fused_frame, encode_sensor_frame

GOLDEN_PATH = Path(__file__).with_name("golden_outputs.npz")
RIG = "golden"
FPS = 30.0


@dataclass(frozen=True)
class Take:
    """One golden take: per instant, the sensors' frames (a sensor that saw nobody sends an empty frame)."""

    name: str
    sensor_ids: tuple[str, ...]
    poses: np.ndarray  # (S, 4, 4) world_from_sensor
    times_us: np.ndarray  # (T,)
    frames: list[dict[str, SensorFrame]]

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The take as flat arrays (bodies of every instant and sensor concatenated, in that order)."""
        frames = [instant[sid] for instant in self.frames for sid in self.sensor_ids]
        return {
            "sensor_ids": np.array(self.sensor_ids),
            "poses": self.poses,
            "times_us": self.times_us,
            "host_time_ns": np.array([f.host_time_ns for f in frames], dtype=np.int64),
            "n_bodies": np.array([f.n_bodies for f in frames], dtype=np.int64),
            "body_ids": np.concatenate([f.body_ids for f in frames]),
            "positions": np.concatenate([f.positions for f in frames]),
            "orientations": np.concatenate([f.orientations for f in frames]),
            "confidence": np.concatenate([f.confidence for f in frames]),
        }

    @classmethod
    def from_arrays(cls, name: str, arrays: dict[str, np.ndarray]) -> Take:
        """The inverse of :meth:`to_arrays`."""
        sensor_ids = tuple(str(s) for s in arrays["sensor_ids"])
        times_us = arrays["times_us"]
        ends = np.cumsum(arrays["n_bodies"])
        frames: list[dict[str, SensorFrame]] = []
        for k, (end, n) in enumerate(zip(ends.tolist(), arrays["n_bodies"].tolist(), strict=True)):
            t, s = divmod(k, len(sensor_ids))
            if s == 0:
                frames.append({})
            rows = slice(end - n, end)
            frames[t][sensor_ids[s]] = SensorFrame(
                sensor_id=sensor_ids[s],
                sequence=t,
                device_time_us=int(times_us[t]),
                host_time_ns=int(arrays["host_time_ns"][k]),
                body_ids=arrays["body_ids"][rows],
                positions=arrays["positions"][rows],
                orientations=arrays["orientations"][rows],
                confidence=arrays["confidence"][rows],
            )
        return cls(name, sensor_ids, arrays["poses"], times_us, frames)


# name -> (sensors, people, frames, seed)
TAKES: dict[str, tuple[int, int, int, int]] = {"s4p2": (4, 2, 45, 1), "s8p4": (8, 4, 36, 3)}


def build_take(name: str) -> Take:
    """The crowd walkers seen by the paper rig, with noise, flips, drops, absences and duplicates."""
    n_sensors, n_people, n_frames, seed = TAKES[name]
    scenario = crowd_scenario(n_people=n_people, n_sensors=n_sensors, duration_s=n_frames / FPS, seed=seed)
    sensors = paper_rig(n_sensors)
    truth = np.stack([m.positions[:n_frames] for m in scenario.motions], axis=1)  # (T, P, J, 3) world
    rng = np.random.default_rng(seed)
    sensor_ids = tuple(s.sensor_id for s in sensors)
    poses = np.stack([s.world_from_sensor for s in sensors])
    # Who is absent when: person 0 leaves every view for a stretch (coasts, is picked up again); the last
    # person leaves for good a third of the way in (coasts past the filter, then dies).
    present = np.ones((n_frames, n_people), dtype=bool)
    present[n_frames // 2 : n_frames // 2 + 6, 0] = False
    if n_people > 2:
        present[n_frames // 3 :, n_people - 1] = False
    # Per sensor and person: a mirrored stretch (rear-view label flip) and short drop-outs.
    mirrored = np.zeros((n_frames, n_sensors, n_people), dtype=bool)
    seen = rng.random((n_frames, n_sensors, n_people)) > 0.08
    for s in range(n_sensors):
        for p in range(n_people):
            if rng.random() < 0.5:
                start = int(rng.integers(0, n_frames - 10))
                mirrored[start : start + int(rng.integers(4, 20)), s, p] = True
    frames: list[dict[str, SensorFrame]] = []
    times_us = np.round(1_000_000 + np.arange(n_frames) * 1e6 / FPS).astype(np.int64)
    for t in range(n_frames):
        instant = {}
        for s, sensor in enumerate(sensors):
            bodies = [p for p in range(n_people) if present[t, p] and seen[t, s, p]]
            if bodies and t % 7 == 3 and s == 0:
                bodies.append(bodies[0])  # a duplicate skeleton of one person (tracker split)
            rng.shuffle(bodies)
            positions = np.empty((len(bodies), N_JOINTS, 3))
            confidence = np.empty((len(bodies), N_JOINTS), dtype=np.uint8)
            for b, p in enumerate(bodies):
                local = sensor.to_sensor(truth[t, p]) + rng.normal(0.0, 12.0, (N_JOINTS, 3))
                if mirrored[t, s, p]:
                    local = local[MIRROR]
                positions[b] = local
                confidence[b] = rng.choice([0, 1, 2, 2, 2, 2], size=N_JOINTS).astype(np.uint8)
            quats = apply_derived(body_hint_frames(positions)) if bodies else np.zeros((0, N_JOINTS, 4))
            quats = quat_multiply(quats, quat_from_rotvec(rng.normal(0.0, 0.15, (len(bodies), N_JOINTS, 3))))
            quats = np.where(np.isfinite(quats), quats, 0.0)
            instant[sensor.sensor_id] = SensorFrame(
                sensor_id=sensor.sensor_id,
                sequence=t,
                device_time_us=int(times_us[t]),
                host_time_ns=int(times_us[t]) * 1000 + 1_000_000 * (s + 1),
                body_ids=np.asarray(rng.permutation(64)[: len(bodies)], dtype=np.uint32),
                positions=positions.astype(np.float32),
                orientations=quats.astype(np.float32),
                confidence=confidence,
            )
        frames.append(instant)
    return Take(name, sensor_ids, poses, times_us, frames)


def rig_config(take: Take) -> RigConfig:
    return RigConfig(
        name=RIG,
        sensors=tuple(
            SensorConfig(id=sid, source="sim", world_from_sensor=tuple(map(tuple, pose.tolist())))
            for sid, pose in zip(take.sensor_ids, take.poses, strict=True)
        ),
    )


def _record(frames: list[FusedFrame], extra: dict[str, list[np.ndarray]] | None = None) -> dict[str, np.ndarray]:
    """Fused frames as flat arrays: per-frame person counts, then every person's rows concatenated."""
    out = {
        "time_us": np.array([f.time_us for f in frames], dtype=np.int64),
        "n_persons": np.array([f.n_persons for f in frames], dtype=np.int64),
        "track_ids": np.concatenate([f.track_ids for f in frames]).astype(np.int64),
        "positions": np.concatenate([f.positions for f in frames]),
        "n_agree": np.concatenate([f.n_agree for f in frames]),
        "confidence": np.concatenate([f.confidence for f in frames]),
        "contributors": np.concatenate([f.contributors for f in frames]),
        "orientations": np.concatenate([f.orientations for f in frames]),
        "position_std": np.concatenate([f.position_std for f in frames]),
    }
    for key, parts in (extra or {}).items():
        out[f"{key}_shape"] = np.array([p.shape for p in parts], dtype=np.int64)
        out[key] = np.concatenate([p.ravel() for p in parts])
    return out


def run_people(take: Take) -> dict[str, np.ndarray]:
    """The people path: every instant through GroupFuser (group -> world -> associate -> tracks -> fuse),
    its fused frame through the wire codec and back; plus every body's track id (the memberships)."""
    fuser = GroupFuser(take.sensor_ids, take.poses, preset("skelfuse"))
    frames, assignment, body_track_ids, coasting = [], [], [], []
    for t, instant in enumerate(take.frames):
        result = fuser.step(FrameGroup(int(take.times_us[t]), instant, (), True))
        frames.append(decode_fused_frame(encode_fused_frame(result.frame)))
        assignment.append(result.people.assignment)
        body_track_ids.append(result.people.body_track_ids)
        coasting.append(result.people.coasting)
    return _record(frames, {"assignment": assignment, "body_track_ids": body_track_ids, "coasting": coasting})


def run_node(take: Take) -> dict[str, np.ndarray]:
    """The node's fusion step: encoded sensor payloads into FusionCore.receive (decode, group, fuse,
    encode), the published payloads decoded."""
    core = FusionCore(rig_config(take))
    payloads = []
    arrivals = sorted(
        (frame.host_time_ns, s, frame)
        for instant in take.frames
        for s, frame in enumerate(instant[sid] for sid in take.sensor_ids)
    )
    for arrival_ns, _, frame in arrivals:
        key = f"skelfuse/{RIG}/sensors/{frame.sensor_id}/skeletons"
        payloads += [o.payload for o in core.receive(key, encode_sensor_frame(frame), arrival_ns)]
    payloads += [o.payload for o in core.flush()]
    return _record([decode_fused_frame(p) for p in payloads])


INPUT = "input"  # the golden file's keys: "<take>/input/<field>" for the inputs, "<take>/<field>" for outputs


def stored_take(name: str, golden: dict[str, np.ndarray]) -> Take:
    """The take whose outputs the golden file holds, from the file itself."""
    prefix = f"{name}/{INPUT}/"
    return Take.from_arrays(name, {k[len(prefix) :]: v for k, v in golden.items() if k.startswith(prefix)})


def builder_drift(built: Take, stored: Take) -> list[str]:
    """How ``built`` (this module's take now) differs from ``stored`` beyond float rounding: empty when it is the
    same take. Counts, ids, confidences and times must be equal; positions within 0.01 mm and orientation
    components within 1e-5 (one float32 ulp of a joint 3 m away is 0.00024 mm: rounding passes, a change does not)."""
    a, b = built.to_arrays(), stored.to_arrays()
    drift = []
    for key in ("sensor_ids", "times_us", "host_time_ns", "n_bodies", "body_ids", "confidence"):
        if not np.array_equal(a[key], b[key]):  # False on a shape mismatch too
            drift.append(key)
    for key, atol in (("poses", 1e-6), ("positions", 1e-2), ("orientations", 1e-5)):
        if a[key].shape != b[key].shape or not np.allclose(a[key], b[key], rtol=0, atol=atol, equal_nan=True):
            drift.append(key)
    return drift


def golden_arrays() -> dict[str, np.ndarray]:
    """What the golden file holds: per take its inputs ("<take>/input/<field>") and the people path's outputs
    on them ("<take>/<field>"). The node's fusion step is checked against the same arrays (its published frames
    equal the people path's, bit for bit, at the revision that wrote the file)."""
    out: dict[str, np.ndarray] = {}
    for name in TAKES:
        take = build_take(name)
        for key, value in take.to_arrays().items():
            out[f"{name}/{INPUT}/{key}"] = value
        for key, value in run_people(take).items():
            out[f"{name}/{key}"] = value
    return out


def write_golden(path: Path = GOLDEN_PATH) -> Path:
    np.savez_compressed(path, **golden_arrays())
    return path
