"""The synthetic rig as a virtual robot: a source of rendered frames, scans and ground truth.

Each scene is one moment: the LiDAR scan is stamped `lidar_lag_ms` before the frame (a
revolution that ended just before the exposure), the frame at `period_ms` intervals. With a
`motion` (`edge.sim.motion`) every frame is the same world moved to the frame's time, with its
ground truth, and `scan_every` frames share one scan (a camera faster than the LiDAR).
"""

from __future__ import annotations

from edge_depth.calibration.model import LidarExtrinsics, StereoCalibration
from edge_depth.capture import Source
from edge_depth.sim import RigConfig, make_sample
from edge_depth.sim.lidar import default_T_cam_lidar
from edge_depth.sim.motion import Motion, moving_sample
from edge_depth.types import GroundTruth, LidarScan


class SimSource(Source):
    def __init__(self, count: int, seed: int = 0, rig: RigConfig | None = None,
                 lidar: str = "beams16", period_ms: float = 100.0, lidar_lag_ms: float = 5.0,
                 start_ns: int = 1_000_000_000, realtime: bool = False,
                 distinct: int | None = None, motion: Motion | None = None,
                 scan_every: int = 1) -> None:
        """`distinct`: render only that many scenes and cycle through them (a live sim
        camera must cost the host what a camera does, ~nothing: rendering one takes longer
        than a frame period). `motion`: one world moving (`edge.sim.motion`) instead of a
        new scene a frame; `scan_every`: a scan with every that many frames."""
        if scan_every < 1:
            raise ValueError(f"scan_every: >= 1, got {scan_every}")
        self.count, self.seed, self.rig, self.lidar = count, seed, rig or RigConfig(), lidar
        self.distinct, self.motion, self.scan_every = distinct, motion, scan_every
        self._cache: dict[int, object] = {}
        self.period_ns, self.lag_ns = int(period_ms * 1e6), int(lidar_lag_ms * 1e6)
        self.start_ns = start_ns
        self.realtime = realtime
        super().__init__()
        self.frames = self.scans = 0

    @property
    def calibration(self) -> tuple[StereoCalibration, LidarExtrinsics]:
        r = self.rig
        stereo = StereoCalibration.ideal(r.focal_px, r.baseline_m, (r.width, r.height), r.cx,
                                         r.cy)
        return stereo, LidarExtrinsics(default_T_cam_lidar())

    def _sample(self, i: int):
        """Frame i: a scene of its own, or the moving world at frame i's time; with
        `distinct`, the first `distinct` of them rendered once and looped — a moving world
        played forward and back (the robot reversing), so that its loop has no scene cut."""
        key = i if self.distinct is None else _looped(i, self.distinct, self.motion is not None)
        if key in self._cache:
            return self._cache[key]
        if self.motion is not None:
            sample = moving_sample(self.seed, key * self.period_ns / 1e9, self.motion, self.rig,
                                   self.lidar, frame=key)
        else:
            sample = make_sample(self.seed + key, self.rig, self.lidar)
        if self.distinct is not None:
            self._cache[key] = sample
        return sample

    def __iter__(self):
        import time

        for i in range(min(self.distinct or 0, self.count)):  # before the camera's clock
            self._sample(i)
        t0 = time.monotonic()
        for i in range(self.count):
            if self.realtime:  # a frame every period_ms, like a camera
                self._stop.wait(max(0.0, t0 + i * self.period_ns / 1e9 - time.monotonic()))
            if self._stop.is_set():
                return
            stamp = self.start_ns + i * self.period_ns
            sample = self._sample(i)
            if i % self.scan_every == 0:
                self.scans += 1
                yield LidarScan(stamp - self.lag_ns, sample.scan.points, sample.scan.intensity)
            self.frames += 1
            yield sample.frame(stamp_ns=stamp, seq=i)
            yield GroundTruth(stamp, sample.disp_left)


def _looped(i: int, count: int, back_and_forth: bool) -> int:
    """Frame i of a loop of `count` frames: 0, 1, …, count − 1, 0, 1, … or, back and forth,
    0, 1, …, count − 1, count − 2, …, 1, 0, 1, …"""
    if not back_and_forth or count < 2:
        return i % count
    key = i % (2 * count - 2)
    return key if key < count else 2 * count - 2 - key
