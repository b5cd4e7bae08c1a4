"""``skelfuse bench latency``'s node figures: exact percentiles over every measured instant, from the samples each
status window carries (percentiles of windows do not merge)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skelfuse.bench.latency import _merge_windows
from skelfuse.config import load_rig_config
from skelfuse.service.node import FusionNode, _percentiles
from skelfuse.wire.codec import decode_status


def _windows(values: np.ndarray, per_window: int, with_samples: bool) -> list[dict]:
    """Status infos as a node writes them, one per ``per_window`` values."""
    windows = []
    for start in range(0, len(values), per_window):
        part = values[start : start + per_window].tolist()
        info = {"node_added_ms": _percentiles(part)}
        if with_samples:
            info["node_added_ms_samples"] = [round(v, 4) for v in part]
        windows.append(info)
    return windows


def test_node_percentiles_are_exact_over_every_instant_of_the_windows() -> None:
    # A run of 300 instants in 0.5 s windows of 15, with a heavy tail: one slow instant in about fifty.
    rng = np.random.default_rng(16)
    values = np.round(2.0 + rng.gamma(2.0, 0.2, 300) + (rng.random(300) < 0.02) * rng.uniform(3, 9, 300), 4)
    merged = _merge_windows(_windows(values, 15, with_samples=True), "node_added_ms")
    assert merged == {
        "p50": round(float(np.percentile(values, 50)), 4),
        "p99": round(float(np.percentile(values, 99)), 4),
        "max": float(values.max()),
    }
    # Without the samples (a node from before them), only each window's percentiles: the largest window p99 of 15
    # instants is about the run's max, far above its p99.
    old = _merge_windows(_windows(values, 15, with_samples=False), "node_added_ms")
    assert old["max"] == float(values.max()) and old["p99"] > merged["p99"] + 1.0


def test_windows_without_instants_give_no_figures() -> None:
    empty = [{"node_added_ms": _percentiles([]), "node_added_ms_samples": []}] * 3
    assert _merge_windows(empty, "node_added_ms") == {"p50": None, "p99": None, "max": None}
    assert _merge_windows([{"node_added_ms": _percentiles([])}], "node_added_ms") == {
        "p50": None,
        "p99": None,
        "max": None,
    }


class _Publisher:
    def __init__(self) -> None:
        self.payloads: list[bytes] = []

    def put(self, payload: bytes) -> None:
        self.payloads.append(payload)


def test_each_status_carries_its_windows_values_and_starts_a_new_window() -> None:
    node = FusionNode(load_rig_config(Path(__file__).resolve().parents[2] / "config" / "rig-sim-4.toml"), None)
    publisher = _Publisher()
    node._window_added.extend([1.23456, 2.5, 9.0])
    node._window_fusion.extend([1.0, 2.0, 3.0])
    node._publish_status(publisher, None, 10**9)
    node._publish_status(publisher, None, 2 * 10**9)
    first, second = (decode_status(p).info for p in publisher.payloads)
    assert first["node_added_ms_samples"] == [1.2346, 2.5, 9.0] and first["fusion_ms_samples"] == [1.0, 2.0, 3.0]
    assert first["node_added_ms"]["n"] == 3
    assert second["node_added_ms_samples"] == [] and second["node_added_ms"]["n"] == 0
