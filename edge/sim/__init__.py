"""Synthetic stereo + LiDAR rig with exact ground truth (see `rig.make_sample`)."""

from edge_depth.sim.lidar import PATTERNS, LidarPattern, default_T_cam_lidar
from edge_depth.sim.rig import SyntheticSample, make_sample
from edge_depth.sim.scene import RigConfig

__all__ = ["PATTERNS", "LidarPattern", "RigConfig", "SyntheticSample", "default_T_cam_lidar",
           "make_sample"]
