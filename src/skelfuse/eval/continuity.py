"""Continuity of a fused body over time: the breaks a per-joint "far from every view" count cannot see.

When one view's tracker fails (loses the person, reports them upside down, re-acquires them elsewhere) and
the fusion follows it, the fused joint sits right on that view: it is never far from *every* view, so a gross
error count stays at zero. What shows the episode is the body's path:

``steps``
    instants where the fused pelvis moved faster than a person moves (:data:`MAX_PELVIS_SPEED_MM_S`,
    3 m/s: people walking in a capture space stay below 2-3 m/s; a tracker's re-acquisition jumps
    hundreds of millimetres in one frame);
``one_view_episodes``
    runs of instants in which the fused pelvis sat with one view only (within :data:`NEAR_MM` of it and
    farther than :data:`FAR_MM` from every other view that has a pelvis) and left the constant-velocity path
    of the instants before the run by more than :data:`BREAK_MM`: the fusion followed one view away from
    where the person was going. The episode lasts while the fused pelvis keeps siding with that one view.

Both are counted per take; ``one_view_frames`` is the episodes' total length in instants. Pure numpy.
"""

from __future__ import annotations

import numpy as np

from skelfuse.schema.skeleton import J

MAX_PELVIS_SPEED_MM_S = 3000.0
BREAK_MM = 100.0
NEAR_MM = 100.0
FAR_MM = 150.0


def pelvis_steps(fused: np.ndarray, times_s: np.ndarray, max_speed_mm_s: float = MAX_PELVIS_SPEED_MM_S) -> int:
    """Instants where the (T, 32, 3) fused pelvis moved faster than ``max_speed_mm_s`` since the previous one."""
    pelvis = np.asarray(fused, dtype=np.float64)[:, J["PELVIS"]]
    dt = np.diff(np.asarray(times_s, dtype=np.float64))
    with np.errstate(invalid="ignore", divide="ignore"):
        speed = np.linalg.norm(np.diff(pelvis, axis=0), axis=-1) / dt
    return int(np.sum(speed > max_speed_mm_s))


def one_view_episodes(fused: np.ndarray, views: np.ndarray) -> tuple[int, int]:
    """(episodes, instants) in which the fused pelvis broke from its path and followed one view alone.

    Parameters
    ----------
    fused : (T, 32, 3) mm; views : (T, S, 32, 3) mm, the same instants (NaN where a view has no body).
    """
    pelvis = np.asarray(fused, dtype=np.float64)[:, J["PELVIS"]]
    distance = np.linalg.norm(np.asarray(views, dtype=np.float64)[:, :, J["PELVIS"]] - pelvis[:, None], axis=-1)
    seen = np.isfinite(distance)
    near = (np.where(seen, distance, np.inf) <= NEAR_MM).sum(axis=1)
    far = (np.where(seen, distance, -np.inf) > FAR_MM).sum(axis=1)
    lone = (near == 1) & (far >= 1) & (near + far == seen.sum(axis=1))  # one view with it, the rest far off
    episodes = frames = 0
    t = 0
    while t < len(pelvis):  # run-length pass over the lone runs
        if not lone[t]:
            t += 1
            continue
        end = t
        while end < len(pelvis) and lone[end]:
            end += 1
        if t >= 3 and _left_path(pelvis, t, end):
            episodes += 1
            frames += end - t
        t = end
    return episodes, frames


def _left_path(pelvis: np.ndarray, start: int, end: int) -> bool:
    """The run [start, end) left the constant-velocity path of the instants before it (start - 3, start - 2: the
    instant just before may already be on the way) by more than BREAK_MM."""
    velocity = pelvis[start - 2] - pelvis[start - 3]
    steps = np.arange(start, end) - (start - 2)
    path = pelvis[start - 2] + steps[:, None] * velocity
    departure = np.linalg.norm(pelvis[start:end] - path, axis=-1)
    return bool(np.nanmax(departure, initial=0.0) > BREAK_MM) if np.isfinite(departure).any() else False


def continuity(fused: np.ndarray, views: np.ndarray, times_s: np.ndarray) -> dict[str, int]:
    """Every continuity count of a fused take (see the module docstring)."""
    episodes, frames = one_view_episodes(fused, views)
    return {"steps": pelvis_steps(fused, times_s), "one_view_episodes": episodes, "one_view_frames": frames}
