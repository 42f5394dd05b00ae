"""LiDAR -> sparse disparity: geometry, z-buffer, and the occlusion filter on the rig."""

from __future__ import annotations

import numpy as np

from edge_depth.calibration.model import StereoCalibration
from edge_depth.calibration.projection import (
    OcclusionFilterConfig,
    _search_box_max,
    filter_occluded,
    project_rectified,
    project_to_disparity,
)
from edge_depth.sim import PATTERNS, RigConfig, make_sample


def test_projection_puts_a_point_at_its_pixel_with_fb_over_z():
    pts = np.array([[0.0, 0.0, 2.0], [0.5, -0.25, 5.0]])
    d, v = project_rectified(pts, 400.0, 100.0, 50.0, 0.1, (200, 100))
    assert v.sum() == 2
    assert np.isclose(d[50, 100], 400 * 0.1 / 2)
    assert np.isclose(d[30, 140], 400 * 0.1 / 5)  # u = 400*0.1+100, v = 400*-0.05+50
    dr, _ = project_rectified(pts, 400.0, 100.0, 50.0, 0.1, (200, 100), side="right")
    assert np.isclose(dr[50, 80], 20.0)  # shifted left by the disparity


def test_nearest_point_wins_and_points_behind_or_outside_are_dropped():
    pts = np.array([[0, 0, 4.0], [0, 0, 2.0], [0, 0, 8.0], [0, 0, -1.0], [10, 0, 1.0],
                    [np.nan, 0, 1.0]])
    d, v = project_rectified(pts, 100.0, 10.0, 10.0, 0.1, (21, 21))
    assert v.sum() == 1 and np.isclose(d[10, 10], 100 * 0.1 / 2)


def test_points_with_any_non_finite_coordinate_or_infinite_depth_are_dropped():
    pts = np.array([[0, 0, 2.0], [np.inf, 0, 2.0], [0, -np.inf, 2.0], [0, np.nan, 2.0],
                    [0, 0, np.inf], [0, 0, np.nan], [0, 0, -np.inf]])
    d, v = project_rectified(pts, 100.0, 10.0, 10.0, 0.1, (21, 21))
    assert v.sum() == 1 and np.isclose(d[10, 10], 100 * 0.1 / 2) and np.isfinite(d).all()


def test_search_box_covers_exactly_the_segment_side_of_each_pixel():
    rng = np.random.default_rng(3)
    image = rng.random((40, 50)).astype(np.float32)
    for direction in ([0.0, -1.0], [1.0, 0.0], [0.6, 0.8], [-0.8, 0.6], [-0.6, -0.8]):
        direction = np.array(direction)
        got = _search_box_max(image, direction, 7)
        ex, ey = (int(np.ceil(7 * abs(c))) for c in direction)
        for y, x in ((0, 0), (20, 25), (39, 49), (5, 44), (33, 3)):
            x0, x1 = (x, x + ex) if direction[0] >= 0 else (x - ex, x)
            y0, y1 = (y, y + ey) if direction[1] >= 0 else (y - ey, y)
            box = image[max(y0, 0):y1 + 1, max(x0, 0):x1 + 1]
            assert got[y, x] == box.max(), (direction, y, x)


def test_occlusion_filter_removes_far_points_displaced_under_a_near_edge():
    # LiDAR 8 cm above a camera with B = 7.5 cm: background hidden by an object whose top edge
    # the LiDAR looks over lands up to 1.07 * (d_near - d_far) px *below* the object's points
    sparse = np.zeros((80, 60), np.float32)
    sparse[10, 10:50] = 5.0       # background above the object: visible
    sparse[20, 10:50] = 30.0      # the object's top scan line
    sparse[26, 20:40] = 5.0       # background "seen over" the object's top: hidden
    sparse[60, 10:50] = 5.0       # background 40 px below (> 1.07 * 25 + 3): not affected
    valid = sparse > 0
    keep = filter_occluded(sparse, valid, np.array([0.0, -0.08, 0.0]), 0.075,
                           OcclusionFilterConfig(slack_px=3.0))
    assert keep[20, 10:50].all()
    assert not keep[26, 20:40].any()
    assert keep[10, 10:50].all()
    assert keep[60, 10:50].all()
    # with no offset between LiDAR and camera only the small window acts
    keep_none = filter_occluded(sparse, valid, np.zeros(3), 0.075)
    assert keep_none[26, 20:40].all()


def _fractions(lidar: str, n: int = 6):
    rig = RigConfig()
    wrong_raw = wrong = kept = correct = total_raw = total = 0
    for seed in range(n):
        s = make_sample(5000 + seed, rig, PATTERNS[lidar].noiseless())
        raw, v_raw = s.sparse_disparity(filtered=False)
        flt, v_flt = s.sparse_disparity()
        bad = np.abs(raw - s.disp_left) > 1
        wrong_raw += (v_raw & bad).sum()
        total_raw += v_raw.sum()
        wrong += (v_flt & bad).sum()
        total += v_flt.sum()
        kept += (v_flt & ~bad).sum()
        correct += (v_raw & ~bad).sum()
    return wrong_raw / total_raw, wrong / total, kept / correct


def test_filter_cuts_parallax_errors_on_the_rig_and_keeps_most_true_points():
    raw, filtered, kept = _fractions("beams64")
    assert raw > 0.02          # the rig's parallax produces real artefacts
    assert filtered < 0.005    # the target (noiseless LiDAR; see README)
    assert kept > 0.85
    raw16, filtered16, kept16 = _fractions("beams16")
    assert filtered16 < raw16 / 2 and kept16 > 0.9


def test_project_to_disparity_matches_the_plain_projection_on_an_ideal_rig():
    s = make_sample(3, RigConfig(width=160, height=100, focal_px=112.5))
    calib = StereoCalibration.ideal(112.5, 0.075, (160, 100))
    d, v = project_to_disparity(s.scan.points, calib, s.T_cam_lidar, filter_occlusions=False)
    d0, v0 = project_rectified(s.lidar_in_camera(), 112.5, 79.5, 49.5, 0.075, (160, 100))
    np.testing.assert_array_equal(v, v0)
    np.testing.assert_allclose(d, d0, rtol=1e-6)
