"""Retargeting: fused joint positions to a fixed-length armature with per-frame joint rotations.

The one retargeting behind the file exports (BVH, FBX: :mod:`skelfuse.export`) and the live avatar stream
(VMC: :mod:`skelfuse.stream`), so it sits below both. Pure numpy: arrays in, arrays out, no I/O.
:mod:`~skelfuse.retarget.armature` fits the armature and solves the rotations (rest pose, forward kinematics,
retargeting error); :mod:`~skelfuse.retarget.rotations` holds the rotation algebra they use.
"""
