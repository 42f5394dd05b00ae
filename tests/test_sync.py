"""Pairing LiDAR with frames: known offsets and jitter on synthetic streams."""

from __future__ import annotations

import numpy as np
import pytest

from edge.capture.sync import LidarSync, SyncConfig
from edge.errors import ConfigError
from edge.types import LidarScan

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
