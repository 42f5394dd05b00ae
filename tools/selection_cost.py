"""Time a bundle's two selections on the same frames, alternately: the LiDAR selection on the
network's outputs with each scene's LiDAR, the edge selection on its outputs with the LiDAR
zeroed (the frames each runs on in the engine).

    python tools/selection_cost.py DATA_DIR [--bundle DIR] [--frames 12] [--rounds 8]
        [--runtime onnxruntime] [--json OUT]

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


def measure(bundle: Path, data: Path, frames: int, rounds: int, runtime: str) -> dict:
    """{'lidar_select' | 'edge_select': {median_ms, p90_ms, calls}}."""
    engine = Engine(bundle, precision="int8", threads=2, runtime=runtime, lidar_select=False,
                    edge_select=False)
    stages = Engine(bundle, precision="int8", threads=2, runtime=runtime)
    if stages.select is None or stages.edge_select is None:
        raise SystemExit(f"{bundle}: needs both selections in model.json (tools/fit_select.py, "
                         "tools/fit_edge_select.py)")
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
    for _ in range(rounds):
        for left, right, sparse, with_lidar, stereo in cases:
            t = time.perf_counter()
            stages.select.apply(left, right, with_lidar.disparity, with_lidar.confidence, sparse)
            times["lidar_select"].append((time.perf_counter() - t) * 1000)
            t = time.perf_counter()
            stages.edge_select.apply(left, right, stereo.disparity, stereo.confidence)
            times["edge_select"].append((time.perf_counter() - t) * 1000)
    return {k: dict(median_ms=float(np.median(v)), p90_ms=float(np.percentile(v, 90)),
                    calls=len(v)) for k, v in times.items()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("data", type=Path)
    p.add_argument("--bundle", type=Path, default=DEFAULT_BUNDLE)
    p.add_argument("--frames", type=int, default=12)
    p.add_argument("--rounds", type=int, default=8)
    p.add_argument("--runtime", default="onnxruntime")
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    result = measure(args.bundle, args.data, args.frames, args.rounds, args.runtime)
    for name, r in result.items():
        print(f"{name}: median {r['median_ms']:.2f} ms, p90 {r['p90_ms']:.2f} ms "
              f"({r['calls']} calls)")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
