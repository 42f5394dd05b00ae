"""Where the shipped engine's bad-3 pixels lie on a scene folder: at the image's left border
(no match in the right image, x < d), in pixels the right camera cannot see for a nearer
surface (`band_where.seen_by_right`), or elsewhere (docs/experiments.md, 2026-12-08 01:08).

    python experiments/bad3_split.py data/aloe data/motorcycle [--no-lidar]

Shares are % of the GT-valid pixels, as bad-3 counts them.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from band_where import seen_by_right  # noqa: E402

from edge_depth.runtime.engine import Engine  # noqa: E402
from edge_depth.runtime.options import EngineOptions  # noqa: E402
from edge_depth.sim.folder import read_scene_folder  # noqa: E402


def pct(mask: np.ndarray, valid: np.ndarray) -> str:
    return f"{100 * np.count_nonzero(mask) / np.count_nonzero(valid):.2f}"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", nargs="+", type=Path)
    p.add_argument("--no-lidar", action="store_true")
    args = p.parse_args()
    engine = Engine(options=EngineOptions(runtime="onnxruntime", precision="int8"))
    for folder in args.folders:
        s = read_scene_folder(folder)
        sparse = np.zeros_like(s.sparse) if args.no_lidar else s.sparse
        out = engine.infer(s.left, s.right, sparse).disparity
        gt = s.disp
        ok = np.isfinite(gt) & (gt > 0)
        bad = ok & ~(np.abs(out - gt) <= 3)
        border = ok & (np.arange(gt.shape[1])[None, :] - np.where(ok, gt, 0.0) < 0)
        hidden = ok & ~seen_by_right(gt) & ~border
        print(f"{folder}{', stereo only' if args.no_lidar else ''}: bad-3 {pct(bad, ok)}; at "
              f"the left border {pct(bad & border, ok)} (of {pct(border, ok)}), occluded "
              f"{pct(bad & hidden, ok)} (of {pct(hidden, ok)}), elsewhere "
              f"{pct(bad & ~border & ~hidden, ok)}")


if __name__ == "__main__":
    main()
