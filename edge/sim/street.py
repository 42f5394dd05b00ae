"""The "street" world: a scene family none of the shipped model's training saw, for measuring
adaptation (`edge-depth adapt`) — a road seen from a car, KITTI-like: a 1242×375 camera with
a 0.54 m baseline and a 64-beam LiDAR.

A scene is a ground plane 1.4–1.8 m below the camera, building facades on both sides of the
road (several per side, set back by different amounts), a far facade closing the street,
parked and oncoming cars (boxes on the ground), lamp posts and signs. Surfaces, light and the
cameras' responses are the things world's (`edge.sim.world`), so only the layout is new.

The LiDAR is 64 rows sampled from the ground truth over the lower two thirds of the image (the
vertical field of a roof-mounted 64-beam scanner seen by a forward camera), every 2nd column,
N(0, 0.1 px), then back-projected to points in the LiDAR's frame (0.3 m above the camera).
"""

from __future__ import annotations

import numpy as np

from edge_depth.sim.gt_lidar import GtLidarPattern
from edge_depth.sim.primitives import Cylinder, PlanePatch, box_faces
from edge_depth.sim.world import ThingsScene, WorldConfig

STREET_CAMERA = WorldConfig(width=1242, height=375, focal_px=720.0, baseline_m=0.54)
# LiDAR 0.3 m above the left camera, axes aligned with it: p_cam = p_lidar + t
T_CAM_LIDAR = np.array([[1.0, 0, 0, 0.0], [0, 1.0, 0, -0.3], [0, 0, 1.0, 0.0], [0, 0, 0, 1.0]])


class StreetScene(ThingsScene):
    """A street from a car's camera (x right, y down, z forward; metres)."""

    def _build(self, rng: np.random.Generator) -> None:
        up = np.array([0.0, -1.0, 0.0])
        fwd = np.array([0.0, 0.0, 1.0])
        right = np.array([1.0, 0.0, 0.0])
        height = rng.uniform(1.4, 1.8)
        self.prims.append(PlanePatch(np.array([0.0, height, 0.0]), right, fwd, (1.0, 1.0),
                                     "infinite", self._material(rng, 3 * height)))
        z_end = rng.uniform(60.0, 140.0)
        self.prims.append(PlanePatch(np.array([rng.uniform(-5, 5), 0.0, z_end]), right, up,
                                     (1.0, 1.0), "infinite", self._material(rng, z_end)))
        lane = rng.uniform(3.5, 6.0)  # road half-width to the kerb
        for side in (-1.0, 1.0):
            z = 0.0
            while z < z_end:  # facades, each its own building
                length = rng.uniform(8.0, 30.0)
                setback = lane + rng.uniform(1.5, 4.0)
                tall = rng.uniform(6.0, 20.0)
                centre = np.array([side * setback, height - tall / 2, z + length / 2])
                self.prims.append(PlanePatch(centre, fwd, up, (length / 2, tall / 2), "rect",
                                             self._material(rng, max(z + length / 2, 5.0))))
                z += length + (rng.uniform(1.0, 6.0) if rng.random() < 0.3 else 0.0)
            for _ in range(int(rng.integers(1, 7))):  # parked cars along the kerb
                zc = rng.uniform(4.0, 50.0)
                half = np.array([rng.uniform(0.8, 1.0), rng.uniform(0.7, 0.9),
                                 rng.uniform(2.0, 2.5)])
                centre = np.array([side * (lane - half[0] - rng.uniform(0.1, 0.6)),
                                   height - half[1] - rng.uniform(0.2, 0.35), zc])
                yaw = rng.normal(0, 0.05)
                rot = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0],
                                [-np.sin(yaw), 0, np.cos(yaw)]])
                self.prims.extend(box_faces(centre, rot, half, self._material(rng, zc)))
            for _ in range(int(rng.integers(1, 5))):  # lamp posts and signs on the pavement
                zc = rng.uniform(5.0, 60.0)
                x = side * (lane + rng.uniform(0.3, 1.2))
                tall = rng.uniform(3.0, 7.0)
                radius = rng.uniform(0.05, 0.15)
                self.prims.append(Cylinder(np.array([x, height, zc]), up, tall, radius,
                                           self._material(rng, zc)))
                if rng.random() < 0.5:
                    sign = (rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.6))  # its half-extents
                    self.prims.append(PlanePatch(
                        np.array([x, height - tall + sign[1], zc - radius - 0.02]), right, up,
                        sign, str(rng.choice(["rect", "ellipse"])), self._material(rng, zc)))
        for _ in range(int(rng.integers(0, 3))):  # traffic ahead in the lane
            zc = rng.uniform(8.0, 45.0)
            half = np.array([0.9, 0.75, 2.2])
            centre = np.array([rng.uniform(-lane + 1.0, lane - 1.0), height - 0.95, zc])
            self.prims.extend(box_faces(centre, np.eye(3), half, self._material(rng, zc)))


def street_lidar(disparity: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(H, W) sparse disparity of the street's 64-beam LiDAR, sampled from the GT."""
    h, _ = disparity.shape
    rows = h / 3 + (np.arange(64) + 0.5) * (2 * h / 3) / 64
    return GtLidarPattern(rows=rows, column_step=2, noise_px=0.1).sample(disparity, rng)


def lidar_points(sparse: np.ndarray, cfg: WorldConfig) -> np.ndarray:
    """Sparse disparity (H, W) px → (N, 3) float32 points in the LiDAR's frame (metres)."""
    v, u = np.nonzero(sparse > 0)
    z = cfg.focal_px * cfg.baseline_m / sparse[v, u]
    cam = np.stack([(u - cfg.cx) / cfg.focal_px * z, (v - cfg.cy) / cfg.focal_px * z, z], 1)
    return (cam - T_CAM_LIDAR[:3, 3]).astype(np.float32)
