"""Multi-person tracking evaluation: CLEAR-MOT and identity metrics on the crowd simulator.

:func:`clear_mot` scores a fused output (track ids and skeletons per frame) against the truth:

- Distance between a truth person and a track: mean distance (mm) of the mirror-invariant torso
  descriptor (:func:`skelfuse.fusion.association.torso_descriptor`). A pair is a possible match when it is
  within ``threshold_mm`` (default 500 mm).
- Per frame (Bernardin & Stiefelhagen 2008): correspondences of the previous frame are kept while still
  within the threshold; the rest are matched by Hungarian assignment on the distance.
- ID switch: a truth person matched to a track id other than the one it was last matched to (counted once
  per change). Fragmentation: a truth person's matched run interrupted (while present) and resumed,
  counted at the resumption.
- MOTA = 1 - (FN + FP + IDSW) / GT; MOTP = mean torso distance of the matches (mm).
- IDF1 (Ristani et al. 2016): one global truth <-> track id assignment (``linear_sum_assignment``) that
  maximises the frames both co-occur within the threshold; IDF1 = 2 IDTP / (GT + hypotheses).
- Per-person accuracy: RMSE of the paper's joint groups (torso, upper limb, lower limb) over the matched
  frames, per truth person.

Ground truth counts only where a person is *present and visible* (tracked by at least one sensor): no
fusion can output a person no sensor sees. A track counts as a hypothesis in a frame only where its torso
descriptor has at least 3 finite points (a coasting track whose filter gave up is not a hypothesis).

:func:`run_tracking_eval` runs :class:`skelfuse.fusion.people.PeopleFuser` over the crowd scenarios of
:mod:`skelfuse.sim.crowd` and returns a :class:`TrackingEvalResult` (``to_dict``, ``format_markdown``).

References
----------
K. Bernardin, R. Stiefelhagen, "Evaluating Multiple Object Tracking Performance: The CLEAR MOT Metrics",
EURASIP JIVP 2008. E. Ristani et al., "Performance Measures and a Data Set for Multi-Target, Multi-Camera
Tracking", ECCV workshops 2016.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from skelfuse.fusion.association import descriptor_distance, torso_descriptor
from skelfuse.fusion.people import PeopleFuser
from skelfuse.fusion.presets import preset
from skelfuse.schema.errors import ConfigError
from skelfuse.schema.skeleton import JOINT_GROUPS, N_JOINTS
from skelfuse.sim import crowd
from skelfuse.sim.observe import load_profile

DEFAULT_THRESHOLD_MM = 500.0


@dataclass(frozen=True)
class TrackingMetrics:
    """CLEAR-MOT and identity figures of one sequence (see the module docstring).

    ``per_person_rmse_mm``: per truth person, RMSE per joint group over its matched frames (NaN if none).
    """

    n_frames: int
    gt: int
    hypotheses: int
    matches: int
    false_negatives: int
    false_positives: int
    id_switches: int
    fragmentations: int
    mota: float
    motp_mm: float
    idtp: int
    idf1: float
    mostly_tracked: int
    mostly_lost: int
    n_truth: int
    n_track_ids: int
    per_person_rmse_mm: list[dict[str, float]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def clear_mot(
    truth: np.ndarray,
    truth_present: np.ndarray,
    hyp_ids: np.ndarray,
    hyp_positions: np.ndarray,
    *,
    threshold_mm: float = DEFAULT_THRESHOLD_MM,
) -> TrackingMetrics:
    """Score tracks against the truth.

    Parameters
    ----------
    truth : (T, P, J, 3) true joints, world mm.
    truth_present : (T, P) bool, where the truth person counts.
    hyp_ids : (T, H) int, track id per output slot; -1 = empty slot.
    hyp_positions : (T, H, J, 3) fused joints, world mm (NaN allowed).
    threshold_mm : largest torso distance of a match, mm.

    Returns
    -------
    TrackingMetrics
    """
    truth = np.asarray(truth, dtype=np.float64)
    hyp_positions = np.asarray(hyp_positions, dtype=np.float64)
    hyp_ids = np.asarray(hyp_ids, dtype=np.int64)
    truth_present = np.asarray(truth_present, dtype=bool)
    T, P = truth_present.shape
    if truth.shape != (T, P, N_JOINTS, 3) or hyp_positions.shape != (*hyp_ids.shape, N_JOINTS, 3):
        raise ValueError(
            f"shapes do not agree: truth {truth.shape}, truth_present {truth_present.shape}, "
            f"hyp_ids {hyp_ids.shape}, hyp_positions {hyp_positions.shape}"
        )
    if hyp_ids.shape[0] != T:
        raise ValueError(f"hyp_ids covers {hyp_ids.shape[0]} frames, the truth {T}")
    truth_desc = torso_descriptor(truth)  # (T, P, D, 3)
    hyp_desc = torso_descriptor(hyp_positions)  # (T, H, D, 3)
    hyp_ok = (hyp_ids >= 0) & (np.isfinite(hyp_desc).all(axis=-1).sum(axis=-1) >= 3)
    dist = descriptor_distance(truth_desc[:, :, None], hyp_desc[:, None, :])  # (T, P, H)
    dist = np.where(truth_present[:, :, None] & hyp_ok[:, None, :], dist, np.inf)

    all_ids = np.unique(hyp_ids[hyp_ok])
    id_col = {int(i): c for c, i in enumerate(all_ids)}
    cooccur = np.zeros((P, all_ids.size))
    tally = _Tally(P)
    for t in range(T):  # the CLEAR-MOT recursion is sequential over frames; each frame is a handful of people
        d = dist[t]
        ok = d <= threshold_mm
        g_idx, h_idx = np.nonzero(ok)
        for g_hit, h_hit in zip(g_idx, h_idx, strict=True):
            cooccur[g_hit, id_col[int(hyp_ids[t, h_hit])]] += 1
        pair = _frame_pairs(d, ok, hyp_ids[t], tally.prev_match, threshold_mm)
        tally.update(pair, truth_present[t], hyp_ids[t], d, hyp_positions[t], truth[t])
    return _metrics(tally, truth_present, hyp_ok, cooccur, all_ids)


def _frame_pairs(
    d: np.ndarray, ok: np.ndarray, ids: np.ndarray, prev_match: np.ndarray, threshold_mm: float
) -> dict[int, int]:
    """One frame's matches, truth person -> output slot: last frame's correspondences that still hold first,
    then a Hungarian assignment of the others within ``threshold_mm``. ``d``, ``ok``: (P, H)."""
    pair: dict[int, int] = {}
    for g in range(d.shape[0]):  # keep last frame's correspondences that still hold
        if prev_match[g] >= 0:
            cols = np.nonzero((ids == prev_match[g]) & ok[g])[0]
            if cols.size and cols[0] not in pair.values():
                pair[g] = int(cols[0])
    free_g = [g for g in range(d.shape[0]) if g not in pair and ok[g].any()]
    free_h = [h for h in range(ids.shape[0]) if h not in pair.values() and ok[:, h].any()]
    if free_g and free_h:
        sub = d[np.ix_(free_g, free_h)]
        r, c = linear_sum_assignment(np.where(np.isfinite(sub) & (sub <= threshold_mm), sub, 1e12))
        for i, j in zip(r, c, strict=True):
            if sub[i, j] <= threshold_mm:
                pair[free_g[i]] = free_h[j]
    return pair


class _Tally:
    """The CLEAR-MOT counts, accumulated frame by frame, per truth person where they are per person."""

    def __init__(self, n_truth: int) -> None:
        self.matched_frames = np.zeros(n_truth, dtype=np.int64)
        self.last_id = np.full(n_truth, -1, dtype=np.int64)  # last track id each truth was matched to (ever)
        self.prev_match = np.full(n_truth, -1, dtype=np.int64)  # track id matched in the previous frame
        self.ever, self.in_gap = np.zeros(n_truth, dtype=bool), np.zeros(n_truth, dtype=bool)
        self.sq_err = {name: np.zeros(n_truth) for name in JOINT_GROUPS}
        self.n_err = {name: np.zeros(n_truth) for name in JOINT_GROUPS}
        self.matches = self.idsw = self.frag = 0
        self.dist_sum = 0.0

    def update(
        self,
        pair: dict[int, int],
        present: np.ndarray,
        ids: np.ndarray,
        d: np.ndarray,
        hyp_positions: np.ndarray,
        truth: np.ndarray,
    ) -> None:
        """Count one frame's matches, switches, fragmentations and joint errors (arrays of that frame)."""
        self.prev_match[:] = -1
        for g in range(present.shape[0]):
            if not present[g]:
                continue
            if g in pair:
                h = pair[g]
                tid = int(ids[h])
                self.matches += 1
                self.matched_frames[g] += 1
                self.dist_sum += float(d[g, h])
                if self.last_id[g] >= 0 and self.last_id[g] != tid:
                    self.idsw += 1
                if self.in_gap[g]:
                    self.frag += 1
                self.last_id[g] = tid
                self.prev_match[g] = tid
                self.ever[g], self.in_gap[g] = True, False
                err = np.sum((hyp_positions[h] - truth[g]) ** 2, axis=-1)  # (J,)
                for name, joints in JOINT_GROUPS.items():
                    e = err[joints]
                    e = e[np.isfinite(e)]
                    self.sq_err[name][g] += e.sum()
                    self.n_err[name][g] += e.size
            elif self.ever[g]:
                self.in_gap[g] = True


def _metrics(
    tally: _Tally, truth_present: np.ndarray, hyp_ok: np.ndarray, cooccur: np.ndarray, all_ids: np.ndarray
) -> TrackingMetrics:
    """The summary figures of a finished tally (IDF1 from the best one-to-one truth / track id assignment)."""
    T, P = truth_present.shape
    present_frames = truth_present.sum(axis=0)
    matches, idsw, frag = tally.matches, tally.idsw, tally.frag
    gt = int(truth_present.sum())
    hyps = int(hyp_ok.sum())
    fn, fp = gt - matches, hyps - matches
    idtp = 0
    if cooccur.size:
        r, c = linear_sum_assignment(-cooccur)
        idtp = int(cooccur[r, c].sum())
    counted = present_frames > 0
    share = tally.matched_frames / np.maximum(present_frames, 1)
    sq_err, n_err = tally.sq_err, tally.n_err
    per_person = [
        {
            name: float(np.sqrt(sq_err[name][g] / n_err[name][g])) if n_err[name][g] else float("nan")
            for name in JOINT_GROUPS
        }
        for g in range(P)
    ]
    return TrackingMetrics(
        n_frames=T,
        gt=gt,
        hypotheses=hyps,
        matches=matches,
        false_negatives=fn,
        false_positives=fp,
        id_switches=idsw,
        fragmentations=frag,
        mota=1.0 - (fn + fp + idsw) / gt if gt else float("nan"),
        motp_mm=tally.dist_sum / matches if matches else float("nan"),
        idtp=idtp,
        idf1=2.0 * idtp / (gt + hyps) if gt + hyps else float("nan"),
        mostly_tracked=int(((share >= 0.8) & counted).sum()),
        mostly_lost=int(((share <= 0.2) & counted).sum()),
        n_truth=int(counted.sum()),
        n_track_ids=int(all_ids.size),
        per_person_rmse_mm=per_person,
    )


# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ScenarioResult:
    name: str
    n_people: int
    n_sensors: int
    metrics: TrackingMetrics
    step_p50_ms: float
    step_p99_ms: float

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["metrics"] = self.metrics.to_dict()
        return out


@dataclass(frozen=True)
class TrackingEvalResult:
    """Tracking metrics over the crowd scenarios."""

    preset: str
    seed: int
    quick: bool
    scenarios: list[ScenarioResult]

    def to_dict(self) -> dict[str, Any]:
        return {
            "preset": self.preset,
            "seed": self.seed,
            "quick": self.quick,
            "scenarios": [s.to_dict() for s in self.scenarios],
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrackingEvalResult:
        """Read back what :meth:`to_dict` wrote (docs/evidence.md is rendered from the stored JSON)."""
        scenarios = [ScenarioResult(**{**s, "metrics": TrackingMetrics(**s["metrics"])}) for s in data["scenarios"]]
        return cls(data["preset"], data["seed"], data["quick"], scenarios)

    def format_markdown(self) -> str:
        lines = [
            f"## Multi-person tracking (preset {self.preset}, seed {self.seed}{', quick' if self.quick else ''})",
            "",
            "| scenario | people | sensors | MOTA | MOTP mm | IDF1 | ID sw | frag | FN | FP | track ids | MT/ML |"
            " step p50/p99 ms |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for s in self.scenarios:
            m = s.metrics
            lines.append(
                f"| {s.name} | {s.n_people} | {s.n_sensors} | {m.mota:.3f} | {m.motp_mm:.1f} | {m.idf1:.3f} | "
                f"{m.id_switches} | {m.fragmentations} | {m.false_negatives} | {m.false_positives} | "
                f"{m.n_track_ids} | {m.mostly_tracked}/{m.mostly_lost} | {s.step_p50_ms:.2f}/{s.step_p99_ms:.2f} |"
            )
        lines += ["", "Per-person RMSE (mm) over matched frames: torso / upper limb / lower limb", ""]
        for s in self.scenarios:
            people = "; ".join(
                f"P{g}: {r['torso']:.1f} / {r['upper_limb']:.1f} / {r['lower_limb']:.1f}"
                for g, r in enumerate(s.metrics.per_person_rmse_mm)
            )
            lines.append(f"- {s.name}: {people}")
        return "\n".join(lines) + "\n"


def run_people(observations: Any, fuser: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run a PeopleFuser over CrowdObservations.

    Returns
    -------
    hyp_ids : (T, H) int64 (-1 padded), hyp_positions : (T, H, J, 3), step_ms : (T,) time per step.
    """
    world = observations.positions_world(calibrated=True)
    # Where each sensor stands (the rig's calibration), for the realignment's rear-view rule, as the node has.
    fuser.sensor_positions = observations.world_from_sensor_calibrated[:, :3, 3]
    T = observations.n_frames
    ids_list, pos_list, step_ms = [], [], np.zeros(T)
    for t in range(T):
        start = time.perf_counter_ns()
        result = fuser.step(world[t], observations.confidence[t], observations.valid[t], observations.times_s[t])
        step_ms[t] = (time.perf_counter_ns() - start) / 1e6
        ids_list.append(result.track_ids)
        pos_list.append(result.positions)
    H = max([1, *(ids.size for ids in ids_list)])
    hyp_ids = np.full((T, H), -1, dtype=np.int64)
    hyp_pos = np.full((T, H, N_JOINTS, 3), np.nan)
    for t, (ids, pos) in enumerate(zip(ids_list, pos_list, strict=True)):
        hyp_ids[t, : ids.size] = ids
        hyp_pos[t, : ids.size] = pos
    return hyp_ids, hyp_pos, step_ms


def run_tracking_eval(
    *, quick: bool = False, seed: int = 0, preset_name: str = "skelfuse", threshold_mm: float = DEFAULT_THRESHOLD_MM
) -> TrackingEvalResult:
    """Simulate the crowd scenarios, fuse them with :class:`~skelfuse.fusion.people.PeopleFuser` and score.

    Scenarios (:mod:`skelfuse.sim.crowd`): two people crossing 350 mm apart, a bystander seen by one sensor,
    people entering and leaving, a crowd of 4 on two counter-rotating rings (6 sensors). ``quick`` shortens
    every take.

    Raises
    ------
    ConfigError
        ``preset_name`` is not a fusion preset (the message lists them).
    """
    try:
        params = preset(preset_name)
    except ValueError as exc:
        raise ConfigError(f"--preset: {exc}") from None
    scale = 0.5 if quick else 1.0
    builders = [
        lambda: crowd.crossing_scenario(duration_s=8.0 * scale if not quick else 5.0, seed=seed),
        lambda: crowd.bystander_scenario(duration_s=6.0 * scale, seed=seed),
        lambda: crowd.enter_leave_scenario(duration_s=10.0 if not quick else 8.0, seed=seed),
        lambda: crowd.crowd_scenario(duration_s=8.0 * scale, seed=seed),
    ]
    profile = load_profile()
    results = []
    for build in builders:
        scenario = build()
        observations = crowd.simulate_scenario(scenario, profile, seed=seed)
        hyp_ids, hyp_pos, step_ms = run_people(observations, PeopleFuser(params))
        metrics = clear_mot(
            observations.truth, observations.present & observations.visible, hyp_ids, hyp_pos, threshold_mm=threshold_mm
        )
        results.append(
            ScenarioResult(
                name=scenario.name,
                n_people=observations.n_people,
                n_sensors=observations.n_sensors,
                metrics=metrics,
                step_p50_ms=float(np.percentile(step_ms, 50)),
                step_p99_ms=float(np.percentile(step_ms, 99)),
            )
        )
    return TrackingEvalResult(preset=preset_name, seed=seed, quick=quick, scenarios=results)
