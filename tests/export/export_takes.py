"""Simulated takes for the export tests: ground truth of the procedural gestures, and that truth seen by the
paper's rig through the simulator and fused by our preset (what an export gets in practice)."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from skelfuse.eval.paper import N_CAPTURE, FusionRun, _world_skeletons, fuse_take
from skelfuse.schema.frames import FusedFrame
from skelfuse.schema.skeleton import N_JOINTS
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.rig import paper_rig

FPS = 30.0


def _read_only(array: np.ndarray) -> np.ndarray:
    """The cached takes are shared by every test that asks for them: one that writes into them fails at once."""
    array = np.array(array)
    array.flags.writeable = False
    return array


@lru_cache(maxsize=8)
def truth_take(gesture: str, duration_s: float = 4.0, seed: int = 1) -> np.ndarray:
    """(T, 32, 3) mm world: a rigid, fixed-length skeleton (the simulator's own forward kinematics)."""
    return _read_only(make_gesture(gesture, duration_s=duration_s, fps=FPS, facing_deg=30.0, seed=seed).positions)


@lru_cache(maxsize=8)
def fused_take(gesture: str, duration_s: float = 4.0, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(T, 32, 3) fused positions (NaN where the fuser gave none) and their truth, of the paper's 4-sensor rig."""
    motion = make_gesture(gesture, duration_s=duration_s, fps=FPS, facing_deg=30.0, seed=seed)
    obs = simulate(motion, list(paper_rig(N_CAPTURE)), load_profile(None), seed=seed + 1)
    run = FusionRun("skelfuse", "skelfuse", None, tuple(range(N_CAPTURE)))
    fused = fuse_take(run, _world_skeletons(obs), np.asarray(obs.confidence), FPS)
    return _read_only(fused), _read_only(np.asarray(obs.truth, dtype=np.float64))


def as_frames(positions: np.ndarray, track_id: int = 7, fps: float = FPS) -> list[FusedFrame]:
    """One person's (T, 32, 3) positions as fused frames (time in microseconds from 1 s)."""
    frames = []
    for t, pose in enumerate(positions):
        frames.append(
            FusedFrame(
                time_us=1_000_000 + round(t * 1e6 / fps),
                track_ids=np.array([track_id], dtype=np.int64),
                positions=pose[None].astype(np.float64),
                n_agree=np.ones((1, N_JOINTS), dtype=np.int16),
                confidence=np.full((1, N_JOINTS), 2, dtype=np.uint8),
                contributors=np.ones((1, 1), dtype=bool),
                sensor_ids=("sim",),
            )
        )
    return frames
