"""edge.runtime.band_sgm: its aggregation is Hirschmüller's (equal to edge.guided_sgm's on a band
that covers the whole range), it recovers a plane from an estimate a few px off where the
network is unsure, it never moves an estimate beyond the band the network's confidence
allows, and the engine runs it by default (`[engine] refine = "band"`), the weighted median
after it."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from edge_depth.errors import ConfigError
from edge_depth.guided_sgm import GuidedSgmConfig, aggregate, census_cost
from edge_depth.runtime import band_paths, band_sgm
from edge_depth.runtime.band_sgm import BandSgmConfig, refine
from edge_depth.runtime.engine import Engine
from edge_depth.runtime.nearest_point import nearest_within
from edge_depth.sim import RigConfig, make_sample

from .test_guided_sgm import random_texture, shifted_pair


def test_the_aggregation_is_guided_sgms_on_a_band_over_the_whole_range():
    left, right = shifted_pair(random_texture(), disparity=7)
    config = GuidedSgmConfig(num_disparities=17)
    expected = aggregate(census_cost(left, right, config), left, config)
    shape = left.shape
    lo, count = np.zeros(shape, np.int32), np.full(shape, 17, np.int32)
    start = np.zeros(count.size + 1, np.int64)
    np.cumsum(count, out=start[1:])
    zero = np.zeros(shape, np.float32)
    cost = np.empty(start[-1], np.float32)
    band_sgm.band_cost(band_sgm.census(left), band_sgm.census(right), lo, count, start,
                       zero, zero, zero, 10.0, 1.0, 1.0, cost)
    penalties = np.maximum(10, 120 // np.maximum(np.arange(256), 1)).astype(np.float32)
    totals = np.empty((2, start[-1]), np.float32)
    band_paths.aggregate(cost, lo, count, start, left.astype(np.int32), np.float32(10),
                       penalties, True, totals)
    summed = (totals[0] + totals[1]).reshape(shape + (17,))
    np.testing.assert_array_equal(summed, expected.astype(np.float32))


def _at(before, first, d):
    """A previous pixel's path cost at disparity d (its labels from `first`); ∞ beyond."""
    j = d - first
    return before[j] if 0 <= j < len(before) else np.inf


def reference_paths(cost, lo, count, grey, p1, p2, diagonals):
    """Hirschmüller's recurrence written plainly over ragged bands: S summed over the paths
    (dy, dx) with each pixel following (y − dy, x − dx); a list of per-pixel arrays."""
    h, w = lo.shape
    directions = [(0, 1), (0, -1), (1, 0), (-1, 0)]
    if diagonals:
        directions += [(1, 1), (1, -1), (-1, 1), (-1, -1)]
    total = [[np.zeros(count[y, x]) for x in range(w)] for y in range(h)]
    for dy, dx in directions:
        paths = [[None] * w for _ in range(h)]
        ys = range(h) if dy >= 0 else range(h - 1, -1, -1)
        xs = list(range(w) if dx >= 0 else range(w - 1, -1, -1))
        for y in ys:
            for x in xs:
                here = cost[y][x]
                py, px = y - dy, x - dx
                if not (0 <= py < h and 0 <= px < w):
                    paths[y][x] = here.copy()
                else:
                    before, first = paths[py][px], lo[py, px]
                    floor = before.min()
                    big = max(p1, p2 // max(abs(int(grey[y, x]) - int(grey[py, px])), 1))
                    paths[y][x] = np.array([
                        here[i] + min(_at(before, first, d), _at(before, first, d - 1) + p1,
                                      _at(before, first, d + 1) + p1, floor + big) - floor
                        for i, d in enumerate(range(lo[y, x], lo[y, x] + count[y, x]))])
                total[y][x] += paths[y][x]
    return total


@pytest.mark.parametrize("diagonals", [False, True])
def test_the_ragged_aggregation_is_hirschmullers_recurrence(diagonals):
    rng = np.random.default_rng(5)
    h, w = 9, 14
    lo = rng.integers(0, 12, (h, w)).astype(np.int32)
    count = rng.integers(1, 9, (h, w)).astype(np.int32)
    start = np.zeros(count.size + 1, np.int64)
    np.cumsum(count, out=start[1:])
    flat = rng.integers(0, 62, start[-1]).astype(np.float32)
    grey = rng.integers(0, 256, (h, w)).astype(np.int32)
    penalties = np.maximum(10, 120 // np.maximum(np.arange(256), 1)).astype(np.float32)
    totals = np.empty((2, start[-1]), np.float32)
    band_paths.aggregate(flat, lo, count, start, grey, np.float32(10), penalties, diagonals,
                       totals)
    got = totals[0] + totals[1]
    cost = [[flat[start[y * w + x]:start[y * w + x + 1]].astype(np.float64) for x in range(w)]
            for y in range(h)]
    expected = reference_paths(cost, lo, count, grey, 10, 120, diagonals)
    for y in range(h):
        for x in range(w):
            np.testing.assert_allclose(got[start[y * w + x]:start[y * w + x + 1]],
                                       expected[y][x], rtol=0, atol=1e-3)


@pytest.mark.parametrize("rows, per_row, reach", [(2, 12, 8.0), (40, 12, 8.0), (40, 2, 8.0),
                                                  (12, 30, 8.0), (30, 0, 8.0), (30, 0, 7.5)])
def test_the_nearest_point_within_reach_is_the_exact_euclidean_one(rows, per_row, reach):
    """Rows of many points (a scan line, walked along the image row) and of few (walked point
    by point; 0: a random count per row, both kinds mixed), each against every point written
    plainly; a reach between whole pixels too."""
    rng = np.random.default_rng(rows * 100 + per_row)
    h, w = 40, 50
    points = np.zeros((h, w), np.float32)
    ys = rng.choice(h, rows, replace=False)
    for y in ys:  # scan lines, and points anywhere
        xs = rng.choice(w, per_row or int(rng.integers(1, 20)), replace=False)
        points[y, xs] = rng.uniform(1, 60, len(xs)).astype(np.float32)
    nearby = np.zeros((h, w), np.float32)
    nearest_within(points, np.float32(reach), nearby)
    py, px = np.nonzero(points)  # row-major: a tie goes to the upper row, then the left
    for y in range(h):
        for x in range(w):
            d2 = (py - y) ** 2 + (px - x) ** 2
            best = int(np.argmin(d2))
            expected = points[py[best], px[best]] if d2[best] <= reach * reach else 0.0
            assert nearby[y, x] == expected, (y, x)


def test_the_winners_are_the_plain_minimum_of_each_view():
    """Left: the first label at S's minimum with the parabola's step (−1 at a band's edge);
    right: for each right pixel the lowest S over the left pixels that meet it (a tie: the
    leftmost), −1 where none does — written plainly against the kernel."""
    rng = np.random.default_rng(11)
    h, w = 6, 30
    lo = rng.integers(0, 8, (h, w)).astype(np.int32)
    count = rng.integers(3, 9, (h, w)).astype(np.int32)
    count[2, 5] = 0  # a pixel not refined
    start = np.zeros(count.size + 1, np.int64)
    np.cumsum(count, out=start[1:])
    totals = rng.integers(0, 40, (2, start[-1])).astype(np.float32)  # ties among them
    summed = totals[0] + totals[1]
    prior = np.zeros((h, w), np.float32)
    left, right, fallback = (np.empty((h, w), np.float32) for _ in range(3))
    band_sgm.winners(totals, lo, count, start, 0, prior, np.zeros_like(prior), left, right,
                     fallback)
    for y in range(h):
        best_right = {}
        for x in range(w):
            s, n = start[y * w + x], count[y, x]
            costs = summed[s:s + n]
            if n == 0:
                assert left[y, x] == -1.0
                continue
            i = int(np.argmin(costs))
            if 0 < i < n - 1:
                a, b, c = costs[i - 1], costs[i], costs[i + 1]
                step = 0.0 if a - 2 * b + c <= 0 else (a - c) / (2 * (a - 2 * b + c))
                assert left[y, x] == pytest.approx(lo[y, x] + i + step, abs=1e-5)
            else:
                assert left[y, x] == -1.0
            for i in range(n):
                r = x - (lo[y, x] + i)
                if r >= 0 and (r not in best_right or costs[i] < best_right[r][0]):
                    best_right[r] = (costs[i], lo[y, x] + i)
        expected = [best_right[r][1] if r in best_right else -1 for r in range(w)]
        np.testing.assert_array_equal(right[y], np.array(expected, np.float32))
    assert 0 < np.count_nonzero(left >= 0) < left.size  # inside a band and at its edge


def test_the_check_keeps_a_winner_only_where_both_views_agree():
    rng = np.random.default_rng(12)
    h, w = 5, 40
    left = rng.uniform(0, 20, (h, w)).astype(np.float32)
    left[rng.random((h, w)) < 0.2] = -1.0  # rejected
    right = np.where(rng.random((h, w)) < 0.5, left, left + 3).astype(np.float32)
    fallback = np.full((h, w), 99.0, np.float32)
    out = np.empty((h, w), np.float32)
    band_sgm._checked_choice(left, right, fallback, np.float32(1.0), out)
    for y in range(h):
        for x in range(w):
            d = left[y, x]
            xr = x - int(np.rint(d)) if d >= 0 else -1
            keep = d >= 0 and 0 <= xr < w and abs(d - right[y, xr]) <= 1.0
            assert out[y, x] == (d if keep else 99.0), (y, x)
    assert 0 < np.count_nonzero(out != 99.0) < out.size  # both outcomes met


def test_the_volumes_are_reused_and_a_refinement_repeats_exactly():
    left, right = shifted_pair(random_texture(), disparity=7)
    prior = np.full(left.shape, 10.0, np.float32)
    unsure = np.full(left.shape, 0.3, np.float32)
    sparse = np.zeros_like(prior)
    sparse[10, 20:40] = 7.0
    first, _ = refine(left, right, prior, unsure, sparse)
    bigger, _ = refine(np.tile(left, (2, 2)), np.tile(right, (2, 2)), np.tile(prior, (2, 2)),
                       np.tile(unsure, (2, 2)), np.tile(sparse, (2, 2)))
    again, _ = refine(left, right, prior, unsure, sparse)  # in buffers a larger frame grew
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(bigger[:left.shape[0], :left.shape[1]], prior)


def test_an_unsure_estimate_a_few_px_off_is_refined_onto_the_plane():
    left, right = shifted_pair(random_texture(), disparity=7)
    prior = np.full(left.shape, 10.0, np.float32)  # 3 px off
    unsure = np.full(left.shape, 0.1, np.float32)
    out, changed = refine(left, right, prior, unsure, np.zeros_like(prior))
    inner = out[4:-4, 7 + 5:-5]
    assert np.mean(np.abs(inner - 7.0)) < 0.15
    assert changed > 0.9 * inner.size


def test_a_sure_estimate_moves_within_its_band_and_never_beyond_it():
    left, right = shifted_pair(random_texture(), disparity=7)
    sure = np.full(left.shape, 0.99, np.float32)  # the band ±4
    every_pixel = BandSgmConfig(refine_below=1.0)  # sure pixels refined too
    nearby, _ = refine(left, right, np.full(left.shape, 9.0, np.float32), sure,
                       np.zeros(left.shape, np.float32), every_pixel)
    assert np.mean(np.abs(nearby[4:-4, 12:-5] - 7.0) < 0.5) > 0.9  # 2 px off: reached
    far, _ = refine(left, right, np.full(left.shape, 20.0, np.float32), sure,
                    np.zeros(left.shape, np.float32), every_pixel)
    assert np.all(np.abs(far - 20.0) <= 4.0)  # 13 px off: the plane lies beyond the band


def test_bad_estimates_and_confidences_neither_crash_nor_invent_values():
    left, right = shifted_pair(random_texture(), disparity=7)
    prior = np.full(left.shape, 7.0, np.float32)
    prior[:, :10] = -40.0  # far below 0
    prior[5:8, 20:30] = np.nan
    prior[10, 40:50] = np.inf
    confidence = np.full(left.shape, 0.5, np.float32)
    confidence[20:25] = np.nan
    out, changed = refine(left, right, prior, confidence, np.zeros_like(prior))
    assert np.isnan(out[5:8, 20:30]).all() and np.isinf(out[10, 40:50]).all()
    known = np.isfinite(prior)
    assert np.isfinite(out[known]).all() and out[known].min() >= -40.0
    assert 0 < changed < known.sum()
    with pytest.raises(ValueError, match="paths"):
        BandSgmConfig(paths=6)


def test_a_lidar_point_decides_between_equal_matches():
    # stripes of period 8: 3, 11 and 19 px match alike; the LiDAR says 11
    xs = np.arange(96 + 32, dtype=np.float32)
    texture = np.tile(128 + 80 * np.sin(2 * np.pi * xs / 8), (48, 1))
    left, right = shifted_pair(texture, disparity=11)
    prior = np.full(left.shape, 15.0, np.float32)  # halfway between 11 and 19
    unsure = np.full(left.shape, 0.0, np.float32)
    sparse = np.zeros_like(prior)
    sparse[::6, ::2] = 11.0
    guided, _ = refine(left, right, prior, unsure, sparse)
    alone, _ = refine(left, right, prior, unsure, np.zeros_like(prior))
    def right_share(disparity):  # noqa: E306
        return np.mean(np.abs(disparity[4:-4, 11 + 5:-5] - 11.0) <= 1.0)
    # measured 0.82 (the rest keeps the estimate where the check finds the stripes ambiguous)
    # against 0.19 without the points
    assert right_share(guided) > 0.75 and right_share(alone) < 0.3


def test_the_engine_runs_the_band_refinement_after_the_network_and_counts_what_it_moved():
    rng = np.random.default_rng(4)
    h, w = 400, 640
    texture = (rng.uniform(0, 255, (h, w + 16))).astype(np.uint8)
    left, right = texture[:, :w].copy(), texture[:, 9:9 + w].copy()
    sparse = np.zeros((h, w), np.float32)
    sparse[::25, ::2] = 9.0
    plain = Engine(precision="int8", threads=2, refine="off", edge_median="off")
    band = Engine(precision="int8", threads=2, refine="band", edge_median="off")
    assert band.describe().endswith("band refinement")
    before = plain.infer(left, right, sparse)
    after = band.infer(left, right, sparse)
    assert "band_refine" in after.timings_ms and "edge_median" not in after.timings_ms
    assert after.refined_px is not None and after.refined_px > 0
    moved = int(np.sum(np.abs(after.disparity - before.disparity) > 1.0))
    assert after.refined_px == moved  # the pixels it moved by more than its sub-pixel steps
    assert int(np.sum(after.disparity != before.disparity)) > moved


def test_by_default_the_weighted_median_follows_the_band_over_the_unsure_edges():
    from edge_depth.runtime.edge_median import EdgeMedian, unsure_edges

    sample = make_sample(11, RigConfig(width=640, height=400), "beams16")
    sparse, valid = sample.sparse_disparity("left")
    args = (sample.left, sample.right, (sparse * valid).astype(np.float32))
    default = Engine(precision="int8", threads=2)  # refine "band", the bundle's median 9x9/2
    assert default.describe().endswith("band refinement, weighted median 9x9/2 (the bundle's)")
    bare = Engine(precision="int8", threads=2, edge_median="off").infer(*args)
    got = default.infer(*args)
    gate = unsure_edges(bare.disparity, bare.confidence)
    assert gate.mean() > 0.01 and "edge_median" in got.timings_ms
    expected = EdgeMedian("9x9/2").apply(bare.disparity, sample.left, gate)
    np.testing.assert_array_equal(got.disparity, expected)
    assert np.count_nonzero(got.disparity != bare.disparity) > 0


def test_the_band_refinement_without_numba_is_one_clear_line(monkeypatch):
    monkeypatch.delitem(sys.modules, "edge_depth.runtime.band_sgm")  # imported again
    monkeypatch.setitem(sys.modules, "numba", None)  # import numba raises ImportError
    with pytest.raises(ConfigError, match=r"refine: expected numba installed .*pip install "
                       r"numba\), or refine = \"off\""):
        Engine(precision="int8", threads=1)  # the default


def test_only_the_pixels_the_network_is_unsure_of_and_their_neighbours_are_refined():
    left, right = shifted_pair(random_texture(), disparity=7)
    prior = np.full(left.shape, 9.0, np.float32)  # 2 px off everywhere
    confidence = np.full(left.shape, 0.95, np.float32)
    confidence[15:30, 40:70] = 0.2
    out, changed = refine(left, right, prior, confidence, np.zeros_like(prior))
    near = np.zeros(left.shape, bool)
    near[13:32, 38:72] = True  # the unsure block and refine_margin_px (2) around it
    assert np.all(out[~near] == 9.0)
    assert np.mean(np.abs(out[15:30, 40:70] - 7.0) < 0.5) > 0.9
    assert changed == np.count_nonzero(out != 9.0)
