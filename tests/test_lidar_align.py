"""A misregistered LiDAR map put back onto the image's edges (`[engine] align_lidar`)."""

from __future__ import annotations

import numpy as np
import pytest

from edge_depth.runtime.lidar_align import (
    JUMP_PX,
    MIN_JUMPS,
    MIN_Z,
    LidarAlign,
    depth_jumps,
    jump_px,
    offset,
    shifted,
)
from edge_depth.runtime.lidar_rows import map_points, measured, noise_level

H, W = 240, 320


def _scene(seed: int = 0, shape: tuple[int, int] = (H, W)) -> tuple[np.ndarray, np.ndarray]:
    """(left image, disparity): discs at random depths before a far wall, each brighter than
    the wall, so every depth edge is an intensity edge, running every way."""
    rng = np.random.default_rng(seed)
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w]
    disparity = np.full(shape, 8.0, np.float32)
    left = np.full(shape, 60.0)
    for _ in range(16 * (h * w) // (H * W)):
        cx, cy, r = rng.uniform(0, w), rng.uniform(0, h), rng.uniform(10, 30)
        disc = (xx - cx) ** 2 + (yy - cy) ** 2 < r * r
        disparity[disc] = rng.uniform(15, 40)
        left[disc] = rng.uniform(120, 230)
    return left.astype(np.uint8), disparity


def _rows(disparity: np.ndarray, every: int = 12) -> np.ndarray:
    """A LiDAR map: every `every`-th row, every 2nd pixel."""
    sparse = np.zeros_like(disparity)
    sparse[::every, ::2] = disparity[::every, ::2]
    return sparse


def _turned(sparse: np.ndarray, deg: float) -> np.ndarray:
    ys, xs = np.nonzero(sparse)
    a = np.deg2rad(deg)
    cx, cy = (W - 1) / 2, (H - 1) / 2
    u = np.rint(cx + np.cos(a) * (xs - cx) - np.sin(a) * (ys - cy)).astype(int)
    v = np.rint(cy + np.sin(a) * (xs - cx) + np.cos(a) * (ys - cy)).astype(int)
    ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    out = np.zeros_like(sparse)
    np.maximum.at(out, (v[ok], u[ok]), sparse[ys[ok], xs[ok]])
    return out


def test_jumps_are_the_depth_edges_between_neighbouring_points_of_a_row():
    sparse = np.zeros((3, 20), np.float32)
    sparse[1, ::2] = [5, 5, 5, 9, 9, 9, 9, 2, 2, 2]  # jumps between x 4-6 and 12-14
    sparse[2, [0, 10]] = [5, 30]  # 10 px apart: not neighbours
    ys, xs = depth_jumps(sparse)
    assert ys.tolist() == [1, 1] and xs.tolist() == [5, 13]
    nan = sparse.copy()
    nan[0, 3] = np.nan  # not a point
    assert map_points(nan)[0].tolist() == map_points(sparse)[0].tolist()


def test_a_map_that_sits_right_is_left_as_it_is():
    left, disparity = _scene()
    sparse = _rows(disparity)
    out, found = LidarAlign().apply(left, sparse)
    assert found.jumps >= MIN_JUMPS and not found.moves
    assert out is sparse


@pytest.mark.parametrize("dx, dy", [(2, 1), (-3, 0), (0, -2)])
def test_a_moved_map_is_put_back_where_it_was(dx, dy):
    left, disparity = _scene(1)
    sparse = _rows(disparity)
    out, found = LidarAlign().apply(left, shifted(sparse, dx, dy))
    assert (found.dx, found.dy, found.turn_deg) == (dx, dy, 0.0) and found.moves
    inner = (slice(8, -8), slice(8, -8))  # what the move pushed out is gone
    assert np.array_equal(out[inner], sparse[inner])


def test_a_turned_map_is_turned_back():
    left, disparity = _scene(2)
    sparse = _rows(disparity, every=8)
    found = offset(left, _turned(sparse, 0.75))
    assert found.moves and found.turn_deg == 0.75 and (found.dx, found.dy) == (0, 0)
    back = found.undo(_turned(sparse, 0.75))
    # each point back within a pixel of where it was (rounded twice)
    ys, xs = np.nonzero(sparse[10:-10, 10:-10])
    near = np.stack([np.roll(np.roll(back, a, 0), b, 1)[10:-10, 10:-10][ys, xs]
                     for a in (-1, 0, 1) for b in (-1, 0, 1)])
    assert np.mean(np.any(near == sparse[10:-10, 10:-10][ys, xs], axis=0)) > 0.97


def test_a_map_without_depth_jumps_is_not_searched():
    left, disparity = _scene(3)
    sparse = np.zeros_like(disparity)
    sparse[::12, ::9] = disparity[::12, ::9]  # points too far apart to be neighbours
    found = offset(left, shifted(sparse, 2, 0))
    assert found.jumps < MIN_JUMPS and not found.moves


def test_the_engine_puts_the_map_back_unless_told_not_to_and_the_summary_says_so():
    from edge_depth.frame_summary import selection_summary
    from edge_depth.runtime.engine import Engine

    left, disparity = _scene(4, (400, 640))
    sparse = shifted(_rows(disparity), 2, 1)
    right = left.copy()
    on = Engine(runtime="onnxruntime").infer(left, right, sparse, iters=1)
    assert on.lidar_offset.moves and (on.lidar_offset.dx, on.lidar_offset.dy) == (2, 1)
    off = Engine(runtime="onnxruntime", align_lidar=False).infer(left, right, sparse, iters=1)
    assert off.lidar_offset is None
    timings = [dict(lidar_put_back=1.0, lidar_dx_px=2.0, lidar_dy_px=1.0, lidar_turn_deg=0.0),
               dict(lidar_put_back=0.0)]
    assert selection_summary(timings).startswith(
        "LiDAR map: put back onto the image's edges in 1 of 2 frames (it sat turned +0.00° "
        "and moved (+2, +1) px off them, medians)")


def _noisy(sparse: np.ndarray, sigma: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = sparse.copy()
    points = out > 0
    out[points] = np.maximum(out[points] + rng.normal(0, sigma, points.sum()), 0.1)
    return out


def test_a_noisy_map_finds_its_edges_not_its_noise_and_is_not_moved():
    left, disparity = _scene(5)
    sparse = _rows(disparity)
    noisy = _noisy(sparse, 0.75)
    assert jump_px(measured(noise_level(sparse))) == JUMP_PX
    assert 3.5 < jump_px(measured(noise_level(noisy))) < 5.0  # 4·√2·0.75 = 4.2
    # the same depth edges as the clean map's, not one neighbour pair in six
    assert abs(len(depth_jumps(noisy)[0]) - len(depth_jumps(sparse)[0])) <= 3
    out, found = LidarAlign().apply(left, noisy)
    assert not found.moves and out is noisy
    assert 0.6 < found.noise_px < 0.9 and offset(left, sparse).noise_px < 0.1  # measured


def test_a_noisy_moved_map_is_still_put_back():
    left, disparity = _scene(6)
    noisy = _noisy(shifted(_rows(disparity), 2, 1), 0.5)
    found = offset(left, noisy)
    assert found.moves and (found.dx, found.dy, found.turn_deg) == (2, 1, 0.0)


def _mixed(sparse: np.ndarray, disparity: np.ndarray, seed: int, reach: int = 2,
           share: float = 0.5) -> np.ndarray:
    """Mixed returns: each point with a depth edge within `reach` px along its row takes the
    other surface's disparity with probability `share`."""
    rng = np.random.default_rng(seed)
    out = sparse.copy()
    ys, xs = np.nonzero(sparse)
    w = disparity.shape[1]
    window = np.stack([disparity[ys, np.clip(xs + k, 0, w - 1)]
                       for k in range(-reach, reach + 1)])
    lo, hi = window.min(axis=0), window.max(axis=0)
    edge = (hi - lo >= 2.0) & (rng.random(len(ys)) < share)
    other = np.where(np.abs(sparse[ys, xs] - hi) < np.abs(sparse[ys, xs] - lo), lo, hi)
    out[ys[edge], xs[edge]] = other[edge]
    return out


def test_a_noisy_map_with_mixed_returns_that_sits_right_is_not_moved_but_a_moved_one_is():
    left, disparity = _scene(17)
    rows = _rows(disparity, every=8)
    noisy = _noisy(_mixed(rows, disparity, 17), 1.0, 17)
    out, found = LidarAlign().apply(left, noisy)
    # the peak is off the identity and 1.2x its score (the gain alone would have moved it),
    # but the halves of the rows do not confirm each other's offset
    assert (found.dx, found.dy, found.turn_deg) == (0, -1, 0.5) and found.gain > 1.15
    assert found.held_out_z < 1.0 and not found.moves and out is noisy
    back, moved = LidarAlign().apply(left, shifted(rows, -2, 2))
    assert (moved.dx, moved.dy, moved.turn_deg) == (-2, 2, 0.0) and moved.moves
    assert moved.held_out_z > 3 * MIN_Z
    inner = (slice(8, -8), slice(8, -8))
    assert np.array_equal(back[inner], rows[inner])
