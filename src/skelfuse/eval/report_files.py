"""The paper evaluation report's files (:mod:`skelfuse.eval.report`): the CSV tables and the charts, and the
cell formatting they share with the markdown.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.eval import paper_reference
from skelfuse.eval.paper import (
    EXPERIMENTS,
    GROUP_NAMES,
    PROTOCOLS,
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


def fmt(value: float | None, digits: int = 1) -> str:
    if value is None or not math.isfinite(value):
        return "—"
    return f"{value:.{digits}f}"


def by_label(experiment: str, config: str) -> str:
    """Who the row's algorithm is: the paper's, ours, or raw sensor data."""
    if experiment == "n_sensors" and config == "1":
        return "raw"
    return "**ours**" if is_ours(config) else "paper"


def row_label(experiment: str, config: str) -> str:
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


def row_cell(experiment: str, config: str) -> str:
    """Row label for markdown: our rows in bold."""
    label = row_label(experiment, config)
    return f"**{label}**" if is_ours(config) else label


def pct(frac: float | None) -> str:
    return "—" if frac is None or not math.isfinite(frac) else f"{100 * frac:.1f}%"


# ----------------------------------------------------------------------------------------------------
# Files.


def write_csvs(result: PaperEvalResult, out_dir: Path) -> list[Path]:

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
                _write_experiment_rows(jw, gw, result, exp, protocol, gestures)
            paths += [jpath, gpath]
    paths.append(_write_lag_csv(result, out_dir))
    return paths


def _write_experiment_rows(
    jw: Any, gw: Any, result: PaperEvalResult, exp: str, protocol: str, gestures: list[str]
) -> None:
    """One experiment and protocol: a row per config, gesture and joint (``jw``), and per group (``gw``)."""
    for config in result.experiment_configs(exp):
        by = by_label(exp, config).strip("*")
        for gesture in gestures:
            s = result.joint_stats(exp, config, protocol, gesture)
            for k, name in enumerate(EVAL_JOINT_NAMES):
                jw.writerow(
                    [
                        config,
                        gesture,
                        name,
                        csv_number(s.ae_mm[k]),
                        csv_number(s.rmse_mm[k]),
                        csv_number(s.std_mm[k]),
                        int(s.n_frames[k]),
                        int(s.n_missing[k]),
                        int(s.n_ref_missing[k]),
                        by,
                    ]
                )
            gs = result.group_stats(exp, config, protocol, gesture)
            for g in GROUP_NAMES:
                paper = [
                    result.paper_value(exp, config, m, g) if gesture == "all" else None for m in ("ae_mm", "std_mm")
                ]
                gw.writerow(
                    [
                        config,
                        gesture,
                        g,
                        csv_number(gs[g]["ae_mm"]),
                        csv_number(gs[g]["rmse_mm"]),
                        csv_number(gs[g]["std_mm"]),
                        gs[g]["n_frames"],
                        gs[g]["n_missing"],
                        *("" if p is None else p for p in paper),
                        by,
                    ]
                )


def _write_lag_csv(result: PaperEvalResult, out_dir: Path) -> Path:
    """lag.csv: per output and group, lag (frames), its error and the jitter."""
    lag_path = out_dir / "lag.csv"
    with lag_path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["output", "group", "lag_frames", "error_mm", "jitter_mm_per_frame2", "algorithm"])
        for key, by_group in result.lag.items():
            by = "ours" if is_ours(key) else ("raw" if "raw" in key else "paper")
            for g, entry in by_group.items():
                jitter = result.jitter.get(key, {}).get(g, float("nan"))
                w.writerow(
                    [
                        key,
                        g,
                        csv_number(entry["lag_frames"], 3),
                        csv_number(entry["error_mm"]),
                        csv_number(jitter, 3),
                        by,
                    ]
                )
        for g, jitter in result.jitter.get("exact_truth", {}).items():
            w.writerow(["exact_truth", g, "", "", csv_number(jitter, 3), "truth"])
    return lag_path


def csv_number(value: float, digits: int = 2) -> str:
    value = float(value)
    return f"{value:.{digits}f}" if math.isfinite(value) else "nan"


def plot_axes(axes: Any, result: PaperEvalResult, experiment: str, *, legend: bool = True) -> None:
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
        labels = [row_label(experiment, c).replace(" (ours)", "\n(ours)") for c in configs]
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


def plot_experiment(result: PaperEvalResult, experiment: str, path: Path, title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(GROUP_NAMES), figsize=(4.6 * len(GROUP_NAMES), 4.4), sharey=False)
    plot_axes(axes, result, experiment)
    fig.suptitle(title + OURS_NOTE, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


OURS_NOTE = "\nA1-A5: the paper's algorithm; shaded, bold: ours (skelfuse)"


def plot_suite(suite: PaperEvalSuite, experiment: str, path: Path, title: str) -> Path:
    """One row of panels per scenario."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(suite.scenarios)
    fig, axes = plt.subplots(n, len(GROUP_NAMES), figsize=(4.6 * len(GROUP_NAMES), 4.2 * n), squeeze=False)
    for row, (name, result) in enumerate(suite.scenarios.items()):
        plot_axes(axes[row], result, experiment, legend=row == 0)
        axes[row][0].set_ylabel(f'scenario "{name}"\nRMSE ± STD (mm)')
    fig.suptitle(title + OURS_NOTE, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
