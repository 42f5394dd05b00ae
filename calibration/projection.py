"""LiDAR points to sparse disparity in a rectified stereo image.

Pure numpy. A sparse disparity map is (H, W) float32 with 0 where there is no point, plus a
(H, W) bool valid mask; disparity d = f B / z in pixels of that image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a (4, 4) rigid transform to (N, 3) points; returns (N, 3) float64."""
    points = np.asarray(points, np.float64)
    return points @ T[:3, :3].T + T[:3, 3]


def _pixels(points_cam: np.ndarray, focal_px: float, cx: float, cy: float, baseline_m: float,
            size: tuple[int, int], side: str, min_depth_m: float
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Nearest pixel (u, v) and depth z of each point (N,) in one rectified view, and whether it
    lands in front of the camera and inside the image."""
    pts = np.asarray(points_cam, np.float64)
    if side == "right":
        pts = pts - np.array([baseline_m, 0.0, 0.0])
    elif side != "left":
        raise ValueError(f"side: expected 'left' or 'right', got {side!r}")
    x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
    ok = (z > min_depth_m) & (z < np.inf)  # NaN fails both
    zs = np.where(ok, z, 1.0)
    uf = focal_px * x / zs + cx
    vf = focal_px * y / zs + cy
    ok &= np.isfinite(uf) & np.isfinite(vf)  # a non-finite x or y
    u = np.rint(np.where(ok, uf, -1)).astype(np.int64)
    v = np.rint(np.where(ok, vf, -1)).astype(np.int64)
    w, h = size
    ok &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
    return u, v, z, ok


def _zbuffer(u: np.ndarray, v: np.ndarray, d: np.ndarray, size: tuple[int, int]
             ) -> tuple[np.ndarray, np.ndarray]:
    """Sparse (H, W) float32 disparity and valid mask of pixels (u, v) with disparities d: the
    nearest (largest d) wins per pixel."""
    w, h = size
    disparity = np.zeros((h, w), np.float32)
    valid = np.zeros((h, w), bool)
    flat = v * w + u
    # the largest disparity per pixel, unbuffered (~13x faster than sorting the points far to
    # near and writing them in that order, as this did until the projection's speed was
    # measured; the same map)
    np.maximum.at(disparity.ravel(), flat, np.asarray(d, np.float32))
    valid.ravel()[flat] = True
    return disparity, valid


def project_rectified(points_cam: np.ndarray, focal_px: float, cx: float, cy: float,
                      baseline_m: float, size: tuple[int, int], side: str = "left",
                      min_depth_m: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffered projection of points (N, 3), metres in the rectified left camera frame.

    size: (width, height). side "right" projects into the right camera, B metres along +x.
    Nearest point wins per pixel (rounded to the nearest pixel centre).
    Returns (sparse_disparity (H, W) float32, valid (H, W) bool).
    """
    u, v, z, ok = _pixels(points_cam, focal_px, cx, cy, baseline_m, size, side, min_depth_m)
    d = (focal_px * baseline_m / z[ok]).astype(np.float32)
    return _zbuffer(u[ok], v[ok], d, size)


@dataclass(frozen=True)
class OcclusionFilterConfig:
    """Settings of the parallax-aware occlusion filter (pixels; `relative` is a fraction).

    A point is removed when a markedly nearer point (disparity > d (1 + relative) + margin_px)
    lies within `window` (width, height) around it, or along the parallax direction at a
    distance up to |t_xy| / B times the disparity difference plus `slack_px` (see
    `filter_occluded`).
    """

    window: tuple[int, int] = (7, 5)
    relative: float = 0.03
    margin_px: float = 0.5
    search_width_px: int = 5
    slack_px: float = 3.0
    step_px: int = 1
    max_search_px: int = 96
    both_directions: bool = False

    def __post_init__(self) -> None:
        if min(self.window) < 1 or self.window[0] % 2 == 0 or self.window[1] % 2 == 0:
            raise ValueError(f"window: expected odd (width, height) >= 1, got {self.window}")
        if self.relative < 0 or self.margin_px < 0 or self.slack_px < 0:
            raise ValueError("relative, margin_px and slack_px must be >= 0")
        if self.step_px < 1 or self.max_search_px < 0 or self.search_width_px < 1:
            raise ValueError("step_px and search_width_px must be >= 1, max_search_px >= 0")


def filter_occluded(sparse: np.ndarray, valid: np.ndarray, lidar_offset_m: np.ndarray,
                    baseline_m: float, config: OcclusionFilterConfig | None = None
                    ) -> np.ndarray:
    """Valid mask with the points the camera cannot see removed. (H, W) bool.

    The LiDAR sits at `lidar_offset_m` (x, y, z metres in the rectified camera frame), so
    behind every foreground edge it sees background the camera cannot. Such a background point
    projects inside the foreground, displaced from the occluding edge by
    (-t_xy / B) * (d_near - d_far) pixels. Following the KITTI ground-truth cleaning, a point is
    dropped when a markedly nearer point lies (a) inside a small window around it, or (b)
    along that displacement direction no farther than the disparity difference allows.
    """
    cfg = config or OcclusionFilterConfig()
    import cv2

    sparse = np.where(valid, np.asarray(sparse, np.float32), np.float32(0))
    keep = valid.copy()
    ys, xs = np.divmod(np.flatnonzero(valid), valid.shape[1])
    if ys.size == 0:
        return keep
    d = sparse[ys, xs]
    threshold = d * (1 + cfg.relative) + cfg.margin_px
    local = cv2.dilate(sparse, cv2.getStructuringElement(cv2.MORPH_RECT, cfg.window))
    occluded = local[ys, xs] > threshold
    t_xy = np.asarray(lidar_offset_m, np.float64)[:2]
    norm = float(np.hypot(*t_xy))
    if norm > 1e-6 and cfg.max_search_px > 0:
        # the hidden background lands up to gain * (d_near - d) px from the occluding edge,
        # displaced away from the LiDAR; the nearer surface's own points lie towards it
        _search_along(sparse, ys, xs, threshold, occluded, t_xy / norm, norm / baseline_m, cfg)
    keep[ys[occluded], xs[occluded]] = False
    return keep


def _search_along(sparse: np.ndarray, ys: np.ndarray, xs: np.ndarray, threshold: np.ndarray,
                  occluded: np.ndarray, direction: np.ndarray, gain: float,
                  config: OcclusionFilterConfig) -> None:
    """Marks in `occluded` the points (at `ys`, `xs`, not yet occluded) that a markedly
    nearer point hides along `direction` (a unit (x, y) in the image, both ways with
    `both_directions`): one no farther than `gain` (px of displacement per px of disparity
    difference) × the difference, plus `slack_px`, probed every `step_px`."""
    import cv2

    cfg = config
    d = sparse[ys, xs]
    h, w = sparse.shape
    wide = sparse
    if cfg.search_width_px > 1:
        across = (cfg.search_width_px, 1) if abs(direction[1]) >= abs(direction[0]) \
            else (1, cfg.search_width_px)
        wide = cv2.dilate(sparse, cv2.getStructuringElement(cv2.MORPH_RECT, across))
    signs = (1.0, -1.0) if cfg.both_directions else (1.0,)
    # zero-pad by the search length so every probe is in bounds (zero never occludes)
    pad = cfg.max_search_px + 1
    pw = w + 2 * pad
    padded = np.zeros((h + 2 * pad, pw), np.float32)
    padded[pad:pad + h, pad:pad + w] = wide
    flat = (ys + pad) * pw + (xs + pad)
    for sign in signs:
        nearby = _search_box_max(wide, sign * direction, cfg.max_search_px)[ys, xs]
        reach = gain * (nearby - d) + cfg.slack_px
        # a point whose box holds nothing markedly nearer can never be hit
        idx = np.nonzero(~occluded & (reach >= cfg.step_px) & (nearby > threshold))[0]
        p_flat, p_d, p_thr, p_reach = flat[idx], d[idx], threshold[idx], reach[idx]
        steps = np.arange(cfg.step_px, cfg.max_search_px + 1, cfg.step_px)
        # probes in blocks of 8 steps, one gather each (fewer numpy calls: the whole
        # projection 4.98 against 5.43 ms median for one step at a time, interleaved on
        # 6 scenes); a probe past a point's reach cannot hit (it would need a nearer
        # point than its box holds), so none is masked
        for start in range(0, steps.size, 8):
            k = steps[start:start + 8]
            offsets = (np.rint(sign * k * direction[1]).astype(np.int64) * pw
                       + np.rint(sign * k * direction[0]).astype(np.int64))
            near = padded.ravel()[p_flat[:, None] + offsets]
            hit = ((near > p_thr[:, None])
                   & (gain * (near - p_d[:, None]) + cfg.slack_px >= k)).any(axis=1)
            occluded[idx[hit]] = True
            # drop the points just removed and those no nearer point can reach any more
            stay = ~hit & (p_reach >= k[-1] + cfg.step_px)
            if not stay.all():
                idx, p_flat, p_d, p_thr, p_reach = (a[stay] for a in
                                                    (idx, p_flat, p_d, p_thr, p_reach))
                if idx.size == 0:
                    break


def _search_box_max(image: np.ndarray, direction: np.ndarray, length: int) -> np.ndarray:
    """Per pixel, the maximum of `image` over the box that the segment from the pixel to
    `length` px along `direction` (x, y) spans: no probe of a search along that segment can
    meet a nearer point than this. No k beyond a point's reach can hit, so this bounds how far
    each point searches. The box lies on the search's side of the pixel only (an anchored
    dilation): the symmetric box let every point on a slanted floor, which has nearer floor
    behind it, search to its full reach; one-sided, the 64-beam filter is ~2x faster."""
    import cv2

    extent = [int(np.ceil(length * abs(c))) for c in direction]
    size = (extent[0] + 1, extent[1] + 1)
    # dilate reads src(p + offset - anchor) for every offset in the kernel
    anchor = tuple(0 if c >= 0 else e for c, e in zip(direction, extent, strict=True))
    kernel = np.ones((size[1], size[0]), np.uint8)
    return cv2.dilate(image, kernel, anchor=anchor, borderType=cv2.BORDER_CONSTANT,
                      borderValue=0)


def rectified_lidar(calib, T_cam_lidar: np.ndarray) -> np.ndarray:
    """(4, 4) transform from the LiDAR to the rectified left camera (R1 after T_cam_lidar)."""
    T_rect = np.eye(4)
    T_rect[:3, :3] = calib.rect["R1"]
    return T_rect @ np.asarray(T_cam_lidar, np.float64)


def _parallax_source(calib, T: np.ndarray, side: str) -> np.ndarray:
    """The LiDAR's position in the rectified camera of `side` (T: LiDAR to rectified left)."""
    # seen from the right camera the LiDAR sits B metres further left
    return T[:3, 3] - (np.array([calib.baseline_m, 0, 0]) if side == "right" else 0)


def project_to_disparity(points: np.ndarray, calib, T_cam_lidar: np.ndarray,
                         side: str = "left", occlusion: OcclusionFilterConfig | None = None,
                         filter_occlusions: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """LiDAR points (N, 3) metres in the LiDAR frame -> sparse disparity in a rectified image.

    Transform by T_cam_lidar into the left camera, rotate by the rectification R1, project with
    P1 (nearest point wins per pixel, d = f B / z), then drop points the camera cannot see
    (`filter_occluded`, with the LiDAR's rectified position as the parallax source).
    calib: a `calibration.model.StereoCalibration`. Returns ((H, W) float32, (H, W) bool).
    """
    T = rectified_lidar(calib, T_cam_lidar)
    cx, cy = calib.principal_point
    sparse, valid = project_rectified(transform_points(T, points), calib.focal_px, cx, cy,
                                      calib.baseline_m, calib.image_size, side)
    if filter_occlusions:
        valid = filter_occluded(sparse, valid, _parallax_source(calib, T, side),
                                calib.baseline_m, occlusion)
        sparse = np.where(valid, sparse, np.float32(0))
    return sparse, valid


def visible_points(points: np.ndarray, calib, T_cam_lidar: np.ndarray, side: str = "left",
                   occlusion: OcclusionFilterConfig | None = None) -> np.ndarray:
    """(N,) bool: which LiDAR points the camera of `side` sees, by the same z-buffer and
    occlusion filter as `project_to_disparity`. A point that lost its pixel's z-buffer counts
    as seen unless the winner is markedly nearer by the filter's own threshold: a tighter test
    keeps the points whose range noise made them nearer and biases the set (on the rig, +0.34
    px of disparity at 0.7 m with 1 cm noise)."""
    cfg = occlusion or OcclusionFilterConfig()
    T = rectified_lidar(calib, T_cam_lidar)
    cx, cy = calib.principal_point
    fb = calib.focal_px * calib.baseline_m
    u, v, z, ok = _pixels(transform_points(T, points), calib.focal_px, cx, cy,
                          calib.baseline_m, calib.image_size, side, 0.05)
    d = np.where(ok, fb / np.where(ok, z, 1.0), 0.0).astype(np.float32)
    sparse, valid = _zbuffer(u[ok], v[ok], d[ok], calib.image_size)
    keep = filter_occluded(sparse, valid, _parallax_source(calib, T, side), calib.baseline_m,
                           cfg)
    seen = np.zeros(len(d), bool)
    winner = np.where(keep, sparse, np.inf)[v[ok], u[ok]]
    seen[ok] = winner <= d[ok] * (1 + cfg.relative) + cfg.margin_px
    return seen
