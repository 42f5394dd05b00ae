"""A noisy LiDAR map smoothed along its rows, where its own points say it is noisy.

On a surface, a point lies on the line through its two row neighbours; its deviation from that
line, scaled by the deviation's spread for unit noise, measures the range noise, and its median
absolute value (× 1.4826) does so robustly: the few triples that straddle a depth edge do not
move it. Where that level is above THRESHOLD_PX on at least MIN_TRIPLES points, each point
becomes the mean of the points among itself and its NEIGHBOURS neighbours each side along its
row (`lidar_align.row_runs`: consecutive points at most GAP_PX apart) that lie within
TOLERANCE × the level of it — so a depth edge's far side stays out. A map at or below the
level (the rig's, ground truth sampled) is left as it is. `[engine] denoise_lidar`, off by
default: at 0.5 px of noise it gains the real pairs 0–1 %, at 0.75–1.5 px 1–21 %
(docs/experiments.md, 2026-12-06 20:05).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from edge_depth.runtime.lidar_align import map_points, row_runs

THRESHOLD_PX = 0.3  # the real pairs' sampled maps read 0.11-0.15, 0.5 px of noise 0.54
MIN_TRIPLES = 50
NEIGHBOURS = 2
TOLERANCE = 2.5


def noise_level(sparse: np.ndarray, points: tuple[np.ndarray, np.ndarray] | None = None
                ) -> tuple[float, int]:
    """(the map's range noise in px, how many triples measured it); `points`:
    `map_points(sparse)`, if at hand."""
    ys, xs = map_points(sparse) if points is None else points
    if len(ys) < 3:
        return 0.0, 0
    d = sparse[ys, xs].astype(np.float64)
    run = row_runs(ys, xs)
    inner = (run[1:-1] == run[:-2]) & (run[1:-1] == run[2:])
    xl, xm, xr = xs[:-2][inner], xs[1:-1][inner], xs[2:][inner]
    dl, dm, dr = d[:-2][inner], d[1:-1][inner], d[2:][inner]
    t = (xm - xl) / (xr - xl)
    deviation = (dm - (dl + (dr - dl) * t)) / np.sqrt(1 + t ** 2 + (1 - t) ** 2)
    if len(deviation) == 0:
        return 0.0, 0
    return float(1.4826 * np.median(np.abs(deviation))), int(len(deviation))


def smoothed(sparse: np.ndarray, level: float,
             points: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Each point the mean of itself and its row neighbours (NEIGHBOURS each side, in its run)
    within TOLERANCE × `level` of it."""
    ys, xs = map_points(sparse) if points is None else points
    d = sparse[ys, xs].astype(np.float64)
    run = row_runs(ys, xs)
    total, count = d.copy(), np.ones(len(d))
    for k in range(1, NEIGHBOURS + 1):
        for a, b in ((slice(k, None), slice(None, -k)), (slice(None, -k), slice(k, None))):
            near = (run[a] == run[b]) & (np.abs(d[b] - d[a]) <= TOLERANCE * level)
            total[a] += np.where(near, d[b], 0.0)
            count[a] += near
    out = sparse.copy()
    out[ys, xs] = (total / count).astype(sparse.dtype)
    return out


@dataclass(frozen=True)
class LidarDenoise:
    """`apply(sparse)` -> (the map, smoothed where it is noisy; its noise level in px)."""

    def apply(self, sparse: np.ndarray) -> tuple[np.ndarray, float]:
        points = map_points(sparse)
        level, triples = noise_level(sparse, points)
        if level <= THRESHOLD_PX or triples < MIN_TRIPLES:
            return sparse, level
        return smoothed(sparse, level, points), level
