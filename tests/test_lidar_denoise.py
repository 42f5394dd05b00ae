"""A noisy LiDAR map smoothed along its rows (`[engine] denoise_lidar`)."""

from __future__ import annotations

import numpy as np
import pytest

from edge_depth.runtime.lidar_denoise import THRESHOLD_PX, LidarDenoise
from edge_depth.runtime.lidar_rows import noise_level


def _map(seed: int = 0, sigma: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(noisy map, clean map): rows every 10 px, a point every 2nd pixel, on a slanted wall
    with a nearer box in front (a depth edge in every row)."""
    rng = np.random.default_rng(seed)
    h, w = 200, 320
    yy, xx = np.mgrid[0:h, 0:w]
    clean = (10 + 0.02 * xx + 0.01 * yy).astype(np.float32)
    clean[:, 120:200] = 30.0
    sparse = np.zeros_like(clean)
    sparse[::10, ::2] = clean[::10, ::2]
    noisy = sparse.copy()
    points = noisy > 0
    noisy[points] += rng.normal(0, sigma, points.sum()).astype(np.float32)
    return noisy, sparse


def test_the_noise_level_reads_the_noise_and_not_the_depth_edges():
    noisy, clean = _map(1, 0.8)
    level, triples = noise_level(noisy)
    assert 0.7 < level < 0.9 and triples > 1000
    assert noise_level(clean)[0] < 0.01  # a slanted plane and a box: no noise


def test_a_noisy_map_is_smoothed_and_its_depth_edges_kept():
    noisy, clean = _map(2, 0.8)
    out, level = LidarDenoise().apply(noisy)
    points = clean > 0
    before = np.abs(noisy - clean)[points].mean()
    after = np.abs(out - clean)[points].mean()
    assert level > THRESHOLD_PX and after < 0.7 * before
    # the box's first and last points stay the box's, the wall's the wall's
    row = out[50]
    assert abs(row[120] - 30) < 2 and abs(row[118] - clean[50, 118]) < 2.5
    assert np.array_equal(out > 0, points)  # no point added or removed


def test_a_quiet_map_is_left_as_it_is():
    noisy, clean = _map(3, 0.1)
    out, level = LidarDenoise().apply(noisy)
    assert level <= THRESHOLD_PX and out is noisy


def test_the_engine_smooths_only_when_asked_and_the_summary_says_so():
    from edge_depth.frame_summary import selection_summary
    from edge_depth.runtime.engine import Engine

    rng = np.random.default_rng(4)
    left = rng.integers(0, 255, (400, 640), np.uint8)
    noisy = np.zeros((400, 640), np.float32)
    noisy[::20, ::2] = 20 + rng.normal(0, 1.0, noisy[::20, ::2].shape)
    unmeasured = Engine(runtime="onnxruntime", align_lidar=False).infer(left, left, noisy,
                                                                         iters=1)
    assert unmeasured.lidar_noise_px is None
    # the alignment measures the level (to tell the map's depth edges from its noise) ...
    measured = Engine(runtime="onnxruntime").infer(left, left, noisy, iters=1)
    assert 0.9 < measured.lidar_noise_px < 1.1
    # ... and the smoothing, when on, the same
    on = Engine(runtime="onnxruntime", denoise_lidar=True).infer(left, left, noisy, iters=1)
    assert on.lidar_noise_px == pytest.approx(measured.lidar_noise_px)
    assert selection_summary([dict(lidar_noise_px=1.0, lidar_smoothed=1.0),
                              dict(lidar_noise_px=0.1, lidar_smoothed=0.0)]) == (
        "LiDAR noise: smoothed along the rows in 1 of 2 frames (noise median 1.00 px, "
        f"smoothed above {THRESHOLD_PX} px)")
    # measured, not smoothed: said, with what the alignment then reads as a depth edge
    said = selection_summary([dict(lidar_noise_px=0.8, lidar_smoothed=0.0),
                              dict(lidar_noise_px=0.7, lidar_smoothed=0.0),
                              dict(lidar_noise_px=0.1, lidar_smoothed=0.0)])
    assert said.startswith("LiDAR noise: 2 of 3 frames' maps above 0.3 px of range noise "
                           "(median 0.75 px; the real pairs' maps read 0.1-0.15): their depth "
                           "edges are read from jumps above 4.2 px only.")  # 4·√2·0.75
    assert selection_summary([dict(lidar_noise_px=0.1, lidar_smoothed=0.0)]) is None


def test_a_map_too_sparse_to_measure_is_left_as_it_is_and_its_level_unknown():
    sparse = np.zeros((100, 200), np.float32)
    sparse[50, 10:40:2] = 5.0 + np.arange(15) % 2 * 3.0  # 15 points: 13 triples, zig-zagging
    out, level = LidarDenoise().apply(sparse)
    assert out is sparse and level is None
