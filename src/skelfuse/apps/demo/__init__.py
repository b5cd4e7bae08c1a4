"""``skelfuse demo``: a simulated 4-sensor rig fused frame by frame and drawn in Rerun.

The first thing a new user runs. It needs no sensor and no data: the simulator plays a person walking
through a rig of four virtual Azure Kinects (rear views mirror left and right, occluded joints are guessed,
everything trembles), the fusion core merges the views frame by frame, and Rerun shows the raw and fused
skeletons live. Where there is no screen the recording is saved to a .rrd file instead.

Two modes:

* live (default, :func:`run_demo`): the real service on loopback zenoh: four capture workers
  (``python -m skelfuse capture`` subprocesses, one per virtual sensor, each in its own process group),
  the fusion node in this process, and a subscriber that scores the fused stream against the simulator's
  ground truth (the demo knows the motion) and measures latency from the workers' publish timestamps.
  Peer mode with explicit ``tcp/127.0.0.1`` endpoints and multicast scouting off, so it runs in CI
  sandboxes. Child processes are always stopped (SIGTERM to their group, then SIGKILL); a spawned Rerun
  viewer is left open for the user.
* offline (``--offline``, :func:`run_demo_offline`): the same per-frame cycle in one loop, no zenoh.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

from skelfuse.service.worker import DEFAULT_TAKE_S

DEFAULT_RRD = Path("skelfuse-demo.rrd")
DEMO_RIG = "demo"
CONVERGE_S = 1.5
"""Accuracy is scored from this long after a fused track appears, and from this long into each pass of the
take: a new track starts from one noisy measurement and its filter settles within about 0.7 s (hundreds of
mm at first), and each pass of the looping take starts with the person jumping back to the take's start."""
DEMO_TAKE_S = DEFAULT_TAKE_S
"""The demo's take: this many seconds of the gesture, played in a loop for the whole ``--duration``. Every
pass shows the sensors exactly the same frames, so the score over whole passes is the same figure for any
duration of at least one pass (a longer run only adds passes of the same material)."""


def __getattr__(name: str) -> Any:
    """The runs (:mod:`skelfuse.apps.demo.run` lists them) load on first use: ``skelfuse demo --help`` does not pay for
    the simulator, the fusion pipeline and Rerun."""
    run = importlib.import_module("skelfuse.apps.demo.run")
    try:
        return getattr(run, name)
    except AttributeError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
