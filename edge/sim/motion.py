"""The synthetic rig's world in motion: one scene seen from a camera that drives forward and
turns, with one object that moves on its own, exact ground truth on every frame.

A layer of `edge.sim.scene` is a piece of a plane, d = a0 + a1 (u − cx) + a2 (v − cy), with an
outline in the left image. In the left camera's frame the plane is m · P = 1 with
m = (a1 / B, a2 / B, a0 / (f B)). Time t moves the world (the scene at t = 0 is the world's
frame): the mover's points by `mover_mps`·t, so its plane becomes m / (1 + m · v t); the camera
sits at c(t) = `speed_mps`·t forward, turned by `yaw_dps`·t about its y axis, and sees a point
P as R(t) (P − c(t)), so a plane becomes R m / (1 − m · c). Outlines are carried by their
vertices (an ellipse as a 48-gon): each is lifted onto its plane at t = 0, moved, and
projected again. The texture moves with its plane exactly: a point of the plane seen at
p0 at t = 0 is seen at G p0, G = K R (I + (o − c) mᵀ) K⁻¹ (o the layer's own offset), so
the texture at time t is the one at t = 0 through G⁻¹ (`Layer.tex_homography`): an affine
map through three points is exact only while a plane stays fronto-parallel, and a turn of a
degree leaves it pixels from where its surface went, where the optical flow and the ground
truth then disagree. A layer whose points would reach behind the camera leaves the
scene.

`moving_sample(seed, t, motion)`: the frame at time t of the world `start_world(seed)` (the
scene `make_sample(seed)` draws, its nearest surfaces at half the rig's disparity range),
rendered and scanned as `make_sample` does (its camera noise and LiDAR noise drawn per
frame).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from edge_depth.sim.lidar import PATTERNS, LidarPattern, default_T_cam_lidar
from edge_depth.sim.rig import SyntheticSample, random_scene, render_sample
from edge_depth.sim.scene import LEFT, Layer, RigConfig, Scene

ELLIPSE_VERTICES = 48
# the longest sequence a recording may ask for: beyond it the turning world's background
# plane reaches the horizon at the image's corners (seeds 0, 1, 19 at 15°/s within 2 s leave
# corners without a surface, their truth unknown) and driving carries surfaces past the range
MAX_SECONDS = 3.0
MIN_DEPTH_M = 0.3  # a layer with a point nearer than this (or behind) leaves the frame
# a moving world's nearest surfaces start at half the rig's disparity range (1.1 m on the
# default rig): a second or two of driving then keeps them within the range the network was
# trained for instead of carrying them past it
START_RANGE_SHARE = 0.5


@dataclass(frozen=True)
class Motion:
    """How the world moves: the camera forward at `speed_mps` (its z), turning at `yaw_dps`
    (positive: to the right), and the scene's nearest object (the layer with the highest
    disparity at its outline's centre) moving at `mover_mps` (x, y, z in the first frame's
    camera axes)."""

    speed_mps: float = 0.0
    yaw_dps: float = 0.0
    mover_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)


KINDS = {
    "still": Motion(),
    "forward": Motion(speed_mps=0.3),
    "turn": Motion(speed_mps=0.2, yaw_dps=15.0),
    "mover": Motion(speed_mps=0.2, mover_mps=(0.3, 0.0, 0.0)),
}


def plane_of(layer: Layer, rig: RigConfig) -> np.ndarray:
    """m with m · P = 1 for points P (metres, left camera frame) on the layer's plane."""
    return layer.plane_normal(rig.focal_px) / (rig.focal_px * rig.baseline_m)


def layer_plane(m: np.ndarray, rig: RigConfig) -> tuple[float, float, float]:
    """The layer's (a0, a1, a2) of a plane m · P = 1."""
    f, b = rig.focal_px, rig.baseline_m
    return float(f * b * m[2]), float(b * m[0]), float(b * m[1])


def lift(m: np.ndarray, uv: np.ndarray, rig: RigConfig) -> np.ndarray:
    """Left-image points (N, 2) lifted onto the plane m · P = 1: (N, 3) metres."""
    rays = np.stack([(uv[:, 0] - rig.cx) / rig.focal_px, (uv[:, 1] - rig.cy) / rig.focal_px,
                     np.ones(len(uv))], axis=1)
    return rays / (rays @ m)[:, None]


def project(points: np.ndarray, rig: RigConfig) -> np.ndarray:
    """(N, 3) metres in the left camera frame -> (N, 2) left-image pixels."""
    return np.stack([rig.cx + rig.focal_px * points[:, 0] / points[:, 2],
                     rig.cy + rig.focal_px * points[:, 1] / points[:, 2]], axis=1)


def camera_pose(t: float, motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """(R, c): the camera at time t sees a world point P at R (P − c)."""
    yaw = math.radians(motion.yaw_dps * t)
    # the camera turned right by `yaw` (about its y axis, y down): world → camera is R_y(−yaw)
    R = np.array([[math.cos(yaw), 0.0, -math.sin(yaw)],
                  [0.0, 1.0, 0.0],
                  [math.sin(yaw), 0.0, math.cos(yaw)]])
    c = np.array([0.0, 0.0, motion.speed_mps * t])
    return R, c


def outline(layer: Layer, rig: RigConfig) -> np.ndarray | None:
    """The layer's outline as left-image vertices (K, 2), counter-clockwise; None: the
    background (the whole image: its three anchor points for the texture come from the
    image's corners)."""
    if layer.kind == "background":
        return None
    if layer.kind == "ellipse":
        a = np.linspace(0.0, 2 * np.pi, ELLIPSE_VERTICES, endpoint=False)
        c, s = math.cos(layer.angle), math.sin(layer.angle)
        p, q = layer.axes[0] * np.cos(a), layer.axes[1] * np.sin(a)
        return np.stack([layer.centre[0] + c * p - s * q, layer.centre[1] + s * p + c * q],
                        axis=1)
    assert layer.vertices is not None, 'a "polygon" layer has its vertices'
    return np.asarray(layer.vertices, np.float64)


def mover_index(scene: Scene) -> int | None:
    """The nearest object layer (highest disparity at its outline's centre), None without
    objects."""
    best, index = -np.inf, None
    for k, layer in enumerate(scene.layers):
        verts = outline(layer, scene.rig)
        if verts is None:
            continue
        u, v = verts.mean(axis=0)
        d = float(layer.disparity(LEFT, np.array(u), np.array(v), scene.rig.cx, scene.rig.cy))
        if d > best:
            best, index = d, k
    return index


def moved_layer(layer: Layer, rig: RigConfig, t: float, motion: Motion,
                velocity: np.ndarray) -> Layer | None:
    """The layer at time t (its own `velocity` m/s in world axes), None when it has left the
    frame (a point behind or nearer than MIN_DEPTH_M)."""
    m = plane_of(layer, rig)
    verts = outline(layer, rig)
    R, c = camera_pose(t, motion)
    offset = velocity * t
    seen = None if verts is None else (lift(m, verts, rig) + offset - c) @ R.T
    if seen is not None and seen[:, 2].min() < MIN_DEPTH_M:
        return None
    moved_by = 1.0 + m @ offset
    if abs(moved_by) < 1e-9:  # the plane moved onto the first camera's centre
        return None
    m_world = m / moved_by  # the plane moved with the layer
    denominator = 1.0 - m_world @ c
    if abs(denominator) < 1e-9:
        return None
    m_seen = (R @ m_world) / denominator
    if verts is None and m_seen[2] <= 0:  # the background turned away or passed
        return None
    changes = dict(plane=layer_plane(m_seen, rig),
                   tex_homography=texture_map(layer) @ np.linalg.inv(
                       plane_motion(m, R, offset - c, rig)))
    if seen is not None:
        changes.update(kind="polygon", vertices=project(seen, rig))
    return replace(layer, **changes)


def texture_map(layer: Layer) -> np.ndarray:
    """The layer's map from left-image (u, v, 1) to its texture as a 3×3 homography."""
    if layer.tex_homography is not None:
        return layer.tex_homography
    assert layer.tex_affine is not None, "a textured layer has its affine map"
    return np.vstack([layer.tex_affine, [0.0, 0.0, 1.0]])


def plane_motion(m: np.ndarray, R: np.ndarray, shift: np.ndarray, rig: RigConfig
                 ) -> np.ndarray:
    """G (3×3): where a point of the plane m · P = 1 seen at left-image (u, v) is seen after
    the points move by `shift` and the camera turns by R (P' = R (P + shift)): G (u, v, 1),
    up to scale. On the plane P + shift = (I + shift mᵀ) P."""
    K = np.array([[rig.focal_px, 0.0, rig.cx], [0.0, rig.focal_px, rig.cy], [0.0, 0.0, 1.0]])
    return K @ R @ (np.eye(3) + np.outer(shift, m)) @ np.linalg.inv(K)


def scene_at(scene: Scene, t: float, motion: Motion) -> Scene:
    """The scene at time t: every layer moved and seen from the camera's pose then."""
    mover = mover_index(scene)
    layers = []
    for k, layer in enumerate(scene.layers):
        velocity = np.asarray(motion.mover_mps if k == mover else (0.0, 0.0, 0.0), np.float64)
        moved = moved_layer(layer, scene.rig, t, motion, velocity)
        if moved is not None:
            layers.append(moved)
    return Scene(scene.rig, layers, scene.textures)


def start_world(seed: int, rig: RigConfig) -> Scene:
    """`make_sample(seed)`'s scene drawn on the rig with its disparity range halved
    (START_RANGE_SHARE): the moving world at t = 0."""
    near = max(rig.min_disparity_px * 2, rig.max_disparity_px * START_RANGE_SHARE)
    scene_seq, _, _ = np.random.SeedSequence(seed).spawn(3)
    return random_scene(replace(rig, max_disparity_px=near), np.random.default_rng(scene_seq))


def moving_sample(seed: int, t: float, motion: Motion, rig: RigConfig | None = None,
                  lidar: str | LidarPattern = "beams16", stamp_ns: int = 0,
                  frame: int = 0) -> SyntheticSample:
    """Frame `frame` at time t (s) of `make_sample(seed)`'s world moving by `motion`: both
    views, their exact disparity and occlusion, and a LiDAR scan of the scene at that time.
    The camera's and the LiDAR's noise are drawn from (seed, frame)."""
    rig = rig or RigConfig()
    pattern = PATTERNS[lidar] if isinstance(lidar, str) else lidar
    T = default_T_cam_lidar()
    world = start_world(seed, rig)
    scene = scene_at(world, t, motion)
    camera_rng, lidar_rng = (np.random.default_rng(s) for s in
                             np.random.SeedSequence([seed, frame]).spawn(2))
    return render_sample(seed, scene, pattern, T, stamp_ns, camera_rng, lidar_rng)


def mover_mask(seed: int, t: float, motion: Motion, disparity: np.ndarray,
               rig: RigConfig | None = None, tolerance_px: float = 0.25) -> np.ndarray:
    """The pixels of the frame at time t that show the mover (its outline, where the frame's
    exact `disparity` is its plane's: not hidden behind another layer)."""
    rig = rig or RigConfig()
    world = start_world(seed, rig)
    k = mover_index(world)
    h, w = disparity.shape
    layer = None if k is None else moved_layer(world.layers[k], rig, t, motion,
                                               np.asarray(motion.mover_mps, np.float64))
    if layer is None:
        return np.zeros((h, w), bool)
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    with np.errstate(invalid="ignore"):
        on_plane = np.abs(layer.disparity(LEFT, u, v, rig.cx, rig.cy) - disparity) < tolerance_px
    return layer.contains(u, v) & on_plane


def positions_then(seed: int, t: float, t_then: float, motion: Motion, disparity: np.ndarray,
                   disparity_then: np.ndarray, rig: RigConfig | None = None,
                   tolerance_px: float = 0.5) -> np.ndarray:
    """Where the surface at each pixel of the frame at time t is in the frame at `t_then`:
    (H, W, 2) left-image (x, y), NaN where it is not seen then (outside the image, hidden —
    that frame's exact `disparity_then` there is not the surface's — or unknown now). From
    the frame's exact `disparity` and the known motion: the camera's poses, the mover's
    own velocity on `mover_mask`'s pixels."""
    rig = rig or RigConfig()
    f, b = rig.focal_px, rig.baseline_m
    h, w = disparity.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(np.isfinite(disparity) & (disparity > 0), f * b / disparity, np.nan)
    seen = np.stack([(u - rig.cx) / f * z, (v - rig.cy) / f * z, z], axis=-1)
    R, c = camera_pose(t, motion)
    world = seen @ R + c  # P = Rᵀ p + c for each pixel's p
    mover = mover_mask(seed, t, motion, disparity, rig)
    world[mover] += np.asarray(motion.mover_mps, np.float64) * (t_then - t)
    R_then, c_then = camera_pose(t_then, motion)
    then = (world - c_then) @ R_then.T
    with np.errstate(divide="ignore", invalid="ignore"):
        x = rig.cx + f * then[..., 0] / then[..., 2]
        y = rig.cy + f * then[..., 1] / then[..., 2]
        expected = f * b / then[..., 2]
    xi, yi = np.rint(x), np.rint(y)
    inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h) & (then[..., 2] > 0)
    found = np.full((h, w), np.nan)
    found[inside] = disparity_then[yi[inside].astype(int), xi[inside].astype(int)]
    with np.errstate(invalid="ignore"):
        shown = inside & (np.abs(found - expected) < tolerance_px)
    out = np.stack([x, y], axis=-1).astype(np.float32)
    out[~shown] = np.nan
    return out
