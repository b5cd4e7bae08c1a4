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

import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

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
from skelfuse.schema.skeleton import EVAL_JOINT_NAMES

GROUP_LABELS = {"torso": "torso", "upper_limb": "upper limb", "lower_limb": "lower limb"}
EXPERIMENT_TITLES = {
    "algorithms": "Experiment 1 — algorithms (4 sensors; A3-A5 = mean over eps, as the paper's Figure 9)",
    "eps_sweep": "Experiment 2 — DBSCAN radius eps (4 sensors; paper Figure 10 has A5 only)",
    "n_sensors": "Experiment 3 — number of sensors (A5, eps 100 mm; 1 = raw; mean over all combinations)",
}
PROTOCOL_TITLES = {"truth": "exact ground truth", "best_view": "best-view sensor (the paper's protocol)"}


def _f(value: float | None, digits: int = 1) -> str:
    if value is None or not math.isfinite(value):
        return "—"
    return f"{value:.{digits}f}"


def _by(experiment: str, config: str) -> str:
    """Who the row's algorithm is: the paper's, ours, or raw sensor data."""
    if experiment == "n_sensors" and config == "1":
        return "raw"
    return "**ours**" if is_ours(config) else "paper"


def _row_label(experiment: str, config: str) -> str:
    if experiment == "n_sensors":
        algorithm, _, n = config.rpartition("_")
        plural = "s" if n != "1" else ""
        if n == "1":
            return "1 sensor (raw)"
        return f"{n} sensor{plural}, " + (f"{algorithm} (ours)" if algorithm else "A5")
    if experiment == "eps_sweep":
        name, eps = config.split("_")
        return f"{name} eps {eps} mm"
    return f"{config} (ours)" if is_ours(config) else config


def _row_cell(experiment: str, config: str) -> str:
    """Row label for markdown: our rows in bold."""
    label = _row_label(experiment, config)
    return f"**{label}**" if is_ours(config) else label


def _pct(frac: float | None) -> str:
    return "—" if frac is None or not math.isfinite(frac) else f"{100 * frac:.1f}%"


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
        cells = [_row_cell("algorithms", config), _by("algorithms", config)]
        cells.append(_pct(result.row_swapped("algorithms", config)))
        cells += [_f(result.row_lag("algorithms", config, g), 2) for g in GROUP_NAMES]
        cells += [_f(result.row_jitter("algorithms", config, g), 2) for g in GROUP_NAMES]
        lines.append("| " + " | ".join(cells) + " |")
    if "exact_truth" in result.jitter:
        cells = ["exact truth", "—", "—"] + ["—"] * len(GROUP_NAMES)
        cells += [_f(result.jitter["exact_truth"].get(g), 2) for g in GROUP_NAMES]
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
            + ", ".join(f"{GROUP_LABELS[g]} {_f(best[g]['rmse_mm'])} ± {_f(best[g]['std_mm'])} mm" for g in GROUP_NAMES)
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
        cells = [_row_cell(exp, config), _by(exp, config)]
        for g in GROUP_NAMES:
            pa, ps = (
                result.paper_value(exp, config, "ae_mm", g),
                result.paper_value(exp, config, "std_mm", g),
            )
            cells += [
                f"{_f(t[g]['rmse_mm'])} ± {_f(t[g]['std_mm'])}",
                f"{_f(b[g]['rmse_mm'])} ± {_f(b[g]['std_mm'])}",
                "—" if pa is None else f"{_f(pa)} ± {_f(ps)}",
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
            cells = [_row_cell(exp, config), _by(exp, config)]
            for g in GROUP_NAMES:
                cells += [_f(gs[g]["ae_mm"]), _f(gs[g]["rmse_mm"]), _f(gs[g]["std_mm"])]
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
        "| joint | " + " | ".join(_row_cell("algorithms", c) for c in configs) + " |",
        "|---|" + "---|" * len(configs),
    ]
    per_config = {c: result.joint_stats("algorithms", c, "truth") for c in configs}
    for k, name in enumerate(EVAL_JOINT_NAMES):
        lines.append(f"| {name} | " + " | ".join(_f(float(per_config[c].rmse_mm[k])) for c in configs) + " |")
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
        cells = [f"**{key} (ours)**" if is_ours(key) else key, _pct(frac)]
        for g in GROUP_NAMES:
            entry = result.lag[key].get(g, {})
            cells += [
                _f(entry.get("lag_frames"), 2),
                _f(entry.get("error_mm")),
                _f(result.jitter.get(key, {}).get(g), 2),
            ]
        lines.append("| " + " | ".join(cells) + " |")
    if "exact_truth" in result.jitter:
        cells = ["exact truth", "—"]
        for g in GROUP_NAMES:
            cells += ["—", "—", _f(result.jitter["exact_truth"].get(g), 2)]
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
            cells.append(f"{_f(entry.get('median_deg'))} / {_f(entry.get('p90_deg'))}")
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


# ----------------------------------------------------------------------------------------------------
# Files.


def _write_csvs(result: PaperEvalResult, out_dir: Path) -> list[Path]:

    paths: list[Path] = []
    gestures = ["all", *result.gestures]
    for exp in EXPERIMENTS:
        for protocol in PROTOCOLS:
            jpath = out_dir / f"{exp}_{protocol}_joints.csv"
            gpath = out_dir / f"{exp}_{protocol}_groups.csv"
            with jpath.open("w", newline="") as jf, gpath.open("w", newline="") as gf:
                jw, gw = csv.writer(jf), csv.writer(gf)
                jw.writerow(
                    [
                        "config",
                        "gesture",
                        "joint",
                        "ae_mm",
                        "rmse_mm",
                        "std_mm",
                        "n_frames",
                        "n_missing",
                        "n_ref_missing",
                        "algorithm",
                    ]
                )
                gw.writerow(
                    [
                        "config",
                        "gesture",
                        "group",
                        "ae_mm",
                        "rmse_mm",
                        "std_mm",
                        "n_frames",
                        "n_missing",
                        "paper_ae_mm",
                        "paper_std_mm",
                        "algorithm",
                    ]
                )
                for config in result.experiment_configs(exp):
                    by = _by(exp, config).strip("*")
                    for gesture in gestures:
                        s = result.joint_stats(exp, config, protocol, gesture)
                        for k, name in enumerate(EVAL_JOINT_NAMES):
                            jw.writerow(
                                [
                                    config,
                                    gesture,
                                    name,
                                    _c(s.ae_mm[k]),
                                    _c(s.rmse_mm[k]),
                                    _c(s.std_mm[k]),
                                    int(s.n_frames[k]),
                                    int(s.n_missing[k]),
                                    int(s.n_ref_missing[k]),
                                    by,
                                ]
                            )
                        gs = result.group_stats(exp, config, protocol, gesture)
                        for g in GROUP_NAMES:
                            paper = [
                                result.paper_value(exp, config, m, g) if gesture == "all" else None
                                for m in ("ae_mm", "std_mm")
                            ]
                            gw.writerow(
                                [
                                    config,
                                    gesture,
                                    g,
                                    _c(gs[g]["ae_mm"]),
                                    _c(gs[g]["rmse_mm"]),
                                    _c(gs[g]["std_mm"]),
                                    gs[g]["n_frames"],
                                    gs[g]["n_missing"],
                                    *("" if p is None else p for p in paper),
                                    by,
                                ]
                            )
            paths += [jpath, gpath]
    lag_path = out_dir / "lag.csv"
    with lag_path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["output", "group", "lag_frames", "error_mm", "jitter_mm_per_frame2", "algorithm"])
        for key, by_group in result.lag.items():
            by = "ours" if is_ours(key) else ("raw" if "raw" in key else "paper")
            for g, entry in by_group.items():
                jitter = result.jitter.get(key, {}).get(g, float("nan"))
                w.writerow([key, g, _c(entry["lag_frames"], 3), _c(entry["error_mm"]), _c(jitter, 3), by])
        for g, jitter in result.jitter.get("exact_truth", {}).items():
            w.writerow(["exact_truth", g, "", "", _c(jitter, 3), "truth"])
    paths.append(lag_path)
    return paths


def _c(value: float, digits: int = 2) -> str:
    value = float(value)
    return f"{value:.{digits}f}" if math.isfinite(value) else "nan"


def _plot_axes(axes: Any, result: PaperEvalResult, experiment: str, *, legend: bool = True) -> None:
    """Grouped bars of one experiment into one axis per joint group; our rows on a shaded background."""
    configs = result.experiment_configs(experiment)
    if experiment == "eps_sweep":
        configs = [c for c in configs if c.startswith(paper_reference.EPS_SWEEP_PRESET + "_")]
    series = [
        ("vs exact truth", "truth", "#1f77b4", None),
        ("vs best view", "best_view", "#ff7f0e", None),
        ("paper's figure (vs best view)", "paper", "#ffffff", "///"),
    ]
    x = np.arange(len(configs))
    width = 0.8 / len(series)
    for ax, group in zip(axes, GROUP_NAMES, strict=True):
        for k, config in enumerate(configs):
            if is_ours(config):
                ax.axvspan(k - 0.5, k + 0.5, color="#2ca02c", alpha=0.12, linewidth=0)
        for i, (label, source, color, hatch) in enumerate(series):
            if source == "paper":
                vals = [result.paper_value(experiment, c, "ae_mm", group) for c in configs]
                errs = [result.paper_value(experiment, c, "std_mm", group) for c in configs]
            else:
                gs = [result.group_stats(experiment, c, source)[group] for c in configs]
                vals = [g["rmse_mm"] for g in gs]
                errs = [g["std_mm"] for g in gs]
            vals_arr = np.array([np.nan if v is None else v for v in vals], dtype=float)
            errs_arr = np.array([np.nan if v is None else v for v in errs], dtype=float)
            ax.bar(
                x + (i - (len(series) - 1) / 2) * width,
                np.nan_to_num(vals_arr),
                width,
                yerr=np.where(np.isfinite(vals_arr), np.nan_to_num(errs_arr), 0.0),
                capsize=2,
                label=label,
                color=color,
                edgecolor="black",
                hatch=hatch,
                linewidth=0.6,
            )
        labels = [_row_label(experiment, c).replace(" (ours)", "\n(ours)") for c in configs]
        ax.set_xticks(
            x, labels, rotation=30 if len(configs) > 5 else 0, fontsize=7, ha="right" if len(configs) > 5 else "center"
        )
        for tick, config in zip(ax.get_xticklabels(), configs, strict=True):
            if is_ours(config):
                tick.set_fontweight("bold")
                tick.set_color("#1a6b1a")
        ax.set_title(GROUP_LABELS[group])
        ax.set_ylabel("RMSE ± STD (mm)")
        ax.grid(axis="y", alpha=0.3)
    if legend:
        axes[0].legend(fontsize=7)


def _plot(result: PaperEvalResult, experiment: str, path: Path, title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(GROUP_NAMES), figsize=(4.6 * len(GROUP_NAMES), 4.4), sharey=False)
    _plot_axes(axes, result, experiment)
    fig.suptitle(title + _OURS_NOTE, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


_OURS_NOTE = "\nA1-A5: the paper's algorithm; shaded, bold: ours (skelfuse)"


def _plot_suite(suite: PaperEvalSuite, experiment: str, path: Path, title: str) -> Path:
    """One row of panels per scenario."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(suite.scenarios)
    fig, axes = plt.subplots(n, len(GROUP_NAMES), figsize=(4.6 * len(GROUP_NAMES), 4.2 * n), squeeze=False)
    for row, (name, result) in enumerate(suite.scenarios.items()):
        _plot_axes(axes[row], result, experiment, legend=row == 0)
        axes[row][0].set_ylabel(f'scenario "{name}"\nRMSE ± STD (mm)')
    fig.suptitle(title + _OURS_NOTE, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def write_report(result: PaperEvalResult, out_dir: Path) -> list[Path]:
    """Write report.md, the CSV tables, the figures and result.json into ``out_dir``; returns the paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = _write_csvs(result, out_dir)
    paths.append(
        _plot(result, "algorithms", out_dir / "fig09_algorithms.png", "Algorithms, 4 sensors (paper Figure 9)")
    )
    paths.append(
        _plot(
            result,
            "eps_sweep",
            out_dir / "fig10_eps.png",
            f"DBSCAN radius, {paper_reference.EPS_SWEEP_PRESET} (paper Figure 10)",
        )
    )
    paths.append(
        _plot(
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
    return " / ".join(_f(gs[g]["rmse_mm"], 0) for g in GROUP_NAMES)


def _paper_triple(result: PaperEvalResult, experiment: str, config: str) -> str:

    values = [result.paper_value(experiment, config, "ae_mm", g) for g in GROUP_NAMES]
    return "—" if all(v is None for v in values) else " / ".join(_f(v, 0) for v in values)


def format_summary(suite: PaperEvalSuite) -> str:
    """The combined summary of every scenario as markdown (the text of ``out_dir/report.md``)."""

    s = suite.settings
    results = suite.scenarios
    names = list(results)
    first = results[names[0]]
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
            f"{_pct(mirrored)} of frames. Details: [{name}/report.md]({name}/report.md)."
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

    def table(experiment: str, configs: list[str], title: str) -> list[str]:
        header = ["config", "by"]
        for name in names:
            header += [f"{name}: vs truth", f"{name}: vs best view"]
        header.append("paper's figure")
        out = [f"## {title}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for config in configs:
            cells = [_row_cell(experiment, config), _by(experiment, config)]
            for name in names:
                cells += [
                    _triple(results[name], experiment, config, "truth"),
                    _triple(results[name], experiment, config, "best_view"),
                ]
            cells.append(_paper_triple(first, experiment, config))
            out.append("| " + " | ".join(cells) + " |")
        return [*out, ""]

    lines += table(
        "algorithms",
        first.experiment_configs("algorithms"),
        "Experiment 1 — algorithms, 4 sensors (A3-A5: mean over eps 50-200 mm; paper Figure 9)",
    )
    lines += table(
        "eps_sweep",
        [c for c in first.experiment_configs("eps_sweep") if c.startswith(paper_reference.EPS_SWEEP_PRESET + "_")],
        f"Experiment 2 — DBSCAN radius, {paper_reference.EPS_SWEEP_PRESET} (paper Figure 10)",
    )
    lines += table(
        "n_sensors",
        first.experiment_configs("n_sensors"),
        "Experiment 3 — number of sensors (A5 eps 100 mm and ours; mean over all combinations; paper Figure 11)",
    )

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
        cells = [_row_cell("algorithms", config), _by("algorithms", config)]
        for name in names:
            r = results[name]
            if config not in r.experiment_configs("algorithms"):
                cells += ["—"] * 3
                continue
            cells += [
                _pct(r.row_swapped("algorithms", config)),
                " / ".join(_f(r.row_lag("algorithms", config, g), 1) for g in GROUP_NAMES),
                " / ".join(_f(r.row_jitter("algorithms", config, g), 1) for g in GROUP_NAMES),
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
                    _pct(sum(swapped) / len(swapped) if swapped else None),
                    " / ".join(
                        _f(_mean([r.lag[k][g]["lag_frames"] for k in raw if k in r.lag]), 1) for g in GROUP_NAMES
                    ),
                    " / ".join(_f(_mean([r.jitter[k][g] for k in raw if k in r.jitter]), 1) for g in GROUP_NAMES),
                ]
            else:
                cells += ["—", "—", " / ".join(_f(r.jitter.get(key, {}).get(g), 1) for g in GROUP_NAMES)]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")

    lines += ["## How good is the paper's reference?", ""]
    for name in names:
        r = results[name]
        if "best_view_raw" in r.stats:
            best = r.group_stats_key("best_view_raw", "truth")
            lines.append(
                f"- {name}: the best-view skeleton against exact truth, RMSE "
                + " / ".join(_f(best[g]["rmse_mm"], 0) for g in GROUP_NAMES)
                + " mm (torso / upper / lower)."
            )
    lines += [""]
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
            best = min(raw, key=lambda k: _mean([r.orientation[k][g]["median_deg"] for g in GROUP_NAMES]), default=None)

            fused_cell = _orientation_cell(r, key)
            best_cell = f"{_orientation_cell(r, best)} [{best}]" if best else "—"
            lines.append(f"| {name} | {key} | {fused_cell} | {best_cell} |")
        lines += [""]
    lines += ["## Notes on the paper's figures", ""] + [f"- {o}" for o in paper_reference.ODDITIES] + [""]
    return "\n".join(lines)


def _orientation_cell(result: PaperEvalResult, key: str) -> str:
    """ "median (p90)" of each group of one output's angular errors, degrees."""
    entry = result.orientation[key]
    return " / ".join(f"{_f(entry[g]['median_deg'])} ({_f(entry[g]['p90_deg'])})" for g in GROUP_NAMES)


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
        _plot_suite(suite, "algorithms", out_dir / "summary_algorithms.png", "Algorithms, 4 sensors (paper Figure 9)")
    )
    paths.append(
        _plot_suite(
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
