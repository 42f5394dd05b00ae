"""The calibration watched: the LiDAR–camera rotation error, estimated from the frames the
daemon already processes, with its uncertainty and a level.

Every `every`-th frame with LiDAR points is a sample. Its reference is the engine's network
run without the LiDAR (`Engine.stereo_only`, two steps): a disparity that never saw the points,
so it cannot follow them where they are misplaced (the engine's own output does; a block
matcher's fattened edges moved the estimate by 0.1–0.6°, docs/experiments.md). The points are
those the left camera sees by the occlusion filter grown by GROW_PX (the exact filter keeps
LiDAR points the camera cannot see behind edges, and they pull pitch by ~0.1°). For each probe
rotation of the calibration — a (pitch, yaw) grid and a roll line, about the rectified left
camera's x (right), y (down) and z (forward) axes — each point's disparity is compared with
the reference's at the pixel it then lands on: the mean of min(|d − D|, TRUNCATE_PX), HOLE_PX
where it lands outside the image. Off by a rotation, the points near depth edges land on the
other surface. The costs are summed over the samples; the lowest probe, refined by a parabola
per axis, is the rotation that makes the points land best, and its negative the calibration's
error. The estimate stands on the last WINDOW samples; its uncertainty is the jackknife's
(the spread of the estimate without each sample in turn).

A rotation moves every projected point by about f · angle pixels whatever its depth (about the
optical axis: the points' distance from the image centre · angle), so the level is in pixels:
ERROR when the error, less twice its uncertainty, moves the points by more than ERROR_PX, WARN
beyond WARN_PX once RESOLUTION_DEG more is allowed (what the estimate reads with the right
calibration on the sim robot's scenes). The uncertainty assumes the samples see different
scenes: a robot that stands still for the window's length samples one scene, and that
scene's own bias (up to the resolution) is then read as certain. Nothing here changes the
calibration: `edge-depth calibrate lidar --refine` writes a new file when the user decides
to.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np

from edge_depth.calibration.model import StereoCalibration
from edge_depth.calibration.projection import (
    OcclusionFilterConfig,
    rectified_lidar,
    transform_points,
    visible_points,
)

AXES = ("pitch", "yaw", "roll")
GRID_STEP_DEG, GRID_REACH_DEG = 0.15, 0.6  # the (pitch, yaw) grid: 9 x 9 probes
ROLL_STEP_DEG, ROLL_REACH_DEG = 0.2, 1.2  # the roll line: 13 probes
TRUNCATE_PX, HOLE_PX = 3.0, 1.5
GROW_PX = 6
MAX_POINTS = 3000  # per sample, evenly thinned beyond it: a fixed budget
MIN_DEPTH_M = 0.2
WINDOW = 60  # the samples the estimate stands on: older ones are forgotten (a drift shows)
MIN_SAMPLES = 8
EVERY = 12  # one sample in this many frames with LiDAR (the daemon's default: < 3 % of it)
REFERENCE_ITERS = 2
WARN_PX, ERROR_PX = 0.1, 1.0
# what the estimate reads with the right calibration on the sim robot's scenes, per axis
# (pitch, yaw, roll): yaw and pitch up to 0.07°, roll up to 0.32° (its lever, the points'
# distance from the image centre, is short and the rig's edges seldom constrain it)
RESOLUTION_DEG = np.array([0.1, 0.1, 0.35])
OK, WARN, ERROR, SETTLING = "OK", "WARN", "ERROR", "SETTLING"
LEVELS = (OK, WARN, ERROR)


@dataclass(frozen=True)
class WatchEstimate:
    """The calibration's rotation error (degrees: pitch, yaw, roll), its standard error, the
    pixels it moves the points by beyond twice that, the level and the samples it stands on.
    `at_reach`: an axis at the probes' edge (the error is at least that)."""

    error_deg: tuple[float, float, float]
    sigma_deg: tuple[float, float, float]
    shift_px: float
    level: str
    samples: int
    at_reach: bool = False

    def describe(self) -> str:
        """'yaw +0.31° ± 0.02°, pitch −0.01° ± 0.02°, roll +0.05° ± 0.06° (2.4 px): ERROR'."""
        if self.level == SETTLING:
            return f"settling ({self.samples} of {MIN_SAMPLES} samples)"
        parts = [f"{name} {self.error_deg[AXES.index(name)]:+.2f}° ± "
                 f"{self.sigma_deg[AXES.index(name)]:.2f}°" for name in ("yaw", "pitch", "roll")]
        reach = ", at least that: beyond the probes" if self.at_reach else ""
        return f"{', '.join(parts)} ({self.shift_px:.2f} px{reach}): {self.level}"

    def as_dict(self) -> dict:
        return dict(level=self.level, samples=self.samples, shift_px=round(self.shift_px, 3),
                    at_reach=self.at_reach,
                    **{f"{axis}_deg": round(self.error_deg[i], 3) for i, axis in enumerate(AXES)},
                    **{f"{axis}_sigma_deg": round(self.sigma_deg[i], 3)
                       for i, axis in enumerate(AXES)})


def stereo_reference(engine) -> np.ndarray:
    """The reference for the frame the engine has just inferred: its network without the LiDAR
    (`Engine.stereo_only`, REFERENCE_ITERS steps on the frame's own encoding), (H, W) float32
    px at the camera's size."""
    return engine.stereo_only(REFERENCE_ITERS)


def _axis(step: float, reach: float) -> np.ndarray:
    n = int(round(reach / step))
    return np.arange(-n, n + 1) * step


def _rotations(angles_deg: np.ndarray) -> np.ndarray:
    """(P, 3) rotation vectors in degrees -> (P, 3, 3)."""
    return np.stack([cv2.Rodrigues(np.radians(a))[0] for a in angles_deg])


def parabola_minimum(xs: np.ndarray, costs: np.ndarray) -> tuple[float, bool]:
    """Where the costs are lowest, refined by a parabola through the lowest probe and its
    neighbours; and whether that is the probes' edge."""
    i = int(np.argmin(costs))
    if 0 < i < len(xs) - 1:
        a, b, c = costs[i - 1], costs[i], costs[i + 1]
        curve = a - 2 * b + c
        if curve > 0:
            return float(xs[i] + 0.5 * (a - c) / curve * (xs[1] - xs[0])), False
        return float(xs[i]), False
    return float(xs[i]), True


class CalibrationWatch:
    """`due()` before a frame with LiDAR points; when True, `add(reference, points)` with the
    engine's stereo-only disparity and the frame's points (LiDAR frame, metres); read
    `estimate()` at any time."""

    def __init__(self, calib: StereoCalibration, T_cam_lidar: np.ndarray,
                 every: int = EVERY) -> None:
        if every < 1:
            raise ValueError(f"every: >= 1, got {every}")
        self.calib, self.T = calib, np.asarray(T_cam_lidar, np.float64)
        self.every = every
        self.offered = 0
        base = OcclusionFilterConfig()
        self._filter = OcclusionFilterConfig(
            window=(base.window[0] + 2 * GROW_PX, base.window[1] + 2 * GROW_PX),
            slack_px=base.slack_px + GROW_PX, relative=0.08, margin_px=1.0)
        self.grid_axis = _axis(GRID_STEP_DEG, GRID_REACH_DEG)
        pitch, yaw = np.meshgrid(self.grid_axis, self.grid_axis, indexing="ij")
        self._grid = np.stack([pitch.ravel(), yaw.ravel(), np.zeros(pitch.size)], 1)
        self.roll_axis = _axis(ROLL_STEP_DEG, ROLL_REACH_DEG)
        # each sample's probe costs: (pitch, yaw) grid, roll line, the points' median
        # distance from the image centre (px)
        self._samples: deque[tuple[np.ndarray, np.ndarray, float]] = deque(maxlen=WINDOW)
        self.samples = 0  # all samples taken, the forgotten ones too
        self._lock = threading.Lock()  # `add` on the engine's thread, `estimate` on others

    def due(self) -> bool:
        """Whether this frame (one with LiDAR points) becomes a sample: one in `every`."""
        take = self.offered % self.every == 0
        self.offered += 1
        return take

    def add(self, reference: np.ndarray, points: np.ndarray) -> bool:
        """A sample: the stereo-only disparity (H, W) and the frame's LiDAR points (N, 3). False
        (nothing counted) when no point the camera sees lands in the image."""
        cam = self._seen_points(np.asarray(points, np.float64))
        if len(cam) == 0:
            return False
        moves = self._jacobian(cam)
        grid = self._costs(moves, reference, self._grid).reshape(len(self.grid_axis), -1)
        with self._lock:
            total = sum((g for g, _, _ in self._samples), grid)
        pitch, yaw = self._grid_minimum(total)[0]
        roll = np.stack([np.full(len(self.roll_axis), pitch), np.full(len(self.roll_axis), yaw),
                         self.roll_axis], 1)
        roll_costs = self._costs(moves, reference, roll)
        f = self.calib.focal_px
        radius = float(np.median(np.hypot(f * cam[:, 0] / cam[:, 2],
                                          f * cam[:, 1] / cam[:, 2])))
        with self._lock:
            self._samples.append((grid, roll_costs, radius))
            self.samples += 1
        return True

    def _seen_points(self, points: np.ndarray) -> np.ndarray:
        """The points the left camera sees (grown filter), in the rectified left camera, at most
        MAX_POINTS."""
        if len(points) == 0:
            return np.zeros((0, 3))
        if len(points) > 2 * MAX_POINTS:  # the filter's cost: a point in two is enough
            points = points[::len(points) // (2 * MAX_POINTS)]
        seen = visible_points(points, self.calib, self.T, "left", self._filter)
        cam = transform_points(rectified_lidar(self.calib, self.T), points[seen])
        cam = cam[cam[:, 2] > MIN_DEPTH_M]
        if len(cam) > MAX_POINTS:
            cam = cam[np.linspace(0, len(cam) - 1, MAX_POINTS).astype(int)]
        return cam

    @staticmethod
    def _costs(moves: tuple[np.ndarray, np.ndarray], reference: np.ndarray,
               probes_deg: np.ndarray) -> np.ndarray:
        """Each probe rotation's (P, 3 degrees) mean truncated |d − D| over the points. A
        probe moves each point's (u, v, d) by its first-order change (`_jacobian`): within
        the probes' reach (0.6°, roll 1.2°) the second-order terms stay below 0.1 px."""
        base, jacobian = moves
        probes = np.asarray(probes_deg, np.float32)
        u, v, d = (base[c] + probes @ jacobian[c] for c in range(3))  # (P, N) each
        h, w = reference.shape
        inside = (u > -0.5) & (u < w - 0.5) & (v > -0.5) & (v < h - 0.5)
        col = np.clip(u + 0.5, 0, w - 1).astype(np.int32)  # the nearest pixel
        row = np.clip(v + 0.5, 0, h - 1).astype(np.int32)
        gap = np.abs(d - reference.ravel()[row * w + col])
        np.minimum(gap, TRUNCATE_PX, out=gap)
        gap[~(inside & np.isfinite(gap))] = HOLE_PX
        return gap.mean(axis=1)

    def _jacobian(self, cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The points' (u, v, d) at the calibration, (3, N), and their change per degree of
        pitch, yaw and roll, (3 values, 3 axes, N)."""
        f, (cx, cy) = self.calib.focal_px, self.calib.principal_point
        fb = f * self.calib.baseline_m

        def project(points: np.ndarray) -> np.ndarray:
            z = np.maximum(points[:, 2], 1e-3)
            return np.stack([f * points[:, 0] / z + cx, f * points[:, 1] / z + cy, fb / z])

        base = project(cam)
        step = 0.1  # degrees
        columns = [(project(cam @ _rotations(np.eye(3)[k:k + 1] * step)[0].T) - base) / step
                   for k in range(3)]
        return base.astype(np.float32), np.stack(columns, axis=1).astype(np.float32)

    def _grid_minimum(self, costs: np.ndarray) -> tuple[tuple[float, float], bool]:
        i, j = np.unravel_index(int(np.argmin(costs)), costs.shape)
        pitch, edge_p = parabola_minimum(self.grid_axis, costs[:, j])
        yaw, edge_y = parabola_minimum(self.grid_axis, costs[i, :])
        return (pitch, yaw), edge_p or edge_y

    def _minimum(self, grid: np.ndarray, roll: np.ndarray) -> tuple[np.ndarray, bool]:
        (pitch, yaw), edge = self._grid_minimum(grid)
        r, edge_r = parabola_minimum(self.roll_axis, roll)
        return np.array([pitch, yaw, r]), edge or edge_r

    def estimate(self) -> WatchEstimate:
        """The current estimate ("settling" before MIN_SAMPLES samples)."""
        with self._lock:
            window = list(self._samples)
        n = len(window)
        if n < MIN_SAMPLES:
            return WatchEstimate((0.0,) * 3, (0.0,) * 3, 0.0, SETTLING, n)
        grid = np.stack([g for g, _, _ in window])
        roll = np.stack([r for _, r, _ in window])
        best, at_reach = self._minimum(grid.sum(axis=0), roll.sum(axis=0))
        # the jackknife: the estimate without each sample in turn
        grid_total, roll_total = grid.sum(axis=0), roll.sum(axis=0)
        leave_one = np.array([self._minimum(grid_total - g, roll_total - r)[0]
                              for g, r in zip(grid, roll, strict=True)])
        sigma = np.sqrt((n - 1) / n * ((leave_one - leave_one.mean(axis=0)) ** 2).sum(axis=0))
        radius = float(np.mean([r for _, _, r in window]))
        samples = n
        error = -best
        lever = np.array([self.calib.focal_px, self.calib.focal_px, radius])
        shift, level = verdict(error, sigma, lever)
        e, s = [float(x) for x in error], [float(x) for x in sigma]
        return WatchEstimate((e[0], e[1], e[2]), (s[0], s[1], s[2]), shift, level, samples,
                             at_reach)


def verdict(error_deg: np.ndarray, sigma_deg: np.ndarray, lever_px: np.ndarray
            ) -> tuple[float, str]:
    """(px the points move by beyond twice the standard error, the level): ERROR beyond
    ERROR_PX, WARN beyond WARN_PX once RESOLUTION_DEG more is allowed, else OK. `lever_px`:
    px per radian per axis (f, f, the points' distance from the image centre)."""
    def shift_px(margin_deg) -> float:
        beyond = np.radians(np.maximum(np.abs(error_deg) - margin_deg, 0.0))
        return float(np.hypot.reduce(beyond * lever_px))

    shift = shift_px(2 * sigma_deg)
    if shift > ERROR_PX:
        return shift, ERROR
    return shift, WARN if shift_px(2 * sigma_deg + RESOLUTION_DEG) > WARN_PX else OK


def refine_command(recording: str | None, calibration: str | None) -> str:
    """The command that fixes it, pre-filled where the paths are known (without a calibration
    file, the recording's own is refined)."""
    command = f"edge-depth calibrate lidar --recording {recording or 'REC.mcap'} --refine"
    if calibration:
        stem = calibration[:-5] if calibration.endswith(".toml") else calibration
        return f"{command} --calib {calibration} --out {stem}_refined.toml"
    return f"{command} --out refined.toml"
