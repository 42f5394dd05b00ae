"""Pairing LiDAR with frames: known offsets and jitter on synthetic streams."""

from __future__ import annotations

import numpy as np
import pytest

from edge_depth.capture.sync import LidarSync, SyncConfig
from edge_depth.errors import ConfigError
from edge_depth.types import LidarScan

MS = 1_000_000


def scan(stamp_ns: int, tag: float, n: int = 4, point_stamps=None) -> LidarScan:
    pts = np.full((n, 3), tag, np.float32)
    ps = None if point_stamps is None else np.asarray(point_stamps, np.int64)
    return LidarScan(int(stamp_ns), pts, point_stamps_ns=ps)


def test_nearest_revolution_with_a_clock_offset_and_jitter():
    rng = np.random.default_rng(0)
    offset = -37 * MS  # LiDAR clock runs 37 ms ahead of the camera's
    sync = LidarSync(SyncConfig("nearest", window_ms=60, time_offset_ns=offset))
    for k in range(20):  # 10 Hz spinning LiDAR, ±3 ms jitter, in its own clock
        sync.add(scan(k * 100 * MS - offset + int(rng.integers(-3, 4)) * MS, float(k)))
    for k in range(1, 19):
        frame = k * 100 * MS + int(rng.integers(-20, 21)) * MS  # camera frames near scan k
        assert float(sync.points_for(frame)[0, 0]) == k
    # a frame far from every scan gets nothing, and it is counted
    assert len(sync.points_for(5_000 * MS)) == 0 and sync.unmatched == 1


def test_accumulate_gathers_points_by_their_own_stamps_across_scans():
    sync = LidarSync(SyncConfig("accumulate", window_ms=40))
    # a 2-D scanner's scans every 100 ms, one point every 10 ms
    for k in range(3):
        stamps = [k * 100 * MS + j * 10 * MS for j in range(10)]
        sync.add(scan(k * 100 * MS, float(k), n=10, point_stamps=stamps))
    pts = sync.points_for(100 * MS)  # ±20 ms: 80, 90 of scan 0 and 100, 110, 120 of scan 1
    assert sorted(pts[:, 0].tolist()) == [0.0, 0.0, 1.0, 1.0, 1.0]


def test_old_scans_are_forgotten_and_bad_settings_rejected():
    sync = LidarSync(SyncConfig("nearest", keep_s=0.5))
    for k in range(20):
        sync.add(scan(k * 100 * MS, float(k)))
    assert len(sync._scans) == 6
    with pytest.raises(ConfigError, match="sync.mode"):
        SyncConfig("latest")
    with pytest.raises(ConfigError, match="window_ms"):
        SyncConfig(window_ms=0)


def test_a_frame_is_ready_once_no_later_scan_could_pair_better():
    sync = LidarSync(SyncConfig("nearest", window_ms=100))
    assert not sync.ready(0)                       # nothing yet
    sync.add(scan(0, 0.0))
    assert not sync.ready(30 * MS)                 # period unknown: wait for a later scan
    sync.add(scan(100 * MS, 1.0))                  # period 100 ms
    assert sync.ready(140 * MS)                    # 40 ms after the newest: nothing nearer
    assert not sync.ready(160 * MS)                # the next scan (200 ms) would be nearer
    acc = LidarSync(SyncConfig("accumulate", window_ms=40))
    acc.add(scan(0, 0.0, n=3, point_stamps=[0, 10 * MS, 20 * MS]))
    assert acc.ready(0) and not acc.ready(1 * MS)  # needs points up to frame + 20 ms


def test_counters_and_the_stamp_gap_of_unpaired_frames():
    sync = LidarSync(SyncConfig("nearest", window_ms=50, max_wait_ms=30))
    assert sync.config.wait_ms == 30 and SyncConfig(window_ms=50).wait_ms == 100
    sync.add(scan(1_000 * MS, 1.0))
    assert len(sync.points_for(1_010 * MS)) == 4
    assert len(sync.points_for(3_000 * MS)) == 0   # 2 s away: a clock problem
    assert sync.counters()["frames_with_lidar"] == 1
    assert sync.counters()["frames_without_lidar"] == 1
    assert sync.median_gap_ms() == pytest.approx(-2_000.0)
    with pytest.raises(ConfigError, match="max_wait_ms"):
        SyncConfig(max_wait_ms=-1)
