"""Loop-by-loop reference implementation of :mod:`skelfuse.fusion`: the oracle for tests and benchmarks.

It implements the semantics documented in :mod:`skelfuse.fusion.realign`, :mod:`skelfuse.fusion.merge`,
:mod:`skelfuse.fusion.filters` and :mod:`skelfuse.fusion.pipeline`, written independently of the
vectorized code (including the "temporal" realignment's cold-start and recovery policy, and the filter's
prediction as trick 2's candidate): plain Python loops over bodies, sensors and joints, scikit-learn
``DBSCAN(min_samples=1)``
per joint, and one filterpy ``KalmanFilter`` per joint. It is slow on purpose (about 100x), clear rather
than fast; "both give the same output" is what the benchmark and the pipeline tests check.

scikit-learn and filterpy (the dev extra) load when a :class:`ReferenceFuser` is built, so that importing this
module, and the benchmarks beside it, needs neither (:func:`reference_libraries`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from skelfuse.fusion.pipeline import FusionResult
from skelfuse.fusion.presets import FusionParams
from skelfuse.schema.errors import ConfigError
from skelfuse.schema.skeleton import MIRROR_PAIRS, N_JOINTS, PAPER_REALIGN_PAIRS, J

MEDIUM = 2


@dataclass(frozen=True)
class ReferenceLibraries:
    """The reference's oracles: scikit-learn's DBSCAN (and its config context), filterpy's Kalman filter."""

    sklearn_config_context: Any
    DBSCAN: Any
    KalmanFilter: Any
    Q_discrete_white_noise: Any


def reference_libraries() -> ReferenceLibraries:
    """scikit-learn and filterpy, loaded now.

    Raises
    ------
    ConfigError
        One of them is not installed (they come with the dev extra).
    """
    try:
        import sklearn
        from filterpy.common import Q_discrete_white_noise
        from filterpy.kalman import KalmanFilter
        from sklearn.cluster import DBSCAN
    except ImportError as exc:
        raise ConfigError(
            f"the scikit-learn + filterpy reference fusion needs both: {exc}; "
            f'install them with `pip install -e ".[dev]"`'
        ) from None
    return ReferenceLibraries(sklearn.config_context, DBSCAN, KalmanFilter, Q_discrete_white_noise)


class _Track:
    """Filter of one joint: a filterpy KalmanFilter, or the alpha-beta position and velocity."""

    def __init__(self, params: FusionParams, z: np.ndarray, libraries: ReferenceLibraries) -> None:
        self.coast = 0
        self.kind = params.filter
        self.libraries = libraries
        KalmanFilter = libraries.KalmanFilter
        if self.kind == "paper_kalman":
            kf = KalmanFilter(dim_x=3, dim_z=3)
            kf.F = np.eye(3)
            kf.H = np.eye(3)
            kf.Q = params.kalman_q_mm2 * np.eye(3)
            kf.R = params.kalman_r_mm2 * np.eye(3)
            kf.P = params.kalman_p0_mm2 * np.eye(3)
            kf.x = z.reshape(3, 1).copy()
            self.kf = kf
        elif self.kind == "cv_kalman":
            kf = KalmanFilter(dim_x=6, dim_z=3)  # state (x, vx, y, vy, z, vz)
            kf.H = np.zeros((3, 6))
            kf.H[[0, 1, 2], [0, 2, 4]] = 1.0
            kf.P = np.kron(np.eye(3), np.diag([params.cv_meas_sigma_mm**2, params.cv_velocity0_sigma_mm_s**2]))
            kf.x = np.zeros((6, 1))
            kf.x[[0, 2, 4], 0] = z
            self.kf = kf
        else:
            self.position = z.copy()
            self.velocity = np.zeros(3)

    def step(self, params: FusionParams, z: np.ndarray | None, n_agree: int, dt_s: float) -> np.ndarray:
        """Predict, output, update; returns this frame's output position."""
        if self.kind == "paper_kalman":
            self.kf.predict()
            out = self.kf.x[:, 0].copy()  # eq. 9: output the prediction
            if z is not None:
                self.kf.update(z.reshape(3, 1))
            return out
        if self.kind == "cv_kalman":
            self.kf.F = np.kron(np.eye(3), np.array([[1.0, dt_s], [0.0, 1.0]]))
            self.kf.Q = self.libraries.Q_discrete_white_noise(
                dim=2, dt=dt_s, var=params.cv_accel_sigma_mm_s2**2, block_size=3
            )
            self.kf.predict()
            if z is not None:
                r = params.cv_meas_sigma_mm**2
                if params.cv_scale_r_by_agree:
                    r /= max(n_agree, 1)
                self.kf.update(z.reshape(3, 1), R=r * np.eye(3))
            return self.kf.x[[0, 2, 4], 0].copy()
        predicted = self.position + self.velocity * dt_s
        if z is None:
            self.position = predicted
        else:
            residual = z - predicted
            self.position = predicted + params.alpha * residual
            self.velocity = self.velocity + params.beta * residual / dt_s
        return self.position.copy()


class ReferenceFuser:
    """Slow, obvious implementation of :class:`skelfuse.fusion.pipeline.Fuser` (same inputs and outputs)."""

    def __init__(self, params: FusionParams, n_bodies: int = 1, sensor_positions: np.ndarray | None = None) -> None:
        self.params = params
        self.n_bodies = n_bodies
        self.sensor_positions = sensor_positions
        self.libraries = reference_libraries()
        self.reset()

    def reset(self) -> None:
        self.previous: list[list[np.ndarray | None]] = [[None] * N_JOINTS for _ in range(self.n_bodies)]
        self.tracks: list[list[_Track | None]] = [[None] * N_JOINTS for _ in range(self.n_bodies)]
        self.flip_counters: list[tuple[int, int, int, int]] = [(0, 0, 0, 0)] * self.n_bodies

    def step(self, candidates: np.ndarray, confidence: np.ndarray, dt_s: float = 1.0 / 30.0) -> FusionResult:
        # Inputs are checked here; scikit-learn's own per-call validation would dominate the run time.
        with self.libraries.sklearn_config_context(assume_finite=True, skip_parameter_validation=True):
            return self._step(np.asarray(candidates), np.asarray(confidence), dt_s)

    def _step(self, candidates: np.ndarray, confidence: np.ndarray, dt_s: float) -> FusionResult:
        B, S, J, _ = candidates.shape
        positions = np.full((B, J, 3), np.nan)
        n_agree = np.zeros((B, J), dtype=np.int16)
        conf_out = np.zeros((B, J), dtype=np.uint8)
        contributors = np.zeros((B, S), dtype=bool)
        for b in range(B):
            pos, conf = self._select(candidates[b], confidence[b])
            previous = [self._previous_candidate(b, j, dt_s) for j in range(J)]
            if self.params.realign == "paper":
                pos, conf = _realign_paper(pos, conf)
            elif self.params.realign == "body":
                pos, conf = _realign_body(pos, conf, self.params.realign_passes)
            elif self.params.realign == "temporal":
                pos, conf, self.flip_counters[b] = _realign_temporal(
                    pos, conf, previous, self.flip_counters[b], self.params, dt_s, self.sensor_positions
                )
            for j in range(J):
                merged, members, best_conf = self._merge_joint(pos, conf, j, previous[j])
                self.previous[b][j] = merged
                if merged is not None:
                    n_agree[b, j] = len(members)
                    conf_out[b, j] = best_conf
                    contributors[b, members] = True
                positions[b, j] = self._filter_joint(b, j, merged, len(members), dt_s)
        return FusionResult(positions=positions, n_agree=n_agree, confidence=conf_out, contributors=contributors)

    def _previous_candidate(self, b: int, j: int, dt_s: float) -> np.ndarray | None:
        """Trick 2's candidate: the last merged position, or the live filter track's one-step prediction."""
        track = self.tracks[b][j]
        if self.params.previous_candidate == "merged" or track is None or track.kind not in ("cv_kalman", "alpha_beta"):
            return self.previous[b][j]
        if track.kind == "cv_kalman":
            state = track.kf.x[:, 0]
            return np.array([state[0] + dt_s * state[1], state[2] + dt_s * state[3], state[4] + dt_s * state[5]])
        return track.position + dt_s * track.velocity

    def _select(self, cand: np.ndarray, conf: np.ndarray) -> tuple[list[list], list[list[int]]]:
        S, J = conf.shape
        pos: list[list[np.ndarray | None]] = [[None] * J for _ in range(S)]
        out_conf = [[0] * J for _ in range(S)]
        for s in range(S):
            for j in range(J):
                ok = bool(np.all(np.isfinite(cand[s, j])))
                if self.params.min_confidence is not None and conf[s, j] < self.params.min_confidence:
                    ok = False
                if ok:
                    pos[s][j] = np.asarray(cand[s, j], dtype=np.float64)
                    out_conf[s][j] = int(conf[s, j])
        return pos, out_conf

    def _merge_joint(
        self, pos: list[list], conf: list[list[int]], j: int, previous: np.ndarray | None
    ) -> tuple[np.ndarray | None, list[int], int]:
        """Returns (merged position or None, sensor indices averaged, their highest confidence)."""
        sensors = [s for s in range(len(pos)) if pos[s][j] is not None]
        if not sensors:
            return None, [], 0
        if self.params.merge == "average":
            return np.mean([pos[s][j] for s in sensors], axis=0), sensors, max(conf[s][j] for s in sensors)
        points = [pos[s][j] for s in sensors]
        kinds = ["sensor"] * len(sensors)
        weights = [1.0] * len(sensors)
        if self.params.reference_weight is not None:
            ref = _reference(pos, conf, j)
            if ref is not None:
                points.append(ref)
                kinds.append("ref")
                weights.append(self.params.reference_weight)
        if self.params.previous_weight is not None and previous is not None:
            points.append(previous)
            kinds.append("prev")
            weights.append(self.params.previous_weight)
        # Nc = 1 and every weight counted by hand (sample_weight below 1 would make a point non-core).
        labels = (
            self.libraries.DBSCAN(eps=self.params.eps_mm, min_samples=1, algorithm="brute")
            .fit(np.array(points))
            .labels_
        )
        best_key = None
        best = None
        for label in sorted(set(labels.tolist())):
            idx = [i for i in range(len(points)) if labels[i] == label]
            cluster_sensors = [sensors[i] for i in idx if kinds[i] == "sensor"]
            if not cluster_sensors:
                continue
            score = 0.0
            for i in idx:
                score += weights[i]
            centroid = np.mean([pos[s][j] for s in cluster_sensors], axis=0)
            rounded: np.ndarray = np.round(np.asarray(centroid), 6)
            key = (
                score,
                any(kinds[i] == "prev" for i in idx),
                len(cluster_sensors),
                any(kinds[i] == "ref" for i in idx),
                sum(conf[s][j] for s in cluster_sensors),
                -rounded[0],
                -rounded[1],
                -rounded[2],
                -min(cluster_sensors),
            )
            if best_key is None or key > best_key:
                best_key, best = key, (centroid, cluster_sensors)
        assert best is not None  # the loop above always has a cluster with a sensor: the candidates include them
        centroid, members = best
        return centroid, members, max(conf[s][j] for s in members)

    def _filter_joint(self, b: int, j: int, z: np.ndarray | None, n_agree: int, dt_s: float) -> np.ndarray:
        if self.params.filter is None:
            return z if z is not None else np.full(3, np.nan)
        track = self.tracks[b][j]
        if track is None:
            if z is None:
                return np.full(3, np.nan)
            self.tracks[b][j] = _Track(self.params, z, self.libraries)
            return z
        out = track.step(self.params, z, n_agree, dt_s)
        if z is not None:
            track.coast = 0
            return out
        track.coast += 1
        if track.coast > self.params.max_coast_frames:
            self.tracks[b][j] = None
            return np.full(3, np.nan)
        return out


def _reference(pos: list[list], conf: list[list[int]], j: int) -> np.ndarray | None:
    """Mean of the joint's valid candidates in the best tier present (MEDIUM+ > LOW > NONE)."""
    tiers = [min(conf[s][j], MEDIUM) for s in range(len(pos)) if pos[s][j] is not None]
    if not tiers:
        return None
    best = max(tiers)
    return np.mean(
        [pos[s][j] for s in range(len(pos)) if pos[s][j] is not None and min(conf[s][j], MEDIUM) == best], axis=0
    )


def _swap(pos: list[list], conf: list[list[int]], s: int, left: int, right: int) -> None:
    pos[s][left], pos[s][right] = pos[s][right], pos[s][left]
    conf[s][left], conf[s][right] = conf[s][right], conf[s][left]


def _realign_paper(pos: list[list], conf: list[list[int]]) -> tuple[list[list], list[list[int]]]:
    pos = [row[:] for row in pos]
    conf = [row[:] for row in conf]
    for left, right in PAPER_REALIGN_PAIRS.tolist():
        ref_right = _reference(pos, conf, right)  # pairs are disjoint: earlier swaps do not touch it
        if ref_right is None:
            continue
        for s in range(len(pos)):
            if pos[s][left] is None or pos[s][right] is None:
                continue
            if np.linalg.norm(ref_right - pos[s][right]) > np.linalg.norm(ref_right - pos[s][left]):
                _swap(pos, conf, s, left, right)
    return pos, conf


def _realign_body(pos: list[list], conf: list[list[int]], passes: int) -> tuple[list[list], list[list[int]]]:
    S = len(pos)
    mirrored = [False] * S
    for _ in range(passes):
        current_pos = [row[:] for row in pos]
        current_conf = [row[:] for row in conf]
        for s in range(S):
            if mirrored[s]:
                for left, right in PAPER_REALIGN_PAIRS.tolist():
                    _swap(current_pos, current_conf, s, left, right)
        refs = {j: _reference(current_pos, current_conf, j) for j in PAPER_REALIGN_PAIRS.ravel().tolist()}
        decided = []
        for s in range(S):
            total = 0.0
            for left, right in PAPER_REALIGN_PAIRS.tolist():
                pl, pr, rl, rr = pos[s][left], pos[s][right], refs[left], refs[right]
                if pl is None or pr is None or rl is None or rr is None:
                    continue
                keep = math.dist(rr, pr) + math.dist(rl, pl)
                swap = math.dist(rr, pl) + math.dist(rl, pr)
                total += swap - keep
            decided.append(total < 0.0)
        mirrored = decided
    pos = [row[:] for row in pos]
    conf = [row[:] for row in conf]
    for s in range(S):
        if mirrored[s]:
            for left, right in MIRROR_PAIRS.tolist():
                _swap(pos, conf, s, left, right)
    return pos, conf


def _teleported(pos: list[list], previous: list[np.ndarray | None], max_jump_mm: float) -> bool:
    """The body centre (mean of both shoulders and hips) is further than ``max_jump_mm`` from the previous
    skeleton's in every view that has all four."""
    centre = [J["SHOULDER_LEFT"], J["SHOULDER_RIGHT"], J["HIP_LEFT"], J["HIP_RIGHT"]]
    if any(previous[j] is None for j in centre):
        return False
    then = np.mean([p for j in centre if (p := previous[j]) is not None], axis=0)  # all four: checked above
    views = [np.mean([row[j] for j in centre], axis=0) for row in pos if all(row[j] is not None for j in centre)]
    return bool(views) and all(math.dist(now, then) > max_jump_mm for now in views)


def _realign_temporal(
    pos: list[list],
    conf: list[list[int]],
    previous: list[np.ndarray | None],
    counters: tuple[int, int, int, int],
    params: FusionParams,
    dt_s: float,
    sensor_positions: np.ndarray | None = None,
) -> tuple[list[list], list[list[int]], tuple[int, int, int, int]]:
    """Whole-body flip per sensor against the previous skeleton (seed view on a cold start), with recovery."""
    S = len(pos)
    pairs = PAPER_REALIGN_PAIRS.tolist()
    clear, simple, views_seen, rear_streak = counters
    if params.max_body_speed_mm_s is not None and _teleported(pos, previous, params.max_body_speed_mm_s * dt_s):
        previous = [None] * len(previous)  # the anchor is of another pose: start cold
    n_views = sum(
        1 for s in range(S) if any(pos[s][left] is not None and pos[s][right] is not None for left, right in pairs)
    )
    if n_views > views_seen:  # more views than built the anchor: start cold, forget the previous skeleton
        prev_has = [False] * len(pairs)
    else:
        prev_has = [previous[left] is not None and previous[right] is not None for left, right in pairs]
    cold = not any(prev_has)
    evidence = []
    present = []
    for s in range(S):
        present.append(sum(1 for pair in pairs for j in pair if pos[s][j] is not None))
        evidence.append(sum(1 for j in range(len(pos[s])) if pos[s][j] is not None and conf[s][j] >= MEDIUM))
    seed = 0
    for s in range(1, S):  # most MEDIUM joints, then most pair joints; the lowest index on a tie
        if (evidence[s], present[s]) > (evidence[seed], present[seed]):
            seed = s
    anchors = []
    for p, (left, right) in enumerate(pairs):
        if prev_has[p]:
            anchors.append((previous[left], previous[right]))
        elif cold and pos[seed][left] is not None and pos[seed][right] is not None:
            anchors.append((pos[seed][left], pos[seed][right]))
        else:
            anchors.append((_reference(pos, conf, left), _reference(pos, conf, right)))
    flipped = [False] * S
    decided = [False] * S
    for s in range(S):
        total = 0.0
        for (left, right), (a_left, a_right) in zip(pairs, anchors, strict=True):
            p_left, p_right = pos[s][left], pos[s][right]
            if p_left is None or p_right is None or a_left is None or a_right is None:
                continue
            decided[s] = True
            keep = math.dist(a_right, p_right) + math.dist(a_left, p_left)
            swap = math.dist(a_right, p_left) + math.dist(a_left, p_right)
            total += (swap - keep) / max(2.0 * math.dist(a_left, a_right), 1.0)  # each pair votes in [-1, 1]
        flipped[s] = total < 0.0
    against = sum(evidence[s] for s in range(S) if flipped[s])
    weight = sum(evidence[s] for s in range(S) if decided[s])
    rear_against = rear_for = 0  # decided views facing away from their own sensor, by their decision
    if sensor_positions is not None and params.rear_view_cos is not None:
        for s in range(S):
            if decided[s] and _faces_away(pos[s], sensor_positions[s], params.rear_view_cos):
                rear_against += flipped[s]
                rear_for += not flipped[s]
    invert = False
    if cold:
        if rear_against != rear_for:  # the group holding more rear views facing away is right
            invert = rear_against > rear_for
        else:
            invert = against > weight - against  # the flipped group holds more MEDIUM evidence
        clear = simple = rear_streak = 0
        views_seen = n_views
    else:
        confirmed = rear_for > rear_against
        if weight > 0 and against >= params.recovery_share * weight and not confirmed:
            clear += 1
        elif sum(decided) >= max(views_seen, 2) and not any(flipped):  # every view vouches for the anchor: credit
            clear = max(min(clear, 0) - 1, -params.recovery_credit_frames)
        else:
            clear = min(clear, 0)
        simple = simple + 1 if against > weight - against and not confirmed else 0
        rear_streak = rear_streak + 1 if rear_against > rear_for else 0
        slow = params.majority_recovery_frames
        if (
            clear >= params.recovery_frames
            or (slow is not None and simple >= slow)
            or rear_streak >= params.rear_view_frames + min(max(-clear, 0), params.recovery_frames)
        ):
            invert = True
            clear = simple = rear_streak = 0
    pos = [row[:] for row in pos]
    conf = [row[:] for row in conf]
    for s in range(S):
        if flipped[s] != (invert and decided[s]):
            for left, right in MIRROR_PAIRS.tolist():
                _swap(pos, conf, s, left, right)
    return pos, conf, (clear, simple, views_seen, rear_streak)


def _faces_away(joints: list, sensor_position: np.ndarray, max_cos: float) -> bool:
    """True when the view's skeleton, as labelled, faces away from its sensor: the cosine between its facing
    (left x up from the hips and shoulders) and the horizontal direction to the sensor is below ``max_cos``."""
    names = ("SHOULDER_LEFT", "SHOULDER_RIGHT", "HIP_LEFT", "HIP_RIGHT")
    quad = [joints[J[name]] for name in names]
    if any(p is None for p in quad):
        return False
    left = np.asarray(quad[0]) - quad[1] + quad[2] - quad[3]
    facing = np.array([left[1], -left[0]])
    centre = np.mean(quad, axis=0)
    to_sensor = np.asarray(sensor_position[:2], dtype=float) - centre[:2]
    norms = max(math.hypot(*facing) * math.hypot(*to_sensor), 1e-9)
    return bool(float(facing @ to_sensor) / norms < max_cos)
