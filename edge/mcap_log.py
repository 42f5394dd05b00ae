"""Writing sensor data and results to MCAP (foxglove-sdk, protobuf Foxglove schemas).

Topics (DESIGN.md): /stereo/{left,right}/image_rect (mono8; /stereo/{left,right}/image when
the pair is not rectified), /stereo/{left,right}/calibration (rectified intrinsics; the right
one's P carries -f·B, as in ROS), /lidar/points (LiDAR frame, x y z intensity float32),
/depth/sparse_disparity, /depth/disparity, /depth/image, /depth/confidence (32FC1; confidence
only from a model with the refinement stage), /depth/points, /diagnostics
(JSON). Two more of ours: /edge/calibration (JSON, the calibration file's TOML text, logged at
the start of every file so a recording replays without side files) and /sim/gt_disparity
(32FC1, ground truth where a simulator made the data).

Log time is the sensor stamp (nanoseconds), so a replay reproduces the recording's timing.
Files rotate by size or duration into NAME_0001.mcap, NAME_0002.mcap, ...; `close()` writes
the summary (the caller makes sure it runs, on signals too: see edge.daemon and edge.commands).
"""

from __future__ import annotations

import json
import logging
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from edge_depth.disk_reserve import DiskReserve
from edge_depth.foxglove_msgs import (
    CAMERA_FRAME,
    LIDAR_FRAME,
    RIGHT_FRAME,
    depth_to_points,
    image_message,
    point_cloud_message,
    timestamp,
)
from edge_depth.topics import LATCHED, RAW_TOPICS, RESULT_TOPICS, TOPICS  # noqa: F401 - re-exported
from edge_depth.types import DepthResult, LidarScan, StereoFrame

log = logging.getLogger(__name__)

# a 640x400 frame's six result topics (experiments/log_cost.py): none 4.35 MB in 3.2 ms, lz4
# 3.23 MB in 6.7 ms (nearly all of the saving the sparse disparity's zeros: the float maps
# barely compress), zstd 2.68 MB in 21.6 ms; lz4 is the default
COMPRESSIONS = ("lz4", "zstd", "none")


# the topics one message of each frame goes on: its images' (rectified or raw), its results'
FRAME_KEYS = ("left", "left_raw", "disparity", "depth")
MIN_FREE_BYTES = 64 * 2**20  # the least free space kept (edge.disk_reserve adds a frame's)


# the JSON channels' schemas (JSON Schema), so viewers can type their fields
JSON_SCHEMAS = {
    "calibration_file": {"title": "edge.Calibration", "type": "object",
                         "properties": {"toml": {"type": "string",
                                                 "description": "the calibration file"}},
                         "required": ["toml"]},
    "diagnostics": {"title": "edge.Diagnostics", "type": "object", "properties": {
        "frames": {"type": "integer"}, "scans": {"type": "integer"},
        "drops": {"type": "integer"}, "errors": {"type": "object"},
        "lidar_sync": {"type": "object"}, "sources": {"type": "object"},
        "latency_ms": {"type": "object"}, "iterations": {"type": "array",
                                                         "items": {"type": "integer"}},
        # per frame that ran it, the % of pixels each selection replaced
        "lidar_select_replaced_pct": {"type": "array", "items": {"type": "number"}},
        "band_refined_pct": {"type": "array", "items": {"type": "number"}},
        # frames whose band refinement the deadline skipped
        "band_skipped": {"type": "integer"},
        # the depth map's health (edge.health): level OK / WARN / ERROR and its cause
        "output_health": {"type": "object", "properties": {
            "level": {"type": "string"}, "invalid_pct": {"type": "number"},
            "message": {"type": "string"}}}}},
}


def _late_joiner_listener(logger: McapLogger):
    """A live-view ServerListener that sends the latched topics again to each subscriber."""
    import foxglove

    class LateJoiners(foxglove.ServerListener):
        def on_subscribe(self, client, channel) -> None:
            logger.resend_latched(channel.topic)

    return LateJoiners()


class McapLogger:
    """Log frames, scans and results to rotating MCAP files (a context manager).

    At each frame's start it checks the free space on the log's disk (edge.disk_reserve: at
    least `min_free_bytes`, and room for the largest frame written so far, the chunk in memory
    and the summary): below it, the frame is not logged, the file is closed with its summary,
    no rotated part is left without a frame, it says so once, and `stopped` holds what
    happened (the daemon then exits non-zero, so systemd restarts it once space is made). A
    writer that fails all the same (another process filled the disk) leaves a file cut back
    to its last complete chunk and ended without a summary, which every reader takes.

    `topics`: which keys of TOPICS to write (default all); `rotate_bytes` / `rotate_s`: start
    a new file after this many bytes (as counted on disk) or seconds of log time;
    `compression`: chunk compression, one of COMPRESSIONS; `live`: also serve the channels on
    a Foxglove WebSocket server (foxglove.sdk.v1 / foxglove.websocket.v1 subprotocols:
    Foxglove, Lichtblick) at live_host:live_port; a client that subscribes after the start
    is sent the calibration and the transforms (LATCHED) when it subscribes."""

    def __init__(self, path: str | Path, topics: tuple[str, ...] | None = None,
                 rotate_bytes: int | None = None, rotate_s: float | None = None,
                 calibration_toml: str | None = None, chunk_size: int = 1 << 20,
                 compression: str = "lz4", live: bool = False, live_port: int = 8765,
                 min_free_bytes: int = MIN_FREE_BYTES, live_host: str = "127.0.0.1",
                 overwrite: bool = True, parent_frame: str = "",
                 T_parent_camera=None) -> None:
        import foxglove

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.enabled = set(TOPICS) if topics is None else set(topics)
        unknown = self.enabled - set(TOPICS)
        if unknown:
            raise ValueError(f"unknown topics {sorted(unknown)}; choose from {sorted(TOPICS)}")
        self.rotate_bytes, self.rotate_s = rotate_bytes, rotate_s
        self.overwrite = overwrite  # False (the daemon): an existing file gets a new name
        # the transforms' root: camera_left, or camera_left under this robot frame
        self.parent_frame = parent_frame
        self.T_parent_camera = np.eye(4) if T_parent_camera is None else np.asarray(
            T_parent_camera, float)
        self.calibration_toml = calibration_toml
        self.camera: tuple | None = None  # (size, focal_px, principal_point, baseline_m)
        self.lidar_T: np.ndarray | None = None  # T_cam_lidar, for the transforms
        self._latest: dict[str, tuple] = {}  # LATCHED key -> (message, stamp_ns)
        self._latest_lock = threading.Lock()
        self.chunk_size = chunk_size
        if compression not in COMPRESSIONS:
            raise ValueError(f"compression: expected one of {COMPRESSIONS}, got {compression!r}")
        self.compression = compression
        self.context = foxglove.Context()
        self._channels: dict[str, object] = {}
        self.files: list[Path] = []
        self.messages = 0
        self._writer = None
        self._next_index = 0
        self._file_start_ns: int | None = None
        self.server = None
        self.reserve = DiskReserve(min_free_bytes, chunk_size)
        self.stopped: str | None = None  # why logging stopped early (the disk filling up)
        self._frames_in_file = 0
        self._last_frame_ns: int | None = None  # the frame in hand's stamp
        self._space_checked_at = 0.0  # monotonic s: the scans' own check of the free space
        if live:
            self.server = foxglove.start_server(context=self.context, host=live_host,
                                                port=live_port, name="edge-depth",
                                                server_listener=_late_joiner_listener(self))
        self._open(None)

    # -- files -------------------------------------------------------------------------------
    def _is_rotating(self) -> bool:
        return self.rotate_bytes is not None or self.rotate_s is not None

    def _file_path(self, index: int) -> Path:
        if not self._is_rotating():  # one file: NAME.mcap, then NAME_0001.mcap if taken
            if self.overwrite or index == 0:
                return self.path
            return self.path.with_name(f"{self.path.stem}_{index:04d}{self.path.suffix}")
        return self.path.with_name(f"{self.path.stem}_{index + 1:04d}{self.path.suffix}")

    def _open(self, stamp_ns: int | None) -> None:
        # rotating files never overwrite: a restarted daemon continues at the next free index
        # instead of replacing the file its predecessor was cut off in
        path = self._file_path(self._next_index)
        while (self._is_rotating() or not self.overwrite) and path.exists():
            self._next_index += 1
            path = self._file_path(self._next_index)
        self._next_index += 1
        self._writer = self._start_writer(path)
        self.files.append(path)
        self._file_start_ns = stamp_ns
        self._calibration_logged = False
        self._frames_in_file = 0

    def _start_writer(self, path: Path):
        import foxglove
        from foxglove.mcap import MCAPCompression, MCAPWriteOptions

        compression = {"zstd": MCAPCompression.Zstd, "lz4": MCAPCompression.Lz4,
                       "none": None}[self.compression]
        options = MCAPWriteOptions(chunk_size=self.chunk_size, compression=compression,
                                   compression_threads=0)
        return foxglove.open_mcap(path, allow_overwrite=True, context=self.context,
                                  writer_options=options)

    def _frame_start(self, stamp_ns: int, pixels: int) -> bool:
        """Whether the frame at `stamp_ns` (of `pixels` pixels a view) is logged. At a new
        frame the free space is checked first; below the reserve logging stops, and the file
        is closed while its summary fits. A frame's result follows its images: one check."""
        if self.stopped is not None:
            return False
        if self._last_frame_ns == stamp_ns:
            return True
        file = self.files[-1]
        low = self.reserve.below(file.parent, file.stat().st_size if file.exists() else 0,
                                 pixels)
        if low is not None:
            self._stop_for_space(low)
            return False
        self._maybe_rotate(stamp_ns)
        self._last_frame_ns = stamp_ns
        self._frames_in_file += 1
        return True

    def _stop(self, why: str) -> None:
        """Logging stops for good (the daemon then exits non-zero): said once."""
        self.stopped = f"{why}; make space and restart"
        log.error("%s", self.stopped)

    def _stop_for_space(self, low: str) -> None:
        # a part is opened at a frame's start after this check, so none is left empty
        self._stop(f"{low}: {self._close_writer()}")

    def _maybe_rotate(self, stamp_ns: int) -> None:
        if self._writer is None:  # stopped: no new file either
            return
        if self._file_start_ns is None:
            self._file_start_ns = stamp_ns
        too_big = (self.rotate_bytes is not None and self.files[-1].exists()
                   and self.files[-1].stat().st_size >= self.rotate_bytes)
        too_long = (self.rotate_s is not None
                    and stamp_ns - self._file_start_ns >= self.rotate_s * 1e9)
        if too_big or too_long:
            closed = self._close_writer()
            if not closed.startswith("closed "):  # the part could not be closed: stop here
                self._stop(closed)
                return
            self._open(stamp_ns)

    def _channel(self, key: str):
        if key not in self._channels:
            from foxglove import Channel
            from foxglove.channels import (
                CameraCalibrationChannel,
                FrameTransformsChannel,
                PointCloudChannel,
                RawImageChannel,
            )

            topic = TOPICS[key]
            channel: Any
            if key in ("diagnostics", "calibration_file"):
                channel = Channel(topic, message_encoding="json", context=self.context,
                                  schema=JSON_SCHEMAS[key])
            elif key in ("lidar", "points"):
                channel = PointCloudChannel(topic, context=self.context)
            elif key == "transforms":
                channel = FrameTransformsChannel(topic, context=self.context)
            elif key.endswith("calibration"):
                channel = CameraCalibrationChannel(topic, context=self.context)
            else:
                channel = RawImageChannel(topic, context=self.context)
            self._channels[key] = channel
        return self._channels[key]

    def _topic(self, key: str) -> str:
        """The topic `key` is written on (the ros2 profile's differ)."""
        return TOPICS[key]

    def _logs(self, key: str) -> bool:
        """Whether `key` is written to this logger's files."""
        return key in self.enabled

    def _log(self, key: str, message, stamp_ns: int) -> None:
        if not self._logs(key) or self._writer is None:
            return
        if not self._calibration_logged:  # first in every file, so each replays on its own
            self._calibration_logged = True
            self._log_file_start(stamp_ns)
        try:
            self._write(key, message, stamp_ns)
        except OSError as exc:  # a writer that raises (the ros2 profile's): stop cleanly
            self._stop(f"writing {self.files[-1]} failed ({exc}): {self._close_writer()}")
            return
        self.messages += 1

    def _log_file_start(self, stamp_ns: int) -> None:
        """What opens every file: the calibration's TOML, both cameras and the transforms."""
        if self.calibration_toml is not None:
            self._log("calibration_file", {"toml": self.calibration_toml}, stamp_ns)
        if self.camera is not None:
            self.log_calibration(stamp_ns, *self.camera)
            self._log("transforms", self._transforms(stamp_ns), stamp_ns)

    def _write(self, key: str, message, stamp_ns: int) -> None:
        if key in LATCHED:
            with self._latest_lock:
                self._latest[key] = (message, int(stamp_ns))
        self._channel(key).log(message, log_time=int(stamp_ns))

    def resend_latched(self, topic: str) -> None:
        """Send the latest calibration / transforms on `topic` again (a live-view client
        just subscribed to it; the file gets the copy too, which replays the same)."""
        for key in LATCHED:
            with self._latest_lock:
                latest = self._latest.get(key) if TOPICS[key] == topic else None
            if latest is not None:
                self._channel(key).log(latest[0], log_time=latest[1])

    def frame_tree(self) -> list[tuple[str, str, np.ndarray]]:
        """(parent, child, T_parent_child): camera_left → camera_right (B along x,
        rectified), camera_left → lidar (T_cam_lidar), parent_frame → camera_left."""
        assert self.camera is not None, "the transforms follow the camera's calibration"
        right = np.eye(4)
        right[0, 3] = self.camera[3]
        tree = [(CAMERA_FRAME, RIGHT_FRAME, right)]
        if self.lidar_T is not None:
            tree.append((CAMERA_FRAME, LIDAR_FRAME, self.lidar_T))
        if self.parent_frame:
            tree.append((self.parent_frame, CAMERA_FRAME, self.T_parent_camera))
        return tree

    def _transforms(self, stamp_ns: int):
        """The frame tree as foxglove FrameTransforms."""
        from foxglove.messages import FrameTransform, FrameTransforms, Quaternion, Vector3
        from scipy.spatial.transform import Rotation

        out = []
        for parent, child, T in self.frame_tree():
            x, y, z, w = (float(v) for v in Rotation.from_matrix(T[:3, :3]).as_quat())
            out.append(FrameTransform(
                timestamp=timestamp(stamp_ns), parent_frame_id=parent, child_frame_id=child,
                translation=Vector3(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
                rotation=Quaternion(x=x, y=y, z=z, w=w)))
        return FrameTransforms(transforms=out)

    def set_calibration(self, stereo, lidar=None) -> None:
        """The calibration logged at the start of every file from now on (and again now): the
        TOML on /edge/calibration and the rectified intrinsics of both views."""
        from edge_depth.calibration.io import dumps_calibration

        self.calibration_toml = dumps_calibration(stereo, lidar)
        self.camera = (stereo.image_size, stereo.focal_px, stereo.principal_point,
                       stereo.baseline_m)
        self.lidar_T = None if lidar is None else np.asarray(lidar.T_cam_lidar, float)
        self._calibration_logged = False

    # -- messages (the profile: Ros2Logger builds ROS 2 messages instead) ----------------------
    def _image(self, image: np.ndarray, stamp_ns: int, frame_id: str = CAMERA_FRAME):
        return image_message(image, stamp_ns, frame_id)

    def _cloud(self, points: np.ndarray, stamp_ns: int, frame_id: str, intensity=None,
               point_stamps_ns=None):
        return point_cloud_message(points, stamp_ns, frame_id, intensity, point_stamps_ns)

    def _disparity(self, result: DepthResult):
        return image_message(result.disparity, result.stamp_ns)

    def _depth(self, result: DepthResult):
        depth = np.where(result.valid, result.depth, np.float32(np.nan))  # REP 118, float32
        return self._image(depth, result.stamp_ns)

    # -- what gets logged --------------------------------------------------------------------
    def log_frame(self, frame: StereoFrame) -> None:
        if not self._frame_start(frame.stamp_ns, frame.left.shape[0] * frame.left.shape[1]):
            return
        left, right = ("left", "right") if frame.rectified else ("left_raw", "right_raw")
        self._log(left, self._image(frame.left, frame.stamp_ns), frame.stamp_ns)
        self._log(right, self._image(frame.right, frame.stamp_ns, RIGHT_FRAME), frame.stamp_ns)

    def log_calibration(self, stamp_ns: int, size: tuple[int, int], focal_px: float,
                        principal_point: tuple[float, float], baseline_m: float) -> None:
        """Rectified intrinsics of both views (ROS convention: right P[3] = -f·B)."""
        from foxglove.messages import CameraCalibration

        w, h = size
        cx, cy = principal_point
        K = [focal_px, 0, cx, 0, focal_px, cy, 0, 0, 1]
        R = [1.0, 0, 0, 0, 1, 0, 0, 0, 1]
        for key, tx, frame_id in (("left_calibration", 0.0, CAMERA_FRAME),
                                  ("right_calibration", -focal_px * baseline_m, RIGHT_FRAME)):
            P = [focal_px, 0, cx, tx, 0, focal_px, cy, 0, 0, 0, 1, 0]
            msg = CameraCalibration(timestamp=timestamp(stamp_ns), frame_id=frame_id, width=w,
                                    height=h, distortion_model="plumb_bob", D=[0.0] * 5, K=K,
                                    R=R, P=P)
            self._log(key, msg, stamp_ns)

    def log_scan(self, scan: LidarScan) -> None:
        # files rotate at a frame's start only, so a frame's images and result share a file;
        # while no frame comes (a camera away) scans still fill the disk: checked once a second
        if self._writer is None or self._scan_space_low():
            return
        self._log("lidar", self._cloud(scan.points, scan.stamp_ns, LIDAR_FRAME, scan.intensity,
                                       scan.point_stamps_ns), scan.stamp_ns)

    def _scan_space_low(self) -> bool:
        now = time.monotonic()
        if now - self._space_checked_at < 1.0:
            return False
        self._space_checked_at = now
        file = self.files[-1]
        low = self.reserve.below(file.parent, file.stat().st_size if file.exists() else 0, 0,
                                 measure=False)
        if low is not None:
            self._stop_for_space(low)
        return low is not None

    def log_gt(self, stamp_ns: int, disparity: np.ndarray) -> None:
        self._log("gt_disparity", self._image(disparity.astype(np.float32, copy=False),
                                              stamp_ns),
                  stamp_ns)

    def log_result(self, result: DepthResult, sparse: np.ndarray | None = None,
                   focal_px: float | None = None,
                   principal_point: tuple[float, float] | None = None,
                   left: np.ndarray | None = None) -> None:
        """The result's images and, with the camera's focal length and principal point, the
        depth as a point cloud (each point's intensity from `left`, the rectified image)."""
        t = result.stamp_ns
        if not self._frame_start(t, result.disparity.size):
            return
        # a message is built only for a topic that is written (`topics`: [log] results)
        if sparse is not None and self._logs("sparse"):
            self._log("sparse", self._image(sparse.astype(np.float32, copy=False), t), t)
        if self._logs("disparity"):
            self._log("disparity", self._disparity(result), t)
        if self._logs("depth"):
            self._log("depth", self._depth(result), t)
        if result.confidence is not None and self._logs("confidence"):
            self._log("confidence", self._image(result.confidence, t), t)
        if self._logs("points") and focal_px is not None and principal_point is not None:
            pts, intensity = depth_to_points(result.depth, result.valid, focal_px,
                                             principal_point, image=left if left is not None
                                             else np.zeros(result.depth.shape, np.uint8))
            self._log("points", self._cloud(pts, t, CAMERA_FRAME, intensity), t)

    def log_diagnostics(self, stamp_ns: int, values: dict) -> None:
        self._log("diagnostics", json.loads(json.dumps(values, default=float)), stamp_ns)

    def _close_writer(self) -> str:
        """Close the open file; what happened, in words ("" when none was open)."""
        if self._writer is None:
            return ""
        writer, self._writer = self._writer, None
        path, frames = self.files[-1], self._frames_in_file
        try:
            self._finish(writer)
        except (OSError, RuntimeError) as exc:  # FoxgloveError is a RuntimeError
            return self._end_cut_file(path, exc)
        return f"closed {path} with its summary ({frames} frames)"

    def _end_cut_file(self, path: Path, exc: BaseException) -> str:
        """The writer failed (a full disk): end the file after its last complete chunk,
        without a summary, and count the frames it still holds (the stamps of its frame
        topics: a frame's images and results share its stamp)."""
        from edge_depth.capture.mcap_tolerant import ReadReport, end_cut_file, iter_messages

        frame_topics = {self._topic(key) for key in FRAME_KEYS}
        try:
            end_cut_file(path)
            stamps = {message.log_time for _, channel, message
                      in iter_messages(path, ReadReport()) if channel.topic in frame_topics}
        except (OSError, ValueError) as repair_exc:
            said = (f"could not close {path} ({exc}), nor end it after its last complete chunk "
                    f"({repair_exc}); `edge-depth replay` reads what it holds")
        else:
            said = (f"could not write the summary of {path} ({exc}): ended it after its last "
                    f"complete chunk, without a summary; {len(stamps)} of its "
                    f"{self._frames_in_file} frames are readable")
        log.error("%s", said)
        return said

    def _finish(self, writer) -> None:
        """Write the file's summary and close it."""
        writer.close()

    def close(self) -> None:
        self._close_writer()
        if self.server is not None:
            self.server.stop()
            self.server = None

    def __enter__(self) -> McapLogger:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
