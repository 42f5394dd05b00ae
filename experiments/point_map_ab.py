"""The full-resolution matching's LiDAR point map from the 2×2 cells (`cells.cell_nearest_point`,
what the engine runs) against the pixel-exact nearest point (`baselines.lidar_nearest`),
alternated frame by frame in one engine on the same rig frame (640x400, 16 LiDAR rows): median
ms of the engine and of its matching stage, per run.

    python experiments/point_map_ab.py [--frames 40] [--runs 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

from bundle_engine_ab import rig_frame

from edge_depth.baselines import lidar_nearest
from edge_depth.runtime import edge_match
from edge_depth.runtime.cells import cell_nearest_point
from edge_depth.runtime.engine import Engine

MAPS = {"cells": cell_nearest_point,
        "pixels": lambda sparse: lidar_nearest(sparse, sparse > 0)}


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--runs", type=int, default=3)
    args = p.parse_args()
    sample, sparse = rig_frame()
    engine = Engine(threads=2)
    print(f"# {engine.describe()}")
    engine.warm_up()
    for run in range(args.runs):
        times: dict[str, dict[str, list[float]]] = {name: {} for name in MAPS}
        for _ in range(args.frames):
            for name, point_map in MAPS.items():
                edge_match.cell_nearest_point = point_map  # what pair_terms calls
                t = time.perf_counter()
                result = engine.infer(sample.left, sample.right, sparse)
                times[name].setdefault("engine", []).append((time.perf_counter() - t) * 1000)
                times[name].setdefault("edge_match", []).append(
                    result.timings_ms["edge_match"])
        edge_match.cell_nearest_point = cell_nearest_point
        line = ", ".join(f"{name}: engine {statistics.median(t['engine']):.1f}, matching "
                         f"{statistics.median(t['edge_match']):.1f} ms"
                         for name, t in times.items())
        print(f"run {run + 1}: {line}")


if __name__ == "__main__":
    main()
