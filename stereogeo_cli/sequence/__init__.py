"""``calibrate-sequence``: one calibration of a stereo rig from a sequence of frames.

- :mod:`~stereogeo_cli.sequence.sources`: the frames — a folder of pairs, two videos, a side-by-side
  video or a ROS bag — as timestamped left/right pairs.
"""
