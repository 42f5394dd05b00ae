"""The output profiles: which logger writes a run's MCAP files. Above both writers, so neither
imports the other."""

from __future__ import annotations

from edge_depth.mcap_log import McapLogger
from edge_depth.ros2_log import Ros2Logger

PROFILES = ("foxglove", "ros2")


def open_logger(path, profile: str = "foxglove", **kwargs) -> McapLogger:
    """McapLogger (foxglove profile: protobuf Foxglove schemas) or, for "ros2", Ros2Logger
    (ROS 2 messages in CDR, for `ros2 bag play`); the same interface."""
    if profile == "ros2":
        return Ros2Logger(path, **kwargs)
    if profile != "foxglove":
        raise ValueError(f"profile: expected one of {PROFILES}, got {profile!r}")
    return McapLogger(path, **kwargs)
