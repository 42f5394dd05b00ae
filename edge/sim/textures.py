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


# Photos from Debian's opencv-doc examples (never aloe*, never the stereo pairs left*/right*,
# never tsukuba*): used when the package's data folder is found (tools/real_pairs.py copies
# them to data/textures), otherwise the world uses the other sources alone.
OPENCV_DOC_PHOTOS = ("baboon.jpg", "building.jpg", "butterfly.jpg", "fruits.jpg", "home.jpg",
                     "leuvenA.jpg", "messi5.jpg", "orange.jpg", "apple.jpg", "starry_night.jpg",
                     "stuff.jpg", "graf1.png", "aero1.jpg", "squirrel_cls.jpg", "smarties.png",
                     "blox.jpg", "board.jpg", "box_in_scene.png", "basketball1.png",
                     "Blender_Suzanne1.jpg", "ela_original.jpg", "licenseplate_motion.jpg",
                     "sudoku.png", "cards.png", "chicky_512.png")
OPENCV_DOC_DIRS = ("data/textures", "/usr/share/doc/opencv-doc/examples/data")


def opencv_doc_textures() -> tuple[np.ndarray, ...]:
    """The opencv-doc photos (grey, normalised) from the first folder of OPENCV_DOC_DIRS (or
    $EDGE_TEXTURE_DIR) that holds them; empty when none does."""
    import os
    from pathlib import Path

    dirs = [os.environ["EDGE_TEXTURE_DIR"]] if os.environ.get("EDGE_TEXTURE_DIR") else []
    for folder in map(Path, dirs + list(OPENCV_DOC_DIRS)):
        if (folder / OPENCV_DOC_PHOTOS[0]).exists():
            images = [cv2.imread(str(folder / name), cv2.IMREAD_GRAYSCALE)
                      for name in OPENCV_DOC_PHOTOS]
            return tuple(_normalised(im) for im in images if im is not None)
    return ()


def repetitive_texture(kind: str, period_px: float, size: int = 256) -> np.ndarray:
    """Stripes, a checkerboard or a brick-like grid: the repetitive surfaces on which a
    matcher finds several equally good disparities."""
    v, u = np.mgrid[0:size, 0:size].astype(np.float32)
    phase = 2 * np.pi / period_px
    if kind == "stripes":
        out = np.sin(u * phase)
    elif kind == "checker":
        out = np.sign(np.sin(u * phase) * np.sin(v * phase))
    else:
        row = np.floor(v / period_px)
        out = ((np.mod(v, period_px) < 2) | (np.mod(u + (row % 2) * period_px, 2 * period_px)
                                              < 2)).astype(np.float32)
    return _normalised(out)


@lru_cache(maxsize=2)
def texture_pyramids(levels: int) -> tuple[tuple[np.ndarray, ...], ...]:
    """The things world's texture pool, each texture as a Gaussian pyramid of `levels`
    (level k halves level k-1): scikit-image and opencv-doc photos, value noise, repetitive
    patterns and one nearly flat texture (textureless walls, with the material's contrast)."""
    rng = np.random.default_rng(12345)
    pool = list(photo_textures()) + list(opencv_doc_textures())
    pool += [procedural_texture(rng) for _ in range(6)]
    pool += [repetitive_texture(kind, p) for kind in ("stripes", "checker", "bricks")
             for p in (6.0, 16.0)]
    pool.append(0.05 * procedural_texture(rng))
    out = []
    for texture in pool:
        pyramid = [texture.astype(np.float32)]
        for _ in range(levels - 1):
            pyramid.append(cv2.pyrDown(pyramid[-1]))
        out.append(tuple(pyramid))
    return tuple(out)
