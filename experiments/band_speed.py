"""The engine's time with the band refinement against the shipped engine and SGBM, in one run.

    python experiments/band_speed.py runs/band/aloe runs/band/moto runs/band/test16/100000[0-3] \
        [--runs 3] [--repeat 3]
    bash experiments/avx2_kernels.sh .venv/bin/python experiments/band_speed.py ...

The engine at its defaults (OpenVINO where installed, int8, 2 threads), the same with
`refine = "band"`, and OpenCV's SGBM (3-way, 64 disparities; its own 2 threads) on the same
640×400 pairs; methods alternate in blocks over every pair, each block after an untimed call.
Per run: the median of each; the summary is the median over runs of each method's time and of
the per-run ratios to SGBM, and the band stage's own median time.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from edge_depth.baselines import make_sgbm, sgbm_disparity
from edge_depth.runtime.engine import Engine
from edge_depth.runtime.options import EngineOptions
from edge_depth.sim.folder import read_scene_folder


def one_run(scenes: list, engines: dict, sgbm, repeat: int) -> dict[str, float]:
    times: dict[str, list[float]] = {name: [] for name in (*engines, "sgbm", "band stage")}
    for _ in range(repeat):
        for name, engine in engines.items():
            engine.infer(*scenes[0])  # untimed: the block's first call
            for left, right, sparse in scenes:
                t = time.perf_counter()
                result = engine.infer(left, right, sparse)
                times[name].append((time.perf_counter() - t) * 1000)
                if "band_refine" in result.timings_ms:
                    times["band stage"].append(result.timings_ms["band_refine"])
        sgbm_disparity(scenes[0][0], scenes[0][1], sgbm)
        for left, right, _ in scenes:
            t = time.perf_counter()
            sgbm_disparity(left, right, sgbm)
            times["sgbm"].append((time.perf_counter() - t) * 1000)
    return {name: float(np.median(v)) for name, v in times.items()}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", nargs="+", type=Path)
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--repeat", type=int, default=3)
    args = p.parse_args()
    cv2.setNumThreads(2)
    scenes = []
    for folder in args.folders:
        s = read_scene_folder(folder)
        scenes.append((s.left, s.right, s.sparse))
    engines = {"shipped": Engine(options=EngineOptions()),
               "band": Engine(options=EngineOptions(refine="band"))}
    print(engines["band"].describe())
    runs = [one_run(scenes, engines, make_sgbm(64), args.repeat) for _ in range(args.runs)]
    for i, run in enumerate(runs):
        print(f"run {i + 1}: " + ", ".join(f"{k} {v:.1f} ms" for k, v in run.items()))
    summary = {k: float(np.median([r[k] for r in runs])) for k in runs[0]}
    ratios = {k: float(np.median([r[k] / r["sgbm"] for r in runs])) for k in engines}
    print("median: " + ", ".join(f"{k} {v:.1f} ms" for k, v in summary.items()))
    print("ratio to SGBM: " + ", ".join(f"{k} {v:.2f}x" for k, v in ratios.items()))


if __name__ == "__main__":
    main()
