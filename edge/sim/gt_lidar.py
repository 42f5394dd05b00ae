"""LiDAR sampled from a ground-truth disparity map, in the image: for training on rendered or
recorded data whose LiDAR is not simulated by ray casting (the things world, SceneFlow), and
for the real-pair evaluation recipe (16 rows, every 2nd column, N(0, 0.1 px)).

Patterns, drawn per sample: none (stereo only), one 2-D scan line, or 16 / 32 / 64 beams as
near-horizontal rows with a slight tilt; points every 1-4 columns with jitter, dropouts,
disparity noise, and now and then a slightly wrong extrinsic (a shift of up to 2 px and a
disparity scale off by up to 2 %). `sample_projected` reads the rows in the *right* view's GT and
projects them into the left, as a LiDAR one baseline to the right of the left camera would
be: the background it sees behind foreground edges lands inside the foreground, and the
project's occlusion filter removes most of it but not all — as on a robot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PATTERN_WEIGHTS = {"none": 0.12, "planar": 0.08, "rows16": 0.4, "rows32": 0.2, "rows64": 0.2}


@dataclass(frozen=True)
class GtLidarPattern:
    """rows: row positions (K,) in pixels (for the full image); slope: rows' tilt (px/px);
    column_step: pixels between points; jitter_px; dropout 0-1; noise_px: disparity std;
    shift_px (du, dv) and scale: the extrinsic error."""

    rows: np.ndarray
    slope: float = 0.0
    column_step: int = 2
    jitter_px: float = 0.0
    dropout: float = 0.0
    noise_px: float = 0.1
    shift_px: tuple[float, float] = (0.0, 0.0)
    scale: float = 1.0

    @classmethod
    def evenly(cls, height: int, count: int = 16, **kw) -> GtLidarPattern:
        """`count` rows at the centres of equal horizontal bands: v_k = (k + 0.5) H / count."""
        return cls(rows=(np.arange(count) + 0.5) * height / count, **kw)

    @classmethod
    def random(cls, height: int, rng: np.random.Generator,
               none_share: float | None = None) -> GtLidarPattern | None:
        """A random pattern for training (None: no LiDAR). none_share: the probability of no
        LiDAR (default PATTERN_WEIGHTS'); the other patterns keep their relative weights."""
        names = list(PATTERN_WEIGHTS)
        weights = np.array(list(PATTERN_WEIGHTS.values()))
        if none_share is not None:
            if not 0.0 <= none_share <= 1.0:
                raise ValueError(f"none_share must be within 0-1, got {none_share}")
            weights[1:] *= (1.0 - none_share) / weights[1:].sum()
            weights[0] = none_share
        name = names[int(rng.choice(len(names), p=weights / weights.sum()))]
        if name == "none":
            return None
        if name == "planar":
            rows = np.array([rng.uniform(0.2, 0.9) * height])
        else:
            count = int(name[4:])
            span = rng.uniform(0.5, 1.0) * height
            top = rng.uniform(0, height - span)
            rows = top + (np.arange(count) + rng.uniform(0, 1)) * span / count
        wrong = rng.random() < 0.1
        return cls(rows=rows, slope=float(rng.uniform(-0.03, 0.03)),
                   column_step=int(rng.integers(1, 5)), jitter_px=float(rng.uniform(0, 0.5)),
                   dropout=float(rng.uniform(0, 0.3)), noise_px=float(rng.uniform(0, 0.3)),
                   shift_px=tuple(rng.uniform(-2, 2, 2)) if wrong else (0.0, 0.0),
                   scale=float(rng.uniform(0.98, 1.02)) if wrong else 1.0)

    def sample(self, disparity: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(H, W) float32 sparse disparity (0 = no point) from a GT map (0 = unknown): each
        point reads the GT where the (mis-calibrated) LiDAR thinks it is and lands at the
        nearest pixel of where it really is."""
        h, w = disparity.shape
        sparse = np.zeros((h, w), np.float32)
        us = np.arange(0, w, self.column_step, dtype=np.float64)
        for row in self.rows:
            u = us + rng.uniform(-self.jitter_px, self.jitter_px, us.size)
            v = row + self.slope * (u - w / 2) + rng.uniform(-self.jitter_px, self.jitter_px,
                                                              us.size)
            ui, vi = np.rint(u).astype(int), np.rint(v).astype(int)
            src_u = np.rint(u + self.shift_px[0]).astype(int)
            src_v = np.rint(v + self.shift_px[1]).astype(int)
            ok = (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h) & (src_u >= 0) & (src_u < w) \
                & (src_v >= 0) & (src_v < h) & (rng.random(us.size) >= self.dropout)
            d = disparity[src_v[ok], src_u[ok]] * self.scale
            d = d + rng.normal(0, self.noise_px, d.size) if self.noise_px > 0 else d
            keep = (disparity[src_v[ok], src_u[ok]] > 0) & (d > 0)
            sparse[vi[ok][keep], ui[ok][keep]] = d[keep]
        return sparse

    def sample_projected(self, disparity_right: np.ndarray, rng: np.random.Generator,
                         occlusion=None) -> np.ndarray:
        """(H, W) float32 sparse disparity in the *left* view, from the right view's GT: the
        points are drawn there as `sample` does, moved by their own disparity into the left
        image (u_left = u_right + d; the nearest point wins a pixel), then filtered by
        `calibration.projection.filter_occluded` with the LiDAR at the right camera."""
        from edge_depth.calibration.projection import filter_occluded

        h, w = disparity_right.shape
        in_right = self.sample(disparity_right, rng)
        vs, us = np.nonzero(in_right)
        d = in_right[vs, us]
        u_left = np.rint(us + d).astype(np.int64)
        inside = u_left < w
        sparse = np.zeros((h, w), np.float32)
        np.maximum.at(sparse.ravel(), vs[inside] * w + u_left[inside], d[inside])
        # a LiDAR at the right camera: one baseline along +x, so the offset over the baseline is 1
        keep = filter_occluded(sparse, sparse > 0, np.array([1.0, 0.0, 0.0]), 1.0, occlusion)
        return np.where(keep, sparse, np.float32(0))
