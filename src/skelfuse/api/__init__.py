"""The public Python API for apps: what ``import skelfuse`` re-exports (its ``__all__``).

Three doors, each a module:

* :mod:`skelfuse.api.live`: subscribe to a running rig's fused skeletons over zenoh
  (:func:`~skelfuse.api.live.subscribe`, :class:`~skelfuse.api.live.FusedSubscriber`);
* :mod:`skelfuse.api.recordings`: read a recording of any supported format, read the fused frames a recorder
  wrote, and fuse recordings offline into the same :class:`~skelfuse.schema.frames.FusedFrame` objects;
* the vocabulary, defined once in :mod:`skelfuse.schema` and re-exported as is: joint names, the skeleton's
  topology, confidence levels, frames and typed errors.

Everything else in the package is internal and may change between minor versions (docs/python-api.md,
"Versioning").
"""
