"""Scene folders with a noisier LiDAR: every point's disparity + N(0, σ) for σ 0.4, 0.75,
1.0 and 1.5 px, and + N(0, 0.5) with 2 % of the points moved by up to ±10 px. The same images
and ground truth. A folder of scenes (the rig's splits) becomes one folder of the same scenes
per σ.

    python experiments/lidar_noise.py data/aloe data/motorcycle --out data/noisy
    python experiments/lidar_noise.py data/test16 --sigma n050=0.5 --sigma n100=1.0 \
        --seed 29 --no-outliers --out data/noisy_fresh
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scene_variants import write_lidar_variants

from edge_depth.sim.folder import read_pfm, write_pfm

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


def write_split_variants(split: Path, sigmas: dict[str, float], rng: np.random.Generator,
                         out: Path) -> None:
    """OUT/<split>_<key>/<scene>: every scene of a split with its map made noisy."""
    import shutil

    for key, sigma in sigmas.items():
        dst = out / f"{split.name}_{key}"
        if dst.exists():
            shutil.rmtree(dst)
        shutil.copytree(split, dst)
        for scene in sorted(p.parent for p in dst.glob("*/sparse.pfm")):
            write_pfm(scene / "sparse.pfm",
                      noisy(read_pfm(scene / "sparse.pfm"), sigma, rng).astype(np.float32))
        print(dst)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("folders", nargs="+", type=Path)
    p.add_argument("--out", type=Path, default=Path("data/noisy"))
    p.add_argument("--seed", type=int, default=SEED)
    p.add_argument("--sigma", action="append", default=None, metavar="NAME=PX",
                   help="a variant's name and σ (repeatable; default the four above)")
    p.add_argument("--no-outliers", action="store_true", help="without the outlier variant")
    args = p.parse_args()
    sigmas = SIGMAS if args.sigma is None else \
        {k: float(v) for k, v in (s.split("=", 1) for s in args.sigma)}
    for folder in args.folders:
        rng = np.random.default_rng(args.seed)
        if not (folder / "sparse.pfm").exists():  # a split: a folder of scenes
            write_split_variants(folder, sigmas, rng, args.out)
            continue
        sparse = read_pfm(folder / "sparse.pfm")
        variants = {k: noisy(sparse, s, rng) for k, s in sigmas.items()}
        if not args.no_outliers:
            name, sigma, share, reach = OUTLIERS
            variants[name] = noisy(sparse, sigma, rng, share, reach)
        write_lidar_variants(folder, variants, args.out)


if __name__ == "__main__":
    main()
