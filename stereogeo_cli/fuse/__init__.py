"""Stereo fusion: feature matches, the essential matrix, gravity coupling and the pose head's prior."""

from stereogeo_cli.fuse.gravity import share_gravity
from stereogeo_cli.fuse.matches import Matches, match_features
from stereogeo_cli.fuse.pose import RelativePose, essential_pose, fuse_relative_pose, sampson_errors

__all__ = [
    "Matches",
    "RelativePose",
    "essential_pose",
    "fuse_relative_pose",
    "match_features",
    "sampson_errors",
    "share_gravity",
]
