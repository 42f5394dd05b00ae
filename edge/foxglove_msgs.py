"""Foxglove protobuf messages (foxglove-sdk) built from the pipeline's arrays: the images, point
clouds and stamps `edge.mcap_log` writes (the ros2 profile's are `edge.ros2_log`'s)."""

from __future__ import annotations

import numpy as np

CAMERA_FRAME = "camera_left"
RIGHT_FRAME = "camera_right"
LIDAR_FRAME = "lidar"


def timestamp(ns: int):
    """A nanosecond stamp as a Foxglove Timestamp."""
    from foxglove.messages import Timestamp

    return Timestamp(int(ns) // 1_000_000_000, int(ns) % 1_000_000_000)


def image_message(image: np.ndarray, stamp_ns: int, frame_id: str = CAMERA_FRAME):
    """uint8 (H, W) -> RawImage mono8; float32 (H, W) -> RawImage 32FC1 (little endian)."""
    from foxglove.messages import RawImage

    h, w = image.shape
    if image.dtype == np.uint8:
        encoding, step = "mono8", w
    elif image.dtype == np.float32:
        encoding, step = "32FC1", 4 * w
        image = image.astype("<f4", copy=False)
    else:
        raise TypeError(f"image dtype {image.dtype}: expected uint8 or float32")
    return RawImage(timestamp=timestamp(stamp_ns), frame_id=frame_id, width=w, height=h,
                    encoding=encoding, step=step, data=np.ascontiguousarray(image).tobytes())


def point_cloud_message(points: np.ndarray, stamp_ns: int, frame_id: str,
                        intensity: np.ndarray | None = None,
                        point_stamps_ns: np.ndarray | None = None):
    """(N, 3) float32 metres (+ optional (N,) intensity) -> PointCloud, 16 bytes per point;
    with `point_stamps_ns`, 20: each point's time as "time", float32 seconds after the stamp."""
    from foxglove.messages import (
        PackedElementField,
        PackedElementFieldNumericType,
        PointCloud,
        Pose,
        Quaternion,
        Vector3,
    )

    names, packed = packed_points(points, stamp_ns, intensity, point_stamps_ns)
    f32 = PackedElementFieldNumericType.Float32
    fields = [PackedElementField(name=name, offset=4 * i, type=f32)
              for i, name in enumerate(names)]
    pose = Pose(position=Vector3(x=0, y=0, z=0), orientation=Quaternion(x=0, y=0, z=0, w=1))
    return PointCloud(timestamp=timestamp(stamp_ns), frame_id=frame_id, pose=pose,
                      point_stride=4 * len(names), fields=fields, data=packed.tobytes())


def packed_points(points: np.ndarray, stamp_ns: int, intensity: np.ndarray | None = None,
                  point_stamps_ns: np.ndarray | None = None) -> tuple[tuple[str, ...],
                                                                     np.ndarray]:
    """A point cloud's float32 fields, x y z intensity (0 where none) and, with per-point
    stamps, "time" (seconds after `stamp_ns`, the Velodyne drivers' convention): (names, (N,
    4 or 5) little-endian float32)."""
    names = ("x", "y", "z", "intensity") + (("time",) if point_stamps_ns is not None else ())
    packed = np.zeros((len(points), len(names)), "<f4")
    packed[:, :3] = points
    if intensity is not None:
        packed[:, 3] = intensity
    if point_stamps_ns is not None:
        packed[:, 4] = (point_stamps_ns - stamp_ns) / 1e9
    return names, packed


def depth_to_points(depth: np.ndarray, valid: np.ndarray, focal_px: float,
                    principal_point: tuple[float, float], stride: int = 4,
                    image: np.ndarray | None = None):
    """Back-project every `stride`-th valid depth pixel to (N, 3) float32 camera points;
    with `image` (the rectified left), also each point's intensity: (points, (N,))."""
    cx, cy = principal_point
    ys, xs = np.nonzero(valid[::stride, ::stride])
    ys, xs = ys * stride, xs * stride
    z = depth[ys, xs]
    points = np.stack([(xs - cx) * z / focal_px, (ys - cy) * z / focal_px, z], 1).astype(
        np.float32)
    if image is None:
        return points
    return points, image[ys, xs].astype(np.float32)
