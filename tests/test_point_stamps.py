"""A LiDAR point's own time survives a recording: both output profiles write it ("time",
seconds after the scan's stamp) and replay reads it back, so a replay pairs points with frames
as the live run did; peers' clouds with an Ouster-style "t" field or a LaserScan's
time_increment are read too."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from edge_depth.calibration.model import LidarExtrinsics
from edge_depth.capture.decode import decode_points
from edge_depth.capture.replay import McapSource
from edge_depth.loggers import open_logger
from edge_depth.mcap_log import RAW_TOPICS
from edge_depth.sim import RigConfig, make_sample
from edge_depth.sim.lidar import default_T_cam_lidar
from edge_depth.types import LidarScan

STAMP = 2_000_000_000


def scans_read_back(tmp_path, profile: str, scans: list[LidarScan]) -> list[LidarScan]:
    rig = RigConfig(width=64, height=64, focal_px=45.0, max_disparity_px=8.0)
    sample = make_sample(7, rig, "beams16")
    path = tmp_path / f"{profile}.mcap"
    with open_logger(path, profile, topics=RAW_TOPICS) as logger:
        logger.set_calibration(sample.calibration(), LidarExtrinsics(default_T_cam_lidar()))
        for scan in scans:
            logger.log_scan(scan)
        logger.log_frame(sample.frame(STAMP + 50_000_000, 0))
    return [e for e in McapSource(path) if isinstance(e, LidarScan)]


@pytest.mark.parametrize("profile", ["foxglove", "ros2"])
def test_each_points_time_is_recorded_and_replayed(tmp_path, profile):
    rng = np.random.default_rng(3)
    points = rng.uniform(-5, 5, (300, 3)).astype(np.float32)
    # a revolution swept over the 100 ms before its stamp, and one point of a scan without
    # per-point times
    times = STAMP - np.linspace(100_000_000, 0, 300).astype(np.int64)
    intensity = rng.uniform(0, 255, 300).astype(np.float32)
    swept = LidarScan(STAMP, points, intensity, times)
    plain = LidarScan(STAMP + 100_000_000, points[:1], intensity[:1])
    back = scans_read_back(tmp_path, profile, [swept, plain])
    assert len(back) == 2
    np.testing.assert_array_equal(back[0].points, points)
    np.testing.assert_array_equal(back[0].intensity, intensity)
    assert back[0].point_stamps_ns is not None
    assert np.abs(back[0].point_stamps_ns - times).max() <= 10  # float32 seconds: ~7 ns
    assert back[0].point_stamps_ns[0] == pytest.approx(STAMP - 100_000_000, abs=10)
    assert back[1].point_stamps_ns is None


def cloud2(fields: list[tuple[str, int, int]], rows: np.ndarray) -> SimpleNamespace:
    """A sensor_msgs/PointCloud2 as mcap-ros2's decoder gives it: (name, offset, datatype)."""
    return SimpleNamespace(fields=[SimpleNamespace(name=n, offset=o, datatype=d, count=1)
                                   for n, o, d in fields],
                           point_step=rows.dtype.itemsize, is_bigendian=False,
                           data=rows.tobytes())


def test_an_ouster_style_t_field_reads_as_nanoseconds_after_the_stamp():
    rows = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("pad", "<f4"),
                              ("t", "<u4"), ("ring", "<u2")])
    rows["x"], rows["z"] = [1, 2, np.nan], [3, 4, 5]
    rows["t"] = [0, 50_000_000, 99_000_000]
    msg = cloud2([("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("t", 16, 6), ("ring", 20, 4)], rows)
    points, intensity, offsets = decode_points(msg)
    assert points.shape == (2, 3) and intensity is None     # the NaN point dropped
    assert offsets.dtype == np.int64 and offsets.tolist() == [0, 50_000_000]


def test_a_float_time_field_and_none_at_all():
    rows = np.zeros(2, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("time", "<f8")])
    rows["time"] = [-0.1, -0.025]
    points, _, offsets = decode_points(
        cloud2([("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("time", 12, 8)], rows))
    assert offsets.tolist() == [-100_000_000, -25_000_000]
    _, _, none = decode_points(cloud2([("x", 0, 7), ("y", 4, 7), ("z", 8, 7)], rows))
    assert none is None
    rows["time"] = [np.nan, 1e30]  # a corrupt time field: ignored, the points kept
    points, _, ignored = decode_points(
        cloud2([("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("time", 12, 8)], rows))
    assert len(points) == 2 and ignored is None


def test_a_laserscans_time_increment_times_each_beam():
    msg = SimpleNamespace(ranges=[1.0, float("inf"), 2.0, 3.0], intensities=[], angle_min=0.0,
                          angle_increment=0.1, range_min=0.1, range_max=10.0,
                          time_increment=0.001)
    points, _, offsets = decode_points(msg)
    assert len(points) == 3 and offsets.tolist() == [0, 2_000_000, 3_000_000]
    msg.time_increment = 0.0
    assert decode_points(msg)[2] is None
