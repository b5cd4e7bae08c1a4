"""The paper evaluation's result: the tables it collects from the takes, saved as JSON and read back.

:mod:`skelfuse.eval.paper` produces it; :mod:`skelfuse.eval.report` formats it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skelfuse.eval import paper_reference
from skelfuse.eval.metrics import (
    ErrorStats,
    group_means,
    mean_stats,
)
from skelfuse.eval.paper_plan import (
    BEST_VIEW_RAW,
    EXPERIMENTS,
    GROUP_NAMES,
    N_CAPTURE,
    PAPER_PRESETS,
    PROTOCOLS,
    SCENARIO_DESCRIPTIONS,
    TNOS_EPS_MM,
    _eps_key,
    is_ours,
    sensor_combinations,
)
from skelfuse.schema.skeleton import EVAL_JOINT_NAMES, EVAL_JOINTS, JOINT_GROUPS

# ----------------------------------------------------------------------------------------------------
# The result.


@dataclass
class PaperEvalResult:
    """Everything ``skelfuse eval paper`` measured in one scenario.

    Attributes
    ----------
    settings : dict
        Scenario, gestures, directions, duration, fps, seed, eps values, our presets ("ours"), workers, quick.
    stats : dict output key -> protocol -> gesture -> ErrorStats over the 16 EVAL_JOINTS
        Frames pooled over the directions of that gesture.
    lag : dict output key -> group -> {"lag_frames", "error_mm"}
        Against exact truth, pooled over all takes.
    takes : list of per-take info dicts
    swapped : dict output key -> fraction of (frame, pair) samples with a left/right pair the wrong way round
        against exact truth (pairs: shoulders, elbows, wrists, hips, knees, ankles), over all takes
    jitter : dict output key -> group -> RMS second difference over time, mm/frame², over all takes
        4-sensor outputs, raw sensors and ``exact_truth`` (the motion's own acceleration).
    elapsed_s : float
        Wall time of the whole run.
    files : list of str
        Files written (empty without an output folder).
    """

    settings: dict[str, Any]
    stats: dict[str, dict[str, dict[str, ErrorStats]]]
    lag: dict[str, dict[str, dict[str, float]]]
    takes: list[dict[str, Any]]
    swapped: dict[str, float] = field(default_factory=dict)
    elapsed_s: float = 0.0
    files: list[str] = field(default_factory=list)
    jitter: dict[str, dict[str, float]] = field(default_factory=dict)
    orientation: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)

    # ---- derived views -------------------------------------------------------------------------------------

    @property
    def gestures(self) -> list[str]:
        return list(self.settings["gestures"])

    @property
    def eps_values(self) -> list[float]:
        return list(self.settings["eps_mm"])

    @property
    def scenario(self) -> str:
        return str(self.settings.get("scenario", "rear_mirroring"))

    @property
    def ours(self) -> list[str]:
        """Our presets that were run (extra rows of experiments 1 and 3)."""
        return [name for name in self.settings.get("ours", []) if name in self.stats]

    def experiment_configs(self, experiment: str) -> list[str]:
        """Row names of an experiment, in display order: the paper's rows, then ours."""
        if experiment == "algorithms":
            return [*PAPER_PRESETS, *self.ours]
        if experiment == "eps_sweep":
            return [_eps_key(p, e) for p in ("A3", "A4", "A5") for e in self.eps_values]
        if experiment == "n_sensors":
            rows = [str(n) for n in sorted(self._combinations())]
            return rows + [f"{name}_{n}" for name in self.ours for n in sorted(self._combinations()) if n > 1]
        raise ValueError(f"unknown experiment {experiment!r}; expected one of {EXPERIMENTS}")

    def _combinations(self, algorithm: str = "A5") -> dict[int, list[str]]:
        return sensor_combinations(N_CAPTURE, TNOS_EPS_MM, algorithm)

    def members(self, experiment: str, config: str) -> list[str]:
        """The base output keys whose per-gesture stats are averaged into one row."""
        if experiment == "algorithms" and config in ("A3", "A4", "A5"):
            return [_eps_key(config, e) for e in self.eps_values]
        if experiment == "n_sensors":
            algorithm, _, n = config.rpartition("_")
            return self._combinations(algorithm or "A5")[int(n)]
        return [config]

    @staticmethod
    def n_sensors_of(config: str) -> int:
        """Number of sensors of an experiment-3 row ("3" or "skelfuse_3")."""
        return int(config.rpartition("_")[2])

    def row_lag(self, experiment: str, config: str, group: str) -> float:
        """Lag in frames of a row against exact truth: mean over its member outputs that have one (4 sensors)."""
        values = [self.lag[k][group]["lag_frames"] for k in self.members(experiment, config) if k in self.lag]
        return float(np.mean(values)) if values else float("nan")

    def row_jitter(self, experiment: str, config: str, group: str) -> float:
        """RMS second difference (mm/frame²) of a row: mean over its member outputs that have one."""
        values = [self.jitter[k][group] for k in self.members(experiment, config) if k in self.jitter]
        return float(np.mean(values)) if values else float("nan")

    def row_swapped(self, experiment: str, config: str) -> float:
        """Share of left/right limb pairs the wrong way round in a row: mean over its member outputs."""
        values = [self.swapped[k] for k in self.members(experiment, config) if k in self.swapped]
        return float(np.mean(values)) if values else float("nan")

    def joint_stats(self, experiment: str, config: str, protocol: str, gesture: str = "all") -> ErrorStats:
        """Per-joint stats of one row: mean over its member outputs (eps values or sensor combinations) and,
        for ``gesture="all"``, over gestures."""
        gestures = self.gestures if gesture == "all" else [gesture]
        items = [self.stats[key][protocol][g] for key in self.members(experiment, config) for g in gestures]
        return mean_stats(items)

    def group_stats(
        self, experiment: str, config: str, protocol: str, gesture: str = "all"
    ) -> dict[str, dict[str, float]]:
        """{group: {"ae_mm", "rmse_mm", "std_mm", "n_frames", "n_missing"}} of one row."""
        s = self.joint_stats(experiment, config, protocol, gesture)
        out: dict[str, dict[str, float]] = {g: {} for g in GROUP_NAMES}
        for metric in ("ae_mm", "rmse_mm", "std_mm"):
            for g, v in group_means(getattr(s, metric), EVAL_JOINTS, JOINT_GROUPS).items():
                out[g][metric] = float(v)
        col = {int(j): k for k, j in enumerate(EVAL_JOINTS)}
        for g, idx in JOINT_GROUPS.items():
            cols = [col[int(j)] for j in idx]
            out[g]["n_frames"] = int(s.n_frames[cols].sum())
            out[g]["n_missing"] = int(s.n_missing[cols].sum())
        return out

    def paper_value(self, experiment: str, config: str, metric: str, group: str) -> float | None:
        """The paper's figure for a row (``metric`` "ae_mm" or "std_mm"), or None (e.g. for our rows)."""
        if is_ours(config):
            return None
        if experiment == "algorithms":
            return paper_reference.reference_value("algorithms", config, metric, group)
        if experiment == "eps_sweep":
            name, eps = config.split("_")
            if name != paper_reference.EPS_SWEEP_PRESET:
                return None
            return paper_reference.reference_value("eps_sweep", float(eps), metric, group)
        if experiment == "n_sensors":
            if is_ours(config):
                return None
            return paper_reference.reference_value("n_sensors", int(config), metric, group)
        return None

    def to_dict(self) -> dict[str, Any]:
        """JSON-serializable summary (NaN becomes None).

        Scenario and settings; per experiment, protocol and row the group and joint values over all gestures and
        the group values per gesture, the row's lag, jitter and swapped share; lag, jitter and swapped share per
        output; per-take facts; the paper's figures.
        """
        experiments: dict[str, Any] = {}
        for exp in EXPERIMENTS:
            experiments[exp] = {}
            for protocol in PROTOCOLS:
                rows = {}
                for config in self.experiment_configs(exp):
                    s = self.joint_stats(exp, config, protocol)
                    rows[config] = {
                        "algorithm": "ours" if is_ours(config) else "paper",
                        "members": self.members(exp, config),
                        "groups": self.group_stats(exp, config, protocol),
                        "groups_by_gesture": {g: self.group_stats(exp, config, protocol, g) for g in self.gestures},
                        "joints": {
                            name: {
                                "ae_mm": float(s.ae_mm[k]),
                                "rmse_mm": float(s.rmse_mm[k]),
                                "std_mm": float(s.std_mm[k]),
                                "n_frames": int(s.n_frames[k]),
                                "n_missing": int(s.n_missing[k]),
                                "n_ref_missing": int(s.n_ref_missing[k]),
                            }
                            for k, name in enumerate(EVAL_JOINT_NAMES)
                        },
                        "n_missing": int(s.n_missing.sum()),
                        "lag_frames": {g: self.row_lag(exp, config, g) for g in GROUP_NAMES},
                        "jitter_mm_per_frame2": {g: self.row_jitter(exp, config, g) for g in GROUP_NAMES},
                        "swapped_fraction": self.row_swapped(exp, config),
                        "paper": {
                            g: {m: self.paper_value(exp, config, m, g) for m in ("ae_mm", "std_mm")}
                            for g in GROUP_NAMES
                        },
                    }
                experiments[exp][protocol] = rows
        best = {g: v for g, v in self.group_stats_key(BEST_VIEW_RAW, "truth").items()}
        return _json_safe(
            {
                "scenario": self.scenario,
                "settings": self.settings,
                "elapsed_s": self.elapsed_s,
                "experiments": experiments,
                "best_view_vs_truth": best,
                "lag": self.lag,
                "jitter_mm_per_frame2": self.jitter,
                "swapped_fraction": self.swapped,
                "orientation_error_deg": self.orientation,
                "takes": self.takes,
                "paper": {
                    "citation": paper_reference.CITATION,
                    "algorithms": paper_reference.ALGORITHMS,
                    "eps_sweep": {str(int(k)): v for k, v in paper_reference.EPS_SWEEP.items()},
                    "n_sensors": {str(k): v for k, v in paper_reference.N_SENSORS.items()},
                    "oddities": list(paper_reference.ODDITIES),
                },
                "files": self.files,
            }
        )

    def group_stats_key(self, key: str, protocol: str) -> dict[str, dict[str, float]]:
        """Group values of one base output key (e.g. ``best_view_raw``) over all gestures."""
        s = mean_stats([self.stats[key][protocol][g] for g in self.gestures])
        out: dict[str, dict[str, float]] = {g: {} for g in GROUP_NAMES}
        for metric in ("ae_mm", "rmse_mm", "std_mm"):
            for g, v in group_means(getattr(s, metric), EVAL_JOINTS, JOINT_GROUPS).items():
                out[g][metric] = float(v)
        return out


@dataclass
class PaperEvalSuite:
    """``skelfuse eval paper`` over several scenarios: one ``PaperEvalResult`` per scenario.

    Attributes
    ----------
    scenarios : dict scenario name -> PaperEvalResult
        In ``SCENARIOS`` order.
    settings : dict
        What all scenarios share (the per-scenario settings add the scenario and its profile change).
    elapsed_s : float
        Wall time of the whole run.
    files : list of str
        Files written: the combined report.md and result.json, and each scenario's folder.
    """

    scenarios: dict[str, PaperEvalResult]
    settings: dict[str, Any]
    elapsed_s: float = 0.0
    files: list[str] = field(default_factory=list)

    def __getitem__(self, scenario: str) -> PaperEvalResult:
        return self.scenarios[scenario]

    def to_dict(self) -> dict[str, Any]:
        """JSON-serializable: settings, run time, files, and each scenario's ``PaperEvalResult.to_dict()``."""
        return _json_safe(
            {
                "settings": self.settings,
                "elapsed_s": self.elapsed_s,
                "scenario_descriptions": {k: SCENARIO_DESCRIPTIONS.get(k, "") for k in self.scenarios},
                "scenarios": {name: result.to_dict() for name, result in self.scenarios.items()},
                "files": self.files,
            }
        )


def _json_safe(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return _json_safe(value.tolist())
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        value = float(value)
        return value if math.isfinite(value) else None
    return value
