"""`edge-depth ros2-play REC`: a recording published as ROS 2 topics at its own pace, for a
machine without `ros2 bag play` (rosbag2 is not served as a wheel) and for the node's tests.

A ROS 2 bag or a ros2-profile recording (CDR messages) is published as it is: each message's
bytes on its own topic with its own type, in file order, paced by log time — another tool's
topic names, frames and stamps, scans stored after their frames included. Our own
foxglove-profile recordings are published through the ros2 profile's messages
(`edge.ros2_node.Ros2Outputs`): the pair on `left/image_rect`, `right/image_rect` with
their `CameraInfo`, the LiDAR on `points` — the node's default inputs.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field

from edge_depth.capture.mcap_tolerant import ReadReport, iter_messages
from edge_depth.capture.replay import McapSource, bag_files
from edge_depth.ros2_node import INPUTS, Ros2Outputs, message_class
from edge_depth.types import LidarScan, StereoFrame

log = logging.getLogger(__name__)
# our recordings' raw topics, published under the node's default input names
RAW_NAMES = dict(left=INPUTS["left"], right=INPUTS["right"], left_raw="left/image_raw",
                 right_raw="right/image_raw",
                 left_calibration=INPUTS["left_info"], right_calibration=INPUTS["right_info"],
                 lidar=INPUTS["lidar"])


@dataclass
class PlayStats:
    published: int = 0
    skipped: dict[str, int] = field(default_factory=dict)  # topic -> messages not published


class Pacer:
    """Sleeps until a log time's turn at `rate` times real time (0: as fast as it goes)."""

    def __init__(self, rate: float, stop: threading.Event) -> None:
        self.rate, self.stop = rate, stop
        self.origin: tuple[int, float] | None = None  # (log time, monotonic s)

    def wait(self, log_time_ns: int) -> None:
        if self.rate <= 0:
            return
        now = time.monotonic()
        if self.origin is None:
            self.origin = (log_time_ns, now)
        due = self.origin[1] + (log_time_ns - self.origin[0]) / 1e9 / self.rate
        if due > now:
            self.stop.wait(due - now)


def is_cdr(path) -> bool:
    """Whether a recording holds ROS 2 messages (CDR): a bag, or the ros2 profile."""
    for _, channel, _ in iter_messages(bag_files(path)[0], ReadReport()):
        return channel.message_encoding == "cdr"
    return False


def wait_for_subscribers(publishers: list, timeout_s: float, settle_s: float = 1.0) -> None:
    """Give the graph up to `timeout_s` to match subscribers to the publishers (one that
    discovers its topic late misses the first messages): until one matches, then until no
    further one has matched for `settle_s` (a subscriber's node may want only some topics)."""
    from edge_depth.ros2_node import wait_for

    def matched() -> int:
        return sum(p.get_subscription_count() > 0 for p in publishers)

    deadline = time.monotonic() + timeout_s
    if not wait_for(lambda: matched() > 0, timeout_s):
        return
    while (count := matched()) < len(publishers) and time.monotonic() < deadline:
        if not wait_for(lambda: matched() > count, min(settle_s, deadline - time.monotonic())):
            return


def _channels(path) -> dict:
    """topic -> schema of every channel of a bag or file (one pass over what it holds)."""
    found: dict = {}
    for file in bag_files(path):
        for schema, channel, _ in iter_messages(file, ReadReport()):
            found.setdefault(channel.topic, schema)
    return found


def play_cdr(node, path, qos, pacer: Pacer, stop: threading.Event,
             wait_s: float = 5.0) -> PlayStats:
    """Every CDR message of a bag or ros2-profile file, published raw on its own topic."""
    stats = PlayStats()
    publishers = {topic: _publisher(node, topic, schema, qos)
                  for topic, schema in _channels(path).items()}
    wait_for_subscribers([p for p in publishers.values() if p is not None], wait_s)
    for file in bag_files(path):
        for _, channel, message in iter_messages(file, ReadReport()):
            if stop.is_set():
                return stats
            topic = channel.topic
            if publishers.get(topic) is None:
                stats.skipped[topic] = stats.skipped.get(topic, 0) + 1
                continue
            pacer.wait(message.log_time)
            publishers[topic].publish(bytes(message.data))
            stats.published += 1
    return stats


def _publisher(node, topic: str, schema, qos):
    """A raw publisher of the schema's type, or None when its package is not installed
    (tf2_msgs is not served as a wheel: /tf_static is then left out, and said)."""
    try:
        msg_type = message_class(schema.name)
    except (ImportError, AttributeError, ValueError):
        log.warning("%s: %s is not installed here; its messages are not published", topic,
                    schema.name if schema is not None else "an untyped channel")
        return None
    return node.create_publisher(msg_type, topic, 10 if topic.startswith("/tf") else qos)


def play_ours(node, path, qos, pacer: Pacer, stop: threading.Event,
              wait_s: float = 5.0) -> PlayStats:
    """A foxglove-profile recording's pair, camera infos and scans, as ROS 2 messages."""
    from edge_depth.capture.recording_calibration import recording_calibration

    source = McapSource(path)
    found = recording_calibration(source)
    outputs = Ros2Outputs(node, RAW_NAMES, qos)
    if found is not None:
        outputs.set_calibration(*found[:2])
    wait_for_subscribers(outputs.advertise(), wait_s)
    stats = PlayStats()
    for event in source:
        if stop.is_set():
            break
        if isinstance(event, StereoFrame):
            pacer.wait(event.stamp_ns)
            outputs.log_frame(event)
        elif isinstance(event, LidarScan):
            pacer.wait(event.stamp_ns)
            outputs.log_scan(event)
    stats.published = outputs.published
    outputs.close()
    return stats
