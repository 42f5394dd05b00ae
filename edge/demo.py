"""`edge-depth demo`: the embedded default, run on the synthetic rig with no hardware.

The network engine is not built yet (the deployment issue adds it). Until then the demo runs
the parts that exist and says so: the synthetic rig as a virtual robot, LiDAR projection, and
the classical baselines (OpenCV SGBM, LiDAR-only densification), scored against the rig's exact
ground truth. It writes a picture and prints a summary; it never shows a fake network result.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from edge.baselines import lidar_linear, make_sgbm, sgbm_disparity
from edge.metrics import disparity_metrics
from edge.sim.rig import make_sample


def colorize_disparity(disparity: np.ndarray, max_disparity: float) -> np.ndarray:
    """(H, W) disparity -> (H, W, 3) uint8 BGR (turbo), black where <= 0 or not finite."""
    ok = np.isfinite(disparity) & (disparity > 0)
    scaled = np.clip(np.where(ok, disparity, 0) / max(max_disparity, 1e-6) * 255, 0, 255)
    colour = cv2.applyColorMap(scaled.astype(np.uint8), cv2.COLORMAP_TURBO)
    colour[~ok] = 0
    return colour


def error_map(pred: np.ndarray, gt: np.ndarray, max_error_px: float = 4.0) -> np.ndarray:
    """|pred - gt| as a (H, W, 3) heat map (black = exact, white = >= max_error_px; holes red)."""
    has = np.isfinite(pred) & (pred > 0)
    err = np.clip(np.abs(np.where(has, pred, 0) - gt) / max_error_px * 255, 0, 255)
    heat = cv2.applyColorMap(err.astype(np.uint8), cv2.COLORMAP_INFERNO)
    heat[~has] = (0, 0, 255)
    return heat


def _label(image: np.ndarray, text: str) -> np.ndarray:
    out = image.copy()
    cv2.rectangle(out, (0, 0), (out.shape[1], 22), (0, 0, 0), -1)
    cv2.putText(out, text, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1,
                cv2.LINE_AA)
    return out


def demo_command(out: Path, frames: int, seed: int) -> int:
    out.mkdir(parents=True, exist_ok=True)
    print("edge-depth demo: synthetic rig (640x400, 16-beam LiDAR)")
    print("NOTE: the network engine is not built yet; this demo runs the rig, the LiDAR "
          "projection and the classical baselines only.")
    matcher = make_sgbm()
    rows, picture = [], None
    for i in range(frames):
        t0 = time.perf_counter()
        sample = make_sample(seed + i)
        t1 = time.perf_counter()
        sparse, valid = sample.sparse_disparity()
        t2 = time.perf_counter()
        sgbm = sgbm_disparity(sample.left, sample.right, matcher)
        t3 = time.perf_counter()
        lidar = lidar_linear(sparse, valid)
        t4 = time.perf_counter()
        m_sgbm = disparity_metrics(sgbm, sample.disp_left)
        m_lidar = disparity_metrics(lidar, sample.disp_left)
        rows.append((m_sgbm, m_lidar, (t1 - t0, t2 - t1, t3 - t2, t4 - t3)))
        print(f"frame {i}: {int(valid.sum())} LiDAR px | SGBM EPE {m_sgbm['epe']:.2f} px "
              f"bad-3 {m_sgbm['bad3']:.1f}% | LiDAR-linear EPE {m_lidar['epe']:.2f} px "
              f"bad-3 {m_lidar['bad3']:.1f}%")
        if picture is None:
            max_d = float(sample.disp_left.max())
            left = cv2.cvtColor(sample.left, cv2.COLOR_GRAY2BGR)
            lidar_view = left.copy()
            ys, xs = np.nonzero(valid)
            colours = colorize_disparity(sparse[ys, xs][None], max_d)[0]
            for x, y, c in zip(xs, ys, colours, strict=True):
                cv2.circle(lidar_view, (int(x), int(y)), 1, tuple(int(v) for v in c), -1)
            top = np.hstack([_label(left, "left (rectified)"),
                             _label(lidar_view, "LiDAR projected (disparity)"),
                             _label(colorize_disparity(sample.disp_left, max_d), "ground truth")])
            bottom = np.hstack([
                _label(colorize_disparity(sgbm, max_d), "OpenCV SGBM"),
                _label(error_map(sgbm, sample.disp_left), "SGBM |error| (0-4 px, red=hole)"),
                _label(error_map(lidar, sample.disp_left), "LiDAR-linear |error|")])
            picture = np.vstack([top, bottom])
    cv2.imwrite(str(out / "demo.png"), picture)
    med = np.median(np.array([r[2] for r in rows]), axis=0) * 1000
    print(f"summary over {frames} frames (median ms): render {med[0]:.0f}, project {med[1]:.1f}, "
          f"sgbm {med[2]:.0f}, lidar-linear {med[3]:.0f}")
    for name, k in (("SGBM", 0), ("LiDAR-linear", 1)):
        epe = np.mean([r[k]["epe"] for r in rows])
        bad3 = np.mean([r[k]["bad3"] for r in rows])
        print(f"  {name:13s} EPE {epe:.2f} px, bad-3 {bad3:.1f}%")
    print(f"wrote {out / 'demo.png'}")
    return 0
