"""The band refinement's aggregation (`edge.runtime.band_sgm`): Hirschmüller's paths over a
ragged cost volume, each pixel with labels of its own,

    L_r(p, d) = C(p, d) + min(L_r(p−r, d), L_r(p−r, d±1) + P1, min_i L_r(p−r, i) + P2)
                − min_i L_r(p−r, i),

a neighbour's label matched to this pixel's by their absolute disparity (one it does not have
counts as BIG). numba, the downward and the upward paths on two threads, loops written to run
in SIMD lanes (`_step`).
"""

from __future__ import annotations

import numba
import numpy as np

BIG = 1e6  # beyond any path cost: the labels a neighbour does not have
BIG32 = np.float32(BIG)


def _make_step(summed: bool):
    """`_step` (summed: each label's path cost also added to the running sum of the pixel's
    paths) or `_step_alone` (the first path: only its own costs)."""

    @numba.njit(fastmath=True, inline="always")
    def step(before: np.ndarray, q: np.uint64, lo_q: np.uint64, n_q: np.uint64,
             floor: np.float32, jump: np.float32, p1: np.float32, cost: np.ndarray,
             c: np.uint64, lo_p: np.uint64, n_p: np.uint64, out: np.ndarray, o: np.uint64,
             total: np.ndarray, partner: np.ndarray, po: np.uint64) -> np.float32:
        """One pixel of one path: L(p, ·) from the previous pixel's L (`before[q:q + n_q]`,
        its labels from disparity lo_q, its minimum `floor`) and p's costs `cost[c:c + n_p]`
        (from disparity lo_p) into `out[o:o + n_p]` and, summed, `total[c + i]` = L(p, i) +
        `partner[po + i]` (the pixel's paths before this one); returns L(p)'s minimum.

        p's label i is the previous pixel's label j = i + lo_p − lo_q. Where j − 1 … j + 1
        are all the previous pixel's, the loop reads them at a fixed offset and runs in SIMD
        lanes; the few labels beyond (a band's ends, or bands apart) are read one by one, a
        label the previous pixel does not have counting as BIG. Every index in the SIMD loop
        is unsigned (numba tests signed ones for wrap-around; the offset's wrap-around
        cancels in the sum). No per-pixel buffer is laid out, cleared or copied: at ~30
        labels a pixel, each loop's set-up costs about as much as its labels."""
        # signed (numba's int() of an unsigned stays unsigned)
        shift = int(np.int64(lo_p) - np.int64(lo_q))  # j = i + shift
        labels_q, labels_p = int(np.int64(n_q)), int(np.int64(n_p))
        first = min(max(1 - shift, 0), labels_p)  # the labels whose j ± 1 are all inside
        last = max(min(labels_q - 1 - shift, labels_p), first)
        base = q + np.uint64(shift)  # before[base + i] is label j's (mod 2^64)
        one = np.uint64(1)
        for i in range(np.uint64(first), np.uint64(last)):
            near = min(before[base + i - one], before[base + i + one]) + p1
            value = cost[c + i] + min(min(before[base + i], near), jump) - floor
            out[o + i] = value
            if summed:
                total[c + i] = value + partner[po + i]
        for k in range(first + labels_p - last):  # the labels at and beyond the bands' ends
            i = k if k < first else last + k - first
            j = i + shift
            near = BIG32
            here = BIG32
            if 0 <= j < labels_q:
                here = before[q + np.uint64(j)]
            if 1 <= j <= labels_q:
                near = before[q + np.uint64(j - 1)]
            if -1 <= j < labels_q - 1:
                near = min(near, before[q + np.uint64(j + 1)])
            u = np.uint64(i)
            value = cost[c + u] + min(min(here, near + p1), jump) - floor
            out[o + u] = value
            if summed:
                total[c + u] = value + partner[po + u]
        # the minimum over the costs' bits as int32 (non-negative floats order as their
        # bits): numba's float minimum over a loop stays scalar
        bits = out.view(np.int32)
        lowest = bits[o]
        for i in range(n_p):
            lowest = min(lowest, bits[o + i])
        return np.int32(lowest).view(np.float32)

    return step


_step = _make_step(True)
_step_alone = _make_step(False)


@numba.njit(fastmath=True, inline="always")
def _fresh(cost: np.ndarray, c: np.uint64, n_p: np.uint64, out: np.ndarray, o: np.uint64,
           total: np.ndarray, partner: np.ndarray, po: np.uint64, summed: bool) -> np.float32:
    """A path that starts at this pixel: L(p, ·) = its costs into `out[o:]` and, `summed`,
    `total[c + i]` = its cost + `partner[po + i]`; returns their minimum."""
    lowest = BIG32
    for i in range(n_p):
        out[o + i] = cost[c + i]
        lowest = min(lowest, cost[c + i])
    if summed:
        for i in range(n_p):
            total[c + i] = cost[c + i] + partner[po + i]
    return lowest


@numba.njit(cache=True, fastmath=True)
def _paths(cost: np.ndarray, lo: np.ndarray, count: np.ndarray, start: np.ndarray,
           grey: np.ndarray, p1: np.float32, penalties: np.ndarray, down: bool,
           diagonals: bool, total: np.ndarray) -> None:
    """Four of the eight paths (two without the diagonals), row by row: down (top to bottom:
    the three arriving from the row above, and left to right along the row) or up (the
    mirror four); their sum written to `total` (ragged, as `cost`): the path along the row
    first, then each from the row above adding its own. Only the last row's path costs are
    kept, each pixel's at its offset within its row. `penalties[g]`: P2 at a grey-level
    step g."""
    h, w = lo.shape
    dy, dx_row = (1, 1) if down else (-1, -1)
    widest = 0
    for y in range(h):
        widest = max(widest, start[(y + 1) * w] - start[y * w])
    before = np.empty(3 * widest, np.float32)
    now = np.empty(3 * widest, np.float32)
    floor_before = np.zeros((3, w), np.float32)
    floor_now = np.zeros((3, w), np.float32)
    along = np.empty(count.max(), np.float32)  # the previous pixel's along the row
    along_next = np.empty(count.max(), np.float32)
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
            px = x - dx_row
            if visit == 0 or count[y, px] == 0:
                along_floor = _fresh(cost, c, n_p, along_next, zero, total, along, zero,
                                     False)
            else:
                jump = along_floor + penalties[abs(grey[y, x] - grey[y, px])]
                along_floor = _step_alone(along, zero, np.uint64(lo[y, px]),
                                          np.uint64(count[y, px]), along_floor, jump, p1,
                                          cost, c, lo_p, n_p, along_next, zero, total, along,
                                          zero)
            along, along_next = along_next, along  # `along`: this pixel's, the sum's start
            partner, po = along, zero
            for k in range(0 if diagonals else 1, 3 if diagonals else 2):
                px, py = x - (k - 1), y - dy
                ko = np.uint64(k * widest) + o
                if step == 0 or px < 0 or px >= w or count[py, px] == 0:
                    floor_now[k, x] = _fresh(cost, c, n_p, now, ko, total, partner, po, True)
                else:
                    q = np.uint64(k * widest + start[py * w + px] - row_before)
                    floor = floor_before[k, px]
                    jump = floor + penalties[abs(grey[y, x] - grey[py, px])]
                    floor_now[k, x] = _step(before, q, np.uint64(lo[py, px]),
                                            np.uint64(count[py, px]), floor, jump, p1, cost,
                                            c, lo_p, n_p, now, ko, total, partner, po)
                partner, po = total, c
        before, now = now, before
        floor_before, floor_now = floor_now, floor_before


@numba.njit(cache=True, parallel=True)
def aggregate(cost: np.ndarray, lo: np.ndarray, count: np.ndarray, start: np.ndarray,
              grey: np.ndarray, p1: np.float32, penalties: np.ndarray,
              diagonals: bool, totals: np.ndarray) -> None:
    """S over the 8 paths as two partial sums into `totals` (2, ≥ labels) float32, ragged as
    `cost`: the four down paths and the four up paths, each on its own thread."""
    for half in numba.prange(2):
        _paths(cost, lo, count, start, grey, p1, penalties, half == 0, diagonals,
               totals[half])
