"""Core types reject bad arrays where they enter the pipeline."""

from __future__ import annotations

import numpy as np
import pytest

from edge_depth.errors import InvalidDataError
from edge_depth.types import DepthResult, LidarScan, StereoFrame


def _img(h=4, w=6, dtype=np.uint8):
    return np.zeros((h, w), dtype)


def test_stereo_frame_accepts_a_grey_pair_and_reports_its_size():
    frame = StereoFrame(stamp_ns=10, seq=1, left=_img(), right=_img(), rectified=True)
    assert frame.size == (6, 4)


@pytest.mark.parametrize("left,right", [
    (_img(), _img(4, 7)),                       # size mismatch
    (_img(dtype=np.float32), _img()),           # wrong dtype
    (np.zeros((4, 6, 3), np.uint8), _img()),    # colour
    (_img(0, 6), _img(0, 6)),                   # empty
])
def test_stereo_frame_rejects_bad_images(left, right):
    with pytest.raises(InvalidDataError):
        StereoFrame(stamp_ns=0, seq=0, left=left, right=right)


def test_stereo_frame_rejects_negative_stamp():
    with pytest.raises(InvalidDataError, match="stamp_ns"):
        StereoFrame(stamp_ns=-1, seq=0, left=_img(), right=_img())


def test_lidar_scan_validates_points_and_optional_fields():
    pts = np.zeros((5, 3), np.float32)
    scan = LidarScan(0, pts, np.ones(5, np.float32), np.arange(5, dtype=np.int64))
    assert len(scan) == 5
    with pytest.raises(InvalidDataError, match="points"):
        LidarScan(0, np.zeros((5, 2), np.float32))
    with pytest.raises(InvalidDataError, match="float32"):
        LidarScan(0, np.zeros((5, 3), np.float64))
    with pytest.raises(InvalidDataError, match="intensity"):
        LidarScan(0, pts, intensity=np.ones(4, np.float32))
    with pytest.raises(InvalidDataError, match="point_stamps_ns"):
        LidarScan(0, pts, point_stamps_ns=np.arange(5, dtype=np.int32))


def test_lidar_scan_finite_drops_nan_points_with_their_fields():
    pts = np.array([[1, 2, 3], [np.nan, 0, 0], [4, 5, np.inf], [7, 8, 9]], np.float32)
    scan = LidarScan(0, pts, np.arange(4, dtype=np.float32)).finite()
    np.testing.assert_array_equal(scan.points, [[1, 2, 3], [7, 8, 9]])
    np.testing.assert_array_equal(scan.intensity, [0, 3])


def test_depth_result_requires_matching_float32_maps():
    d = np.ones((4, 6), np.float32)
    ok = DepthResult(0, d, d, np.ones((4, 6), bool), iterations=4, timings_ms={"encoder": 1.0})
    assert ok.iterations == 4
    with pytest.raises(InvalidDataError, match="depth"):
        DepthResult(0, d, np.ones((4, 5), np.float32), np.ones((4, 6), bool), 4)
    with pytest.raises(InvalidDataError, match="valid"):
        DepthResult(0, d, d, np.ones((4, 6), np.uint8), 4)


def test_a_stage_share_is_of_the_grid_it_was_counted_on_and_never_over_100_percent():
    from edge_depth.daemon import _shares

    small = np.zeros((16, 16), np.float32)  # a camera image smaller than the engine's grid
    result = DepthResult(1, small, small, small > 0, 4, selected_px=1000, refined_px=4096,
                         counted_px=64 * 64)
    shares = _shares(result)
    assert shares == {"replaced_pct": pytest.approx(100 * 1000 / 4096), "refined_pct": 100.0}
    assert _shares(DepthResult(1, small, small, small > 0, 4, refined_px=64)) == {
        "refined_pct": 25.0}  # no grid given: the disparity's own


def test_the_runs_metrics_are_running_means_that_do_not_grow_with_the_frames():
    import tracemalloc

    from edge_depth.daemon import MetricsMean

    total = MetricsMean()
    total.add({"epe": 1.0, "bad3": 10.0})
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    for _ in range(20_000):
        total.add({"epe": 3.0, "bad3": 0.0})
    grown = tracemalloc.get_traced_memory()[0] - before
    tracemalloc.stop()
    assert len(total) == 20_001 and total.mean("epe") == pytest.approx(60_001 / 20_001)
    assert total.mean("bad3") == pytest.approx(10 / 20_001)
    assert grown < 10_000  # a list of every frame's dict grew with each frame
