"""The full-resolution matching's LiDAR point map three ways, alternated frame by frame in one
engine on the same rig frame (640x400, 16 LiDAR rows): the pixel-exact nearest point
(`baselines.lidar_nearest`), the 2×2 cells' (`cells.CellPoints`) made again by the matching,
and the cells' the LiDAR selection made (what the engine runs). Median ms of the engine, its
selection and its matching stage, per run.

    python experiments/point_map_ab.py [--frames 40] [--runs 3]

Runs on commit 0795b0f, which had the cells' point map (reverted: it moved Motorcycle's bad-3
over its bar on this host's own kernels and on ONNX Runtime; docs/experiments.md).
"""

from __future__ import annotations

import argparse
import statistics

from bundle_engine_ab import rig_frame

from edge_depth.baselines import lidar_nearest
from edge_depth.runtime.cells import CellPoints
from edge_depth.runtime.edge_match import EdgeMatch
from edge_depth.runtime.engine import Engine

SHIPPED = EdgeMatch.pair_terms


class PixelPoints(CellPoints):
    """Stands in for the cells: the pixel-exact nearest point's map."""

    def __init__(self, sparse) -> None:
        self.sparse = sparse

    def pixel_map(self, shape):
        return lidar_nearest(self.sparse, self.sparse > 0)


VARIANTS = {
    "pixels": lambda self, left, right, sparse=None, cell_points=None: SHIPPED(
        self, left, right, sparse, None if sparse is None else PixelPoints(sparse)),
    "cells made again": lambda self, left, right, sparse=None, cell_points=None: SHIPPED(
        self, left, right, sparse, None),
    "cells shared": SHIPPED,
}


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--runs", type=int, default=3)
    args = p.parse_args()
    sample, sparse = rig_frame()
    engine = Engine(threads=2)
    print(f"# {engine.describe()}")
    engine.warm_up()
    stages = ("engine", "select", "edge_match")
    for run in range(args.runs):
        times: dict[str, dict[str, list[float]]] = {name: {} for name in VARIANTS}
        for _ in range(args.frames):
            for name, pair_terms in VARIANTS.items():
                EdgeMatch.pair_terms = pair_terms  # type: ignore[method-assign]
                result = engine.infer(sample.left, sample.right, sparse)
                for stage in stages:
                    times[name].setdefault(stage, []).append(result.timings_ms[stage])
        EdgeMatch.pair_terms = SHIPPED  # type: ignore[method-assign]
        line = "; ".join(f"{name}: " + ", ".join(
            f"{stage} {statistics.median(t[stage]):.1f}" for stage in stages)
            for name, t in times.items())
        print(f"run {run + 1} (ms): {line}")


if __name__ == "__main__":
    main()
