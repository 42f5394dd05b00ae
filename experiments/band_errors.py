"""Where the network's estimate is off by more than 3 px on the published pairs, by how much,
and whether full-range guided SGM (its left-right check passed) is right there: why a narrow
band around the estimate cannot be enough (docs/experiments.md, the band refinement).

    python experiments/band_errors.py runs/band/aloe runs/band/moto

The estimate is the engine's with every stage after the network off (no LiDAR or edge
selection, no matching, no median).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from edge_depth.guided_sgm import GuidedSgmConfig, guided_sgm, guided_sgm_lidar
from edge_depth.runtime.engine import Engine
from edge_depth.runtime.options import EngineOptions
from edge_depth.sim.folder import read_scene_folder

BARE = dict(lidar_select=False, edge_select=False, edge_match=0, edge_median="off")
BINS = ((3, 5), (5, 10), (10, 20), (20, np.inf))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", nargs="+", type=Path)
    args = p.parse_args()
    engine = Engine(options=EngineOptions(runtime="onnxruntime", **BARE))
    for folder in args.folders:
        s = read_scene_folder(folder)
        gt = s.disp
        ok = np.isfinite(gt) & (gt > 0)
        count = max(64, int(np.ceil(np.max(gt[ok]) / 16) * 16))
        config = GuidedSgmConfig(num_disparities=count)
        result = engine.infer(s.left, s.right, s.sparse)
        checked = guided_sgm(s.left, s.right, s.sparse, config)
        filled = guided_sgm_lidar(s.left, s.right, s.sparse, config)
        off = np.abs(result.disparity - gt)
        right = np.abs(filled - gt) <= 3
        bad = ok & (off > 3)
        print(f"{folder.name}: estimate bad-3 {bad.mean() * 100 / ok.mean():.2f} %, guided SGM "
              f"+ LiDAR bad-3 {(ok & ~right).sum() / ok.sum() * 100:.2f} %")
        for lo, hi in BINS:
            m = bad & (off > lo) & (off <= hi)
            share = m.sum() / ok.sum() * 100
            print(f"  off {lo}-{hi} px: {share:.2f} % of pixels; guided right there "
                  f"{(m & right).sum() / ok.sum() * 100:.2f} %, checked there "
                  f"{(m & (checked > 0)).sum() / ok.sum() * 100:.2f} %")
        c = result.confidence
        print(f"  confidence where off: median {np.median(c[bad]):.2f}; below 0.5 there "
              f"{(c[bad] < 0.5).mean() * 100:.0f} %, everywhere {(c[ok] < 0.5).mean() * 100:.0f} %")


if __name__ == "__main__":
    main()
