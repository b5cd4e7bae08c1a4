"""Waiting on an in-process recorder: what ``run_recorder`` has handed its writer (the ``recorder_progress``
fixture of conftest.py installs the count)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable

import numpy as np

from skelfuse.schema.frames import FusedFrame
from skelfuse.schema.skeleton import N_JOINTS
from skelfuse.wire.codec import encode_fused_frame
from waiting import wait_until


class RecorderProgress:
    """What an in-process ``run_recorder`` has taken from its queue, by kind (written or rejected).

    A test puts its payloads, then :meth:`end_marker` on the fused key from the same session: one session's
    messages keep their order, so once the marker is handled, everything put before it has been too (or was
    never subscribed to). No sleep, no guess of how long delivery takes.
    """

    def __init__(self) -> None:
        self.handled: Counter[str] = Counter()

    @staticmethod
    def end_marker(time_us: int = 1) -> bytes:
        """A valid fused frame with nobody in it (it adds one fused frame to the recording)."""
        empty = FusedFrame(
            time_us=time_us,
            track_ids=np.zeros(0, np.int64),
            positions=np.zeros((0, N_JOINTS, 3)),
            n_agree=np.zeros((0, N_JOINTS), np.int16),
            confidence=np.zeros((0, N_JOINTS), np.uint8),
            contributors=np.zeros((0, 1), bool),
            sensor_ids=("end",),
        )
        return encode_fused_frame(empty)

    def wait_for_end_marker(self, details: Callable[[], str] = str) -> None:
        wait_until(lambda: self.handled["fused"] >= 1, "the recorder to handle the end marker", details=details)
