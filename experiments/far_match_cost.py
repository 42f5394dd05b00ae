"""What SGBM far from the LiDAR (`[engine] edge_match_far_px`) costs the shipped engine: the
engine with it on and off, alternated frame by frame in one process, on scene folders (the
bench's rig frames and sparser real pairs); median ms of the engine and its matching stage
per folder, and the share of frames where it acted.

    bash experiments/avx2_kernels.sh python experiments/far_match_cost.py data/test16 \\
        data/aloe data/aloe_r8 [--frames 12] [--no-lidar]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from edge_depth.runtime.backends import cpu_description
from edge_depth.runtime.edge_match import FAR_PX
from edge_depth.runtime.engine import Engine
from edge_depth.sim.folder import list_scene_folders, read_scene_folder


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", nargs="+", type=Path)
    p.add_argument("--frames", type=int, default=12, help="frames per folder and setting")
    p.add_argument("--no-lidar", action="store_true", help="the frames without their points")
    args = p.parse_args()
    cpu = cpu_description()
    print(f"# {cpu['model']}, {' '.join(cpu['isa'])}")
    engines = {"on": Engine(edge_match_far_px=FAR_PX), "off": Engine(edge_match_far_px=0.0)}
    for engine in engines.values():
        engine.warm_up()
    print(f"{engines['on'].describe()}; against far off; {args.frames} frames each, alternated")
    print("| data | engine ms, on | off | matching ms, on | off | frames it acted on |")
    print("|---|---|---|---|---|---|")
    for folder in args.folders:
        scenes = [read_scene_folder(f) for f in list_scene_folders(folder)][:4]
        times = {name: {"engine": [], "edge_match": []} for name in engines}
        acted = 0
        for i in range(args.frames):
            s = scenes[i % len(scenes)]
            taken = {}
            for name, engine in engines.items():
                t = time.perf_counter()
                sparse = np.zeros_like(s.sparse) if args.no_lidar else s.sparse
                result = engine.infer(s.left, s.right, sparse)
                times[name]["engine"].append((time.perf_counter() - t) * 1000)
                times[name]["edge_match"].append(result.timings_ms.get("edge_match", 0.0))
                taken[name] = result.disparity
            acted += int((taken["on"] != taken["off"]).any())
        med = {n: {k: statistics.median(v) for k, v in t.items()} for n, t in times.items()}
        print(f"| {folder.name} | {med['on']['engine']:.1f} | {med['off']['engine']:.1f} | "
              f"{med['on']['edge_match']:.1f} | {med['off']['edge_match']:.1f} | "
              f"{acted} of {args.frames} |")


if __name__ == "__main__":
    main()
