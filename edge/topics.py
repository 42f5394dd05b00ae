"""Topic names, in one place for the writers (`edge.mcap_log`, `edge.ros2_log`) and the reader
(`edge.capture.replay`): the foxglove profile's (DESIGN.md) and the ros2 profile's."""

from __future__ import annotations

TOPICS = dict(
    left="/stereo/left/image_rect", right="/stereo/right/image_rect",
    left_raw="/stereo/left/image", right_raw="/stereo/right/image",
    left_calibration="/stereo/left/calibration", right_calibration="/stereo/right/calibration",
    lidar="/lidar/points", sparse="/depth/sparse_disparity", disparity="/depth/disparity",
    depth="/depth/image", points="/depth/points", confidence="/depth/confidence",
    diagnostics="/diagnostics",
    calibration_file="/edge/calibration", gt_disparity="/sim/gt_disparity", transforms="/tf",
)
RAW_TOPICS = ("left", "right", "left_raw", "right_raw", "left_calibration",
              "right_calibration", "lidar", "calibration_file", "gt_disparity", "transforms")
# written once per file, and sent again to each live-view client that subscribes later
LATCHED = ("calibration_file", "left_calibration", "right_calibration", "transforms")
RESULT_TOPICS = ("sparse", "disparity", "depth", "points", "confidence", "diagnostics")

ROS2_TOPICS = dict(
    left="stereo/left/image_rect", right="stereo/right/image_rect",
    left_raw="stereo/left/image_raw", right_raw="stereo/right/image_raw",
    left_calibration="stereo/left/camera_info", right_calibration="stereo/right/camera_info",
    lidar="lidar/points", sparse="stereo/sparse_disparity", disparity="stereo/disparity",
    depth="stereo/depth", points="stereo/points", confidence="stereo/confidence",
    diagnostics="/diagnostics", calibration_file="edge/calibration",
    gt_disparity="sim/gt_disparity", tf_static="/tf_static",
)


def ros2_topic(key: str, prefix: str = "/") -> str:
    """The ros2 profile's topic for a role: under `prefix` unless it is absolute."""
    name = ROS2_TOPICS[key]
    return name if name.startswith("/") else prefix.rstrip("/") + "/" + name
