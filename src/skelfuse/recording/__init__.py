"""Record raw sensor frames to MCAP, read them back, replay them, and fuse a recording offline.

* :mod:`skelfuse.recording.mcap_io`: :class:`RecordingWriter`, :class:`RecordingReader` (file layout in
  ``docs/recording.md``).
* :mod:`skelfuse.recording.offline`: :func:`fuse_recording`, :func:`replay_frames` (the fused table is written by
  :mod:`skelfuse.export.csv`).
"""

from skelfuse.recording.mcap_io import RecordedFrame, RecordedFused, RecordingReader, RecordingWriter
from skelfuse.recording.offline import fuse_recording, replay_frames

__all__ = [
    "RecordedFrame",
    "RecordedFused",
    "RecordingReader",
    "RecordingWriter",
    "fuse_recording",
    "replay_frames",
]
