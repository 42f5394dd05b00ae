"""Decoding one message of a recording, whichever tool wrote it: images (RawImage,
sensor_msgs Image and CompressedImage), point clouds (PointCloud, PointCloud2, LaserScan),
camera infos, static transforms, the calibration TOML, and the stamps (`edge.capture.replay`
reads files with these)."""

from __future__ import annotations

import json

import cv2
import numpy as np

MAX_STAMP_NS = 2**32 * 1_000_000_000  # year 2106: past it a stamp is corrupt, not a time


def message_decoders() -> list:
    """The decoder factories of the encodings recordings use (protobuf: foxglove; cdr: ROS 2)."""
    from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoder
    from mcap_ros2.decoder import DecoderFactory as Ros2Decoder

    return [ProtobufDecoder(), Ros2Decoder()]


def decode_message(schema, channel, message, factories: list, decoders: dict):
    """One MCAP message decoded (JSON, or by the first factory with a decoder for its channel,
    cached per channel id in `decoders`); ValueError when none has one."""
    if channel.message_encoding == "json":
        return json.loads(message.data)
    if channel.id not in decoders:
        decoder = None
        for factory in factories:
            decoder = factory.decoder_for(channel.message_encoding, schema)
            if decoder is not None:
                break
        if decoder is None:
            raise ValueError(f"no decoder for {channel.message_encoding} "
                             f"{schema.name if schema else ''}")
        decoders[channel.id] = decoder
    return decoders[channel.id](message.data)


def header_stamp(msg, fallback: int) -> int:
    """The ROS 2 header's stamp, else `fallback` (the log time); ValueError (the message is
    counted and skipped) for one outside 0 … 2³² s, which no clock writes."""
    header = getattr(msg, "header", None)
    stamp = fallback
    if header is not None:  # ROS 2
        stamp = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
    if not 0 <= stamp < MAX_STAMP_NS:
        raise ValueError(f"stamp {stamp} ns is out of range (corrupt)")
    return stamp


def decode_image(msg) -> np.ndarray:
    """RawImage / sensor_msgs Image (mono8, rgb8, bgr8, rgba8, bgra8, 32FC1) or a compressed
    image -> uint8 grey (H, W), or float32 (H, W) for 32FC1."""
    if hasattr(msg, "format"):  # CompressedImage, both schemas
        image = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise ValueError("compressed image does not decode")
        return image
    h, w, step, enc = int(msg.height), int(msg.width), int(msg.step), msg.encoding.lower()
    data = np.frombuffer(bytes(msg.data), np.uint8)
    channels = {"mono8": 1, "8uc1": 1, "rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4,
                "32fc1": 4}.get(enc)
    if channels is None:
        raise ValueError(f"image encoding {msg.encoding!r} not supported")
    if step < w * channels or data.size < step * h:
        raise ValueError(f"image data {data.size} bytes is short for {w}x{h} {enc}")
    rows = data[: step * h].reshape(h, step)[:, : w * channels]
    if enc == "32fc1":
        big = bool(getattr(msg, "is_bigendian", False))
        return rows.copy().view(">f4" if big else "<f4").astype(np.float32).reshape(h, w)
    if channels == 1:
        return np.ascontiguousarray(rows)
    pixels = rows.reshape(h, w, channels)[..., :3]
    code = cv2.COLOR_RGB2GRAY if enc.startswith("rgb") else cv2.COLOR_BGR2GRAY
    return cv2.cvtColor(np.ascontiguousarray(pixels), code)


# datatype codes: sensor_msgs/PointField and foxglove NumericType agree on 7 = float32 and
# 8 = float64 and disagree on the integer codes, which are not used for coordinates here
_FLOAT_TYPES = {7: "f4", 8: "f8"}
# a point's own time, relative to the message's stamp: "time", float seconds (the Velodyne
# drivers' field, and what edge-depth writes), or "t", uint32 nanoseconds (Ouster's); the
# uint32 code is 6 in sensor_msgs/PointField and 5 in foxglove's NumericType
_TIME_FIELDS = {("time", 7): ("f4", 1e9), ("time", 8): ("f8", 1e9), ("t", "uint32"): ("u4", 1.0)}
MAX_POINT_TIME_NS = 60e9  # a point's time further than this from its message's stamp is corrupt


def _point_time_field(name: str, code: int, ros: bool) -> tuple[str, float] | None:
    """A point cloud field's (dtype, to-nanoseconds scale) if it holds the point's own time;
    `code` its datatype, `ros`: sensor_msgs/PointField's codes, else foxglove's."""
    uint32 = 6 if ros else 5
    return _TIME_FIELDS.get((name, "uint32" if code == uint32 else code))


def decode_points(msg) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """PointCloud / PointCloud2 / LaserScan -> (N, 3) float32 metres, (N,) intensity or None,
    (N,) int64 each point's time in ns after the message's stamp or None (a "time" or "t"
    field, `_TIME_FIELDS`); non-finite points dropped."""
    if hasattr(msg, "ranges"):  # LaserScan
        ranges = np.asarray(msg.ranges, np.float32)
        angles = msg.angle_min + msg.angle_increment * np.arange(len(ranges), dtype=np.float32)
        keep = np.isfinite(ranges) & (ranges >= msg.range_min) & (ranges <= msg.range_max)
        pts = np.stack([ranges * np.cos(angles), ranges * np.sin(angles),
                        np.zeros_like(ranges)], 1)[keep]
        inten = np.asarray(msg.intensities, np.float32)
        offsets = None
        if float(getattr(msg, "time_increment", 0.0) or 0.0) > 0:  # REP: the beam's time
            offsets = np.round(np.arange(len(ranges)) * float(msg.time_increment)
                               * 1e9).astype(np.int64)[keep]
        return pts.astype(np.float32), (inten[keep] if inten.size == ranges.size else None), \
            offsets
    stride = int(getattr(msg, "point_stride", 0) or getattr(msg, "point_step", 0))
    big = bool(getattr(msg, "is_bigendian", False))
    data = bytes(msg.data)
    if stride <= 0 or len(data) % stride:
        raise ValueError(f"point data of {len(data)} bytes is not a multiple of {stride}")
    n = len(data) // stride
    raw = np.frombuffer(data, np.uint8).reshape(n, stride)

    def column(offset: int, dtype: str) -> np.ndarray:
        t = np.dtype(dtype).newbyteorder(">" if big else "<")
        if offset + t.itemsize > stride:
            raise ValueError(f"a point field at byte {offset} runs past the {stride}-byte point")
        return raw[:, offset:offset + t.itemsize].copy().view(t)[:, 0]

    columns: dict[str, np.ndarray] = {}
    offsets = None
    for f in msg.fields:
        ros = getattr(f, "datatype", None)
        code = int(ros if ros is not None else getattr(f, "type", 0) or 0)
        if f.name in ("x", "y", "z", "intensity") and code in _FLOAT_TYPES:
            columns[f.name] = column(int(f.offset), _FLOAT_TYPES[code]).astype(np.float32)
        elif (time_field := _point_time_field(f.name, code, ros is not None)) is not None:
            dtype, scale = time_field
            offsets = np.round(column(int(f.offset), dtype).astype(np.float64) * scale)
    if not {"x", "y", "z"} <= set(columns):
        raise ValueError("point cloud lacks float x, y, z fields")
    pts = np.stack([columns["x"], columns["y"], columns["z"]], 1)
    keep = np.isfinite(pts).all(1)
    if offsets is not None and not (np.abs(offsets) < MAX_POINT_TIME_NS).all():
        offsets = None  # a time field that is no time (NaN, years): the points keep the stamp
    intensity = columns.get("intensity")
    return pts[keep], (intensity[keep] if intensity is not None else None), \
        (offsets[keep].astype(np.int64) if offsets is not None else None)


def camera_info(msg) -> tuple[float, float, float, float, tuple[int, int]]:
    P = [float(v) for v in (getattr(msg, "p", None) or getattr(msg, "P", None) or ())]
    if len(P) < 7:
        raise ValueError(f"a CameraInfo needs its 3x4 projection P, got {P}")
    return P[0], P[2], P[6], P[3], (int(msg.width), int(msg.height))


def toml_text(msg) -> str:
    """The calibration TOML of /edge/calibration: JSON {"toml": ...} (foxglove profile) or
    std_msgs/String (ros2 profile)."""
    return str(msg["toml"]) if isinstance(msg, dict) else str(msg.data)


def frame_id(msg) -> str:
    header = getattr(msg, "header", None)
    return str(header.frame_id if header is not None else getattr(msg, "frame_id", ""))


def camera_info_dict(msg) -> dict:
    """sensor_msgs/CameraInfo (k d r p) or foxglove CameraCalibration (K D R P) → dict(K, D,
    R, P, size, frame_id) as `calibration.ros.stereo_from_camera_infos` takes it."""
    def field_(name: str) -> np.ndarray:
        value = getattr(msg, name.lower(), None)
        if value is None or len(value) == 0:
            value = getattr(msg, name, None) or []
        return np.asarray([float(v) for v in value], np.float64)

    D = field_("D")
    return dict(K=field_("K").reshape(3, 3), D=D if D.size else np.zeros(5),
                R=field_("R").reshape(3, 3), P=field_("P").reshape(3, 4),
                size=(int(msg.width), int(msg.height)), frame_id=frame_id(msg))


def static_transforms(msg) -> list[tuple[str, str, np.ndarray]]:
    from edge_depth.calibration.ros import transform_matrix

    out = []
    for t in msg.transforms:
        tr, q = t.transform.translation, t.transform.rotation
        out.append((str(t.header.frame_id), str(t.child_frame_id),
                    transform_matrix((tr.x, tr.y, tr.z), (q.x, q.y, q.z, q.w))))
    return out


