"""Decoded messages of the mapped topics → the pipeline's events: a frame paired from its two
images by stamp, scans, calibrations, ground truth. One path for every reader of messages:
replay (`edge.capture.replay`) and the live ROS 2 node (`edge.ros2_node`).

Stamps are the messages' header stamps — or, once those prove not to increase (all 0,
duplicated, a clock going back), their arrival times (a file's log times, a node's receive
times), counted and said once, so frames do not pair with the wrong scans.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator

import numpy as np

from edge_depth.capture.decode import (
    camera_info,
    decode_image,
    decode_points,
    header_stamp,
    toml_text,
)
from edge_depth.types import Calibration, GroundTruth, LidarScan, StereoFrame

log = logging.getLogger(__name__)
HALF_PAIR_NS = 1_000_000_000  # a half pair older than this will not be completed


class MessageEvents:
    """`topics`: the TopicMap (`edge.capture.replay`) of roles to topic names; `stats`: the
    source's counters (frames, scans, errors by reason), updated here; `name`: the source
    in warnings; `pair_window_ns`: how far apart a pair's two stamps may be."""

    def __init__(self, topics, stats, name: str, pair_window_ns: int = 5_000_000) -> None:
        self.topics, self.stats, self.name = topics, stats, name
        self.pair_window_ns = pair_window_ns
        self.pending: dict[int, dict[str, np.ndarray]] = {}  # stamp -> the half pair
        self._info: dict[str, tuple] = {}
        self._last_stamp: dict[str, int] = {}  # frame / scan: the previous one's stamp
        self.arrival_order = False  # stamps proved useless: arrival times instead

    def events(self, topic: str, decoded, arrival_ns: int) -> Iterator:
        """The events one decoded message on `topic` completes (none, or one). Malformed
        messages raise ValueError, TypeError, AttributeError or IndexError: the caller
        counts and skips them."""
        t = self.topics
        if topic == t.calibration:
            yield Calibration(arrival_ns, toml=toml_text(decoded))
        elif topic in (t.left_info, t.right_info):
            yield from self._camera_info(topic, decoded, arrival_ns)
        elif topic == t.gt:
            yield GroundTruth(self.stamp(decoded, arrival_ns), decode_image(decoded))
        elif topic == t.lidar:
            pts, inten, offsets = decode_points(decoded)
            self.stats.scans += 1
            stamp = self.stamp(decoded, arrival_ns)
            self._check_order("scan", stamp)
            yield LidarScan(stamp, pts, inten, None if offsets is None else stamp + offsets)
        else:  # left or right image
            yield from self._image("left" if topic == t.left else "right", decoded,
                                   arrival_ns)

    def finish(self) -> None:
        """The stream ended: its half pairs are counted."""
        if self.pending:
            self.stats.errors["unpaired image"] += len(self.pending)
            self.pending.clear()

    def stamp(self, msg, arrival_ns: int) -> int:
        """The message's header stamp — or, once those have proved not to increase, its
        arrival time (`_check_order`)."""
        stamp = header_stamp(msg, arrival_ns)
        return arrival_ns if self.arrival_order else stamp

    def _camera_info(self, topic: str, decoded, arrival_ns: int) -> Iterator:
        t = self.topics
        self._info["left" if topic == t.left_info else "right"] = camera_info(decoded)
        if len(self._info) == 2:
            f, cx, cy, _, size = self._info["left"]
            tx = self._info["right"][3]
            if f > 0 and tx < 0:
                yield Calibration(arrival_ns, focal_px=f, principal_point=(cx, cy),
                                  baseline_m=-tx / f, size=size)
            self._info.clear()

    def _image(self, side: str, decoded, arrival_ns: int) -> Iterator:
        stamp = self.stamp(decoded, arrival_ns)
        image = decode_image(decoded)
        if image.dtype != np.uint8:
            raise ValueError(f"{side} image: a camera image must be 8-bit, got {image.dtype}")
        pending = self.pending
        match = next((s for s in pending
                      if abs(s - stamp) <= self.pair_window_ns and side not in pending[s]), None)
        if match is None:
            pending[stamp] = {side: image}
        else:
            pair = pending.pop(match)
            pair[side] = image
            self.stats.frames += 1
            self._check_order("frame", min(match, stamp))
            yield StereoFrame(min(match, stamp), self.stats.frames - 1, pair["left"],
                              pair["right"], rectified=self.topics.rectified)
        for s in [s for s in pending if stamp - s > HALF_PAIR_NS]:
            del pending[s]
            self.stats.errors["unpaired image"] += 1

    def _check_order(self, kind: str, stamp_ns: int) -> None:
        """Stamps that do not increase would pair frames with the wrong scans: counted, said
        once, and from then on frames and scans are stamped by their arrival times, where
        those do increase."""
        last = self._last_stamp.get(kind)
        self._last_stamp[kind] = stamp_ns
        if last is None or stamp_ns > last:
            return
        key = order_note(kind)
        if not self.stats.errors[key]:
            log.warning("%s: a %s stamp (%d ns) is not after the previous one (%d ns): the "
                        "stamps are zero, duplicated or go back; pairing by the messages' "
                        "arrival order (a recording's log times) from here on", self.name,
                        kind, stamp_ns, last)
        self.stats.errors[key] += 1
        self.arrival_order = True


def order_note(kind: str) -> str:
    return f"{kind} stamp not after the previous {kind}'s (zero, duplicated or going back)"
