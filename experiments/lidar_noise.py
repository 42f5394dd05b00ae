"""Real-pair folders with a noisier LiDAR: every point's disparity + N(0, σ) for σ 0.4, 0.75,
1.0 and 1.5 px, and + N(0, 0.5) with 2 % of the points moved by up to ±10 px. The same images
and ground truth.

    python experiments/lidar_noise.py data/aloe data/motorcycle --out data/noisy
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scene_variants import write_lidar_variants

from edge_depth.sim.folder import read_pfm

SEED = 13
SIGMAS = {"n040": 0.4, "n075": 0.75, "n100": 1.0, "n150": 1.5}
OUTLIERS = ("n050out2", 0.5, 0.02, 10.0)  # name, σ, share moved, by up to (px)


def noisy(sparse: np.ndarray, sigma: float, rng: np.random.Generator, share: float = 0.0,
          reach_px: float = 0.0) -> np.ndarray:
    out = sparse.copy()
    points = np.flatnonzero(out > 0)
    values = out.ravel()[points] + rng.normal(0.0, sigma, points.size)
    moved = rng.random(points.size) < share
    values[moved] += rng.uniform(-reach_px, reach_px, moved.sum())
    out.ravel()[points] = np.maximum(values, 0.1)
    return out


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("folders", nargs="+", type=Path)
    p.add_argument("--out", type=Path, default=Path("data/noisy"))
    args = p.parse_args()
    for folder in args.folders:
        rng = np.random.default_rng(SEED)
        sparse = read_pfm(folder / "sparse.pfm")
        name, sigma, share, reach = OUTLIERS
        variants = {k: noisy(sparse, s, rng) for k, s in SIGMAS.items()}
        variants[name] = noisy(sparse, sigma, rng, share, reach)
        write_lidar_variants(folder, variants, args.out)


if __name__ == "__main__":
    main()
