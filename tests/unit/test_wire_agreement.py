"""Fused payload 1.2: the per-person agreement figure as an optional section, backward compatible both ways.

"Old decoder" means the real 1.1 code: the wire package (layout, rules, codec) and the stdlib example subscriber
as they were before 1.2, taken from the git history (skipped where the history is not available)."""

from __future__ import annotations

import importlib.util
import struct
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from test_wire_orientations import frame_with_sections

from skelfuse.schema.frames import FusedFrame
from skelfuse.schema.skeleton import N_JOINTS
from skelfuse.service.zenoh_io import Received
from skelfuse.stream.daemon import StreamReport, _forward
from skelfuse.wire import codec

ROOT = Path(__file__).resolve().parents[2]
BEFORE_1_2 = "6c08697"  # the last commit whose fused frames were at most 1.1 (codec, layout, rules, example)
OLD_WIRE = ("layout", "rules", "codec")


def _git_text(path: str) -> str:
    try:
        return subprocess.run(
            ["git", "-C", str(ROOT), "show", f"{BEFORE_1_2}:{path}"], capture_output=True, text=True, check=True
        ).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip(f"git history with commit {BEFORE_1_2} is not available: cannot load the 1.1 {path}")


def _load(name: str, file: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, file)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses and sibling imports look their module up while it is built
    spec.loader.exec_module(module)
    return module


def old_codec(tmp_path: Path) -> ModuleType:
    """The 1.1 wire codec with its own 1.1 layout and rules (imports renamed into a package of its own)."""
    package = "skelfuse_wire_1_1"
    folder = tmp_path / package
    folder.mkdir()
    (folder / "__init__.py").write_text("")
    _load(package, folder / "__init__.py")
    for name in OLD_WIRE:
        text = _git_text(f"src/skelfuse/wire/{name}.py").replace("skelfuse.wire.", f"{package}.")
        (folder / f"{name}.py").write_text(text)
    for name in OLD_WIRE:
        module = _load(f"{package}.{name}", folder / f"{name}.py")
    assert module.FUSED_MINOR_WITH_SECTIONS == 1 and not hasattr(module, "FUSED_SECTION_AGREEMENT")
    return module


def old_example(tmp_path: Path) -> ModuleType:
    file = tmp_path / "skelfuse_example_1_1.py"
    file.write_text(_git_text("scripts/example_subscriber.py"))
    return _load("skelfuse_example_1_1", file)


def new_example() -> ModuleType:
    return _load("skelfuse_example_subscriber_12", ROOT / "scripts" / "example_subscriber.py")


def frame_with_agreement(n_persons: int = 2, *, others: bool = True) -> FusedFrame:
    """``frame_with_sections`` plus agreement_mm (person 0: one view, NaN)."""
    frame = frame_with_sections(n_persons, orientations=others, std=others)
    figure = np.linspace(8.0, 120.0, n_persons)
    if n_persons:
        figure[0] = np.nan
    return FusedFrame(**{f: getattr(frame, f) for f in frame.__slots__ if f != "agreement_mm"}, agreement_mm=figure)


def test_round_trip_layout_and_version():
    frame = frame_with_agreement(3)
    payload = codec.encode_fused_frame(frame)
    before = codec.encode_fused_frame(frame_with_sections(3))  # the same frame without the figure: 1.1
    assert payload[4:6] == b"\x01\x02" and before[4:6] == b"\x01\x01"
    assert struct.unpack_from("<I", payload, 28)[0] == 7
    assert len(payload) == len(before) + 8 * 3
    assert payload[32 : len(before)] == before[32:]  # everything 1.1 had, unchanged; the figure after it
    assert [i for i in range(32) if payload[i] != before[i]] == [5, 28]  # minor and the sections bits
    assert struct.unpack_from("<3d", payload, len(before))[1:] == tuple(frame.agreement_mm[1:])
    back = codec.decode_fused_frame(payload)
    np.testing.assert_array_equal(back.agreement_mm, frame.agreement_mm)  # NaN where one view
    np.testing.assert_array_equal(back.position_std, frame.position_std)
    np.testing.assert_array_equal(back.orientations, frame.orientations)
    np.testing.assert_array_equal(back.positions, frame.positions)
    # The figure alone: 1.2 with only bit 2; nobody: a zero-length section.
    alone = codec.encode_fused_frame(frame_with_agreement(1, others=False))
    assert alone[5] == 2 and struct.unpack_from("<I", alone, 28)[0] == 4
    back = codec.decode_fused_frame(alone)
    assert back.orientations is None and back.position_std is None and np.isnan(back.agreement_mm).all()
    nobody = codec.decode_fused_frame(codec.encode_fused_frame(frame_with_agreement(0)))
    assert nobody.agreement_mm.shape == (0,)


def test_example_subscriber_reads_the_figure():
    frame = frame_with_agreement(2)
    decoded = new_example().decode_fused(codec.encode_fused_frame(frame))
    assert decoded["version"] == (1, 2)
    assert np.isnan(decoded["persons"][0]["agreement_mm"])
    assert decoded["persons"][1]["agreement_mm"] == frame.agreement_mm[1]
    np.testing.assert_array_equal(np.array(decoded["persons"][1]["position_std"]), frame.position_std[1])


@pytest.mark.live
def test_the_1_1_decoders_read_1_2_payloads(tmp_path):
    old = old_codec(tmp_path)
    frame = frame_with_agreement(2)
    payload = codec.encode_fused_frame(frame)
    by_old = old.decode_fused_frame(payload)
    np.testing.assert_array_equal(by_old.positions, frame.positions)
    np.testing.assert_array_equal(by_old.orientations, frame.orientations)
    np.testing.assert_array_equal(by_old.position_std, frame.position_std)
    np.testing.assert_array_equal(by_old.track_ids, frame.track_ids)
    alone = old.decode_fused_frame(codec.encode_fused_frame(frame_with_agreement(2, others=False)))
    assert alone.orientations is None and alone.position_std is None
    view = old_example(tmp_path).decode_fused(payload)
    assert [p["track_id"] for p in view["persons"]] == [3, 4] and "agreement_mm" not in view["persons"][1]
    assert view["persons"][1]["position_std"] == frame.position_std[1].tolist()
    # The 1.1 reader still refuses damage in what it knows: a 1.2 payload cut inside the 1.1 sections.
    with pytest.raises(old.DecodeError) as info:
        old.decode_fused_frame(payload[: len(payload) - 8 * 2 - 8])
    assert info.value.reason == "truncated"


@pytest.mark.live
def test_the_1_2_decoders_read_1_1_and_1_0_payloads(tmp_path):
    old = old_codec(tmp_path)
    for others in (True, False):  # 1.1 (orientations, position_std) and 1.0 (neither)
        old_frame = frame_with_sections(2, orientations=others, std=others)
        old_payload = old.encode_fused_frame(old_frame)
        assert old_payload == codec.encode_fused_frame(old_frame)  # what a 1.1 writer sent, a 1.2 writer sends
        back = codec.decode_fused_frame(old_payload)
        assert back.agreement_mm is None
        np.testing.assert_array_equal(back.positions, old_frame.positions)
        assert "agreement_mm" not in new_example().decode_fused(old_payload)["persons"][0]


def _damaged(figure: list[float]) -> bytes:
    payload = bytearray(codec.encode_fused_frame(frame_with_agreement(2)))
    payload[-16:] = np.asarray(figure, "<f8").tobytes()
    return bytes(payload)


@pytest.mark.parametrize(("figure", "reason"), [([5.0, -1.0], "bad_value"), ([np.inf, 5.0], "non_finite")])
def test_bad_figures_are_refused_both_ways_and_counted(figure, reason):
    frame = frame_with_agreement(2)
    with pytest.raises(ValueError, match="cannot be sent"):
        codec.encode_fused_frame(FusedFrame(**{**_fields(frame), "agreement_mm": np.asarray(figure)}))
    with pytest.raises(codec.DecodeError) as info:
        codec.decode_fused_frame(_damaged(figure))
    assert info.value.reason == reason
    # A subscriber daemon counts the reject per reason and forwards the next good frame.
    sent: list[FusedFrame] = []
    report = StreamReport()
    sender = type("Sender", (), {"send": lambda self, f: sent.append(f)})()
    for payload in (_damaged(figure), codec.encode_fused_frame(frame)):
        _forward(Received(0, "skelfuse/lab/fused/skeletons", payload), sender, report, "stream")
    assert report.rejects == {reason: 1} and report.frames_out == 1
    np.testing.assert_array_equal(sent[0].agreement_mm, frame.agreement_mm)


def _fields(frame: FusedFrame) -> dict[str, object]:
    return {f: getattr(frame, f) for f in frame.__slots__}


def test_short_padded_and_unknown_bits_are_rejected():
    payload = codec.encode_fused_frame(frame_with_agreement(2))
    for cut, reason in ((payload[:-4], "truncated"), (payload + b"\x00", "bad_length")):
        with pytest.raises(codec.DecodeError) as info:
            codec.decode_fused_frame(cut)
        assert info.value.reason == reason
    undefined = bytearray(payload)
    undefined[28] |= 8  # a bit 1.2 does not define
    older = bytearray(payload)
    older[5] = 1  # bit 2 in a 1.1 frame, which defines bits 0 and 1 only
    for bad in (undefined, older):
        with pytest.raises(codec.DecodeError) as info:
            codec.decode_fused_frame(bytes(bad))
        assert info.value.reason == "bad_header"
    newer = bytearray(payload + b"\xee" * 24)  # a newer minor's section after the figure: skipped
    newer[5], newer[28] = 3, newer[28] | 8
    np.testing.assert_array_equal(codec.decode_fused_frame(bytes(newer)).agreement_mm, [np.nan, 120.0])


def test_fused_recordings_and_the_public_api_carry_the_figure(tmp_path):
    """The recorder stores the payload as it is; skelfuse.read_fused_frames gives the figure back."""
    import skelfuse
    from skelfuse.recording import RecordingWriter

    path = tmp_path / "take.mcap"
    frames = [frame_with_agreement(2), frame_with_sections(1)]  # a 1.2 and a 1.1 frame in one take
    writer = RecordingWriter(path, rig="lab", sensor_ids=frames[0].sensor_ids, flush_interval_s=None)
    for i, frame in enumerate(frames):
        writer.write_fused_payload(codec.encode_fused_frame(frame), log_time_ns=1_700_000_000_000_000_000 + i)
    writer.close()
    back = list(skelfuse.read_fused_frames(path))
    np.testing.assert_array_equal(back[0].agreement_mm, frames[0].agreement_mm)
    assert back[1].agreement_mm is None


def test_the_node_publishes_each_persons_agreement():
    """A simulated two-view take through the node's per-instant path: the published payload carries the
    fused people's agreement_mm, finite where both views see the person."""
    from skelfuse.fusion.presets import preset
    from skelfuse.rig.grouping import FrameGroup
    from skelfuse.rig.instant import GroupFuser
    from skelfuse.schema.frames import SensorFrame
    from skelfuse.sim.gestures import make_gesture
    from skelfuse.sim.observe import load_profile, simulate
    from skelfuse.sim.rig import paper_rig

    motion = make_gesture("hands_up_down", duration_s=1.0, fps=30.0, facing_deg=0.0, seed=4)
    obs = simulate(motion, list(paper_rig(2)), load_profile(), seed=5)
    ids = tuple(obs.sensor_ids)
    fuser = GroupFuser(ids, obs.world_from_sensor_calibrated, preset("skelfuse"), birth_frames=1)
    figures = []
    for t in range(obs.n_frames):
        frames = {
            sid: SensorFrame(
                sid,
                t,
                int(obs.device_time_us[t, s]),
                int(obs.host_time_ns[t, s]),
                np.array([1], np.uint32),
                obs.positions[t, s][None],
                np.tile([1.0, 0.0, 0.0, 0.0], (1, N_JOINTS, 1)).astype(np.float32),
                obs.confidence[t, s][None],
            )
            for s, sid in enumerate(ids)
            if obs.tracked[t, s]
        }
        instant = fuser.step(FrameGroup(time_us=1_000_000 + t * 33_333, frames=frames, missing=(), complete=True))
        decoded = codec.decode_fused_frame(codec.encode_fused_frame(instant.frame))
        np.testing.assert_array_equal(decoded.agreement_mm, instant.people.agreement_mm)
        figures.extend(decoded.agreement_mm.tolist())
    seen = np.array(figures)
    assert seen.size > 20 and np.isfinite(seen).mean() > 0.9 and np.nanmedian(seen) < 50.0


def test_the_osc_stream_sends_each_persons_agreement():
    """Decoded with python-osc's own parser: one agreement message per person, -1 for one view."""
    from pythonosc.osc_bundle import OscBundle

    from skelfuse.stream.osc import frame_bundles

    frame = frame_with_agreement(2, others=False)
    messages = [(m.address, list(m.params)) for d in frame_bundles(frame) for m in OscBundle(d)]
    agreement = [(address, params) for address, params in messages if address.endswith("/agreement")]
    assert agreement == [("/skelfuse/person/3/agreement", [-1.0]), ("/skelfuse/person/4/agreement", [120.0])]
    without = [m.address for d in frame_bundles(frame_with_sections(1)) for m in OscBundle(d)]
    assert not any(address.endswith("/agreement") for address in without)


def test_the_rerun_view_labels_each_person_with_the_agreement(tmp_path):
    """Read back from the saved .rrd: the label above each head carries the figure, "one view" for NaN."""
    import rerun as rr
    from test_rerun_sink import _columns

    from skelfuse.sinks.rerun_sink import RerunSink

    recording = rr.RecordingStream("skelfuse_test")
    path = tmp_path / "agreement.rrd"
    recording.save(path)
    sink = RerunSink(recording, ["left", "right"])
    sink.set_time(0.0)
    sink.log_fused(np.zeros((2, N_JOINTS, 3)), np.array([7, 8]), np.array([12.4, np.nan]))
    recording.flush()
    recording.disconnect()
    labels = _columns(path)["/world/fused/labels"]["Points3D:labels"][0]
    assert labels == ["person 7 · views ±12 mm", "person 8 · one view"]
