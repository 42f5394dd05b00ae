"""ROS 2 message definitions (the `ros2msg` text ROS 2 ships, with every dependency), so an
MCAP file written with them (`edge.ros2_log`) decodes in any ROS 2 tool without the message
packages installed — and so tests can write bags as other tools do."""

from __future__ import annotations

SEP = "=" * 80 + "\n"
TIME = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
HEADER = SEP + "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n" + SEP \
    + TIME
ROI = (SEP + "MSG: sensor_msgs/RegionOfInterest\nuint32 x_offset\nuint32 y_offset\n"
       "uint32 height\nuint32 width\nbool do_rectify\n")
IMAGE_FIELDS = ("std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n"
                "uint8 is_bigendian\nuint32 step\nuint8[] data\n")
POINT_FIELD = ("MSG: sensor_msgs/PointField\nstring name\nuint32 offset\nuint8 datatype\n"
               "uint32 count\n")
VECTOR3 = "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n"
QUATERNION = "MSG: geometry_msgs/Quaternion\nfloat64 x\nfloat64 y\nfloat64 z\nfloat64 w\n"

MSGDEFS = {
    "sensor_msgs/msg/Image": IMAGE_FIELDS + HEADER,
    "sensor_msgs/msg/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data\n"
    + HEADER,
    "sensor_msgs/msg/PointCloud2": "std_msgs/Header header\nuint32 height\nuint32 width\n"
    "sensor_msgs/PointField[] fields\nbool is_bigendian\nuint32 point_step\nuint32 row_step\n"
    "uint8[] data\nbool is_dense\n" + HEADER + SEP + POINT_FIELD,
    "sensor_msgs/msg/LaserScan": "std_msgs/Header header\nfloat32 angle_min\n"
    "float32 angle_max\nfloat32 angle_increment\nfloat32 time_increment\nfloat32 scan_time\n"
    "float32 range_min\nfloat32 range_max\nfloat32[] ranges\nfloat32[] intensities\n"
    + HEADER,
    "sensor_msgs/msg/CameraInfo": "std_msgs/Header header\nuint32 height\nuint32 width\n"
    "string distortion_model\nfloat64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\n"
    "uint32 binning_x\nuint32 binning_y\nsensor_msgs/RegionOfInterest roi\n" + HEADER + ROI,
    "stereo_msgs/msg/DisparityImage": "std_msgs/Header header\nsensor_msgs/Image image\n"
    "float32 f\nfloat32 t\nsensor_msgs/RegionOfInterest valid_window\nfloat32 min_disparity\n"
    "float32 max_disparity\nfloat32 delta_d\n" + HEADER + SEP + "MSG: sensor_msgs/Image\n"
    + IMAGE_FIELDS + ROI,
    "tf2_msgs/msg/TFMessage": "geometry_msgs/TransformStamped[] transforms\n" + SEP
    + "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\n"
    "Transform transform\n" + HEADER + SEP + "MSG: geometry_msgs/Transform\n"
    "Vector3 translation\nQuaternion rotation\n" + SEP + VECTOR3 + SEP + QUATERNION,
    "diagnostic_msgs/msg/DiagnosticArray": "std_msgs/Header header\n"
    "DiagnosticStatus[] status\n" + HEADER + SEP + "MSG: diagnostic_msgs/DiagnosticStatus\n"
    "byte level\nstring name\nstring message\nstring hardware_id\nKeyValue[] values\n" + SEP
    + "MSG: diagnostic_msgs/KeyValue\nstring key\nstring value\n",
    "std_msgs/msg/String": "string data\n",
}


def header(stamp_ns: int, frame_id: str) -> dict:
    return {"stamp": {"sec": int(stamp_ns) // 10**9, "nanosec": int(stamp_ns) % 10**9},
            "frame_id": frame_id}


def transform(parent: str, child: str, T, stamp_ns: int = 0) -> dict:
    """geometry_msgs/TransformStamped of the 4×4 T_parent_child (X_parent = T X_child)."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    T = np.asarray(T, float)
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    tx, ty, tz = (float(v) for v in T[:3, 3])
    return {"header": header(stamp_ns, parent), "child_frame_id": child,
            "transform": {"translation": {"x": tx, "y": ty, "z": tz},
                          "rotation": {"x": float(x), "y": float(y), "z": float(z),
                                       "w": float(w)}}}


def cdr_decoder(type_name: str):
    """A function from a message's CDR bytes (with their encapsulation header, as an MCAP
    file and an rclpy raw subscription hold them) to the decoded message, by the definition
    above: the decoder a ROS 2 bag's replay uses (mcap-ros2-support). KeyError for a type
    without a definition here."""
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory

    schema = Schema(id=0, name=type_name, encoding="ros2msg",
                    data=MSGDEFS[type_name].encode())
    decoder = DecoderFactory().decoder_for("cdr", schema)
    if decoder is None:
        raise ValueError(f"no CDR decoder for {type_name}")
    return decoder


def cdr_encoder(type_name: str):
    """A function from a message as a dict (`edge.ros2_log`'s builders) to its CDR bytes:
    the bytes the ros2 MCAP profile writes, published as they are by an rclpy publisher."""
    from mcap_ros2._dynamic import serialize_dynamic

    return serialize_dynamic(type_name, MSGDEFS[type_name])[type_name]
