"""Pairing LiDAR points with stereo frames by time.

Two modes: `nearest` (a spinning 3-D LiDAR: the one revolution nearest the frame in time,
within the window) and `accumulate` (a 2-D scanner slower than the camera: every point whose
own stamp falls within ±window/2 of the frame, gathered from as many scans as that takes).
LiDAR stamps are moved into the camera's clock with the calibration's time offset first.
Causal: a frame is paired with the scans received before it, so the daemon adds no latency.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from edge.errors import ConfigError
from edge.types import LidarScan


@dataclass(frozen=True)
class SyncConfig:
    mode: str = "nearest"
    window_ms: float = 100.0
    time_offset_ns: int = 0
    keep_s: float = 2.0

    def __post_init__(self) -> None:
        if self.mode not in ("nearest", "accumulate"):
            raise ConfigError("sync.mode", "'nearest' or 'accumulate'", self.mode)
        if not self.window_ms > 0:
            raise ConfigError("sync.window_ms", "> 0", self.window_ms)


class LidarSync:
    def __init__(self, config: SyncConfig | None = None) -> None:
        self.config = config or SyncConfig()
        self._scans: deque[LidarScan] = deque()
        self.unmatched = 0

    def add(self, scan: LidarScan) -> None:
        """Keep a scan (non-finite points dropped); forget scans older than keep_s."""
        scan = scan.finite()
        self._scans.append(scan)
        newest = max(s.stamp_ns for s in self._scans)
        while self._scans and newest - self._scans[0].stamp_ns > self.config.keep_s * 1e9:
            self._scans.popleft()

    def points_for(self, stamp_ns: int) -> np.ndarray:
        """(N, 3) float32 LiDAR points for a frame at `stamp_ns` (camera clock); (0, 3) and a
        count in `unmatched` when there are none."""
        cfg = self.config
        half = cfg.window_ms * 1e6 / 2
        offset = cfg.time_offset_ns
        if cfg.mode == "nearest":
            best = min(self._scans, key=lambda s: abs(s.stamp_ns + offset - stamp_ns),
                       default=None)
            if best is not None and abs(best.stamp_ns + offset - stamp_ns) <= half \
                    and len(best):
                return best.points
        else:
            chunks = []
            for scan in self._scans:
                stamps = (scan.point_stamps_ns if scan.point_stamps_ns is not None
                          else np.full(len(scan), scan.stamp_ns, np.int64)) + offset
                keep = np.abs(stamps - stamp_ns) <= half
                if keep.any():
                    chunks.append(scan.points[keep])
            if chunks:
                return np.concatenate(chunks)
        self.unmatched += 1
        return np.zeros((0, 3), np.float32)
