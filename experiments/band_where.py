"""Where the shipped engine's bad-3 pixels lie on the published pairs, and whether census SGM
(full range, `edge.guided_sgm`) is right there: by the network's confidence (refined by the
band or kept), by whether the right camera sees the pixel (the ground truth's own
visibility), and, where SGM is right, by what the band's own winner did (docs/experiments.md,
2026-12-07 22:36).

    python experiments/band_where.py data/aloe data/motorcycle [--no-lidar]

Shares are % of the GT-valid pixels, as bad-3 counts them. The winners' split runs the
engine without the median after the band (its winners are the band's last word there).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from edge_depth.guided_sgm import GuidedSgmConfig, guided_sgm_filled, guided_sgm_lidar
from edge_depth.runtime import band_sgm
from edge_depth.runtime.engine import Engine
from edge_depth.runtime.options import EngineOptions
from edge_depth.sim.folder import read_scene_folder


def seen_by_right(gt: np.ndarray) -> np.ndarray:
    """Pixels whose match in the right image no nearer surface hides: no GT-valid pixel to
    their right lands on their right column or left of it."""
    h, w = gt.shape
    with np.errstate(invalid="ignore"):
        known = np.isfinite(gt) & (gt > 0)
    xs = np.arange(w)[None, :] - np.where(known, gt, 0.0)
    seen = np.ones((h, w), bool)
    nearest = np.full(h, np.inf)  # the leftmost right column reached from the right so far
    for x in range(w - 1, -1, -1):
        seen[:, x] = xs[:, x] < nearest + 0.5
        nearest = np.minimum(nearest, xs[:, x])
    return seen


class Kept:
    """The band's bands and both views' winners of its last call, kept by wrapping
    `band_sgm._bands` and `band_sgm._checked_choice` (restored by `close`)."""

    def __init__(self) -> None:
        self.bands, self.choice = band_sgm._bands, band_sgm._checked_choice
        self.lo = self.count = self.left = np.zeros(0)

        def bands(*args):
            lo, count, start, nearby = self.bands(*args)
            self.lo, self.count = lo.copy(), count.copy()
            return lo, count, start, nearby

        def choice(left, *args):
            self.left = left.copy()
            return self.choice(left, *args)

        band_sgm._bands, band_sgm._checked_choice = bands, choice

    def close(self) -> None:
        band_sgm._bands, band_sgm._checked_choice = self.bands, self.choice


def share(mask: np.ndarray, ok: np.ndarray) -> float:
    return 100.0 * np.count_nonzero(mask & ok) / np.count_nonzero(ok)


def by_confidence(s, out, prior, sgm: np.ndarray) -> None:
    """The engine's, the network's and SGM's bad-3 by confidence and visibility."""
    gt = s.disp
    ok = np.isfinite(gt) & (gt > 0)
    bad = ok & ~(np.abs(out.disparity - gt) <= 3)
    bad_prior = ok & ~(np.abs(prior.disparity - gt) <= 3)
    bad_sgm = ok & ~(np.abs(sgm - gt) <= 3)
    sure, seen = prior.confidence >= 0.9, seen_by_right(gt)
    print(f"  bad-3: engine {share(bad, ok):.2f}, before the band {share(bad_prior, ok):.2f}, "
          f"SGM {share(bad_sgm, ok):.2f}")
    for name, m in (("sure (kept)", sure), ("unsure", ~sure)):
        for vis, v in (("seen", seen), ("hidden", ~seen)):
            cell = m & v
            print(f"  {name:12s} {vis:6s} pixels {share(cell, ok):5.1f}  engine bad "
                  f"{share(bad & cell, ok):5.2f}  before {share(bad_prior & cell, ok):5.2f}  "
                  f"SGM bad {share(bad_sgm & cell, ok):5.2f}  SGM right where the engine is "
                  f"not {share(bad & ~bad_sgm & cell, ok):5.2f}")


def by_winner(s, sparse: np.ndarray, sgm: np.ndarray, engine: Engine, kept: Kept) -> None:
    """Where the band (no median after it) is wrong, SGM right and the right camera sees:
    what the band's own winner was."""
    gt = s.disp
    ok = np.isfinite(gt) & (gt > 0)
    g = np.where(ok, gt, 0.0)
    out = engine.infer(s.left, s.right, sparse).disparity
    cell = ok & ~(np.abs(out - gt) <= 3) & (np.abs(sgm - gt) <= 3) & seen_by_right(gt)
    refined = kept.count > 0
    outside = refined & ((g < kept.lo) | (g > kept.lo + kept.count - 1))
    inside = refined & ~outside
    near = np.abs(kept.left - g) <= 3
    print(f"  band wrong, SGM right, seen {share(cell, ok):.2f}: not refined "
          f"{share(cell & ~refined, ok):.2f}, the truth outside the band "
          f"{share(cell & outside, ok):.2f}, its winner rejected "
          f"{share(cell & inside & (kept.left < 0), ok):.2f}, wrong "
          f"{share(cell & inside & (kept.left >= 0) & ~near, ok):.2f}, right but not kept "
          f"{share(cell & inside & (kept.left >= 0) & near, ok):.2f}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", nargs="+", type=Path)
    p.add_argument("--no-lidar", action="store_true")
    args = p.parse_args()
    base = dict(runtime="onnxruntime", precision="int8")
    engine = Engine(options=EngineOptions(**base))
    bare = Engine(options=EngineOptions(**base, refine="off", edge_median="off"))
    unmedianed = Engine(options=EngineOptions(**base, edge_median="off"))
    kept = Kept()
    try:
        for folder in args.folders:
            s = read_scene_folder(folder)
            sparse = np.zeros_like(s.sparse) if args.no_lidar else s.sparse
            ok = np.isfinite(s.disp) & (s.disp > 0)
            config = GuidedSgmConfig(num_disparities=max(
                64, int(np.ceil(np.max(s.disp[ok]) / 16) * 16)))
            sgm = (guided_sgm_filled(s.left, s.right, config) if args.no_lidar
                   else guided_sgm_lidar(s.left, s.right, sparse, config))
            print(f"{folder}{', stereo only' if args.no_lidar else ''}:")
            by_confidence(s, engine.infer(s.left, s.right, sparse),
                          bare.infer(s.left, s.right, sparse), sgm)
            by_winner(s, sparse, sgm, unmedianed, kept)
    finally:
        kept.close()


if __name__ == "__main__":
    main()
