"""A noisy LiDAR map smoothed along its rows, where its own points say it is noisy.

Where the map's robust noise level (`lidar_rows.noise_level`) is above THRESHOLD_PX on at
least MIN_TRIPLES points, each point becomes the mean of the points among itself and its
NEIGHBOURS neighbours each side along its row (`lidar_rows.row_runs`: consecutive points at
most GAP_PX apart) that lie within TOLERANCE × the level of it — so a depth edge's far side
stays out. A map at or below the level (the rig's, ground truth sampled) is left as it is.
`[engine] denoise_lidar`, off by default: at 0.5 px of noise it gains the real pairs 0–1 %,
at 0.75–1.5 px 1–21 %, but the rig's test split at 1 px loses 2–3 % (docs/experiments.md,
2026-12-06 20:05 and 21:27).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from edge_depth.runtime.lidar_rows import map_points, measured, noise_level, row_runs

THRESHOLD_PX = 0.3  # the real pairs' sampled maps read 0.11-0.15, 0.5 px of noise 0.54
NEIGHBOURS = 2
TOLERANCE = 2.5


def smooths(level: float | None) -> bool:
    """Whether a map of this noise level (`lidar_rows.measured`; None: unknown) is smoothed."""
    return level is not None and level > THRESHOLD_PX


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
    """`apply(sparse)` -> (the map, smoothed where it is noisy; its noise level in px, None on
    a map too sparse to measure it: fewer than MIN_TRIPLES triples)."""

    def apply(self, sparse: np.ndarray) -> tuple[np.ndarray, float | None]:
        points = map_points(sparse)
        level = measured(noise_level(sparse, points))
        if level is None or not smooths(level):
            return sparse, level
        return smoothed(sparse, level, points), level
