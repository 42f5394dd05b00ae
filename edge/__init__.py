"""LiDAR-assisted stereo depth for robots, at the edge."""

__version__ = "0.1.0"
