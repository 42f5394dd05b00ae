"""Procedural planar scenes seen by a rectified stereo rig, with exact disparity and occlusion.

A scene is a stack of layers. Each layer is a piece of a 3-D plane, so its disparity is affine in
the left image: d(u, v) = a0 + a1 (u - cx) + a2 (v - cy). Its outline (a convex polygon or an
ellipse) is defined in left-image coordinates, which makes the same surface patch exactly
addressable from the right view: a right pixel u_r lies on layer k when u_r + d_k(u_r, v) falls
inside the outline, with d_k the layer's right-view disparity. The background layer has no
outline. A z-buffer over disparity (nearest = largest) resolves visibility in both views.

Camera model: pinhole, rectified, focal f (px), principal point (cx, cy), left camera at the
origin, right camera at (B, 0, 0) metres; x right, y down, z forward (OpenCV).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from edge_depth.calibration.sampling import sample_bilinear
from edge_depth.errors import ConfigError

LEFT, RIGHT = "left", "right"


@dataclass(frozen=True)
class RigConfig:
    """The virtual stereo rig and the scene statistics (pixels, metres, grey levels)."""

    width: int = 640
    height: int = 400
    focal_px: float = 450.0
    baseline_m: float = 0.075
    min_objects: int = 3
    max_objects: int = 15
    min_disparity_px: float = 1.5
    max_disparity_px: float = 60.0
    sensor_noise_std: float = 1.5
    gain_jitter: float = 0.08
    bias_jitter: float = 6.0

    def __post_init__(self) -> None:
        if self.width < 16 or self.height < 16:
            raise ConfigError("size", "at least 16x16 pixels", (self.width, self.height))
        if self.focal_px <= 0:
            raise ConfigError("focal_px", "> 0", self.focal_px)
        if self.baseline_m <= 0:
            raise ConfigError("baseline_m", "> 0", self.baseline_m)
        if not 0 <= self.min_objects <= self.max_objects:
            raise ConfigError("min_objects/max_objects", "0 <= min <= max",
                              (self.min_objects, self.max_objects))
        if not 0 < self.min_disparity_px < self.max_disparity_px:
            raise ConfigError("min/max_disparity_px", "0 < min < max",
                              (self.min_disparity_px, self.max_disparity_px))
        if self.sensor_noise_std < 0 or self.gain_jitter < 0 or self.bias_jitter < 0:
            raise ConfigError("noise", "non-negative", self.sensor_noise_std)

    @property
    def cx(self) -> float:
        return (self.width - 1) / 2.0

    @property
    def cy(self) -> float:
        return (self.height - 1) / 2.0

    def noiseless(self) -> RigConfig:
        """The same rig with photometric noise and gain/bias differences switched off."""
        from dataclasses import replace

        return replace(self, sensor_noise_std=0.0, gain_jitter=0.0, bias_jitter=0.0)


# an outline's bounding box widened by this much before its exact test, so that rounding in
# the test can never meet the box's edge
BOX_MARGIN_PX = 1.0


@dataclass(frozen=True)
class Layer:
    """One planar surface patch.

    plane: (a0, a1, a2), left disparity d = a0 + a1 (u - cx) + a2 (v - cy) in pixels.
    kind: "background", "polygon" (vertices (K, 2), counter-clockwise in image coordinates) or
    "ellipse" (centre, semi-axes, angle). The outline lives in left-image pixel coordinates.
    texture: index into the scene's texture list; tex_affine (2, 3) maps (u_left, v) to texture
    pixels, or tex_homography (3, 3) where given (a moved layer: a plane's texture seen from
    another pose, `edge.sim.motion`), (x, y, w) = H (u_left, v, 1) and the texture pixel
    (x / w, y / w); brightness, contrast: grey levels.
    """

    plane: tuple[float, float, float]
    kind: str
    vertices: np.ndarray | None = None
    centre: tuple[float, float] = (0.0, 0.0)
    axes: tuple[float, float] = (1.0, 1.0)
    angle: float = 0.0
    texture: int = 0
    tex_affine: np.ndarray | None = None
    tex_homography: np.ndarray | None = None
    brightness: float = 128.0
    contrast: float = 40.0

    def disparity(self, view: str, u: np.ndarray, v: np.ndarray, cx: float, cy: float
                  ) -> np.ndarray:
        """Disparity (px) of this plane at pixel positions (u, v) of the given view."""
        a0, a1, a2 = self.plane
        d = a0 + a1 * (u - cx) + a2 * (v - cy)
        if view == RIGHT:
            # u_left = u_right + d  =>  d = (a0 + a1 (u_r - cx) + a2 (v - cy)) / (1 - a1)
            d = d / (1.0 - a1)
        return d

    def contains(self, u_left: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Whether left-image positions (u_left, v) lie inside the outline."""
        if self.kind == "background":
            return np.ones(np.broadcast(u_left, v).shape, bool)
        if self.kind == "ellipse":
            c, s = np.cos(self.angle), np.sin(self.angle)
            du, dv = u_left - self.centre[0], v - self.centre[1]
            p = (c * du + s * dv) / self.axes[0]
            q = (-s * du + c * dv) / self.axes[1]
            return p * p + q * q <= 1.0
        verts = self.vertices
        assert verts is not None, 'a "polygon" layer has its vertices'
        inside = np.ones(np.broadcast(u_left, v).shape, bool)
        for i in range(len(verts)):
            x0, y0 = verts[i]
            x1, y1 = verts[(i + 1) % len(verts)]
            inside &= (x1 - x0) * (v - y0) - (y1 - y0) * (u_left - x0) >= 0
        return inside

    def left_bbox(self) -> tuple[float, float, float, float] | None:
        """(u_min, u_max, v_min, v_max) of the outline in the left image; None = unbounded."""
        if self.kind == "background":
            return None
        if self.kind == "ellipse":
            r = max(self.axes)
            return (self.centre[0] - r, self.centre[0] + r, self.centre[1] - r, self.centre[1] + r)
        verts = self.vertices
        assert verts is not None, 'a "polygon" layer has its vertices'
        return (float(verts[:, 0].min()), float(verts[:, 0].max()),
                float(verts[:, 1].min()), float(verts[:, 1].max()))

    def plane_normal(self, focal_px: float) -> np.ndarray:
        """n with n . P = f B for points P (metres, left camera frame) on this plane."""
        a0, a1, a2 = self.plane
        return np.array([a1 * focal_px, a2 * focal_px, a0], np.float64)


class Scene:
    """A set of layers seen by a rig: renders views and answers visibility queries exactly."""

    def __init__(self, rig: RigConfig, layers: list[Layer], textures: list[np.ndarray]) -> None:
        self.rig = rig
        self.layers = layers
        self.textures = textures

    def _view_bbox(self, layer: Layer, view: str) -> tuple[int, int, int, int]:
        """Integer pixel window (x0, x1, y0, y1), end-exclusive, that can hold the layer."""
        w, h = self.rig.width, self.rig.height
        box = layer.left_bbox()
        if box is None:
            return 0, w, 0, h
        u0, u1, v0, v1 = box
        if view == RIGHT:
            corners_u = np.array([u0, u1, u0, u1])
            corners_v = np.array([v0, v0, v1, v1])
            d = layer.disparity(LEFT, corners_u, corners_v, self.rig.cx, self.rig.cy)
            u0, u1 = u0 - float(d.max()) - 1, u1 - float(d.min()) + 1
        x0, x1 = max(int(np.floor(u0)), 0), min(int(np.ceil(u1)) + 1, w)
        y0, y1 = max(int(np.floor(v0)), 0), min(int(np.ceil(v1)) + 1, h)
        return x0, x1, y0, y1

    def render_depth_order(self, view: str) -> tuple[np.ndarray, np.ndarray]:
        """Z-buffered (H, W) float32 disparity (px) and (H, W) int16 owning layer of a view."""
        h, w = self.rig.height, self.rig.width
        disparity = np.full((h, w), -np.inf, np.float64)
        owner = np.full((h, w), -1, np.int16)
        for k, layer in enumerate(self.layers):
            x0, x1, y0, y1 = self._view_bbox(layer, view)
            if x0 >= x1 or y0 >= y1:
                continue
            u, v = np.meshgrid(np.arange(x0, x1, dtype=np.float64),
                               np.arange(y0, y1, dtype=np.float64))
            d = layer.disparity(view, u, v, self.rig.cx, self.rig.cy)
            u_left = u + d if view == RIGHT else u
            wins = layer.contains(u_left, v) & (d > disparity[y0:y1, x0:x1])
            disparity[y0:y1, x0:x1][wins] = d[wins]
            owner[y0:y1, x0:x1][wins] = k
        return disparity.astype(np.float32), owner

    def nearest_disparity_at(self, view: str, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Disparity (px) of the nearest surface at continuous positions (u, v) of a view."""
        u, v = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64))
        shape, u, v = u.shape, u.ravel(), v.ravel()
        best = np.full(u.shape, -np.inf)
        # positions by row, so that the rows a layer's outline spans are one run of them (a
        # frame's occlusion query would otherwise test every pixel against every layer); a
        # frame's positions come by row already, and their runs are slices
        by_row = None if bool(np.all(v[1:] >= v[:-1])) else np.argsort(v, kind="stable")
        rows = v if by_row is None else v[by_row]
        for layer in self.layers:
            box = layer.left_bbox()
            lo, hi = 0, len(rows)
            if box is not None:
                u0, u1, v0, v1 = box
                lo = int(np.searchsorted(rows, v0 - BOX_MARGIN_PX, "left"))
                hi = int(np.searchsorted(rows, v1 + BOX_MARGIN_PX, "right"))
            at = slice(lo, hi) if by_row is None else by_row[lo:hi]
            u_at, v_at = u[at], v[at]
            d = layer.disparity(view, u_at, v_at, self.rig.cx, self.rig.cy)
            u_left = u_at + d if view == RIGHT else u_at
            nearer = d > best[at]
            if box is not None:
                nearer &= (u_left >= u0 - BOX_MARGIN_PX) & (u_left <= u1 + BOX_MARGIN_PX)
            hit = np.flatnonzero(nearer)
            hit = hit[layer.contains(u_left[hit], v_at[hit])]
            best[lo + hit if by_row is None else by_row[lo:hi][hit]] = d[hit]
        return best.reshape(shape)

    def occlusion(self, view: str, disparity: np.ndarray, tol_px: float = 1e-4) -> np.ndarray:
        """(H, W) bool: pixels of `view` whose surface point is not visible in the other view.

        The correspondent of left pixel u is u - d in the right image (u + d for a right pixel).
        It is occluded when it falls outside the other image or when the other view's nearest
        surface there is nearer (larger disparity) than this pixel's own surface.
        """
        h, w = disparity.shape
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        if view == LEFT:
            u_other, other = u - disparity, RIGHT
        else:
            u_other, other = u + disparity, LEFT
        outside = (u_other < -0.5) | (u_other > w - 0.5)
        nearest = self.nearest_disparity_at(other, u_other, v)
        return outside | (nearest > disparity + tol_px)

    def render_image(self, view: str, owner: np.ndarray, disparity: np.ndarray) -> np.ndarray:
        """(H, W) float32 radiance of a view before camera gain, bias and noise."""

        image = np.zeros(owner.shape, np.float32)
        for k, layer in enumerate(self.layers):
            ys, xs = np.nonzero(owner == k)
            if ys.size == 0:
                continue
            u_left = xs.astype(np.float64)
            if view == RIGHT:
                u_left = u_left + disparity[ys, xs]
            seen = np.stack([u_left, ys.astype(np.float64), np.ones_like(u_left)])
            if layer.tex_homography is not None:
                coords = layer.tex_homography @ seen
                coords = coords[:2] / coords[2]
            else:
                assert layer.tex_affine is not None, "a textured layer has its affine map"
                coords = layer.tex_affine @ seen
            sample = sample_bilinear(self.textures[layer.texture], coords[0], coords[1],
                                     cv2.BORDER_WRAP)
            image[ys, xs] = layer.brightness + layer.contrast * sample
        return image

    def ray_cast(self, origin: np.ndarray, directions: np.ndarray,
                 min_depth_m: float = 0.1) -> np.ndarray:
        """Distance (m) along unit rays (N, 3) from `origin` (3,) in the left camera frame to the
        nearest surface; inf where a ray hits nothing in front of the rig."""
        f, cx, cy, b = self.rig.focal_px, self.rig.cx, self.rig.cy, self.rig.baseline_m
        best = np.full(len(directions), np.inf)
        for layer in self.layers:
            n = layer.plane_normal(f)
            denom = directions @ n
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (f * b - n @ origin) / denom
            hit = origin[None, :] + t[:, None] * directions
            ok = (denom > 1e-12) & (t > 0) & (hit[:, 2] > min_depth_m) & (t < best)
            if not ok.any():
                continue
            u = f * hit[ok, 0] / hit[ok, 2] + cx
            v = f * hit[ok, 1] / hit[ok, 2] + cy
            inside = layer.contains(u, v)
            idx = np.flatnonzero(ok)[inside]
            best[idx] = t[idx]
        return best
