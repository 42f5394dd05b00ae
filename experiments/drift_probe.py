"""A study, not shipped: can the daemon estimate the LiDAR–camera rotation error online from the
frames it already has? (docs/experiments.md, 2026-12-05 22:25.)

    python experiments/drift_probe.py [--frames 100] [--every 5] [--points 2000] [--blur 1]

runs the estimator below on sim rig frames (16-beam LiDAR) with the right calibration and with
±0.3° of yaw and of pitch injected, and prints each estimate, its level over time and its cost.

Every `every`-th frame with LiDAR points is a sample: the photometric cost of
`calibration.extrinsics.PhotometricCost` (the truncated |left − right| grey difference at the
two projections of each point both cameras see; at the right extrinsics each point lands on
the same surface in both images, off by a fraction of a degree the points near depth edges
land on different surfaces) is evaluated at a centre and at small rotations of it about the
left camera's three axes, OFFSETS_DEG each side. Over the samples at that centre the costs
are summed per rotation, and per axis a parabola through the sums puts the minimum: the
rotation that makes the points land best, whose negative is the calibration's error. The
centre starts at the calibration and moves to the estimate whenever the estimate leaves the
probes' inner pair (RECENTRE_DEG), the samples starting again there: a parabola is a good
model of the cost only near its minimum (probed ±0.6° about a calibration 0.3° off, the
per-axis minima were 0.1° off and the axes leaked into each other; near the minimum they
agree with a joint search of the three rotations, `refine_extrinsics` without translation).
The uncertainty is the spread of the minimum over BATCHES interleaved batches of the samples
(the standard error of their mean).

A rotation moves every projected point by about f · angle pixels whatever its depth (a
rotation about the optical axis: the point's distance from the image centre · angle), so the
verdict is in pixels: WARN when the error, less twice its uncertainty, moves the points by
more than WARN_PX, ERROR beyond ERROR_PX. The translation and the clock offset are not
estimated here. Nothing here changes the calibration: `edge-depth calibrate lidar --refine`
writes a new file when the user decides to.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from edge_depth.calibration.errors import CalibrationError
from edge_depth.calibration.extrinsics import PhotometricCost, _perturb, _subpixel
from edge_depth.calibration.model import StereoCalibration

AXES = ("pitch", "yaw", "roll")  # about the left camera's x (right), y (down), z (forward)
OFFSETS_DEG = (-0.3, -0.15, 0.0, 0.15, 0.3)
REACH_DEG = 0.45  # a parabola's minimum is taken at most this far from the centre
RECENTRE_DEG = 0.15  # ... and beyond this, the centre moves to it
MAX_CENTRE_DEG = 3.0  # a centre this far off: the estimate says "at least" this
BLUR_PX = 1.0  # the images' blur: a smoother cost over the probes' spacing
MAX_POINTS = 2000  # per sample, a fixed budget: evenly thinned beyond it
BATCHES = 3
MIN_SAMPLES = 6  # samples at a centre before its estimate counts
WARN_PX, ERROR_PX = 0.1, 1.0
# what the estimate resolves: with the right calibration the cost's flat bottom reads up to
# 0.09° of pitch on the sim robot, so WARN (0.1 px: 0.013° at f = 450 px) is called only for
# an error this much beyond it and its two standard errors; ERROR (1 px) is above it
RESOLUTION_DEG = 0.1
OK, WARN, ERROR, SETTLING = "OK", "WARN", "ERROR", "SETTLING"


@dataclass(frozen=True)
class DriftEstimate:
    """The calibration's rotation error (degrees, per axis of AXES), its standard error, the
    pixels it moves the points by (after subtracting twice the standard error), the level and
    the samples it stands on."""

    error_deg: tuple[float, float, float]
    sigma_deg: tuple[float, float, float]
    shift_px: float
    level: str
    samples: int
    beyond_reach: bool = False

    def describe(self) -> str:
        """'yaw +0.31° ± 0.02°, pitch −0.01° ± 0.02°, roll +0.05° ± 0.06° (2.4 px): ERROR'."""
        if self.level == SETTLING:
            return f"settling ({self.samples} of {MIN_SAMPLES} samples at this centre)"
        parts = [f"{name} {self.error_deg[AXES.index(name)]:+.2f}° ± "
                 f"{self.sigma_deg[AXES.index(name)]:.2f}°" for name in ("yaw", "pitch", "roll")]
        reach = f", at least {MAX_CENTRE_DEG}° on one axis" if self.beyond_reach else ""
        return f"{', '.join(parts)} ({self.shift_px:.2f} px{reach}): {self.level}"


class DriftWatch:
    """Feed it frames (`add`: rectified left, right, LiDAR points in the LiDAR frame); read
    `estimate()`. `every`: one sample per this many frames offered; `window`: the samples
    kept."""

    def __init__(self, calib: StereoCalibration, T_cam_lidar: np.ndarray, every: int = 5,
                 window: int = 60) -> None:
        if every < 1 or window < MIN_SAMPLES:
            raise ValueError(f"every >= 1 and window >= {MIN_SAMPLES}, got {every}, {window}")
        self.calib, self.T = calib, np.asarray(T_cam_lidar, np.float64)
        self.every = every
        self.offered = 0
        self.samples: deque[np.ndarray] = deque(maxlen=window)  # each (3, len(OFFSETS_DEG))
        self.radius_px: deque[float] = deque(maxlen=window)
        self.recentred = 0
        self.last: DriftEstimate | None = None  # the estimate before the centre last moved
        self._centre(np.zeros(3))

    def _centre(self, rotation_deg: np.ndarray) -> None:
        """Probe about the calibration rotated by `rotation_deg` (pitch, yaw, roll) from now."""
        self.centre = np.asarray(rotation_deg, np.float64)
        self.samples.clear()
        self.probes = [[_perturb(self.T, np.r_[self.centre + _axis_vector(axis, offset),
                                               0.0, 0.0, 0.0]) for offset in OFFSETS_DEG]
                       for axis in range(3)]

    def due(self) -> bool:
        """Whether the next frame offered becomes a sample (`add` counts the offer)."""
        return self.offered % self.every == 0

    def add(self, left: np.ndarray, right: np.ndarray, points: np.ndarray) -> bool:
        """Offer a frame; True when it became a sample (one in `every`, with points both
        cameras see)."""
        take = self.due()
        self.offered += 1
        if not take or len(points) == 0:
            return False
        cost = thinned_cost(self.calib, self.T, left, right, points, MAX_POINTS, BLUR_PX)
        if cost is None:
            return False
        try:
            costs = np.array([[cost(T) for T in axis] for axis in self.probes])
        except CalibrationError:  # no point lands in both images at some probe
            return False
        self.samples.append(costs)
        self.radius_px.append(median_radius(cost, self.calib, self.T))
        if len(self.samples) >= MIN_SAMPLES:
            minimum, sigma = self._fit(list(self.samples))
            # an axis moves when its minimum is both beyond the probes' inner pair and
            # significant (twice its standard error): noise does not walk the centre
            move = (np.abs(minimum) > RECENTRE_DEG) & (np.abs(minimum) > 2 * sigma)
            if move.any() and np.abs(self.centre + minimum).max() < MAX_CENTRE_DEG:
                self.last = self.estimate()
                self.recentred += 1
                self._centre(self.centre + np.where(move, minimum, 0.0))
        return True

    @staticmethod
    def _fit(samples: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Per axis, where the summed costs' parabola is lowest (degrees from the centre), and
        that minimum's standard error over BATCHES interleaved batches."""
        def minimum(part: list[np.ndarray]) -> np.ndarray:
            total = np.sum(np.stack(part), axis=0)
            return np.array([_minimum(total[axis]) for axis in range(3)])

        batches = np.array([minimum(samples[b::BATCHES]) for b in range(BATCHES)])
        return minimum(samples), np.std(batches, axis=0, ddof=1) / np.sqrt(BATCHES)

    def estimate(self) -> DriftEstimate:
        """The current estimate: from the samples at the current centre once there are
        MIN_SAMPLES, until then the one before the centre moved (or "settling")."""
        n = len(self.samples)
        if n < MIN_SAMPLES:
            return self.last or DriftEstimate((0.0,) * 3, (0.0,) * 3, 0.0, SETTLING, n)
        minimum, sigma = self._fit(list(self.samples))
        error = -(self.centre + minimum)
        beyond = bool(np.abs(self.centre).max() >= MAX_CENTRE_DEG - RECENTRE_DEG)
        lever = np.array([self.calib.focal_px, self.calib.focal_px,
                          float(np.median(self.radius_px))])
        shift, level = verdict(error, sigma, lever, RESOLUTION_DEG)
        e, s = [float(v) for v in error], [float(v) for v in sigma]
        return DriftEstimate((e[0], e[1], e[2]), (s[0], s[1], s[2]), shift, level, n, beyond)


def thinned_cost(calib: StereoCalibration, T: np.ndarray, left: np.ndarray, right: np.ndarray,
                 points: np.ndarray, max_points: int, blur_px: float) -> PhotometricCost | None:
    """A frame's photometric cost on at most `max_points` of its points, evenly thinned; None
    when no point lands in both images."""
    points = np.asarray(points, np.float64)
    if len(points) > max_points:
        points = points[np.linspace(0, len(points) - 1, max_points).astype(int)]
    cost = PhotometricCost([(left, right, points)], calib, T, blur_px)
    return cost if cost.points else None


def median_radius(cost: PhotometricCost, calib: StereoCalibration, T: np.ndarray) -> float:
    """The seen points' median distance from the principal point, px (roll's lever)."""
    seen = np.vstack([p for p, _, _ in cost.items])
    u, v, _, _ = _subpixel(seen, calib, T, 1e-3)
    cx, cy = calib.principal_point
    return float(np.median(np.hypot(u - cx, v - cy))) if len(u) else 0.0


def verdict(error: np.ndarray, sigma: np.ndarray, lever: np.ndarray,
            resolution_deg) -> tuple[float, str]:
    """(px the points move by beyond twice the standard error, the level): ERROR beyond
    ERROR_PX, WARN beyond WARN_PX once `resolution_deg` more is allowed, else OK. `lever`:
    px per radian per axis (f, f, the points' distance from the image centre)."""
    def shift_px(margin_deg) -> float:
        beyond = np.radians(np.maximum(np.abs(error) - margin_deg, 0.0))
        return float(np.hypot.reduce(beyond * lever))

    shift = shift_px(2 * sigma)
    level = ERROR if shift > ERROR_PX else WARN \
        if shift_px(2 * sigma + resolution_deg) > WARN_PX else OK
    return shift, level


# the calibration errors the studies inject: (name, rotation about x, y, z in degrees)
CASES = (("right calibration", (0, 0, 0)), ("yaw +0.3", (0, 0.3, 0)), ("yaw -0.3", (0, -0.3, 0)),
         ("pitch +0.3", (0.3, 0, 0)), ("pitch -0.3", (-0.3, 0, 0)))


def run_cases(make_watch, frames, every: int):
    """Each case's watch fed every frame: yields (name, watch, ms a frame, worst ms of one
    frame, the level's first letter every `every` frames)."""
    import time

    from edge_depth.sim.lidar import default_T_cam_lidar

    calib, T = frames[0].calibration(), default_T_cam_lidar()
    for name, x in CASES:
        watch = make_watch(calib, _perturb(T, np.r_[x, 0.0, 0.0, 0.0]))
        started, levels, worst = time.perf_counter(), [], 0.0
        for s in frames:
            t = time.perf_counter()
            watch.add(s.left, s.right, s.scan.points)
            worst = max(worst, time.perf_counter() - t)
            levels.append(watch.estimate().level[0])
        ms = (time.perf_counter() - started) / len(frames) * 1000
        yield name, watch, ms, worst * 1000, "".join(levels[every - 1::every])


def _axis_vector(axis: int, degrees: float) -> np.ndarray:
    x = np.zeros(3)
    x[axis] = degrees
    return x


def _minimum(costs: np.ndarray) -> float:
    """Where a parabola through (OFFSETS_DEG, costs) is lowest, within ±REACH_DEG; the lowest
    probe where the costs do not curve upwards."""
    a, b, _ = np.polyfit(OFFSETS_DEG, costs, 2)
    if a <= 0:
        return float(OFFSETS_DEG[int(np.argmin(costs))])
    return float(np.clip(-b / (2 * a), -REACH_DEG, REACH_DEG))


def main() -> None:
    import argparse

    from edge_depth.sim import RigConfig, make_sample

    global MAX_POINTS, BLUR_PX
    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--every", type=int, default=5)
    p.add_argument("--points", type=int, default=MAX_POINTS)
    p.add_argument("--blur", type=float, default=BLUR_PX)
    args = p.parse_args()
    MAX_POINTS, BLUR_PX = args.points, args.blur
    frames = [make_sample(1_000_000 + i, RigConfig(), "beams16") for i in range(args.frames)]
    for name, watch, ms, _, levels in run_cases(
            lambda calib, T: DriftWatch(calib, T, every=args.every), frames, args.every):
        print(f"{name}: {watch.estimate().describe()}; centre moved {watch.recentred}x; "
              f"{ms:.2f} ms/frame; levels {levels}")


if __name__ == "__main__":
    main()
