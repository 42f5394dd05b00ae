"""Core data types passed between pipeline stages.

Units: images in pixels, distances in metres, times in integer nanoseconds. Each type is a frozen
dataclass that validates its arrays on construction, so a bad frame is rejected where it enters.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from edge_depth.errors import InvalidDataError


def _check_image(name: str, image: np.ndarray) -> None:
    if not isinstance(image, np.ndarray):
        raise InvalidDataError(name, "numpy array", type(image).__name__)
    if image.ndim != 2:
        raise InvalidDataError(f"{name}.shape", "(H, W) grey image", image.shape)
    if image.dtype != np.uint8:
        raise InvalidDataError(f"{name}.dtype", "uint8", image.dtype)
    if image.shape[0] == 0 or image.shape[1] == 0:
        raise InvalidDataError(f"{name}.shape", "non-empty image", image.shape)


@dataclass(frozen=True)
class StereoFrame:
    """One grey stereo pair.

    stamp_ns: capture time in nanoseconds (host monotonic clock unless the source says otherwise).
    seq: the source's sequence number. left, right: (H, W) uint8. rectified: True when the pair
    is already row-aligned (a rectified OAK output, the synthetic rig, a replayed rectified topic).
    """

    stamp_ns: int
    seq: int
    left: np.ndarray
    right: np.ndarray
    rectified: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.stamp_ns, (int, np.integer)) or self.stamp_ns < 0:
            raise InvalidDataError("StereoFrame.stamp_ns", "non-negative integer ns", self.stamp_ns)
        _check_image("StereoFrame.left", self.left)
        _check_image("StereoFrame.right", self.right)
        if self.left.shape != self.right.shape:
            raise InvalidDataError(
                "StereoFrame.right.shape", f"same as left {self.left.shape}", self.right.shape
            )

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return int(self.left.shape[1]), int(self.left.shape[0])


@dataclass(frozen=True)
class LidarScan:
    """One LiDAR revolution (or an accumulated window of points).

    stamp_ns: time of the scan in nanoseconds (the source's clock). points: (N, 3) float32 metres
    in the LiDAR's own frame. intensity: optional (N,) float32. point_stamps_ns: optional (N,)
    int64 per-point times in the same clock as stamp_ns.
    """

    stamp_ns: int
    points: np.ndarray
    intensity: np.ndarray | None = None
    point_stamps_ns: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.stamp_ns, (int, np.integer)) or self.stamp_ns < 0:
            raise InvalidDataError("LidarScan.stamp_ns", "non-negative integer ns", self.stamp_ns)
        pts = self.points
        if not isinstance(pts, np.ndarray) or pts.ndim != 2 or pts.shape[1] != 3:
            raise InvalidDataError("LidarScan.points", "(N, 3) array", getattr(pts, "shape", pts))
        if pts.dtype != np.float32:
            raise InvalidDataError("LidarScan.points.dtype", "float32", pts.dtype)
        n = pts.shape[0]
        if self.intensity is not None:
            if self.intensity.shape != (n,) or self.intensity.dtype != np.float32:
                raise InvalidDataError(
                    "LidarScan.intensity",
                    f"({n},) float32",
                    f"{self.intensity.shape} {self.intensity.dtype}",
                )
        if self.point_stamps_ns is not None:
            if self.point_stamps_ns.shape != (n,) or self.point_stamps_ns.dtype != np.int64:
                raise InvalidDataError(
                    "LidarScan.point_stamps_ns",
                    f"({n},) int64",
                    f"{self.point_stamps_ns.shape} {self.point_stamps_ns.dtype}",
                )

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def finite(self) -> LidarScan:
        """The same scan without points that have a NaN or infinite coordinate."""
        keep = np.isfinite(self.points).all(axis=1)
        if keep.all():
            return self
        return LidarScan(
            stamp_ns=self.stamp_ns,
            points=self.points[keep],
            intensity=None if self.intensity is None else self.intensity[keep],
            point_stamps_ns=None if self.point_stamps_ns is None else self.point_stamps_ns[keep],
        )


@dataclass(frozen=True)
class DepthResult:
    """Dense output for one frame, in the rectified left image.

    disparity: (H, W) float32 pixels. depth: (H, W) float32 metres (0 where invalid).
    valid: (H, W) bool. iterations: GRU update steps actually run.
    timings_ms: stage name -> milliseconds for this frame. confidence: (H, W) float32 0-1,
    the model's estimate that the disparity is within 1 px (None when the model has none).
    selected_px: pixels the LiDAR selection replaced by a LiDAR value (None when the engine
    ran no selection). refined_px: pixels the band refinement moved by more than 1 px (its
    match or the LiDAR's nearest point; None when it did not run).
    counted_px: the pixels of the grid those counts were taken on (the engine's, scaled and
    padded; None: the disparity's own), so that a share is count / counted_px.
    lidar_offset: the LiDAR map's misregistration as its depth edges against the image's show
    it (`edge.runtime.lidar_align.Offset`; put back where `.moves`), None when not looked for.
    lidar_noise_px: the LiDAR map's range noise, px (`edge.runtime.lidar_rows.noise_level`,
    measured by the alignment or the smoothing; with `denoise_lidar` smoothed above its
    threshold), None when not measured.
    """

    stamp_ns: int
    disparity: np.ndarray
    depth: np.ndarray
    valid: np.ndarray
    iterations: int
    timings_ms: dict[str, float] = field(default_factory=dict)
    confidence: np.ndarray | None = None
    selected_px: int | None = None
    refined_px: int | None = None
    counted_px: int | None = None
    lidar_offset: Any = None
    lidar_noise_px: float | None = None

    def __post_init__(self) -> None:
        shape = getattr(self.disparity, "shape", None)
        if not isinstance(self.disparity, np.ndarray) or self.disparity.ndim != 2:
            raise InvalidDataError("DepthResult.disparity", "(H, W) array", shape)
        for name in ("disparity", "depth"):
            arr = getattr(self, name)
            if not isinstance(arr, np.ndarray) or arr.dtype != np.float32 or arr.shape != shape:
                raise InvalidDataError(
                    f"DepthResult.{name}", f"{shape} float32", getattr(arr, "shape", arr)
                )
        if (
            not isinstance(self.valid, np.ndarray)
            or self.valid.dtype != np.bool_
            or self.valid.shape != shape
        ):
            raise InvalidDataError("DepthResult.valid", f"{shape} bool", self.valid.shape)
        if self.iterations < 0:
            raise InvalidDataError("DepthResult.iterations", ">= 0", self.iterations)
        if self.confidence is not None and (
            not isinstance(self.confidence, np.ndarray)
            or self.confidence.dtype != np.float32
            or self.confidence.shape != shape
        ):
            raise InvalidDataError("DepthResult.confidence", f"{shape} float32",
                                   getattr(self.confidence, "shape", self.confidence))


# -- events a recording carries besides frames and scans (edge.capture.replay) -------------
@dataclass(frozen=True)
class Calibration:
    """Calibration found in the recording: the TOML text of ours, or (f, cx, cy, B, size)
    from rectified CameraInfo / CameraCalibration pairs."""

    stamp_ns: int
    toml: str | None = None
    focal_px: float | None = None
    principal_point: tuple[float, float] | None = None
    baseline_m: float | None = None
    size: tuple[int, int] | None = None


@dataclass(frozen=True)
class GroundTruth:
    stamp_ns: int
    disparity: np.ndarray
