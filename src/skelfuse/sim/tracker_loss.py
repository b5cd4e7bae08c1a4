"""Tracker loss: a view's body tracker loses the person, reports them upside down, re-acquires them elsewhere.

The episode recorded on a real two-Kinect take (and reported on the SDK's issue tracker: bodies flipping
180 deg when a person leans back or turns away, re-acquisition under new ids): for about 0.1 s the view
reports the person turned upside down, then finds them again as a new body id at a different place (about
350 mm off) and stays there for a while before its fit comes back to the person. Profile keys (the
``[failures]`` section; the ``tracker_loss`` family of :mod:`skelfuse.sim.failures` switches them on):

* ``tracker_loss_prob``: per frame and view, an episode starts (only while the view tracks the person);
* ``tracker_loss_flip_frames``: frames the body is reported upside down (turned 180 deg about the
  horizontal axis through its pelvis that is square to the sensor's line of sight);
* ``tracker_loss_offset_mm``: how far away the re-acquired body is reported (a random horizontal direction);
* ``tracker_loss_away_frames``: frames the re-acquired body stays that far off before the fit returns.

A new body id starts at the flip and at the re-acquisition. Pure numpy over frames; one stream of its own.
"""

from __future__ import annotations

import numpy as np

from skelfuse.schema.skeleton import J


def tracker_loss_episodes(
    rng: np.random.Generator, tracked: np.ndarray, prob: float, flip_frames: int, away_frames: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the episodes are.

    Parameters
    ----------
    rng : the view's own stream; tracked : (T,) bool, the view tracks the person.
    prob : per frame, an episode starts; flip_frames, away_frames : the two phases' lengths.

    Returns
    -------
    flipped : (T,) bool, upside down; away : (T,) bool, re-acquired elsewhere; starts : (T,) bool, a new body id.
    """
    n = tracked.size
    uniform = rng.random(n)
    flipped = np.zeros(n, dtype=bool)
    away = np.zeros(n, dtype=bool)
    starts = np.zeros(n, dtype=bool)
    k = 0
    while k < n:  # episodes never overlap: the next one may start after this one ends
        if tracked[k] and uniform[k] < prob:
            flip_end = min(k + flip_frames, n)
            away_end = min(flip_end + away_frames, n)
            flipped[k:flip_end] = True
            away[flip_end:away_end] = True
            starts[k] = True
            if flip_end < n:
                starts[flip_end] = True
            k = away_end
        else:
            k += 1
    return flipped & tracked, away & tracked, starts & tracked


def apply_tracker_loss(
    positions: np.ndarray,
    flipped: np.ndarray,
    away: np.ndarray,
    down: np.ndarray,
    offset_mm: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """The view's (T, 32, 3) sensor-frame skeletons with the episodes applied (a new array).

    ``down`` is the world's down in the sensor frame (the tracker's "upside down" is about the world's up).
    """
    out = np.array(positions, dtype=np.float64, copy=True)
    down = np.asarray(down, dtype=np.float64) / np.linalg.norm(down)
    axis = np.cross(down, np.array([0.0, 0.0, 1.0]))  # horizontal, square to the line of sight
    if np.linalg.norm(axis) < 1e-6:  # a sensor looking straight down: any horizontal axis
        axis = np.cross(down, np.array([1.0, 0.0, 0.0]))
    axis /= np.linalg.norm(axis)
    half_turn = 2.0 * np.outer(axis, axis) - np.eye(3)  # 180 deg about the axis
    if flipped.any():
        pelvis = out[flipped, J["PELVIS"]][:, None]
        out[flipped] = pelvis + (out[flipped] - pelvis) @ half_turn.T
    if away.any():
        # One direction per episode: a run of consecutive away frames shares its draw.
        episode = np.cumsum(np.diff(np.concatenate([[False], away]).astype(np.int8)) == 1)
        angles = rng.uniform(0.0, 2.0 * np.pi, int(episode.max()) + 1)
        side = np.cross(axis, down)  # the other horizontal direction
        directions = np.cos(angles)[:, None] * axis + np.sin(angles)[:, None] * side
        out[away] += offset_mm * directions[episode[away]][:, None, :]
    return out
