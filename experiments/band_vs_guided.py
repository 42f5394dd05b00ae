"""Where the band refinement is still off by more than 3 px on the published pairs: how sure
the network was there, how far off, whether full-range guided SGM (its left-right check
passed) is right there, and what taking guided SGM wherever its checked match disagrees with
the band by more than 3 px would give (docs/experiments.md, 2026-12-07 17:44).

    python experiments/band_vs_guided.py runs/band/moto runs/band/aloe

The prior is the engine's with the matching and its median off (`band_refine.py`'s
"selected"), refined by `BandSgmConfig()`; guided SGM is `edge.guided_sgm` at its constants.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from edge_depth.guided_sgm import guided_sgm, guided_sgm_lidar
from edge_depth.runtime.band_sgm import BandSgmConfig, refine
from edge_depth.runtime.engine import Engine
from edge_depth.runtime.options import EngineOptions
from edge_depth.sim.folder import read_scene_folder


def share(mask: np.ndarray, of: np.ndarray) -> float:
    return 100.0 * np.count_nonzero(mask) / max(np.count_nonzero(of), 1)


def main() -> None:
    bare = Engine(options=EngineOptions(runtime="onnxruntime", edge_match=0,
                                        edge_median="off"))
    for folder in sys.argv[1:]:
        s = read_scene_folder(Path(folder))
        prior = bare.infer(s.left, s.right, s.sparse)
        band, _ = refine(s.left, s.right, prior.disparity, prior.confidence, s.sparse,
                         BandSgmConfig())
        checked = guided_sgm(s.left, s.right, s.sparse)  # 0 where the check rejects
        filled = guided_sgm_lidar(s.left, s.right, s.sparse)
        gt = s.disp
        known = np.isfinite(gt) & (gt > 0)
        err_band, err_checked = np.abs(band - gt), np.abs(checked - gt)
        bad = known & (err_band > 3)
        there = bad & (checked > 0)
        print(f"{folder}: band bad-3 {share(bad, known):.2f} %, guided SGM + LiDAR "
              f"{share(known & (np.abs(filled - gt) > 3), known):.2f} %")
        print(f"  at the band's bad pixels: guided SGM checked at {share(there, bad):.0f} %, "
              f"right at {share(there & (err_checked <= 3), there):.0f} % of those; the "
              f"network's confidence median {np.median(prior.confidence[bad]):.2f}, its "
              f"error median {np.median(np.abs(prior.disparity - gt)[bad]):.1f} px")
        both = np.where((checked > 0) & (np.abs(checked - band) > 3), checked, band)
        err = np.abs(both - gt)
        print(f"  guided SGM where its checked match disagrees by > 3 px: EPE "
              f"{err[known].mean():.3f} / bad-3 {share(known & (err > 3), known):.2f} % "
              f"(band {err_band[known].mean():.3f} / {share(bad, known):.2f})")


if __name__ == "__main__":
    main()
