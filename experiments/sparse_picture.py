"""docs/sparse_lidar.jpg: what SGBM's match far from the points does on a sparse LiDAR map.

One real pair at a few LiDAR densities (scene folders by `tools/real_pairs.py --rows N`), one
row each: the left image with the LiDAR points, then |error| of the engine with the far
matching off (`edge_match_far_px = 0`), on (the default), and of the SGBM + LiDAR fusion, each
labelled with its EPE px / bad-3 % (the shipped bundle, ONNX Runtime, int8, 4 iterations).
    python experiments/sparse_picture.py data/aloe_r1 data/aloe_r8 --out docs/sparse_lidar.jpg
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from edge_depth.baselines import (
    make_sgbm,
    sgbm_disparities_for,
    sgbm_disparity,
    sgbm_lidar_fusion,
)
from edge_depth.demo import error_map, labelled
from edge_depth.metrics import disparity_metrics
from edge_depth.runtime.engine import Engine
from edge_depth.sim.folder import read_scene_folder


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", nargs="+", type=Path)
    p.add_argument("--out", type=Path, default=Path("docs/sparse_lidar.jpg"))
    p.add_argument("--scale", type=float, default=0.5)
    args = p.parse_args()
    engines = {"far matching off": Engine(runtime="onnxruntime", precision="int8",
                                          edge_match_far_px=0.0),
               "far matching on (default)": Engine(runtime="onnxruntime", precision="int8")}
    rows = []
    for folder in args.folders:
        s = read_scene_folder(folder)
        known = np.isfinite(s.disp) & (s.disp > 0)
        gt = np.where(known, s.disp, 0).astype(np.float32)
        points = cv2.cvtColor(np.asarray(s.left, np.uint8), cv2.COLOR_GRAY2BGR)
        ys, xs = np.nonzero(s.sparse > 0)
        drawn = cv2.dilate((s.sparse > 0).astype(np.uint8), np.ones((5, 3), np.uint8)) > 0
        points[drawn] = (0, 255, 255)  # thick enough to see at the tiles' scale
        rows_of_points = len(np.unique(ys))
        small = lambda im: cv2.resize(im, None, fx=args.scale, fy=args.scale,  # noqa: E731
                                      interpolation=cv2.INTER_AREA)
        plural = "s" * (rows_of_points != 1)
        tiles = [labelled(small(points), f"{folder.name}: {rows_of_points} LiDAR row{plural}")]
        preds = {name: e.infer(s.left, s.right, s.sparse).disparity for name, e in engines.items()}
        sgbm = sgbm_disparity(s.left, s.right, make_sgbm(sgbm_disparities_for(float(gt.max()))))
        preds["SGBM + LiDAR fusion"] = sgbm_lidar_fusion(sgbm, s.sparse, s.sparse > 0)
        for name, pred in preds.items():
            m = disparity_metrics(pred, s.disp)
            heat = error_map(pred, gt)
            heat[~known] = 64
            tiles.append(labelled(small(heat), f"{name}: {m['epe']:.2f} / {m['bad3']:.1f} %"))
        rows.append(np.hstack(tiles))
    cv2.imwrite(str(args.out), np.vstack(rows), [cv2.IMWRITE_JPEG_QUALITY, 85])
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
