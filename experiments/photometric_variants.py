"""Real-pair folders with the two cameras' grey levels made to disagree, six ways each:
the right image × 0.9, × 1.2 (clipped), gamma 0.85, 20 grey levels darker, × 0.85 then gamma
1.1, and the left image × 0.8 instead of the right. The same LiDAR and ground truth.

    python experiments/photometric_variants.py data/aloe data/motorcycle --out data/photo_variants
    python experiments/photometric_variants.py data/aloe data/motorcycle --strong \
        --out data/photo_strong

`--strong`: the right image × 0.75, × 1.3, gamma 1.3, 30 grey levels darker, and the left × 0.75.
`--fresh`: milder, other than the first six: the right × 0.93, × 1.1, gamma 0.9, gamma 1.12,
12 grey levels brighter, and the left × 0.88. `--sensor`: the right camera noisier (+ N(0, 5)
grey levels, seeded) or softer (a Gaussian blur of σ 1 px). A folder of scenes (the rig's
splits) becomes one folder of the same scenes per variant.

    python experiments/photometric_variants.py data/aloe data/motorcycle data/test16 --fresh \
        --out data/photo_fresh
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import cv2
import numpy as np


def _levels(image: np.ndarray, gain: float = 1.0, offset: float = 0.0,
            gamma: float = 1.0) -> np.ndarray:
    """255 · ((gain · x + offset) / 255) ^ gamma, clipped and rounded to uint8."""
    out = np.clip(image.astype(np.float32) * gain + offset, 0, 255) / 255.0
    return np.clip(255.0 * out ** gamma, 0, 255).round().astype(np.uint8)


def _changed(image: np.ndarray, change: dict | str) -> np.ndarray:
    """The image with a variant's change: grey levels (`_levels`' keywords), or "noise" (+ N(0,
    5), seeded) or "blur" (Gaussian, σ 1 px)."""
    if change == "noise":
        noise = np.random.default_rng(3).normal(0.0, 5.0, image.shape)
        return np.clip(image.astype(np.float32) + noise, 0, 255).round().astype(np.uint8)
    if change == "blur":
        return cv2.GaussianBlur(image, (0, 0), 1.0)
    assert isinstance(change, dict)
    return _levels(image, **change)


VARIANTS = {  # name: (the image changed, its change)
    "gain09": ("right", dict(gain=0.9)),
    "gain12": ("right", dict(gain=1.2)),
    "gamma085": ("right", dict(gamma=0.85)),
    "minus20": ("right", dict(offset=-20.0)),
    "gain085g11": ("right", dict(gain=0.85, gamma=1.1)),
    "leftdark": ("left", dict(gain=0.8)),
}
STRONG = {  # `--strong`: further apart
    "gain075": ("right", dict(gain=0.75)),
    "gain13": ("right", dict(gain=1.3)),
    "gamma13": ("right", dict(gamma=1.3)),
    "minus30": ("right", dict(offset=-30.0)),
    "leftdark075": ("left", dict(gain=0.75)),
}
SENSOR = {  # `--sensor`: not a grey-level mapping but the right sensor's noise or its focus
    "noise5": ("right", "noise"),
    "blur1": ("right", "blur"),
}
FRESH = {  # `--fresh`
    "gain093": ("right", dict(gain=0.93)),
    "gain11": ("right", dict(gain=1.1)),
    "gamma09": ("right", dict(gamma=0.9)),
    "gamma112": ("right", dict(gamma=1.12)),
    "plus12": ("right", dict(offset=12.0)),
    "leftdark088": ("left", dict(gain=0.88)),
}


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("folders", nargs="+", type=Path)
    p.add_argument("--out", type=Path, default=Path("data/photo_variants"))
    which = p.add_mutually_exclusive_group()
    which.add_argument("--strong", action="store_true", help="the further-apart set")
    which.add_argument("--fresh", action="store_true", help="the milder second set")
    which.add_argument("--sensor", action="store_true", help="the right sensor noisier, softer")
    args = p.parse_args()
    variants = STRONG if args.strong else FRESH if args.fresh else \
        SENSOR if args.sensor else VARIANTS
    for folder in args.folders:
        for name, (side, change) in variants.items():
            dst = args.out / f"{folder.name}_{name}"
            if dst.exists():
                shutil.rmtree(dst)
            shutil.copytree(folder, dst)
            # a scene folder, or a split's scenes
            scenes = [dst] if (dst / f"{side}.png").exists() else \
                sorted(q.parent for q in dst.glob(f"*/{side}.png"))
            for scene in scenes:
                image = cv2.imread(str(scene / f"{side}.png"), cv2.IMREAD_UNCHANGED)
                cv2.imwrite(str(scene / f"{side}.png"), _changed(image, change))
            print(dst)


if __name__ == "__main__":
    main()
