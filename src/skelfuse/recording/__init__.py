"""Record raw sensor frames to MCAP, read them back, replay them, and fuse a recording offline.

* :mod:`skelfuse.recording.mcap_io`: :class:`RecordingWriter`, :class:`RecordingReader` (file layout in
  ``docs/recording.md``).
* :mod:`skelfuse.recording.offline`: :func:`fuse_recording`, :func:`write_fused`, :func:`replay_frames`.
"""

from skelfuse.recording.mcap_io import RecordedFrame, RecordedFused, RecordingReader, RecordingWriter
from skelfuse.recording.offline import fuse_recording, replay_frames, write_fused

__all__ = [
    "RecordedFrame",
    "RecordedFused",
    "RecordingReader",
    "RecordingWriter",
    "fuse_recording",
    "replay_frames",
    "write_fused",
]
