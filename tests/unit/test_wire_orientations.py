"""Fused payload 1.1: orientations and position_std as optional sections, backward compatible both ways.

"Old decoder" means the real 1.0 code: the codec and the stdlib example subscriber as they were before 1.1,
taken from the git history (skipped where the history is not available)."""

from __future__ import annotations

import importlib.util
import struct
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skelfuse.fusion.orientation import aim_directions
from skelfuse.fusion.presets import preset
from skelfuse.rig.grouping import FrameGroup
from skelfuse.rig.instant import GroupFuser
from skelfuse.schema.frames import FusedFrame, SensorFrame
from skelfuse.schema.skeleton import N_JOINTS, ORIENTATION_DERIVED_SOURCE
from skelfuse.sim.gestures import make_gesture
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.orientation import observe_orientations, truth_orientations
from skelfuse.sim.rig import paper_rig
from skelfuse.wire import codec

ROOT = Path(__file__).resolve().parents[2]
BEFORE_1_1 = "46d2b63"  # the last commit with the 1.0-only codec and example subscriber


def _module_from_git(path: str, name: str, tmp_path: Path) -> ModuleType:
    try:
        text = subprocess.run(
            ["git", "-C", str(ROOT), "show", f"{BEFORE_1_1}:{path}"], capture_output=True, text=True, check=True
        ).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip(f"git history with commit {BEFORE_1_1} is not available: cannot load the 1.0 {path}")
    file = tmp_path / f"{name}.py"
    file.write_text(text)
    spec = importlib.util.spec_from_file_location(name, file)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    return module


def _example() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "skelfuse_example_subscriber_11", ROOT / "scripts" / "example_subscriber.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def frame_with_sections(n_persons: int = 2, *, orientations: bool = True, std: bool = True) -> FusedFrame:
    rng = np.random.default_rng(11)
    positions = rng.normal(0.0, 1000.0, (n_persons, N_JOINTS, 3))
    quats = Rotation.random(n_persons * N_JOINTS, random_state=12).as_quat()[:, [3, 0, 1, 2]]
    quats = quats.reshape(n_persons, N_JOINTS, 4)
    sigma = rng.uniform(2.0, 40.0, (n_persons, N_JOINTS))
    if n_persons:
        positions[0, 9] = np.nan
        quats[0, 9] = np.nan
        sigma[0, 9] = np.nan
    return FusedFrame(
        time_us=1_234_567,
        track_ids=np.arange(3, 3 + n_persons, dtype=np.int64),
        positions=positions,
        n_agree=np.full((n_persons, N_JOINTS), 3, dtype=np.int16),
        confidence=np.full((n_persons, N_JOINTS), 2, dtype=np.uint8),
        contributors=np.ones((n_persons, 2), dtype=bool),
        sensor_ids=("000123", "000456"),
        orientations=quats if orientations else None,
        position_std=sigma if std else None,
    )


def test_round_trip_layout_and_version():
    frame = frame_with_sections(2)
    payload = codec.encode_fused_frame(frame)
    plain = codec.encode_fused_frame(frame_with_sections(2, orientations=False, std=False))
    assert payload[4:6] == b"\x01\x01"  # version 1.1
    assert plain[4:6] == b"\x01\x00"  # no sections: exactly 1.0
    assert struct.unpack_from("<I", payload, 28)[0] == 3 and struct.unpack_from("<I", plain, 28)[0] == 0
    assert len(payload) == len(plain) + 2 * N_JOINTS * (4 * 8 + 8)
    assert payload[32 : len(plain)] == plain[32:]  # the 1.0 sections unchanged, the new ones after them
    assert [i for i in range(32) if payload[i] != plain[i]] == [5, 28]  # minor and the sections bits
    back = codec.decode_fused_frame(payload)
    np.testing.assert_array_equal(back.orientations, frame.orientations)
    np.testing.assert_array_equal(back.position_std, frame.position_std)
    np.testing.assert_array_equal(back.positions, frame.positions)
    # One section alone.
    only_std = codec.decode_fused_frame(codec.encode_fused_frame(frame_with_sections(1, orientations=False)))
    assert only_std.orientations is None and only_std.position_std.shape == (1, N_JOINTS)
    none = codec.decode_fused_frame(plain)
    assert none.orientations is None and none.position_std is None


def test_example_subscriber_decodes_the_sections():
    frame = frame_with_sections(2)
    decoded = _example().decode_fused(codec.encode_fused_frame(frame))
    assert decoded["version"] == (1, 1)
    for p, person in enumerate(decoded["persons"]):
        np.testing.assert_array_equal(np.array(person["orientations"]), frame.orientations[p])
        np.testing.assert_array_equal(np.array(person["position_std"]), frame.position_std[p])
    plain = _example().decode_fused(codec.encode_fused_frame(frame_with_sections(1, orientations=False, std=False)))
    assert "orientations" not in plain["persons"][0] and "position_std" not in plain["persons"][0]


@pytest.mark.live
def test_old_decoders_read_new_payloads_and_new_decoders_read_old_ones(tmp_path):
    old_codec = _module_from_git("src/skelfuse/wire/codec.py", "skelfuse_wire_codec_1_0", tmp_path)
    old_example = _module_from_git("scripts/example_subscriber.py", "skelfuse_example_1_0", tmp_path)
    frame = frame_with_sections(2)
    payload = codec.encode_fused_frame(frame)
    by_old = old_codec.decode_fused_frame(payload)
    np.testing.assert_array_equal(by_old.positions, frame.positions)
    np.testing.assert_array_equal(by_old.track_ids, frame.track_ids)
    old_view = old_example.decode_fused(payload)
    assert [p["track_id"] for p in old_view["persons"]] == [3, 4]
    assert old_view["persons"][1]["positions"][0] == frame.positions[1, 0].tolist()
    # A 1.0 writer's payload, read by the 1.1 codec and example.
    old_payload = old_codec.encode_fused_frame(frame_with_sections(2, orientations=False, std=False))
    assert old_payload == codec.encode_fused_frame(frame_with_sections(2, orientations=False, std=False))
    back = codec.decode_fused_frame(old_payload)
    assert back.orientations is None and back.position_std is None
    assert "orientations" not in _example().decode_fused(old_payload)["persons"][0]


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        (lambda f: f.orientations.__setitem__((0, 0, 1), np.nan), "non_finite"),
        (lambda f: f.orientations.__setitem__((0, 0), [2.0, 0.0, 0.0, 0.0]), "bad_value"),
        (lambda f: f.position_std.__setitem__((1, 3), -1.0), "bad_value"),
        (lambda f: f.position_std.__setitem__((1, 3), np.inf), "non_finite"),
    ],
)
def test_bad_sections_are_refused_both_ways(change, reason):
    frame = frame_with_sections(2)
    good = codec.encode_fused_frame(frame)
    change(frame)
    with pytest.raises(ValueError, match="cannot be sent"):
        codec.encode_fused_frame(frame)
    # The same damage written straight into a valid payload is rejected by the decoder with its reason.
    damaged = bytearray(good)
    table_end = len(good) - 2 * N_JOINTS * 40
    damaged[table_end:] = frame.orientations.astype("<f8").tobytes() + frame.position_std.astype("<f8").tobytes()
    with pytest.raises(codec.DecodeError) as info:
        codec.decode_fused_frame(bytes(damaged))
    assert info.value.reason == reason


def test_truncated_or_padded_sections_are_rejected():
    payload = codec.encode_fused_frame(frame_with_sections(1))
    with pytest.raises(codec.DecodeError) as info:
        codec.decode_fused_frame(payload[:-8])
    assert info.value.reason == "truncated"
    with pytest.raises(codec.DecodeError) as info:
        codec.decode_fused_frame(payload + b"\x00")
    assert info.value.reason == "bad_length"
    newer = bytearray(payload + b"\xee" * 5)  # a newer writer may append more sections: read what this reader knows
    newer[5] = codec.FUSED_MINOR_WITH_AGREEMENT + 1
    assert codec.decode_fused_frame(bytes(newer)).orientations.shape == (1, N_JOINTS, 4)


def test_group_fuser_publishes_orientations_the_example_decodes():
    """A simulated take through the live/offline path (GroupFuser, skelfuse preset): the fused frames carry
    orientations and position_std; the stdlib example reads them back from the payload."""
    motion = make_gesture("hands_up_down", duration_s=1.0, fps=30.0, facing_deg=0.0, seed=4)
    sensors = list(paper_rig(3))
    obs = simulate(motion, sensors, load_profile(), seed=5)
    views = observe_orientations(obs, truth_orientations(obs.truth, 30.0, seed=5), seed=5)
    ids = tuple(obs.sensor_ids)
    fuser = GroupFuser(ids, obs.world_from_sensor_calibrated, preset("skelfuse"), birth_frames=1)
    frame = None
    for t in range(obs.n_frames):
        frames = {}
        for s, sid in enumerate(ids):
            if not obs.tracked[t, s]:
                continue
            frames[sid] = SensorFrame(
                sid,
                t,
                int(obs.device_time_us[t, s]),
                int(obs.host_time_ns[t, s]),
                np.array([1], np.uint32),
                obs.positions[t, s][None],
                views[t, s][None],
                obs.confidence[t, s][None],
            )
        group = FrameGroup(time_us=int(1_000_000 + t * 33_333), frames=frames, missing=(), complete=True)
        frame = fuser.step(group).frame
    assert frame is not None and frame.n_persons == 1
    assert frame.orientations.shape == (1, N_JOINTS, 4) and frame.position_std.shape == (1, N_JOINTS)
    knowable = np.isfinite(aim_directions(frame.positions)).all(axis=-1)[..., ORIENTATION_DERIVED_SOURCE]
    assert knowable.mean() > 0.9 and np.isfinite(frame.orientations[knowable]).all()
    assert (frame.position_std[np.isfinite(frame.positions).all(axis=-1)] > 0).all()
    decoded = _example().decode_fused(codec.encode_fused_frame(frame))
    np.testing.assert_array_equal(np.array(decoded["persons"][0]["orientations"]), frame.orientations[0])


@pytest.mark.parametrize(
    ("quat", "refused"),
    [
        ([1.0, 0.0, 0.0, 0.0], None),
        ([2.0, 0.0, 0.0, 0.0], "norm is not 1"),
        ([1.0, 0.0, 0.0, 0.05], "norm is not 1"),  # norm 1.00125
        ([np.inf, 0.0, 0.0, 0.0], "Inf"),
    ],
)
def test_a_frame_with_every_orientation_known_is_checked_as_strictly(quat, refused):
    """No unknown joint: the encoder's shorter path for fully known orientations refuses what the full rule does."""
    frame = frame_with_sections(2)
    frame.orientations[0, 9] = [0.0, 1.0, 0.0, 0.0]  # every joint known
    frame.orientations[1, 4] = quat
    if refused is None:
        back = codec.decode_fused_frame(codec.encode_fused_frame(frame))
        np.testing.assert_array_equal(back.orientations, frame.orientations)
    else:
        with pytest.raises(ValueError, match=refused):
            codec.encode_fused_frame(frame)
