"""``skelfuse bench fusion``: time per fused frame, vectorized core against a straightforward reference.

Both fusers run over the same seeded input frames from the same start state. The reference
(:mod:`skelfuse.bench.reference`: scikit-learn DBSCAN per joint and one filterpy KalmanFilter per joint)
implements the same documented semantics, so the outputs must agree; the benchmark checks that and reports
the speed-up as a ratio measured in the same run, next to the absolute figures.

Timing follows the ping-pong pattern: warm-up frames, then one ``perf_counter_ns`` sample per frame, and
the distribution (p50 / p99 / max), never a mean alone.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from skelfuse.bench.reference import ReferenceFuser
from skelfuse.fusion.pipeline import Fuser
from skelfuse.fusion.presets import preset
from skelfuse.schema.skeleton import N_JOINTS, PARENTS, Confidence

OUTPUT_TOLERANCE_MM = 1e-6
"""Largest difference between the two fusers' outputs that still counts as "the same output"."""


@dataclass(frozen=True)
class BenchCase:
    """Timings of one (sensors, bodies) case; times in milliseconds per fused frame."""

    n_sensors: int
    n_bodies: int
    fast_p50_ms: float
    fast_p99_ms: float
    fast_max_ms: float
    reference_p50_ms: float
    reference_p99_ms: float
    speedup_p50: float
    max_abs_diff_mm: float
    fast_frames: int
    reference_frames: int

    @property
    def outputs_match(self) -> bool:
        return self.max_abs_diff_mm <= OUTPUT_TOLERANCE_MM


@dataclass(frozen=True)
class FusionBenchResult:
    preset: str
    cases: list[BenchCase] = field(default_factory=list)
    numpy_version: str = np.__version__

    @property
    def outputs_match(self) -> bool:
        return all(case.outputs_match for case in self.cases)

    def to_dict(self) -> dict[str, Any]:
        return {
            "preset": self.preset,
            "numpy_version": self.numpy_version,
            "outputs_match": self.outputs_match,
            "tolerance_mm": OUTPUT_TOLERANCE_MM,
            "cases": [asdict(case) | {"outputs_match": case.outputs_match} for case in self.cases],
        }


def make_inputs(n_frames: int, n_sensors: int, n_bodies: int, *, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Seeded fusion inputs that exercise every branch: agreement, outliers, mirrored pairs, gaps.

    Returns
    -------
    candidates : (T, B, S, 32, 3) float64, world mm; NaN where a sensor misses a body or a joint
    confidence : (T, B, S, 32) uint8
    """
    rng = np.random.default_rng(seed)
    # A body: a smooth random walk of the pelvis plus a fixed random pose hanging off the parent chain.
    offsets = rng.normal(0.0, 150.0, size=(n_bodies, N_JOINTS, 3))
    offsets[:, 0] = 0.0
    pose = np.zeros_like(offsets)
    for joint in range(1, N_JOINTS):  # set-up only, not timed
        pose[:, joint] = pose[:, PARENTS[joint]] + offsets[:, joint]
    drift = np.cumsum(rng.normal(0.0, 8.0, size=(n_frames, n_bodies, 1, 3)), axis=0)
    wobble = np.cumsum(rng.normal(0.0, 3.0, size=(n_frames, n_bodies, N_JOINTS, 3)), axis=0)
    truth = (
        pose[None]
        + drift
        + wobble
        + np.array([0.0, 0.0, 1000.0])
        + 2000.0 * np.arange(n_bodies)[None, :, None, None] * np.array([1.0, 0.0, 0.0])
    )
    noise = rng.normal(0.0, 15.0, size=(n_frames, n_bodies, n_sensors, N_JOINTS, 3))
    candidates = truth[:, :, None] + noise
    # Outliers (occlusion guesses): 10% of candidates thrown 150-400 mm away, labelled LOW.
    outlier = rng.random((n_frames, n_bodies, n_sensors, N_JOINTS)) < 0.10
    direction = rng.normal(size=(*outlier.shape, 3))
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    candidates += outlier[..., None] * direction * rng.uniform(150.0, 400.0, size=(*outlier.shape, 1))
    confidence = np.where(outlier, Confidence.LOW, Confidence.MEDIUM).astype(np.uint8)
    # Gaps: 3% of joints unreported, and 2% of whole sensor views missing a body.
    gap = rng.random((n_frames, n_bodies, n_sensors, N_JOINTS)) < 0.03
    gap |= (rng.random((n_frames, n_bodies, n_sensors)) < 0.02)[..., None]
    candidates[gap] = np.nan
    confidence[gap] = Confidence.NONE
    return candidates, confidence


def _percentiles_ms(samples_ns: np.ndarray) -> tuple[float, float, float]:
    p50, p99 = np.percentile(samples_ns, [50, 99])
    return float(p50) / 1e6, float(p99) / 1e6, float(samples_ns.max()) / 1e6


def bench_case(
    n_sensors: int, n_bodies: int, *, preset_name: str, n_frames: int, reference_frames: int, warmup: int = 20
) -> BenchCase:
    """Time the vectorized and the reference fuser on the same inputs; compare their outputs frame by frame."""

    params = preset(preset_name)
    total = warmup + max(n_frames, reference_frames)
    candidates, confidence = make_inputs(total, n_sensors, n_bodies, seed=1000 * n_sensors + n_bodies)
    dt_s = 1.0 / 30.0

    # Each fuser runs in its own pass: interleaving a 10+ ms scikit-learn step before every fast step would
    # time the fast path with cold caches and branch predictors. Outputs are compared afterwards.
    checked = warmup + reference_frames
    fast = Fuser(params, n_bodies=n_bodies)
    fast_ns: list[int] = []
    fast_positions: list[np.ndarray] = []
    for frame in range(warmup + n_frames):
        start = time.perf_counter_ns()
        fused = fast.step(candidates[frame], confidence[frame], dt_s)
        elapsed = time.perf_counter_ns() - start
        if frame >= warmup:
            fast_ns.append(elapsed)
        if frame < checked:
            fast_positions.append(fused.positions)

    reference = ReferenceFuser(params, n_bodies=n_bodies)  # loads scikit-learn and filterpy (the dev extra)
    reference_ns: list[int] = []
    max_diff = 0.0
    for frame in range(checked):
        start = time.perf_counter_ns()
        expected = reference.step(candidates[frame], confidence[frame], dt_s)
        elapsed = time.perf_counter_ns() - start
        if frame >= warmup:
            reference_ns.append(elapsed)
        max_diff = max(max_diff, _max_abs_diff(fast_positions[frame], expected.positions))
    fast_p50, fast_p99, fast_max = _percentiles_ms(np.asarray(fast_ns))
    ref_p50, ref_p99, _ = _percentiles_ms(np.asarray(reference_ns))
    return BenchCase(
        n_sensors=n_sensors,
        n_bodies=n_bodies,
        fast_p50_ms=fast_p50,
        fast_p99_ms=fast_p99,
        fast_max_ms=fast_max,
        reference_p50_ms=ref_p50,
        reference_p99_ms=ref_p99,
        speedup_p50=ref_p50 / fast_p50,
        max_abs_diff_mm=max_diff,
        fast_frames=n_frames,
        reference_frames=reference_frames,
    )


def _max_abs_diff(a: np.ndarray, b: np.ndarray) -> float:
    """Largest difference, where NaN must sit in the same places in both (else infinite)."""
    nan_a, nan_b = np.isnan(a), np.isnan(b)
    if (nan_a != nan_b).any():
        return float("inf")
    if nan_a.all():
        return 0.0
    return float(np.abs(a[~nan_a] - b[~nan_b]).max())


def run_fusion_bench(
    *,
    sensor_counts: Sequence[int] = (1, 2, 4, 5, 8, 16),
    body_counts: Sequence[int] = (1, 3, 6),
    preset_name: str = "A5",
    n_frames: int = 300,
    quick: bool = False,
    progress: bool = True,
) -> FusionBenchResult:
    """Benchmark every (sensors, bodies) combination; ``quick`` keeps a few cases and frames for CI."""
    if quick:
        sensor_counts = [n for n in sensor_counts if n in (1, 5)] or list(sensor_counts)[:1]
        body_counts = [n for n in body_counts if n in (1, 3)] or list(body_counts)[:1]
        n_frames = min(n_frames, 60)
    if min(sensor_counts) < 1 or min(body_counts) < 1 or n_frames < 1:
        raise ValueError("sensor counts, body counts and --frames must all be at least 1")
    result = FusionBenchResult(preset=preset_name)
    combos = [(s, b) for b in body_counts for s in sensor_counts]
    for index, (n_sensors, n_bodies) in enumerate(combos, start=1):
        # The reference is 100-1000x slower: time it on fewer frames so big rigs finish in seconds.
        reference_frames = max(10, min(n_frames, 3000 // (n_sensors * n_bodies)))
        if progress:
            print(f"[{index}/{len(combos)}] {n_sensors} sensors x {n_bodies} bodies ...", file=sys.stderr)
        result.cases.append(
            bench_case(
                n_sensors, n_bodies, preset_name=preset_name, n_frames=n_frames, reference_frames=reference_frames
            )
        )
    return result


def format_table(result: FusionBenchResult) -> str:
    """A markdown table of the cases, with the verdict on output agreement."""
    lines = [
        f"Fusion time per frame, preset {result.preset} (numpy {result.numpy_version}); reference = "
        "scikit-learn DBSCAN per joint + one filterpy KalmanFilter per joint, same inputs, same run.",
        "",
        "| sensors | bodies | skelfuse p50 ms | p99 ms | max ms | reference p50 ms | p99 ms | speed-up (p50) "
        "| max diff mm |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for c in result.cases:
        lines.append(
            f"| {c.n_sensors} | {c.n_bodies} | {c.fast_p50_ms:.3f} | {c.fast_p99_ms:.3f} | {c.fast_max_ms:.3f} "
            f"| {c.reference_p50_ms:.2f} | {c.reference_p99_ms:.2f} | {c.speedup_p50:.0f}x | {c.max_abs_diff_mm:.1e} |"
        )
    verdict = (
        "outputs agree on every case"
        if result.outputs_match
        else f"OUTPUTS DIFFER (tolerance {OUTPUT_TOLERANCE_MM} mm): see max diff"
    )
    lines += ["", verdict]
    return "\n".join(lines)
