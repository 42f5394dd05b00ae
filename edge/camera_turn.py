"""The camera's turn about its vertical axis between consecutive frames, from the images alone:
what a LiDAR–camera clock offset turns into a rotation (`edge.calibration_watch`), and what
moves a LiDAR point between its own time and the frame's (`deskew`)."""

from __future__ import annotations

from collections import deque

import cv2
import numpy as np

from edge_depth.calibration.projection import transform_points

SCALE = 4  # the turn measured on images this many times smaller
MAX_GAP_S = 0.5  # ... of frames no further apart than this
# ... matching at least this well (phase correlation's peak: 0.83 and more between frames of
# one scene on the turning sim robot, at most 0.17 between two scenes)
MIN_RESPONSE = 0.5
# two frames match and are this close (px at 1/SCALE): the camera sees the same view (a robot
# standing still), and a sample of it says nothing the last one did not
SAME_VIEW_PX = 0.5
# the least a point must move by the camera's turn for a frame's points to be deskewed
DESKEW_MIN_PX = 0.25


class TurnMeter:
    """`frame(stamp, left)` on every frame; `rate()`: the turn between the last two, deg/s."""

    def __init__(self, focal_px: float) -> None:
        self.focal_px = focal_px
        self.frames: deque[tuple[int, np.ndarray]] = deque(maxlen=2)  # (stamp, grey, 1/SCALE)
        self._window: np.ndarray | None = None
        self._rate: tuple[tuple[int, int], float] | None = None  # (the pair's stamps, rate)

    def frame(self, stamp_ns: int, left: np.ndarray) -> None:
        h, w = left.shape
        small = cv2.resize(left, (max(8, w // SCALE), max(8, h // SCALE)),
                           interpolation=cv2.INTER_AREA).astype(np.float32)
        self.frames.append((int(stamp_ns), small))

    def view(self) -> np.ndarray | None:
        """The last frame, small (what `same_view` compares)."""
        return self.frames[-1][1] if self.frames else None

    def same_view(self, a: np.ndarray | None, b: np.ndarray | None) -> bool:
        """Whether two frames' small copies (`view`) show the same view: they match and
        neither shifted by SAME_VIEW_PX."""
        if a is None or b is None or a.shape != b.shape:
            return False
        (dx, dy), response = cv2.phaseCorrelate(a, b, self._hanning(a.shape))
        return response >= MIN_RESPONSE and float(np.hypot(dx, dy)) < SAME_VIEW_PX

    def _hanning(self, shape: tuple[int, ...]) -> np.ndarray:
        if self._window is None or self._window.shape != shape:
            self._window = cv2.createHanningWindow(shape[::-1], cv2.CV_32F)
        return self._window

    def rate(self) -> float:
        """The camera's turn about its vertical axis between the last two frames, deg/s, from
        the images' shift (phase correlation; computed once a pair); NaN when they are too far
        apart in time or do not match (a new scene, a blur)."""
        if len(self.frames) < 2:
            return float("nan")
        (t0, a), (t1, b) = self.frames
        if self._rate is None or self._rate[0] != (t0, t1):
            self._rate = ((t0, t1), self._measure(a, b, (t1 - t0) / 1e9))
        return self._rate[1]

    def _measure(self, a: np.ndarray, b: np.ndarray, dt: float) -> float:
        if not 0 < dt <= MAX_GAP_S or a.shape != b.shape:
            return float("nan")
        (dx, _), response = cv2.phaseCorrelate(a, b, self._hanning(a.shape))
        if response < MIN_RESPONSE:
            return float("nan")
        # a turn by θ moves a pixel at x (in focal lengths from the centre) by f·θ·(1 + x²):
        # the shift found is about the image's mean, (1 + (w / 2f)² / 3) times the centre's
        f = self.focal_px
        spread = 1.0 + (a.shape[1] * SCALE / (2 * f)) ** 2 / 3
        return float(np.degrees(dx * SCALE / f) / dt / spread)


def turned_points(points: np.ndarray, T_cam_lidar: np.ndarray, yaw_rad) -> np.ndarray:
    """LiDAR points (N, 3) as the camera sees them after it turned by `yaw_rad` (a scalar or
    one per point) about its vertical axis: X_cam -> R_y(yaw)^T X_cam; LiDAR frame in and
    out, float32."""
    cam = transform_points(T_cam_lidar, points)
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    turned = np.stack([c * cam[:, 0] - s * cam[:, 2], cam[:, 1], s * cam[:, 0] + c * cam[:, 2]],
                      1)
    return transform_points(np.linalg.inv(T_cam_lidar), turned).astype(np.float32)


def deskew(points: np.ndarray, times_ns: np.ndarray, frame_ns: int, turn_dps: float,
           T_cam_lidar: np.ndarray) -> np.ndarray:
    """LiDAR points moved to where the camera sees them at the frame's time: each turned by
    the camera's turn between the point's own time and the frame's (`TurnMeter.rate`, deg/s;
    a positive rate moves the image's content right). `times_ns`: (N,) or one stamp, in the
    camera's clock."""
    gap_s = (frame_ns - np.asarray(times_ns, np.int64)) / 1e9
    return turned_points(points, T_cam_lidar, -np.radians(turn_dps) * gap_s)


def deskew_shift_px(times_ns, frame_ns: int, turn_dps: float, focal_px: float) -> float:
    """The most the camera's turn moves one of the points (px at the image centre); 0 where
    the turn is not measured."""
    if not np.isfinite(turn_dps):
        return 0.0
    gap_s = np.max(np.abs(frame_ns - np.asarray(times_ns, np.int64))) / 1e9
    return float(np.radians(abs(turn_dps)) * gap_s * focal_px)


def deskewed(points: np.ndarray, times_ns, frame_ns: int, turn_dps: float, focal_px: float,
             T_cam_lidar: np.ndarray) -> tuple[np.ndarray, float]:
    """`deskew` where the turn moves a point by DESKEW_MIN_PX or more, else the points as
    they are; with the most the turn moved one (px; 0 where they are as they were)."""
    moved_px = deskew_shift_px(times_ns, frame_ns, turn_dps, focal_px)
    if moved_px < DESKEW_MIN_PX:
        return points, 0.0
    return deskew(points, times_ns, frame_ns, turn_dps, T_cam_lidar), moved_px
