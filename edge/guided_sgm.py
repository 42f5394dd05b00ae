"""LiDAR-guided semi-global matching: the classical anchor the engine is judged against.

The stages, each a function below:

1. Matching cost: census transform over a 9×7 window (62 bits: "neighbour darker than the
   centre"), cost = Hamming distance between the left pixel's and the right pixel's bit
   strings at each disparity; `(H, W, D)` int16, 0–62.
2. Guidance (Poggi et al., "Guided Stereo Matching", CVPR 2019, the cost-volume form for
   SGM): at each pixel with a LiDAR disparity g the cost is multiplied by
   `1 − v + v·k·(1 − exp(−(d − g)² / (2c²)))` with v = 1 there (0 elsewhere): the inverted
   Gaussian of the paper's feature enhancement, since SGM minimises a cost. It drives the
   cost at d = g to 0 and multiplies it by up to k away from g.
3. Aggregation (Hirschmüller, PAMI 2008, eq. 13): 8 paths, each
   `L_r(p, d) = C(p, d) + min(L_r(p−r, d), L_r(p−r, d±1) + P1, min_i L_r(p−r, i) + P2)
   − min_i L_r(p−r, i)`, with the adaptive `P2 = max(P1, P2' / |I(p) − I(p−r)|)` (section
   III-C); S = the sum over paths.
4. Winner-take-all on S, the parabola through the minimum and its neighbours for the
   sub-pixel part, a 3×3 median, and the left–right check: the right view's disparity is the
   minimum of S along the diagonal (section III-D's cheap variant, no second matching), and a
   pixel whose two disparities differ by more than 1 px is a hole (0).

The constants are the papers' standard ones, nothing fitted to the pairs this project scores:
P1 = 10 and P2' = 120 (census costs, Hirschmüller's grey-level step P2), k = 10 and c = 1 px
(Poggi et al.'s values for SGM), LR tolerance 1 px. Pure numpy (OpenCV only for the median):
every path step is one vectorised update of a whole image row or column across all
disparities. What it does not do: no segmentation or plane fitting of the holes (the callers
fill them: `fill_row_nearest` without LiDAR, the LiDAR value and the nearest point with it).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from edge_depth.baselines import fill_row_nearest, nearest_point


@dataclass(frozen=True)
class GuidedSgmConfig:
    """The method's constants (defaults: the papers' values)."""

    num_disparities: int = 64  # disparities searched: 0 … num_disparities − 1 (px)
    census_width: int = 9  # census window (px), odd
    census_height: int = 7  # census window (px), odd
    p1: int = 10  # penalty for a 1 px disparity change along a path (census units)
    p2: int = 120  # penalty for larger changes, divided by the path's grey-level step
    k: float = 10.0  # Poggi et al.'s Gaussian height: the cost factor far from the LiDAR value
    c: float = 1.0  # Poggi et al.'s Gaussian width (px)
    lr_max_diff: float = 1.0  # left–right check tolerance (px)

    def __post_init__(self) -> None:
        if self.num_disparities < 2:
            raise ValueError(f"num_disparities must be ≥ 2, got {self.num_disparities}")
        if self.census_width % 2 == 0 or self.census_height % 2 == 0:
            raise ValueError("the census window's sides must be odd, got "
                             f"{self.census_width}×{self.census_height}")
        if self.census_width * self.census_height - 1 > 64:
            raise ValueError("the census window must hold at most 64 neighbours")
        if not 0 < self.p1 <= self.p2:
            raise ValueError(f"need 0 < p1 <= p2, got p1={self.p1}, p2={self.p2}")
        if self.k < 1 or self.c <= 0 or self.lr_max_diff < 0:
            raise ValueError(f"need k ≥ 1, c > 0, lr_max_diff ≥ 0; got k={self.k}, "
                             f"c={self.c}, lr_max_diff={self.lr_max_diff}")


def census(grey: np.ndarray, width: int = 9, height: int = 7) -> np.ndarray:
    """Census transform of an (H, W) grey image over a `width`×`height` window: one bit per
    neighbour, set where the neighbour is darker than the centre; (H, W) uint64. The border
    is replicated."""
    image = np.asarray(grey, np.float32)
    h, w = image.shape
    ry, rx = height // 2, width // 2
    padded = np.pad(image, ((ry, ry), (rx, rx)), mode="edge")
    bits = np.zeros((h, w), np.uint64)
    for dy in range(-ry, ry + 1):
        for dx in range(-rx, rx + 1):
            if dy == 0 and dx == 0:
                continue
            neighbour = padded[ry + dy:ry + dy + h, rx + dx:rx + dx + w]
            bits = (bits << np.uint64(1)) | (neighbour < image).astype(np.uint64)
    return bits


def census_cost(left: np.ndarray, right: np.ndarray, config: GuidedSgmConfig) -> np.ndarray:
    """Hamming distance between the census strings of left pixel (y, x) and right pixel
    (y, x − d): (H, W, D) int16. Where x − d leaves the image the cost is the window's
    maximum (no evidence either way is weaker than the worst match)."""
    cl = census(left, config.census_width, config.census_height)
    cr = census(right, config.census_width, config.census_height)
    h, w = cl.shape
    worst = config.census_width * config.census_height - 1
    cost = np.full((h, w, config.num_disparities), worst, np.int16)
    for d in range(min(config.num_disparities, w)):
        cost[:, d:, d] = np.bitwise_count(cl[:, d:] ^ cr[:, :w - d])
    return cost


def guide_cost(cost: np.ndarray, sparse: np.ndarray, config: GuidedSgmConfig) -> np.ndarray:
    """Poggi et al.'s modulation at the pixels with a LiDAR disparity (`sparse` > 0, px):
    C·(1 − v + v·k·(1 − exp(−(d − g)² / (2c²)))) with v = 1 there; other pixels unchanged.
    Returns a new (H, W, D) int16 volume."""
    guided = cost.copy()
    ys, xs = np.nonzero(sparse > 0)
    if len(ys) == 0:
        return guided
    d = np.arange(cost.shape[2], dtype=np.float32)[None, :]
    g = sparse[ys, xs].astype(np.float32)[:, None]
    factor = config.k * (1.0 - np.exp(-(d - g) ** 2 / (2.0 * config.c ** 2)))
    guided[ys, xs] = np.rint(cost[ys, xs] * factor).astype(np.int16)
    return guided


def _penalties(grey: np.ndarray, dx: int, config: GuidedSgmConfig) -> np.ndarray:
    """Hirschmüller's adaptive P2 for the path arriving at (y, x) from (y − 1, x − dx):
    max(P1, P2' / |I(p) − I(p − r)|), P2' where the step is 0; (H, W, 1) int16 (row 0 and
    the columns the path enters at hold P2', unused)."""
    image = np.asarray(grey, np.int32)
    previous = np.roll(image, (1, dx), axis=(0, 1))
    step = np.maximum(np.abs(image - previous), 1)
    return np.maximum(config.p1, config.p2 // step).astype(np.int16)[..., None]


def _aggregate_down(cost: np.ndarray, grey: np.ndarray, dx: int, config: GuidedSgmConfig,
                    total: np.ndarray) -> None:
    """Add to `total` (H, W, D) int16 the path costs L_r for the direction r = (1, dx):
    top to bottom, each pixel following (y − 1, x − dx); one vectorised update per row."""
    h, w, _ = cost.shape
    p2 = _penalties(grey, dx, config)
    p1 = np.int16(config.p1)
    previous = cost[0].copy()
    total[0] += previous
    arriving = np.zeros_like(previous)  # L_r(p − r, ·); 0 where the path enters the image
    for y in range(1, h):
        arriving[:] = 0
        if dx == 0:
            arriving[:] = previous
        elif dx > 0:
            arriving[1:] = previous[:-1]
        else:
            arriving[:-1] = previous[1:]
        floor = arriving.min(axis=1, keepdims=True)
        best = np.minimum(arriving, floor + p2[y])
        np.minimum(best[:, 1:], arriving[:, :-1] + p1, out=best[:, 1:])
        np.minimum(best[:, :-1], arriving[:, 1:] + p1, out=best[:, :-1])
        previous = cost[y] + best - floor
        total[y] += previous


def aggregate(cost: np.ndarray, grey: np.ndarray, config: GuidedSgmConfig) -> np.ndarray:
    """S = Σ over 8 paths of L_r (Hirschmüller eq. 13–14): (H, W, D) int16. `grey` (H, W) is
    the left image the adaptive P2 reads."""
    total = np.zeros_like(cost)
    flipped_total = np.zeros_like(cost)
    for dx in (-1, 0, 1):  # down-left, down, down-right
        _aggregate_down(cost, grey, dx, config, total)
        _aggregate_down(cost[::-1], grey[::-1], dx, config, flipped_total)  # the upward three
    total += flipped_total[::-1]
    # left-to-right and right-to-left: the same recurrence on the transposed volume
    cost_t = np.ascontiguousarray(cost.transpose(1, 0, 2))
    grey_t = np.ascontiguousarray(grey.T)
    across = np.zeros_like(cost_t)
    flipped_across = np.zeros_like(cost_t)
    _aggregate_down(cost_t, grey_t, 0, config, across)
    _aggregate_down(cost_t[::-1], grey_t[::-1], 0, config, flipped_across)
    across += flipped_across[::-1]
    total += across.transpose(1, 0, 2)
    return total


def winner_subpixel(total: np.ndarray) -> np.ndarray:
    """Winner-take-all over the disparities with the parabola through the minimum and its two
    neighbours (none at the range's ends): (H, W) float32, px."""
    best = np.argmin(total, axis=2)
    d = total.shape[2]
    inner = np.clip(best, 1, d - 2)
    at = np.take_along_axis
    s = total.astype(np.float32)
    lo = at(s, (inner - 1)[..., None], 2)[..., 0]
    mid = at(s, inner[..., None], 2)[..., 0]
    hi = at(s, (inner + 1)[..., None], 2)[..., 0]
    curvature = lo - 2 * mid + hi
    offset = np.where(curvature > 0, (lo - hi) / (2 * np.maximum(curvature, 1e-6)), 0.0)
    offset = np.where((best == inner), offset, 0.0)
    return (best + offset).astype(np.float32)


def right_disparity(total: np.ndarray) -> np.ndarray:
    """The right view's integer disparity from the left's S: right pixel x matches left pixel
    x + d, so its cost at d is S(x + d, d) (Hirschmüller section III-D); (H, W) float32."""
    h, w, d = total.shape
    diagonal = np.full_like(total, np.iinfo(total.dtype).max)
    for disparity in range(min(d, w)):
        diagonal[:, :w - disparity, disparity] = total[:, disparity:, disparity]
    return np.argmin(diagonal, axis=2).astype(np.float32)


def left_right_check(left_disp: np.ndarray, right_disp: np.ndarray,
                     max_diff: float) -> np.ndarray:
    """`left_disp` with 0 where the right view's disparity at x − round(d) differs by more
    than `max_diff` px (or falls outside the image): (H, W) float32."""
    h, w = left_disp.shape
    xs = np.arange(w)[None, :] - np.rint(left_disp).astype(np.int64)
    inside = xs >= 0
    seen = np.take_along_axis(right_disp, np.clip(xs, 0, w - 1), axis=1)
    agree = inside & (np.abs(left_disp - seen) <= max_diff)
    return np.where(agree, left_disp, 0.0).astype(np.float32)


def guided_sgm(left: np.ndarray, right: np.ndarray, sparse: np.ndarray | None = None,
               config: GuidedSgmConfig | None = None) -> np.ndarray:
    """(Guided) census SGM on a rectified (H, W) uint8 grey pair: (H, W) float32 disparity of
    the left view in px, 0 where the left–right check rejects. `sparse` (H, W): LiDAR
    disparity in px, 0 where none; None or all 0 is plain census SGM."""
    config = config or GuidedSgmConfig()
    cost = census_cost(left, right, config)
    if sparse is not None:
        cost = guide_cost(cost, sparse, config)
    total = aggregate(cost, left, config)
    del cost
    disparity = cv2.medianBlur(winner_subpixel(total), 3)
    seen_right = cv2.medianBlur(right_disparity(total), 3)
    return left_right_check(disparity, seen_right, config.lr_max_diff)


def guided_sgm_filled(left: np.ndarray, right: np.ndarray,
                      config: GuidedSgmConfig | None = None) -> np.ndarray:
    """Census SGM without LiDAR, its holes taking the nearest valid pixel of the row:
    (H, W) float32, px."""
    return fill_row_nearest(guided_sgm(left, right, None, config))


def guided_sgm_lidar(left: np.ndarray, right: np.ndarray, sparse: np.ndarray,
                     config: GuidedSgmConfig | None = None) -> np.ndarray:
    """LiDAR-guided SGM with the LiDAR written in: the LiDAR value at its pixels, the guided
    match elsewhere, the nearest LiDAR point in the holes that remain: (H, W) float32, px.
    Without any LiDAR point this is `guided_sgm_filled`."""
    valid = sparse > 0
    if not valid.any():
        return guided_sgm_filled(left, right, config)
    disparity = guided_sgm(left, right, sparse, config)
    nearest, _ = nearest_point(sparse, valid)
    disparity = np.where(disparity > 0, disparity, nearest)
    return np.where(valid, sparse, disparity).astype(np.float32)
