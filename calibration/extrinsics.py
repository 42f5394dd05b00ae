"""Check and refine the LiDAR-to-camera extrinsics on recorded frames.

The check: the projected LiDAR disparity should agree with OpenCV SGBM on the same rectified
frames. The disagreement at each LiDAR point (SGBM sampled bilinearly where the point lands) is
reported as median and 90th percentile.

The refinement (`refine_extrinsics`) does not use SGBM: it minimises the photometric difference
between the left and right projections of each LiDAR point both cameras see (`PhotometricCost`).
SGBM was the first reference and its own errors biased the optimum by 0.2 degrees of pitch
and 4-8 mm of height (block sizes 5, 3 and 1 alike; with the exact disparity in its place
the optimum is the true pose), however it was scored: least squares on |LiDAR - SGBM|, a
truncated L1, or the fraction of points agreeing within 0.5 px (which ended at 0.16-0.50
degrees).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from edge_depth.calibration.errors import CalibrationError
from edge_depth.calibration.model import StereoCalibration
from edge_depth.calibration.sampling import sample_bilinear


@dataclass(frozen=True)
class ExtrinsicsFrame:
    """One frame for the check: SGBM disparity (H, W) float32 with NaN holes, and the LiDAR
    points (N, 3) metres in the LiDAR frame."""

    stereo_disparity: np.ndarray
    points: np.ndarray


def _subpixel(points: np.ndarray, calib: StereoCalibration, T: np.ndarray,
              min_depth_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each LiDAR point's continuous position (u, v) float32 in the rectified left image, its
    disparity d and its depth z; d, u, v use the depth clamped to `min_depth_m` (callers mask
    the points nearer than that when it matters)."""
    from edge_depth.calibration.projection import rectified_lidar, transform_points

    cam = transform_points(rectified_lidar(calib, T), points)
    zs = np.maximum(cam[:, 2], min_depth_m)
    f = calib.focal_px
    cx, cy = calib.principal_point
    u = (f * cam[:, 0] / zs + cx).astype(np.float32)
    v = (f * cam[:, 1] / zs + cy).astype(np.float32)
    return u, v, f * calib.baseline_m / zs, cam[:, 2]


def _residuals(frames: list[ExtrinsicsFrame], calib: StereoCalibration, T: np.ndarray,
               min_depth_m: float = 0.2) -> np.ndarray:
    """LiDAR disparity minus SGBM disparity at each projected point (NaN where not comparable)."""
    out = []
    for frame in frames:
        u, v, d, z = _subpixel(frame.points, calib, T, min_depth_m)
        res = d - sample_bilinear(frame.stereo_disparity, u, v)
        res[z <= min_depth_m] = np.nan
        out.append(res)
    return np.concatenate(out) if out else np.zeros(0)


def disagreement(frames: list[ExtrinsicsFrame], calib: StereoCalibration, T: np.ndarray
                 ) -> dict[str, float]:
    """Median and 90th percentile of |LiDAR - SGBM| disparity (px), and the points compared."""
    res = np.abs(_residuals(frames, calib, T))
    res = res[np.isfinite(res)]
    if res.size == 0:
        raise CalibrationError("no LiDAR point lands where SGBM has a disparity")
    return dict(median_px=float(np.median(res)), p90_px=float(np.percentile(res, 90)),
                points=int(res.size))


class PhotometricCost:
    """Mean truncated |left - right| intensity at the two projections of every LiDAR point that
    both cameras see: at the right extrinsics each point lands on the same surface point in the
    rectified pair (left (u, v), right (u - d, v)); off by a fraction of a degree, points near
    depth edges land on the wrong surface in one image or both.

    The visible set is fixed while the pose moves (it is recomputed between searches), so it is
    taken conservatively: an occlusion filter with a window and slack grown by `grow_px`. With
    the exact filter the set itself favours the pose it was computed at (on the rig a search
    stalled 0.5 degrees away); with the grown one the cost falls all the way to the true pose.
    Images are blurred by `sigma` px, and the right one is matched to the left's mean and
    standard deviation (the cameras' gain and offset differ)."""

    def __init__(self, frames: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
                 calib: StereoCalibration, T: np.ndarray, sigma: float = 0.0,
                 grow_px: int = 6, relative: float = 0.08, margin_px: float = 1.0,
                 truncate: float = 20.0) -> None:
        import cv2

        from edge_depth.calibration.projection import OcclusionFilterConfig, visible_points

        base = OcclusionFilterConfig()
        # "markedly nearer" well above the range noise (1 cm is 0.7 px at 0.7 m on the rig):
        # at the default threshold neighbours' noise drops the points that happen to be far
        cfg = OcclusionFilterConfig(window=(base.window[0] + 2 * grow_px,
                                            base.window[1] + 2 * grow_px),
                                    slack_px=base.slack_px + grow_px,
                                    relative=relative, margin_px=margin_px)
        self.calib, self.truncate = calib, truncate
        self.items = []
        for left, right, points in frames:
            points = np.asarray(points, np.float64)
            seen = (visible_points(points, calib, T, "left", cfg)
                    & visible_points(points, calib, T, "right", cfg))
            images = [np.asarray(im, np.float32) for im in (left, right)]
            if sigma > 0:
                images = [cv2.GaussianBlur(im, (0, 0), sigma) for im in images]
            lf, rt = images
            rt = (rt - rt.mean()) / max(float(rt.std()), 1e-6) * lf.std() + lf.mean()
            self.items.append((points[seen], lf, rt))
        self.points = sum(len(p) for p, _, _ in self.items)

    def __call__(self, T: np.ndarray) -> float:
        total, count = 0.0, 0
        for points, left, right in self.items:
            u, v, d, _ = _subpixel(points, self.calib, T, 1e-3)
            r = sample_bilinear(left, u, v) - sample_bilinear(right, u - d.astype(np.float32), v)
            r = np.abs(r[np.isfinite(r)])
            total += float(np.minimum(r, self.truncate).sum())
            count += r.size
        if count == 0:
            raise CalibrationError("no LiDAR point lands in both images")
        return total / count


def _perturb(T: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Left-multiply by a small motion x: rotation vector (degrees) and translation (cm), both
    in the left camera's frame."""
    import cv2

    D = np.eye(4)
    D[:3, :3] = cv2.Rodrigues(np.radians(np.asarray(x[:3], np.float64)))[0]
    D[:3, 3] = np.asarray(x[3:], np.float64) / 100
    return D @ T


# (blur sigma px, initial simplex: degrees, cm): coarse to fine; the blurred stages widen the
# basin (a 2 degree / 5 cm error converges), the unblurred one removes their bias
REFINE_STAGES = ((2.0, 0.5, 1.0), (1.0, 0.2, 0.3), (0.0, 0.1, 0.15))


def refine_extrinsics(frames: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
                      calib: StereoCalibration, T_init: np.ndarray,
                      stages=REFINE_STAGES, restarts: int = 3, max_evals: int = 400,
                      progress=None) -> tuple[np.ndarray, dict[str, float]]:
    """Refine T_cam_lidar by minimising `PhotometricCost` over (left, right, points) frames of
    rectified pairs: Nelder-Mead over the 6 pose parameters per stage, restarted with the
    visible set recomputed at the new pose until a search moves less than 0.01 deg / 0.1 mm.
    Returns (T, dict(cost_before, cost_after, points)) with both costs on the final stage.

    Measured on the rig (640x400, 64 beams, 1 degree / 2 cm and 2 degree / 5 cm errors, three
    sets of scenes; `tools/extrinsics_study.py`, README): 6 or 12 frames end within 0.17
    degrees / 2.7 mm, nearly all of it roll (about the optical axis, the weakest direction).
    3 frames end up to 0.25 degrees / 6.3 mm off."""
    from scipy.optimize import minimize

    if not frames:
        raise CalibrationError("no frames to refine the extrinsics on")
    T = np.asarray(T_init, np.float64).copy()
    for sigma, degrees, cm in stages:
        simplex = np.vstack([np.zeros(6), np.diag([degrees] * 3 + [cm] * 3)])
        for _ in range(restarts):
            cost = PhotometricCost(frames, calib, T, sigma)
            result = minimize(lambda x, c=cost, T0=T: c(_perturb(T0, x)), np.zeros(6),
                              method="Nelder-Mead",
                              options=dict(initial_simplex=simplex, xatol=0.005, fatol=1e-6,
                                           maxfev=max_evals, adaptive=True))
            T = _perturb(T, result.x)
            if progress is not None:
                progress(sigma, cost.points, float(result.fun))
            if np.abs(result.x).max() < 0.01:
                break
    final = PhotometricCost(frames, calib, T, stages[-1][0])
    summary = dict(cost_before=final(np.asarray(T_init, np.float64)), cost_after=final(T),
                   points=final.points)
    return T, summary


def pose_difference(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(rotation angle in degrees, translation distance in metres) between two transforms."""
    dR = T_a[:3, :3] @ T_b[:3, :3].T
    angle = np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
    return float(angle), float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]))


def overlay(left: np.ndarray, points: np.ndarray, calib: StereoCalibration, T: np.ndarray
            ) -> np.ndarray:
    """(H, W, 3) BGR: the rectified left image with the LiDAR points it sees coloured by
    disparity (near red, far blue), for judging the extrinsics at depth edges by eye."""
    import cv2

    from edge_depth.calibration.projection import project_to_disparity

    sparse, valid = project_to_disparity(points, calib, T)
    image = cv2.cvtColor(np.asarray(left, np.uint8), cv2.COLOR_GRAY2BGR)
    if valid.any():
        d = sparse[valid]
        lo, hi = np.percentile(d, [2, 98])
        scaled = np.clip((d - lo) / max(hi - lo, 1e-6) * 255, 0, 255).astype(np.uint8)
        image[valid] = cv2.applyColorMap(scaled[:, None], cv2.COLORMAP_JET)[:, 0]
    return image


def perturbed(T: np.ndarray, degrees: float, metres: float, seed: int = 0) -> np.ndarray:
    """T (4, 4) moved by `degrees` about a random axis and `metres` in a random direction
    (a misregistered LiDAR, for checks and studies)."""
    import cv2

    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    D = np.eye(4)
    D[:3, :3] = cv2.Rodrigues(axis / np.linalg.norm(axis) * np.radians(degrees))[0]
    direction = rng.normal(size=3)
    D[:3, 3] = direction / np.linalg.norm(direction) * metres
    return D @ T
