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

import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.eval.metrics import (
    ErrorAccumulator,
    angle_stats,
    angular_errors,
    best_lag,
    jitter_rms,
    jitter_sums,
    lag_error_curve,
    swap_counts,
)
from skelfuse.fusion.orientation import views_to_world
from skelfuse.fusion.pipeline import Fuser
from skelfuse.fusion.transform import apply_transform
from skelfuse.progress import Progress
from skelfuse.schema.skeleton import EVAL_JOINTS, JOINT_GROUPS, N_JOINTS, PAPER_REALIGN_PAIRS
from skelfuse.sim.gestures import GESTURES, make_gesture
from skelfuse.sim.observe import load_profile, simulate
from skelfuse.sim.orientation import observe_orientations, truth_orientations
from skelfuse.sim.rig import best_view_sensor, paper_rig

__all__ = [  # with the plan's and the result's names, which the report and the tests reach through here
    "BEST_VIEW_RAW",
    "DIRECTIONS_DEG",
    "EPS_MM",
    "EXACT_TRUTH",
    "EXPERIMENTS",
    "GROUP_NAMES",
    "LAG_SHIFTS",
    "N_CAPTURE",
    "OURS",
    "PAPER_PRESETS",
    "PROTOCOLS",
    "SCENARIOS",
    "SCENARIO_DESCRIPTIONS",
    "FusionRun",
    "PaperEvalResult",
    "PaperEvalSuite",
    "TakeResult",
    "TakeTask",
    "collect",
    "evaluate_take",
    "fuse_sequence",
    "fuse_take",
    "fuse_take_oriented",
    "fusion_runs",
    "is_ours",
    "plan_takes",
    "run_paper_eval",
    "scenario_profile",
    "sensor_combinations",
]

from skelfuse.eval.paper_plan import (
    BEST_VIEW_RAW,
    DEFAULT_DURATION_S,
    DIRECTIONS_DEG,
    EPS_MM,
    EXACT_TRUTH,
    EXPERIMENTS,
    FPS,
    GROUP_NAMES,
    LAG_SHIFTS,
    N_CAPTURE,
    OURS,
    PAPER_PRESETS,
    PROTOCOLS,
    QUICK_DIRECTIONS_DEG,
    QUICK_DURATION_S,
    QUICK_GESTURES,
    SCENARIO_DESCRIPTIONS,
    SCENARIOS,
    TNOS_EPS_MM,
    FusionRun,
    _raw_key,
    fusion_runs,
    is_ours,
    scenario_profile,
    sensor_combinations,
)
from skelfuse.eval.paper_result import (
    PaperEvalResult,
    PaperEvalSuite,
)

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
    return _fuse_bodies(params, candidates[:, None], confidence[:, None], fps, sensor_positions)[:, 0]


def _fuse_bodies(
    params: Any, candidates: np.ndarray, confidence: np.ndarray, fps: float, sensor_positions: np.ndarray | None = None
) -> np.ndarray:
    """:func:`fuse_sequence` of B bodies fused side by side: ``candidates`` (T, B, S, 32, 3), ``confidence``
    (T, B, S, 32); returns (T, B, 32, 3)."""
    cand = np.ascontiguousarray(candidates)
    conf = np.ascontiguousarray(confidence)
    fuser = Fuser(
        _positions_only(params, keep_orientations=False), n_bodies=cand.shape[1], sensor_positions=sensor_positions
    )
    out = np.full((cand.shape[0], cand.shape[1], N_JOINTS, 3), np.nan)
    dt_s = 1.0 / fps
    for t in range(cand.shape[0]):
        out[t] = fuser.step(cand[t], conf[t], dt_s=dt_s).positions
    return out


def fuse_runs(
    runs: Sequence[FusionRun],
    candidates: np.ndarray,
    confidence: np.ndarray,
    fps: float,
    sensor_positions: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """:func:`fuse_take` of every run, by key: the same positions, in fewer calls of the fuser (its bodies are
    fused independently, and a call costs about as much for a few bodies as for one). A configuration that keeps
    nothing from frame to frame fuses all frames at once (one body per frame); runs sharing a configuration and
    a sensor count fuse side by side (one body per run); the "temporal" realignment, the only stage that reads
    ``sensor_positions``, gets each run's own sensors' positions."""
    fused: dict[str, np.ndarray] = {}
    together: dict[tuple[str, float | None, int], list[FusionRun]] = {}
    for run in runs:
        params = _positions_only(run.params(), keep_orientations=False)
        sensors = list(run.sensors)
        if _keeps_no_state(params):
            fuser = Fuser(params, n_bodies=candidates.shape[0])
            result = fuser.step(candidates[:, sensors], confidence[:, sensors], dt_s=1.0 / fps)
            fused[run.key] = np.asarray(result.positions)
        else:
            together.setdefault((run.preset, run.eps_mm, len(sensors)), []).append(run)
    for group in together.values():
        positions = None if sensor_positions is None else np.asarray(sensor_positions)
        stacked = _fuse_bodies(
            group[0].params(),
            np.stack([candidates[:, list(run.sensors)] for run in group], axis=1),
            np.stack([confidence[:, list(run.sensors)] for run in group], axis=1),
            fps,
            None if positions is None else np.stack([positions[list(run.sensors)] for run in group]),
        )
        fused.update((run.key, stacked[:, k]) for k, run in enumerate(group))
    return {run.key: fused[run.key] for run in runs}


def _keeps_no_state(params: Any) -> bool:
    """Whether a fused frame depends on that frame's views alone (``params`` a ``FusionParams``)."""
    kept = (params.previous_weight, params.filter, params.plausibility_gate_mm)  # each keeps state when set
    return params.realign != "temporal" and all(value is None for value in kept)


def _positions_only(params: Any, *, keep_orientations: bool) -> Any:
    """``params`` (a ``FusionParams``) without the outputs that never change the fused positions and that this
    module does not score: the per-joint position uncertainty, and the orientations unless kept. The positions
    are the same bit for bit; a "skelfuse" run takes about a third of the time."""
    if keep_orientations:
        return replace(params, position_std=False)
    return replace(params, orientations=False, position_std=False)


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
    fuser = Fuser(
        _positions_only(run.params(), keep_orientations=True), n_bodies=1, sensor_positions=positions_of_sensors
    )
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
    obs = _simulate_take(task)
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
        orientation[key] = _orientation_errors(quats, true_quats)

    for sensor in range(N_CAPTURE):
        score_orientation(_raw_key(sensor), view_quats[:, sensor])
    score_orientation(BEST_VIEW_RAW, view_quats[:, N_CAPTURE])

    t1 = time.perf_counter()
    runs = fusion_runs(N_CAPTURE, task.eps_values, ours=task.ours)
    sensor_positions = obs.world_from_sensor_calibrated[:N_CAPTURE, :3, 3]  # as the live node knows them
    oriented = [run for run in runs if run.params().orientations and len(run.sensors) == N_CAPTURE]
    fused_by_key = fuse_runs(
        [run for run in runs if run not in oriented], capture, confidence, task.fps, sensor_positions
    )
    for run in runs:
        if run in oriented:
            fused, fused_quats = fuse_take_oriented(
                run, capture, confidence, view_quats[:, :N_CAPTURE], task.fps, sensor_positions
            )
            score_orientation(run.key, fused_quats)
        else:
            fused = fused_by_key[run.key]
        score(run.key, fused, with_lag=len(run.sensors) == N_CAPTURE)
    t_fuse = time.perf_counter() - t1

    info = _take_info(task, obs, n_frames=int(truth.shape[0]), n_runs=len(runs), simulate_s=t_sim, fuse_s=t_fuse)
    return TakeResult(task.gesture, task.facing_deg, errors, lag, info, swaps, jitter, task.scenario, orientation)


def _simulate_take(task: TakeTask) -> Any:
    """The take's observations: its gesture seen by the four capture sensors and the best-view sensor."""
    motion = make_gesture(
        task.gesture,
        duration_s=task.duration_s,
        fps=task.fps,
        facing_deg=task.facing_deg,
        seed=task.motion_seed,
    )
    sensors = [*list(paper_rig(N_CAPTURE)), best_view_sensor(task.facing_deg)]
    profile = scenario_profile(load_profile(task.profile_path), task.scenario)
    return simulate(motion, sensors, profile, seed=task.sim_seed)


def _orientation_errors(quats: np.ndarray, true_quats: np.ndarray) -> dict[str, np.ndarray]:
    """Angular error of each joint group's finite orientations, degrees (float32, the result's storage)."""
    errors = angular_errors(quats, true_quats)
    return {g: errors[:, idx][np.isfinite(errors[:, idx])].astype(np.float32) for g, idx in JOINT_GROUPS.items()}


def _take_info(
    task: TakeTask, obs: Any, *, n_frames: int, n_runs: int, simulate_s: float, fuse_s: float
) -> dict[str, Any]:
    """What the take was and how the views tracked it (tracked and mirrored share per sensor), with its timing."""
    tracked = np.asarray(obs.tracked, dtype=bool)
    mirrored = np.asarray(obs.mirrored, dtype=bool) & tracked
    return {
        "scenario": task.scenario,
        "gesture": task.gesture,
        "facing_deg": task.facing_deg,
        "n_frames": n_frames,
        "tracked_fraction": [float(x) for x in tracked.mean(axis=0)],
        "mirrored_fraction": [float(x) for x in mirrored.mean(axis=0)],
        "simulate_s": simulate_s,
        "fuse_s": fuse_s,
        "n_fusion_steps": n_frames * n_runs,
    }


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
    settings = _run_settings(
        tasks, quick=quick, seed=seed, scenarios=scenarios, ours=ours, profile=profile, workers=workers
    )
    results = _run_takes(tasks, scenarios, workers=workers, progress=progress)
    per_scenario = {name: collect(results[name], {**settings, **_scenario_settings(name)}) for name in scenarios}
    suite = PaperEvalSuite(per_scenario, settings)
    suite.elapsed_s = time.perf_counter() - t0
    for result in per_scenario.values():
        result.elapsed_s = suite.elapsed_s
    return suite


def _run_settings(
    tasks: Sequence[TakeTask],
    *,
    quick: bool,
    seed: int,
    scenarios: Sequence[str],
    ours: Sequence[str],
    profile: str | None,
    workers: int,
) -> dict[str, Any]:
    """The run's settings as the result records them (what was run, so a reader can rerun it)."""
    return {
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


def _scenario_settings(name: str) -> dict[str, Any]:
    """What a scenario adds to the run's settings: its description and its change to the profile."""
    return {
        "scenario": name,
        "scenario_description": SCENARIO_DESCRIPTIONS[name],
        "profile_change": {"flip_on_prob": 0.0} if name == "paper" else {},
    }


def _run_takes(
    tasks: Sequence[TakeTask], scenarios: Sequence[str], *, workers: int, progress: bool
) -> dict[str, list[TakeResult]]:
    """Every take's result by scenario, in this process or spread over ``workers`` processes."""
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
    return results
