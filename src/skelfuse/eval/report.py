"""Report of ``skelfuse eval paper``: markdown tables, CSV files, bar charts like the paper's Figures 9-11.

Files written into the output folder:

- ``report.md``: the markdown of ``format_markdown``;
- ``{experiment}_{protocol}_joints.csv`` and ``{experiment}_{protocol}_groups.csv``: one row per
  configuration, gesture ("all" = mean over gestures) and joint or group, with AE / RMSE / STD and frame
  counts;
- ``lag.csv``: best lag per output and group;
- ``fig09_algorithms.png``, ``fig10_eps.png``, ``fig11_n_sensors.png``: grouped bars per joint group, ours
  against exact truth, ours against the best view, and the paper's figure (hatched);
- ``result.json``: ``PaperEvalResult.to_dict()``.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING

from skelfuse.eval import paper_reference
from skelfuse.skeleton import EVAL_JOINT_NAMES

if TYPE_CHECKING:
    from skelfuse.eval.paper import PaperEvalResult

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


def _row_label(experiment: str, config: str) -> str:
    if experiment == "n_sensors":
        return f"{config} sensor" + ("s" if config != "1" else "")
    if experiment == "eps_sweep":
        name, eps = config.split("_")
        return f"{name} eps {eps} mm"
    return config


def format_markdown(result: PaperEvalResult) -> str:
    """The whole report as markdown."""
    from skelfuse.eval.paper import EXPERIMENTS, GROUP_NAMES, PROTOCOLS

    s = result.settings
    lines = [
        "# skelfuse eval paper — Lee et al. 2022 re-run on simulated data",
        "",
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
        f"Paper: {paper_reference.CITATION}.",
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

    for exp in EXPERIMENTS:
        configs = result.experiment_configs(exp)
        lines += [f"## {EXPERIMENT_TITLES[exp]}", ""]
        # Comparison with the paper: RMSE ± STD for both protocols and the paper's figure.
        header = ["config"] + [
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
            cells = [_row_label(exp, config)]
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
            header = ["config"] + [f"{GROUP_LABELS[g]} {m}" for g in GROUP_NAMES for m in ("AE", "RMSE", "STD")]
            header += ["NaN joint-frames"]
            lines += [
                f"AE / RMSE / STD (mm) against the {PROTOCOL_TITLES[protocol]}:",
                "",
                "| " + " | ".join(header) + " |",
                "|" + "---|" * len(header),
            ]
            for config in configs:
                gs = result.group_stats(exp, config, protocol)
                cells = [_row_label(exp, config)]
                for g in GROUP_NAMES:
                    cells += [_f(gs[g]["ae_mm"]), _f(gs[g]["rmse_mm"]), _f(gs[g]["std_mm"])]
                missing = sum(gs[g]["n_missing"] for g in GROUP_NAMES)
                total = missing + sum(gs[g]["n_frames"] for g in GROUP_NAMES)
                cells.append(f"{missing} / {total}")
                lines.append("| " + " | ".join(cells) + " |")
            lines.append("")

    # Per joint, experiment 1, exact truth.
    configs = result.experiment_configs("algorithms")
    lines += [
        "## Per joint — experiment 1, RMSE (mm) against exact truth",
        "",
        "| joint | " + " | ".join(configs) + " |",
        "|---|" + "---|" * len(configs),
    ]
    per_config = {c: result.joint_stats("algorithms", c, "truth") for c in configs}
    for k, name in enumerate(EVAL_JOINT_NAMES):
        lines.append(f"| {name} | " + " | ".join(_f(float(per_config[c].rmse_mm[k])) for c in configs) + " |")
    lines.append("")

    # Lag.
    lag_keys = [
        k
        for k in (
            "A1",
            "A2",
            *[f"A{n}_{int(e)}" for n in (3, 4, 5) for e in result.eps_values],
            *[f"raw[{i}]" for i in range(4)],
            "best_view_raw",
        )
        if k in result.lag
    ]
    lines += [
        "## Lag and left/right swaps, against exact truth",
        "",
        "Lag: the shift in frames that best aligns the output with the truth (positive = late). Swapped: share "
        "of frames x limb pairs (shoulders, elbows, wrists, hips, knees, ankles) whose left and right are the "
        "wrong way round.",
        "",
        "| output | swapped | "
        + " | ".join(f"{GROUP_LABELS[g]} lag | {GROUP_LABELS[g]} error at lag (mm)" for g in GROUP_NAMES)
        + " |",
        "|---|---|" + "---|---|" * len(GROUP_NAMES),
    ]
    for key in lag_keys:
        frac = result.swapped.get(key)
        cells = [key, "—" if frac is None or not math.isfinite(frac) else f"{100 * frac:.1f}%"]
        for g in GROUP_NAMES:
            entry = result.lag[key].get(g, {})
            cells += [_f(entry.get("lag_frames"), 2), _f(entry.get("error_mm"))]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")

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
    lines += ["## Notes on the paper's figures", ""] + [f"- {o}" for o in paper_reference.ODDITIES] + [""]
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------------
# Files.


def _write_csvs(result: PaperEvalResult, out_dir: Path) -> list[Path]:
    from skelfuse.eval.paper import EXPERIMENTS, GROUP_NAMES, PROTOCOLS

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
                    ]
                )
                for config in result.experiment_configs(exp):
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
                                ]
                            )
            paths += [jpath, gpath]
    lag_path = out_dir / "lag.csv"
    with lag_path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["output", "group", "lag_frames", "error_mm"])
        for key, by_group in result.lag.items():
            for g, entry in by_group.items():
                w.writerow([key, g, _c(entry["lag_frames"], 3), _c(entry["error_mm"])])
    paths.append(lag_path)
    return paths


def _c(value: float, digits: int = 2) -> str:
    value = float(value)
    return f"{value:.{digits}f}" if math.isfinite(value) else "nan"


def _plot(result: PaperEvalResult, experiment: str, path: Path, title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from skelfuse.eval.paper import GROUP_NAMES

    configs = result.experiment_configs(experiment)
    if experiment == "eps_sweep":
        configs = [c for c in configs if c.startswith(paper_reference.EPS_SWEEP_PRESET + "_")]
    series = [
        ("ours vs exact truth", "truth", "#1f77b4", None),
        ("ours vs best view", "best_view", "#ff7f0e", None),
        ("paper (vs best view)", "paper", "#ffffff", "///"),
    ]
    fig, axes = plt.subplots(1, len(GROUP_NAMES), figsize=(4.2 * len(GROUP_NAMES), 4.0), sharey=False)
    x = np.arange(len(configs))
    width = 0.8 / len(series)
    for ax, group in zip(axes, GROUP_NAMES, strict=True):
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
        ax.set_xticks(
            x,
            [_row_label(experiment, c) for c in configs],
            rotation=30 if len(configs) > 5 else 0,
            fontsize=8,
        )
        ax.set_title(GROUP_LABELS[group])
        ax.set_ylabel("RMSE ± STD (mm)")
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
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
            "Number of sensors, A5 eps 100 mm (paper Figure 11)",
        )
    )
    md_path = out_dir / "report.md"
    json_path = out_dir / "result.json"
    paths += [md_path, json_path]
    result.files = [str(p) for p in paths]
    md_path.write_text(format_markdown(result))
    json_path.write_text(json.dumps(result.to_dict(), indent=1, allow_nan=False))
    return paths
