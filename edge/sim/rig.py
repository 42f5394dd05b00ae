"""The synthetic rig: random scenes, both rendered views, exact ground truth and a LiDAR scan."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from edge_depth.calibration.model import StereoCalibration
from edge_depth.calibration.projection import project_to_disparity, transform_points
from edge_depth.sim.lidar import PATTERNS, LidarPattern, default_T_cam_lidar, simulate_scan
from edge_depth.sim.scene import LEFT, RIGHT, Layer, RigConfig, Scene
from edge_depth.sim.textures import photo_textures, procedural_texture
from edge_depth.types import LidarScan, StereoFrame


@dataclass(frozen=True)
class SyntheticSample:
    """One rendered stereo pair with ground truth. Images (H, W) uint8; disparities (H, W)
    float32 px; occlusion masks (H, W) bool (True = not visible in the other view)."""

    seed: int
    left: np.ndarray
    right: np.ndarray
    disp_left: np.ndarray
    disp_right: np.ndarray
    occ_left: np.ndarray
    occ_right: np.ndarray
    scan: LidarScan
    T_cam_lidar: np.ndarray
    rig: RigConfig
    scene: Scene

    def frame(self, stamp_ns: int | None = None, seq: int | None = None) -> StereoFrame:
        return StereoFrame(stamp_ns=self.scan.stamp_ns if stamp_ns is None else stamp_ns,
                           seq=self.seed if seq is None else seq,
                           left=self.left, right=self.right, rectified=True)

    def lidar_in_camera(self) -> np.ndarray:
        """(N, 3) float64 LiDAR points in the left camera frame, metres."""
        return transform_points(self.T_cam_lidar, self.scan.points)

    def calibration(self) -> StereoCalibration:
        """The rig as a (rectified, distortion-free) stereo calibration."""
        r = self.rig
        return StereoCalibration.ideal(r.focal_px, r.baseline_m, (r.width, r.height), r.cx, r.cy)

    def sparse_disparity(self, side: str = "left", filtered: bool = True
                         ) -> tuple[np.ndarray, np.ndarray]:
        """The scan projected into one view as disparity, with the occlusion filter
        (`calibration.projection.project_to_disparity`) unless filtered=False."""
        return project_to_disparity(self.scan.points, self.calibration(), self.T_cam_lidar,
                                    side, filter_occlusions=filtered)


def _convex_polygon(rng: np.random.Generator, centre: np.ndarray, radius: float) -> np.ndarray:
    k = int(rng.integers(5, 12))
    angle = rng.uniform(0, 2 * np.pi, k)
    aspect = rng.uniform(0.4, 1.0)
    rad = radius * np.sqrt(rng.uniform(0.3, 1.0, k))
    pts = np.stack([rad * np.cos(angle), aspect * rad * np.sin(angle)], 1)
    rot = rng.uniform(0, np.pi)
    c, s = np.cos(rot), np.sin(rot)
    pts = pts @ np.array([[c, -s], [s, c]]).T + centre
    hull = cv2.convexHull(pts.astype(np.float32)).reshape(-1, 2).astype(np.float64)
    # Orient so that the interior is on the side Layer.contains tests for.
    x, y = hull[:, 0], hull[:, 1]
    signed_area = np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    return hull if signed_area > 0 else hull[::-1].copy()


def _tex_affine(rng: np.random.Generator) -> np.ndarray:
    scale = rng.uniform(0.4, 1.0)  # texture px per image px: <= 1 keeps the views band-limited
    theta = rng.uniform(0, 2 * np.pi)
    c, s = np.cos(theta) * scale, np.sin(theta) * scale
    return np.array([[c, -s, rng.uniform(0, 512)], [s, c, rng.uniform(0, 512)]])


def _fit_plane(rig: RigConfig, rng: np.random.Generator, centre: tuple[float, float],
               box: tuple[float, float, float, float], d_centre: float, max_slope: float
               ) -> tuple[float, float, float]:
    """Affine disparity with value d_centre at `centre`, kept inside the rig's range on `box`."""
    a1, a2 = rng.uniform(-max_slope, max_slope, 2)
    for _ in range(8):
        a0 = d_centre - a1 * (centre[0] - rig.cx) - a2 * (centre[1] - rig.cy)
        us = np.array([box[0], box[1], box[0], box[1]])
        vs = np.array([box[2], box[2], box[3], box[3]])
        d = a0 + a1 * (us - rig.cx) + a2 * (vs - rig.cy)
        if d.min() >= rig.min_disparity_px and d.max() <= rig.max_disparity_px:
            return float(a0), float(a1), float(a2)
        a1, a2 = a1 / 2, a2 / 2
    return float(d_centre), 0.0, 0.0


def random_scene(rig: RigConfig, rng: np.random.Generator) -> Scene:
    """A slanted background plane plus min..max_objects planar polygons and ellipses."""
    textures = list(photo_textures()) + [procedural_texture(rng) for _ in range(3)]

    def appearance() -> dict:
        return dict(texture=int(rng.integers(len(textures))), tex_affine=_tex_affine(rng),
                    brightness=float(rng.uniform(60, 190)), contrast=float(rng.uniform(18, 50)))

    w, h = rig.width, rig.height
    full = (0.0, w - 1.0, 0.0, h - 1.0)
    bg_d = float(rng.uniform(rig.min_disparity_px + 0.5,
                             rig.min_disparity_px + 0.15 * rig.max_disparity_px))
    bg_plane = _fit_plane(rig, rng, (rig.cx, rig.cy), full, bg_d, 8.0 / max(w, h))
    layers = [Layer(plane=bg_plane, kind="background", **appearance())]
    n_objects = int(rng.integers(rig.min_objects, rig.max_objects + 1))
    for _ in range(n_objects):
        centre = rng.uniform([-0.1 * w, -0.1 * h], [1.1 * w, 1.1 * h])
        radius = float(rng.uniform(0.05, 0.35) * min(w, h) * 1.5)
        d_centre = float(rng.uniform(bg_d + 1.0, rig.max_disparity_px * 0.95))
        if rng.random() < 0.6:
            verts = _convex_polygon(rng, centre, radius)
            box = (verts[:, 0].min(), verts[:, 0].max(), verts[:, 1].min(), verts[:, 1].max())
            shape: dict[str, Any] = dict(kind="polygon", vertices=verts)
        else:
            axes = (radius, radius * float(rng.uniform(0.4, 1.0)))
            box = (centre[0] - radius, centre[0] + radius, centre[1] - radius, centre[1] + radius)
            shape = dict(kind="ellipse", centre=(float(centre[0]), float(centre[1])), axes=axes,
                         angle=float(rng.uniform(0, np.pi)))
        plane = _fit_plane(rig, rng, (float(centre[0]), float(centre[1])), box, d_centre, 0.06)
        layers.append(Layer(plane=plane, **shape, **appearance()))
    return Scene(rig, layers, textures)


def _camera(radiance: np.ndarray, rig: RigConfig, rng: np.random.Generator) -> np.ndarray:
    gain = 1.0 + rng.uniform(-rig.gain_jitter, rig.gain_jitter) if rig.gain_jitter else 1.0
    bias = rng.uniform(-rig.bias_jitter, rig.bias_jitter) if rig.bias_jitter else 0.0
    image = radiance * gain + bias
    if rig.sensor_noise_std > 0:
        image = image + rng.normal(0.0, rig.sensor_noise_std, image.shape)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def make_sample(seed: int, rig: RigConfig | None = None,
                lidar: str | LidarPattern = "beams16", T_cam_lidar: np.ndarray | None = None,
                stamp_ns: int = 0) -> SyntheticSample:
    """Render one scene deterministically from `seed` (the scene does not depend on the LiDAR
    pattern, so the same seed with another pattern sees the same world)."""
    rig = rig or RigConfig()
    pattern = PATTERNS[lidar] if isinstance(lidar, str) else lidar
    T = default_T_cam_lidar() if T_cam_lidar is None else np.asarray(T_cam_lidar, np.float64)
    scene_seq, camera_seq, lidar_seq = np.random.SeedSequence(seed).spawn(3)
    scene = random_scene(rig, np.random.default_rng(scene_seq))
    return render_sample(seed, scene, pattern, T, stamp_ns, np.random.default_rng(camera_seq),
                         np.random.default_rng(lidar_seq))


def render_sample(seed: int, scene: Scene, pattern: LidarPattern, T_cam_lidar: np.ndarray,
                  stamp_ns: int, camera_rng: np.random.Generator,
                  lidar_rng: np.random.Generator) -> SyntheticSample:
    """A scene's both views (the camera's gain, bias and noise from `camera_rng`), their
    exact disparity and occlusion, and a LiDAR scan of it (its noise from `lidar_rng`)."""
    rig = scene.rig
    disp, occ, images = {}, {}, {}
    for view in (LEFT, RIGHT):
        disp[view], owner = scene.render_depth_order(view)
        occ[view] = scene.occlusion(view, disp[view])
        images[view] = _camera(scene.render_image(view, owner, disp[view]), rig, camera_rng)
    scan = simulate_scan(scene, pattern, T_cam_lidar, stamp_ns, lidar_rng)
    return SyntheticSample(seed=seed, left=images[LEFT], right=images[RIGHT],
                           disp_left=disp[LEFT], disp_right=disp[RIGHT], occ_left=occ[LEFT],
                           occ_right=occ[RIGHT], scan=scan, T_cam_lidar=T_cam_lidar, rig=rig,
                           scene=scene)
