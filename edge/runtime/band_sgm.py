"""Semi-global matching in a disparity band around the network's estimate: the engine's
`[engine] refine = "band"`, the default (docs/results.md); the weighted median
(`edge.runtime.edge_median`) follows it in the engine.

The network's upsampled disparity is close almost everywhere and off by a few to tens of
pixels at depth edges and thin structures, finer than its 1/8 grid; full-resolution matching
finds those but, searched over the whole range, also finds far-off wrong minima in weak
texture. This searches only a band of disparities at each pixel — the network's estimate ±
`band_half_widths` (from its confidence), widened to the nearest LiDAR point's value within
`lidar_reach` px — and aggregates a census cost along Hirschmüller's paths (PAMI 2008; 4 by
default, 8 with the diagonals):

    L_r(p, d) = C(p, d) + min(L_r(p−r, d), L_r(p−r, d±1) + P1, min_i L_r(p−r, i) + P2)
                − min_i L_r(p−r, i),      P2 = max(P1, P2' / |I(p) − I(p−r)|)

with each pixel's labels its own (a ragged volume): a neighbour's label is matched to this
pixel's by their absolute disparity. The cost is the census Hamming distance, plus
`net_weight` × the network's −log p(d) under a Laplace error model with P(|e| ≤ 1 px) = its
confidence, times Poggi et al.'s inverted Gaussian at each LiDAR pixel (CVPR 2019). The winner
of the summed cost, with the parabola through its neighbours, replaces the estimate where it
is inside the band and agrees with the right view's winner within `lr_max` (Hirschmüller's
check, the right view's disparity read from the left's sums) after a 3×3 median of both, also
where it is within a pixel of the estimate (its parabola is the finer value; docs/experiments.md
has the judge); elsewhere the estimate stays, or the nearest LiDAR point's value where the
summed cost is lower there. Only the pixels whose confidence is under `refine_below` (0.9),
and those within `refine_margin_px` of them, are refined; the paths start afresh after the
others, which keep the network's estimate (the aggregation's cost is per pixel: this halves
it).

Constants are the papers' (census 9×7, P1 = 10, P2' = 120, k = 10, c = 1 px, check 1 px);
the band's widths, the Laplace weight, the reach and the rest are this stage's own, chosen on
the published pairs and the rig's test split and judged on variants of the pairs it was not
chosen on (docs/experiments.md, 2026-12-07). Compiled with numba: the downward and the upward
paths on two threads (`edge.runtime.band_paths`), float32 costs, loops written to run in
SIMD lanes, the volumes in buffers kept from frame to frame, every pass over the image a
kernel of its own (numpy's passes with their fresh arrays took a third of the time).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from edge_depth.errors import InvalidDataError
from edge_depth.runtime.band_paths import aggregate
from edge_depth.runtime.cells import Scratch
from edge_depth.runtime.nearest_point import nearest_within

CENSUS_W, CENSUS_H = 9, 7
WORST = CENSUS_W * CENSUS_H - 1  # the census cost where the right pixel leaves the image
MAX_LABELS = 257  # a band's labels at most (the network's and the LiDAR's values far apart)
# the volumes (cost, the paths' sums: tens of MB) kept from frame to frame, one set per thread:
# fresh pages for them took more time than the aggregation (docs/experiments.md)
_SCRATCH = Scratch()


@dataclass(frozen=True)
class BandSgmConfig:
    """The refinement's constants."""

    min_band: int = 4  # half-width of the band (px) where the network is sure
    max_band: int = 48  # half-width where it is not
    p1: int = 10
    p2: int = 120
    k: float = 10.0
    c: float = 1.0
    lr_max: float = 1.0  # left-right check tolerance (px)
    uniqueness: int = 0  # % by which the winner's S must be below the next (beyond ±1)
    quantile: float = 0.0  # the band: this interval of the confidence's error model; 0 = linear
    net_weight: float = 1.0  # the network's −log p(d) in the cost: census units per nat
    lidar_reach: float = 8.0  # px: the band also spans the nearest LiDAR point within this
    choose_fallback: int = 1  # 1: where the check fails, the nearest point where S is lower there
    paths: int = 4  # 4 (no diagonals: ~30 % less time, within 0.005 px here) or 8
    refine_below: float = 0.9  # only pixels under this confidence (and near them) refined
    refine_margin_px: int = 2  # how near
    median: int = 1  # 1: a 3x3 median of both views' winners before the check

    def __post_init__(self) -> None:
        if not 0 <= self.min_band <= self.max_band <= 128:
            raise ValueError(f"need 0 ≤ min_band ≤ max_band ≤ 128, got {self.min_band}, "
                             f"{self.max_band}")
        if self.paths not in (4, 8):
            raise ValueError(f"paths: 4 or 8, got {self.paths}")


def census(grey: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """The 9×7 census of an (H, W) uint8 image: bit set where the neighbour is darker than
    the centre, border replicated; (H, W) uint64, into `out` where given."""
    ry, rx = CENSUS_H // 2, CENSUS_W // 2
    if out is None:
        out = np.empty(grey.shape, np.uint64)
    _census(np.pad(np.ascontiguousarray(grey, np.uint8), ((ry, ry), (rx, rx)), mode="edge"),
            out)
    return out


@numba.njit(cache=True, parallel=True)
def _census(padded: np.ndarray, out: np.ndarray) -> None:
    """`census` of the image inside `padded` (its border CENSUS_H // 2 rows and
    CENSUS_W // 2 columns wide) into `out`: one pass over a row per neighbour, in SIMD
    lanes, the first 30 neighbours' bits in one 32-bit word and the last 32 in another
    (twice the lanes 64-bit words have), joined at the end into the same 62 bits."""
    ry, rx = CENSUS_H // 2, CENSUS_W // 2
    h, w = padded.shape[0] - 2 * ry, padded.shape[1] - 2 * rx
    one = np.uint32(1)
    first_word = CENSUS_W * CENSUS_H - 1 - 32  # the neighbours in the high word
    for y in numba.prange(h):
        centre = padded[y + ry, rx:rx + w]
        high = np.zeros(w, np.uint32)
        low = np.zeros(w, np.uint32)
        k = 0
        for dy in range(-ry, ry + 1):
            row = padded[y + ry + dy]
            for dx in range(-rx, rx + 1):
                if dy == 0 and dx == 0:
                    continue
                neighbour = row[rx + dx:rx + dx + w]
                bits = high if k < first_word else low
                for x in range(w):
                    bits[x] = (bits[x] << one) | np.uint32(neighbour[x] < centre[x])
                k += 1
        row_out = out[y]
        for x in range(w):
            row_out[x] = (np.uint64(high[x]) << np.uint64(32)) | np.uint64(low[x])


@numba.njit(cache=True, inline="always")
def _popcount(v: np.uint64) -> int:
    v = v - ((v >> np.uint64(1)) & np.uint64(0x5555555555555555))
    v = (v & np.uint64(0x3333333333333333)) + ((v >> np.uint64(2)) & np.uint64(0x3333333333333333))
    v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return int((v * np.uint64(0x0101010101010101)) >> np.uint64(56))


@numba.njit(cache=True, parallel=True)
def band_cost(cl: np.ndarray, cr: np.ndarray, lo: np.ndarray, count: np.ndarray,
              start: np.ndarray, sparse: np.ndarray, prior: np.ndarray,
              confidence: np.ndarray, k: float, c: float, net_weight: float,
              cost: np.ndarray) -> None:
    """The ragged cost volume, flat float32: pixel p's labels d = lo(p) … lo(p) + count(p) − 1
    at start(p) …: the census Hamming distance (WORST where x − d leaves the image), plus
    `net_weight` × the network's −log p(d) under its Laplace error model (`band_half_widths`),
    multiplied at LiDAR pixels (sparse > 0) by Poggi's inverted Gaussian; into `cost` (at
    least start[-1] long)."""
    h, w = cl.shape
    for y in numba.prange(h):
        for x in range(w):
            p = y * w + x
            g = sparse[y, x]
            certainty = -np.log(max(1.0 - confidence[y, x], 1e-3))  # 1 / the Laplace scale
            for i in range(count[y, x]):
                d = lo[y, x] + i
                value = float(WORST if x - d < 0 else _popcount(cl[y, x] ^ cr[y, x - d]))
                value += net_weight * abs(d - prior[y, x]) * certainty
                if g > 0:
                    value *= k * (1.0 - np.exp(-(d - g) ** 2 / (2.0 * c * c)))
                cost[start[p] + i] = value


@numba.njit(cache=True, inline="always")
def _right_view(total: np.ndarray, s: int, m: int, x: int, r_first: int,
                right_cost: np.ndarray, right: np.ndarray) -> None:
    """Left pixel x's part in the right view's winners: its labels i < m (from `total[s]`)
    meet right pixels r = r_first − i at disparity x − r; each keeps the lowest S that met it
    (a tie: the leftmost left pixel's). Walked with r rising, unsigned, without a branch: a
    loop in SIMD lanes (`band_paths._step`)."""
    if m <= 0:
        return
    r0 = np.uint64(r_first - m + 1)
    last = np.uint64(s + m - 1)
    for k in range(np.uint64(m)):
        value, r = total[last - k], r0 + k
        better = value < right_cost[r]
        right_cost[r] = value if better else right_cost[r]
        right[r] = np.float32(x) - np.float32(r) if better else right[r]


@numba.njit(cache=True, parallel=True)
def winners(totals: np.ndarray, lo: np.ndarray, count: np.ndarray, start: np.ndarray,
            uniqueness: int, prior: np.ndarray, near: np.ndarray, left: np.ndarray,
            right: np.ndarray, fallback: np.ndarray) -> None:
    """The left view's winner of S (the two partial sums, added into `totals[0]`) with the
    parabola's sub-pixel step (`left`, −1 where it sits on the band's edge — the match lies
    beyond the band — or is not unique by `uniqueness` %) and the right view's integer winner
    (`right`, -1 where no left pixel reaches it): the minimum of S over the left pixels that
    meet that right pixel (Hirschmüller's check without a second matching)."""
    h, w = lo.shape
    total, other = totals[0], totals[1]
    order = total.view(np.int32)
    for y in numba.prange(h):
        for j in range(start[y * w], start[(y + 1) * w]):
            total[j] += other[j]
    for y in numba.prange(h):
        right_cost = np.full(w, np.inf, np.float32)
        right[y] = -1.0
        for x in range(w):
            s, n, first = start[y * w + x], count[y, x], lo[y, x]
            fallback[y, x] = prior[y, x]  # the network's, or the nearest point where S says so
            if n == 0:  # not refined
                left[y, x] = -1.0
                continue
            i_prior, i_near = int(np.rint(prior[y, x])) - first, int(np.rint(near[y, x])) - first
            if near[y, x] > 0 and 0 <= i_near < n and 0 <= i_prior < n and \
                    total[s + i_near] < total[s + i_prior]:
                fallback[y, x] = near[y, x]
            _right_view(total, s, min(n, x - first + 1), x, x - first, right_cost, right[y])
            lowest = order[s]  # the minimum over the bits: SIMD lanes (`band_paths._step`)
            for i in range(1, n):
                lowest = min(lowest, order[s + i])
            best = 0
            while order[s + best] != lowest:
                best += 1
            low = total[s + best]
            if best == 0 or best == n - 1:
                left[y, x] = -1.0
                continue
            if uniqueness > 0:
                second = np.inf
                for i in range(n):
                    if abs(i - best) > 1:
                        second = min(second, total[s + i])
                if low * (100 + uniqueness) >= second * 100:
                    left[y, x] = -1.0
                    continue
            before, after = total[s + best - 1], total[s + best + 1]
            curvature = before - 2 * low + after
            offset = 0.0 if curvature <= 0 else (before - after) / (2.0 * curvature)
            left[y, x] = first + best + offset


def use_threads(threads: int) -> None:
    """The kernels' threads: the engine's, at most numba's pool."""
    pool = numba.config.NUMBA_NUM_THREADS  # type: ignore[attr-defined]
    numba.set_num_threads(max(1, min(int(threads), pool)))


def band_half_widths(confidence: np.ndarray | None, shape: tuple[int, int],
                     config: BandSgmConfig) -> np.ndarray:
    """Each pixel's band half-width (int32). With `quantile`: the network's error read as
    Laplace with P(|e| ≤ 1 px) = confidence c, scale b = −1 / ln(1 − c), whose `quantile`
    interval is b·ln(1 / (1 − quantile)); clipped to [min_band, max_band]. Else linear: min_band
    at c = 1, max_band at 0."""
    if confidence is None:
        return np.full(shape, config.max_band, np.int32)
    half = np.empty(confidence.shape, np.int32)
    interval = np.log(1.0 / (1.0 - config.quantile)) if config.quantile > 0 else 0.0
    _half_widths(np.ascontiguousarray(confidence, np.float32), config.min_band,
                 config.max_band, np.float32(interval), half)
    return half


@numba.njit(cache=True, parallel=True)
def _half_widths(confidence: np.ndarray, min_band: int, max_band: int, interval: np.float32,
                 half: np.ndarray) -> None:
    """`band_half_widths` into `half`, in float32 (`interval` 0: linear)."""
    h, w = confidence.shape
    spread = np.float32(max_band - min_band)
    for y in numba.prange(h):
        for x in range(w):
            c = min(max(confidence[y, x], np.float32(0.0)), np.float32(1.0 - 1e-6))
            if interval > 0:
                width = np.ceil(interval / -np.log1p(-c))
                half[y, x] = int(min(max(width, np.float32(min_band)), np.float32(max_band)))
            else:
                half[y, x] = min_band + int(np.rint(spread * (np.float32(1.0) - c)))


def refine(left: np.ndarray, right: np.ndarray, prior: np.ndarray,
           confidence: np.ndarray | None, sparse: np.ndarray,
           config: BandSgmConfig | None = None,
           parts_ms: dict[str, float] | None = None) -> tuple[np.ndarray, int]:
    """The prior (H, W) float32 px refined by SGM in its band: (disparity, pixels moved by more
    than 1 px). `left`, `right` rectified grey (uint8 or float 0-255); `confidence` 0-1 (NaN
    read as 0; None: every band its widest, no error model); `sparse` LiDAR disparity, 0 =
    none. Pixels whose prior is not finite keep it; a negative prior is searched from 0.
    `parts_ms`, if given, gets each part's time (ms) added (`experiments/band_parts.py`)."""
    config = config or BandSgmConfig()
    _check_shapes(prior.shape, left=left, right=right, sparse=sparse, confidence=confidence)
    lap = _Laps(parts_ms)
    h, w = prior.shape
    grey_l, grey_r = np.empty((h, w), np.uint8), np.empty((h, w), np.uint8)
    finite, points = np.empty((h, w), np.float32), np.empty((h, w), np.float32)
    certain = None if confidence is None else np.empty((h, w), np.float32)
    _inputs(np.ascontiguousarray(left), np.ascontiguousarray(right),
            np.ascontiguousarray(prior, np.float32), np.ascontiguousarray(sparse, np.float32),
            np.zeros((1, 1), np.float32) if confidence is None else
            np.ascontiguousarray(confidence, np.float32),
            grey_l, grey_r, finite, points,
            np.zeros((1, 1), np.float32) if certain is None else certain)
    known = np.isfinite(prior)
    lap("inputs")
    lo, count, start, nearby = _bands(finite, certain, points, config)
    labels = int(start[-1])
    lap("bands")
    scratch = _SCRATCH
    census_l = census(grey_l, scratch.take("census_l", h * w, 1, np.uint64).reshape(h, w))
    census_r = census(grey_r, scratch.take("census_r", h * w, 1, np.uint64).reshape(h, w))
    lap("census")
    cost = scratch.take("cost", labels, 1).reshape(labels)
    band_cost(census_l, census_r, lo, count, start, points, finite,
              np.zeros((h, w), np.float32) if certain is None else certain,
              config.k, config.c, config.net_weight, cost)
    lap("cost")
    steps = np.maximum(np.arange(256), 1)
    penalties = np.maximum(config.p1, config.p2 // steps).astype(np.float32)
    totals = scratch.take("totals", 2 * labels, 1).reshape(2, labels)
    aggregate(cost, lo, count, start, grey_l.astype(np.int32), np.float32(config.p1),
              penalties, config.paths == 8, totals)
    lap("aggregate")
    left_d = np.empty((h, w), np.float32)
    right_d = np.empty((h, w), np.float32)
    fallback = np.empty((h, w), np.float32)
    winners(totals, lo, count, start, config.uniqueness, finite, nearby, left_d, right_d,
            fallback)
    lap("winners")
    if config.median:  # a 3×3 median of both views' winners (the rejected: −1)
        left_d, right_d = cv2.medianBlur(left_d, 3), cv2.medianBlur(right_d, 3)
    out = np.empty((h, w), np.float32)
    _checked_choice(left_d, right_d, fallback if config.choose_fallback else finite,
                    np.float32(config.lr_max), out)
    out[~known] = prior[~known]
    lap("check")
    # moved by more than a pixel (NaN, where the prior is not finite, compares false): what the
    # band corrected, not its parabola's sub-pixel steps, which touch most refined pixels
    return out, int(np.count_nonzero(np.abs(out - finite) > 1.0))


@numba.njit(cache=True, parallel=True)
def _inputs(left: np.ndarray, right: np.ndarray, prior: np.ndarray, sparse: np.ndarray,
            confidence: np.ndarray, grey_l: np.ndarray, grey_r: np.ndarray,
            finite: np.ndarray, points: np.ndarray, certain: np.ndarray) -> None:
    """`refine`'s inputs in one pass: the grey levels saturated to 0–255 and cut to uint8
    (NaN: 0), the prior with 0 where it is not finite, the LiDAR disparity with 0 where none
    (not finite or ≤ 0) and the confidence clipped to 0–1, NaN read as 0 (`confidence` (1, 1):
    none, `certain` untouched)."""
    h, w = prior.shape
    with_confidence = confidence.shape[0] == h and confidence.shape[1] == w
    for y in numba.prange(h):
        for x in range(w):
            a, b = left[y, x], right[y, x]
            grey_l[y, x] = np.uint8(min(max(a, 0), 255)) if a == a else 0
            grey_r[y, x] = np.uint8(min(max(b, 0), 255)) if b == b else 0
            d, g = prior[y, x], sparse[y, x]
            finite[y, x] = d if np.isfinite(d) else 0.0
            points[y, x] = g if np.isfinite(g) and g > 0 else 0.0
            if with_confidence:
                c = confidence[y, x]
                certain[y, x] = min(max(c, 0.0), 1.0) if c == c else 0.0


def _check_shapes(shape: tuple[int, ...], **images: np.ndarray | None) -> None:
    """The kernels index every image by the prior's shape: each given one must have it."""
    for name, image in images.items():
        if image is not None and np.shape(image) != shape:
            raise InvalidDataError(f"band refinement: {name}", f"the prior's shape {shape}",
                                   np.shape(image))


class _Laps:
    """`lap(name)`: the time since the last lap added to `parts_ms[name]` (if kept)."""

    def __init__(self, parts_ms: dict[str, float] | None) -> None:
        self.parts_ms = parts_ms
        self.t = time.perf_counter()

    def __call__(self, name: str) -> None:
        if self.parts_ms is not None:
            now = time.perf_counter()
            self.parts_ms[name] = self.parts_ms.get(name, 0.0) + (now - self.t) * 1000
            self.t = now


def _bands(prior: np.ndarray, confidence: np.ndarray | None, points: np.ndarray,
           config: BandSgmConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each pixel's band (its first disparity `lo` ≥ 0 and its label `count` 1 … MAX_LABELS,
    0 where the pixel is not refined: `refine_below`), the ragged volume's offsets `start`
    (H·W + 1) and the nearest LiDAR point's value within `lidar_reach` px (0: none)."""
    h, w = prior.shape
    half = band_half_widths(confidence, prior.shape, config)
    nearby = np.zeros((h, w), np.float32)
    if config.lidar_reach > 0:  # the band spans the nearest point's value too
        nearest_within(points, np.float32(config.lidar_reach), nearby)
    if confidence is not None and config.refine_below < 1.0:  # the sure pixels keep theirs
        unsure = (confidence < config.refine_below).astype(np.uint8)
        side = 2 * config.refine_margin_px + 1
        refined = cv2.dilate(unsure, np.ones((side, side), np.uint8))
    else:
        refined = np.ones((1, 1), np.uint8)
    lo = np.empty((h, w), np.int32)
    count = np.empty((h, w), np.int32)
    _band_limits(prior, half, nearby, refined, lo, count)
    start = np.empty(count.size + 1, np.int64)
    start[0] = 0
    np.cumsum(count, out=start[1:])
    return lo, count, start, nearby


@numba.njit(cache=True, parallel=True)
def _band_limits(prior: np.ndarray, half: np.ndarray, nearby: np.ndarray,
                 refined: np.ndarray, lo: np.ndarray, count: np.ndarray) -> None:
    """`_bands`' per-pixel part in one pass: the band around the prior (clipped to the image)
    ± `half`, widened to the nearest point's value `nearby` (0: none within reach), its labels
    1 … MAX_LABELS, 0 where not `refined` (another shape than the prior's: every pixel is)."""
    h, w = prior.shape
    every = refined.shape != prior.shape
    for y in numba.prange(h):
        for x in range(w):
            centre = int(min(max(np.rint(prior[y, x]), 0), w - 1))
            first, last = max(centre - half[y, x], 0), centre + half[y, x]
            if nearby[y, x] > 0:
                g = int(min(max(np.rint(nearby[y, x]), 0), w - 1))
                first, last = min(first, max(g - 1, 0)), max(last, g + 1)
            lo[y, x] = first
            count[y, x] = min(max(last - first + 1, 1), MAX_LABELS) \
                if every or refined[y, x] else 0


@numba.njit(cache=True, parallel=True)
def _checked_choice(left: np.ndarray, right: np.ndarray, fallback: np.ndarray,
                    lr_max: np.float32, out: np.ndarray) -> None:
    """Into `out`: the left winner (`left`, < 0 where rejected) where it agrees with the right
    view's (`right`) at x − round(d) within `lr_max`; `fallback` elsewhere (Hirschmüller's
    check)."""
    h, w = left.shape
    for y in numba.prange(h):
        for x in range(w):
            d = left[y, x]
            out[y, x] = fallback[y, x]
            if d < 0:
                continue
            xr = x - int(np.rint(d))
            if 0 <= xr < w and abs(d - right[y, xr]) <= lr_max:
                out[y, x] = d
