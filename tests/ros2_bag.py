"""Writing ROS 2 bags (MCAP, CDR) in tests with mcap-ros2-support, as another tool writes
them (the message definitions are the package's, `edge.ros2_msgs`)."""

from __future__ import annotations

import numpy as np

from edge_depth.ros2_msgs import MSGDEFS, transform  # noqa: F401 - re-exported for the tests
from edge_depth.ros2_msgs import header as _header


def header(stamp_ns: int, frame_id: str = "camera") -> dict:
    return _header(stamp_ns, frame_id)


def write_bag(path, samples, tf: list[dict] | None = None, zero_stamps: bool = False,
              scans_after_frames: bool = False) -> None:
    """A ROS 2 bag of rig samples as another tool writes one: CameraInfo pair (rectified
    cameras, frame "camera"), PointCloud2 on /points (frame "lidar") written 5 ms before
    each frame, a LaserScan on /scan, Image pairs (mono8 / rgb8 / bgr8) on
    /left|right/image_rect, the right image PNG-compressed on /right/compressed, and, if
    given, these transforms on /tf_static. `zero_stamps`: every header stamp 0 (a driver
    that never set them), the log times still increasing. `scans_after_frames`: each
    PointCloud2 stored (and logged) 20 ms after its frame's images, its stamp unchanged, as a
    slow LiDAR driver delivers it."""
    import cv2
    from mcap_ros2.writer import Writer

    rig = samples[0].rig
    w_px, h_px = samples[0].left.shape[1], samples[0].left.shape[0]
    f_px, cx, cy = rig.focal_px, rig.cx, rig.cy
    def hdr(stamp, frame_id="camera"):
        return header(0 if zero_stamps else stamp, frame_id)

    with open(path, "wb") as f:
        w = Writer(f)
        schemas = {k: w.register_msgdef(k, v) for k, v in MSGDEFS.items()}

        def image(img, stamp, encoding):
            data = img if encoding == "mono8" else np.repeat(img[..., None], 3, 2)
            return {"header": hdr(stamp), "height": img.shape[0], "width": img.shape[1],
                    "encoding": encoding, "is_bigendian": 0, "step": data.shape[1] * (
                        1 if encoding == "mono8" else 3), "data": data.tobytes()}

        if tf is not None:
            w.write_message("/tf_static", schemas["tf2_msgs/msg/TFMessage"],
                            {"transforms": tf}, log_time=1)
        for key, tx in (("left", 0.0), ("right", -f_px * rig.baseline_m)):
            info = {"header": hdr(1), "height": h_px, "width": w_px,
                    "distortion_model": "", "d": [],
                    "k": [f_px, 0, cx, 0, f_px, cy, 0, 0, 1],
                    "r": [1.0, 0, 0, 0, 1, 0, 0, 0, 1],
                    "p": [f_px, 0, cx, tx, 0, f_px, cy, 0, 0, 0, 1, 0],
                    "binning_x": 0, "binning_y": 0,
                    "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0,
                            "do_rectify": False}}
            w.write_message(f"/{key}/camera_info", schemas["sensor_msgs/msg/CameraInfo"],
                            info, log_time=1)
        for i, s in enumerate(samples):
            t = 10**9 + i * 10**8
            pts = s.scan.points
            cloud = np.concatenate([pts, np.ones((len(pts), 1), np.float32)], 1)
            fields = [{"name": n, "offset": 4 * j, "datatype": 7, "count": 1}
                      for j, n in enumerate("xyz")]
            points = {"header": hdr(t - 5 * 10**6, "lidar"), "height": 1, "width": len(pts),
                      "fields": fields, "is_bigendian": False, "point_step": 16,
                      "row_step": 16 * len(pts), "data": cloud.astype("<f4").tobytes(),
                      "is_dense": True}
            if not scans_after_frames:
                w.write_message("/points", schemas["sensor_msgs/msg/PointCloud2"], points,
                                log_time=t - 5 * 10**6)
            ranges = np.array([1.0, 2.0, np.inf, 4.0], np.float32)
            w.write_message("/scan", schemas["sensor_msgs/msg/LaserScan"], {
                "header": hdr(t, "laser"), "angle_min": 0.0, "angle_max": 4.71,
                "angle_increment": np.pi / 2, "time_increment": 0.0, "scan_time": 0.1,
                "range_min": 0.1, "range_max": 10.0, "ranges": ranges.tolist(),
                "intensities": []}, log_time=t)
            w.write_message("/left/image_rect", schemas["sensor_msgs/msg/Image"],
                            image(s.left, t, "mono8" if i == 0 else "rgb8"), log_time=t)
            w.write_message("/right/image_rect", schemas["sensor_msgs/msg/Image"],
                            image(s.right, t, "bgr8"), log_time=t)
            png = cv2.imencode(".png", s.right)[1].tobytes()
            w.write_message("/right/compressed", schemas["sensor_msgs/msg/CompressedImage"],
                            {"header": hdr(t), "format": "png", "data": png}, log_time=t)
            if scans_after_frames:
                w.write_message("/points", schemas["sensor_msgs/msg/PointCloud2"], points,
                                log_time=t + 20 * 10**6)
        w.finish()
