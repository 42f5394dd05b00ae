"""Time a bundle's two selections on the same frames, alternately: the LiDAR selection on the
network's outputs with each scene's LiDAR, the edge selection on its outputs with the LiDAR
zeroed (the frames each runs on in the engine); with `--against OTHER_BUNDLE`, that bundle's
LiDAR selection too, in the same rounds on the same network outputs (two fits of the stage
compared).

    python experiments/selection_cost.py DATA_DIR [--bundle DIR] [--against DIR] [--frames 12]
        [--rounds 8] [--runtime onnxruntime] [--json OUT]

Prints the median and p90 ms per call of each (the network runs once per frame, untimed).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from edge_depth.runtime.engine import DEFAULT_BUNDLE, Engine
from edge_depth.sim.folder import list_scene_folders, read_scene_folder


def measure(bundle: Path, data: Path, frames: int, rounds: int, runtime: str,
            against: Path | None = None) -> dict:
    """{'lidar_select' | 'edge_select' [| 'lidar_select_against']: {median_ms, p90_ms,
    calls}}."""
    engine = Engine(bundle, precision="int8", threads=2, runtime=runtime, lidar_select=False,
                    edge_select=False, edge_match=0)
    stages = Engine(bundle, precision="int8", threads=2, runtime=runtime, edge_match=0)
    if stages.select is None or stages.edge_select is None:
        raise SystemExit(f"{bundle}: needs both selections in model.json (tools/fit_select.py, "
                         "tools/fit_edge_select.py)")
    other = None if against is None else Engine(against, precision="int8", threads=2,
                                                runtime=runtime).select
    if against is not None and other is None:
        raise SystemExit(f"{against}: has no LiDAR selection to compare")
    cases = []
    for folder in list_scene_folders(data)[:frames]:
        scene = read_scene_folder(folder)
        if scene.sparse is None:
            raise SystemExit(f"{folder}: needs sparse.pfm")
        sparse = np.where(scene.sparse > 0, scene.sparse, 0).astype(np.float32)
        left, right = (np.asarray(scene.left, np.float32), np.asarray(scene.right, np.float32))
        with_lidar = engine.infer(scene.left, scene.right, sparse)
        stereo = engine.infer(scene.left, scene.right, np.zeros_like(sparse))
        cases.append((left, right, sparse, with_lidar, stereo))
    if not cases:
        raise SystemExit(f"{data}: no scene folders")
    times: dict[str, list[float]] = {"lidar_select": [], "edge_select": []}
    if other is not None:
        times["lidar_select_against"] = []
    for _ in range(rounds):
        for left, right, sparse, with_lidar, stereo in cases:
            t = time.perf_counter()
            stages.select.apply(left, right, with_lidar.disparity, with_lidar.confidence, sparse)
            times["lidar_select"].append((time.perf_counter() - t) * 1000)
            t = time.perf_counter()
            stages.edge_select.apply(left, right, stereo.disparity, stereo.confidence)
            times["edge_select"].append((time.perf_counter() - t) * 1000)
            if other is not None:
                t = time.perf_counter()
                other.apply(left, right, with_lidar.disparity, with_lidar.confidence, sparse)
                times["lidar_select_against"].append((time.perf_counter() - t) * 1000)
    return {k: dict(median_ms=float(np.median(v)), p90_ms=float(np.percentile(v, 90)),
                    calls=len(v)) for k, v in times.items()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("data", type=Path)
    p.add_argument("--bundle", type=Path, default=DEFAULT_BUNDLE)
    p.add_argument("--against", type=Path,
                   help="also time this bundle's LiDAR selection (same network outputs)")
    p.add_argument("--frames", type=int, default=12)
    p.add_argument("--rounds", type=int, default=8)
    p.add_argument("--runtime", default="onnxruntime")
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    result = measure(args.bundle, args.data, args.frames, args.rounds, args.runtime,
                     args.against)
    for name, r in result.items():
        print(f"{name}: median {r['median_ms']:.2f} ms, p90 {r['p90_ms']:.2f} ms "
              f"({r['calls']} calls)")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
