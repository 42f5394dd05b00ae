"""Running a camera of any size on a bundle of fixed input size: scale, pad, and back.

The camera's images are scaled by `scale` (by default the largest factor ≤ 1 that fits the
bundle, so a smaller camera runs at full resolution and a larger one is reduced), padded on
the right and bottom to the bundle's size (edge-replicated images, no LiDAR in the padding),
and the outputs are cropped and brought back to the camera's size with disparities divided
by the scale. A sparse LiDAR point keeps its value exactly: it moves to its scaled pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from edge_depth.errors import ConfigError


@dataclass(frozen=True)
class FitPlan:
    """camera (w, h) → scaled (w, h) inside the bundle's (w, h); scale: scaled / camera."""

    camera: tuple[int, int]
    bundle: tuple[int, int]
    scale: float

    @classmethod
    def make(cls, camera: tuple[int, int], bundle: tuple[int, int],
             scale: float | None = None) -> FitPlan:
        w, h = camera
        fit = min(1.0, bundle[0] / w, bundle[1] / h)
        if scale is None or scale == 0:
            scale = fit
        elif not 0 < scale <= 1:
            raise ConfigError("engine.scale", 'a factor in (0, 1], or "budget", "fit", "native"',
                              scale)
        elif scale > fit + 1e-9:
            raise ConfigError("engine.scale", f"at most {fit:.3f} for a {w}x{h} camera on a "
                              f'{bundle[0]}x{bundle[1]} bundle ("fit": that factor)', scale)
        return cls((int(camera[0]), int(camera[1])), (int(bundle[0]), int(bundle[1])),
                   float(scale))

    @property
    def scaled(self) -> tuple[int, int]:
        w, h = self.camera
        return (min(self.bundle[0], max(1, round(w * self.scale))),
                min(self.bundle[1], max(1, round(h * self.scale))))

    @property
    def identity(self) -> bool:
        return self.camera == self.bundle and self.scale == 1.0

    def prepare(self, left: np.ndarray, right: np.ndarray, sparse: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Camera-size (H, W) images and sparse disparity (px, 0 = none) → bundle-size ones."""
        sw, sh = self.scaled
        bw, bh = self.bundle
        if (sw, sh) != self.camera:
            sparse = self._scale_sparse(sparse)
        pad = ((0, bh - sh), (0, bw - sw))
        return self.image(left), self.image(right), np.pad(sparse.astype(np.float32), pad)

    def image(self, image: np.ndarray) -> np.ndarray:
        """A camera-size (H, W) image → bundle-size, as `prepare` brings the pair."""
        sw, sh = self.scaled
        bw, bh = self.bundle
        if (sw, sh) != self.camera:
            interp = cv2.INTER_AREA if self.scale < 1 else cv2.INTER_LINEAR
            image = cv2.resize(image, (sw, sh), interpolation=interp)
        return np.pad(image, ((0, bh - sh), (0, bw - sw)), mode="edge")

    def _scale_sparse(self, sparse: np.ndarray) -> np.ndarray:
        sw, sh = self.scaled
        out = np.zeros((sh, sw), np.float32)
        ok = np.isfinite(sparse) & (sparse > 0)
        ys, xs = np.nonzero(ok)
        sx, sy = sw / self.camera[0], sh / self.camera[1]
        u = np.clip(np.floor((xs + 0.5) * sx).astype(int), 0, sw - 1)
        v = np.clip(np.floor((ys + 0.5) * sy).astype(int), 0, sh - 1)
        out[v, u] = sparse[ys, xs] * sx  # disparity is in pixels of the scaled image
        return out

    def restore(self, image: np.ndarray, disparity: bool) -> np.ndarray:
        """A bundle-size output → camera size (disparities back in camera pixels)."""
        sw, sh = self.scaled
        out = image[:sh, :sw]
        if (sw, sh) != self.camera:
            out = cv2.resize(out, self.camera, interpolation=cv2.INTER_LINEAR)
            if disparity:
                out = out * (self.camera[0] / sw)
        return np.ascontiguousarray(out, dtype=np.float32)
