"""Scene folders whose LiDAR map is scattered points instead of rows: the ground truth at a
random fraction of the pixels plus N(0, 0.1 px), as a solid-state or non-repetitive LiDAR
might leave it. Writes OUT/<folder>_rand1 (1 % of the pixels) and OUT/<folder>_rand03 (0.3 %).
    python experiments/random_points.py data/aloe data/motorcycle --out data/random_pts
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scene_variants import write_lidar_variants

from edge_depth.sim.folder import read_scene_folder

FRACTIONS = {"rand1": 0.01, "rand03": 0.003}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", nargs="+", type=Path)
    p.add_argument("--out", type=Path, default=Path("data/random_pts"))
    p.add_argument("--seed", type=int, default=7)
    args = p.parse_args()
    for folder in args.folders:
        gt = read_scene_folder(folder).disp
        known = np.isfinite(gt) & (gt > 0)
        rng = np.random.default_rng(args.seed)
        variants = {}
        for key, fraction in FRACTIONS.items():
            pick = known & (rng.random(gt.shape) < fraction)
            sparse = np.zeros(gt.shape, np.float32)
            sparse[pick] = gt[pick] + rng.normal(0.0, 0.1, int(pick.sum()))
            variants[key] = sparse
        write_lidar_variants(folder, variants, args.out)


if __name__ == "__main__":
    main()
