"""The network's graphs exported with dynamic height and width against the static export, at
the bundle's own size (640x400): ms per frame (encoder + 4 steps + upsampling, float graphs,
no matching), median of N frames, on both runtimes.

    python experiments/any_size_speed.py STATIC_BUNDLE DYNAMIC_BUNDLE [--frames 30]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from edge_depth.runtime.backends import cpu_description
from edge_depth.runtime.engine import Engine


def frame_ms(bundle: str, runtime: str, frames: int, size=(640, 400)) -> float:
    engine = Engine(bundle, precision="fp32", runtime=runtime, threads=2, edge_match=0,
                    lidar_select=False, edge_select=False,
                    scale="native" if size != (640, 400) else "fit")
    rng = np.random.default_rng(0)
    w, h = size
    left = rng.integers(0, 255, (h, w), dtype=np.uint8)
    right = np.roll(left, -8, axis=1)
    sparse = np.zeros((h, w), np.float32)
    sparse[::16, ::8] = 8.0
    engine.warm_up(camera=size)
    times = []
    for _ in range(frames):
        t = time.perf_counter()
        engine.infer(left, right, sparse, iters=4)
        times.append((time.perf_counter() - t) * 1000)
    return statistics.median(times)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("static")
    p.add_argument("dynamic")
    p.add_argument("--frames", type=int, default=30)
    args = p.parse_args()
    cpu = cpu_description()
    print(f"# {cpu['model']}, {' '.join(cpu['isa'])}")
    for runtime in ("onnxruntime", "openvino"):
        for name, bundle in (("static", args.static), ("dynamic", args.dynamic)):
            print(f"{runtime:12s} {name:8s} {frame_ms(bundle, runtime, args.frames):7.1f} ms")


if __name__ == "__main__":
    main()
