"""The "things" world: random 3-D scenes in the spirit of FlyingThings3D, ray-cast with exact
ground truth, for teaching the network stereo matching that transfers to real cameras.

A scene is a background (a far wall, often a ground plane) plus clutter: textured plane
patches at any slant, boxes, spheres, thick cylinders, thin poles and wires. Surfaces carry
photo, procedural, repetitive or near-textureless textures in surface coordinates (so both
views see the same surface point alike, perspective-correct, mip-mapped against aliasing), lit
by an ambient term, a point light (Lambert) and view-dependent specular highlights that move
between the views. `edge.sim.photometry` then applies each camera's own response.

Disparities span ~0.5 to `max_disparity_px` (drawn per scene up to ~140 px at 640 wide).
The LiDAR for this world is sampled from the ground truth at training time
(`edge.model.lidar_sampling`), so one rendering serves every beam pattern.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from edge_depth.calibration.sampling import sample_bilinear
from edge_depth.sim.photometry import CameraResponse, apply_camera
from edge_depth.sim.primitives import (
    Cylinder,
    PlanePatch,
    Primitive,
    Sphere,
    box_faces,
    projected_window,
)
from edge_depth.sim.textures import texture_pyramids

MIP_LEVELS = 5


@dataclass(frozen=True)
class WorldConfig:
    """Camera and scene statistics (pixels, metres)."""

    width: int = 640
    height: int = 400
    focal_px: float = 450.0
    baseline_m: float = 0.075
    min_objects: int = 4
    max_objects: int = 22
    max_disparity_range_px: tuple[float, float] = (40.0, 140.0)
    # how much the two cameras' responses differ (`CameraResponse.for_view`'s ranges times
    # this): 1 is the world every shipped model trained on, where SGBM's own matches are
    # 3-4x less reliable than on the rig or a real pair (docs/experiments.md)
    view_spread: float = 1.0
    # one response for both views, gamma 1, no vignetting, blur or JPEG, read noise 0.5 (the
    # scene and its seeds unchanged): SGBM's matches about as reliable as on a real pair
    clean_cameras: bool = False

    @property
    def cx(self) -> float:
        return (self.width - 1) / 2.0

    @property
    def cy(self) -> float:
        return (self.height - 1) / 2.0


@dataclass(frozen=True)
class Material:
    texture: int
    scale: float          # texture pixels per metre of surface
    offset: tuple[float, float]
    angle: float
    albedo: float         # mean reflectance 0-1
    contrast: float       # texture amplitude around it
    specular: float
    shininess: float


@dataclass(frozen=True)
class Light:
    position: np.ndarray  # metres, left camera frame
    ambient: float
    diffuse: float


@dataclass(frozen=True)
class ThingsSample:
    """One rendered pair: images (H, W) uint8, disparities (H, W) float32 px, occlusion (H, W)
    bool (True = not visible in the other view)."""

    seed: int
    left: np.ndarray
    right: np.ndarray
    disp_left: np.ndarray
    disp_right: np.ndarray
    occ_left: np.ndarray
    occ_right: np.ndarray


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    return q * np.sign(np.diag(r))


def _point_at(cfg: WorldConfig, u: float, v: float, z: float) -> np.ndarray:
    return np.array([(u - cfg.cx) / cfg.focal_px * z, (v - cfg.cy) / cfg.focal_px * z, z])


class ThingsScene:
    """Primitives, materials and a light; renders either view of the rig."""

    def __init__(self, cfg: WorldConfig, rng: np.random.Generator) -> None:
        self.cfg = cfg
        self.textures = texture_pyramids(MIP_LEVELS)
        self.materials: list[Material] = []
        self.prims: list[Primitive] = []
        self._build(rng)

    # -- scene generation --------------------------------------------------------------------
    def _material(self, rng: np.random.Generator, depth_m: float) -> int:
        cfg = self.cfg
        density = rng.uniform(0.3, 1.5)  # texture px per image px at the object's depth
        low_contrast = rng.random() < 0.15
        self.materials.append(Material(
            texture=int(rng.integers(len(self.textures))),
            scale=float(density * cfg.focal_px / depth_m),
            offset=(float(rng.uniform(0, 512)), float(rng.uniform(0, 512))),
            angle=float(rng.uniform(0, 2 * np.pi)),
            albedo=float(rng.uniform(0.15, 0.85)),
            contrast=float(rng.uniform(0.02, 0.08) if low_contrast else rng.uniform(0.1, 0.3)),
            specular=float(rng.uniform(0.2, 0.9) if rng.random() < 0.3 else 0.0),
            shininess=float(rng.uniform(8, 80))))
        return len(self.materials) - 1

    def _build(self, rng: np.random.Generator) -> None:
        cfg = self.cfg
        fb = cfg.focal_px * cfg.baseline_m
        d_max = rng.uniform(*cfg.max_disparity_range_px)
        d_far = rng.uniform(0.5, 6.0)
        z_far = fb / d_far
        # far wall, slanted
        normal = np.array([rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4), -1.0])
        normal /= np.linalg.norm(normal)
        e1 = np.cross(normal, [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        self.prims.append(PlanePatch(np.array([0, 0, z_far]), e1, np.cross(normal, e1),
                                     (1.0, 1.0), "infinite", self._material(rng, z_far)))
        if rng.random() < 0.6:  # ground plane below the camera, pitched a little
            height = rng.uniform(0.15, 1.2)
            pitch = rng.uniform(-0.25, 0.1)
            up = np.array([0.0, -np.cos(pitch), np.sin(pitch)])
            fwd = np.cross([1.0, 0.0, 0.0], up)
            self.prims.append(PlanePatch(-height * up, np.array([1.0, 0, 0]), fwd, (1.0, 1.0),
                                         "infinite", self._material(rng, 3 * height)))
        for _ in range(int(rng.integers(cfg.min_objects, cfg.max_objects + 1))):
            # disparity density favours the near half a little: real scenes put detail there
            d = float(d_far + (d_max - d_far) * rng.power(0.8))
            z = fb / d
            u = rng.uniform(-0.1, 1.1) * cfg.width
            v = rng.uniform(-0.1, 1.1) * cfg.height
            centre = _point_at(cfg, u, v, z)
            size_m = rng.uniform(15, 220) * z / cfg.focal_px  # apparent radius, pixels → m
            size_m = min(size_m, 0.8 * (z - 0.06))
            self._add_object(rng, centre, size_m, z)

    def _add_object(self, rng, centre, size_m, z) -> None:
        kind = rng.choice(["plane", "box", "sphere", "cylinder", "pole", "wire"],
                          p=[0.34, 0.2, 0.14, 0.1, 0.14, 0.08])
        mat = self._material(rng, z)
        rot = _random_rotation(rng)
        if kind == "plane":
            outline = str(rng.choice(["rect", "ellipse", "polygon"]))
            half = (size_m * rng.uniform(0.4, 1.0), size_m * rng.uniform(0.2, 1.0))
            verts = None
            if outline == "polygon":
                k = int(rng.integers(3, 9))
                ang = np.sort(rng.uniform(0, 2 * np.pi, k))
                verts = np.stack([half[0] * np.cos(ang), half[1] * np.sin(ang)], 1)
                hull = cv2.convexHull(verts.astype(np.float32)).reshape(-1, 2)
                x, y = hull[:, 0], hull[:, 1]
                area = np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
                verts = (hull if area > 0 else hull[::-1]).astype(np.float64)
                if len(verts) < 3:
                    outline, verts = "ellipse", None
            self.prims.append(PlanePatch(centre, rot[:, 0], rot[:, 1], half, outline, mat,
                                         verts))
        elif kind == "box":
            half = size_m * rng.uniform(0.25, 0.7, 3)
            self.prims.extend(box_faces(centre, rot, half, mat))
        elif kind == "sphere":
            self.prims.append(Sphere(centre, float(size_m * rng.uniform(0.4, 0.9)), mat, rot))
        else:
            f = self.cfg.focal_px
            if kind == "cylinder":
                radius, length = size_m * rng.uniform(0.15, 0.4), size_m * rng.uniform(1, 3)
                axis = rot[:, 0]
            elif kind == "pole":  # 1-8 px thick, mostly upright: table and chair legs, posts
                radius, length = rng.uniform(0.5, 4.0) * z / f, size_m * rng.uniform(2, 5)
                axis = np.array([rng.normal(0, 0.25), 1.0, rng.normal(0, 0.25)])
            else:  # wire: under 2 px, long, any direction in the image
                radius, length = rng.uniform(0.3, 1.0) * z / f, size_m * rng.uniform(3, 8)
                axis = rot[:, 0] * np.array([1.0, 1.0, 0.3])
            axis = axis / np.linalg.norm(axis)
            self.prims.append(Cylinder(centre - 0.5 * length * axis, axis, float(length),
                                       float(radius), mat))

    # -- rendering ---------------------------------------------------------------------------
    def origin(self, view: str) -> np.ndarray:
        return np.array([self.cfg.baseline_m if view == "right" else 0.0, 0.0, 0.0])

    def trace(self, view: str, u: np.ndarray, v: np.ndarray):
        """Nearest hit for rays through continuous pixel positions (N,) of a view: depth
        (N,) m (inf = none), owning primitive (N,), texture coordinates (N, 2), normals
        (N, 3)."""
        cfg = self.cfg
        origin = self.origin(view)
        dirs = np.stack([(u - cfg.cx) / cfg.focal_px, (v - cfg.cy) / cfg.focal_px,
                         np.ones_like(u)], 1)
        depth = np.full(len(u), np.inf)
        owner = np.full(len(u), -1, np.int32)
        tex = np.zeros((len(u), 2))
        normal = np.zeros((len(u), 3))
        for k, prim in enumerate(self.prims):
            x0, x1, y0, y1 = projected_window(prim, origin, cfg.focal_px, cfg.cx, cfg.cy,
                                              (cfg.width, cfg.height))
            sel = np.flatnonzero((u >= x0 - 1) & (u < x1) & (v >= y0 - 1) & (v < y1))
            if sel.size == 0:
                continue
            hit = prim.intersect(origin, dirs[sel])
            win = hit.t < depth[sel]
            idx = sel[win]
            depth[idx], owner[idx] = hit.t[win], k
            tex[idx], normal[idx] = hit.tex[win], hit.normal[win]
        return depth, owner, tex, normal, dirs

    def shade(self, view: str, light: Light, depth, owner, tex, normal, dirs) -> np.ndarray:
        """Radiance 0-1 of each traced ray."""
        out = np.zeros(len(depth), np.float32)
        points = self.origin(view)[None] + depth[:, None] * dirs
        view_dir = self.origin(view)[None] - points
        view_dir /= np.maximum(np.linalg.norm(view_dir, axis=1, keepdims=True), 1e-9)
        to_light = light.position[None] - points
        to_light /= np.maximum(np.linalg.norm(to_light, axis=1, keepdims=True), 1e-9)
        lambert = np.clip(np.einsum("ij,ij->i", normal, to_light), 0, None)
        half = to_light + view_dir
        half /= np.maximum(np.linalg.norm(half, axis=1, keepdims=True), 1e-9)
        n_dot_h = np.clip(np.einsum("ij,ij->i", normal, half), 0, None)
        cos_view = np.abs(np.einsum("ij,ij->i", normal, view_dir))
        for m in np.unique(owner[owner >= 0]):
            prim = self.prims[m]
            mat = self.materials[prim.material]
            sel = np.flatnonzero(owner == m)
            c, s = np.cos(mat.angle), np.sin(mat.angle)
            st = tex[sel] * mat.scale
            tu = c * st[:, 0] - s * st[:, 1] + mat.offset[0]
            tv = s * st[:, 0] + c * st[:, 1] + mat.offset[1]
            # mip level from the footprint: texture px per image px on this surface
            footprint = mat.scale * depth[sel] / (self.cfg.focal_px
                                                  * np.maximum(cos_view[sel], 0.15))
            level = np.clip(np.round(np.log2(np.maximum(footprint, 1.0))), 0, MIP_LEVELS - 1)
            texel = np.zeros(sel.size, np.float32)
            pyramid = self.textures[mat.texture]
            for lv in np.unique(level).astype(int):
                part = level == lv
                texel[part] = sample_bilinear(pyramid[lv], tu[part] / 2 ** lv,
                                              tv[part] / 2 ** lv, cv2.BORDER_WRAP)
            albedo = np.clip(mat.albedo + mat.contrast * texel, 0.02, 1.0)
            spec = mat.specular * n_dot_h[sel] ** mat.shininess
            out[sel] = albedo * (light.ambient + light.diffuse * lambert[sel]) + spec
        return out

    def render(self, view: str, light: Light):
        """(depth (H, W) m, radiance (H, W) 0-1) of a whole view."""
        cfg = self.cfg
        v, u = np.mgrid[0:cfg.height, 0:cfg.width].astype(np.float64)
        depth, owner, tex, normal, dirs = self.trace(view, u.ravel(), v.ravel())
        radiance = self.shade(view, light, depth, owner, tex, normal, dirs)
        return depth.reshape(u.shape), radiance.reshape(u.shape)

    def occlusion(self, view: str, depth: np.ndarray) -> np.ndarray:
        """(H, W) bool: pixels whose surface point the other camera does not see (outside
        its image or behind a nearer surface). The cameras differ by a shift along x only, so
        the point has the same depth in both."""
        cfg = self.cfg
        fb = cfg.focal_px * cfg.baseline_m
        v, u = np.mgrid[0:cfg.height, 0:cfg.width].astype(np.float64)
        disparity = fb / depth
        u_other = u - disparity if view == "left" else u + disparity
        other = "right" if view == "left" else "left"
        outside = (u_other < -0.5) | (u_other > cfg.width - 0.5)
        seen = np.ones(u.shape, bool)
        ok = ~outside & np.isfinite(depth)
        nearest, *_ = self.trace(other, u_other[ok], v[ok])
        seen[ok] = nearest >= depth[ok] * (1 - 1e-4)
        return outside | ~seen | ~np.isfinite(depth)


def make_things_sample(seed: int, cfg: WorldConfig | None = None,
                       scene_class: type[ThingsScene] = ThingsScene) -> ThingsSample:
    """Render one scene of the things world (or another layout on its surfaces, e.g.
    `edge.sim.street.StreetScene`) deterministically from `seed`."""
    cfg = cfg or WorldConfig()
    scene_seq, light_seq, camera_seq = np.random.SeedSequence([seed, 7]).spawn(3)
    scene = scene_class(cfg, np.random.default_rng(scene_seq))
    rng = np.random.default_rng(light_seq)
    light = Light(position=np.array([rng.uniform(-2, 2), rng.uniform(-2, 0.5),
                                     rng.uniform(-0.5, 2)]),
                  ambient=float(rng.uniform(0.25, 0.7)), diffuse=float(rng.uniform(0.2, 0.8)))
    fb = cfg.focal_px * cfg.baseline_m
    disp, occ, images = {}, {}, {}
    camera_rng = np.random.default_rng(camera_seq)
    response = CameraResponse.random(camera_rng)
    if cfg.clean_cameras:
        response = response.clean()
    spread = 0.0 if cfg.clean_cameras else cfg.view_spread
    radiance = {}
    for view in ("left", "right"):
        depth, radiance[view] = scene.render(view, light)
        with np.errstate(divide="ignore"):
            disp[view] = np.where(np.isfinite(depth), fb / depth, 0.0).astype(np.float32)
        occ[view] = scene.occlusion(view, depth)
    metered = float(radiance["left"].mean())
    for view in ("left", "right"):
        images[view] = apply_camera(radiance[view],
                                    response.for_view(view, camera_rng, spread),
                                    camera_rng, metered)
    return ThingsSample(seed, images["left"], images["right"], disp["left"], disp["right"],
                        occ["left"], occ["right"])
