"""A recording's frames with their LiDAR and ground truth, for the offline readers (training,
adapt, `calibrate lidar`): paired by the same sync, and the same bounded wait in stream time,
as replay and the daemon (`edge.runner`)."""

from __future__ import annotations

from collections import deque
from pathlib import Path

import numpy as np

from edge_depth.camera_turn import TurnMeter, deskewed
from edge_depth.capture.replay import McapSource, TopicMap
from edge_depth.capture.sync import LidarSync, SyncConfig
from edge_depth.types import GroundTruth, LidarScan, StereoFrame


def synced_frames(path: str | Path, stereo, time_offset_ns: int = 0, window_ms: float = 100.0,
                  topics: TopicMap | None = None, counters: dict | None = None,
                  max_wait_ms: float | None = None, deskew_with: np.ndarray | None = None):
    """Each frame of a recording with its LiDAR and ground truth, for offline use (training,
    adapt, the extrinsics check): yields (frame as recorded, rectified left, rectified right,
    points (N, 3) of the revolution nearest in time (0 rows if none), GT disparity or None).

    Frames pair as replay and the daemon pair them (`edge.runner`): each waits, in the
    stream's time, up to `max_wait_ms` (default twice the window) for the scans that cover
    it, so a recording that stores scans after their frames (a spinning LiDAR's revolution
    ends after the frame taken in its middle; kitti2mcap writes them so) pairs as one that
    stores them before. `stereo` rectifies frames the recording did not store rectified;
    `time_offset_ns` moves LiDAR stamps into the camera clock; `topics` maps a ROS 2 bag's.
    `counters`, if given, receives the sync's counts when the recording ends
    (frames_with_lidar, frames_without_lidar, ...). `deskew_with`: the calibration's
    T_cam_lidar, to deskew the points by the camera's turn as the daemon does
    (`edge.camera_turn.deskew`; where a point would move by DESKEW_MIN_PX or more); the
    frames deskewed so far are counted in `counters["frames_deskewed"]` as they go."""
    turn = None if deskew_with is None else TurnMeter(stereo.focal_px)
    for frame, left, right, points, stamp, times, gt in _paired_frames(
            path, stereo, time_offset_ns, window_ms, topics, counters, max_wait_ms):
        if turn is not None:
            turn.frame(frame.stamp_ns, left)
            if len(points) and stamp is not None:
                points, moved_px = deskewed(points, stamp if times is None else times,
                                            frame.stamp_ns, turn.rate(), stereo.focal_px,
                                            deskew_with)
                if moved_px and counters is not None:
                    counters["frames_deskewed"] = counters.get("frames_deskewed", 0) + 1
        yield frame, left, right, points, gt


def deskewed_note(counters: dict) -> str:
    """The reading's summary addition for `synced_frames(..., counters=...)`: how many frames'
    points the camera's turn moved ("" for none)."""
    count = counters.get("frames_deskewed", 0)
    return f"; the points of {count} deskewed by the camera's turn" if count else ""


def stamped_frames(path: str | Path, stereo, time_offset_ns: int = 0, window_ms: float = 100.0,
                   topics: TopicMap | None = None, counters: dict | None = None,
                   max_wait_ms: float | None = None):
    """`synced_frames` with the points' stamp in the camera's clock (None without points),
    never deskewed: yields (frame, left, right, points, points' stamp, GT or None)."""
    for frame, left, right, points, stamp, _, gt in _paired_frames(
            path, stereo, time_offset_ns, window_ms, topics, counters, max_wait_ms):
        yield frame, left, right, points, stamp, gt


def _paired_frames(path: str | Path, stereo, time_offset_ns: int, window_ms: float,
                   topics: TopicMap | None, counters: dict | None, max_wait_ms: float | None):
    """(frame, left, right, points, points' stamp, each point's time or None, GT or None)."""
    sync = LidarSync(SyncConfig("nearest", window_ms, time_offset_ns, max_wait_ms=max_wait_ms))
    wait_ns = sync.config.wait_ms * 1e6
    rectifier = stereo.rectifier()
    held: deque[list] = deque()  # [frame, GT or None], oldest first
    latest: int | None = None  # the newest frame's stamp: the stream's time

    def ready_frames(everything: bool = False):
        while held:
            stamp = held[0][0].stamp_ns
            ready = sync.ready(stamp)
            waited = latest is not None and latest - stamp > wait_ns
            if not (ready or waited or everything):
                return
            frame, gt = held.popleft()
            if not ready:
                sync.waited_out += 1
            left, right = rectifier.pair(frame)
            points = sync.points_for(stamp)
            yield (frame, left, right, points,
                   sync.last_points_stamp_ns if len(points) else None,
                   sync.last_points_times_ns if len(points) else None, gt)

    for event in McapSource(path, topics):
        if isinstance(event, GroundTruth):  # joins its frame; never moves the stream on
            for item in held:
                if item[0].stamp_ns == event.stamp_ns:
                    item[1] = event.disparity
            continue
        if isinstance(event, LidarScan):
            sync.add(event)
        elif isinstance(event, StereoFrame):
            latest = event.stamp_ns if latest is None else max(latest, event.stamp_ns)
        yield from ready_frames()
        if isinstance(event, StereoFrame):
            held.append([event, None])
    yield from ready_frames(everything=True)
    if counters is not None:
        counters.update(sync.counters())
