"""`edge-depth ros2`: the engine as a live ROS 2 node (rclpy from PyPI's ROS 2 wheels: the
`ros2` extra; no ROS installation needed).

It subscribes a robot's stereo pair (`sensor_msgs/Image` mono8 / rgb8 / bgr8 or
`CompressedImage`, rectified, or raw with their `CameraInfo`) and its LiDAR (`PointCloud2`
with float32 x y z in any layout, or `LaserScan`) and publishes, each stamped with its
frame's stamp and frame id: `stereo_msgs/DisparityImage` on `disparity`, the depth as
`sensor_msgs/Image` 32FC1 in metres (NaN where invalid, REP 118) on `depth/image_rect` with
its `CameraInfo` on `depth/camera_info`, the confidence (32FC1, 0-1) on `confidence_map`,
the depth as `PointCloud2` on `points2`, and `diagnostic_msgs/DiagnosticArray` on
`/diagnostics` (the daemon's counts, latency, output health and the calibration watch, as
statuses) — the names `stereo_image_proc` and `isaac_ros_ess` users know, remappable.

One code path with the daemon and replay: messages arrive as CDR bytes (raw subscriptions)
and are decoded by the ROS 2 bag reader's decoder, become events in
`edge.capture.message_events`, and go through the daemon's runner and pipeline (pairing with
scans that arrive after their frame, deskew, the calibration watch); outputs are the ros2
MCAP profile's messages (`edge.ros2_log`), published as the bytes that profile writes.

Not served as wheels, so done without: `tf2_ros` (the LiDAR extrinsics come from the
calibration file: `--calib` or the config's), `message_filters` (the pairing above),
`cv_bridge` (`edge.capture.decode`), `rosbag2` (`edge-depth ros2-play` publishes a recording).
"""

from __future__ import annotations

import importlib
import logging
import threading
import time
from collections import deque
from functools import partial
from typing import Any

from edge_depth.capture import Source
from edge_depth.capture.message_events import MessageEvents
from edge_depth.capture.replay import ReplayStats, TopicMap
from edge_depth.errors import EdgeError
from edge_depth.foxglove_msgs import CAMERA_FRAME
from edge_depth.ros2_log import TYPES, Ros2Logger, camera_info_msg
from edge_depth.ros2_msgs import cdr_decoder, cdr_encoder

log = logging.getLogger(__name__)
ROS2_HINT = "pip install 'edge-depth[ros2]'"
# the inputs' defaults: stereo_image_proc's and isaac_ros_ess's names, relative to the node
INPUTS = dict(left="left/image_rect", right="right/image_rect", left_info="left/camera_info",
              right_info="right/camera_info", lidar="points", calibration="", gt="")
OUTPUTS = dict(disparity="disparity", depth="depth/image_rect", depth_info="depth/camera_info",
               confidence="confidence_map", points="points2", diagnostics="/diagnostics")
OUTPUT_TYPES = dict(TYPES, depth_info="sensor_msgs/msg/CameraInfo")
INPUT_TYPES = {"sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage",
               "sensor_msgs/msg/CameraInfo", "sensor_msgs/msg/PointCloud2",
               "sensor_msgs/msg/LaserScan"}
QUEUE_MESSAGES = 64  # raw messages held between the DDS threads and the pipeline


class Ros2MissingError(EdgeError):
    """rclpy or a message package is not installed."""


def import_rclpy():
    """rclpy, or Ros2MissingError naming the extra that installs it."""
    try:
        import rclpy

        for package in ("sensor_msgs", "stereo_msgs", "diagnostic_msgs"):
            importlib.import_module(f"{package}.msg")
    except ImportError as exc:
        raise Ros2MissingError(f"needs ROS 2's rclpy and message packages ({exc.name} is not "
                          f"installed): {ROS2_HINT}") from None
    return rclpy


def message_class(type_name: str):
    """The rclpy class of "package/msg/Name" (its type support, for raw (de)serialisation)."""
    package, _, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.msg"), name)


def input_topics(topics: TopicMap | None) -> TopicMap:
    """The node's topic map: a topics file's (the same as replay's), else INPUTS."""
    return topics if topics is not None else TopicMap(**INPUTS)


class Ros2Source(Source):
    """The mapped topics of a running ROS 2 graph as the pipeline's events. Each topic is
    subscribed once the graph advertises it, with the type it advertises (so a LiDAR topic
    may carry PointCloud2 or LaserScan); messages wait in a bounded queue (the oldest dropped
    and counted when the pipeline falls behind) and are decoded and paired as replay does.
    Arrival time is the node clock's, the fall-back where stamps do not increase."""

    def __init__(self, node, topics: TopicMap, qos, queue_messages: int = QUEUE_MESSAGES,
                 pair_window_ns: int = 5_000_000) -> None:
        super().__init__()
        self.node, self.topics, self.qos = node, topics, qos
        self.stats = ReplayStats()
        self.pair_window_ns = pair_window_ns
        self.subscribed: dict[str, str] = {}  # topic -> its message type
        self._queue: deque = deque()
        self._queue_messages = queue_messages
        self._cond = threading.Condition()
        self._closed = threading.Event()
        self._wrong_type: set[str] = set()
        self.frame_id = ""  # the left camera's, from its first image
        self.discover()
        self._timer = node.create_timer(0.2, self.discover)

    def wanted(self) -> list[str]:
        t = self.topics
        return [name for name in (t.left, t.right, t.left_info, t.right_info, t.lidar) if name]

    def discover(self) -> None:
        """Subscribe every wanted topic the graph now advertises (names as the node resolves
        them: relative ones under its namespace)."""
        advertised = dict(self.node.get_topic_names_and_types())
        for topic in self.wanted():
            resolved = self.node.resolve_topic_name(topic)
            if topic in self.subscribed or resolved not in advertised:
                continue
            type_name = next((t for t in advertised[resolved] if t in INPUT_TYPES), None)
            if type_name is None:
                if topic not in self._wrong_type:
                    self._wrong_type.add(topic)
                    log.warning("%s carries %s, not one of %s: not subscribed", resolved,
                                ", ".join(advertised[resolved]), ", ".join(sorted(INPUT_TYPES)))
                    self.stats.errors[f"{resolved}: type {advertised[resolved][0]}"] += 1
                continue
            self.node.create_subscription(message_class(type_name), topic,
                                          partial(self._received, topic, type_name), self.qos,
                                          raw=True)
            self.subscribed[topic] = type_name

    def _received(self, topic: str, type_name: str, data: bytes) -> None:
        arrival_ns = self.node.get_clock().now().nanoseconds
        with self._cond:
            if len(self._queue) >= self._queue_messages:
                self._queue.popleft()
                self.stats.errors["input queue full: the oldest message dropped"] += 1
            self._queue.append((topic, type_name, data, arrival_ns))
            self._cond.notify()

    def _next(self):
        with self._cond:
            while not self._queue and not self._closed.is_set():
                self._cond.wait(0.1)
            return self._queue.popleft() if self._queue else None

    def __iter__(self):
        events = MessageEvents(self.topics, self.stats, "ros2", self.pair_window_ns)
        decoders: dict[str, object] = {}
        while (item := self._next()) is not None:
            topic, type_name, data, arrival_ns = item
            self.stats.messages += 1
            try:
                if type_name not in decoders:
                    decoders[type_name] = cdr_decoder(type_name)
                decoded = decoders[type_name](data)  # type: ignore[operator]
                if topic == self.topics.left and not self.frame_id:
                    self.frame_id = str(decoded.header.frame_id)
                yield from events.events(topic, decoded, arrival_ns)
            except Exception as exc:  # noqa: BLE001 - a malformed message: counted, skipped
                key = f"{topic}: {type(exc).__name__}: {exc}"[:120]
                if not self.stats.errors[key]:
                    log.warning("skipped a message on %s: %s", topic, exc)
                self.stats.errors[key] += 1
        events.finish()  # half pairs left at the end are counted, as replay counts them

    def close(self) -> None:
        self._closed.set()
        with self._cond:
            self._cond.notify_all()

    def counters(self) -> dict:
        s = self.stats
        return dict(messages=s.messages, frames=s.frames, scans=s.scans,
                    subscribed=sorted(self.subscribed), waiting_for=sorted(
                        set(self.wanted()) - set(self.subscribed)), errors=dict(s.errors))


class Ros2Outputs(Ros2Logger):
    """The pipeline's logger interface, publishing instead of writing a file: each output is
    the ros2 profile's message (`edge.ros2_log`), serialised to the bytes that profile writes
    and published raw on `names[key]` (keys of OUTPUTS; a key left out is not published),
    built only while a subscriber listens. No files, no free-space checks, no rotation;
    `close` destroys the publishers."""

    def __init__(self, node, names: dict[str, str], qos, frame_id=lambda: CAMERA_FRAME) -> None:
        self.node, self.names, self.qos = node, names, qos
        self.frame_id = frame_id  # the input's left camera frame, once one has come
        self._publishers: dict[str, Any] = {}
        self._encoders: dict[str, object] = {}
        self.published = 0
        super().__init__("ros2", topics=())

    def _image(self, image, stamp_ns: int, frame_id: str = CAMERA_FRAME) -> dict:
        return super()._image(image, stamp_ns, self._frame(frame_id))

    def _cloud(self, points, stamp_ns: int, frame_id: str, intensity=None,
               point_stamps_ns=None) -> dict:
        return super()._cloud(points, stamp_ns, self._frame(frame_id), intensity,
                              point_stamps_ns)

    def _disparity(self, result) -> dict:
        message = super()._disparity(result)
        message["header"]["frame_id"] = message["image"]["header"]["frame_id"] = self.frame_id()
        return message

    def _frame(self, frame_id: str) -> str:
        """Our left camera's frame is the input's left camera frame."""
        return self.frame_id() if frame_id == CAMERA_FRAME else frame_id

    def _open(self, stamp_ns: int | None) -> None:
        self._writer: object | None = self  # never None while open: somewhere to publish
        self._frames_in_file = 0
        self._calibration_logged = False

    def _frame_start(self, stamp_ns: int, pixels: int) -> bool:
        return True

    def _scan_space_low(self) -> bool:
        return False

    def _close_writer(self) -> str:
        """The publishers destroyed, once their subscribers have had the last outputs (a
        second at most)."""
        from rclpy.duration import Duration

        self._writer = None
        for publisher in self._publishers.values():
            publisher.wait_for_all_acked(Duration(seconds=1))
            self.node.destroy_publisher(publisher)
        self._publishers.clear()
        return ""

    def _logs(self, key: str) -> bool:
        """Published only where someone listens (a 640x400 frame's point cloud alone is 4 MB
        to build and send); /diagnostics always."""
        if self._writer is None or key not in self.names:  # closed, or not published
            return False
        return key == "diagnostics" or self._publisher(key).get_subscription_count() > 0

    def advertise(self) -> list:
        """A publisher for every name (they are otherwise made at their first message)."""
        return [self._publisher(key) for key in self.names]

    def _publisher(self, key: str):
        if key not in self._publishers:
            type_name = OUTPUT_TYPES.get(key, "sensor_msgs/msg/Image")
            qos = 10 if key == "diagnostics" else self.qos
            self._publishers[key] = self.node.create_publisher(
                message_class(type_name), self.names[key], qos)
            self._encoders[key] = cdr_encoder(type_name)
        return self._publishers[key]

    def _write(self, key: str, message: dict, stamp_ns: int) -> None:
        publisher = self._publisher(key)
        publisher.publish(self._encoders[key](message))  # type: ignore[operator]
        self.published += 1

    def log_result(self, result, sparse=None, focal_px=None, principal_point=None,
                   left=None) -> None:
        """The results, then the depth image's CameraInfo stamped like it."""
        super().log_result(result, sparse, focal_px, principal_point, left)
        if self.camera is not None and self._logs("depth_info"):
            size, f, pp, _ = self.camera
            self._log("depth_info", camera_info_msg(result.stamp_ns, self.frame_id(), size, f,
                                                    pp, 0.0), result.stamp_ns)


class LoggerPair:
    """Two loggers as one (the node's publisher and an MCAP log beside it): every call goes
    to both; `stopped` is the file's (a full disk stops the node as it stops the daemon)."""

    def __init__(self, outputs: Ros2Outputs, log_file) -> None:
        self.outputs, self.log_file = outputs, log_file

    def __getattr__(self, name: str):
        if name in ("stopped", "files"):
            return getattr(self.log_file, name)
        first, second = getattr(self.outputs, name), getattr(self.log_file, name)
        if not callable(first):
            return first

        def both(*args, **kwargs):
            first(*args, **kwargs)
            return second(*args, **kwargs)

        return both


def spin_in_thread(rclpy, node, on_error=None) -> tuple[object, threading.Thread]:
    """The node's callbacks (subscriptions, discovery) on an executor thread of their own;
    an error that ends it (while the node's context is up) is logged and given to
    `on_error`."""
    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)

    def spin() -> None:
        try:
            executor.spin()
        except Exception as exc:  # noqa: BLE001 - a shutdown ends the spin too: only say others
            if node.context.ok():
                log.exception("the ROS 2 executor stopped")
                if on_error is not None:
                    on_error(exc)

    thread = threading.Thread(target=spin, name="ros2-spin", daemon=True)
    thread.start()
    return executor, thread


def wait_for(predicate, timeout_s: float, period_s: float = 0.02) -> bool:
    """Poll `predicate` until it holds or `timeout_s` passes; whether it held."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(period_s)
    return bool(predicate())
