"""Record raw sensor frames to MCAP, read them back, replay them, and fuse a recording offline.

* :mod:`skelfuse.recording.mcap_io`: :class:`RecordingWriter`, :class:`RecordingReader` (file layout in
  ``docs/recording.md``).
* :mod:`skelfuse.recording.offline`: :func:`fuse_recording`, :func:`replay_frames` (the fused table is written by
  :mod:`skelfuse.export.csv`).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from skelfuse.recording.mcap_io import RecordedFrame, RecordedFused, RecordingReader, RecordingWriter
    from skelfuse.recording.offline import fuse_recording, replay_frames

#: Where each public name lives, loaded on first use: reading a file (``recording.inputs``) must not pay for
#: the fusion pipeline that ``offline`` brings (the command line's start-up).
_HOMES = {
    **dict.fromkeys(
        ("RecordedFrame", "RecordedFused", "RecordingReader", "RecordingWriter"), "skelfuse.recording.mcap_io"
    ),
    **dict.fromkeys(("fuse_recording", "replay_frames"), "skelfuse.recording.offline"),
}


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(home), name)
    globals()[name] = value
    return value


__all__ = [
    "RecordedFrame",
    "RecordedFused",
    "RecordingReader",
    "RecordingWriter",
    "fuse_recording",
    "replay_frames",
]
