"""The nearest LiDAR point within reach of each pixel, exact (Euclidean): the band
refinement (`edge.runtime.band_sgm`) widens each pixel's band to that point's disparity. A
compiled kernel (numba) whose work grows with the points, not with the image."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, parallel=True)
def nearest_within(points: np.ndarray, reach: np.float32, nearby: np.ndarray) -> None:
    """Into `nearby` (zeroed): the value of each pixel's nearest point (`points` > 0) within
    `reach` px, Euclidean, exact (a tie: the upper row's, then the left one's). Each image row
    looks at the rows of points within reach, upper first: a row of few points by its points,
    each over the columns within reach of it; a row of many (a scan line: more points than
    w / (2r + 1)) by one pass along the image row with each column's nearest point of that row
    to its left and to its right, found once per row of points. The work grows with the
    points, never beyond a pass per row within reach."""
    h, w = points.shape
    span = int(reach)
    rows = np.zeros(h + 1, np.int64)  # the points' columns, row by row (CSR)
    dense = np.full(h, -1, np.int64)  # a dense row's index into left_of and right_of, or -1
    n_dense = 0
    for y in range(h):
        count = np.count_nonzero(points[y] > 0)
        rows[y + 1] = rows[y] + count
        if count * (2 * span + 1) > w:
            dense[y] = n_dense
            n_dense += 1
    columns = np.empty(rows[h], np.int64)
    # per dense row: each column's nearest point at or left of it, at or right of it (-1: none)
    left_of = np.empty((n_dense, w), np.int32)
    right_of = np.empty((n_dense, w), np.int32)
    for y in numba.prange(h):
        k = rows[y]
        for x in range(w):
            if points[y, x] > 0:
                columns[k] = x
                k += 1
        if dense[y] >= 0:
            _nearest_columns(points[y], left_of[dense[y]], right_of[dense[y]])
    limit = reach * reach
    for y in numba.prange(h):
        best = np.full(w, np.inf, np.float32)
        for yy in range(max(y - span, 0), min(y + span + 1, h)):
            dy2 = np.float32((yy - y) * (yy - y))
            if dense[yy] >= 0:
                _nearest_in_dense_row(points[yy], left_of[dense[yy]], right_of[dense[yy]],
                                      dy2, limit, best, nearby[y])
                continue
            for k in range(rows[yy], rows[yy + 1]):
                column = columns[k]
                for x in range(max(column - span, 0), min(column + span + 1, w)):
                    dx = np.float32(column - x)
                    d2 = dy2 + dx * dx
                    if d2 < best[x] and d2 <= limit:
                        best[x] = d2
                        nearby[y, x] = points[yy, column]


@numba.njit(cache=True, inline="always")
def _nearest_columns(row: np.ndarray, left_of: np.ndarray, right_of: np.ndarray) -> None:
    """Each column's nearest point (`row` > 0) at or left of it into `left_of`, at or right
    of it into `right_of` (-1 where none)."""
    w = row.shape[0]
    last = -1
    for x in range(w):
        if row[x] > 0:
            last = x
        left_of[x] = last
    last = -1
    for x in range(w - 1, -1, -1):
        if row[x] > 0:
            last = x
        right_of[x] = last


@numba.njit(cache=True, inline="always")
def _nearest_in_dense_row(row: np.ndarray, left_of: np.ndarray, right_of: np.ndarray,
                          dy2: np.float32, limit: np.float32, best: np.ndarray,
                          out: np.ndarray) -> None:
    """`nearest_within` for one image row and one row of points `dy2` rows away: at each
    column the nearer of that row's points left and right of it (a tie: the left one), kept
    where nearer than `best` and within `limit` (both squared)."""
    for x in range(row.shape[0]):
        a, b = left_of[x], right_of[x]
        if a < 0 and b < 0:
            continue
        column = a if b < 0 or (a >= 0 and x - a <= b - x) else b
        dx = np.float32(column - x)
        d2 = dy2 + dx * dx
        if d2 < best[x] and d2 <= limit:
            best[x] = d2
            out[x] = row[column]
