"""The output's health: a depth map that is mostly invalid for frame after frame says that
something upstream is wrong (a calibration whose rectification looks outside the image, a
camera that sees black or white, LiDAR points projected where they cannot be), even when
every stage ran without an error.

The engine's disparity is dense: with a working camera and calibration every pixel has a
positive, finite value whatever the LiDAR covers, so the thresholds below are far from what
a real scene gives. Each frame is scored in `Pipeline.finish`; `/diagnostics` and the closing
summary of `run` and `replay` read the verdict.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

OK, WARN, ERROR = "OK", "WARN", "ERROR"
WARN_INVALID_PCT = 20.0  # a frame this invalid is unhealthy
ERROR_INVALID_PCT = 90.0  # ... and this invalid, unusable
RUN = 3  # consecutive frames before a level is raised (one odd frame is not a fault)
BLACK_PCT = 50.0  # rectified pixels exactly 0: the maps look outside the camera's image


@dataclass(frozen=True)
class FrameHealth:
    invalid_pct: float  # share of the depth map that is not a positive finite disparity
    black_pct: float  # share of the rectified left image that is exactly 0
    mean_grey: float
    lidar_points: int


def score_frame(disparity: np.ndarray, left: np.ndarray, sparse: np.ndarray) -> FrameHealth:
    """One frame's measures: disparity (H, W) pixels, left (H, W) rectified grey,
    sparse (H, W) projected LiDAR disparity (0 = no point). The images are read at every 4th
    pixel (a fraction of a millisecond)."""
    disparity, left = disparity[::4, ::4], left[::4, ::4]
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(disparity) & (disparity > 0)
    return FrameHealth(invalid_pct=100.0 * (1.0 - float(valid.mean())),
                       black_pct=100.0 * float((left == 0).mean()),
                       mean_grey=float(left.mean()), lidar_points=int((sparse > 0).sum()))


def likely_cause(frame: FrameHealth) -> str:
    """What most likely made this frame's depth invalid, in words a robot engineer acts on."""
    if frame.black_pct >= BLACK_PCT:
        return (f"the calibration: {frame.black_pct:.0f} % of the rectified image is black, so "
                "its undistortion maps look outside the camera's image (check the intrinsics "
                "and distortion: edge-depth calibrate)")
    if frame.mean_grey < 10 or frame.mean_grey > 245:
        return (f"the exposure: the rectified image's mean grey level is {frame.mean_grey:.0f} "
                "of 255 (a covered lens, or a camera blinded or left dark)")
    if frame.lidar_points:
        return ("the LiDAR's projection or the calibration: the images look sane and "
                f"{frame.lidar_points} LiDAR points projected (check [lidar] T_cam_lidar)")
    return "the model bundle or the calibration: the images look sane (check [engine] bundle)"


class OutputHealth:
    """A running verdict over the frames: OK, WARN after RUN frames in a row with more than
    WARN_INVALID_PCT % invalid depth, ERROR after RUN frames with more than
    ERROR_INVALID_PCT %. The worst level seen stays in `worst` for the closing summary."""

    def __init__(self) -> None:
        self.recent: deque[FrameHealth] = deque(maxlen=RUN)
        self.frames = self.unhealthy = 0
        self.level = self.worst = OK
        self.worst_frame: FrameHealth | None = None

    def add(self, frame: FrameHealth) -> None:
        self.recent.append(frame)
        self.frames += 1
        self.unhealthy += frame.invalid_pct > WARN_INVALID_PCT
        least = min(f.invalid_pct for f in self.recent) if len(self.recent) == RUN else 0.0
        self.level = ERROR if least > ERROR_INVALID_PCT else WARN \
            if least > WARN_INVALID_PCT else OK
        if _rank(self.level) > _rank(self.worst):
            self.worst, self.worst_frame = self.level, frame

    def message(self, level: str | None = None) -> str:
        """'OK' or the verdict with its share and likely cause."""
        level = level or self.level
        frame = self.worst_frame if level == self.worst else self.recent[-1]
        if level == OK or frame is None:
            return f"{OK}: depth valid on {self.frames - self.unhealthy} of {self.frames} frames"
        return (f"{level}: {frame.invalid_pct:.0f} % of the depth map invalid ({self.unhealthy} "
                f"of {self.frames} frames over {WARN_INVALID_PCT:g} %); likely cause: "
                f"{likely_cause(frame)}")

    def diagnostics(self) -> dict:
        """For /diagnostics: the current level, the last frame's invalid share, the verdict."""
        last = self.recent[-1].invalid_pct if self.recent else 0.0
        return dict(level=self.level, invalid_pct=round(last, 2),
                    message=self.message(self.level))

    def summary(self) -> str | None:
        """The closing line when any level above OK was reached, else None."""
        if self.worst == OK:
            return None
        return f"output health {self.message(self.worst)}"


def _rank(level: str) -> int:
    return (OK, WARN, ERROR).index(level)
