"""The numpy forms of the stages that run as compiled kernels (:mod:`skelfuse.fusion.kernels`): the test reference.

The live path never imports this package (an import-linter contract in pyproject.toml holds it so). The tests
compare each kernel with its reference here on random inputs (NaN joints, empty bodies, a single sensor), and
``skelfuse bench instant --reference`` times the per-instant path with these forms in place of the kernels
(:data:`LIVE_STAGES`), so a speed-up is measured against them in the same run.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from skelfuse.fusion.reference import (
    association,
    filters,
    merge,
    orientation,
    pipeline,
    plausibility,
    realign,
    tracks,
    transform,
    uncertainty,
)

LIVE_STAGES: dict[tuple[str, str], Callable[..., Any]] = {
    ("skelfuse.fusion.pipeline", "merge_dbscan"): merge.merge_dbscan,
    ("skelfuse.fusion.pipeline", "filter_step"): filters.filter_step,
    ("skelfuse.fusion.smoother", "filter_step"): filters.filter_step,
    ("skelfuse.fusion.pipeline", "select_candidates"): pipeline.select_candidates,
    ("skelfuse.fusion.pipeline", "predicted_positions"): pipeline.predicted_positions,
    ("skelfuse.fusion.pipeline", "plausibility_step"): plausibility.plausibility_step,
    ("skelfuse.fusion.pipeline", "merge_views"): plausibility.merge_views,
    ("skelfuse.fusion.pipeline", "learn_bones"): plausibility.learn_bones,
    ("skelfuse.fusion.pipeline", "realign_temporal"): realign.realign_temporal,
    ("skelfuse.fusion.tracks", "seen_motion"): tracks.seen_motion,
    ("skelfuse.fusion.pipeline", "fuse_orientations"): orientation.fuse_orientations,
    ("skelfuse.fusion.association", "assign_to_tracks"): association.assign_to_tracks,
    ("skelfuse.fusion.association", "match_tracks"): association.match_tracks,
    ("skelfuse.fusion.association", "person_descriptors"): association.person_descriptors,
    ("skelfuse.fusion.pipeline", "position_uncertainty"): uncertainty.position_uncertainty,
    ("skelfuse.rig.instant", "stack_views_to_world"): transform.stack_views_to_world,
}
"""Where the live path looks each compiled stage up (module, name) -> its numpy reference."""
