"""The shipped engine with its block matching started right after the graphs (beside the
LiDAR selection and the choice's preparation) against started after the selection (as
before), alternated frame by frame on rig frames (640x400, 16 LiDAR rows): median ms of the
engine and its after-graph stages, and whether the outputs are the same.

    python experiments/match_start_ab.py [--frames 40] [--scenes 4]

It needs `FrameMatch.after_graphs`, which only commit 0d41c7c has (measured, not kept:
docs/experiments.md, "StereoBM from the end of the graphs").
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from edge_depth.runtime.backends import cpu_description
from edge_depth.runtime.engine import Engine
from edge_depth.runtime.match_schedule import FrameMatch
from edge_depth.sim import RigConfig, make_sample

STAGES = ("engine", "select", "edge_match", "edge_median")


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--scenes", type=int, default=4)
    args = p.parse_args()
    cpu = cpu_description()
    print(f"# {cpu['model']}, {' '.join(cpu['isa'])}")
    inputs = []
    for seed in range(args.scenes):
        sample = make_sample(1_000_000 + seed, RigConfig(), "beams16")
        sparse, valid = sample.sparse_disparity("left")
        inputs.append((sample.left, sample.right, (sparse * valid).astype(np.float32)))
    engine = Engine(threads=2)
    engine.warm_up()
    after_graphs = FrameMatch.after_graphs
    times: dict[str, dict[str, list[float]]] = {"after the graphs": {}, "after the selection": {}}
    same = True
    for i in range(args.frames):
        outputs = []
        for name in times:
            FrameMatch.after_graphs = after_graphs if name == "after the graphs" else \
                (lambda self, disparity: None)
            t = time.perf_counter()
            result = engine.infer(*inputs[i % len(inputs)])
            result.timings_ms["engine"] = (time.perf_counter() - t) * 1000
            outputs.append(result.disparity)
            for k in STAGES:
                if k in result.timings_ms:
                    times[name].setdefault(k, []).append(result.timings_ms[k])
        same &= bool(np.array_equal(*outputs))
    FrameMatch.after_graphs = after_graphs
    print(f"{engine.describe()}; {args.frames} frames each, alternated; outputs the same: {same}")
    for name, stages in times.items():
        print(f"StereoBM started {name}: " + ", ".join(
            f"{k} {statistics.median(v):.1f}" for k, v in stages.items()) + " ms")
    print(f"matching restarted after the selection moved the count: "
          f"{engine.match_schedule.starts['recounted'] if engine.match_schedule else 0}")


if __name__ == "__main__":
    main()
