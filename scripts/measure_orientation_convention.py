#!/usr/bin/env python3
"""Measure the k4abt joint-frame convention on the real andyj1 recordings (docs/orientations.md).

For every joint: how far the SDK's own local X axis is from the bone skelfuse aims it along
(``skelfuse.schema.skeleton.ORIENTATION_AIM``): the angle of the smallest rotation that puts it there
("swing"), and how far the SDK frame is from the frame built from the bones and the body alone (the fallback
used without any view, ``ORIENTATION_HINT``). Also which quaternion component order the files really hold, and
where the foot bone lies in the SDK's ankle frame (``ANKLE_FOOT_ANGLE_DEG``), per file, and per file the one
rotation that best puts the joints' frames on their own bones (a file whose orientations were mapped into another
frame by another rotation than its positions shows it as a constant offset).

    python scripts/measure_orientation_convention.py [DATA_DIR]

DATA_DIR defaults to ../shared/data/azure-kinect-andyj1 (relative to the repository root).
"""

from __future__ import annotations

import itertools
import sys
from pathlib import Path

import numpy as np

from skelfuse.calibration.rigid import fit_rigid, rotation_angle_deg
from skelfuse.fusion.orientation import (
    aim_directions,
    apply_derived,
    body_hint_frames,
    quat_angle_deg,
    quat_conjugate,
    quat_rotate,
    swing_onto_aims,
)
from skelfuse.retarget.rotations import kabsch
from skelfuse.schema.skeleton import ANKLE_FOOT_ANGLE_DEG, JOINT_NAMES, ORIENTATION_AIMED, Confidence, J
from skelfuse.sources.recorded import load_andyj1_csv

FILES = (
    "saved_data_2_3dev/joints_gen_master.csv",
    "saved_data_2_3dev/joints_gen_sub1.csv",
    "saved_data_2_3dev/joints_gen_sub2.csv",
    "extrinsic_calculation/joints_sync_1.csv",
    "extrinsic_calculation/joints_sync_2.csv",
)
OFFSET_FILES = (*FILES, "extrinsic_calculation/joints_sync_tf.csv")
# Joints whose X lies on a bone the tracker holds well (LOW or better in most frames): no hands, thumbs or ankles.
OFFSET_JOINTS = [
    J[name]
    for name in (
        "PELVIS SPINE_NAVEL SPINE_CHEST NECK CLAVICLE_LEFT SHOULDER_LEFT ELBOW_LEFT CLAVICLE_RIGHT SHOULDER_RIGHT "
        "ELBOW_RIGHT HIP_LEFT KNEE_LEFT HIP_RIGHT KNEE_RIGHT"
    ).split()
]


def main(argv: list[str]) -> int:
    root = Path(__file__).resolve().parents[1]
    data = Path(argv[1]) if len(argv) > 1 else root.parent / "shared" / "data" / "azure-kinect-andyj1"
    if not data.is_dir():
        print(f"no andyj1 data at {data}; pass its folder as the first argument", file=sys.stderr)
        return 2
    positions, stored, confidence = [], [], []
    for name in FILES:
        rec = load_andyj1_csv(data / name)
        positions.append(rec.positions[:, 0].astype(np.float64))
        stored.append(rec.orientations[:, 0].astype(np.float64))
        confidence.append(rec.confidence[:, 0])
    p = np.concatenate(positions)
    # The reader returns the quaternion columns in the file's order (it takes them as w, x, y, z, the
    # order this script measures): every permutation of them is tried below.
    columns = np.concatenate(stored)
    conf = np.concatenate(confidence)
    print(f"{p.shape[0]} frames from {len(FILES)} files in {data}")

    aims = aim_directions(p)
    print("\nWhich component order holds w, x, y, z? Mean |cos| between the SDK X axis and the aim bone:")
    best = None
    for order in itertools.permutations(range(4)):
        q = columns[..., list(order)]
        x_axis = quat_rotate(q / np.linalg.norm(q, axis=-1, keepdims=True), np.array([1.0, 0.0, 0.0]))
        score = float(np.nanmean(np.abs(np.sum(x_axis * aims, axis=-1))[:, ORIENTATION_AIMED]))
        if best is None or score > best[0]:
            best = (score, order)
        if order in ((0, 1, 2, 3), (3, 0, 1, 2)):
            label = "file columns read as w,x,y,z" if order == (0, 1, 2, 3) else "as the header says (x,y,z,w)"
            print(f"  {label}: {score:.3f}")
    print(f"  best order {best[1]}: {best[0]:.3f}")
    sdk = columns[..., list(best[1])]

    swung = apply_derived(swing_onto_aims(sdk, aims))
    hinted = apply_derived(body_hint_frames(p))
    swing = quat_angle_deg(sdk, swung)
    hint = quat_angle_deg(sdk, hinted)
    print("\njoint            n   swing to our bone (deg)   bones + body hint (deg)")
    print("                     median    p90            median    p90")
    for j, name in enumerate(JOINT_NAMES):
        seen = (conf[:, j] >= int(Confidence.LOW)) & np.isfinite(swing[:, j])
        if not seen.any():
            print(f"{name:14s} {0:5d}")
            continue
        s, h = swing[seen, j], hint[seen, j]
        print(
            f"{name:14s} {seen.sum():5d}   {np.median(s):6.1f} {np.percentile(s, 90):6.1f}"
            f"          {np.median(h):6.1f} {np.percentile(h, 90):6.1f}"
        )
    print_ankle_frames(data)
    print_frame_offsets(data)
    return 0


def print_ankle_frames(data: Path) -> None:
    """Per file and ankle: the foot bone's angle about the SDK ankle frame's Z from its X (median, range), how far
    the foot leaves the frame's XY plane, and how far the frame's X lies off the shin (the ankle's flexion)."""
    print(f"\nThe foot bone in the SDK's ankle frame (schema ANKLE_FOOT_ANGLE_DEG: {ANKLE_FOOT_ANGLE_DEG}):")
    print("file                                      ankle   angle about Z (median, min..max)  |z| max  X off shin")
    for name in FILES:
        rec = load_andyj1_csv(data / name)
        p = rec.positions[:, 0].astype(np.float64)
        q = rec.orientations[:, 0].astype(np.float64)
        for side, sign in (("LEFT", -1.0), ("RIGHT", 1.0)):  # sign: X points up the left leg, down the right
            ankle, foot, knee = J[f"ANKLE_{side}"], J[f"FOOT_{side}"], J[f"KNEE_{side}"]
            bone = p[:, foot] - p[:, ankle]
            local = quat_rotate(quat_conjugate(q[:, ankle]), bone / np.linalg.norm(bone, axis=-1, keepdims=True))
            angle = np.degrees(np.arctan2(local[:, 1], local[:, 0]))
            shin = sign * (p[:, ankle] - p[:, knee])
            shin /= np.linalg.norm(shin, axis=-1, keepdims=True)
            off = np.degrees(np.arccos(np.clip(np.sum(quat_rotate(q[:, ankle], [1.0, 0, 0]) * shin, -1), -1, 1)))
            print(
                f"{name:41s} {side:6s} {np.median(angle):8.2f} ({angle.min():7.2f}..{angle.max():7.2f})"
                f"          {np.abs(local[:, 2]).max():5.3f}   {np.median(off):4.1f} ({off.min():.1f}..{off.max():.1f})"
            )


def print_frame_offsets(data: Path) -> None:
    """Per file: the one rotation R that best puts the bones on the SDK X axes of the torso, arm and leg joints
    (``x ~ R bone`` over every joint and frame), its angle and axis; the median angle of X off its bone before and
    after R; and how far each frame's own best rotation lies from R. For the mapped file of the two-camera take,
    the rotation that maps the subordinate's positions onto it (its orientations are the subordinate's own)."""
    print("\nOne rotation between each file's joint frames and its bones (torso, arms to the elbow, legs to the knee):")
    print(f"{'file':41s} angle  axis (file frame)        X off bone: before  after   per frame")
    offsets = {}
    for name in OFFSET_FILES:
        rec = load_andyj1_csv(data / name)
        p, q = rec.positions[:, 0].astype(np.float64), rec.orientations[:, 0].astype(np.float64)
        x_axis = quat_rotate(q / np.linalg.norm(q, axis=-1, keepdims=True), np.array([1.0, 0.0, 0.0]))[:, OFFSET_JOINTS]
        bone = aim_directions(p)[:, OFFSET_JOINTS]
        ok = np.isfinite(x_axis).all(axis=-1) & np.isfinite(bone).all(axis=-1)
        R = offsets[name] = kabsch(bone[ok], x_axis[ok], np.ones(int(ok.sum())))
        per_frame = kabsch(bone, x_axis, ok.astype(float))
        drift = [rotation_angle_deg(f @ R.T) for f, n in zip(per_frame, ok.sum(axis=1), strict=True) if n >= 6]
        before = np.degrees(np.arccos(np.clip(np.sum(x_axis * bone, -1)[ok], -1, 1)))
        after = np.degrees(np.arccos(np.clip(np.sum(x_axis * (bone @ R.T), -1)[ok], -1, 1)))
        axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
        axis = axis / max(np.linalg.norm(axis), 1e-12)
        print(
            f"{name:41s} {rotation_angle_deg(R):5.2f}  ({axis[0]:+.2f}, {axis[1]:+.2f}, {axis[2]:+.2f})"
            f"          {np.median(before):5.2f}  {np.median(after):5.2f}   {np.median(drift):.2f} median"
        )
    own = load_andyj1_csv(data / "extrinsic_calculation/joints_sync_2.csv").positions[:, 0].reshape(-1, 3)
    mapped = load_andyj1_csv(data / "extrinsic_calculation/joints_sync_tf.csv").positions[:, 0].reshape(-1, 3)
    fit = fit_rigid(own.astype(np.float64), mapped.astype(np.float64))
    offset = offsets["extrinsic_calculation/joints_sync_tf.csv"]
    print(
        f"joints_sync_2 -> joints_sync_tf: positions rotated {rotation_angle_deg(fit.R):.2f} deg (rigid fit), "
        f"orientations unchanged; the file's offset undoes it to {rotation_angle_deg(offset @ fit.R):.2f} deg"
    )


if __name__ == "__main__":
    raise SystemExit(main(sys.argv))
