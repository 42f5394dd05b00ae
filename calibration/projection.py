"""LiDAR points to sparse disparity in a rectified stereo image.

Pure numpy. A sparse disparity map is (H, W) float32 with 0 where there is no point, plus a
(H, W) bool valid mask; disparity d = f B / z in pixels of that image.
"""

from __future__ import annotations

import numpy as np


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a (4, 4) rigid transform to (N, 3) points; returns (N, 3) float64."""
    points = np.asarray(points, np.float64)
    return points @ T[:3, :3].T + T[:3, 3]


def project_rectified(points_cam: np.ndarray, focal_px: float, cx: float, cy: float,
                      baseline_m: float, size: tuple[int, int], side: str = "left",
                      min_depth_m: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffered projection of points (N, 3), metres in the rectified left camera frame.

    size: (width, height). side "right" projects into the right camera, B metres along +x.
    Nearest point wins per pixel (rounded to the nearest pixel centre).
    Returns (sparse_disparity (H, W) float32, valid (H, W) bool).
    """
    w, h = size
    pts = np.asarray(points_cam, np.float64)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if side == "right":
        pts = pts - np.array([baseline_m, 0.0, 0.0])
    elif side != "left":
        raise ValueError(f"side: expected 'left' or 'right', got {side!r}")
    z = pts[:, 2]
    front = z > min_depth_m
    pts, z = pts[front], z[front]
    u = np.rint(focal_px * pts[:, 0] / z + cx).astype(np.int64)
    v = np.rint(focal_px * pts[:, 1] / z + cy).astype(np.int64)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    u, v, z = u[inside], v[inside], z[inside]
    disparity = np.zeros((h, w), np.float32)
    valid = np.zeros((h, w), bool)
    if z.size == 0:
        return disparity, valid
    # Far to near, so the nearest point is written last and wins.
    order = np.argsort(-z, kind="stable")
    flat = v[order] * w + u[order]
    d = (focal_px * baseline_m / z[order]).astype(np.float32)
    disparity.ravel()[flat] = d
    valid.ravel()[flat] = True
    return disparity, valid
