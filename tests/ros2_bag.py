"""Writing ROS 2 bags (MCAP, CDR) in tests with mcap-ros2-support: the sensor_msgs
definitions the replay reads, as ROS 2 ships them (message definition text)."""

from __future__ import annotations

SEP = "=" * 80 + "\n"
HEADER = (SEP + "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
          + SEP + "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n")
MSGDEFS = {
    "sensor_msgs/msg/Image": "std_msgs/Header header\nuint32 height\nuint32 width\n"
    "string encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n" + HEADER,
    "sensor_msgs/msg/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data\n"
    + HEADER,
    "sensor_msgs/msg/PointCloud2": "std_msgs/Header header\nuint32 height\nuint32 width\n"
    "sensor_msgs/PointField[] fields\nbool is_bigendian\nuint32 point_step\nuint32 row_step\n"
    "uint8[] data\nbool is_dense\n" + HEADER + SEP + "MSG: sensor_msgs/PointField\n"
    "string name\nuint32 offset\nuint8 datatype\nuint32 count\n",
    "sensor_msgs/msg/LaserScan": "std_msgs/Header header\nfloat32 angle_min\n"
    "float32 angle_max\nfloat32 angle_increment\nfloat32 time_increment\nfloat32 scan_time\n"
    "float32 range_min\nfloat32 range_max\nfloat32[] ranges\nfloat32[] intensities\n"
    + HEADER,
    "sensor_msgs/msg/CameraInfo": "std_msgs/Header header\nuint32 height\nuint32 width\n"
    "string distortion_model\nfloat64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\n"
    "uint32 binning_x\nuint32 binning_y\nsensor_msgs/RegionOfInterest roi\n" + HEADER + SEP
    + "MSG: sensor_msgs/RegionOfInterest\nuint32 x_offset\nuint32 y_offset\nuint32 height\n"
    "uint32 width\nbool do_rectify\n",
}


def header(stamp_ns: int, frame_id: str = "camera") -> dict:
    return {"stamp": {"sec": stamp_ns // 10**9, "nanosec": stamp_ns % 10**9},
            "frame_id": frame_id}
