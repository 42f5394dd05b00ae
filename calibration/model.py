"""Calibration data: a stereo pair's intrinsics and extrinsics, its rectification, and the
LiDAR-to-camera extrinsics. Units: pixels for K, metres for T, nanoseconds for time offsets."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from edge_depth.calibration.errors import CalibrationError
from edge_depth.calibration.geometry import check_image_geometry


def _array(name: str, value, shape: tuple[int, ...]) -> np.ndarray:
    arr = np.asarray(value, np.float64)
    if arr.shape != shape:
        raise CalibrationError(f"expected shape {shape}, got {arr.shape}", key=name)
    if not np.isfinite(arr).all():
        raise CalibrationError("expected finite numbers, got NaN or inf", key=name)
    return arr


def check_rotation(name: str, R: np.ndarray, tol: float = 1e-4) -> None:
    """Raise CalibrationError unless R is a proper rotation (R Rᵀ = I, det = +1)."""
    if np.abs(R @ R.T - np.eye(3)).max() > tol or abs(np.linalg.det(R) - 1) > tol:
        raise CalibrationError("expected a rotation matrix (R Rᵀ = I, det R = 1)", key=name)


# pixels a side: below MIN_IMAGE_SIDE the depth network's 1/4-resolution features and the
# block matcher's window have nothing to match (the daemon's [camera] size has the same bounds)
MIN_IMAGE_SIDE, MAX_IMAGE_SIDE = 64, 16384
MAX_DISTORTION = 1000.0  # |coefficient|: rational models reach hundreds, nothing real 1e3
MAX_BASELINE_M = 10.0
MAX_SKEW = 0.01  # |s| / fx: calibration tools fix the skew at 0; a real one is tiny
MAX_LIDAR_OFFSET_M = 10.0  # a LiDAR mounted on the same robot as the camera


def _check_K(name: str, K: np.ndarray, size: tuple[int, int]) -> None:
    """Focal lengths between 0.05 and 50 image widths, principal point within half an image
    of the image: anything else is a unit mistake or a corrupted file, not a camera."""
    w, h = size
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise CalibrationError(f"expected positive focal lengths, got fx={K[0, 0]}, "
                               f"fy={K[1, 1]}", key=name)
    if K[2, 2] != 1 or K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0:
        raise CalibrationError("expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]]", key=name)
    if abs(K[0, 1]) > MAX_SKEW * K[0, 0]:
        raise CalibrationError(f"expected a skew near zero (|s| <= {MAX_SKEW:g} fx = "
                               f"{MAX_SKEW * K[0, 0]:g} px), got {K[0, 1]:g}", key=name)
    for f, axis in ((K[0, 0], "fx"), (K[1, 1], "fy")):
        if not 0.05 * w <= f <= 50 * w:
            raise CalibrationError(f"expected {axis} within 0.05-50 image widths "
                                   f"({0.05 * w:g}-{50 * w:g} px for {w} px), got {f:g}",
                                   key=name)
    if not (-0.5 * w <= K[0, 2] <= 1.5 * w and -0.5 * h <= K[1, 2] <= 1.5 * h):
        raise CalibrationError(f"expected the principal point near the {w}x{h} image, got "
                               f"cx={K[0, 2]:g}, cy={K[1, 2]:g}", key=name)


def _image_size(size) -> tuple[int, int]:
    """(width, height) pixels, each side within MIN_IMAGE_SIDE-MAX_IMAGE_SIDE: checked first,
    so a size the engine cannot use is refused for its size, not for the intrinsics or the
    rectification it breaks."""
    w, h = (int(v) for v in size)
    if not (MIN_IMAGE_SIDE <= w <= MAX_IMAGE_SIDE and MIN_IMAGE_SIDE <= h <= MAX_IMAGE_SIDE):
        raise CalibrationError(f"expected (width, height) each in {MIN_IMAGE_SIDE}-"
                               f"{MAX_IMAGE_SIDE} px (below {MIN_IMAGE_SIDE} the depth network "
                               f"and block matching have nothing to match), got {w}x{h}",
                               key="image_size")
    return w, h


@dataclass(frozen=True)
class StereoCalibration:
    """Two pinhole cameras with OpenCV distortion; R, T map left-camera points to the right
    camera (X_r = R X_l + T, metres). image_size: (width, height) pixels.

    The rectification (R1, R2, P1, P2, Q) is derived once with cv2.stereoRectify
    (CALIB_ZERO_DISPARITY, alpha 0).
    """

    K_left: np.ndarray
    dist_left: np.ndarray
    K_right: np.ndarray
    dist_right: np.ndarray
    R: np.ndarray
    T: np.ndarray
    image_size: tuple[int, int]
    rect: dict = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        w, h = _image_size(self.image_size)
        set_(self, "image_size", (w, h))
        set_(self, "K_left", _array("left.K", self.K_left, (3, 3)))
        set_(self, "K_right", _array("right.K", self.K_right, (3, 3)))
        set_(self, "dist_left", _array("left.dist", self.dist_left, (len(self.dist_left),)))
        set_(self, "dist_right", _array("right.dist", self.dist_right,
                                        (len(self.dist_right),)))
        for name, dist in (("left.dist", self.dist_left), ("right.dist", self.dist_right)):
            if dist.size not in (4, 5, 8, 12, 14):
                raise CalibrationError(f"expected 4, 5, 8, 12 or 14 coefficients, got "
                                       f"{dist.size}", key=name)
        for name, dist in (("left.dist", self.dist_left), ("right.dist", self.dist_right)):
            if np.abs(dist).max(initial=0) > MAX_DISTORTION:
                raise CalibrationError(f"expected distortion coefficients within "
                                       f"±{MAX_DISTORTION:g}, got {dist.tolist()}", key=name)
        set_(self, "R", _array("extrinsics.R", self.R, (3, 3)))
        set_(self, "T", _array("extrinsics.T", self.T, (3,)))
        _check_K("left.K", self.K_left, (w, h))
        _check_K("right.K", self.K_right, (w, h))
        check_rotation("extrinsics.R", self.R)
        baseline = float(np.linalg.norm(self.T))
        if not 0 < baseline <= MAX_BASELINE_M:
            raise CalibrationError(f"expected a baseline in (0, {MAX_BASELINE_M:g}] m, got "
                                   f"{baseline:g} m", key="extrinsics.T")
        right_centre = -self.R.T @ self.T  # the right camera in the left camera's frame
        if right_centre[0] <= 0:
            raise CalibrationError(
                f"the right camera sits at x = {right_centre[0]:+.3f} m in the left camera's "
                "frame (it must be to the right, x > 0; with X_r = R X_l + T that means T[0] "
                "< 0): left and right are swapped, or T has the opposite sign convention",
                key="extrinsics.T")
        R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
            self.K_left, self.dist_left, self.K_right, self.dist_right, (w, h), self.R,
            self.T.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
        set_(self, "rect", dict(R1=R1, R2=R2, P1=P1, P2=P2, Q=Q))
        check_image_geometry(self.K_left, self.dist_left, self.K_right, self.dist_right,
                             self.rect, (w, h))

    @classmethod
    def ideal(cls, focal_px: float, baseline_m: float, size: tuple[int, int],
              cx: float | None = None, cy: float | None = None) -> StereoCalibration:
        """An already-rectified, distortion-free rig (what the synthetic rig renders)."""
        w, h = size
        cx = (w - 1) / 2 if cx is None else cx
        cy = (h - 1) / 2 if cy is None else cy
        K = np.array([[focal_px, 0, cx], [0, focal_px, cy], [0, 0, 1]])
        return cls(K, np.zeros(5), K.copy(), np.zeros(5), np.eye(3),
                   np.array([-baseline_m, 0.0, 0.0]), (w, h))

    @property
    def focal_px(self) -> float:
        """Rectified focal length, pixels."""
        return float(self.rect["P1"][0, 0])

    @property
    def baseline_m(self) -> float:
        """Rectified baseline, metres."""
        P2 = self.rect["P2"]
        return float(-P2[0, 3] / P2[0, 0])

    @property
    def principal_point(self) -> tuple[float, float]:
        """Rectified (cx, cy) of the left image, pixels."""
        P1 = self.rect["P1"]
        return float(P1[0, 2]), float(P1[1, 2])

    def rectifier(self) -> Rectifier:
        return Rectifier(self)


class Rectifier:
    """Rectification maps computed once; `rectify` is then two remaps."""

    def __init__(self, calib: StereoCalibration) -> None:
        r = calib.rect
        size = calib.image_size
        self.maps = [
            cv2.initUndistortRectifyMap(calib.K_left, calib.dist_left, r["R1"], r["P1"], size,
                                        cv2.CV_16SC2),
            cv2.initUndistortRectifyMap(calib.K_right, calib.dist_right, r["R2"], r["P2"], size,
                                        cv2.CV_16SC2),
        ]

    def rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return tuple(cv2.remap(img, m[0], m[1], cv2.INTER_LINEAR)  # type: ignore[return-value]
                     for img, m in zip((left, right), self.maps, strict=True))

    def pair(self, frame) -> tuple[np.ndarray, np.ndarray]:
        """A StereoFrame's rectified pair: as it is if it says it is rectified already."""
        if frame.rectified:
            return frame.left, frame.right
        return self.rectify(frame.left, frame.right)


@dataclass(frozen=True)
class LidarExtrinsics:
    """T_cam_lidar (4, 4): LiDAR frame -> left (unrectified) camera frame, metres.
    time_offset_ns: add to LiDAR stamps to express them in the camera's clock."""

    T_cam_lidar: np.ndarray
    time_offset_ns: int = 0

    def __post_init__(self) -> None:
        T = _array("lidar.T_cam_lidar", self.T_cam_lidar, (4, 4))
        if not np.allclose(T[3], [0, 0, 0, 1]):
            raise CalibrationError("expected last row [0, 0, 0, 1]", key="lidar.T_cam_lidar")
        check_rotation("lidar.T_cam_lidar", T[:3, :3])
        offset = float(np.abs(T[:3, 3]).max())  # the norm of 1e308s overflows
        if offset > MAX_LIDAR_OFFSET_M:
            raise CalibrationError(f"expected the LiDAR within {MAX_LIDAR_OFFSET_M:g} m of the "
                                   f"camera, got a translation of {offset:g} m along an axis",
                                   key="lidar.T_cam_lidar")
        object.__setattr__(self, "T_cam_lidar", T)
        object.__setattr__(self, "time_offset_ns", int(self.time_offset_ns))
