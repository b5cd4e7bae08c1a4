"""``skelfuse eval paper``: the experiments of Lee et al. 2022 (section 3) re-run on simulated data.

The set-up follows the paper's section 2.3: four capture sensors at fixed places (``paper_rig(4)``), a
subject performing each of the six gestures while facing each of four directions (0, 90, 180, 270
degrees), and a fifth "best view" sensor placed in front of the subject, whose skeleton the paper used as
its ground truth. All five sensors are simulated together, once per take, so every algorithm and every
sensor subset sees the same noise. The four capture skeletons are brought to world coordinates with the
*calibrated* extrinsics (as a real rig would) and fused; the best-view skeleton is transformed with its
calibrated extrinsics too. Every output is scored twice:

- ``truth``: against the simulator's exact ground truth (what we actually want to know);
- ``best_view``: against the best-view sensor's skeleton (the paper's protocol, to compare with its figures).

Scenarios (``SCENARIOS``), each a complete run of the experiments with its own result:

- ``paper``: the paper's conditions as it reports them: no left/right mirroring at all (section 3.1: "there
  was no misorientation case in evaluation data"); the default profile with ``flip_on_prob = 0``.
- ``rear_mirroring``: the default profile: views that see the subject from behind mirror in bursts (reported
  for body trackers; the rate is the profile's assumption, not a measurement). With the subject facing between
  two sensors, two of four views are rear views, which the paper's realignment cannot out-vote.

Both scenarios use the same per-take seeds (common random numbers), so their difference is the mirroring and
what follows from it (a mirrored burst also restarts the view's body id and its noise state).

Experiments (names used in tables, CSV files and ``to_dict()``):

- ``algorithms`` (paper section 3.1, Figure 9): A1, A2, A3, A4, A5 with 4 sensors; A3-A5 averaged over
  eps 50/100/150/200 mm as the paper did. A2 is reported although the paper dropped it. Extra row, ours:
  ``skelfuse`` (``preset("skelfuse")`` at its own default eps).
- ``eps_sweep`` (section 3.2, Figure 10): A3, A4, A5 at each eps.
- ``n_sensors`` (section 3.3, Figure 11): A5 at eps 100 mm with 1-4 sensors (rows "1".."4"), every
  combination (4, 6, 4, 1), averaged over the combinations; one sensor is its raw skeleton, as in the paper.
  Extra rows, ours: ``skelfuse_2`` .. ``skelfuse_4``, the same combinations fused by ``skelfuse`` (one sensor
  is the shared raw row "1").

Aggregation (``metrics`` has the formulas): per joint, the frames of one gesture are pooled over the four
directions (AE / RMSE / STD of the Euclidean distance); those per-gesture values are averaged over gestures
with equal weight (as the paper averages its per-gesture Appendix tables); a group value is the plain mean
over the group's joints (the paper's group figures are the means of its per-joint RMSEs). Frames where an
output is NaN while the reference is not are counted per joint (``n_missing``), never dropped silently.

Lag: for every 4-sensor output and joint group, the shift in frames (searched over ``LAG_SHIFTS``) that
minimizes the mean distance between the output and the exact truth, pooled over all takes; positive means the
output is late. Jitter: per 4-sensor output and group, the RMS second difference over time (mm/frame²),
pooled over all takes; the exact truth's own value (``exact_truth``) is the motion's real acceleration.
Swapped: the share of (frame, limb pair) samples whose left and right are the wrong way round.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.eval import paper_reference
from skelfuse.eval.metrics import (
    ErrorAccumulator,
    ErrorStats,
    angle_stats,
    angular_errors,
    best_lag,
    group_means,
    jitter_rms,
    jitter_sums,
    lag_error_curve,
    mean_stats,
    swap_counts,
)
from skelfuse.fusion import presets
from skelfuse.fusion.orientation import views_to_world
from skelfuse.fusion.pipeline import Fuser
from skelfuse.fusion.transform import apply_transform
from skelfuse.progress import Progress
from skelfuse.schema.skeleton import EVAL_JOINT_NAMES, EVAL_JOINTS, JOINT_GROUPS, N_JOINTS, PAPER_REALIGN_PAIRS
from skelfuse.sim.gestures import GESTURES, make_gesture
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.orientation import observe_orientations, truth_orientations
from skelfuse.sim.rig import best_view_sensor, paper_rig

__all__ = [
    "DIRECTIONS_DEG",
    "EPS_MM",
    "EXPERIMENTS",
    "OURS",
    "PAPER_PRESETS",
    "PROTOCOLS",
    "SCENARIOS",
    "PaperEvalResult",
    "PaperEvalSuite",
    "run_paper_eval",
]

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


# ----------------------------------------------------------------------------------------------------
# One take (runs in a worker process when workers > 1).


@dataclass(frozen=True)
class TakeTask:
    gesture: str
    facing_deg: float
    duration_s: float
    fps: float
    motion_seed: int
    sim_seed: int
    profile_path: str | None
    eps_values: tuple[float, ...]
    scenario: str = "rear_mirroring"
    ours: tuple[str, ...] = (OURS,)


@dataclass
class TakeResult:
    """Accumulated errors of every output of one take.

    Attributes
    ----------
    errors : dict key -> protocol -> ErrorAccumulator over the 16 EVAL_JOINTS
    lag : dict key -> group -> (sums, counts) over LAG_SHIFTS, against exact truth
    swaps : dict key -> (n_swapped, n_valid) per PAPER_REALIGN_PAIRS pair, against exact truth
    info : per-take facts (frames, tracked and mirrored fractions, seconds spent)
    jitter : dict key -> group -> (sum of squared second differences, count), see ``metrics.jitter_sums``
    scenario : the scenario the take was simulated under
    orientation : dict key -> group -> (n,) float32 angular errors (deg) against the true orientations, of the
        outputs that compute orientations (ours, 4 sensors) and of the raw views (all finite samples)
    """

    gesture: str
    facing_deg: float
    errors: dict[str, dict[str, ErrorAccumulator]]
    lag: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]]
    info: dict[str, Any]
    swaps: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    jitter: dict[str, dict[str, tuple[float, int]]] = field(default_factory=dict)
    scenario: str = "rear_mirroring"
    orientation: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)


def _world_skeletons(obs: Any) -> np.ndarray:
    """(T, S, 32, 3) world positions with the calibrated extrinsics; NaN where a sensor tracked nobody."""

    world = np.asarray(
        apply_transform(obs.world_from_sensor_calibrated, np.asarray(obs.positions, np.float64)),
        dtype=np.float64,
    )
    tracked = np.asarray(obs.tracked, dtype=bool)
    return np.where(tracked[..., None, None], world, np.nan)


def fuse_take(
    run: FusionRun,
    candidates: np.ndarray,
    confidence: np.ndarray,
    fps: float,
    sensor_positions: np.ndarray | None = None,
) -> np.ndarray:
    """Fuse a whole take with one configuration.

    Parameters
    ----------
    run : FusionRun
    candidates : (T, S, 32, 3) world mm, NaN = missing (all capture sensors; ``run.sensors`` picks)
    confidence : (T, S, 32) uint8
    fps : frame rate of the take
    sensor_positions : (S, 3) world mm of all capture sensors, or None
        Where the sensors stand (the live node passes its calibrated poses' translations): the temporal
        realignment's rear-view rule needs them and is off without them.

    Returns
    -------
    (T, 32, 3) fused positions, NaN where the fuser gave none.
    """

    sensors = list(run.sensors)
    positions = None if sensor_positions is None else np.asarray(sensor_positions)[sensors]
    return fuse_sequence(run.params(), candidates[:, sensors], confidence[:, sensors], fps, positions)


def fuse_sequence(
    params: Any, candidates: np.ndarray, confidence: np.ndarray, fps: float, sensor_positions: np.ndarray | None = None
) -> np.ndarray:
    """Fuse one person's take frame by frame with ``params`` (a ``FusionParams``).

    ``candidates`` (T, S, 32, 3) world mm, NaN = missing; ``confidence`` (T, S, 32); ``sensor_positions`` (S, 3)
    world mm or None (the realignment's rear-view rule is off without them). Returns (T, 32, 3), NaN where the
    fuser gave none.
    """
    cand = np.ascontiguousarray(candidates)
    conf = np.ascontiguousarray(confidence)
    fuser = Fuser(params, n_bodies=1, sensor_positions=sensor_positions)
    out = np.full((cand.shape[0], N_JOINTS, 3), np.nan)
    dt_s = 1.0 / fps
    for t in range(cand.shape[0]):
        result = fuser.step(cand[t][None], conf[t][None], dt_s=dt_s)
        out[t] = np.asarray(result.positions)[0]
    return out


def fuse_take_oriented(
    run: FusionRun,
    candidates: np.ndarray,
    confidence: np.ndarray,
    orientations: np.ndarray,
    fps: float,
    sensor_positions: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fuse_take` with the views' world orientations (T, S, 32, 4) as well: returns the fused positions
    (the same as :func:`fuse_take`'s: orientations never change them) and (T, 32, 4) fused orientations (NaN
    where the configuration computes none)."""
    sensors = list(run.sensors)
    cand = np.ascontiguousarray(candidates[:, sensors])
    conf = np.ascontiguousarray(confidence[:, sensors])
    views = np.ascontiguousarray(orientations[:, sensors])
    positions_of_sensors = None if sensor_positions is None else np.asarray(sensor_positions)[sensors]
    fuser = Fuser(run.params(), n_bodies=1, sensor_positions=positions_of_sensors)
    positions = np.full((cand.shape[0], N_JOINTS, 3), np.nan)
    quats = np.full((cand.shape[0], N_JOINTS, 4), np.nan)
    dt_s = 1.0 / fps
    for t in range(cand.shape[0]):
        result = fuser.step(cand[t][None], conf[t][None], dt_s=dt_s, orientations=views[t][None])
        positions[t] = np.asarray(result.positions)[0]
        if result.orientations is not None:
            quats[t] = result.orientations[0]
    return positions, quats


def evaluate_take(task: TakeTask) -> TakeResult:
    """Simulate one take of ``task.scenario`` with all five sensors, run every output and accumulate its
    errors, lag, jitter and left/right swaps."""

    t0 = time.perf_counter()
    motion = make_gesture(
        task.gesture,
        duration_s=task.duration_s,
        fps=task.fps,
        facing_deg=task.facing_deg,
        seed=task.motion_seed,
    )
    sensors = [*list(paper_rig(N_CAPTURE)), best_view_sensor(task.facing_deg)]
    profile = scenario_profile(load_profile(task.profile_path), task.scenario)
    obs = simulate(motion, sensors, profile, seed=task.sim_seed)
    t_sim = time.perf_counter() - t0

    world = _world_skeletons(obs)
    capture = world[:, :N_CAPTURE]
    confidence = np.asarray(obs.confidence)[:, :N_CAPTURE]
    best_view = world[:, N_CAPTURE]
    truth = np.asarray(obs.truth, dtype=np.float64)
    references = {"truth": truth[:, EVAL_JOINTS], "best_view": best_view[:, EVAL_JOINTS]}

    errors: dict[str, dict[str, ErrorAccumulator]] = {}
    lag: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]] = {}
    swaps: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    jitter: dict[str, dict[str, tuple[float, int]]] = {
        EXACT_TRUTH: {g: jitter_sums(truth[:, idx]) for g, idx in JOINT_GROUPS.items()}
    }

    def score(key: str, output: np.ndarray, with_lag: bool, protocols: Sequence[str] = PROTOCOLS) -> None:
        est = output[:, EVAL_JOINTS]
        errors[key] = {p: ErrorAccumulator.zeros(len(EVAL_JOINTS)).add(est, references[p]) for p in protocols}
        swaps[key] = swap_counts(output, truth, PAPER_REALIGN_PAIRS)
        if with_lag:
            lag[key] = {
                g: lag_error_curve(output[:, idx], truth[:, idx], LAG_SHIFTS) for g, idx in JOINT_GROUPS.items()
            }
            jitter[key] = {g: jitter_sums(output[:, idx]) for g, idx in JOINT_GROUPS.items()}

    for sensor in range(N_CAPTURE):
        score(_raw_key(sensor), capture[:, sensor], with_lag=True)
    score(BEST_VIEW_RAW, best_view, with_lag=True, protocols=("truth",))
    # Orientations: truth from the motion, the views' as the trackers would report them (own random streams,
    # so the positions above are the same with or without this), in the world by the calibrated poses.
    true_quats = truth_orientations(truth, task.fps, seed=task.sim_seed)
    view_quats = views_to_world(
        observe_orientations(obs, true_quats, seed=task.sim_seed), obs.world_from_sensor_calibrated
    )
    orientation: dict[str, dict[str, np.ndarray]] = {}

    def score_orientation(key: str, quats: np.ndarray) -> None:
        errors = angular_errors(quats, true_quats)
        orientation[key] = {
            g: errors[:, idx][np.isfinite(errors[:, idx])].astype(np.float32) for g, idx in JOINT_GROUPS.items()
        }

    for sensor in range(N_CAPTURE):
        score_orientation(_raw_key(sensor), view_quats[:, sensor])
    score_orientation(BEST_VIEW_RAW, view_quats[:, N_CAPTURE])

    t1 = time.perf_counter()
    runs = fusion_runs(N_CAPTURE, task.eps_values, ours=task.ours)
    sensor_positions = obs.world_from_sensor_calibrated[:N_CAPTURE, :3, 3]  # as the live node knows them
    for run in runs:
        if run.params().orientations and len(run.sensors) == N_CAPTURE:
            fused, fused_quats = fuse_take_oriented(
                run, capture, confidence, view_quats[:, :N_CAPTURE], task.fps, sensor_positions
            )
            score_orientation(run.key, fused_quats)
        else:
            fused = fuse_take(run, capture, confidence, task.fps, sensor_positions)
        score(run.key, fused, with_lag=len(run.sensors) == N_CAPTURE)
    t_fuse = time.perf_counter() - t1

    tracked = np.asarray(obs.tracked, dtype=bool)
    mirrored = np.asarray(obs.mirrored, dtype=bool) & tracked
    info = {
        "scenario": task.scenario,
        "gesture": task.gesture,
        "facing_deg": task.facing_deg,
        "n_frames": int(truth.shape[0]),
        "tracked_fraction": [float(x) for x in tracked.mean(axis=0)],
        "mirrored_fraction": [float(x) for x in mirrored.mean(axis=0)],
        "simulate_s": t_sim,
        "fuse_s": t_fuse,
        "n_fusion_steps": int(truth.shape[0]) * len(runs),
    }
    return TakeResult(task.gesture, task.facing_deg, errors, lag, info, swaps, jitter, task.scenario, orientation)


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


# ----------------------------------------------------------------------------------------------------
# Driver.


def plan_takes(
    *,
    quick: bool,
    seed: int,
    duration_s: float | None,
    profile_path: str | None,
    gestures: Sequence[str] | None = None,
    directions_deg: Sequence[float] | None = None,
    eps_values: Sequence[float] = EPS_MM,
    fps: float = FPS,
    scenarios: Sequence[str] = ("rear_mirroring",),
    ours: Sequence[str] = (OURS,),
) -> list[TakeTask]:
    """The takes of a run: every scenario, gesture and facing direction, each gesture/direction with its own
    seeds from ``seed`` (the same in every scenario: common random numbers)."""
    for scenario in scenarios:
        if scenario not in SCENARIOS:
            raise ValueError(f"unknown scenario {scenario!r}; expected some of {SCENARIOS}")
    if gestures is None:
        if quick:
            gestures = QUICK_GESTURES
        else:
            gestures = GESTURES
    if directions_deg is None:
        directions_deg = QUICK_DIRECTIONS_DEG if quick else DIRECTIONS_DEG
    if duration_s is None:
        duration_s = QUICK_DURATION_S if quick else DEFAULT_DURATION_S
    if duration_s <= 0:
        raise ValueError(f"duration_s must be > 0, got {duration_s}")
    tasks = []
    for scenario in scenarios:
        for gi, gesture in enumerate(gestures):
            for di, facing in enumerate(directions_deg):
                motion_seed, sim_seed = np.random.SeedSequence([seed, gi, di]).generate_state(2)
                tasks.append(
                    TakeTask(
                        gesture,
                        float(facing),
                        float(duration_s),
                        float(fps),
                        int(motion_seed),
                        int(sim_seed),
                        profile_path,
                        tuple(float(e) for e in eps_values),
                        scenario,
                        tuple(ours),
                    )
                )
    return tasks


def collect(takes: Sequence[TakeResult], settings: dict[str, Any], elapsed_s: float = 0.0) -> PaperEvalResult:
    """Pool take results: per output key, protocol and gesture, add the accumulators of the directions and
    turn them into stats; per key and group, add the lag curves of all takes and find the best lag, and add the
    jitter sums. ``takes`` must all be of one scenario."""
    gestures = list(settings["gestures"])
    if len({t.scenario for t in takes}) > 1:
        raise ValueError(f"collect() pools one scenario at a time, got {sorted({t.scenario for t in takes})}")
    pooled: dict[str, dict[str, dict[str, ErrorAccumulator]]] = {}
    lag_sums: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]] = {}
    swap_sums: dict[str, np.ndarray] = {}
    jitter_pooled: dict[str, dict[str, tuple[float, int]]] = {}
    orientation_pooled: dict[str, dict[str, list[np.ndarray]]] = {}
    for take in takes:
        for key, orientation_by_group in take.orientation.items():
            for group, values in orientation_by_group.items():
                orientation_pooled.setdefault(key, {}).setdefault(group, []).append(values)
        for key, jitter_by_group in take.jitter.items():
            slot_j = jitter_pooled.setdefault(key, {})
            for group, (sq, n) in jitter_by_group.items():
                old = slot_j.get(group, (0.0, 0))
                slot_j[group] = (old[0] + sq, old[1] + n)
        for key, (n_swapped, n_valid) in take.swaps.items():
            swap_sums[key] = swap_sums.get(key, np.zeros(2)) + np.array([n_swapped.sum(), n_valid.sum()])
        for key, by_protocol in take.errors.items():
            for protocol, acc in by_protocol.items():
                slot = pooled.setdefault(key, {}).setdefault(protocol, {})
                slot[take.gesture] = slot[take.gesture] + acc if take.gesture in slot else acc
        for key, lag_by_group in take.lag.items():
            for group, (s, c) in lag_by_group.items():
                lag_slot = lag_sums.setdefault(key, {})
                lag_slot[group] = (lag_slot[group][0] + s, lag_slot[group][1] + c) if group in lag_slot else (s, c)
    stats = {
        key: {p: {g: pooled[key][p][g].stats() for g in gestures if g in pooled[key][p]} for p in pooled[key]}
        for key in pooled
    }
    lag: dict[str, dict[str, dict[str, float]]] = {}
    for key, sums_by_group in lag_sums.items():
        lag[key] = {}
        for group, (s, c) in sums_by_group.items():
            frames, err = best_lag(s, c, LAG_SHIFTS)
            lag[key][group] = {"lag_frames": frames, "error_mm": err}
    infos = sorted((t.info for t in takes), key=lambda i: (gestures.index(i["gesture"]), i["facing_deg"]))
    swapped = {key: float(n[0] / n[1]) if n[1] > 0 else float("nan") for key, n in swap_sums.items()}
    jitter = {key: {g: jitter_rms(sq, n) for g, (sq, n) in by_group.items()} for key, by_group in jitter_pooled.items()}
    orientation = {
        key: {g: angle_stats(np.concatenate(parts)) for g, parts in by_group.items()}
        for key, by_group in orientation_pooled.items()
    }
    return PaperEvalResult(
        settings=settings,
        stats=stats,
        lag=lag,
        takes=infos,
        swapped=swapped,
        elapsed_s=elapsed_s,
        jitter=jitter,
        orientation=orientation,
    )


def run_paper_eval(
    *,
    quick: bool = False,
    seed: int = 0,
    duration_s: float | None = None,
    profile_path: str | Path | None = None,
    progress: bool = True,
    workers: int = 1,
    gestures: Sequence[str] | None = None,
    directions_deg: Sequence[float] | None = None,
    scenarios: Sequence[str] = SCENARIOS,
    ours: Sequence[str] = (OURS,),
) -> PaperEvalSuite:
    """Run the paper's three experiments on simulated takes in each scenario (:mod:`skelfuse.eval.report`
    writes the reports: ``write_suite``).

    Parameters
    ----------
    quick : bool
        CI mode: 2 gestures x 2 directions x 4 s takes (well under a minute) instead of 6 x 4 x 33 s
        (1000 frames, as the paper's takes).
    seed : int
        Master seed; each take derives its own motion and simulation seeds from it.
    duration_s : float or None
        Length of each take; None for the mode's default.
    profile_path : path or None
        Simulator noise profile (``skelfuse.sim.observe.load_profile``); None for the packaged default. The
        "paper" scenario switches its mirroring off.
    progress : bool
        Draw a progress bar on stderr (only when stderr is a terminal).
    workers : int
        Processes to spread the takes over (1 runs in this process).
    gestures, directions_deg : optional overrides of the takes (e.g. for tests).
    scenarios : names from ``SCENARIOS``
        Which scenarios to run, each a complete set of experiments.
    ours : preset names
        Our presets, run as extra rows beside the paper's (empty: the paper's algorithms only).

    Returns
    -------
    PaperEvalSuite
        One ``PaperEvalResult`` per scenario.
    """
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    scenarios = tuple(dict.fromkeys(scenarios))
    if not scenarios:
        raise ValueError(f"scenarios must name at least one of {SCENARIOS}")
    t0 = time.perf_counter()
    profile = None if profile_path is None else str(profile_path)
    tasks = plan_takes(
        quick=quick,
        seed=seed,
        duration_s=duration_s,
        profile_path=profile,
        gestures=gestures,
        directions_deg=directions_deg,
        scenarios=scenarios,
        ours=tuple(ours),
    )
    settings = {
        "quick": quick,
        "seed": seed,
        "scenarios": list(scenarios),
        "gestures": list(dict.fromkeys(t.gesture for t in tasks)),
        "directions_deg": list(dict.fromkeys(t.facing_deg for t in tasks)),
        "duration_s": tasks[0].duration_s,
        "fps": tasks[0].fps,
        "eps_mm": list(EPS_MM),
        "tnos_eps_mm": TNOS_EPS_MM,
        "ours": list(ours),
        "n_capture_sensors": N_CAPTURE,
        "lag_shifts_frames": [int(LAG_SHIFTS[0]), int(LAG_SHIFTS[-1])],
        "profile_path": profile,
        "workers": workers,
        "n_takes": len(tasks) // len(scenarios),
    }
    results: dict[str, list[TakeResult]] = {name: [] for name in scenarios}
    with Progress(len(tasks), "eval paper", enabled=None if progress else False) as bar:
        if workers == 1:
            for task in tasks:
                results[task.scenario].append(evaluate_take(task))
                bar.update(1, f"{task.scenario} {task.gesture} {task.facing_deg:.0f}°")
        else:
            # spawn: a fresh interpreter per worker, safe whatever threads the parent runs.
            with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn")) as pool:
                futures = {pool.submit(evaluate_take, task): task for task in tasks}
                for future in as_completed(futures):
                    task = futures[future]
                    results[task.scenario].append(future.result())
                    bar.update(1, f"{task.scenario} {task.gesture} {task.facing_deg:.0f}°")
    per_scenario = {
        name: collect(
            results[name],
            {
                **settings,
                "scenario": name,
                "scenario_description": SCENARIO_DESCRIPTIONS[name],
                "profile_change": {"flip_on_prob": 0.0} if name == "paper" else {},
            },
        )
        for name in scenarios
    }
    suite = PaperEvalSuite(per_scenario, settings)
    suite.elapsed_s = time.perf_counter() - t0
    for result in per_scenario.values():
        result.elapsed_s = suite.elapsed_s
    return suite
