"""What the demo prints at the end: :class:`DemoSummary`, its scoring window and its text.

The live and the offline demo score the same way (:func:`scoring_window`, the paper's joint groups), so that
their figures compare.
"""

from __future__ import annotations

import math
import sys
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from skelfuse.apps.demo import CONVERGE_S, DEMO_TAKE_S
from skelfuse.schema.skeleton import EVAL_JOINTS, JOINT_GROUPS


@dataclass(frozen=True)
class DemoSummary:
    """What the demo prints at the end. Errors are mean Euclidean distances to ground truth, mm.

    ``latency_*``: publish of the last sensor frame of an instant -> its fused frame received by a zenoh
    subscriber (live demo only); ``node_added_*``: the fusion node's own share of it.
    """

    frames_fused: int
    duration_s: float
    gesture: str
    preset: str
    n_sensors: int
    error_fused_mm: dict[str, float]
    error_best_single_sensor_mm: dict[str, Any]  # the groups' errors (mm) and "sensor": which one
    fusion_p50_ms: float
    fusion_p99_ms: float
    recording: str | None
    latency_p50_ms: float | None = None
    latency_p99_ms: float | None = None
    node_added_p50_ms: float | None = None
    node_added_p99_ms: float | None = None
    mode: str = "offline"
    frames_scored: int | None = None
    """Fused frames the errors are computed over: the scoring window of every whole pass of the take."""
    frames_before_run: int = 0
    """Live: frames fused while the rig came up, before the run's ``duration_s`` began (not in ``frames_fused``)."""
    converge_s: float = CONVERGE_S
    take_s: float = DEMO_TAKE_S
    """Length of the looping take; each pass is scored over take time [converge_s, take_s)."""
    passes_scored: int = 1
    partial_pass: bool = False
    """The run was shorter than one pass: only its part of the window is scored (not comparable)."""
    error_fused_per_pass_mm: list[float] | None = None
    """The fused ``all16`` error of each scored pass (they agree: every pass is the same material)."""

    def to_dict(self) -> dict[str, Any]:
        """As JSON takes it: a figure that could not be computed (nothing scored) is None, not NaN."""

        def finite(value: Any) -> Any:
            if isinstance(value, float) and not math.isfinite(value):
                return None
            if isinstance(value, dict):
                return {k: finite(v) for k, v in value.items()}
            if isinstance(value, list):
                return [finite(v) for v in value]
            return value

        return finite(asdict(self))


def progress_line(text: str, *, final: bool = False) -> None:
    """A progress line on stderr: redrawn in place on a terminal, one plain line each in a log file."""
    if sys.stderr.isatty():
        print(f"\r{text:<60}", end="\n" if final else "", file=sys.stderr, flush=True)
    elif text:
        print(text, file=sys.stderr, flush=True)


def group_errors(estimate: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Mean distance per paper joint group over frames where the estimate exists; (T, 32, 3) inputs."""
    distance = np.linalg.norm(estimate - truth, axis=-1)
    out = {}
    for group, joints in JOINT_GROUPS.items():
        values = distance[:, joints]
        out[group] = float(np.mean(values[np.isfinite(values)])) if np.isfinite(values).any() else float("nan")
    values = distance[:, EVAL_JOINTS]
    out["all16"] = float(np.mean(values[np.isfinite(values)])) if np.isfinite(values).any() else float("nan")
    return out


def scoring_window(instants: np.ndarray, start_n: int, take_frames: int, run_frames: int, fps: float) -> np.ndarray:
    """Pass index of each instant in the demo's scoring window, -1 outside it.

    ``start_n`` is the instant at which a pass of the take begins (take frame 0) and the run's scored part
    starts; the window is take time [CONVERGE_S, take) of every whole pass of the ``run_frames`` from there
    (of the one, partial pass when the run is shorter than a pass).
    """
    offset = np.asarray(instants, dtype=np.int64) - start_n
    passes = max(1, run_frames // take_frames)
    pass_index = offset // take_frames
    inside = (offset >= 0) & (pass_index < passes) & (offset % take_frames >= round(CONVERGE_S * fps))
    return np.where(inside, pass_index, -1)


def per_pass_errors(estimate: np.ndarray, truth: np.ndarray, pass_index: np.ndarray) -> list[float]:
    """The ``all16`` error of each pass (``pass_index`` per frame, as :func:`scoring_window` gives it)."""
    passes = int(pass_index.max()) + 1 if len(pass_index) else 0
    return [group_errors(estimate[pass_index == p], truth[pass_index == p])["all16"] for p in range(passes)]


def format_summary(summary: DemoSummary) -> str:
    best = summary.error_best_single_sensor_mm
    lines = [
        f"Fused {summary.frames_fused} frames ({summary.duration_s:.1f} s of '{summary.gesture}') from "
        f"{summary.n_sensors} simulated sensors with preset {summary.preset}"
        + (f" ({summary.frames_before_run} more while the rig came up)." if summary.frames_before_run else "."),
        "",
    ]
    if not summary.frames_scored:
        lines.append(
            f"Accuracy not scored: the run stopped before {summary.converge_s:.1f} s of a pass of the take had played "
            f"(the scoring window is {_window_text(summary)})."
        )
    else:
        lines += [
            f"Mean error against the simulator's ground truth (mm), {summary.frames_scored} frames scored: "
            + _window_text(summary)
            + ":",
            "| | torso | upper limb | lower limb | all 16 |",
            "|---|---:|---:|---:|---:|",
        ]
        for label, errors in (("fused", summary.error_fused_mm), (f"best single sensor ({best['sensor']})", best)):
            lines.append(
                f"| {label} | {errors['torso']:.1f} | {errors['upper_limb']:.1f} | {errors['lower_limb']:.1f} "
                f"| {errors['all16']:.1f} |"
            )
    per_pass = summary.error_fused_per_pass_mm or []
    if len(per_pass) > 1:
        lines.append(f"Fused, all 16, pass by pass: {', '.join(f'{e:.1f}' for e in per_pass)} mm.")
    lines += ["", f"Fusion time per frame: p50 {summary.fusion_p50_ms:.3f} ms, p99 {summary.fusion_p99_ms:.3f} ms."]
    if summary.latency_p50_ms is not None and summary.latency_p99_ms is not None:
        lines.append(
            f"Latency, sensor publish -> fused frame received over zenoh: "
            f"p50 {summary.latency_p50_ms:.2f} ms, p99 {summary.latency_p99_ms:.2f} ms."
        )
    if summary.node_added_p50_ms is not None and summary.node_added_p99_ms is not None:
        lines.append(
            f"Added by the fusion node (last frame in -> fused frame out): p50 "
            f"{summary.node_added_p50_ms:.3f} ms, p99 {summary.node_added_p99_ms:.3f} ms."
        )
    if summary.recording:
        lines.append(f"Recording saved to {summary.recording}; open it with:  rerun {summary.recording}")
    return "\n".join(lines)


def _window_text(summary: DemoSummary) -> str:
    """What the figures cover, in words (the scoring window)."""
    window = f"take seconds {summary.converge_s:.1f}-{summary.take_s:.1f}"
    if summary.partial_pass:
        return (
            f"{window} of the {summary.take_s:.0f} s take, cut short by --duration: a run shorter than one pass "
            f"scores only part of the take; run at least {summary.take_s:.0f} s for the comparable figure"
        )
    return (
        f"{window} of each of {summary.passes_scored} whole pass(es) of the {summary.take_s:.0f} s take, which "
        f"loops (every pass is the same material: the same figure for any --duration >= {summary.take_s:.0f} s; "
        "the first seconds of a pass, while the fused track settles, are not scored)"
    )
