"""Classical baselines every learned result is compared against, in the same run.

- OpenCV StereoSGBM (MODE_SGBM_3WAY, 64 disparities, grey input).
- LiDAR-only densification of a sparse disparity map: nearest valid point, or linear
  interpolation over a Delaunay triangulation (nearest outside the hull).
"""

from __future__ import annotations

import cv2
import numpy as np


def make_sgbm(num_disparities: int = 64, block_size: int = 5) -> cv2.StereoSGBM:
    """The SGBM matcher used as the classical baseline (3-way, grey, P1/P2 per OpenCV's docs)."""
    return cv2.StereoSGBM.create(
        minDisparity=0, numDisparities=num_disparities, blockSize=block_size,
        P1=8 * block_size**2, P2=32 * block_size**2, disp12MaxDiff=1, uniquenessRatio=10,
        speckleWindowSize=100, speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)


def sgbm_disparity(left: np.ndarray, right: np.ndarray,
                   matcher: cv2.StereoSGBM | None = None) -> np.ndarray:
    """(H, W) float32 disparity in pixels; 0 where SGBM found no match."""
    matcher = matcher or make_sgbm()
    raw = matcher.compute(left, right).astype(np.float32) / 16.0
    raw[raw <= 0] = 0.0
    return raw


def lidar_nearest(sparse: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Each pixel takes the disparity of the nearest valid sparse pixel; (H, W) float32."""
    if not valid.any():
        return np.zeros_like(sparse, np.float32)
    return nearest_point(sparse, valid)[0]


def nearest_point(sparse: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`lidar_nearest`'s map and each pixel's distance to that point (px): (H, W) float32
    each. `valid` must have at least one True."""
    index, distance = nearest_valid_index(valid)
    return sparse[valid].astype(np.float32)[index], distance


def nearest_valid_index(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each pixel, the nearest valid pixel as an index into `np.nonzero(valid)`'s
    (row-major) order, and the distance to it in pixels: (H, W) int, (H, W) float32.
    `valid` must have at least one True."""
    distance, labels = cv2.distanceTransformWithLabels((~valid).astype(np.uint8), cv2.DIST_L2,
                                                       5, labelType=cv2.DIST_LABEL_PIXEL)
    # labels count valid pixels from 1 in row-major scan order, the order np.nonzero returns
    return labels - 1, distance


def lidar_linear(sparse: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Linear interpolation of the sparse disparity over its Delaunay triangulation; pixels
    outside the convex hull take the nearest point's value. (H, W) float32."""
    from scipy.interpolate import LinearNDInterpolator

    nearest = lidar_nearest(sparse, valid)
    ys, xs = np.nonzero(valid)
    if len(ys) < 3:
        return nearest
    h, w = sparse.shape
    try:
        interp = LinearNDInterpolator(np.stack([xs, ys], 1), sparse[ys, xs])
    except Exception:  # degenerate (collinear) points, e.g. one planar scan line
        return nearest
    gy, gx = np.mgrid[0:h, 0:w]
    dense = interp(gx.ravel(), gy.ravel()).reshape(h, w).astype(np.float32)
    return np.where(np.isfinite(dense), dense, nearest).astype(np.float32)


def fill_row_nearest(disparity: np.ndarray) -> np.ndarray:
    """Holes (<= 0) take the value of the nearest valid pixel in the same row (rows with no
    valid pixel stay 0); (H, W) float32."""
    out = disparity.astype(np.float32).copy()
    h, w = out.shape
    cols = np.arange(w)
    for y in range(h):
        ok = out[y] > 0
        if ok.all() or not ok.any():
            continue
        xs = cols[ok]
        right = np.clip(np.searchsorted(xs, cols), 0, len(xs) - 1)
        left = np.clip(right - 1, 0, len(xs) - 1)
        nearer = np.where(np.abs(xs[left] - cols) <= np.abs(xs[right] - cols), xs[left],
                          xs[right])
        out[y] = out[y, nearer]
    return out


def sgbm_disparities_for(max_disparity_px: float) -> int:
    """SGBM's disparity count for data whose GT reaches `max_disparity_px`: rounded up to a
    multiple of 16, at least 64."""
    return max(64, int(np.ceil(max(max_disparity_px, 0.0) / 16.0)) * 16)


def sgbm_lidar_fusion(sgbm: np.ndarray, sparse: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The trivial fusion: SGBM where it matched, the nearest LiDAR point in its holes."""
    nearest = lidar_nearest(sparse, valid)
    return np.where(sgbm > 0, sgbm, nearest).astype(np.float32)
