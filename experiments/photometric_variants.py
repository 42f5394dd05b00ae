"""Real-pair folders with the two cameras' grey levels made to disagree, six ways each:
the right image × 0.9, × 1.2 (clipped), gamma 0.85, 20 grey levels darker, × 0.85 then gamma
1.1, and the left image × 0.8 instead of the right. The same LiDAR and ground truth.

    python experiments/photometric_variants.py data/aloe data/motorcycle --out data/photo_variants
    python experiments/photometric_variants.py data/aloe data/motorcycle --strong \
        --out data/photo_strong

`--strong`: the right image × 0.75, × 1.3, gamma 1.3, 30 grey levels darker, and the left × 0.75.
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


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("folders", nargs="+", type=Path)
    p.add_argument("--out", type=Path, default=Path("data/photo_variants"))
    p.add_argument("--strong", action="store_true", help="the further-apart set")
    args = p.parse_args()
    for folder in args.folders:
        for name, (side, change) in (STRONG if args.strong else VARIANTS).items():
            dst = args.out / f"{folder.name}_{name}"
            if dst.exists():
                shutil.rmtree(dst)
            shutil.copytree(folder, dst)
            image = cv2.imread(str(folder / f"{side}.png"), cv2.IMREAD_UNCHANGED)
            cv2.imwrite(str(dst / f"{side}.png"), _levels(image, **change))
            print(dst)


if __name__ == "__main__":
    main()
