"""The paper evaluation's plan: its constants (experiments, protocols, scenarios, sensor counts) and which
fusion runs one take produces; :mod:`skelfuse.eval.paper` runs the plan.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from skelfuse.fusion import presets
from skelfuse.schema.skeleton import JOINT_GROUPS

EPS_MM: tuple[float, ...] = (50.0, 100.0, 150.0, 200.0)
DIRECTIONS_DEG: tuple[float, ...] = (0.0, 90.0, 180.0, 270.0)
N_CAPTURE = 4
TNOS_EPS_MM = 100.0
LAG_SHIFTS = np.arange(-5, 21)
PROTOCOLS: tuple[str, ...] = ("truth", "best_view")
EXPERIMENTS: tuple[str, ...] = ("algorithms", "eps_sweep", "n_sensors")
GROUP_NAMES: tuple[str, ...] = tuple(JOINT_GROUPS)
PAPER_PRESETS: tuple[str, ...] = ("A1", "A2", "A3", "A4", "A5")
OURS = "skelfuse"
"""Our preset (``skelfuse.fusion.presets.preset("skelfuse")``), run beside the paper's in experiments 1 and 3."""
SCENARIOS: tuple[str, ...] = ("paper", "rear_mirroring")
SCENARIO_DESCRIPTIONS: dict[str, str] = {
    "paper": "the paper's conditions: no left/right mirroring in any view (section 3.1: \"no misorientation "
    'case in evaluation data"); default profile with flip_on_prob = 0',
    "rear_mirroring": "the default profile: views from behind mirror left/right in bursts (trackers are reported "
    "to do so; the rate is the profile's assumption, not a measurement); two of the four capture views are rear "
    "views",
}
EXACT_TRUTH = "exact_truth"
"""Output key of the simulator's exact truth in the jitter table: the motion's own acceleration."""

DEFAULT_DURATION_S = 1000.0 / 30.0  # the paper's takes: 1000 frames per gesture (section 2.3)
QUICK_DURATION_S = 4.0
QUICK_GESTURES: tuple[str, ...] = ("hands_up_down", "squat")
QUICK_DIRECTIONS_DEG: tuple[float, ...] = (0.0, 180.0)
FPS = 30.0


# ----------------------------------------------------------------------------------------------------
# Run plan: which outputs one take produces.


@dataclass(frozen=True)
class FusionRun:
    """One fusion configuration applied to one take.

    Attributes
    ----------
    key : str
        Name in tables: "A5_100" (all four sensors), "A5_100[0,2]" (a subset of the capture sensors).
    preset : str
        Preset name: the paper's "A1".."A5" or ours, "skelfuse".
    eps_mm : float or None
        DBSCAN radius handed to the preset; None: the preset's own default (A1/A2 and ours).
    sensors : tuple of int
        Indices of the capture sensors that take part.
    """

    key: str
    preset: str
    eps_mm: float | None
    sensors: tuple[int, ...]

    def params(self) -> Any:
        """The preset's ``FusionParams``: eps is passed only where the run sets one (A3-A5)."""

        return presets.preset(self.preset) if self.eps_mm is None else presets.preset(self.preset, eps_mm=self.eps_mm)


def fusion_runs(
    n_capture: int = N_CAPTURE,
    eps_values: Sequence[float] = EPS_MM,
    tnos_eps_mm: float = TNOS_EPS_MM,
    ours: Sequence[str] = (OURS,),
) -> list[FusionRun]:
    """Every fusion run of one take: the paper's algorithm/eps grid on all sensors and ours on all sensors,
    then A5 and ours on every proper subset of 2..n-1 sensors (the full set is already run; single sensors are
    raw data, not fused)."""
    all_sensors = tuple(range(n_capture))
    runs = [FusionRun("A1", "A1", None, all_sensors), FusionRun("A2", "A2", None, all_sensors)]
    for name in ("A3", "A4", "A5"):
        runs += [FusionRun(_eps_key(name, eps), name, float(eps), all_sensors) for eps in eps_values]
    runs += [FusionRun(name, name, None, all_sensors) for name in ours]
    for size in range(2, n_capture):
        for combo in itertools.combinations(all_sensors, size):
            runs.append(FusionRun(_subset_key(_eps_key("A5", tnos_eps_mm), combo), "A5", tnos_eps_mm, combo))
            runs += [FusionRun(_subset_key(name, combo), name, None, combo) for name in ours]
    return runs


def sensor_combinations(
    n_capture: int = N_CAPTURE, tnos_eps_mm: float = TNOS_EPS_MM, algorithm: str = "A5"
) -> dict[int, list[str]]:
    """Output keys averaged for each number of sensors in experiment 3: raw skeletons for one sensor,
    ``algorithm`` (A5 at ``tnos_eps_mm``, or ours at its own eps) on every combination otherwise (4, 6, 4, 1 of
    them for four sensors)."""
    full = _eps_key("A5", tnos_eps_mm) if algorithm == "A5" else algorithm
    out: dict[int, list[str]] = {1: [_raw_key(s) for s in range(n_capture)]}
    for size in range(2, n_capture):
        out[size] = [_subset_key(full, c) for c in itertools.combinations(range(n_capture), size)]
    out[n_capture] = [full]
    return out


def is_ours(config: str) -> bool:
    """Whether a row or output key is our algorithm (not the paper's, not raw data)."""
    return config == OURS or config.startswith((OURS + "_", OURS + "["))


def scenario_profile(profile: Any, scenario: str) -> Any:
    """The simulator profile of a scenario (``SCENARIOS``), derived from ``profile``."""
    if scenario == "paper":
        return replace(profile, flip_on_prob=0.0)
    if scenario == "rear_mirroring":
        return profile
    raise ValueError(f"unknown scenario {scenario!r}; expected one of {SCENARIOS}")


def _eps_key(preset: str, eps_mm: float) -> str:
    return f"{preset}_{round(eps_mm)}"


def _subset_key(key: str, sensors: Sequence[int]) -> str:
    return f"{key}[{','.join(str(s) for s in sensors)}]"


def _raw_key(sensor: int) -> str:
    return f"raw[{sensor}]"


BEST_VIEW_RAW = "best_view_raw"
"""Output key of the best-view skeleton itself, scored against exact truth: how good the paper's reference
is."""
