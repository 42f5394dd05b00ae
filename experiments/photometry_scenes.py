"""Per scene of a folder of scene folders: the pair's grey-level histogram distance, how far
the photometric match would move the right image (grey levels: its gate) and the engine's
EPE with `match_photometry` off and on, with LiDAR and stereo only (int8, 4
iterations, the engine's defaults otherwise).

    python experiments/photometry_scenes.py data/test16 --runtime onnxruntime
    bash experiments/avx2_kernels.sh python experiments/photometry_scenes.py data/test16 \\
        --runtime openvino --bf16 off
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))

from evaluate import read_scene_folder  # noqa: E402

from edge_depth.metrics import disparity_metrics  # noqa: E402
from edge_depth.runtime.engine import Engine  # noqa: E402
from edge_depth.runtime.options import EngineOptions  # noqa: E402
from edge_depth.runtime.photometry import (  # noqa: E402
    PhotometricMatch,
    grey8,
    histogram_distance,
)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("data", type=Path)
    p.add_argument("--runtime", default="auto")
    p.add_argument("--bf16", default="auto")
    args = p.parse_args()
    kw = dict(precision="int8", runtime=args.runtime, bf16=args.bf16)
    engines = [Engine(None, EngineOptions(match_photometry=on, **kw)) for on in (False, True)]
    rows = []
    for folder in sorted(d for d in args.data.iterdir() if d.is_dir()):
        scene = read_scene_folder(folder)
        distance = histogram_distance(grey8(scene.left), grey8(scene.right))
        change = PhotometricMatch().apply(scene.left, scene.right)[1]
        epe = [disparity_metrics(e.infer(scene.left, scene.right, sparse).disparity,
                                 scene.disp)["epe"]
               for e in engines for sparse in (scene.sparse, np.zeros_like(scene.sparse))]
        rows.append((distance, *epe))
        print(f"{folder.name} distance {distance:.3f} change {change:4.1f}  with LiDAR "
              f"{epe[0]:.3f} -> {epe[2]:.3f} ({epe[2] - epe[0]:+.3f})  stereo only "
              f"{epe[1]:.3f} -> {epe[3]:.3f} ({epe[3] - epe[1]:+.3f})")
    mean = np.mean(rows, axis=0)
    print(f"mean of {len(rows)}: with LiDAR {mean[1]:.4f} -> {mean[3]:.4f} "
          f"({100 * (mean[3] / mean[1] - 1):+.2f} %), stereo only {mean[2]:.4f} -> {mean[4]:.4f} "
          f"({100 * (mean[4] / mean[2] - 1):+.2f} %)")


if __name__ == "__main__":
    main()
