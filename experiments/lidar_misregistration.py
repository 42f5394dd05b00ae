"""Real-pair folders with the LiDAR map misregistered ten ways: moved (−2, 0), (0, 2), (3, −1),
(−1, −2) and (1, 0) px (x right, y down); turned about the image centre by 0.5°, −0.5° and
0.75°; turned 0.5° and moved (1, −1); turned −1° and moved (−2, 0). The same images and
ground truth; the points keep their disparities, only their pixels move.

    python experiments/lidar_misregistration.py data/aloe data/motorcycle --out data/misregistered
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))

from evaluate import read_scene_folder  # noqa: E402
from scene_variants import write_lidar_variants  # noqa: E402

MOVES = {"left2": (-2, 0), "down2": (0, 2), "r3u1": (3, -1), "l1u2": (-1, -2), "right1": (1, 0)}
# turned about the image centre (degrees), then moved
TURNS = {"turn05": (0.5, 0, 0), "turnm05": (-0.5, 0, 0), "turn075": (0.75, 0, 0),
         "turn05r1u1": (0.5, 1, -1), "turnm1l2": (-1.0, -2, 0)}


def moved(sparse: np.ndarray, dx: float, dy: float, turn_deg: float = 0.0) -> np.ndarray:
    """The map with every point turned by `turn_deg` about the image centre, then moved by
    (dx, dy) px, rounded to the nearest pixel; points that leave the image are dropped, the
    nearer wins where two land on one pixel."""
    h, w = sparse.shape
    ys, xs = np.nonzero(sparse > 0)
    d = sparse[ys, xs]
    a = np.deg2rad(turn_deg)
    cx, cy = (w - 1) / 2, (h - 1) / 2
    x = cx + np.cos(a) * (xs - cx) - np.sin(a) * (ys - cy) + dx
    y = cy + np.sin(a) * (xs - cx) + np.cos(a) * (ys - cy) + dy
    u, v = np.rint(x).astype(int), np.rint(y).astype(int)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    out = np.zeros_like(sparse)
    np.maximum.at(out, (v[inside], u[inside]), d[inside])
    return out


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("folders", nargs="+", type=Path)
    p.add_argument("--out", type=Path, default=Path("data/misregistered"))
    args = p.parse_args()
    for folder in args.folders:
        sparse = read_scene_folder(folder).sparse
        variants = {name: moved(sparse, dx, dy) for name, (dx, dy) in MOVES.items()}
        variants.update({name: moved(sparse, dx, dy, turn)
                         for name, (turn, dx, dy) in TURNS.items()})
        write_lidar_variants(folder, variants, args.out)


if __name__ == "__main__":
    main()
