"""Pairing LiDAR points with stereo frames by time.

Two modes: `nearest` (a spinning 3-D LiDAR: the one revolution nearest the frame in time,
within the window) and `accumulate` (a 2-D scanner slower than the camera: every point whose
own stamp falls within ±window/2 of the frame, gathered from as many scans as that takes).
LiDAR stamps are moved into the camera's clock with the calibration's time offset first.

Sync waits, boundedly: a frame is ready when the LiDAR has delivered the scans that cover its
window (`ready`): in nearest mode a scan stamped no earlier than half a LiDAR period before
the frame (no later scan can be nearer; the period is the median spacing of recent scans),
in accumulate mode a point stamped at or after the window's end. The runner holds a frame
until it is ready or `max_wait_ms` has passed (stream time in replay, host time live), so
the pairing does not depend on the order in which a recording stored scans and frames (a
spinning LiDAR's revolution ends after the frame taken in its middle; kitti2mcap writes
scans after frames).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from edge_depth.errors import ConfigError
from edge_depth.types import LidarScan


@dataclass(frozen=True)
class SyncConfig:
    mode: str = "nearest"
    window_ms: float = 100.0
    time_offset_ns: int = 0
    keep_s: float = 2.0
    max_wait_ms: float | None = None  # None: twice the window (about two LiDAR periods)
    # each point moved by the camera's turn between its own time and the frame's, where the
    # frames show one (`edge.camera_turn.deskew`; the daemon and replay)
    deskew: bool = True

    def __post_init__(self) -> None:
        if self.mode not in ("nearest", "accumulate"):
            raise ConfigError("sync.mode", "'nearest' or 'accumulate'", self.mode)
        if not self.window_ms > 0:
            raise ConfigError("sync.window_ms", "> 0", self.window_ms)
        if self.max_wait_ms is not None and not 0 <= self.max_wait_ms < 60_000:
            raise ConfigError("sync.max_wait_ms", "0 <= ms < 60000", self.max_wait_ms)

    @property
    def wait_ms(self) -> float:
        return 2.0 * self.window_ms if self.max_wait_ms is None else float(self.max_wait_ms)


class LidarSync:
    def __init__(self, config: SyncConfig | None = None) -> None:
        self.config = config or SyncConfig()
        self._scans: deque[LidarScan] = deque()
        self.unmatched = 0
        self.matched = 0
        self.waited_out = 0       # frames that waited max_wait_ms and went on without their scans
        self._newest_ns: int | None = None  # latest stamp covered by any scan (LiDAR clock)
        self._gaps_ns: deque[int] = deque(maxlen=50)  # unmatched: nearest scan − frame
        self._stamps: deque[int] = deque(maxlen=16)   # recent scan stamps, for the period
        # the last points returned: their (median) stamp and each one's, in the camera's clock
        self.last_points_stamp_ns: int | None = None
        self.last_points_times_ns: np.ndarray | None = None

    def add(self, scan: LidarScan) -> None:
        """Keep a scan (non-finite points dropped); forget scans older than keep_s."""
        scan = scan.finite()
        last = int(scan.point_stamps_ns.max()) if scan.point_stamps_ns is not None \
            and len(scan) else scan.stamp_ns
        self._newest_ns = last if self._newest_ns is None else max(self._newest_ns, last)
        self._stamps.append(scan.stamp_ns)
        self._scans.append(scan)
        newest = max(s.stamp_ns for s in self._scans)
        while self._scans and newest - self._scans[0].stamp_ns > self.config.keep_s * 1e9:
            self._scans.popleft()

    def ready(self, stamp_ns: int) -> bool:
        """Whether the scans that cover a frame at `stamp_ns` (camera clock) have arrived."""
        if self._newest_ns is None:
            return False
        if self.config.mode == "accumulate":
            need = stamp_ns + self.config.window_ms * 1e6 / 2
        else:
            need = stamp_ns - self.period_ns() / 2
        return self._newest_ns + self.config.time_offset_ns >= need

    def period_ns(self) -> float:
        """Median spacing of recent scans (ns); 0 until two scans have arrived."""
        gaps = np.diff(np.asarray(self._stamps, np.int64))
        gaps = gaps[gaps > 0]
        return float(np.median(gaps)) if gaps.size else 0.0

    def recent(self, stamp_ns: int) -> bool:
        """Whether any scan lies within keep_s of `stamp_ns`: a LiDAR that is delivering."""
        if self._newest_ns is None:
            return False
        gap = abs(self._newest_ns + self.config.time_offset_ns - stamp_ns)
        return gap <= self.config.keep_s * 1e9

    def median_gap_ms(self) -> float | None:
        """Median of (nearest scan − frame) over recent unmatched frames, ms (camera clock):
        how far off the LiDAR's stamps are when nothing pairs."""
        return float(np.median(self._gaps_ns)) / 1e6 if self._gaps_ns else None

    def counters(self) -> dict[str, int]:
        return dict(frames_with_lidar=self.matched, frames_without_lidar=self.unmatched,
                    frames_gone_before_their_scans=self.waited_out, scans_kept=len(self._scans))

    def points_for(self, stamp_ns: int) -> np.ndarray:
        points = self._points_for(stamp_ns)
        if len(points):
            self.matched += 1
        else:
            self.unmatched += 1
            if self._scans:
                nearest = min((s.stamp_ns + self.config.time_offset_ns for s in self._scans),
                              key=lambda t: abs(t - stamp_ns))
                self._gaps_ns.append(int(nearest - stamp_ns))
        return points

    def _points_for(self, stamp_ns: int) -> np.ndarray:
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
                self.last_points_stamp_ns = best.stamp_ns + offset
                self.last_points_times_ns = None if best.point_stamps_ns is None \
                    else best.point_stamps_ns + offset
                return best.points
        else:
            chunks, times = [], []
            for scan in self._scans:
                stamps = (scan.point_stamps_ns if scan.point_stamps_ns is not None
                          else np.full(len(scan), scan.stamp_ns, np.int64)) + offset
                keep = np.abs(stamps - stamp_ns) <= half
                if keep.any():
                    chunks.append(scan.points[keep])
                    times.append(stamps[keep])
            if chunks:
                self.last_points_times_ns = np.concatenate(times)
                self.last_points_stamp_ns = int(np.median(self.last_points_times_ns))
                return np.concatenate(chunks)
        return np.zeros((0, 3), np.float32)
