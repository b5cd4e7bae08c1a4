"""The markdown report of ``skelfuse eval real`` (:func:`skelfuse.eval.rig.run_rig_eval`'s result as tables)."""

from __future__ import annotations

import math
from pathlib import Path

from skelfuse.eval.rig import RigEvalResult, finite_median


def _f(value: float, digits: int = 1) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def format_markdown(result: RigEvalResult) -> str:
    """The report as markdown: inputs, how they were matched and calibrated, one table per group."""
    sensors = ", ".join(f"{s} ({result.formats.get(s, '?')})" for s in result.sensors)
    lines = [
        "# Real-data report",
        "",
        f"Sensors: {sensors}; frames matched by {result.time_matching} time; poses: {result.calibration}.",
        f"Instants: {result.n_instants}, evaluated {result.evaluated[0]}..{result.evaluated[1]}.",
        "",
    ]
    lines += [f"- {n}" for n in result.notes]
    if not result.confidence_meaningful:
        lines += [
            "",
            "**Confidence was assumed, not read:** 'agreement' is the distance to every view's joint, not to its "
            "MEDIUM joints only, and leave-one-out uses every joint of the held-out view.",
        ]
    lines += [
        "",
        "Cross-view metrics are lower bounds: errors every view shares are invisible. Definitions and limits: "
        "docs/evaluation.md.",
        "",
    ]
    for group, rows in result.groups.items():
        lines += [
            f"## {group}",
            "",
            "| output | jitter mm/f² | agreement mm (median over views) | lag frames (median) | gross % | dropouts % |",
            "|---|---|---|---|---|---|",
        ]
        for label, row in rows.items():
            lines.append(
                f"| {label} | {_f(row['jitter'])} | {_f(finite_median(row['agreement'].values()))} | "
                f"{_f(finite_median(row['lag'].values()), 0) if row['lag'] else '-'} | {_f(100 * row['gross'])} | "
                f"{_f(100 * row['dropouts']) if math.isfinite(row['dropouts']) else '-'} |"
            )
        lines.append("")
    lines += [
        "## Whole skeleton",
        "",
        "| output | mirrored frames | track ids | pelvis steps > 3 m/s | one-view episodes (instants) |",
        "|---|---|---|---|---|",
    ]
    for label, count in result.mirrored.items():
        breaks = result.continuity.get(label)
        cells = (
            "- | -"
            if breaks is None
            else (f"{breaks['steps']} | {breaks['one_view_episodes']} ({breaks['one_view_frames']})")
        )
        lines.append(f"| {label} | {count} | {result.track_ids.get(label, '-')} | {cells} |")
    lines += _view_mirroring_lines(result)
    if result.orientation_agreement:
        lines += [
            "",
            "## Orientation agreement (median twist about the bone between each view and the fused joint, degrees)",
            "",
            "| preset | group | " + " | ".join(result.sensors) + " |",
            "|---|---|" + "---|" * len(result.sensors),
        ]
        for name, per_group in result.orientation_agreement.items():
            for group, per_view in per_group.items():
                cells = " | ".join(_f(per_view.get(s, math.nan)) for s in result.sensors)
                lines.append(f"| {name} | {group} | {cells} |")
    lines += _orientation_by_joint_lines(result)
    if result.leave_one_out:
        lines += ["", "## Leave-one-out (median distance to the held-out view, mm)", ""]
        for name, per_held in result.leave_one_out.items():
            for held, row in per_held.items():
                cells = ", ".join(f"{k} {_f(v)}" for k, v in row.items())
                lines.append(f"- {name}, held out {held}: {cells}")
    if result.plots:
        lines += ["", "## Plots", ""] + [f"![{Path(p).stem}]({Path(p).name})" for p in result.plots]
    return "\n".join(lines)


def _orientation_by_joint_lines(result: RigEvalResult) -> list[str]:
    """Per preset and aimed joint, the median full angle of the fused orientation to the views (docs/orientations.md
    says how to read it)."""
    lines: list[str] = []
    for name, per_joint in result.orientation_by_joint.items():
        lines += [
            "",
            f"## Orientation per joint, {name} (median angle between the fused and the views' frames, degrees)",
            "",
            "| joint | to the views | " + " | ".join(result.sensors) + " | between the views |",
            "|---|---|" + "---|" * len(result.sensors) + "---|",
        ]
        for joint, row in per_joint.items():
            cells = " | ".join(_f(row.get(s, math.nan)) for s in result.sensors)
            lines.append(f"| {joint} | {_f(row['views'])} | {cells} | {_f(row['between views'])} |")
    return lines


def _view_mirroring_lines(result: RigEvalResult) -> list[str]:
    """Each view's mirrored share (eval/view_mirroring.py): the rig's own rate, to set against the simulator's
    rear-view mirroring sweep."""
    if not result.view_mirroring:
        return []
    lines = [
        "",
        "## Mirrored share per view (this rig's mirroring rate)",
        "",
        "Share of the view's instants that skelfuse's realignment found left/right mirrored, and (3+ views) that "
        "point against the majority of the other views. Set it against the simulator's assumption and the "
        "break-even shares of `skelfuse eval robustness --mirroring-sweep` (docs/simulator.md).",
        "",
        "| view | instants | realigned as mirrored % | against the majority % |",
        "|---|---|---|---|",
    ]
    for view, row in result.view_mirroring.items():
        majority = row.get("against_majority")
        lines.append(
            f"| {view} | {int(row['instants'])} | {_f(100 * row['realigned'])} | "
            f"{'-' if majority is None else _f(100 * majority)} |"
        )
    return lines
