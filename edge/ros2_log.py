"""The ros2 output profile: the same recording as `McapLogger`, written as ROS 2 messages in
CDR with mcap-ros2-support (MCAP profile `ros2`, schema encoding `ros2msg` with the full
definitions of `edge.ros2_msgs`), so `ros2 bag play` publishes it into a robot's graph and any
ROS 2 tool reads it without our packages.

Topics (`ROS2_TOPICS`, under a configurable prefix):
    stereo/left/image_rect, stereo/right/image_rect   sensor_msgs/Image mono8
    stereo/left/camera_info, stereo/right/camera_info sensor_msgs/CameraInfo, with each image
    stereo/depth            sensor_msgs/Image 32FC1, metres, NaN where invalid (REP 118)
    stereo/disparity        stereo_msgs/DisparityImage (f, T = baseline, disparity range)
    stereo/confidence       sensor_msgs/Image 32FC1 0-1 (models with the refinement stage)
    stereo/sparse_disparity sensor_msgs/Image 32FC1 (the LiDAR projected, 0 = none)
    stereo/points           sensor_msgs/PointCloud2 x y z intensity (depth back-projected)
    lidar/points            sensor_msgs/PointCloud2 x y z intensity (+ time: each point's, in s
                            after the stamp, where the LiDAR gives one), as received
    /tf_static              tf2_msgs/TFMessage: parent → camera_left → camera_right, lidar
    /diagnostics            diagnostic_msgs/DiagnosticArray (the foxglove profile's counters;
                            WARN on errors, the output's health)
    edge/calibration        std_msgs/String: the calibration file's TOML (first in each file)
    sim/gt_disparity        sensor_msgs/Image 32FC1 (synthetic recordings only)
Rotation, the free-space check and never-overwrite naming are McapLogger's.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import IO

import numpy as np

from edge_depth.foxglove_msgs import CAMERA_FRAME, RIGHT_FRAME, packed_points
from edge_depth.mcap_log import McapLogger
from edge_depth.ros2_msgs import MSGDEFS, header, transform
from edge_depth.topics import ros2_topic
from edge_depth.types import DepthResult, StereoFrame

TYPES = dict(left_calibration="sensor_msgs/msg/CameraInfo",
             right_calibration="sensor_msgs/msg/CameraInfo",
             lidar="sensor_msgs/msg/PointCloud2", points="sensor_msgs/msg/PointCloud2",
             disparity="stereo_msgs/msg/DisparityImage",
             diagnostics="diagnostic_msgs/msg/DiagnosticArray",
             calibration_file="std_msgs/msg/String", tf_static="tf2_msgs/msg/TFMessage")


def image_msg(image: np.ndarray, stamp_ns: int, frame_id: str) -> dict:
    h, w = image.shape
    if image.dtype == np.uint8:
        encoding, data = "mono8", image
    else:
        encoding, data = "32FC1", image.astype("<f4", copy=False)
    return {"header": header(stamp_ns, frame_id), "height": h, "width": w,
            "encoding": encoding, "is_bigendian": 0, "step": data.itemsize * w,
            "data": np.ascontiguousarray(data).tobytes()}


def cloud_msg(points: np.ndarray, stamp_ns: int, frame_id: str,
              intensity: np.ndarray | None = None,
              point_stamps_ns: np.ndarray | None = None) -> dict:
    names, packed = packed_points(points, stamp_ns, intensity, point_stamps_ns)
    n, step = len(points), 4 * len(names)
    fields = [{"name": name, "offset": 4 * i, "datatype": 7, "count": 1}  # 7 = FLOAT32
              for i, name in enumerate(names)]
    return {"header": header(stamp_ns, frame_id), "height": 1, "width": n, "fields": fields,
            "is_bigendian": False, "point_step": step, "row_step": step * n,
            "data": packed.tobytes(), "is_dense": True}


def camera_info_msg(stamp_ns: int, frame_id: str, size, focal_px: float,
                    principal_point, tx: float) -> dict:
    """A rectified camera (ROS convention: the right one's P[3] = -f·B)."""
    (w, h), (cx, cy), f = size, principal_point, float(focal_px)
    return {"header": header(stamp_ns, frame_id), "height": int(h), "width": int(w),
            "distortion_model": "plumb_bob", "d": [0.0] * 5,
            "k": [f, 0, cx, 0, f, cy, 0, 0, 1], "r": [1.0, 0, 0, 0, 1, 0, 0, 0, 1],
            "p": [f, 0, cx, tx, 0, f, cy, 0, 0, 0, 1, 0], "binning_x": 0, "binning_y": 0,
            "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0,
                    "do_rectify": False}}


class Ros2Logger(McapLogger):
    """McapLogger's interface, writing the ros2 profile. `prefix`: the topics' namespace
    (McapLogger's `parent_frame` and `T_parent_camera` put camera_left under a robot frame in
    /tf_static)."""

    def __init__(self, path, *args, prefix: str = "/", **kwargs) -> None:
        if kwargs.get("live"):
            from edge_depth.errors import ConfigError

            raise ConfigError("--live", "the foxglove profile (the live view speaks only that)",
                              "ros2")
        self.prefix = prefix
        self._file: IO[bytes] | None = None
        super().__init__(path, *args, **kwargs)

    # -- files -------------------------------------------------------------------------------
    def _start_writer(self, path: Path):
        from mcap.writer import CompressionType
        from mcap_ros2.writer import Writer

        self._file = open(path, "wb")  # noqa: SIM115 - closed in _close_writer
        compression = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                       "none": CompressionType.NONE}[self.compression]
        self._schemas: dict[str, object] = {}
        return Writer(self._file, chunk_size=self.chunk_size, compression=compression)

    def _finish(self, writer) -> None:
        try:
            writer.finish()
        finally:
            if self._file is not None:
                self._file.close()

    def _write(self, key: str, message: dict, stamp_ns: int) -> None:
        datatype = TYPES.get(key, "sensor_msgs/msg/Image")
        if datatype not in self._schemas:
            self._schemas[datatype] = self._writer.register_msgdef(datatype, MSGDEFS[datatype])
        self._writer.write_message(ros2_topic(key, self.prefix), self._schemas[datatype],
                                   message, log_time=int(stamp_ns), publish_time=int(stamp_ns))

    def _topic(self, key: str) -> str:
        return ros2_topic(key, self.prefix)

    def _logs(self, key: str) -> bool:
        return key in self.enabled or key == "tf_static"  # /tf_static goes in every file

    def _log_file_start(self, stamp_ns: int) -> None:
        """The TOML as std_msgs/String and /tf_static (camera infos go with every image)."""
        if self.calibration_toml is not None:
            self._log("calibration_file", {"data": self.calibration_toml}, stamp_ns)
        if self.camera is not None:
            self._log("tf_static", self._transforms(stamp_ns), stamp_ns)

    def _transforms(self, stamp_ns: int) -> dict:
        return {"transforms": [transform(parent, child, T, stamp_ns)
                               for parent, child, T in self.frame_tree()]}

    # -- messages ------------------------------------------------------------------------------
    def _image(self, image: np.ndarray, stamp_ns: int, frame_id: str = CAMERA_FRAME) -> dict:
        return image_msg(image, stamp_ns, frame_id)

    def _cloud(self, points: np.ndarray, stamp_ns: int, frame_id: str, intensity=None,
               point_stamps_ns=None) -> dict:
        return cloud_msg(points, stamp_ns, frame_id, intensity, point_stamps_ns)

    def _disparity(self, result: DepthResult) -> dict:
        f = baseline = 0.0
        if self.camera is not None:
            _, f, _, baseline = self.camera
        t, disparity = result.stamp_ns, result.disparity.astype(np.float32)
        finite = disparity[np.isfinite(disparity)]
        h, w = disparity.shape
        return {"header": header(t, CAMERA_FRAME), "image": image_msg(disparity, t,
                                                                       CAMERA_FRAME),
                "f": float(f), "t": float(baseline),
                "valid_window": {"x_offset": 0, "y_offset": 0, "height": h, "width": w,
                                 "do_rectify": False},
                "min_disparity": float(finite.min()) if finite.size else 0.0,
                "max_disparity": float(finite.max()) if finite.size else 0.0,
                "delta_d": 1.0 / 64}  # the network's output is continuous; nominal

    # -- what gets logged --------------------------------------------------------------------
    def log_frame(self, frame: StereoFrame) -> None:
        """The pair, then each camera's info stamped like it (ROS tools pair them)."""
        super().log_frame(frame)
        if self.camera is None or self._writer is None:
            return
        t = frame.stamp_ns
        size, f, pp, baseline = self.camera
        self._log("left_calibration", camera_info_msg(t, CAMERA_FRAME, size, f, pp, 0.0), t)
        self._log("right_calibration", camera_info_msg(t, RIGHT_FRAME, size, f, pp,
                                                       -f * baseline), t)

    def log_calibration(self, *args, **kwargs) -> None:
        pass  # camera infos go with every image (log_frame)

    def log_diagnostics(self, stamp_ns: int, values: dict) -> None:
        flat = {k: json.dumps(v, default=float) for k, v in values.items()}
        errors = sum((values.get("errors") or {}).values())
        message = f"{values.get('frames', 0)} frames, {errors} errors"
        level = 1 if errors else 0  # WARN / OK
        health = values.get("output_health") or {}
        if health.get("level", "OK") != "OK":  # diagnostic_msgs: 1 WARN, 2 ERROR
            level = max(level, {"WARN": 1, "ERROR": 2}[health["level"]])
            message += f", output {health['message']}"
        status = {"level": level, "name": "edge-depth", "message": message,
                  "hardware_id": "", "values": [{"key": k, "value": v}
                                                for k, v in flat.items()]}
        statuses = [status]
        if watch := values.get("calibration_watch"):  # its own status: a panel row of its own
            statuses.append(watch_status(watch))
        self._log("diagnostics", {"header": header(stamp_ns, ""), "status": statuses},
                  stamp_ns)


def watch_status(watch: dict) -> dict:
    """The calibration watch's DiagnosticStatus: OK (also while settling), WARN or ERROR, the
    estimate in the message and each number as a key."""
    level = {"WARN": 1, "ERROR": 2}.get(watch["level"], 0)
    if watch["level"] == "SETTLING":
        message = f"settling ({watch['samples']} samples)"
    else:
        message = (f"{watch['level']}: yaw {watch['yaw_deg']:+.2f}, pitch "
                   f"{watch['pitch_deg']:+.2f}, roll {watch['roll_deg']:+.2f} deg "
                   f"({watch['shift_px']:.2f} px)")
    return {"level": level, "name": "edge-depth/lidar_calibration", "message": message,
            "hardware_id": "", "values": [{"key": k, "value": str(v)}
                                          for k, v in watch.items()]}
