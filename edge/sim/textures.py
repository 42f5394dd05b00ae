"""Natural and procedural grey textures for the synthetic rig.

Photos come from scikit-image's bundled sample images (no download). They are blurred slightly
so that the rendered images are band-limited: bilinear resampling of a rendered view then
reproduces the other view to well under one grey level, which is what makes the rig's ground
truth checkable.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

# Bundled with scikit-image (its stereo pairs are deliberately not used).
PHOTO_NAMES = ("brick", "grass", "gravel", "coffee", "chelsea", "camera", "rocket", "astronaut",
               "moon", "coins", "clock", "cell")
TEXTURE_BLUR_SIGMA = 1.0


def _normalised(image: np.ndarray) -> np.ndarray:
    image = image.astype(np.float32)
    image = cv2.GaussianBlur(image, (0, 0), TEXTURE_BLUR_SIGMA)
    std = float(image.std())
    return (image - float(image.mean())) / max(std, 1e-3)


@lru_cache(maxsize=1)
def photo_textures() -> tuple[np.ndarray, ...]:
    """Zero-mean, unit-std float32 grey textures from scikit-image's sample photos."""
    from skimage import data
    from skimage.color import rgb2gray

    textures = []
    for name in PHOTO_NAMES:
        image = getattr(data, name)()
        if image.ndim == 3:
            image = rgb2gray(image[..., :3]) * 255.0
        textures.append(_normalised(image))
    return tuple(textures)


def procedural_texture(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """Multi-octave value noise, zero-mean and unit-std, (size, size) float32."""
    out = np.zeros((size, size), np.float32)
    amplitude = 1.0
    cells = int(rng.integers(3, 8))
    while cells <= size // 2:
        grid = rng.standard_normal((cells, cells)).astype(np.float32)
        out += amplitude * cv2.resize(grid, (size, size), interpolation=cv2.INTER_CUBIC)
        amplitude *= float(rng.uniform(0.5, 0.8))
        cells *= 2
    return _normalised(out)
