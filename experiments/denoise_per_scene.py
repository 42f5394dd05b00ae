"""Scene by scene, what the LiDAR smoothing (`[engine] denoise_lidar`) does to a noisy
split: the map's mean error against the clean split's map before and after it, and the
engine's EPE with LiDAR off → on (ONNX Runtime, the shipped bundle at its defaults).

    python experiments/denoise_per_scene.py data/noisy_fresh/test16_n100 --clean data/test16
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from edge_depth.runtime.engine import Engine
from edge_depth.runtime.lidar_denoise import LidarDenoise
from edge_depth.sim.folder import read_pfm


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("split", type=Path)
    p.add_argument("--clean", type=Path, required=True, help="the same split, maps clean")
    args = p.parse_args()
    engines = [Engine(runtime="onnxruntime", denoise_lidar=on) for on in (False, True)]
    print("| scene | EPE off | EPE on | change | noise level px | map error before | after |")
    print("|---|---|---|---|---|---|---|")
    for scene in sorted(p.parent for p in args.split.glob("*/sparse.pfm")):
        left, right = (cv2.imread(str(scene / f"{s}.png"), cv2.IMREAD_GRAYSCALE)
                       for s in ("left", "right"))
        sparse, truth = read_pfm(scene / "sparse.pfm"), read_pfm(scene / "disp.pfm")
        known = np.isfinite(truth) & (truth > 0)
        epe = [float(np.abs(e.infer(left, right, sparse).disparity - truth)[known].mean())
               for e in engines]
        clean = read_pfm(args.clean / scene.name / "sparse.pfm")
        points = sparse > 0
        smoothed, level = LidarDenoise().apply(sparse)
        before = float(np.abs(sparse - clean)[points].mean())
        after = float(np.abs(smoothed - clean)[points].mean())
        change = 100 * (epe[1] / epe[0] - 1)
        print(f"| {scene.name} | {epe[0]:.3f} | {epe[1]:.3f} | {change:+.1f} % | {level or 0:.2f} "
              f"| {before:.3f} | {after:.3f} |")


if __name__ == "__main__":
    main()
