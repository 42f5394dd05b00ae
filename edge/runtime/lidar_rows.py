"""A projected LiDAR map's points and its rows: what the checks on the map read
(`edge.runtime.lidar_align`, `edge.runtime.lidar_denoise`).

A scanning LiDAR's points land along image rows (or nearly), neighbour beside neighbour; where
two consecutive points of one row lie at most GAP_PX apart they see one surface or the two
sides of a depth edge. On a surface a point lies on the line through its two row neighbours;
its deviation from that line, scaled by the deviation's spread for unit noise, measures the
range noise, and its median absolute value (× 1.4826) does so robustly: the few triples that
straddle a depth edge do not move it (`noise_level`).
"""

from __future__ import annotations

import cv2
import numpy as np

GAP_PX = 3  # the farthest apart two points of a row may be to count as neighbours
MIN_TRIPLES = 50  # the fewest triples a noise level is read from


def map_points(sparse: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, columns) of the map's points (finite and > 0), in row-major order."""
    # NaN and inf fail the range; OpenCV's scan is ~3x numpy's isfinite & > 0 & nonzero
    found = cv2.findNonZero(cv2.inRange(np.asarray(sparse, np.float32), float(np.finfo(
        np.float32).tiny), float(np.finfo(np.float32).max)))
    if found is None:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    xs, ys = found.reshape(-1, 2).astype(np.int64).T
    return ys, xs


def row_runs(ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """Per point (row-major order), the index of its run: consecutive points of one row at
    most GAP_PX apart, each the neighbour of the next."""
    breaks = np.ones(len(ys), bool)
    breaks[1:] = (ys[1:] != ys[:-1]) | (xs[1:] - xs[:-1] > GAP_PX)
    return np.cumsum(breaks)


def noise_level(sparse: np.ndarray, points: tuple[np.ndarray, np.ndarray] | None = None
                ) -> tuple[float, int]:
    """(the map's range noise in px, how many triples measured it); `points`:
    `map_points(sparse)`, if at hand."""
    ys, xs = map_points(sparse) if points is None else points
    return row_noise(sparse[ys, xs], xs, row_runs(ys, xs))


def measured(noise: tuple[float, int]) -> float | None:
    """A `noise_level` (or `row_noise`) answer's level, None where it rests on fewer than
    MIN_TRIPLES triples: on so few, depth edges may be half of them."""
    level, triples = noise
    return level if triples >= MIN_TRIPLES else None


def row_noise(d: np.ndarray, xs: np.ndarray, run: np.ndarray) -> tuple[float, int]:
    """`noise_level` from the points' disparities, columns and `row_runs`, in row-major
    order."""
    if len(d) < 3:
        return 0.0, 0
    d = d.astype(np.float64)
    inner = (run[1:-1] == run[:-2]) & (run[1:-1] == run[2:])
    xl, xm, xr = xs[:-2][inner], xs[1:-1][inner], xs[2:][inner]
    dl, dm, dr = d[:-2][inner], d[1:-1][inner], d[2:][inner]
    t = (xm - xl) / (xr - xl)
    deviation = (dm - (dl + (dr - dl) * t)) / np.sqrt(1 + t ** 2 + (1 - t) ** 2)
    if len(deviation) == 0:
        return 0.0, 0
    return float(1.4826 * np.median(np.abs(deviation))), int(len(deviation))
