"""A study, not shipped: the second online estimator of the LiDAR–camera rotation error
(docs/experiments.md, 2026-12-05 22:25). It runs on sim rig frames:

    python experiments/drift_search.py [--frames 100] [--seed 1000000]

with the right calibration and with ±0.3° of yaw and of pitch injected, printing each
estimate, its level every 10 frames and its cost a frame.

One frame in `every` with LiDAR points becomes a sample: its `PhotometricCost` (the truncated
|left − right| grey difference at the two projections of each point both cameras see; at the
right extrinsics each point lands on the same surface in both images, off by a fraction of a
degree the points near depth edges land on different surfaces), on at most MAX_POINTS points.
The last `window` samples are kept; every `search_every` new samples the rotation (pitch, yaw,
roll about the left camera's axes) that makes the points land best is searched for on each of
PARTS interleaved parts of them (Nelder–Mead from the part's last optimum, with a weak pull
towards the calibration, PRIOR, so that a flat direction, roll above all, does not wander
from search to search). The estimate is the negative of the optima's mean, its standard error
their spread over √PARTS.

A rotation moves every projected point by about f · angle pixels whatever its depth (about the
optical axis: the points' distance from the image centre · angle), so the verdict is in
pixels: ERROR when the error less twice its standard error moves the points more than
ERROR_PX, WARN when it does so by more than WARN_PX beyond RESOLUTION_DEG, what the estimate
resolves on the sim robot with the right calibration (a WARN of 0.1 px, 0.013° at f = 450 px,
is finer than that). The translation and the clock offset
are not estimated. Nothing here changes the calibration: `edge-depth calibrate lidar
--refine` writes a new file when the user decides to (docs/calibration.md).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from edge_depth.calibration.errors import CalibrationError
from edge_depth.calibration.extrinsics import PhotometricCost, _perturb
from edge_depth.calibration.model import StereoCalibration

# the levels, the verdict and the cases are the first study's (run from experiments/)
from drift_probe import (  # noqa: E402  # isort: skip
    SETTLING, median_radius, run_cases, thinned_cost, verdict)

AXES = ("pitch", "yaw", "roll")  # about the left camera's x (right), y (down), z (forward)
BLUR_PX = 1.0  # the images' blur: a smoother cost for the search
MAX_POINTS = 2000  # per sample, a fixed budget: evenly thinned beyond it
MIN_SAMPLES = 6  # before this many samples the verdict is "settling"
SIMPLEX_DEG = 0.3  # the search's first steps
MAX_EVALS = 60  # per part and search
PARTS = 2
PRIOR = 0.02  # cost per degree² of rotation from the calibration
# what the estimate resolves per axis (pitch, yaw, roll): with the right calibration on the sim
# robot it read up to 0.04° of pitch and yaw and wandered up to 0.37° in roll (whose lever,
# the points' distance from the image centre, is a third of the focal length's)
RESOLUTION_DEG = np.array([0.05, 0.05, 0.3])


@dataclass(frozen=True)
class DriftEstimate:
    """The calibration's rotation error (degrees, per axis of AXES), its standard error, the
    pixels it moves the points by beyond twice that, the level, and the samples behind it."""

    error_deg: tuple[float, float, float]
    sigma_deg: tuple[float, float, float]
    shift_px: float
    level: str
    samples: int

    def describe(self) -> str:
        """'yaw +0.31° ± 0.02°, pitch −0.01° ± 0.02°, roll +0.05° ± 0.06° (2.4 px): ERROR'."""
        if self.level == SETTLING:
            return f"settling ({self.samples} of {MIN_SAMPLES} samples)"
        parts = [f"{name} {self.error_deg[AXES.index(name)]:+.2f}° ± "
                 f"{self.sigma_deg[AXES.index(name)]:.2f}°" for name in ("yaw", "pitch", "roll")]
        return f"{', '.join(parts)} ({self.shift_px:.2f} px): {self.level}"


class DriftWatch:
    """Offer it frames (`add`: rectified left, right and the LiDAR points in the LiDAR's
    frame, metres); read `estimate`. Memory: the window's blurred pairs, 2 MB a sample at
    640×400."""

    def __init__(self, calib: StereoCalibration, T_cam_lidar: np.ndarray, every: int = 10,
                 window: int = 12, search_every: int = 3) -> None:
        if every < 1 or window < MIN_SAMPLES or search_every < 1:
            raise ValueError(f"every >= 1, window >= {MIN_SAMPLES} and search_every >= 1, got "
                             f"{every}, {window}, {search_every}")
        self.calib, self.T = calib, np.asarray(T_cam_lidar, np.float64)
        self.every, self.search_every = every, search_every
        self.offered = 0
        self.samples: deque[PhotometricCost] = deque(maxlen=window)
        self.radius_px: deque[float] = deque(maxlen=window)
        self.since_search = 0
        self.current = DriftEstimate((0.0,) * 3, (0.0,) * 3, 0.0, SETTLING, 0)
        self.optima = [np.zeros(3) for _ in range(PARTS)]  # the searches' warm starts

    def due(self) -> bool:
        """Whether the next frame offered is one to sample (`add` counts the offer)."""
        return self.offered % self.every == 0

    def add(self, left: np.ndarray, right: np.ndarray, points: np.ndarray) -> bool:
        """Offer a frame; True when it became a sample. Searches when one is due."""
        take = self.due()
        self.offered += 1
        if not take or len(points) == 0:
            return False
        cost = thinned_cost(self.calib, self.T, left, right, points, MAX_POINTS, BLUR_PX)
        if cost is None:
            return False
        self.samples.append(cost)
        self.radius_px.append(median_radius(cost, self.calib, self.T))
        self.since_search += 1
        if len(self.samples) < MIN_SAMPLES:
            self.current = DriftEstimate((0.0,) * 3, (0.0,) * 3, 0.0, SETTLING,
                                         len(self.samples))
        elif self.since_search >= self.search_every or self.current.level == SETTLING:
            self.current = self._search()
            self.since_search = 0
        return True

    def estimate(self) -> DriftEstimate:
        return self.current

    def _search(self) -> DriftEstimate:
        from scipy.optimize import minimize

        samples = list(self.samples)
        optima = []
        for k in range(PARTS):
            part = samples[k::PARTS]

            def cost(x: np.ndarray, part=part) -> float:
                T = _perturb(self.T, np.r_[x, 0.0, 0.0, 0.0])
                try:
                    return float(np.mean([c(T) for c in part])) + PRIOR * float(x @ x)
                except CalibrationError:  # no point lands in both images
                    return float("inf")

            start = self.optima[k]
            simplex = np.vstack([start, start + np.eye(3) * SIMPLEX_DEG])
            result = minimize(cost, start, method="Nelder-Mead",
                              options=dict(initial_simplex=simplex, xatol=0.01, fatol=1e-6,
                                           maxfev=MAX_EVALS))
            self.optima[k] = np.asarray(result.x, np.float64)
            optima.append(self.optima[k])
        error = -np.mean(optima, axis=0)
        sigma = np.std(optima, axis=0, ddof=1) / np.sqrt(PARTS)
        lever = np.array([self.calib.focal_px, self.calib.focal_px,
                          float(np.median(self.radius_px))])
        shift, level = verdict(error, sigma, lever, RESOLUTION_DEG)
        e, s = [float(v) for v in error], [float(v) for v in sigma]
        return DriftEstimate((e[0], e[1], e[2]), (s[0], s[1], s[2]), shift, level,
                             len(samples))


def main() -> None:
    import argparse

    from edge_depth.sim import RigConfig, make_sample

    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--seed", type=int, default=1_000_000)
    args = p.parse_args()
    frames = [make_sample(args.seed + i, RigConfig(), "beams16") for i in range(args.frames)]
    for name, watch, ms, worst, levels in run_cases(DriftWatch, frames, 10):
        print(f"{name}: {watch.estimate().describe()}; {ms:.2f} ms a frame (worst "
              f"{worst:.0f} ms); levels every 10 frames {levels}")


if __name__ == "__main__":
    main()
