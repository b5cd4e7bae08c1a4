"""Each view's mirroring rate on a real rig: what ``skelfuse eval real`` measures so that a rig's own rate can
be set against the simulator's rear-view mirroring sweep (``skelfuse eval robustness --mirroring-sweep``).

Two measures per view, over the instants where the view holds the body's torso:

- ``realigned``: the share of instants skelfuse's realignment found the view left/right mirrored (and swapped
  it): the pure per-person fusion (:class:`skelfuse.fusion.pipeline.Fuser`, the ``skelfuse`` preset, the
  sensors' positions for the rear-view rule) run over the views, its ``flipped`` flags counted. This is the
  product's own decision, so it inherits the realignment's errors (a mirrored view it misses is not counted);
- ``against_majority`` (three views or more): the share of decided instants where the view's left/right axis
  points against the majority of the other views' (:func:`skelfuse.eval.real.mirrored_frames`), a check that
  does not go through the realignment. With two views there is no majority: the rate cannot be told apart from
  the other view's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from skelfuse.eval.real import mirrored_frames
from skelfuse.fusion.pipeline import Fuser
from skelfuse.fusion.presets import preset
from skelfuse.schema.skeleton import J

_TORSO = [J["PELVIS"], J["NECK"], J["HIP_LEFT"], J["HIP_RIGHT"], J["SHOULDER_LEFT"], J["SHOULDER_RIGHT"]]


def view_mirroring(
    world: np.ndarray,
    confidence: np.ndarray,
    sensor_ids: Sequence[str],
    sensor_positions: np.ndarray,
    *,
    evaluated: slice = slice(None),
    preset_name: str = "skelfuse",
    fps: float = 30.0,
) -> dict[str, dict[str, float]]:
    """Per view: ``realigned`` and ``against_majority`` shares (module docstring) and ``instants`` counted.

    Parameters
    ----------
    world : (T, S, 32, 3) every instant's view of the person, world mm, NaN where a view has no body.
    confidence : (T, S, 32) uint8.
    sensor_ids : the S views' names.
    sensor_positions : (S, 3) world mm, where each sensor stands (the realignment's rear-view rule).
    evaluated : the instants counted (the fusion runs over all, so its state is warm).
    """
    world = np.asarray(world, dtype=np.float64)
    fuser = Fuser(preset(preset_name), n_bodies=1, sensor_positions=sensor_positions)
    flipped = np.zeros(world.shape[:2], dtype=bool)
    for t in range(world.shape[0]):
        result = fuser.step(world[t][None], np.asarray(confidence[t])[None], dt_s=1.0 / fps)
        if result.flipped is not None:
            flipped[t] = result.flipped[0]
    views = world[evaluated]
    present = np.isfinite(views[:, :, _TORSO]).all(axis=(-1, -2))  # (T, S)
    flipped = flipped[evaluated] & present
    out: dict[str, dict[str, float]] = {}
    for s, sensor_id in enumerate(sensor_ids):
        n = int(present[:, s].sum())
        row = {"instants": float(n), "realigned": float(flipped[:, s].sum() / n) if n else math.nan}
        if len(sensor_ids) >= 3:
            others = np.moveaxis(np.delete(views, s, axis=1), 1, 0)
            against, decided = mirrored_frames(views[:, s], others)
            row["against_majority"] = float(against.sum() / decided.sum()) if decided.any() else math.nan
        out[sensor_id] = row
    return out
