"""A grey-guided weighted median over the network's unsure edges: the refinement's last step.

Where: the gate (`unsure_edges`) is where the network is unsure (confidence under 0.9) at a
depth edge (the disparity's 5×5 range above 1 px), taken on the refined disparity. Why: after
a per-pixel refinement (the band refinement, `edge.runtime.band_sgm`; before it, a block
matching's choice among the network's value, StereoBM's and the LiDAR's nearest point) the
gate mixes sources pixel by pixel. Each pixel is chosen alone, so the mix is salt and
pepper, and its edges follow whichever source won rather than the image. A weighted median
over a few neighbours, each weighted by how alike its grey level is to the pixel's own, gives
each pixel the value that most of its own surface holds: after the matching, motorcycle bad-3
with LiDAR 7.82 → 7.21 %; after the band, 3–16 % EPE on every set (docs/results.md). A
plain median does nothing: the grey guidance is what aligns the edges. Averaging instead
(edge-aware smoothing) is worse than nothing: a blend across an edge is the error bad-3
counts.

How, in numpy at a few ms a frame: only the gated pixels (a quarter to a third of the frame),
`radius`/`stride` sampling (9×9 every 2nd pixel: 25 samples), each sample packed into one
float32 key — its disparity in 1/16 px (StereoBM's own step) × 256 plus its weight in 0–255
(exp(−Δgrey² / 2σ²), from a table) — sorted by a fixed network of min/max passes over
(samples, pixels) arrays, then the first key where the running weight reaches half the total.
A pixel whose median lies within 1/16 px of its own value keeps its own, unquantised.

Pure numpy + OpenCV (robot side, no torch).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

from edge_depth.errors import ConfigError
from edge_depth.runtime.cells import Scratch, local_range

# the gate: the network's confidence below this, where its disparity's range over WINDOW_PX²
# exceeds MIN_RANGE_PX (an edge)
MAX_CONFIDENCE = 0.9
MIN_RANGE_PX = 1.0
WINDOW_PX = 5
SIGMA_GREY = 8.0   # the weights' width in grey levels
SUBPIXEL = 16      # disparity steps per pixel in a key
WEIGHT_BITS = 8     # a key = disparity step × 2^WEIGHT_BITS + weight (0 … 255)
WEIGHT_LEVELS = 1 << WEIGHT_BITS
MAX_DISPARITY_PX = (2 ** 24 // WEIGHT_LEVELS - 1) / SUBPIXEL  # keys exact in float32
# "radius/stride": the samples are the pixels (dy, dx) with dy, dx in −radius … radius by
# stride (docs/experiments.md: 9×9 every 2nd chosen on motorcycle)
PATTERNS = {"9x9/2": (4, 2), "13x13/3": (6, 3), "9x9/4": (4, 4)}
OFF = "off"
# gated pixels per pass: the (samples, pixels) buffers stay ~6 MB whatever the gate (a whole
# 640×400 frame in one pass would take ~180 MB) and nearer the cache — motorcycle's 75 k
# pixels 13.5 → 11.2 ms in passes of 8 k (docs/experiments.md)
CHUNK_PX = 8192


def sorting_network(count: int) -> list[tuple[int, int]]:
    """Batcher's odd-even merge sort as (a, b) compare-exchange pairs for `count` items: the
    network for the next power of two, without the pairs that touch the missing items (they
    would hold +inf and never move)."""
    size = 1 << max(count - 1, 0).bit_length()
    pairs = []
    p = 1
    while p < size:
        k = p
        while k >= 1:
            for j in range(k % p, size - k, 2 * k):
                for i in range(min(k, size - j - k)):
                    if (i + j) // (2 * p) == (i + j + k) // (2 * p) and i + j + k < count:
                        pairs.append((i + j, i + j + k))
            k //= 2
        p *= 2
    return pairs


@dataclass(frozen=True)
class EdgeMedian:
    """`EdgeMedian(pattern)`; `apply(disparity, grey, mask)`. `pattern`: a key of PATTERNS."""

    pattern: str = "9x9/2"
    sigma_grey: float = SIGMA_GREY

    def __post_init__(self) -> None:
        check_pattern(self.pattern)
        if not self.sigma_grey > 0:
            raise ConfigError("edge_median", "a positive σ in grey levels", self.sigma_grey)

    @cached_property
    def offsets(self) -> list[tuple[int, int]]:
        """The samples' (dy, dx), the pixel itself among them."""
        radius, stride = PATTERNS[self.pattern]
        steps = range(-radius, radius + 1, stride)
        return [(dy, dx) for dy in steps for dx in steps]

    def flat_offsets(self, width: int) -> np.ndarray:
        """The samples' offsets in a row-major image `width` wide, int32."""
        return np.array([dy * width + dx for dy, dx in self.offsets], np.int32)

    @cached_property
    def network(self) -> list[tuple[int, int]]:
        """The samples' sorting network."""
        return sorting_network(len(self.offsets))

    @cached_property
    def weight_table(self) -> np.ndarray:
        """Weight (whole numbers 0 … 255, float32) by |Δgrey| 0 … 255."""
        diff = np.arange(256, dtype=np.float64)
        return np.rint((WEIGHT_LEVELS - 1) * np.exp(-diff ** 2 / (2 * self.sigma_grey ** 2))
                       ).astype(np.float32)

    def apply(self, disparity: np.ndarray, grey: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """(H, W) float32: `disparity` (px) with each pixel of `mask` replaced by the weighted
        median of its samples (their values as they were before this call). `grey`: the left
        image (H, W), grey levels 0–255 (rounded here)."""
        out = np.array(disparity, np.float32)
        pixels = np.flatnonzero(mask)
        if len(pixels) == 0:
            return out
        radius = PATTERNS[self.pattern][0]
        border = (radius,) * 4
        width = out.shape[1]
        # rounded and saturated to 0 … 255 in one OpenCV pass (np.rint, np.clip and astype
        # were three over the whole frame)
        level = cv2.copyMakeBorder(cv2.multiply(np.asarray(grey, np.float32), 1.0,
                                                dtype=cv2.CV_8U),
                                   *border, cv2.BORDER_REPLICATE).ravel()
        steps = cv2.copyMakeBorder(disparity_steps(out), *border, cv2.BORDER_REPLICATE).ravel()
        padded_width = width + 2 * radius
        # the pixels in the padded image: `radius` rows above, 2·radius more columns a row
        centre = pixels + (pixels // width) * (2 * radius) + radius * padded_width + radius
        offsets = self.flat_offsets(padded_width)
        median = np.concatenate([self._medians(centre[i:i + CHUNK_PX], offsets, steps, level)
                                 for i in range(0, len(centre), CHUNK_PX)])
        flat = out.reshape(-1)
        own = flat[pixels]
        flat[pixels] = np.where(np.abs(median - own) < 1.0 / SUBPIXEL, own, median)
        return out

    def _medians(self, centre: np.ndarray, offsets: np.ndarray, steps: np.ndarray,
                 level: np.ndarray) -> np.ndarray:
        """The weighted median (px, (N,) float32) at the padded image's flat pixels `centre`
        (N,), from the padded disparity (in 1/SUBPIXEL px steps, uint16) and grey levels. Into
        buffers reused frame to frame (fresh pages for these megabytes cost a third of the
        time)."""
        count, n = len(offsets), len(centre)

        def buffer(name: str, dtype=np.float32) -> np.ndarray:
            return self._scratch.take(name, count * n, 1, dtype).reshape(count, n)

        sample = buffer("sample", np.intp)  # (samples, pixels) flat indices
        np.add(centre[None, :], offsets[:, None], out=sample)
        sample_steps = buffer("steps", np.uint16)
        np.take(steps, sample, out=sample_steps)
        keys, weights = buffer("keys"), buffer("weights")
        np.multiply(sample_steps, np.float32(WEIGHT_LEVELS), out=keys)
        levels, own = buffer("levels", np.uint8), buffer("own", np.uint8)
        np.take(level, sample, out=levels)
        own[...] = level[centre]
        cv2.absdiff(levels, own, dst=levels)
        cv2.LUT(levels, self.weight_table, dst=weights)
        keys += weights
        rows = list(keys)  # sorted per column (pixel) ascending, swapping rows, not copying
        spare = self._scratch.take("spare", n, 1).reshape(n)
        for a, b in self.network:
            np.minimum(rows[a], rows[b], out=spare)
            np.maximum(rows[a], rows[b], out=rows[b])
            rows[a], spare = spare, rows[a]
        whole, running = buffer("whole", np.int32), buffer("running", np.int32)
        for target, row in zip(whole, rows, strict=True):
            target[...] = row  # exact: whole numbers below 2^24
        np.bitwise_and(whole, WEIGHT_LEVELS - 1, out=running)  # each sample's weight ...
        for row in range(1, count):
            running[row] += running[row - 1]                     # ... summed in order
        # the first sorted sample where the running weight reaches half the total
        below = buffer("below", np.bool_)
        np.less(running, (running[-1] + 1) >> 1, out=below)
        first = np.add.reduce(below.view(np.uint8), axis=0, dtype=np.uint8)
        chosen = whole[first, np.arange(n)]
        return (chosen >> WEIGHT_BITS).astype(np.float32) * np.float32(1 / SUBPIXEL)

    @cached_property
    def _scratch(self) -> Scratch:
        return Scratch()


def unsure_edges(disparity: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """The gate: where the network is unsure (`confidence` under MAX_CONFIDENCE) at an edge
    (the disparity's range over WINDOW_PX² above MIN_RANGE_PX)."""
    return (confidence < MAX_CONFIDENCE) & \
        (local_range(disparity, WINDOW_PX) > MIN_RANGE_PX)


def disparity_steps(disparity: np.ndarray) -> np.ndarray:
    """(H, W) float32 px -> uint16 steps of 1/SUBPIXEL px, rounded half to even, clipped to
    0 … MAX_DISPARITY_PX: in 16 bits, half the bytes a float32 image has, gathered from cache
    more often. A non-finite value (none should reach here) must not become a garbage key
    that a neighbour's median could pick: NaN counts as 0, ±inf as the range's ends."""
    if cv2.checkRange(disparity, True, -float(np.finfo(np.float32).max),
                      MAX_DISPARITY_PX)[0]:
        # finite and below the range's end: OpenCV's saturating conversion is the clip
        return cv2.multiply(disparity, float(SUBPIXEL), dtype=cv2.CV_16U)
    finite = np.nan_to_num(disparity, nan=0.0, posinf=MAX_DISPARITY_PX, neginf=0.0)
    return np.rint(np.clip(finite, 0.0, MAX_DISPARITY_PX) * SUBPIXEL).astype(np.uint16)


def settings_text() -> str:
    """'"off" or "9x9/2" or …': what `edge_median` accepts, for error lines."""
    return " or ".join(f'"{p}"' for p in (OFF, *PATTERNS))


def check_pattern(pattern: str) -> None:
    """`[engine] edge_median`: ConfigError unless one of PATTERNS (or OFF, checked by the
    caller)."""
    if pattern not in PATTERNS:
        raise ConfigError("edge_median", settings_text()
                          + " (the weighted median's samples: window / step)", pattern)
