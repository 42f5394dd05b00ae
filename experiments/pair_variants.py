"""Variants of the real pairs' scene folders for robustness checks: the LiDAR noisier, thinner
or misregistered, the right camera darker and with less contrast. Each variant is a scene
folder beside the others under OUT (`tools/evaluate.py OUT/aloe_noise ...`).

    python experiments/pair_variants.py data/aloe data/motorcycle --out data/variants

- noise: every point's disparity + N(0, 0.5 px)
- half: a random half of the points dropped
- shift: the LiDAR map 2 px right and 1 px down (a misregistration)
- photo: the right image × 0.8 + 12 grey levels, then gamma 1.15
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import cv2
import numpy as np

from edge_depth.sim.folder import read_pfm, write_pfm

SEED = 7


def noise(sparse: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    out = sparse.copy()
    points = out > 0
    out[points] = np.maximum(out[points] + rng.normal(0.0, 0.5, points.sum()), 0.1)
    return out


def half(sparse: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    return np.where(rng.random(sparse.shape) < 0.5, 0.0, sparse).astype(np.float32)


def shift(sparse: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    out = np.zeros_like(sparse)
    out[1:, 2:] = sparse[:-1, :-2]
    return out


def photo(right: np.ndarray) -> np.ndarray:
    darker = np.clip(right.astype(np.float32) * 0.8 + 12.0, 0, 255) / 255.0
    return np.clip(255.0 * darker ** 1.15, 0, 255).round().astype(np.uint8)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("folders", nargs="+", type=Path)
    p.add_argument("--out", type=Path, default=Path("data/variants"))
    args = p.parse_args()
    for folder in args.folders:
        rng = np.random.default_rng(SEED)
        sparse = read_pfm(folder / "sparse.pfm")
        for name in ("noise", "half", "shift", "photo"):
            dst = args.out / f"{folder.name}_{name}"
            if dst.exists():
                shutil.rmtree(dst)
            shutil.copytree(folder, dst)
            if name == "photo":
                right = cv2.imread(str(folder / "right.png"), cv2.IMREAD_UNCHANGED)
                cv2.imwrite(str(dst / "right.png"), photo(right))
            else:
                changed = {"noise": noise, "half": half, "shift": shift}[name](sparse, rng)
                write_pfm(dst / "sparse.pfm", changed.astype(np.float32))
            print(dst)


if __name__ == "__main__":
    main()
