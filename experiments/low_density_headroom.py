"""Where the engine's bad-3 pixels lie on sparse LiDAR, and how many of them SGBM gets right.

For each scene folder: the engine's output (the shipped bundle, ONNX Runtime, int8, 4
iterations) and OpenCV SGBM's (the fusion's), each pixel's distance to the nearest LiDAR point
and whether it lies within 2 px of a depth edge of the ground truth (a 1 px step). Prints the
engine's bad-3 split by those, and the share of its bad pixels that SGBM matched within 3 px.
    python experiments/low_density_headroom.py data/aloe data/aloe_r8 data/motorcycle \
        data/motorcycle_r8
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from edge_depth.baselines import (
    make_sgbm,
    nearest_valid_index,
    sgbm_disparities_for,
    sgbm_disparity,
)
from edge_depth.runtime.engine import Engine
from edge_depth.runtime.options import EngineOptions
from edge_depth.sim.folder import read_scene_folder


def depth_edges(gt: np.ndarray, step_px: float = 1.0, grow_px: int = 2) -> np.ndarray:
    """Pixels within `grow_px` of a GT disparity step over `step_px` to a neighbour."""
    g = np.nan_to_num(gt, nan=0.0)
    edge = np.zeros(g.shape, bool)
    edge[:, 1:] |= np.abs(np.diff(g, axis=1)) > step_px
    edge[1:, :] |= np.abs(np.diff(g, axis=0)) > step_px
    kernel = np.ones((2 * grow_px + 1, 2 * grow_px + 1), np.uint8)
    return cv2.dilate(edge.astype(np.uint8), kernel) > 0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", nargs="+", type=Path)
    args = p.parse_args()
    engine = Engine(options=EngineOptions(runtime="onnxruntime", precision="int8"))
    for folder in args.folders:
        scene = read_scene_folder(folder)
        gt = scene.disp
        known = np.isfinite(gt) & (gt > 0)
        net = engine.infer(scene.left, scene.right, scene.sparse, iters=4).disparity
        matcher = make_sgbm(sgbm_disparities_for(float(gt[known].max())))
        sgbm = sgbm_disparity(scene.left, scene.right, matcher)
        _, dist = nearest_valid_index(scene.sparse > 0)
        edges = depth_edges(gt)
        bad = known & (np.abs(net - gt) > 3)
        sgbm_good = known & (sgbm > 0) & (np.abs(sgbm - gt) <= 3)
        n = known.sum()
        print(f"\n{folder.name}: engine bad-3 {100 * bad.sum() / n:.2f} %, SGBM matched within "
              f"3 px on {100 * (bad & sgbm_good).sum() / max(bad.sum(), 1):.0f} % of those")
        for name, part in (("near a depth edge", edges), ("away from edges", ~edges)):
            print(f"  {name:18s} {100 * (part & known).sum() / n:5.1f} % of pixels, "
                  f"bad-3 {100 * (bad & part).sum() / n:.2f} points, SGBM right on "
                  f"{100 * (bad & part & sgbm_good).sum() / n:.2f}")
        for lo, hi in ((0, 4), (4, 12), (12, 25), (25, 1e9)):
            part = (dist >= lo) & (dist < hi)
            print(f"  LiDAR {lo:>2.0f}-{hi:<4.0f}px away "
                  f"{100 * (part & known).sum() / n:5.1f} % of pixels, "
                  f"bad-3 {100 * (bad & part).sum() / n:.2f} points, SGBM right on "
                  f"{100 * (bad & part & sgbm_good).sum() / n:.2f}")


if __name__ == "__main__":
    main()
