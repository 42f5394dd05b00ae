"""Measures of a disparity map that need no ground truth, for judging a model on a robot's own
recordings (`edge-depth adapt`'s check frames):

- photometric error: the right image warped into the left view by the disparity, compared by
  the paper's appearance term (α · (1 − SSIM) / 2 + (1 − α) · |L1|, α = 0.85, 3×3 SSIM, images
  in 0–1) over the pixels the caller calls visible;
- held-out LiDAR error: mean |d − LiDAR| over LiDAR points that were not fed to the network;
- left-right consistency: the share of pixels whose left disparity and the right view's
  disparity at its correspondence differ by more than 1 px.

Everything is numpy + OpenCV on (H, W) arrays; disparities in pixels of the left image,
0 or non-finite = no estimate.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

ALPHA = 0.85  # the paper's SSIM / L1 balance (edge.model.losses.ALPHA)
LR_PX = 1.0


def split_points(valid: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(fed, held out): a fixed coin per LiDAR point of the (H, W) boolean `valid` mask."""
    coin = np.random.default_rng(seed).random(valid.shape) < 0.5
    return valid & coin, valid & ~coin


@lru_cache(maxsize=8)
def _pixel_grid(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """(columns (1, W), rows (H, W)) float32, read-only: the remap's grid, made once per
    size (the selections warp two or three maps a frame)."""
    xs = np.arange(w, dtype=np.float32)[None, :]
    ys = np.ascontiguousarray(np.broadcast_to(np.arange(h, dtype=np.float32)[:, None], (h, w)))
    xs.flags.writeable = ys.flags.writeable = False
    return xs, ys


def warp_right_to_left(right: np.ndarray, disparity: np.ndarray) -> np.ndarray:
    """(H, W) float32: right(x − d, y), bilinear; outside the image reads 0; a non-finite
    disparity is read as np.nan_to_num makes it."""
    columns, rows = _pixel_grid(*disparity.shape)
    disparity = np.asarray(disparity, np.float32)
    if not np.isfinite(disparity).all():
        disparity = np.nan_to_num(disparity)
    return cv2.remap(np.asarray(right, np.float32), columns - disparity, rows, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def ssim(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Per-pixel SSIM over 3×3 windows (images in 0–1), as `edge.model.losses.ssim`."""
    c1, c2 = 0.01**2, 0.03**2

    def mean(a):
        return cv2.blur(a, (3, 3), borderType=cv2.BORDER_REFLECT_101)

    mu_x, mu_y = mean(x), mean(y)
    sx, sy = mean(x * x) - mu_x**2, mean(y * y) - mu_y**2
    sxy = mean(x * y) - mu_x * mu_y
    num = (2 * mu_x * mu_y + c1) * (2 * sxy + c2)
    den = (mu_x**2 + mu_y**2 + c1) * (sx + sy + c2)
    return np.clip(num / den, -1, 1)


def photometric_error(left: np.ndarray, right: np.ndarray, disparity: np.ndarray
                      ) -> np.ndarray:
    """(H, W) per-pixel appearance error of the right image warped by `disparity` (grey 0–255
    images)."""
    img = left.astype(np.float32) / 255.0
    recon = warp_right_to_left(right, disparity) / 255.0
    return ALPHA * (1 - ssim(img, recon)) / 2 + (1 - ALPHA) * np.abs(img - recon)


def _correspondence(disparity: np.ndarray, right_disparity: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(d, inside, other): the disparity with non-finite as 0, whether its correspondence
    x − d lies inside the right image, and the right view's disparity there (all (H, W))."""
    h, w = disparity.shape
    d = np.nan_to_num(disparity)
    xr = np.rint(np.arange(w)[None, :] - d).astype(int)
    inside = (xr >= 0) & (xr < w) & (d > 0)
    other = np.nan_to_num(right_disparity[np.arange(h)[:, None], np.clip(xr, 0, w - 1)])
    return d, inside, other


def visible(disparity: np.ndarray, right_disparity: np.ndarray) -> np.ndarray:
    """(H, W) bool: the correspondence x − d lies inside the right image and nothing nearer
    covers it there (the right view's disparity at it is not more than 1 px larger)."""
    d, inside, other = _correspondence(disparity, right_disparity)
    return inside & (other <= d + LR_PX)


def lr_inconsistent_share(disparity: np.ndarray, right_disparity: np.ndarray) -> float:
    """Share (0–1) of pixels with a correspondence inside the right image whose two views'
    disparities differ by more than 1 px (occlusions count too: equal for any method)."""
    d, inside, other = _correspondence(disparity, right_disparity)
    return float((np.abs(other - d) > LR_PX)[inside].mean()) if inside.any() else float("nan")


def held_out_error(disparity: np.ndarray, lidar: np.ndarray, held_out: np.ndarray) -> float:
    """Mean |d − LiDAR| (px) over the held-out points (NaN when there are none)."""
    keep = held_out & np.isfinite(disparity)
    return float(np.abs(disparity[keep] - lidar[keep]).mean()) if keep.any() else float("nan")
