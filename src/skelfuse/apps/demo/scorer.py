"""The live demo's subscriber: scores the fused stream against the simulator's ground truth as it arrives."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from skelfuse.apps.demo import CONVERGE_S
from skelfuse.apps.demo.summary import group_errors, per_pass_errors, scoring_window
from skelfuse.fusion.transform import apply_transform
from skelfuse.schema.skeleton import EVAL_JOINTS
from skelfuse.wire.codec import DecodeError, decode_fused_frame, decode_sensor_frame


class LiveScorer:
    """The demo's subscriber: fused frames against ground truth, latency from the workers' publish stamps.

    Zenoh callbacks (several threads) only decode and store under a lock; scores are computed at the end.
    """

    def __init__(
        self,
        truth: np.ndarray,
        fps: float,
        poses_calibrated: np.ndarray,
        sensor_ids: tuple[str, ...],
        origin_n: int = 0,
    ) -> None:

        self.truth = truth
        self.origin_n = origin_n  # the instant at which the workers play take frame 0
        self.period_us = 1e6 / fps
        self.poses = poses_calibrated
        self.column = {sid: i for i, sid in enumerate(sensor_ids)}
        self.lock = threading.Lock()
        self.published_ns: dict[int, int] = {}  # instant -> latest publish wall time among its sensor frames
        self.fused: list[tuple[int, np.ndarray, int]] = []  # (instant, (32, 3) world mm, receive wall ns)
        self.converged: list[bool] = []  # per fused entry: its track is at least CONVERGE_S old
        self.start_n = origin_n  # the pass the scored run starts with (run_demo moves it when workers come late)
        self.track_birth_us: dict[int, int] = {}
        self.single: list[list[tuple[int, np.ndarray]]] = [[] for _ in sensor_ids]
        self.first_fused: float | None = None
        self.on_error: Callable[[int, float], None] | None = None

    def instant(self, time_us: int) -> int:
        return round(time_us / self.period_us)

    def on_sensor(self, sample: Any) -> None:

        try:
            frame = decode_sensor_frame(sample.payload.to_bytes())
        except DecodeError:
            return
        n = self.instant(frame.device_time_us)
        column = self.column.get(frame.sensor_id)
        world = None
        if column is not None and frame.n_bodies:
            world = apply_transform(self.poses[column : column + 1], frame.positions[:1])[0]
        with self.lock:
            self.published_ns[n] = max(self.published_ns.get(n, 0), frame.host_time_ns)
            if world is not None and column is not None:
                self.single[column].append((n, world))

    def on_fused(self, sample: Any) -> None:

        received = time.time_ns()
        try:
            frame = decode_fused_frame(sample.payload.to_bytes())
        except DecodeError:
            return
        # One simulated person; when the take loops it jumps back to its start and gets a new track id while
        # the old track coasts out, and a view the tracker got wrong can start a short-lived track of its own:
        # score the person most sensors measured in this instant (no ground truth in the choice).
        seen_by = frame.contributors.sum(axis=1)
        if not seen_by.any():
            return
        person = int(np.argmax(seen_by))
        positions = frame.positions[person]
        track = int(frame.track_ids[person])
        n = self.instant(frame.time_us)
        with self.lock:
            birth = self.track_birth_us.setdefault(track, frame.time_us)
            self.converged.append(frame.time_us - birth >= CONVERGE_S * 1e6)
            self.fused.append((n, positions, received))
            if self.first_fused is None:
                self.first_fused = time.monotonic()
        if self.on_error is not None:
            error = np.linalg.norm(
                positions[EVAL_JOINTS] - self.truth[(n - self.origin_n) % len(self.truth), EVAL_JOINTS], axis=-1
            )
            if np.isfinite(error).any():
                self.on_error(frame.time_us, float(np.nanmean(error)))

    def scores(self, run_frames: int) -> tuple[Any, ...]:
        """Errors over the scoring window (:func:`scoring_window`) of the ``run_frames`` from ``start_n``."""
        with self.lock:
            everything = list(self.fused)
            converged = list(self.converged)
            single = [list(s) for s in self.single]
            published = dict(self.published_ns)
        T = len(self.truth)
        fps = 1e6 / self.period_us
        pass_of = scoring_window(
            np.array([n for n, _, _ in everything], dtype=np.int64), self.start_n, T, run_frames, fps
        )
        keep = [i for i, (p, ok) in enumerate(zip(pass_of, converged, strict=True)) if p >= 0 and ok]
        fused = [everything[i] for i in keep]
        per_pass: list[float] = []
        if fused:
            estimate = np.stack([p for _, p, _ in fused])
            truth = self.truth[[(n - self.origin_n) % T for n, _, _ in fused]]
            fused_errors = group_errors(estimate, truth)
            per_pass = per_pass_errors(estimate, truth, pass_of[keep])
        else:
            fused_errors = {k: float("nan") for k in ("torso", "upper_limb", "lower_limb", "all16")}
        best_id, best = "", {k: float("nan") for k in fused_errors}
        fused_instants = {n for n, _, _ in fused}
        for sensor_id, column in self.column.items():
            rows = [(n, w) for n, w in single[column] if n in fused_instants]
            if not rows:
                continue
            errors = group_errors(
                np.stack([w for _, w in rows]), self.truth[[(n - self.origin_n) % T for n, _ in rows]]
            )
            if not best_id or errors["all16"] < best["all16"]:
                best_id, best = sensor_id, errors
        latency = [(received - published[n]) / 1e6 for n, _, received in everything if n in published]
        in_run = sum(self.start_n <= n < self.start_n + run_frames for n, _, _ in everything)
        return in_run, len(everything) - in_run, len(fused), fused_errors, best, best_id, latency, per_pass
