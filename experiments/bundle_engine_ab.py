"""Bundles' engines at their defaults (or each at several precisions), alternated frame by frame
in one process on the same rig frame (640x400, 16 LiDAR rows): median ms per frame and stage.

    python experiments/bundle_engine_ab.py BUNDLE [BUNDLE ...] [--frames 40]
        [--precisions int8,fp32] [--bf16 auto|on|off] [--int8-encoder auto,off]
        [--edge-match-rows bundle,1] [--iters 4,3]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from edge_depth.runtime.backends import cpu_description
from edge_depth.runtime.engine import Engine
from edge_depth.sim import RigConfig, make_sample


def rig_frame():
    """The frame the A/B scripts time (the test split's first scene, 16 LiDAR rows): (sample,
    its sparse disparity, 0 = no point); says the CPU first."""
    cpu = cpu_description()
    print(f"# {cpu['model']}, {' '.join(cpu['isa'])}")
    sample = make_sample(1_000_000, RigConfig(), "beams16")
    sparse, valid = sample.sparse_disparity("left")
    return sample, (sparse * valid).astype(np.float32)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("bundles", nargs="+")
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--precisions", default="auto")
    p.add_argument("--bf16", default="auto", choices=("auto", "on", "off"))
    p.add_argument("--int8-encoder", default="auto", help="one or more of auto, on, off")
    p.add_argument("--edge-match-rows", default="bundle", help="one or more of bundle, 1, 2")
    p.add_argument("--iters", default="0", help="one or more counts (0: the bundle's)")
    args = p.parse_args()
    sample, sparse = rig_frame()
    engines = {f"{b} {p} int8_encoder={e} rows={r} iters={n}": Engine(
        b, threads=2, precision=p, bf16=args.bf16, int8_encoder=e,
        edge_match_rows=r if r == "bundle" else int(r), iters=int(n))
        for b in args.bundles for p in args.precisions.split(",")
        for e in args.int8_encoder.split(",") for r in args.edge_match_rows.split(",")
        for n in args.iters.split(",")}
    for engine in engines.values():
        engine.warm_up()
    stages: dict[str, dict[str, list[float]]] = {b: {} for b in engines}
    for _ in range(args.frames):
        for b, engine in engines.items():
            t = time.perf_counter()
            result = engine.infer(sample.left, sample.right, sparse,
                                  iters=engine.options.iters or None)
            stages[b].setdefault("frame", []).append((time.perf_counter() - t) * 1000)
            for k, v in result.timings_ms.items():
                stages[b].setdefault(k, []).append(v)
    for b in engines:
        medians = {k: round(statistics.median(v), 1) for k, v in stages[b].items()}
        print(f"{b} ({engines[b].describe()}): {medians}")


if __name__ == "__main__":
    main()
