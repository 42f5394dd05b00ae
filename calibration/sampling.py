"""Bilinear sampling of an image at scattered float positions (OpenCV remap, any count)."""

from __future__ import annotations

import cv2
import numpy as np

_COLS = 1024  # cv2.remap wants maps narrower and shorter than SHRT_MAX


def sample_bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray,
                    border_mode: int = cv2.BORDER_CONSTANT, border_value: float = np.nan
                    ) -> np.ndarray:
    """Values of a (H, W) float32 image at pixel positions x, y (N,); (N,) float32."""
    n = x.size
    rows = max(-(-n // _COLS), 1)
    map_x = np.zeros(rows * _COLS, np.float32)
    map_y = np.zeros(rows * _COLS, np.float32)
    map_x[:n], map_y[:n] = np.ravel(x), np.ravel(y)
    out = cv2.remap(image, map_x.reshape(rows, _COLS), map_y.reshape(rows, _COLS),
                    cv2.INTER_LINEAR, borderMode=border_mode, borderValue=border_value)
    return out.ravel()[:n]
