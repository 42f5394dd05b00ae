"""A study: does the LiDAR's agreement with a stereo matcher that never saw it resolve the
LiDAR–camera rotation error? (docs/experiments.md, 2026-12-06 00:20.)

    python experiments/drift_stereo.py [--frames 100] [--every 5] [--seed 1000000] [--matcher bm]

For each sample frame: the block matcher's disparity D of the rectified pair (StereoBM on every
other row, the engine's own matching, or SGBM), and each LiDAR point's disparity d and position
(u, v) under the calibration rotated by every probe of a (pitch, yaw) grid and a roll line.
The cost of a probe is the mean over the points of min(|d − D(u, v)|, TRUNCATE_PX) where D has a
value (a hole counts HOLE_PX). Off by a rotation, the points near depth edges land on the other
surface. The costs are summed over the samples; the estimate is the grid's lowest probe refined
by a parabola per axis, its negative the error.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from edge_depth.calibration.extrinsics import _perturb
from edge_depth.calibration.projection import rectified_lidar

TRUNCATE_PX = 3.0
HOLE_PX = 1.5
STEP_DEG = 0.1
REACH_DEG = 0.8
ROLL_STEP_DEG = 0.2
ROLL_REACH_DEG = 1.2


def rotations(angles: np.ndarray) -> np.ndarray:
    """(P, 3) rotation vectors in degrees (pitch, yaw, roll) -> (P, 3, 3)."""
    import cv2

    return np.stack([cv2.Rodrigues(np.radians(a))[0] for a in angles])


def probe_costs(points_cam: np.ndarray, disparity: np.ndarray, f: float, cx: float, cy: float,
                baseline: float, probes: np.ndarray) -> np.ndarray:
    """Each probe's summed truncated |d − D| (holes HOLE_PX), and the point count."""
    rot = rotations(probes)
    cam = np.einsum("pij,nj->pni", rot, points_cam)
    z = np.maximum(cam[..., 2], 1e-3)
    u = np.rint(f * cam[..., 0] / z + cx).astype(np.int32)
    v = np.rint(f * cam[..., 1] / z + cy).astype(np.int32)
    h, w = disparity.shape
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h) & (cam[..., 2] > 0.2)
    D = disparity[np.clip(v, 0, h - 1), np.clip(u, 0, w - 1)]
    r = np.where(D > 0, np.minimum(np.abs(f * baseline / z - D), TRUNCATE_PX), HOLE_PX)
    r = np.where(inside, r, HOLE_PX)
    return r.sum(axis=1)


def seen_points(points, calib, T, grow_px: int) -> np.ndarray:
    """The points the left camera sees by the occlusion filter grown by `grow_px` (as
    `PhotometricCost` takes them)."""
    from edge_depth.calibration.projection import OcclusionFilterConfig, visible_points

    base = OcclusionFilterConfig()
    cfg = OcclusionFilterConfig(window=(base.window[0] + 2 * grow_px,
                                        base.window[1] + 2 * grow_px),
                                slack_px=base.slack_px + grow_px, relative=0.08, margin_px=1.0)
    return visible_points(points, calib, T, "left", cfg)


def from_sparse(points, calib, T, limit: int) -> np.ndarray:
    """The daemon's projected, filtered sparse map back in the rectified camera's 3-D."""
    from edge_depth.calibration.projection import project_to_disparity

    sparse, valid = project_to_disparity(np.asarray(points), calib, T)
    v, u = np.nonzero(valid)
    d = sparse[v, u].astype(np.float64)
    if len(d) > limit:
        keep = np.linspace(0, len(d) - 1, limit).astype(int)
        u, v, d = u[keep], v[keep], d[keep]
    f, (cx, cy) = calib.focal_px, calib.principal_point
    z = f * calib.baseline_m / d
    return np.stack([(u - cx) * z / f, (v - cy) * z / f, z], 1)


def grid() -> tuple[np.ndarray, np.ndarray]:
    axis = np.arange(-REACH_DEG, REACH_DEG + 1e-9, STEP_DEG)
    pitch, yaw = np.meshgrid(axis, axis, indexing="ij")
    return axis, np.stack([pitch.ravel(), yaw.ravel(), np.zeros(pitch.size)], 1)


def parabola_min(xs: np.ndarray, costs: np.ndarray) -> float:
    i = int(np.argmin(costs))
    if 0 < i < len(xs) - 1:
        a, b, c = costs[i - 1], costs[i], costs[i + 1]
        curve = a - 2 * b + c
        if curve > 0:
            return float(xs[i] + 0.5 * (a - c) / curve * (xs[1] - xs[0]))
    return float(xs[i])


def main() -> None:
    from edge_depth.baselines import make_sgbm
    from edge_depth.runtime.edge_match import EdgeMatch
    from edge_depth.sim import RigConfig, make_sample
    from edge_depth.sim.lidar import default_T_cam_lidar

    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--every", type=int, default=5)
    p.add_argument("--seed", type=int, default=1_000_000)
    p.add_argument("--matcher", choices=("bm", "sgbm", "gt", "engine"), default="bm")
    p.add_argument("--points", type=int, default=2000)
    p.add_argument("--engine", nargs="*", default=[], metavar="KEY=VALUE",
                   help="engine options of the stereo-only engine (e.g. edge_match=0 iters=2)")
    p.add_argument("--from-sparse", action="store_true",
                   help="the points as the engine gets them: the projected, filtered map")
    p.add_argument("--grow", type=int, default=-1, help="occlusion filter grown by (-1: off)")
    args = p.parse_args()
    rig = RigConfig()
    samples = [make_sample(args.seed + i, rig, "beams16")
               for i in range(0, args.frames, args.every)]
    bm = EdgeMatch(64, row_step=2)
    sgbm = make_sgbm(64, 5)
    axis, probes = grid()
    roll_axis = np.arange(-ROLL_REACH_DEG, ROLL_REACH_DEG + 1e-9, ROLL_STEP_DEG)
    cases = (("right", (0, 0, 0)), ("yaw +0.3", (0, 0.3, 0)), ("yaw -0.3", (0, -0.3, 0)),
             ("pitch +0.3", (0.3, 0, 0)), ("pitch -0.3", (-0.3, 0, 0)),
             ("roll +0.5", (0, 0, 0.5)))
    T_true = default_T_cam_lidar()
    matched = []
    if args.matcher == "engine":  # the shipped engine without the LiDAR: stereo only
        from edge_depth.runtime.engine import Engine

        given = dict(kv.split("=") for kv in args.engine)
        engine = Engine(**{k: int(v) if v.isdigit() else v for k, v in given.items()})
    for s in samples:
        if args.matcher == "gt":  # the diagnosis: the true disparity in place of a matcher's
            matched.append(np.where(np.isfinite(s.disp_left), s.disp_left, 0).astype(np.float32))
        elif args.matcher == "engine":
            out = engine.infer(s.left, s.right, np.zeros(s.left.shape, np.float32))
            matched.append(out.disparity.astype(np.float32))
        elif args.matcher == "bm":
            matched.append(bm.matched(s.left, s.right))
        else:
            raw = sgbm.compute(s.left, s.right).astype(np.float32) / 16
            matched.append(np.where(raw > 0, raw, 0).astype(np.float32))
    for name, x in cases:
        T = _perturb(T_true, np.r_[x, 0, 0, 0])
        started = time.perf_counter()
        points = [camera_points(s, T, args) for s in samples]
        total = sum(probe_costs(cam, D, *_intrinsics(s), probes)
                    for s, cam, D in zip(samples, points, matched, strict=True))
        count = sum(len(cam) for cam in points)
        ms = (time.perf_counter() - started) / len(samples) * 1000
        costs = total.reshape(len(axis), len(axis))
        i, j = np.unravel_index(int(np.argmin(costs)), costs.shape)
        pitch = parabola_min(axis, costs[:, j])
        yaw = parabola_min(axis, costs[i, :])
        rp = np.stack([np.full_like(roll_axis, pitch), np.full_like(roll_axis, yaw),
                       roll_axis], 1)
        roll_total = sum(probe_costs(cam, D, *_intrinsics(s), rp)
                         for s, cam, D in zip(samples, points, matched, strict=True))
        roll = parabola_min(roll_axis, roll_total)
        print(f"{name:11s} error pitch {-pitch:+.3f} yaw {-yaw:+.3f} roll {-roll:+.3f} deg "
              f"(cost {costs.min() / count:.3f}); {ms:.1f} ms a sample, {len(samples)} samples",
              flush=True)


def _intrinsics(sample) -> tuple[float, float, float, float]:
    calib = sample.calibration()
    cx, cy = calib.principal_point
    return calib.focal_px, cx, cy, calib.baseline_m


def camera_points(sample, T, args) -> np.ndarray:
    """A sample's LiDAR points as the case sees them, in the rectified left camera."""
    calib = sample.calibration()
    if args.from_sparse:
        return from_sparse(sample.scan.points, calib, T, args.points)
    pts = np.asarray(sample.scan.points, np.float64)
    if args.grow >= 0:
        pts = pts[seen_points(pts, calib, T, args.grow)]
    if len(pts) > args.points:
        pts = pts[np.linspace(0, len(pts) - 1, args.points).astype(int)]
    T_rect = rectified_lidar(calib, T)
    return pts @ T_rect[:3, :3].T + T_rect[:3, 3]

if __name__ == "__main__":
    main()
