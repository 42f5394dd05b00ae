"""How much of a frame the matching's gate touches — the network's unsure edges, where the
full-resolution matching's result is used (confidence < 0.9 and the disparity ranging over
more than 1 px in 5×5) — as a share of pixels, of rows and of tiles: what block matching
restricted to the gate's rows or tiles could save. The shipped network without its matching,
on four rig test scenes and the real pairs.

    python experiments/gate_coverage.py
"""

from __future__ import annotations

import numpy as np

from edge_depth.runtime.cells import local_range
from edge_depth.runtime.edge_match import MAX_CONFIDENCE, MIN_RANGE_PX, WINDOW_PX
from edge_depth.runtime.engine import Engine
from edge_depth.sim import RigConfig, make_sample
from edge_depth.sim.folder import read_scene_folder

TILES = ((40, 64), (20, 32))


def main() -> None:
    engine = Engine(threads=2, edge_match=0, edge_median="off")
    frames = []
    for seed in range(4):
        sample = make_sample(1_000_000 + seed, RigConfig(), "beams16")
        sparse, valid = sample.sparse_disparity("left")
        frames.append((f"rig {seed}", sample.left, sample.right,
                       (sparse * valid).astype(np.float32)))
    for name in ("aloe", "motorcycle"):
        scene = read_scene_folder(f"data/{name}")
        frames.append((name, scene.left, scene.right, scene.sparse))
    print("| frame | gate, % of pixels | rows touched | " +
          " | ".join(f"{h}×{w} tiles touched" for h, w in TILES) + " |")
    print("|---|---|---|" + "---|" * len(TILES))
    for name, left, right, sparse in frames:
        result = engine.infer(left, right, sparse)
        assert result.confidence is not None
        gate = (result.confidence < MAX_CONFIDENCE) & \
            (local_range(result.disparity, WINDOW_PX) > MIN_RANGE_PX)
        h, w = gate.shape
        cells = []
        for th, tw in TILES:
            tiles = gate[:h // th * th, :w // tw * tw].reshape(h // th, th, w // tw, tw)
            cells.append(f"{100 * tiles.any((1, 3)).mean():.0f} %")
        print(f"| {name} | {100 * gate.mean():.1f} | {100 * gate.any(1).mean():.0f} % | "
              + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
