"""Calibration: where each sensor stands (``world_from_sensor``, 4x4, mm), measured rather than typed in.

Modules (paper section 2.1, and beyond it):

- ``sphere``: sensor to sensor from a coloured sphere carried through the space (histogram back-projection,
  RANSAC sphere of known radius, rigid fit of the centre trajectories to the master's).
- ``marker``: sensor (the master) to world from a plate of four ArUco markers lying on the floor.
- ``skeleton``: sensor to sensor from the body-tracking skeletons themselves.
- ``rigid``: the robust rigid fits (Kabsch / Umeyama without scale, RANSAC) the methods share.
- ``rgbd_folder``: the RGB-D folder the sphere and marker methods read; ``takes``: skeleton takes from a
  recording or per-sensor files; ``render``: a synthetic RGB-D renderer for tests; ``view``: logging a
  calibration to Rerun.

The calibration file itself (read and written) is :mod:`skelfuse.config.calibration_file`; the commands are
:mod:`skelfuse.cli.calibrate`.
"""
