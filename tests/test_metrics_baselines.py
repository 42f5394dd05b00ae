"""Metrics and classical baselines on inputs whose answers are known by hand."""

from __future__ import annotations

import numpy as np
import pytest

from edge_depth.baselines import lidar_linear, lidar_nearest, sgbm_disparity
from edge_depth.metrics import depth_metrics, disparity_metrics


def test_disparity_metrics_count_holes_as_errors():
    gt = np.full((2, 2), 10.0, np.float32)
    pred = np.array([[10.0, 11.5], [0.0, 13.5]], np.float32)  # errors 0, 1.5, hole(10), 3.5
    m = disparity_metrics(pred, gt)
    assert np.isclose(m["epe"], (0 + 1.5 + 10 + 3.5) / 4)
    assert np.isclose(m["bad1"], 75.0) and np.isclose(m["bad2"], 50.0)
    assert np.isclose(m["bad3"], 50.0) and np.isclose(m["density"], 75.0)


def test_disparity_metrics_in_float32_count_as_float64_would():
    rng = np.random.default_rng(3)
    gt = (rng.random((60, 80)) * 60).astype(np.float32)
    gt[rng.random(gt.shape) < 0.1] = np.nan
    pred = (gt + rng.normal(0, 2, gt.shape)).astype(np.float32)
    pred[rng.random(gt.shape) < 0.05] = 0
    # 3 px and a hair: the float32 difference rounds to exactly 3, the pixel is still bad-3
    pred[0, 0], gt[0, 0] = np.nextafter(np.float32(3), np.float32(4)), np.float32(1.5e-7)
    assert np.float32(pred[0, 0]) - np.float32(gt[0, 0]) == 3.0
    ok = np.isfinite(gt) & (gt > 0)
    g, p = gt[ok].astype(np.float64), pred[ok].astype(np.float64)
    err = np.where(p > 0, np.abs(p - g), g)
    m = disparity_metrics(pred, gt)
    assert m["bad3"] == 100.0 * np.count_nonzero(err > 3) / err.size
    assert m["bad1"] == 100.0 * np.count_nonzero(err > 1) / err.size
    assert np.isclose(m["epe"], err.mean(), rtol=1e-7)
    assert disparity_metrics(pred.astype(np.float64), gt)["bad3"] == m["bad3"]


def test_depth_metrics_in_mm_and_inverse_km():
    gt = np.full((1, 1), 10.0, np.float32)  # f B = 1 -> 0.1 m
    pred = np.full((1, 1), 5.0, np.float32)  # 0.2 m
    m = depth_metrics(pred, gt, focal_px=10.0, baseline_m=0.1)
    assert np.isclose(m["mae_mm"], 100.0) and np.isclose(m["rmse_mm"], 100.0)
    assert np.isclose(m["imae"], 5000.0)  # |1/0.2 - 1/0.1| = 5 /m = 5000 /km


def test_lidar_densification_reproduces_a_plane_from_its_samples():
    h, w = 40, 60
    yy, xx = np.mgrid[0:h, 0:w]
    plane = (5 + 0.1 * xx + 0.05 * yy).astype(np.float32)
    valid = np.zeros((h, w), bool)
    valid[::7, ::9] = True
    valid[-1, ::9] = valid[::7, -1] = valid[-1, -1] = True
    sparse = np.where(valid, plane, 0).astype(np.float32)
    linear = lidar_linear(sparse, valid)
    assert np.abs(linear - plane).max() < 1e-3
    nearest = lidar_nearest(sparse, valid)
    assert np.array_equal(nearest[valid], plane[valid])
    assert np.abs(nearest - plane).max() < 0.1 * 5 + 0.05 * 4 + 1e-3


def test_sgbm_finds_a_constant_shift():
    rng = np.random.default_rng(0)
    texture = (rng.random((80, 200)) * 255).astype(np.uint8)
    # the right camera sees the scene 12 px further left
    right = np.ascontiguousarray(texture[:, 32:192])
    left = np.ascontiguousarray(texture[:, 20:180])
    disp = sgbm_disparity(left, right)
    core = disp[10:-10, 80:-10]
    assert np.median(core) == 12.0


def test_row_fill_takes_the_nearest_valid_value_in_the_row():
    from edge_depth.baselines import fill_row_nearest

    d = np.array([[0, 5, 0, 0, 9, 0], [0, 0, 0, 0, 0, 0]], np.float32)
    np.testing.assert_array_equal(fill_row_nearest(d),
                                  [[5, 5, 5, 9, 9, 9], [0, 0, 0, 0, 0, 0]])


def test_sgbm_disparity_count_follows_the_gt_range():
    from edge_depth.baselines import sgbm_disparities_for

    assert sgbm_disparities_for(105.5) == 112
    assert sgbm_disparities_for(40.0) == 64
    assert sgbm_disparities_for(128.0) == 128


def test_trivial_fusion_keeps_sgbm_and_fills_its_holes_from_the_lidar():
    from edge_depth.baselines import sgbm_lidar_fusion

    sgbm = np.array([[3.0, 0.0, 0.0, 4.0]], np.float32)
    sparse = np.array([[0.0, 0.0, 7.0, 0.0]], np.float32)
    fused = sgbm_lidar_fusion(sgbm, sparse, sparse > 0)
    np.testing.assert_array_equal(fused, [[3.0, 7.0, 7.0, 4.0]])


def test_confidence_calibration_reports_share_kept_and_their_bad1():
    from edge_depth.metrics import confidence_calibration

    gt = np.array([[10.0, 10.0, 10.0, 10.0, np.inf]], np.float32)
    pred = np.array([[10.2, 13.0, 10.5, 20.0, 1.0]], np.float32)   # good, bad, good, bad, no GT
    conf = np.array([[0.95, 0.8, 0.6, 0.3, 1.0]], np.float32)
    cal = confidence_calibration(pred, gt, conf)
    assert cal["kept@0.5"] == 75.0 and cal["bad1@0.5"] == pytest.approx(100 / 3)
    assert cal["kept@0.7"] == 50.0 and cal["bad1@0.7"] == 50.0
    assert cal["kept@0.9"] == 25.0 and cal["bad1@0.9"] == 0.0
