"""The band refinement's exact nearest LiDAR point against OpenCV's chamfer transform in its
place, on variants of the real pairs (docs/experiments.md, 2026-12-07 22:16).

    python tools/real_pairs.py --rows R --out DIR/aloe_rR; python tools/real_pairs.py
        --motorcycle --rows R --out DIR/moto_rR   (R = 24, 44)
    python experiments/nearest_judge.py DIR/aloe_r24 DIR/aloe_r44 DIR/moto_r24 DIR/moto_r44

Each folder × KINDS is one set (the map from `lidar_align_gate.variant`, the right camera
from `band_judge.photo`, seed SEED); the engine at its defaults (ONNX Runtime) runs each set
twice, with `band_sgm.nearest_within` as shipped and with the chamfer version below.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from band_judge import photo, score  # noqa: E402
from lidar_align_gate import variant  # noqa: E402

from edge_depth.baselines import nearest_point  # noqa: E402
from edge_depth.runtime import band_sgm  # noqa: E402
from edge_depth.runtime.engine import Engine  # noqa: E402
from edge_depth.runtime.options import EngineOptions  # noqa: E402
from edge_depth.sim.folder import read_scene_folder  # noqa: E402

SEED = 12609
PHOTO = (0.9, 12.0, 1.15, 2.5)
KINDS = {  # (σ px, mixed share, mixed reach px, drop share, turn °, dx, dy), photo change
    "noisy": ((0.7, 0.45, 2, 0.0, 0.0, 0, 0), None),
    "moved": ((0.0, 0.0, 0, 0.0, 0.35, 2, -1), None),
    "photo": ((0.0, 0.0, 0, 0.0, 0.0, 0, 0), PHOTO),
    "all": ((0.5, 0.3, 2, 0.35, 0.0, -1, 2), PHOTO),
}


def chamfer_within(points: np.ndarray, reach: np.float32, nearby: np.ndarray) -> None:
    """`nearest_within` as it was: OpenCV's labelled distance transform (5×5 chamfer)."""
    valid = points > 0
    if valid.any():
        near, distance = nearest_point(points, valid)
        nearby[...] = np.where(distance <= reach, near, 0.0)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", nargs="+", type=Path)
    args = p.parse_args()
    engine = Engine(options=EngineOptions(runtime="onnxruntime"))
    exact = band_sgm.nearest_within
    worst_epe, worst_bad3 = -np.inf, -np.inf
    for folder in args.folders:
        scene = read_scene_folder(folder)
        for name, (kind, change) in KINDS.items():
            sparse = variant(scene, kind, SEED)
            right = scene.right if change is None else \
                photo(scene.right, np.random.default_rng(SEED), change)
            row = {"set": f"{folder.name}/{name}"}
            for label, nearest in (("exact", exact), ("chamfer", chamfer_within)):
                band_sgm.nearest_within = nearest
                row[label] = score(engine.infer(scene.left, right, sparse).disparity,
                                   scene.disp)
            band_sgm.nearest_within = exact
            worst_epe = max(worst_epe, row["exact"][0] / row["chamfer"][0] - 1)
            worst_bad3 = max(worst_bad3, row["exact"][1] - row["chamfer"][1])
            print(json.dumps(row), flush=True)
    print(f"exact against chamfer: worst EPE {worst_epe:+.2%}, worst bad-3 "
          f"{worst_bad3:+.3f} points")


if __name__ == "__main__":
    main()
