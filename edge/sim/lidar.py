"""Simulated LiDARs: beam patterns, mounting and ray casting against a synthetic scene.

The LiDAR frame is the usual one for such sensors: x forward, y left, z up. It sits apart from
the left camera (default 8 cm above it), so it sees some surfaces the camera cannot: the parallax
artefacts that the calibration package's occlusion filter removes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from edge_depth.errors import ConfigError
from edge_depth.sim.scene import Scene
from edge_depth.types import LidarScan

# Rotation taking LiDAR axes (x fwd, y left, z up) to camera axes (x right, y down, z fwd).
R_CAM_LIDAR = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def default_T_cam_lidar(height_above_m: float = 0.08) -> np.ndarray:
    """(4, 4) transform from the LiDAR frame to the left camera, LiDAR mounted above the camera."""
    T = np.eye(4)
    T[:3, :3] = R_CAM_LIDAR
    T[:3, 3] = (0.0, -height_above_m, 0.0)  # camera y points down: "above" is negative y
    return T


@dataclass(frozen=True)
class LidarPattern:
    """A beam pattern. Angles in degrees, ranges in metres, period in seconds.

    kind "spinning": one ray per (elevation, azimuth step); kind "planar": one scan plane of
    `points_per_turn` rays, pitched by `tilt_deg` (negative looks down).
    Only azimuths within ±azimuth_fov_deg/2 of forward are cast (the scene exists in front).
    """

    name: str
    kind: str
    elevations_deg: tuple[float, ...] = (0.0,)
    azimuth_step_deg: float = 0.2
    points_per_turn: int = 450
    tilt_deg: float = 0.0
    azimuth_fov_deg: float = 180.0
    range_noise_m: float = 0.01
    dropout: float = 0.03
    min_range_m: float = 0.1
    max_range_m: float = 40.0
    period_s: float = 0.1

    def __post_init__(self) -> None:
        if self.kind not in ("spinning", "planar"):
            raise ConfigError("lidar.kind", "'spinning' or 'planar'", self.kind)
        if self.kind == "spinning" and (not self.elevations_deg or self.azimuth_step_deg <= 0):
            raise ConfigError("lidar.elevations_deg/azimuth_step_deg", "beams and a step > 0",
                              (self.elevations_deg, self.azimuth_step_deg))
        if not 0 <= self.dropout < 1:
            raise ConfigError("lidar.dropout", "in [0, 1)", self.dropout)
        if self.range_noise_m < 0:
            raise ConfigError("lidar.range_noise_m", ">= 0", self.range_noise_m)

    def ray_directions(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit rays (N, 3) in the LiDAR frame and their azimuths (N,) in radians."""
        half = np.deg2rad(self.azimuth_fov_deg) / 2
        if self.kind == "spinning":
            step = np.deg2rad(self.azimuth_step_deg)
            az = np.arange(-half, half, step)
            el = np.deg2rad(np.asarray(self.elevations_deg))
            az, el = np.meshgrid(az, el)
            az, el = az.ravel(), el.ravel()
            dirs = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1)
            return dirs, az
        az_all = np.arange(self.points_per_turn) * (2 * np.pi / self.points_per_turn)
        az_all = (az_all + np.pi) % (2 * np.pi) - np.pi
        az = az_all[np.abs(az_all) <= half]
        dirs = np.stack([np.cos(az), np.sin(az), np.zeros_like(az)], 1)
        tilt = np.deg2rad(self.tilt_deg)  # pitch about the LiDAR's y axis
        c, s = np.cos(tilt), np.sin(tilt)
        pitch = np.array([[c, 0, -s], [0, 1, 0], [s, 0, c]])
        return dirs @ pitch.T, az

    def noiseless(self) -> LidarPattern:
        from dataclasses import replace

        return replace(self, range_noise_m=0.0, dropout=0.0)


def _spread(n: int, lo: float, hi: float) -> tuple[float, ...]:
    return tuple(float(x) for x in np.linspace(lo, hi, n))


PATTERNS: dict[str, LidarPattern] = {
    "beams16": LidarPattern("beams16", "spinning", _spread(16, -15.0, 15.0), 0.2),
    "beams32": LidarPattern("beams32", "spinning", _spread(32, -25.0, 15.0), 0.2),
    "beams64": LidarPattern("beams64", "spinning", _spread(64, -24.8, 2.0), 0.17),
    "planar": LidarPattern("planar", "planar", points_per_turn=450, tilt_deg=-4.0,
                           range_noise_m=0.01, dropout=0.02, max_range_m=12.0),
}


def simulate_scan(scene: Scene, pattern: LidarPattern, T_cam_lidar: np.ndarray,
                  stamp_ns: int, rng: np.random.Generator) -> LidarScan:
    """Cast the pattern's rays from the LiDAR's pose into the scene; points in the LiDAR frame.

    Range noise is Gaussian along the ray; a `dropout` fraction of returns is lost. Per-point
    stamps spread the points over one revolution (`period_s`) by azimuth.
    """
    dirs_lidar, azimuth = pattern.ray_directions()
    R, t = T_cam_lidar[:3, :3], T_cam_lidar[:3, 3]
    ranges = scene.ray_cast(t.astype(np.float64), dirs_lidar @ R.T)
    keep = np.isfinite(ranges) & (ranges >= pattern.min_range_m) & (ranges <= pattern.max_range_m)
    if pattern.dropout > 0:
        keep &= rng.random(len(ranges)) >= pattern.dropout
    ranges, dirs_lidar, azimuth = ranges[keep], dirs_lidar[keep], azimuth[keep]
    if pattern.range_noise_m > 0:
        ranges = ranges + rng.normal(0.0, pattern.range_noise_m, len(ranges))
    points = (dirs_lidar * ranges[:, None]).astype(np.float32)
    frac = (azimuth + np.pi) / (2 * np.pi)
    point_stamps = stamp_ns + (frac * pattern.period_s * 1e9).astype(np.int64)
    return LidarScan(stamp_ns=int(stamp_ns), points=points,
                     intensity=np.full(len(points), 100.0, np.float32),
                     point_stamps_ns=point_stamps)
