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
check, the right view's disparity read from the left's sums) after a 3×3 median of both, and
differs from the estimate by more than `min_change` (the network's own 1 px); elsewhere the
estimate stays, or the nearest LiDAR point's value where the summed cost is lower there. Only
the pixels whose confidence is under `refine_below` (0.9), and those within
`refine_margin_px` of them, are refined; the paths start afresh after the others, which keep
the network's estimate (the aggregation's cost is per pixel: this halves it).

Constants are the papers' (census 9×7, P1 = 10, P2' = 120, k = 10, c = 1 px, check 1 px);
the band's widths, the Laplace weight, the reach and the rest are this stage's own, chosen on
the published pairs and the rig's test split and judged on variants of the pairs it was not
chosen on (docs/experiments.md, 2026-12-07). Compiled with numba: the downward and the upward
paths on two threads, float32 costs, loops written to run in SIMD lanes (`_step`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np

from edge_depth.baselines import nearest_point

CENSUS_W, CENSUS_H = 9, 7
WORST = CENSUS_W * CENSUS_H - 1  # the census cost where the right pixel leaves the image
BIG = 1e6  # beyond any path cost: the labels a neighbour does not have
BIG32 = np.float32(BIG)
MAX_LABELS = 257  # a band's labels at most (the network's and the LiDAR's values far apart)


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
    min_change: float = 1.0  # px: the prior stays where the match is this close to it
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


def census(grey: np.ndarray) -> np.ndarray:
    """The 9×7 census of an (H, W) uint8 image: bit set where the neighbour is darker than
    the centre, border replicated; (H, W) uint64."""
    ry, rx = CENSUS_H // 2, CENSUS_W // 2
    return _census(np.pad(np.ascontiguousarray(grey, np.uint8), ((ry, ry), (rx, rx)),
                          mode="edge"))


@numba.njit(cache=True, parallel=True)
def _census(padded: np.ndarray) -> np.ndarray:
    """`census` of the image inside `padded` (its border CENSUS_H // 2 rows and
    CENSUS_W // 2 columns wide): one pass over a row per neighbour, in SIMD lanes."""
    ry, rx = CENSUS_H // 2, CENSUS_W // 2
    h, w = padded.shape[0] - 2 * ry, padded.shape[1] - 2 * rx
    out = np.zeros((h, w), np.uint64)
    one = np.uint64(1)
    for y in numba.prange(h):
        centre = padded[y + ry, rx:rx + w]
        bits = out[y]
        for dy in range(-ry, ry + 1):
            row = padded[y + ry + dy]
            for dx in range(-rx, rx + 1):
                if dy == 0 and dx == 0:
                    continue
                neighbour = row[rx + dx:rx + dx + w]
                for x in range(w):
                    bits[x] = (bits[x] << one) | np.uint64(neighbour[x] < centre[x])
    return out


@numba.njit(cache=True, inline="always")
def _popcount(v: np.uint64) -> int:
    v = v - ((v >> np.uint64(1)) & np.uint64(0x5555555555555555))
    v = (v & np.uint64(0x3333333333333333)) + ((v >> np.uint64(2)) & np.uint64(0x3333333333333333))
    v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return int((v * np.uint64(0x0101010101010101)) >> np.uint64(56))


@numba.njit(cache=True, parallel=True)
def band_cost(cl: np.ndarray, cr: np.ndarray, lo: np.ndarray, count: np.ndarray,
              start: np.ndarray, sparse: np.ndarray, prior: np.ndarray,
              confidence: np.ndarray, k: float, c: float, net_weight: float) -> np.ndarray:
    """The ragged cost volume, flat float32: pixel p's labels d = lo(p) … lo(p) + count(p) − 1
    at start(p) …: the census Hamming distance (WORST where x − d leaves the image), plus
    `net_weight` × the network's −log p(d) under its Laplace error model (`band_half_widths`),
    multiplied at LiDAR pixels (sparse > 0) by Poggi's inverted Gaussian."""
    h, w = cl.shape
    cost = np.empty(start[-1], np.float32)
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
    return cost


@numba.njit(cache=True, fastmath=True, inline="always")
def _step(before: np.ndarray, q: np.uint64, lo_q: np.uint64, n_q: np.uint64,
          floor: np.float32, jump: np.float32, p1: np.float32, cost: np.ndarray, c: np.uint64,
          lo_p: np.uint64, n_p: np.uint64, scratch: np.ndarray, out: np.ndarray,
          out_bits: np.ndarray, o: np.uint64, sums: np.ndarray, least: np.ndarray) -> None:
    """One pixel of one path: L(p, ·) from the previous pixel's L (`before[q:q + n_q]`, its
    labels from disparity lo_q, its minimum `floor`) and p's costs `cost[c:c + n_p]` (from
    disparity lo_p) into `out[o:o + n_p]`, added to `sums`; L(p)'s minimum into `least[0]`.

    Written so that each loop runs in SIMD lanes: the previous costs are laid into `scratch`
    by absolute disparity (BIG elsewhere: labels the previous pixel does not have), read there
    without a branch, and cleared again; every index is unsigned (numba tests signed ones for
    wrap-around); and the minimum is taken over the costs' bits as int32 (`out_bits`, the same
    memory: non-negative floats order as their bits), since numba's float minimum over a loop
    stays scalar."""
    pad = np.uint64(2)
    for j in range(n_q):
        scratch[lo_q + pad + j] = before[q + j]
    a = lo_p + pad
    one = np.uint64(1)
    for i in range(n_p):
        near = min(scratch[a + i - one], scratch[a + i + one]) + p1
        value = cost[c + i] + min(min(scratch[a + i], near), jump) - floor
        out[o + i] = value
        sums[i] += value
    for j in range(n_q):
        scratch[lo_q + pad + j] = BIG
    bits = out_bits[o]
    for i in range(n_p):
        bits = min(bits, out_bits[o + i])
    least.view(np.int32)[0] = bits


@numba.njit(cache=True, fastmath=True)
def _paths(cost: np.ndarray, lo: np.ndarray, count: np.ndarray, start: np.ndarray,
           grey: np.ndarray, p1: np.float32, penalties: np.ndarray, down: bool,
           diagonals: bool, total: np.ndarray) -> None:
    """Four of the eight paths (two without the diagonals), row by row: down (top to bottom:
    the three arriving from the row above, and left to right along the row) or up (the
    mirror four); their sum written to `total` (ragged, as `cost`) once per pixel. Only the
    last row's path costs are kept, each pixel's at its offset within its row.
    `penalties[g]`: P2 at a grey-level step g."""
    h, w = lo.shape
    dy, dx_row = (1, 1) if down else (-1, -1)
    widest = 0
    for y in range(h):
        widest = max(widest, start[(y + 1) * w] - start[y * w])
    before = np.empty(3 * widest, np.float32)
    now = np.empty(3 * widest, np.float32)
    before_bits, now_bits = before.view(np.int32), now.view(np.int32)
    floor_before = np.zeros((3, w), np.float32)
    floor_now = np.zeros((3, w), np.float32)
    along = np.empty(count.max(), np.float32)
    along_bits = along.view(np.int32)
    sums = np.empty(count.max(), np.float32)
    scratch = np.full(lo.max() + count.max() + 4, BIG, np.float32)
    least = np.empty(1, np.float32)
    zero = np.uint64(0)
    for step in range(h):
        y = step if down else h - 1 - step
        row = start[y * w]
        row_before = start[(y - dy) * w] if 0 <= y - dy < h else 0
        along_floor = BIG32
        for visit in range(w):
            x = visit if down else w - 1 - visit
            p = y * w + x
            if count[y, x] == 0:  # not refined: the paths through it start again after it
                continue
            n_p, lo_p, c = np.uint64(count[y, x]), np.uint64(lo[y, x]), np.uint64(start[p])
            o = np.uint64(start[p] - row)
            for i in range(n_p):
                sums[i] = 0.0
            px = x - dx_row
            if visit == 0 or count[y, px] == 0:
                along_floor = BIG32
                for i in range(n_p):
                    along[i] = cost[c + i]
                    sums[i] += cost[c + i]
                    along_floor = min(along_floor, cost[c + i])
            else:
                jump = along_floor + penalties[abs(grey[y, x] - grey[y, px])]
                _step(along, zero, np.uint64(lo[y, px]), np.uint64(count[y, px]), along_floor,
                      jump, p1, cost, c, lo_p, n_p, scratch, along, along_bits, zero, sums,
                      least)
                along_floor = least[0]
            for k in range(0 if diagonals else 1, 3 if diagonals else 2):
                px, py = x - (k - 1), y - dy
                ko = np.uint64(k * widest) + o
                if step == 0 or px < 0 or px >= w or count[py, px] == 0:
                    lowest = BIG32
                    for i in range(n_p):
                        now[ko + i] = cost[c + i]
                        sums[i] += cost[c + i]
                        lowest = min(lowest, cost[c + i])
                    floor_now[k, x] = lowest
                else:
                    q = np.uint64(k * widest + start[py * w + px] - row_before)
                    floor = floor_before[k, px]
                    jump = floor + penalties[abs(grey[y, x] - grey[py, px])]
                    _step(before, q, np.uint64(lo[py, px]), np.uint64(count[py, px]), floor,
                          jump, p1, cost, c, lo_p, n_p, scratch, now, now_bits, ko, sums,
                          least)
                    floor_now[k, x] = least[0]
            for i in range(n_p):
                total[c + i] = sums[i]
        before, now = now, before
        before_bits, now_bits = now_bits, before_bits
        floor_before, floor_now = floor_now, floor_before


@numba.njit(cache=True, parallel=True)
def aggregate(cost: np.ndarray, lo: np.ndarray, count: np.ndarray, start: np.ndarray,
              grey: np.ndarray, p1: np.float32, penalties: np.ndarray,
              diagonals: bool = True) -> np.ndarray:
    """S over the 8 paths as two partial sums (2, labels) float32, ragged as `cost`: the four
    down paths and the four up paths, each on its own thread."""
    totals = np.empty((2, cost.shape[0]), np.float32)
    for half in numba.prange(2):
        _paths(cost, lo, count, start, grey, p1, penalties, half == 0, diagonals,
               totals[half])
    return totals


@numba.njit(cache=True, parallel=True)
def winners(totals: np.ndarray, lo: np.ndarray, count: np.ndarray, start: np.ndarray,
            uniqueness: int, prior: np.ndarray, near: np.ndarray, left: np.ndarray,
            right: np.ndarray, fallback: np.ndarray) -> None:
    """The left view's winner of S (the two partial sums, added into `totals[0]`) with the
    parabola's sub-pixel step (`left`, NaN where it sits on the band's edge — the match lies
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
                left[y, x] = np.nan
                continue
            i_prior, i_near = int(np.rint(prior[y, x])) - first, int(np.rint(near[y, x])) - first
            if near[y, x] > 0 and 0 <= i_near < n and 0 <= i_prior < n and \
                    total[s + i_near] < total[s + i_prior]:
                fallback[y, x] = near[y, x]
            for i in range(min(n, x - first + 1)):  # the labels whose right pixel is inside
                if total[s + i] < right_cost[x - first - i]:
                    right_cost[x - first - i] = total[s + i]
                    right[y, x - first - i] = first + i
            lowest = order[s]  # the minimum over the bits: a loop in SIMD lanes (`_step`)
            for i in range(1, n):
                lowest = min(lowest, order[s + i])
            best = 0
            while order[s + best] != lowest:
                best += 1
            low = total[s + best]
            if best == 0 or best == n - 1:
                left[y, x] = np.nan
                continue
            if uniqueness > 0:
                second = np.inf
                for i in range(n):
                    if abs(i - best) > 1:
                        second = min(second, total[s + i])
                if low * (100 + uniqueness) >= second * 100:
                    left[y, x] = np.nan
                    continue
            before, after = total[s + best - 1], total[s + best + 1]
            curvature = before - 2 * low + after
            offset = 0.0 if curvature <= 0 else (before - after) / (2.0 * curvature)
            left[y, x] = first + best + offset


def checked(left: np.ndarray, right: np.ndarray, lr_max: float) -> np.ndarray:
    """Where the left winner agrees with the right view's at x − round(d) within `lr_max`."""
    h, w = left.shape
    finite = np.isfinite(left)
    xs = np.arange(w)[None, :] - np.rint(np.where(finite, left, 0)).astype(np.int64)
    inside = finite & (xs >= 0) & (xs < w)
    seen = np.take_along_axis(right, np.clip(xs, 0, w - 1), axis=1)
    return inside & (np.abs(left - seen) <= lr_max)


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
    c = np.clip(confidence, 0.0, 1.0 - 1e-6)
    if config.quantile > 0:
        width = np.log(1.0 / (1.0 - config.quantile)) / -np.log1p(-c)
        return np.clip(np.ceil(width), config.min_band, config.max_band).astype(np.int32)
    spread = config.max_band - config.min_band
    return (config.min_band + np.rint(spread * (1.0 - c))).astype(np.int32)


def refine(left: np.ndarray, right: np.ndarray, prior: np.ndarray,
           confidence: np.ndarray | None, sparse: np.ndarray,
           config: BandSgmConfig | None = None) -> tuple[np.ndarray, int]:
    """The prior (H, W) float32 px refined by SGM in its band: (disparity, pixels changed).
    `left`, `right` rectified grey (uint8 or float 0-255); `confidence` 0-1 (NaN read as 0;
    None: every band its widest, no error model); `sparse` LiDAR disparity, 0 = none. Pixels
    whose prior is not finite keep it; a negative prior is searched from 0."""
    config = config or BandSgmConfig()
    h, w = prior.shape
    grey_l = np.ascontiguousarray(np.clip(left, 0, 255).astype(np.uint8))
    grey_r = np.ascontiguousarray(np.clip(right, 0, 255).astype(np.uint8))
    known = np.isfinite(prior)
    finite = np.ascontiguousarray(np.where(known, prior, 0.0), np.float32)
    certain = None if confidence is None else np.ascontiguousarray(
        np.clip(np.nan_to_num(confidence, nan=0.0), 0.0, 1.0), np.float32)
    points = np.ascontiguousarray(np.where(np.isfinite(sparse) & (sparse > 0), sparse, 0.0),
                                  np.float32)  # LiDAR disparity, 0 where none
    lo, count, start, nearby = _bands(finite, certain, points, config)
    cost = band_cost(census(grey_l), census(grey_r), lo, count, start, points, finite,
                     np.zeros((h, w), np.float32) if certain is None else certain,
                     config.k, config.c, config.net_weight)
    steps = np.maximum(np.arange(256), 1)
    penalties = np.maximum(config.p1, config.p2 // steps).astype(np.float32)
    totals = aggregate(cost, lo, count, start, grey_l.astype(np.int32), np.float32(config.p1),
                       penalties, config.paths == 8)
    left_d = np.empty((h, w), np.float32)
    right_d = np.empty((h, w), np.float32)
    fallback = np.empty((h, w), np.float32)
    winners(totals, lo, count, start, config.uniqueness, finite, nearby, left_d, right_d,
            fallback)
    if not config.choose_fallback:
        fallback = finite
    if config.median:  # OpenCV's median has no notion of NaN: the rejected as -1, then again
        left_d = cv2.medianBlur(np.nan_to_num(left_d, nan=-1.0), 3)
        left_d[left_d < 0] = np.nan
        right_d = cv2.medianBlur(right_d, 3)
    keep = checked(left_d, right_d, config.lr_max)
    keep &= np.abs(left_d - finite) > config.min_change
    out = np.where(keep, left_d, fallback).astype(np.float32)
    out[~known] = prior[~known]
    return out, int(np.count_nonzero(out[known] != finite[known]))


def _bands(prior: np.ndarray, confidence: np.ndarray | None, points: np.ndarray,
           config: BandSgmConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each pixel's band (its first disparity `lo` ≥ 0 and its label `count` 1 … MAX_LABELS,
    0 where the pixel is not refined: `refine_below`), the ragged volume's offsets `start`
    (H·W + 1) and the nearest LiDAR point's value within `lidar_reach` px (0: none)."""
    h, w = prior.shape
    half = band_half_widths(confidence, prior.shape, config)
    centre = np.clip(np.rint(prior), 0, w - 1).astype(np.int32)
    lo = np.maximum(centre - half, 0)
    hi = centre + half
    valid = points > 0
    nearby = np.zeros(prior.shape, np.float32)
    if config.lidar_reach > 0 and valid.any():  # the band spans the nearest point's value too
        near, distance = nearest_point(points, valid)
        close = distance <= config.lidar_reach
        nearby = np.where(close, near, 0.0).astype(np.float32)
        g = np.clip(np.rint(near), 0, w - 1).astype(np.int32)
        lo = np.where(close, np.minimum(lo, np.maximum(g - 1, 0)), lo)
        hi = np.where(close, np.maximum(hi, g + 1), hi)
    count = np.clip(hi - lo + 1, 1, MAX_LABELS).astype(np.int32)
    if confidence is not None and config.refine_below < 1.0:  # the sure pixels keep theirs
        unsure = (confidence < config.refine_below).astype(np.uint8)
        side = 2 * config.refine_margin_px + 1
        unsure = cv2.dilate(unsure, np.ones((side, side), np.uint8))
        count[unsure == 0] = 0
    start = np.zeros(count.size + 1, np.int64)
    np.cumsum(count, out=start[1:])
    return lo.astype(np.int32), count, start, nearby
