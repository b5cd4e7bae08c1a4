"""``skelfuse`` whose fusion step takes a fixed extra time per instant: a node that cannot keep up, on any machine.

Usage: ``python slow_fusion_node.py COST_MS SKELFUSE_ARGS...``. Every :meth:`GroupFuser.step` sleeps ``COST_MS``
first (the loop thread is held as a slow fusion would hold it, without taking a shared machine's CPU), then the
command line runs as ``skelfuse SKELFUSE_ARGS...`` does.
"""

from __future__ import annotations

import sys
import time

from skelfuse.cli import entrypoint
from skelfuse.rig.grouping import FrameGroup
from skelfuse.rig.instant import FusedInstant, GroupFuser


def main() -> None:
    cost_s = float(sys.argv[1]) / 1000.0
    step = GroupFuser.step

    def slow_step(self: GroupFuser, group: FrameGroup) -> FusedInstant:
        time.sleep(cost_s)
        return step(self, group)

    GroupFuser.step = slow_step  # type: ignore[method-assign]
    sys.argv = ["skelfuse", *sys.argv[2:]]
    entrypoint()


if __name__ == "__main__":
    main()
