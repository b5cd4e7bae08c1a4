"""skelfuse: fuse the skeletons of several Azure Kinect body trackers into one accurate, smooth skeleton."""

__version__ = "0.1.0"
