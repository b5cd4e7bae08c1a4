#!/usr/bin/env python3
"""Measure the k4abt joint-frame convention on the real andyj1 recordings (docs/orientations.md).

For every joint: how far the SDK's own local X axis is from the bone skelfuse aims it along
(``skelfuse.schema.skeleton.ORIENTATION_AIM``): the angle of the smallest rotation that puts it there
("swing"), and how far the SDK frame is from the frame built from the bones and the body alone (the fallback
used without any view, ``ORIENTATION_HINT``). Also which quaternion component order the files really hold, and
where the foot bone lies in the SDK's ankle frame (``ANKLE_FOOT_ANGLE_DEG``), per file, and per file the one
rotation that best puts the joints' frames on their own bones (a file whose orientations were mapped into another
frame by another rotation than its positions shows it as a constant offset).

    python scripts/measure_orientation_convention.py [DATA_DIR] [--json]

DATA_DIR defaults to ../shared/data/azure-kinect-andyj1 (relative to the repository root). ``--json`` prints the
measurements with the run's stamp (docs/evidence.md, "Orientations", renders them with :func:`format_markdown`).
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.calibration.rigid import fit_rigid, rotation_angle_deg
from skelfuse.cli.common import print_json
from skelfuse.cli.stamp import RunStamp
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
MAPPED = "extrinsic_calculation/joints_sync_tf.csv"
"""joints_sync_2.csv's positions mapped into the master's frame by the recording's authors, its orientations not."""
OFFSET_JOINTS = [
    J[name]
    for name in (
        "PELVIS SPINE_NAVEL SPINE_CHEST NECK CLAVICLE_LEFT SHOULDER_LEFT ELBOW_LEFT CLAVICLE_RIGHT SHOULDER_RIGHT "
        "ELBOW_RIGHT HIP_LEFT KNEE_LEFT HIP_RIGHT KNEE_RIGHT"
    ).split()
]
"""Joints whose X lies on a bone the tracker holds well: no head, hands, thumbs or ankles."""


def measure(data: Path) -> dict[str, Any]:
    """The component order, each joint's swing and body-hint angles to the SDK frame, and the ankle frames."""
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
    aims = aim_directions(p)
    scores = {}
    for order in itertools.permutations(range(4)):
        q = columns[..., list(order)]
        x_axis = quat_rotate(q / np.linalg.norm(q, axis=-1, keepdims=True), np.array([1.0, 0.0, 0.0]))
        scores["".join(map(str, order))] = float(
            np.nanmean(np.abs(np.sum(x_axis * aims, axis=-1))[:, ORIENTATION_AIMED])
        )
    best = max(scores, key=scores.__getitem__)
    sdk = columns[..., [int(c) for c in best]]
    swing = quat_angle_deg(sdk, apply_derived(swing_onto_aims(sdk, aims)))
    hint = quat_angle_deg(sdk, apply_derived(body_hint_frames(p)))
    joints = {}
    for j, name in enumerate(JOINT_NAMES):
        seen = (conf[:, j] >= int(Confidence.LOW)) & np.isfinite(swing[:, j])
        s, h = swing[seen, j], hint[seen, j]
        joints[name] = {"n": int(seen.sum())} | (
            {"swing": _median_p90(s), "hint": _median_p90(h)} if seen.any() else {}
        )
    return {"data": str(data), "files": list(FILES), "frames": int(p.shape[0]), "order_scores": scores,
            "best_order": best, "joints": joints, "ankles": ankle_frames(data),
            "frame_offsets": frame_offsets(data),
            "ankle_foot_angle_deg": ANKLE_FOOT_ANGLE_DEG}  # fmt: skip


def _median_p90(values: np.ndarray) -> list[float]:
    return [float(np.median(values)), float(np.percentile(values, 90))]


def ankle_frames(data: Path) -> list[dict[str, Any]]:
    """Per file and ankle: the foot bone's angle about the SDK ankle frame's Z from its X (median, range), how far
    the foot leaves the frame's XY plane, and how far the frame's X lies off the shin (the ankle's flexion)."""
    rows = []
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
            rows.append({"file": name, "ankle": side, "angle_deg": [float(np.median(angle)), float(angle.min()),
                         float(angle.max())], "off_plane_max": float(np.abs(local[:, 2]).max()),
                         "off_shin_deg": [float(np.median(off)), float(off.min()), float(off.max())]})  # fmt: skip
    return rows


def frame_offsets(data: Path) -> dict[str, Any]:
    """Per file: the one rotation R that best puts the bones on the SDK X axes of the torso, arm and leg joints
    (``x ~ R bone`` over every joint and frame), its angle and axis; the median angle of X off its bone before and
    after R; and the median angle of each frame's own best rotation from R. For the authors' mapped file of the
    two-camera take, also the rotation that maps the subordinate's positions onto it, and how far R undoes it."""
    rows, offsets = [], {}
    for name in (*FILES, MAPPED):
        rec = load_andyj1_csv(data / name)
        p, q = rec.positions[:, 0].astype(np.float64), rec.orientations[:, 0].astype(np.float64)
        x_axis, bone, ok = _axes_and_bones(p, q)
        R = offsets[name] = frame_offset(p, q)
        per_frame = kabsch(bone, x_axis, ok.astype(float))
        drift = [rotation_angle_deg(f @ R.T) for f, n in zip(per_frame, ok.sum(axis=1), strict=True) if n >= 6]
        axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
        rows.append({"file": name, "angle_deg": rotation_angle_deg(R),
                     "axis": (axis / max(float(np.linalg.norm(axis)), 1e-12)).tolist(),
                     "off_bone_deg": [_median_angle(x_axis[ok], bone[ok]), _median_angle(x_axis[ok], bone[ok] @ R.T)],
                     "per_frame_deg": float(np.median(drift))})  # fmt: skip
    own = load_andyj1_csv(data / FILES[-1]).positions[:, 0].reshape(-1, 3).astype(np.float64)
    mapped = load_andyj1_csv(data / MAPPED).positions[:, 0].reshape(-1, 3).astype(np.float64)
    position_map = fit_rigid(own, mapped).R
    return {"files": rows, "mapped": MAPPED, "mapped_positions_deg": rotation_angle_deg(position_map),
            "mapped_undone_deg": rotation_angle_deg(offsets[MAPPED] @ position_map)}  # fmt: skip


def _axes_and_bones(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The SDK X axes and the aim bones (unit, (T, joints, 3)) of :data:`OFFSET_JOINTS`, and where both exist."""
    x_axis = quat_rotate(q / np.linalg.norm(q, axis=-1, keepdims=True), np.array([1.0, 0.0, 0.0]))[:, OFFSET_JOINTS]
    bone = aim_directions(p)[:, OFFSET_JOINTS]
    return x_axis, bone, np.isfinite(x_axis).all(axis=-1) & np.isfinite(bone).all(axis=-1)


def frame_offset(positions: np.ndarray, orientations: np.ndarray) -> np.ndarray:
    """(3, 3) the one rotation R with the SDK X axes ~ R bone over every torso, arm and leg joint and frame of one
    body's ``positions`` (T, 32, 3) and ``orientations`` (T, 32, 4, w x y z): identity for a file whose frames lie
    on its own bones; R^T turns the frames of a file whose orientations missed its positions' mapping back."""
    x_axis, bone, ok = _axes_and_bones(positions, orientations)
    return kabsch(bone[ok], x_axis[ok], np.ones(int(ok.sum())))


def _median_angle(u: np.ndarray, v: np.ndarray) -> float:
    """Median angle between unit vectors (rows), degrees."""
    return float(np.median(np.degrees(np.arccos(np.clip(np.sum(u * v, axis=-1), -1.0, 1.0)))))


def format_markdown(result: dict[str, Any]) -> str:
    """The component order, the per-joint angles and the ankle frames as markdown tables."""
    scores, best = result["order_scores"], result["best_order"]
    constant = ", ".join(f"{name.split('_')[1].lower()} {deg}" for name, deg in result["ankle_foot_angle_deg"].items())
    lines = [
        f"{result['frames']} frames from {len(result['files'])} files ({', '.join(result['files'])}).",
        "",
        "Which quaternion component order holds w, x, y, z (mean |cos| between the SDK's X axis and the bone "
        f"skelfuse aims it along): the file's columns read as w, x, y, z {scores['0123']:.3f}; as the header says "
        f"(x, y, z, w) {scores['3012']:.3f}; the best order ({', '.join(best)}) {scores[best]:.3f}.",
        "",
        "Each joint's SDK frame against skelfuse's, degrees (median / p90): the smallest rotation that puts its X on "
        "the bone skelfuse aims it along (swing), and the frame built from the bones and the body alone (hint).",
        "",
        "| joint | frames | swing to the bone | bones + body hint |",
        "|---|---:|---|---|",
    ]
    for name, row in result["joints"].items():
        cells = [f"{row[k][0]:.1f} / {row[k][1]:.1f}" for k in ("swing", "hint")] if "swing" in row else ["—", "—"]
        lines.append(f"| {name} | {row['n']} | " + " | ".join(cells) + " |")
    lines += [
        "",
        f"The foot bone in the SDK's ankle frame (the schema's `ANKLE_FOOT_ANGLE_DEG`: {constant}): its angle "
        "about Z from X (median, min..max), its largest |z| (off the frame's XY plane, unit bone), and how far the "
        "frame's X lies off the shin (median, min..max):",
        "",
        "| file | ankle | angle about Z, deg | off the plane | X off the shin, deg |",
        "|---|---|---|---:|---|",
    ]
    for row in result["ankles"]:
        a, o = row["angle_deg"], row["off_shin_deg"]
        lines.append(
            f"| {row['file']} | {row['ankle'].lower()} | {a[0]:.2f} ({a[1]:.2f}..{a[2]:.2f}) | "
            f"{row['off_plane_max']:.3f} | {o[0]:.1f} ({o[1]:.1f}..{o[2]:.1f}) |"
        )
    if "frame_offsets" in result:
        lines += _frame_offset_lines(result["frame_offsets"])
    return "\n".join(lines)


def _frame_offset_lines(offsets: dict[str, Any]) -> list[str]:
    """The table of :func:`frame_offsets` and its line on the authors' mapped file."""
    lines = [
        "",
        "One rotation between each file's joint frames and its own bones (torso, arms to the elbows, legs to the "
        "knees): its angle and axis (the file's frame), the median angle of X off its bone before and after it, and "
        "the median angle of each frame's own best rotation from it:",
        "",
        "| file | rotation, deg | axis | X off the bone, deg: before / after | per frame, deg |",
        "|---|---:|---|---|---:|",
    ]
    for row in offsets["files"]:
        axis = ", ".join(f"{c:+.2f}" for c in row["axis"])
        before, after = row["off_bone_deg"]
        lines.append(
            f"| {row['file']} | {row['angle_deg']:.2f} | ({axis}) | {before:.2f} / {after:.2f} | "
            f"{row['per_frame_deg']:.2f} |"
        )
    lines += [
        "",
        f"`{offsets['mapped']}` holds the subordinate's positions rotated by {offsets['mapped_positions_deg']:.2f} "
        f"deg (a rigid fit) and its orientations unchanged; its rotation above undoes that one to "
        f"{offsets['mapped_undone_deg']:.2f} deg.",
    ]
    return lines


def main(argv: list[str] | None = None) -> int:
    root = Path(__file__).resolve().parents[1]
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", nargs="?", type=Path, default=root.parent / "shared" / "data" / "azure-kinect-andyj1")
    parser.add_argument("--json", action="store_true", help="print the measurements as JSON, stamped")
    args = parser.parse_args(argv)
    args.stamp = (
        RunStamp.begin(sys.argv[1:], program=("python", "scripts/measure_orientation_convention.py"))
        if args.json
        else None
    )
    if not args.data.is_dir():
        print(f"no andyj1 data at {args.data}; pass its folder as the first argument", file=sys.stderr)
        return 2
    result = measure(args.data)
    if args.json:
        print_json(result, args)
    else:
        print(format_markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
