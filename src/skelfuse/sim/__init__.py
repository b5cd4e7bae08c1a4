"""The simulator: ground truth for everything.

- :mod:`skelfuse.sim.motion`: :class:`Motion`, true 32-joint positions over time (world, mm).
- :mod:`skelfuse.sim.bvh`: real motion capture (CMU BVH) as a Motion.
- :mod:`skelfuse.sim.gestures`: the paper's six gestures, generated procedurally.
- :mod:`skelfuse.sim.rig`: virtual Azure Kinect sensors and the paper's rig layout.
- :mod:`skelfuse.sim.observe`: what each sensor's body tracker reports (:func:`simulate`), with every
  parameter in a TOML profile (:func:`load_profile`).
"""

from skelfuse.sim.bvh import load_bvh
from skelfuse.sim.gestures import GESTURES, make_gesture
from skelfuse.sim.motion import Motion
from skelfuse.sim.observe import Observations, simulate
from skelfuse.sim.profile import SimProfile, load_profile
from skelfuse.sim.rig import VirtualSensor, best_view_sensor, look_at, paper_rig

__all__ = [
    "GESTURES",
    "Motion",
    "Observations",
    "SimProfile",
    "VirtualSensor",
    "best_view_sensor",
    "load_bvh",
    "load_profile",
    "look_at",
    "make_gesture",
    "paper_rig",
    "simulate",
]
