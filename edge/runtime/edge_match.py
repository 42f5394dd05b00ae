"""Full-resolution block matching at the network's uncertain edges (opt-in).

The network works at 1/8 resolution; on real pairs all of its bad-3 loss against the SGBM +
LiDAR fusion lies at depth edges, where thin structures (leaves, spokes, cables) are finer
than its grid (docs/experiments.md, session 24). This stage runs OpenCV's StereoBM over the
frame and takes its left-right-checked value where the network is unsure at its own edges:
confidence below `max_confidence`, the network's disparity ranging over more than
`min_range_px` within `window` × `window` pixels, and the matched value warping the right view
onto the left better than the network's (mean |difference| over `photo_window` ×
`photo_window`). Everything else keeps the network's value.

It costs about 0.6× SGBM's time (64 disparities, `tools/bench.py` on a 2-core host), which issue
11's budget does not have, so it is off by default (`[engine] edge_match = 0`). Its
parameters were chosen on the Middlebury motorcycle pair (`tools/real_pairs.py
--motorcycle`); Aloe was only reported. On the synthetic worlds it costs EPE (there SGBM-like
matching is 3-4× less reliable than on real pairs): see the README before turning it on.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from edge_depth.errors import ConfigError
from edge_depth.runtime.cells import local_range, warped_cost

BLOCK_PX = 7
MAX_CONFIDENCE = 0.9
MIN_RANGE_PX = 1.0
WINDOW_PX = 5
PHOTO_WINDOW_PX = 5


@dataclass
class EdgeMatch:
    """`EdgeMatch(num_disparities)`; `apply(left, right, disparity, confidence)`."""

    num_disparities: int
    block_px: int = BLOCK_PX
    max_confidence: float = MAX_CONFIDENCE
    min_range_px: float = MIN_RANGE_PX
    window_px: int = WINDOW_PX
    photo_window_px: int = PHOTO_WINDOW_PX

    def __post_init__(self) -> None:
        if self.num_disparities <= 0 or self.num_disparities % 16:
            raise ConfigError("edge_match", "0 (off) or a positive multiple of 16 "
                              "(StereoBM's disparity count: above the scene's largest)",
                              self.num_disparities)
        matcher = cv2.StereoBM_create(numDisparities=self.num_disparities,
                                      blockSize=self.block_px)
        matcher.setTextureThreshold(10)
        matcher.setUniquenessRatio(15)
        matcher.setDisp12MaxDiff(1)
        matcher.setSpeckleWindowSize(100)
        matcher.setSpeckleRange(2)
        matcher.setPreFilterCap(31)
        self._matcher = matcher

    def matched(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """StereoBM's disparity in px, (H, W) float32; 0 where it found no checked match."""
        raw = self._matcher.compute(as_grey8(left), as_grey8(right))
        out = raw.astype(np.float32) * (1.0 / 16.0)
        out[raw <= 0] = 0.0
        return out

    def apply(self, left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
              confidence: np.ndarray) -> tuple[np.ndarray, int]:
        """(disparity with the matched values swapped in, how many pixels were swapped)."""
        matched = self.matched(left, right)
        take = (matched > 0) & (confidence < self.max_confidence) & \
            (local_range(disparity, self.window_px) > self.min_range_px)
        if take.any():  # only where the matched value explains the pair better
            grey = [np.asarray(im, np.float32) for im in (left, right)]
            window = (self.photo_window_px,)
            take &= warped_cost(*grey, matched, window)[0] < \
                warped_cost(*grey, disparity, window)[0]
        return np.where(take, matched, disparity).astype(np.float32), int(take.sum())


def as_grey8(image: np.ndarray) -> np.ndarray:
    """StereoBM needs 8-bit grey: float images (the engine's buffers) are rounded and clipped."""
    if image.dtype == np.uint8:
        return image
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)
