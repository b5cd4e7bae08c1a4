"""Report of ``skelfuse eval paper``: markdown tables, CSV files, bar charts like the paper's Figures 9-11.

Files written into the output folder (``write_suite``):

- ``report.md``: the combined summary of all scenarios (``format_summary``): experiment 1-3 headline tables of
  every scenario beside the paper's figures, then lag, jitter and left/right swaps;
- ``result.json``: ``PaperEvalSuite.to_dict()`` (every scenario's full result);
- ``summary_algorithms.png``, ``summary_n_sensors.png``: experiments 1 and 3 of every scenario, one row of
  panels per scenario;
- ``<scenario>/`` per scenario (``write_report``):

  - ``report.md``: the markdown of ``format_scenario``;
  - ``{experiment}_{protocol}_joints.csv`` and ``{experiment}_{protocol}_groups.csv``: one row per
    configuration, gesture ("all" = mean over gestures) and joint or group, with AE / RMSE / STD and frame
    counts, and whether the row is the paper's algorithm or ours;
  - ``lag.csv``: best lag and jitter per output and group;
  - ``fig09_algorithms.png``, ``fig10_eps.png``, ``fig11_n_sensors.png``: grouped bars per joint group,
    against exact truth, against the best view, and the paper's figure (hatched); our rows on a shaded
    background;
  - ``result.json``: ``PaperEvalResult.to_dict()``.

Rows of the paper's algorithm (A1-A5) and of ours (``skelfuse``) are marked in every table ("by" column,
"(ours)" in labels) and figure.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path

from skelfuse.eval import paper_reference
from skelfuse.eval.paper import (
    EXPERIMENTS,
    GROUP_NAMES,
    PROTOCOLS,
    SCENARIO_DESCRIPTIONS,
    PaperEvalResult,
    PaperEvalSuite,
    is_ours,
)
from skelfuse.eval.report_files import (
    EXPERIMENT_TITLES,
    GROUP_LABELS,
    PROTOCOL_TITLES,
    by_label,
    fmt,
    pct,
    plot_experiment,
    plot_suite,
    row_cell,
    write_csvs,
)
from skelfuse.schema.skeleton import EVAL_JOINT_NAMES


def _dynamics_table(result: PaperEvalResult) -> list[str]:
    """Experiment 1's rows: swapped share, lag and jitter per group (4 sensors, against exact truth)."""

    header = ["config", "by", "swapped"]
    header += [f"{GROUP_LABELS[g]} lag (frames)" for g in GROUP_NAMES]
    header += [f"{GROUP_LABELS[g]} jitter (mm/frame²)" for g in GROUP_NAMES]
    lines = [
        "Dynamics against exact truth (A3-A5: mean over eps): left/right pairs swapped, lag (frames, positive "
        "= late) and jitter (RMS second difference over time, mm/frame²; the exact truth's own jitter is the "
        "motion's real acceleration):",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    for config in result.experiment_configs("algorithms"):
        cells = [row_cell("algorithms", config), by_label("algorithms", config)]
        cells.append(pct(result.row_swapped("algorithms", config)))
        cells += [fmt(result.row_lag("algorithms", config, g), 2) for g in GROUP_NAMES]
        cells += [fmt(result.row_jitter("algorithms", config, g), 2) for g in GROUP_NAMES]
        lines.append("| " + " | ".join(cells) + " |")
    if "exact_truth" in result.jitter:
        cells = ["exact truth", "—", "—"] + ["—"] * len(GROUP_NAMES)
        cells += [fmt(result.jitter["exact_truth"].get(g), 2) for g in GROUP_NAMES]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def format_scenario(result: PaperEvalResult) -> str:
    """The whole report of one scenario as markdown."""
    lines = _intro_lines(result)
    for exp in EXPERIMENTS:
        lines += _experiment_lines(result, exp)
    lines += _per_joint_lines(result) + _dynamics_lines(result) + _orientation_lines(result)
    lines += _simulated_data_lines(result)
    lines += ["## Notes on the paper's figures", ""] + [f"- {o}" for o in paper_reference.ODDITIES] + [""]
    return "\n".join(lines)


def _intro_lines(result: PaperEvalResult) -> list[str]:
    """Title, the takes, the error conventions and how good the best-view reference is."""
    s = result.settings
    scenario = s.get("scenario")
    lines = [
        "# skelfuse eval paper — Lee et al. 2022 re-run on simulated data"
        + (f' — scenario "{scenario}"' if scenario else ""),
        "",
    ]
    if scenario:
        lines += [f'Scenario "{scenario}": {s.get("scenario_description", "")}.', ""]
    lines += [
        f"{s['n_takes']} takes: gestures {', '.join(s['gestures'])}; "
        f"facing {', '.join(f'{d:.0f}°' for d in s['directions_deg'])}; "
        f"{s['duration_s']:.0f} s at {s['fps']:.0f} Hz each; seed {s['seed']}"
        + ("; quick mode" if s["quick"] else "")
        + f". Run time {result.elapsed_s:.0f} s.",
        "",
        "Errors are Euclidean joint distances in mm. Per joint, frames of one gesture are pooled over the "
        "directions; AE = mean distance, RMSE = root mean square distance, STD = standard deviation of the "
        "distance; values are then averaged over gestures, and a group is the mean of its joints (the "
        "paper's convention). Two references: the simulator's **exact truth**, and the **best-view** "
        "sensor's skeleton (a fifth simulated sensor in front of the subject, the paper's \"ground truth\"). "
        "The paper's text calls "
        'its group figures "AE" but they are means of its Appendix RMSEs, so they sit next to our RMSE. '
        f"Paper: {paper_reference.CITATION}. Rows A1-A5 are the paper's algorithm; rows marked **ours** are "
        "skelfuse's own algorithm (not in the paper).",
        "",
    ]
    best = result.group_stats_key("best_view_raw", "truth") if "best_view_raw" in result.stats else None
    if best is not None:
        lines += [
            "How good is the paper's reference? The best-view skeleton against exact truth, RMSE ± STD: "
            + ", ".join(
                f"{GROUP_LABELS[g]} {fmt(best[g]['rmse_mm'])} ± {fmt(best[g]['std_mm'])} mm" for g in GROUP_NAMES
            )
            + ".",
            "",
        ]
    return lines


def _experiment_lines(result: PaperEvalResult, exp: str) -> list[str]:
    """One experiment: beside the paper's figures, then AE / RMSE / STD per protocol."""
    lines: list[str] = []
    configs = result.experiment_configs(exp)
    lines += [f"## {EXPERIMENT_TITLES[exp]}", ""]
    # Comparison with the paper: RMSE ± STD for both protocols and the paper's figure.
    header = ["config", "by"] + [
        f"{GROUP_LABELS[g]}: {col}" for g in GROUP_NAMES for col in ("truth", "best view", "paper")
    ]
    lines += [
        "RMSE ± STD (mm) against exact truth, against the best view, and the paper's figure:",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    for config in configs:
        t = result.group_stats(exp, config, "truth")
        b = result.group_stats(exp, config, "best_view")
        cells = [row_cell(exp, config), by_label(exp, config)]
        for g in GROUP_NAMES:
            pa, ps = (
                result.paper_value(exp, config, "ae_mm", g),
                result.paper_value(exp, config, "std_mm", g),
            )
            cells += [
                f"{fmt(t[g]['rmse_mm'])} ± {fmt(t[g]['std_mm'])}",
                f"{fmt(b[g]['rmse_mm'])} ± {fmt(b[g]['std_mm'])}",
                "—" if pa is None else f"{fmt(pa)} ± {fmt(ps)}",
            ]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    for protocol in PROTOCOLS:
        header = ["config", "by"] + [f"{GROUP_LABELS[g]} {m}" for g in GROUP_NAMES for m in ("AE", "RMSE", "STD")]
        header += ["NaN joint-frames"]
        lines += [
            f"AE / RMSE / STD (mm) against the {PROTOCOL_TITLES[protocol]}:",
            "",
            "| " + " | ".join(header) + " |",
            "|" + "---|" * len(header),
        ]
        for config in configs:
            gs = result.group_stats(exp, config, protocol)
            cells = [row_cell(exp, config), by_label(exp, config)]
            for g in GROUP_NAMES:
                cells += [fmt(gs[g]["ae_mm"]), fmt(gs[g]["rmse_mm"]), fmt(gs[g]["std_mm"])]
            missing = sum(gs[g]["n_missing"] for g in GROUP_NAMES)
            total = missing + sum(gs[g]["n_frames"] for g in GROUP_NAMES)
            cells.append(f"{missing} / {total}")
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    if exp == "algorithms":
        lines += [*_dynamics_table(result), ""]
    return lines


def _per_joint_lines(result: PaperEvalResult) -> list[str]:
    """Experiment 1 per joint, RMSE against exact truth."""
    lines: list[str] = []
    configs = result.experiment_configs("algorithms")
    lines += [
        "## Per joint — experiment 1, RMSE (mm) against exact truth",
        "",
        "| joint | " + " | ".join(row_cell("algorithms", c) for c in configs) + " |",
        "|---|" + "---|" * len(configs),
    ]
    per_config = {c: result.joint_stats("algorithms", c, "truth") for c in configs}
    for k, name in enumerate(EVAL_JOINT_NAMES):
        lines.append(f"| {name} | " + " | ".join(fmt(float(per_config[c].rmse_mm[k])) for c in configs) + " |")
    lines.append("")
    return lines


def _dynamics_lines(result: PaperEvalResult) -> list[str]:
    """Lag, jitter and left/right swaps of every output against exact truth."""
    lines: list[str] = []
    lag_keys = [
        k
        for k in (
            "A1",
            "A2",
            *[f"A{n}_{int(e)}" for n in (3, 4, 5) for e in result.eps_values],
            *result.ours,
            *[f"raw[{i}]" for i in range(4)],
            "best_view_raw",
        )
        if k in result.lag
    ]
    lines += [
        "## Lag, jitter and left/right swaps per output, against exact truth",
        "",
        "Lag: the shift in frames that best aligns the output with the truth (positive = late). Jitter: RMS "
        "second difference over time, mm/frame² (the exact truth's own value is the motion's acceleration). "
        "Swapped: share of frames x limb pairs (shoulders, elbows, wrists, hips, knees, ankles) whose left and "
        "right are the wrong way round.",
        "",
        "| output | swapped | "
        + " | ".join(
            f"{GROUP_LABELS[g]} lag | {GROUP_LABELS[g]} error at lag (mm) | {GROUP_LABELS[g]} jitter"
            for g in GROUP_NAMES
        )
        + " |",
        "|---|---|" + "---|---|---|" * len(GROUP_NAMES),
    ]
    for key in lag_keys:
        frac = result.swapped.get(key)
        cells = [f"**{key} (ours)**" if is_ours(key) else key, pct(frac)]
        for g in GROUP_NAMES:
            entry = result.lag[key].get(g, {})
            cells += [
                fmt(entry.get("lag_frames"), 2),
                fmt(entry.get("error_mm")),
                fmt(result.jitter.get(key, {}).get(g), 2),
            ]
        lines.append("| " + " | ".join(cells) + " |")
    if "exact_truth" in result.jitter:
        cells = ["exact truth", "—"]
        for g in GROUP_NAMES:
            cells += ["—", "—", fmt(result.jitter["exact_truth"].get(g), 2)]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    return lines


def _orientation_lines(result: PaperEvalResult) -> list[str]:
    """Angular error of the fused orientations (outputs that compute them) and of the raw views, against the
    simulator's true orientations."""
    if not result.orientation:
        return []
    keys = [k for k in (*result.ours, *[f"raw[{i}]" for i in range(4)], "best_view_raw") if k in result.orientation]
    lines = [
        "## Fused orientations, against the true orientations",
        "",
        "Angle of the rotation between each joint's orientation and the truth, degrees (median / p90 over all "
        "frames and joints of the group, all takes). Truth: the motion's bones in the k4abt joint-frame "
        "convention plus a simulated roll of the arm and hand bones; the views: truth seen through a simulated "
        "tracker orientation error (sim/orientation.py, a model set from one real take, not a measurement of "
        "the tracker); a mirrored view's frames face the other way (about 180 deg). docs/orientations.md.",
        "",
        "| output | " + " | ".join(f"{GROUP_LABELS[g]} median / p90 (deg)" for g in GROUP_NAMES) + " |",
        "|---|" + "---|" * len(GROUP_NAMES),
    ]
    for key in keys:
        by_group = result.orientation[key]
        cells = [f"**{key} (ours)**" if is_ours(key) else key]
        for g in GROUP_NAMES:
            entry = by_group.get(g, {})
            cells.append(f"{fmt(entry.get('median_deg'))} / {fmt(entry.get('p90_deg'))}")
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    return lines


def _simulated_data_lines(result: PaperEvalResult) -> list[str]:
    """How often each simulated sensor tracked and mirrored the person."""
    lines: list[str] = []
    mirrored = [t["mirrored_fraction"] for t in result.takes]
    tracked = [t["tracked_fraction"] for t in result.takes]
    if mirrored:
        n_sensors = len(mirrored[0])
        names = [f"sensor {i}" for i in range(n_sensors - 1)] + ["best view"]
        lines += [
            "## Simulated data",
            "",
            "Mean fraction of frames per sensor (over takes): tracked "
            + ", ".join(f"{names[i]} {sum(t[i] for t in tracked) / len(tracked):.2f}" for i in range(n_sensors))
            + "; mirrored (left/right swapped) "
            + ", ".join(f"{names[i]} {sum(m[i] for m in mirrored) / len(mirrored):.2f}" for i in range(n_sensors))
            + ".",
            "",
        ]
    return lines


def write_report(result: PaperEvalResult, out_dir: Path) -> list[Path]:
    """Write report.md, the CSV tables, the figures and result.json into ``out_dir``; returns the paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = write_csvs(result, out_dir)
    paths.append(
        plot_experiment(
            result, "algorithms", out_dir / "fig09_algorithms.png", "Algorithms, 4 sensors (paper Figure 9)"
        )
    )
    paths.append(
        plot_experiment(
            result,
            "eps_sweep",
            out_dir / "fig10_eps.png",
            f"DBSCAN radius, {paper_reference.EPS_SWEEP_PRESET} (paper Figure 10)",
        )
    )
    paths.append(
        plot_experiment(
            result,
            "n_sensors",
            out_dir / "fig11_n_sensors.png",
            "Number of sensors, A5 eps 100 mm and ours (paper Figure 11)",
        )
    )
    md_path = out_dir / "report.md"
    json_path = out_dir / "result.json"
    paths += [md_path, json_path]
    result.files = [str(p) for p in paths]
    md_path.write_text(format_scenario(result))
    json_path.write_text(json.dumps(result.to_dict(), indent=1, allow_nan=False))
    return paths


# ----------------------------------------------------------------------------------------------------
# The combined summary of all scenarios.


def _triple(result: PaperEvalResult, experiment: str, config: str, protocol: str) -> str:
    """RMSE of a row as "torso / upper / lower", or "—" where the scenario lacks the row."""

    if config not in result.experiment_configs(experiment):
        return "—"
    gs = result.group_stats(experiment, config, protocol)
    return " / ".join(fmt(gs[g]["rmse_mm"], 0) for g in GROUP_NAMES)


def _paper_triple(result: PaperEvalResult, experiment: str, config: str) -> str:

    values = [result.paper_value(experiment, config, "ae_mm", g) for g in GROUP_NAMES]
    return "—" if all(v is None for v in values) else " / ".join(fmt(v, 0) for v in values)


def format_summary(suite: PaperEvalSuite) -> str:
    """The combined summary of every scenario as markdown (the text of ``out_dir/report.md``)."""
    results = suite.scenarios
    first = results[next(iter(results))]
    lines = _summary_intro(suite)
    lines += _experiment_table(
        results,
        "algorithms",
        first.experiment_configs("algorithms"),
        "Experiment 1 — algorithms, 4 sensors (A3-A5: mean over eps 50-200 mm; paper Figure 9)",
    )
    lines += _experiment_table(
        results,
        "eps_sweep",
        [c for c in first.experiment_configs("eps_sweep") if c.startswith(paper_reference.EPS_SWEEP_PRESET + "_")],
        f"Experiment 2 — DBSCAN radius, {paper_reference.EPS_SWEEP_PRESET} (paper Figure 10)",
    )
    lines += _experiment_table(
        results,
        "n_sensors",
        first.experiment_configs("n_sensors"),
        "Experiment 3 — number of sensors (A5 eps 100 mm and ours; mean over all combinations; paper Figure 11)",
    )
    lines += _lag_jitter_swaps(results)
    lines += _reference_quality(results)
    lines += _orientation_table(results)
    lines += ["## Notes on the paper's figures", ""] + [f"- {o}" for o in paper_reference.ODDITIES] + [""]
    return "\n".join(lines)


def _summary_intro(suite: PaperEvalSuite) -> list[str]:
    """The run's settings, the scenarios with their mirrored share, and how to read the tables."""
    s = suite.settings
    results = suite.scenarios
    names = list(results)
    lines = [
        "# skelfuse eval paper — Lee et al. 2022 re-run on simulated data: summary",
        "",
        f"{len(names)} scenario(s) x {s['n_takes']} takes: gestures {', '.join(s['gestures'])}; facing "
        f"{', '.join(f'{d:.0f}°' for d in s['directions_deg'])}; {s['duration_s']:.1f} s at {s['fps']:.0f} Hz "
        f"each; seed {s['seed']}; {s['workers']} worker(s)"
        + ("; quick mode" if s["quick"] else "")
        + f". Run time {suite.elapsed_s:.0f} s. Paper: {paper_reference.CITATION}.",
        "",
        "Scenarios (same per-take seeds in each):",
        "",
    ]
    for name in names:
        takes = results[name].takes
        mirrored = (
            sum(sum(t["mirrored_fraction"][:-1]) / (len(t["mirrored_fraction"]) - 1) for t in takes) / len(takes)
            if takes
            else float("nan")
        )
        lines.append(
            f"- **{name}**: {SCENARIO_DESCRIPTIONS.get(name, '')}. Capture views mirrored: "
            f"{pct(mirrored)} of frames. Details: [{name}/report.md]({name}/report.md)."
        )
    lines += [
        "",
        "Cells are RMSE in mm, **torso / upper limb / lower limb**, per joint then averaged over the group's "
        "joints and the gestures, against the simulator's **exact truth** or against the **best-view** sensor's "
        'skeleton (the paper\'s protocol: its "ground truth" was a fifth Kinect in front of the subject). The '
        "paper's figure is against its best view, so compare it with the best-view columns. Rows A1-A5 are the "
        "paper's algorithm; rows marked **ours** are skelfuse's own (not in the paper).",
        "",
    ]

    return lines


def _experiment_table(
    results: Mapping[str, PaperEvalResult], experiment: str, configs: list[str], title: str
) -> list[str]:
    """One experiment's RMSE table: per config, each scenario against truth and best view, and the paper's."""
    names = list(results)
    first = results[names[0]]
    header = ["config", "by"]
    for name in names:
        header += [f"{name}: vs truth", f"{name}: vs best view"]
    header.append("paper's figure")
    out = [f"## {title}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for config in configs:
        cells = [row_cell(experiment, config), by_label(experiment, config)]
        for name in names:
            cells += [
                _triple(results[name], experiment, config, "truth"),
                _triple(results[name], experiment, config, "best_view"),
            ]
        cells.append(_paper_triple(first, experiment, config))
        out.append("| " + " | ".join(cells) + " |")
    return [*out, ""]


def _lag_jitter_swaps(results: Mapping[str, PaperEvalResult]) -> list[str]:
    """Experiment 1's lag, jitter and left/right swaps per config, then the raw views and the truth."""
    names = list(results)
    first = results[names[0]]
    lines: list[str] = []
    lines += [
        "## Lag, jitter and left/right swaps — experiment 1, 4 sensors, against exact truth",
        "",
        "Swapped: share of frames x limb pairs (shoulders, elbows, wrists, hips, knees, ankles) whose left and "
        "right are the wrong way round. Lag: frames, positive = late. Jitter: RMS second difference over time, "
        "mm/frame² (the exact truth's own jitter is the motion's real acceleration; white noise of s mm per "
        "axis adds about 4.2 s). Cells are torso / upper limb / lower limb; A3-A5 are means over eps.",
        "",
    ]
    header = ["config", "by"]
    for name in names:
        header += [f"{name}: swapped", f"{name}: lag", f"{name}: jitter"]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for config in first.experiment_configs("algorithms"):
        cells = [row_cell("algorithms", config), by_label("algorithms", config)]
        for name in names:
            r = results[name]
            if config not in r.experiment_configs("algorithms"):
                cells += ["—"] * 3
                continue
            cells += [
                pct(r.row_swapped("algorithms", config)),
                " / ".join(fmt(r.row_lag("algorithms", config, g), 1) for g in GROUP_NAMES),
                " / ".join(fmt(r.row_jitter("algorithms", config, g), 1) for g in GROUP_NAMES),
            ]
        lines.append("| " + " | ".join(cells) + " |")
    for label, key in (("1 sensor (raw, mean)", "raw"), ("exact truth", "exact_truth")):
        cells = [label, "raw" if key == "raw" else "—"]
        for name in names:
            r = results[name]
            if key == "raw":
                raw = [f"raw[{i}]" for i in range(len(r.takes[0]["tracked_fraction"]) - 1)] if r.takes else []
                swapped = [r.swapped[k] for k in raw if k in r.swapped]
                cells += [
                    pct(sum(swapped) / len(swapped) if swapped else None),
                    " / ".join(
                        fmt(_mean([r.lag[k][g]["lag_frames"] for k in raw if k in r.lag]), 1) for g in GROUP_NAMES
                    ),
                    " / ".join(fmt(_mean([r.jitter[k][g] for k in raw if k in r.jitter]), 1) for g in GROUP_NAMES),
                ]
            else:
                cells += ["—", "—", " / ".join(fmt(r.jitter.get(key, {}).get(g), 1) for g in GROUP_NAMES)]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")

    return lines


def _reference_quality(results: Mapping[str, PaperEvalResult]) -> list[str]:
    """How far the paper's reference (the best view) is from the exact truth, per scenario."""
    names = list(results)
    lines: list[str] = []
    lines += ["## How good is the paper's reference?", ""]
    for name in names:
        r = results[name]
        if "best_view_raw" in r.stats:
            best = r.group_stats_key("best_view_raw", "truth")
            lines.append(
                f"- {name}: the best-view skeleton against exact truth, RMSE "
                + " / ".join(fmt(best[g]["rmse_mm"], 0) for g in GROUP_NAMES)
                + " mm (torso / upper / lower)."
            )
    lines += [""]
    return lines


def _orientation_table(results: Mapping[str, PaperEvalResult]) -> list[str]:
    """Fused orientations against the truth beside the best raw view (where a scenario has orientations)."""
    names = list(results)
    lines: list[str] = []
    oriented = [(name, key) for name in names for key in results[name].ours if key in results[name].orientation]
    if oriented:
        lines += [
            "## Fused orientations against the true orientations (ours, 4 sensors)",
            "",
            "Degrees, median / p90, torso / upper limb / lower limb; the best single capture view beside it "
            "(the view with the lowest median). Simulated tracker orientation noise: a model, see each "
            "scenario's report and docs/orientations.md.",
            "",
            "| scenario | output | fused | best raw view |",
            "|---|---|---|---|",
        ]
        for name, key in oriented:
            r = results[name]
            raw = [k for k in (f"raw[{i}]" for i in range(4)) if k in r.orientation]
            best_view = min(
                raw, key=lambda k: _mean([r.orientation[k][g]["median_deg"] for g in GROUP_NAMES]), default=None
            )

            fused_cell = _orientation_cell(r, key)
            best_cell = f"{_orientation_cell(r, best_view)} [{best_view}]" if best_view else "—"
            lines.append(f"| {name} | {key} | {fused_cell} | {best_cell} |")
        lines += [""]
    return lines


def _orientation_cell(result: PaperEvalResult, key: str) -> str:
    """ "median (p90)" of each group of one output's angular errors, degrees."""
    entry = result.orientation[key]
    return " / ".join(f"{fmt(entry[g]['median_deg'])} ({fmt(entry[g]['p90_deg'])})" for g in GROUP_NAMES)


def _mean(values: list[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return sum(finite) / len(finite) if finite else float("nan")


def format_markdown(result: PaperEvalResult | PaperEvalSuite) -> str:
    """The report as markdown: the combined summary of a ``PaperEvalSuite`` (the text of ``out_dir/report.md``)
    or the full report of one scenario's ``PaperEvalResult`` (``out_dir/<scenario>/report.md``)."""
    if isinstance(result, PaperEvalSuite):
        return format_summary(result)
    return format_scenario(result)


def write_suite(suite: PaperEvalSuite, out_dir: Path) -> list[Path]:
    """Write every scenario's report into ``out_dir/<scenario>/`` and the combined summary (report.md,
    result.json, summary figures) into ``out_dir``; returns the paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths: list[Path] = []
    for name, result in suite.scenarios.items():
        paths += write_report(result, out_dir / name)
    paths.append(
        plot_suite(suite, "algorithms", out_dir / "summary_algorithms.png", "Algorithms, 4 sensors (paper Figure 9)")
    )
    paths.append(
        plot_suite(
            suite, "n_sensors", out_dir / "summary_n_sensors.png", "Number of sensors, A5 and ours (paper Figure 11)"
        )
    )
    md_path = out_dir / "report.md"
    json_path = out_dir / "result.json"
    paths += [md_path, json_path]
    suite.files = [str(p) for p in paths]
    md_path.write_text(format_summary(suite))
    json_path.write_text(json.dumps(suite.to_dict(), indent=1, allow_nan=False))
    return paths
