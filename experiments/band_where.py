"""Where the shipped engine's bad-3 pixels lie on the published pairs, and whether census SGM
(full range, `edge.guided_sgm`) is right there: by the network's confidence (refined by the
band or kept), by what the band did (its match, its fallback, the estimate kept) and by
whether the right camera sees the pixel (the ground truth's own left-right consistency).

    python experiments/band_where.py data/aloe data/motorcycle [--no-lidar]

Shares are % of the GT-valid pixels, as bad-3 counts them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from edge_depth.guided_sgm import GuidedSgmConfig, guided_sgm_filled, guided_sgm_lidar
from edge_depth.runtime.engine import Engine
from edge_depth.runtime.options import EngineOptions
from edge_depth.sim.folder import read_scene_folder


def seen_by_right(gt: np.ndarray) -> np.ndarray:
    """Pixels whose match in the right image is not hidden by a nearer surface: no pixel to
    their right lands on the same right column with a larger disparity."""
    h, w = gt.shape
    with np.errstate(invalid="ignore"):
        known = np.isfinite(gt) & (gt > 0)
    xs = np.arange(w)[None, :] - np.where(known, gt, 0.0)
    seen = np.ones((h, w), bool)
    nearest = np.full(h, np.inf)  # the smallest right column reached from the right so far
    for x in range(w - 1, -1, -1):
        seen[:, x] = xs[:, x] < nearest + 0.5
        nearest = np.minimum(nearest, xs[:, x])
    return seen


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", nargs="+", type=Path)
    p.add_argument("--no-lidar", action="store_true")
    args = p.parse_args()
    base = dict(runtime="onnxruntime", precision="int8")
    engine = Engine(options=EngineOptions(**base))
    bare = Engine(options=EngineOptions(**base, refine="off", edge_median="off"))
    for folder in args.folders:
        s = read_scene_folder(folder)
        sparse = np.zeros_like(s.sparse) if args.no_lidar else s.sparse
        gt = s.disp
        ok = np.isfinite(gt) & (gt > 0)
        n = ok.sum()
        count = max(64, int(np.ceil(np.max(gt[ok]) / 16) * 16))
        config = GuidedSgmConfig(num_disparities=count)
        out = engine.infer(s.left, s.right, sparse)
        prior = bare.infer(s.left, s.right, sparse)
        sgm = (guided_sgm_filled(s.left, s.right, config) if args.no_lidar
               else guided_sgm_lidar(s.left, s.right, sparse, config))
        bad = ok & ~(np.abs(out.disparity - gt) <= 3)
        bad_prior = ok & ~(np.abs(prior.disparity - gt) <= 3)
        bad_sgm = ok & ~(np.abs(sgm - gt) <= 3)
        sure = prior.confidence >= 0.9
        seen = seen_by_right(gt)
        moved = np.abs(out.disparity - prior.disparity) > 1e-3
        pct = lambda m: 100.0 * np.count_nonzero(m & ok) / n  # noqa: E731
        print(f"{folder}{' stereo only' if args.no_lidar else ''}: bad-3 engine "
              f"{pct(bad):.2f}, before the band {pct(bad_prior):.2f}, SGM {pct(bad_sgm):.2f}")
        for name, m in (("sure (kept)", sure), ("unsure", ~sure)):
            for vis, v in (("seen", seen), ("hidden", ~seen)):
                cell = m & v
                print(f"  {name:12s} {vis:6s} pixels {pct(cell):5.1f}  engine bad "
                      f"{pct(bad & cell):5.2f}  before {pct(bad_prior & cell):5.2f}  SGM bad "
                      f"{pct(bad_sgm & cell):5.2f}  SGM right where engine bad "
                      f"{pct(bad & ~bad_sgm & cell):5.2f}  band moved {pct(moved & cell):5.1f}"
                      f"  made worse {pct(bad & ~bad_prior & cell):4.2f}")


if __name__ == "__main__":
    main()
