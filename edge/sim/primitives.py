"""3-D surface primitives for the "things" world: ray intersection, surface texture coordinates
and normals, all vectorised over rays.

Rays are written o + t·d with d = ((u − cx)/f, (v − cy)/f, 1), so the ray parameter t of a hit
is its depth z in metres (camera frame: x right, y down, z forward). Texture coordinates are
metres on the surface, so the same surface point carries the same texture in both views.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NEAR_M = 0.05


def _rows_dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", a, b)


@dataclass(frozen=True)
class Hit:
    """Per-ray result of one primitive: depth t (N,) (inf = miss), texture coordinates (N, 2)
    in metres and unit normals (N, 3) facing the ray's origin."""

    t: np.ndarray
    tex: np.ndarray
    normal: np.ndarray


class Primitive:
    """Base: a bounding sphere (centre, radius) for culling, and `material` (index)."""

    centre: np.ndarray
    radius: float
    material: int

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> Hit:  # pragma: no cover
        raise NotImplementedError

    @staticmethod
    def _facing(normal: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        flip = _rows_dot(normal, dirs) > 0
        normal[flip] *= -1
        return normal


@dataclass(frozen=True)
class PlanePatch(Primitive):
    """A piece of the plane through `centre` spanned by unit axes e1, e2. outline: "rect"
    (|s| ≤ half[0], |t| ≤ half[1]), "ellipse" (semi-axes half) or "polygon" (convex, (K, 2)
    vertices counter-clockwise in (s, t)), or "infinite"."""

    centre: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    half: tuple[float, float]
    outline: str
    material: int
    vertices: np.ndarray | None = None

    @property
    def radius(self) -> float:  # type: ignore[override]  # a field in Sphere, derived here
        return float(np.hypot(*self.half)) if self.outline != "infinite" else np.inf

    def inside(self, s: np.ndarray, t: np.ndarray) -> np.ndarray:
        if self.outline == "infinite":
            return np.ones(s.shape, bool)
        if self.outline == "rect":
            return (np.abs(s) <= self.half[0]) & (np.abs(t) <= self.half[1])
        if self.outline == "ellipse":
            return (s / self.half[0]) ** 2 + (t / self.half[1]) ** 2 <= 1.0
        ok = np.ones(s.shape, bool)
        verts = self.vertices
        assert verts is not None, 'a "polygon" outline has its vertices'
        for i in range(len(verts)):
            (x0, y0), (x1, y1) = verts[i], verts[(i + 1) % len(verts)]
            ok &= (x1 - x0) * (t - y0) - (y1 - y0) * (s - x0) >= 0
        return ok

    def intersect(self, origin, dirs):
        normal = np.cross(self.e1, self.e2)
        denom = dirs @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self.centre - origin) @ normal) / denom
            rel = origin[None] + np.where(np.isfinite(t), t, 0.0)[:, None] * dirs - self.centre
        s, q = rel @ self.e1, rel @ self.e2
        ok = np.isfinite(t) & (t > NEAR_M) & self.inside(s, q)
        n = self._facing(np.repeat(normal[None], len(dirs), 0), dirs)
        return Hit(np.where(ok, t, np.inf), np.stack([s, q], 1), n)


@dataclass(frozen=True)
class Sphere(Primitive):
    centre: np.ndarray
    radius: float
    material: int
    rotation: np.ndarray  # (3, 3) orientation of the texture's longitude/latitude frame

    def intersect(self, origin, dirs):
        w = origin - self.centre
        a = _rows_dot(dirs, dirs)
        b = 2.0 * (dirs @ w)
        c = float(w @ w) - self.radius ** 2
        disc = b * b - 4 * a * c
        root = np.sqrt(np.maximum(disc, 0.0))
        t = (-b - root) / (2 * a)
        ok = (disc >= 0) & (t > NEAR_M)
        p = (origin[None] + t[:, None] * dirs - self.centre) / self.radius
        q = p @ self.rotation
        tex = np.stack([np.arctan2(q[:, 0], q[:, 2]), np.arcsin(np.clip(q[:, 1], -1, 1))], 1)
        return Hit(np.where(ok, t, np.inf), tex * self.radius, self._facing(p, dirs))


@dataclass(frozen=True)
class Cylinder(Primitive):
    """An open tube of `tube_radius` around the segment base → base + axis · length (a pole,
    a wire, a chair leg, a pipe)."""

    base: np.ndarray
    axis: np.ndarray
    length: float
    tube_radius: float
    material: int

    @property
    def centre(self) -> np.ndarray:  # type: ignore[override]  # derived from the segment
        return self.base + 0.5 * self.length * self.axis

    @property
    def radius(self) -> float:  # type: ignore[override]  # the bounding sphere's
        return float(np.hypot(0.5 * self.length, self.tube_radius))

    def intersect(self, origin, dirs):
        w = origin - self.base
        d_perp = dirs - np.outer(dirs @ self.axis, self.axis)
        w_perp = w - (w @ self.axis) * self.axis
        a = _rows_dot(d_perp, d_perp)
        b = 2.0 * (d_perp @ w_perp)
        c = float(w_perp @ w_perp) - self.tube_radius ** 2
        disc = b * b - 4 * a * c
        root = np.sqrt(np.maximum(disc, 0.0))
        best = np.full(len(dirs), np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            for sign in (1.0, -1.0):  # the far wall shows through an open end
                t = (-b - sign * root) / (2 * a)
                axial = (w @ self.axis) + t * (dirs @ self.axis)
                ok = (disc >= 0) & (a > 1e-12) & (t > NEAR_M) & (axial >= 0) \
                    & (axial <= self.length) & ~np.isfinite(best)
                best[ok] = t[ok]
        t = np.where(np.isfinite(best), best, 0.0)
        rel = origin[None] + t[:, None] * dirs - self.base
        axial = rel @ self.axis
        radial = rel - np.outer(axial, self.axis)
        ref = np.cross(self.axis, [0.0, 0.0, 1.0] if abs(self.axis[2]) < 0.9 else [1.0, 0, 0])
        ref /= np.linalg.norm(ref)
        angle = np.arctan2(radial @ np.cross(self.axis, ref), radial @ ref)
        normal = radial / np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-12)
        tex = np.stack([angle * self.tube_radius, axial], 1)
        return Hit(best, tex, self._facing(normal, dirs))


def box_faces(centre: np.ndarray, rotation: np.ndarray, half: np.ndarray, material: int
              ) -> list[PlanePatch]:
    """The six faces of a box (half-extents `half` along the columns of `rotation`)."""
    faces = []
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3
        for sign in (1.0, -1.0):
            faces.append(PlanePatch(centre + sign * half[k] * rotation[:, k], rotation[:, i],
                                    rotation[:, j], (float(half[i]), float(half[j])), "rect",
                                    material))
    return faces


def projected_window(prim: Primitive, origin: np.ndarray, f: float, cx: float, cy: float,
                     size: tuple[int, int]) -> tuple[int, int, int, int]:
    """Integer pixel window (x0, x1, y0, y1), end-exclusive, that holds the primitive's
    bounding sphere in a view whose camera sits at `origin`; the whole image when the sphere
    reaches behind the near plane."""
    w, h = size
    r = prim.radius
    c = prim.centre - origin
    if not np.isfinite(r) or c[2] - r <= NEAR_M:
        return 0, w, 0, h
    zs = np.array([c[2] - r, c[2] + r])
    xs = np.concatenate([(c[0] - r) / zs, (c[0] + r) / zs])
    ys = np.concatenate([(c[1] - r) / zs, (c[1] + r) / zs])
    x0, x1 = int(np.floor(cx + f * xs.min())) - 1, int(np.ceil(cx + f * xs.max())) + 2
    y0, y1 = int(np.floor(cy + f * ys.min())) - 1, int(np.ceil(cy + f * ys.max())) + 2
    return max(x0, 0), min(x1, w), max(y0, 0), min(y1, h)
