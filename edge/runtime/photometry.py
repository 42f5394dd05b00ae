"""The two cameras' grey levels made to agree before anything matches them.

A pair whose cameras differ in exposure, gain or response (auto-exposure per sensor, a dirty
lens) shows the same surface at different grey levels, which the network (trained with the
two cameras' gain within ±12 % and gamma ±6 %), StereoBM and the selections' warp costs all
read as a mismatch. The right image is mapped onto the left's histogram (each level to the
left's level at the same mid-rank, a 256-entry table) where that would move its grey levels
by more than `threshold` on average — further than the rig's cameras differ in training; the
left image, whose disparity the engine returns, is never changed. Below the threshold the
network's input is not changed: matching cameras that differ within the trained range moves
its result by noise (docs/experiments.md, 2026-12-06 19:15 and 20:15). The stages after the
network (the selections, the matching) compare grey levels across the cameras directly and
read the matched image from STAGES_THRESHOLD on (2026-12-06 22:52).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from edge_depth.runtime.edge_match import as_grey8

# grey levels the match would move the right image by, on average: the real pairs 3.0-3.2, the
# rig's test frames median 7.9 (p95 18.6), a right camera 20 % darker with gamma 1.15 23-35
THRESHOLD = 20.0
# ... and above which the stages after the network read the matched right image (they compare
# grey levels across the cameras directly): the rig's median, above the real pairs' 3
STAGES_THRESHOLD = 8.0


def grey8(image: np.ndarray) -> np.ndarray:
    """(H, W) grey levels as uint8 (`as_grey8`), with the unit stride OpenCV reads rows with."""
    return np.ascontiguousarray(as_grey8(image))


def histogram(image8: np.ndarray) -> np.ndarray:
    """Pixels at each grey level, (256,) float64."""
    return cv2.calcHist([image8], [0], None, [256], [0, 256]).ravel().astype(np.float64)


def cumulative(image8: np.ndarray, counts: np.ndarray | None = None) -> np.ndarray:
    """The cumulative share of pixels at or below each grey level, (256,) float64; `counts`:
    `histogram(image8)`, if at hand."""
    counts = histogram(image8) if counts is None else counts
    return np.cumsum(counts) / max(image8.size, 1)


def histogram_distance(left8: np.ndarray, right8: np.ndarray) -> float:
    """The largest gap between the two images' cumulative histograms, 0 … 1."""
    return float(np.abs(cumulative(left8) - cumulative(right8)).max())


def matching_table(left8: np.ndarray, right8: np.ndarray,
                   right_counts: np.ndarray | None = None) -> np.ndarray:
    """(256,) float32: each right grey level's value at the same mid-rank in the left image;
    `right_counts`: `histogram(right8)`, if at hand."""
    left_c, right_c = cumulative(left8), cumulative(right8, right_counts)
    left_mid = left_c - 0.5 * np.diff(left_c, prepend=0.0)
    right_mid = right_c - 0.5 * np.diff(right_c, prepend=0.0)
    return np.interp(right_mid, left_mid, np.arange(256.0)).astype(np.float32)


@dataclass(frozen=True)
class Levels:
    """`PhotometricMatch.measure`'s answer: the right image in uint8, its 256-entry table onto
    the left's grey levels, and how far that table moves it on average (levels)."""

    right8: np.ndarray
    table: np.ndarray
    change: float

    def mapped(self, out: np.ndarray | None = None) -> np.ndarray:
        """The right image on the left's grey levels (float32; into `out`, if given)."""
        return cv2.LUT(self.right8, self.table, dst=out)


@dataclass(frozen=True)
class PhotometricMatch:
    """`measure(left, right)` -> `Levels`; `apply(left, right)` -> (the right image on the
    left's grey levels where that moves them by more than `threshold`, else as given; the
    move). `stages_threshold`: the move above which the stages after the network read the
    matched image (the engine's `Engine._stage_pair`)."""

    threshold: float = THRESHOLD
    stages_threshold: float = STAGES_THRESHOLD

    def measure(self, left: np.ndarray, right: np.ndarray) -> Levels:
        """The right image's table onto the left's grey levels and how far it moves them."""
        left8, right8 = grey8(left), grey8(right)
        counts = histogram(right8)
        table = matching_table(left8, right8, counts)
        change = float(counts @ np.abs(table - np.arange(256)) / max(counts.sum(), 1.0))
        return Levels(right8, table, change)

    def apply(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, float]:
        """The right image mapped onto the left's grey levels (float32) where that moves them
        by more than `threshold` on average, else as given; and that mean move (levels)."""
        levels = self.measure(left, right)
        return (right if levels.change <= self.threshold else levels.mapped()), levels.change
